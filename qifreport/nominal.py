"""The nominal as an inspection needs it: a STEP part (mesh + PMI zones) or a mesh.

:func:`load_nominal` reads a STEP AP242 file through :mod:`qifreport.step` (tessellation with
per-face ids, semantic PMI turned into tolerance zones by
:func:`qifreport.metrology.acceptance.bands.zones_from_pmi`) or a mesh nominal (STL/PLY/OBJ/OFF)
with one
general zone of the given tolerance.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qifreport.metrology.acceptance.bands import (
    NotEvaluated,
    ToleranceZone,
    symmetric_zone,
    zones_from_pmi,
)
from qifreport.metrology.gdt.characteristics import CharacteristicPlan, specs_from_pmi
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import (
    bounding_diagonal,
    consistent_winding,
    load_mesh,
    remove_unreferenced,
)
from qifreport.step.reader import STEP_SUFFIXES
from qifreport.step.solids import SolidInfo, overlapping_pairs, pick_solid, solid_infos

from .errors import InputError

if TYPE_CHECKING:
    from qifreport.step.gmsh_mesh import SolidMesh

log = logging.getLogger(__name__)

__all__ = [
    "Nominal",
    "load_nominal",
    "pick_part_solid",
    "seat_faces",
]


@dataclass
class Nominal:
    """The nominal as the inspection needs it: mesh, face ids, zones, provenance."""

    V: np.ndarray
    F: np.ndarray
    face_id: np.ndarray | None
    zones: list[ToleranceZone]
    not_evaluated: list[NotEvaluated]
    info: dict
    datums: list[str] = field(default_factory=list)
    #: (f, 3, 3) the B-rep's outward normals at each triangle's corners (a STEP nominal;
    #: :func:`qifreport.step.normals.corner_normals_exact`), None for a mesh nominal
    brep_normals: np.ndarray | None = None
    #: the tetrahedra filling the STEP part's solid, for its elastic model (when asked for:
    #: :func:`load_nominal` ``solid_mesh``)
    solid_mesh: SolidMesh | None = None
    #: the drawing's feature characteristics and datums (a STEP nominal with PMI)
    plan: CharacteristicPlan | None = None
    #: (n_faces,) the STEP entity id of each B-rep face (-1 unknown), None for a mesh
    face_step_ids: np.ndarray | None = None


def load_nominal(
    path: Path,
    tolerance: float | None,
    max_edge: float | None = None,
    deflection: float | None = None,
    *,
    accept_tolerance_as_read: bool = False,
    mesher: str = "gmsh",
    solid: str | None = None,
    solid_mesh: bool = False,
) -> Nominal:
    """Read a STEP part (mesh + PMI zones) or a mesh nominal (one general zone).

    A STEP part whose tolerances the plausibility check flags
    (:func:`qifreport.step.plausibility.implausible_tolerances`: a zone wider than 10 % of
    the part's diagonal, or unreadable as a length) is refused (:class:`InputError`, naming
    the first value) unless ``accept_tolerance_as_read``; then the reasons are kept in
    ``info["implausible_tolerances"]``.

    ``mesher``: ``"gmsh"`` (:func:`qifreport.step.gmsh_mesh.gmsh_tessellate`, isotropic,
    welded and manifold; the default) or ``"brepmesh"``
    (:func:`qifreport.step.tessellate.tessellate`).

    ``solid``: the solid of a multi-solid STEP file to inspect, by index or name
    (:func:`pick_part_solid`; a file with several solids is refused without it).

    ``solid_mesh``: also fill a STEP part's solid with tetrahedra (``Nominal.solid_mesh``,
    edge :data:`qifreport.restraint.SOLID_EDGE_SHARE` of its diagonal), for the elastic
    model of a restrained inspection.
    """
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--tolerance must be a positive length in mm, got {tolerance}")
    if path.suffix.lower() in STEP_SUFFIXES:
        from qifreport.step.normals import corner_normals_exact
        from qifreport.step.plausibility import implausible_tolerances
        from qifreport.step.reader import read_step
        from qifreport.step.supplemental import face_solids
        from qifreport.step.tessellate import shape_diagonal, tessellate

        part = read_step(path)
        diagonal = shape_diagonal(part.shape)
        implausible = implausible_tolerances(part.pmi, diagonal)
        if implausible and not accept_tolerance_as_read:
            more = f" (and {len(implausible) - 1} more)" if len(implausible) > 1 else ""
            raise InputError(
                f"{path.name}: implausible tolerance read from the file: {implausible[0]}{more}; "
                "if the drawing really means it, run with --accept-tolerance-as-read"
            )
        chosen, picked = pick_part_solid(part, solid)
        if picked is not None:  # the part is that solid: its size sets the mesh
            diagonal = float(np.linalg.norm(picked.hi - picked.lo))
        if max_edge is None:
            max_edge = diagonal / 60.0
        if mesher == "gmsh":
            from qifreport.step.gmsh_mesh import gmsh_tessellate

            mesh = gmsh_tessellate(part.shape, part.faces, deflection=deflection, max_edge=max_edge)
        else:
            mesh = tessellate(part.shape, part.faces, deflection=deflection, max_edge=max_edge)
        zones, skipped = zones_from_pmi(part.pmi, part.face_index(), tolerance)
        V, F, face_id = mesh.V, mesh.F, mesh.face_id
        supplemental: list[dict] = []
        face_solid = face_solids(part.shape, part.faces)
        if chosen is not None or (face_solid < 0).any():
            V, F, face_id, zones, skipped, supplemental = seat_faces(
                V,
                F,
                face_id,
                face_solid,
                chosen,
                zones,
                skipped,
                part.face_step_ids,
                2.0 * mesh.deflection,
            )
        pmi = part.pmi
        info = {
            "format": "step",
            "schema": getattr(pmi, "schema", None),
            "length_unit": getattr(pmi, "length_unit", None),
            "b_rep_faces": len(part.faces),
            "solids": part.n_solids,
            "tessellation": {
                "mesher": mesher,
                "deflection_mm": mesh.deflection,
                "max_edge_mm": max_edge,
                "vertices": len(V),
                "triangles": len(F),
            },
            "pmi_counts": {
                "tolerances": len(pmi.tolerances) if pmi else 0,
                "dimensions": len(pmi.dimensions) if pmi else 0,
                "datums": len(pmi.datums) if pmi else 0,
            },
            "timings_s": {**part.timings, "tessellate": mesh.seconds},
        }
        if implausible:
            info["implausible_tolerances"] = implausible
        if supplemental:
            info["supplemental_faces"] = supplemental
        if picked is not None:
            info["solid"] = {"index": chosen, "name": picked.name, "of": part.n_solids}
        datums = [d.label for d in pmi.datums] if pmi is not None else []
        t0 = time.perf_counter()
        normals = corner_normals_exact(part.faces, V, F, face_id)
        info["timings_s"]["corner normals"] = time.perf_counter() - t0
        tets = None
        if solid_mesh:
            from qifreport.step.gmsh_mesh import gmsh_solid_mesh
            from qifreport.step.solids import solid_shape

            from .restraint import SOLID_EDGE_SHARE

            shape = part.shape if chosen is None else solid_shape(part.shape, chosen)
            tets = gmsh_solid_mesh(shape, SOLID_EDGE_SHARE * diagonal)
            info["timings_s"]["solid tetrahedra"] = tets.seconds
        return Nominal(
            V,
            F,
            face_id,
            zones,
            skipped,
            info,
            list(dict.fromkeys(datums)),
            brep_normals=normals,
            solid_mesh=tets,
            plan=specs_from_pmi(pmi, part.face_index()),
            face_step_ids=np.asarray(part.face_step_ids, dtype=np.int64),
        )
    if tolerance is None:
        raise InputError(
            f"{path.name} is a mesh nominal: it carries no tolerance, give "
            "--tolerance MM (or use the STEP file with PMI)"
        )
    V, F = load_mesh(path)
    F, flipped, unorientable = consistent_winding(V, F)
    if flipped:
        log.warning(
            "%s: %d triangle(s) wound against their neighbours were turned over", path.name, flipped
        )
    if unorientable:
        log.warning(
            "%s: %d triangle(s) lie on a piece no winding can orient", path.name, unorientable
        )
    info = {
        "format": "mesh",
        "diagonal_mm": bounding_diagonal(V),
        "winding": {"flipped_triangles": flipped, "unorientable_triangles": unorientable},
    }
    return Nominal(V, F, None, [symmetric_zone(tolerance, "general")], [], info)


def seat_faces(
    V: np.ndarray,
    F: np.ndarray,
    face_id: np.ndarray,
    face_solid: np.ndarray,
    solid: int | None,
    zones: list[ToleranceZone],
    skipped: list[NotEvaluated],
    face_step_ids: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[ToleranceZone], list[NotEvaluated], list]:
    """Keep the mesh of the part inspected: the faces of solid ``solid`` (every solid's when
    None) without the supplemental faces (in no solid), and judge the tolerances that name a
    supplemental face on the solid beneath it (:mod:`qifreport.step.supplemental`).

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3).  face_id : (f,) face of each triangle.
    face_solid : (n_faces,) solid of each face, -1 for none
        (:func:`qifreport.step.supplemental.face_solids`).
    solid : the solid inspected (``--solid``), or None.
    zones, skipped : from ``zones_from_pmi``.
    face_step_ids : (n_faces,) STEP id of each face (-1 unknown).
    tol : mm, how far from a supplemental face the solid's triangles beneath it may lie.

    Returns
    -------
    V, F, face_id : the mesh kept (unused vertices dropped).
    zones : each zone on the faces kept; a zone naming a supplemental face on the solid takes
        its footprint's triangles (``ToleranceZone.triangles``); a zone left with no surface
        is moved to
    skipped : with the reason.
    supplemental : one dict per supplemental face (the JSON's ``nominal.supplemental_faces``).
    """
    from qifreport.step.supplemental import footprints

    free = face_solid < 0
    other = (
        np.zeros(len(face_solid), dtype=bool)
        if solid is None
        else (face_solid >= 0) & (face_solid != solid)
    )
    keep = ~other[face_id]
    F1, fid1 = F[keep], face_id[keep]
    prints = {fp.face: fp for fp in footprints(V, F1, fid1, free, tol)}
    keep2 = ~free[fid1]
    new_tri = np.cumsum(keep2) - 1
    F2, fid2 = F1[keep2], fid1[keep2]
    V2, F2 = remove_unreferenced(V, F2)
    out_zones, out_skipped = [], list(skipped)
    for z in zones:
        if z.faces is None or not (free[z.faces].any() or other[z.faces].any()):
            out_zones.append(z)
            continue
        mine = [int(f) for f in z.faces if free[f]]
        tris = [new_tri[prints[f].triangles] for f in mine if f in prints]
        tris = unique_sorted(np.concatenate(tris)) if tris else np.zeros(0, dtype=np.int64)
        kept = np.array([f for f in z.faces if not free[f] and not other[f]], dtype=np.int64)
        if len(tris) == 0 and len(kept) == 0:
            if other[z.faces].any():
                where = sorted({int(face_solid[f]) for f in z.faces if other[f]})
                reason = (
                    f"its faces are on solid {', '.join(map(str, where))}, not on the solid "
                    f"inspected ({solid})"
                )
            else:
                ids = ", ".join(f"#{face_step_ids[f]}" for f in mine)
                reason = (
                    f"its face {ids} is supplemental geometry off the part's solid: no scan "
                    "of the part can measure it"
                )
            out_skipped.append(
                NotEvaluated(kind=z.kind, name=z.name, step_id=z.step_id, reason=reason)
            )
            continue
        faces = np.array([f for f in z.faces if not other[f]], dtype=np.int64)
        out_zones.append(replace(z, faces=faces, triangles=tris if len(tris) else None))
    supplemental = [
        {
            "face": f,
            "step_id": int(face_step_ids[f]) if face_step_ids[f] >= 0 else None,
            "area_mm2": fp.free_area,
            "footprint_area_mm2": fp.area,
            "on_faces": [int(x) for x in fp.on_faces],
        }
        for f, fp in sorted(prints.items())
    ]
    for f, fp in sorted(prints.items()):
        where = (
            f"on face(s) {', '.join(str(int(x)) for x in fp.on_faces)}"
            if len(fp.triangles)
            else "off the solid"
        )
        log.info(
            "supplemental face %d (#%d, %.1f mm^2) %s: left out of the mesh",
            f,
            face_step_ids[f],
            fp.free_area,
            where,
        )
    return V2, F2, fid2, out_zones, out_skipped, supplemental


def pick_part_solid(part, solid: str | None) -> tuple[int | None, SolidInfo | None]:
    """The solid of a STEP part to inspect: ``(index, its SolidInfo)``, ``(None, None)`` for
    a part with one solid. Several solids without ``solid`` are refused (:class:`InputError`):
    overlapping or nested ones as never one part, separate ones with a request to pick one
    with ``--solid NAME|INDEX``, listing them."""
    if part.n_solids < 2:
        if solid is not None and solid.strip() not in ("0", *part.solid_names):
            raise InputError(f"--solid {solid}: {part.path.name} has one solid (0)")
        return None, None
    infos = solid_infos(part.shape, part.solid_names)
    listing = "; ".join(x.describe() for x in infos)
    if solid is None:
        pairs = overlapping_pairs(part.shape, infos)
        if pairs:
            a, b, v = pairs[0]
            raise InputError(
                f"{part.path.name}: solids {infos[a].describe()} and {infos[b].describe()} "
                f"overlap ({v:,.0f} mm^3 in common; {len(pairs)} overlapping pair(s)): "
                "nested or overlapping solids are not one part; pick one with --solid "
                "NAME|INDEX"
            )
        raise InputError(
            f"{part.path.name} holds {len(infos)} separate solids ({listing}): one part per "
            "inspection, pick one with --solid NAME|INDEX"
        )
    try:
        k = pick_solid(infos, solid)
    except KeyError as exc:
        raise InputError(f"--solid {solid}: {exc.args[0]}; the solids are {listing}") from None
    return k, infos[k]
