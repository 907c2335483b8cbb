"""Generate ``samples/panel.step``: a thin curved cover as STEP AP242 with semantic PMI.

The part (deterministic; re-run to regenerate, byte-identical output):

* a singly curved cover 160 x 100 mm: a cylindrical crown (outer skin radius 220 mm,
  rise 8.9 mm) between two flat flanges 18 mm wide, wall 1.8 mm (measured vertically;
  1.73 mm normal to the skin where the crown meets the flanges);
* four 6 mm mounting holes in the flanges and a 10 mm locating hole in the crown.

Datums and PMI (faces by their index in ``TopExp.MapShapes(solid, TopAbs_FACE)``):

* **A**: the two flange undersides (one coplanar datum feature, the seating plane);
  **B**: the left end face (x = -80 mm); **C**: the front side face (y = -50 mm).
  A, B, C are mutually perpendicular.
* surface profile 1.0 mm |A|B|C| on every face;
* surface profile 0.5 mm |A|B| on the outer skin of the crown (the functional face);
* flatness 0.2 mm on each flange underside;
* the drawing note :data:`RESTRAINT_NOTE` (AP242 semantic text): the cover is a non-rigid
  part (ISO 10579-NR), toleranced in its restrained condition at its datum targets;
* the drawing note :data:`MATERIAL_NOTE`: the cover is moulded in ABS (the virtual
  fixture's load is measured on that material's elastic model).

Usage: ``python samples/make_step_sample.py [OUT.step]`` (default ``samples/panel.step``).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from dataclasses import asdict
from pathlib import Path

import cadquery as cq
from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepCheck import BRepCheck_Analyzer
from OCP.BRepGProp import BRepGProp
from OCP.GeomAbs import GeomAbs_Cylinder, GeomAbs_Plane
from OCP.GProp import GProp_GProps
from OCP.TopAbs import TopAbs_FACE
from OCP.TopExp import TopExp
from OCP.TopoDS import TopoDS, TopoDS_Shape
from OCP.TopTools import TopTools_IndexedMapOfShape

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qifreport.step.write import PMISpecDatum, PMISpecTarget, PMISpecTolerance, write_step_with_pmi  # noqa: E402

logger = logging.getLogger(__name__)

LENGTH = 160.0  # mm, along x
WIDTH = 100.0  # mm, along y
WALL = 1.8  # mm, vertical wall offset
FLANGE = 18.0  # mm, flange width (each end)
SKIN_RADIUS = 220.0  # mm, outer skin of the crown
MOUNT_HOLE_D = 6.0  # mm, four flange holes
LOCATING_HOLE_D = 10.0  # mm, crown hole
PART_NAME = "curved_cover"
TIMESTAMP = "2025-01-01T00:00:00"  # fixed FILE_NAME time stamp: reproducible file
DEFAULT_PATH = Path(__file__).resolve().parent / "panel.step"

#: the drawing's restraint note (ISO 10579 non-rigid part): the cover is toleranced held at
#: its datum targets, as an inspection fixture holds it (samples/panel_clamps.csv)
RESTRAINT_NOTE = (
    "1. ISO 10579-NR. DIMENSIONING AND TOLERANCING APPLY WITH\n"
    "   PART RESTRAINED: DATUM FEATURE A HELD AGAINST ITS SIMULATOR\n"
    "   AT TARGETS A1-A4, DATUM FEATURES B AND C ENGAGED AT TARGETS\n"
    "   B1, C1-C2; RESTRAINT FORCE AT MOST 20 N PER TARGET."
)

#: the drawing's material note (:mod:`qifreport.step.material` reads its MATERIAL: line)
MATERIAL_NOTE = "2. MATERIAL: ABS"

PROFILE_ALL = 1.0  # mm, |A|B|C| on all faces
PROFILE_SKIN = 0.5  # mm, |A|B| on the outer skin
FLATNESS_FLANGE = 0.2  # mm, each flange underside


def build_part() -> TopoDS_Shape:
    """The cover as a single valid solid (mm; z up, seating plane z = 0).

    Returns
    -------
    TopoDS_Shape
        The solid.
    """
    half = LENGTH / 2 - FLANGE  # half chord of the crown
    rise = SKIN_RADIUS - math.sqrt(SKIN_RADIUS**2 - half**2)
    x0 = LENGTH / 2
    profile = (
        cq.Workplane("XZ")
        .moveTo(-x0, 0.0)
        .lineTo(-half, 0.0)
        .threePointArc((0.0, rise), (half, 0.0))  # inner surface of the crown
        .lineTo(x0, 0.0)
        .lineTo(x0, WALL)
        .lineTo(half, WALL)
        .threePointArc((0.0, rise + WALL), (-half, WALL))  # outer skin
        .lineTo(-x0, WALL)
        .close()
    )
    body = profile.extrude(WIDTH / 2, both=True)
    xm, ym = x0 - FLANGE / 2, WIDTH / 2 - 20.0
    mounts = (
        cq.Workplane("XY")
        .pushPoints([(-xm, -ym), (-xm, ym), (xm, -ym), (xm, ym)])
        .circle(MOUNT_HOLE_D / 2)
        .extrude(5.0, both=True)
    )
    locating = cq.Workplane("XY").circle(LOCATING_HOLE_D / 2).extrude(rise + 5.0, both=True)
    solids = body.cut(mounts).cut(locating).solids().vals()
    if len(solids) != 1:
        raise RuntimeError(f"expected one solid, got {len(solids)}")
    solid = solids[0].wrapped
    if not BRepCheck_Analyzer(solid).IsValid():
        raise RuntimeError("the cover is not a valid solid")
    return solid


def _faces(shape: TopoDS_Shape) -> list[dict]:
    """Type, area and centroid of each face, in ``TopExp.MapShapes`` order."""
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    out = []
    for i in range(1, fmap.Extent() + 1):
        face = TopoDS.Face_s(fmap.FindKey(i))
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(face, props)
        c = props.CentreOfMass()
        out.append(
            {
                "type": BRepAdaptor_Surface(face).GetType(),
                "area": props.Mass(),
                "c": (c.X(), c.Y(), c.Z()),
            }
        )
    return out


def _one(faces: list[dict], what: str, pred) -> int:
    hits = [i for i, f in enumerate(faces) if pred(f)]
    if len(hits) != 1:
        raise RuntimeError(f"{what}: expected one face, found {hits}")
    return hits[0]


def sample_spec(shape: TopoDS_Shape) -> tuple[list[PMISpecDatum], list[PMISpecTolerance]]:
    """Datums and tolerances of the cover, faces found by geometry (not by fixed index).

    Parameters
    ----------
    shape : TopoDS_Shape
        The solid from :func:`build_part`.

    Returns
    -------
    datums, tolerances : list of PMISpecDatum, list of PMISpecTolerance
    """
    faces = _faces(shape)
    eps = 1e-6
    x0 = LENGTH / 2

    def flat_at(axis: int, value: float, side: float = 0.0):
        def pred(f: dict) -> bool:
            c = f["c"]
            return f["type"] == GeomAbs_Plane and abs(c[axis] - value) < eps and c[0] * side >= 0.0

        return pred

    under_left = _one(faces, "left flange underside", flat_at(2, 0.0, -1.0))
    under_right = _one(faces, "right flange underside", flat_at(2, 0.0, +1.0))
    end_left = _one(faces, "left end face", flat_at(0, -x0))
    side_front = _one(faces, "front side face", flat_at(1, -WIDTH / 2))
    skin = _one(
        faces,
        "outer skin",
        lambda f: f["type"] == GeomAbs_Cylinder and f["area"] > 1000.0 and f["c"][2] > 7.0,
    )
    # the datum targets: where the inspection fixture (samples/panel_clamps.csv) touches the
    # part, each with its face's outward normal (ISO 10579 RPS points)
    y0, fx = WIDTH / 2, x0 - FLANGE / 2  # the flanges' mid-lines, x = +/-71
    down, mid_wall = (0.0, 0.0, -1.0), WALL / 2

    def target(n: int, p: tuple, d: tuple, face: int) -> PMISpecTarget:
        return PMISpecTarget(n, p, d, face)

    datums = [
        PMISpecDatum(
            "A",
            [under_left, under_right],
            [
                target(1, (-fx, -42.0, 0.0), down, under_left),
                target(2, (fx, -42.0, 0.0), down, under_right),
                target(3, (-fx, 42.0, 0.0), down, under_left),
                target(4, (fx, 42.0, 0.0), down, under_right),
            ],
        ),
        PMISpecDatum(
            "B", [end_left], [target(1, (-x0, 0.0, mid_wall), (-1.0, 0.0, 0.0), end_left)]
        ),
        PMISpecDatum(
            "C",
            [side_front],
            [
                target(1, (-fx, -y0, mid_wall), (0.0, -1.0, 0.0), side_front),
                target(2, (fx, -y0, mid_wall), (0.0, -1.0, 0.0), side_front),
            ],
        ),
    ]
    tolerances = [
        PMISpecTolerance(
            "surface_profile", PROFILE_ALL, list(range(len(faces))), ["A", "B", "C"], "profile_all"
        ),
        PMISpecTolerance("surface_profile", PROFILE_SKIN, [skin], ["A", "B"], "profile_skin"),
        PMISpecTolerance("flatness", FLATNESS_FLANGE, [under_left], [], "flatness_flange_left"),
        PMISpecTolerance("flatness", FLATNESS_FLANGE, [under_right], [], "flatness_flange_right"),
    ]
    return datums, tolerances


def build_sample(step_path: str | Path = DEFAULT_PATH) -> dict:
    """Build the cover and write it with its PMI to ``step_path`` (STEP AP242, mm).

    Parameters
    ----------
    step_path : str or Path
        Output file (written atomically).

    Returns
    -------
    dict
        ``path``, ``part_name``, ``n_faces``, ``functional_face`` (index of the outer
        skin), ``datums`` and ``tolerances``: the written specification as plain dicts
        (face indices into ``TopExp.MapShapes(build_part(), TopAbs_FACE)``, values in mm).
    """
    step_path = Path(step_path)
    shape = build_part()
    datums, tolerances = sample_spec(shape)
    write_step_with_pmi(
        shape,
        step_path,
        tolerances,
        datums,
        PART_NAME,
        timestamp=TIMESTAMP,
        notes=[RESTRAINT_NOTE, MATERIAL_NOTE],
    )
    skin = next(t for t in tolerances if t.name == "profile_skin").faces[0]
    return {
        "path": str(step_path),
        "part_name": PART_NAME,
        "n_faces": len(_faces(shape)),
        "functional_face": skin,
        "datums": [asdict(d) for d in datums],
        "tolerances": [asdict(t) for t in tolerances],
    }


def main(argv: list[str] | None = None) -> None:
    """Write the sample (default ``samples/panel.step``) and print its specification."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", type=Path, default=DEFAULT_PATH)
    args = ap.parse_args(argv)
    spec = build_sample(args.out)
    size = args.out.stat().st_size
    print(f"{spec['path']}: {spec['n_faces']} faces, {size} bytes")
    for d in spec["datums"]:
        print(f"  datum {d['label']}: faces {d['faces']}")
    for t in spec["tolerances"]:
        ref = "|".join(t["datums"])
        print(f"  {t['name']}: {t['type']} {t['value']} mm |{ref}| faces {t['faces']}")


if __name__ == "__main__":
    main()
