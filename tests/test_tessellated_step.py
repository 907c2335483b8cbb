"""A tessellated AP242 part (triangulated faces, no B-rep, as NIST's ``-tg`` editions): its
PMI is read on the triangulated faces, its plan is the B-rep edition's, and it is inspected
on its own triangles (the file's mesh is the nominal).

The files are written by :func:`qifreport.step.write_tessellated.write_tessellated_with_pmi`
and :func:`qifreport.step.write.write_step_with_pmi` from one block, 60 x 40 x 20 mm: its top
face flat within 0.1, its +x side a 0.4 profile to datum A (the bottom face); the
tessellated edition's drawing names its material."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

from qifreport.errors import InputError
from qifreport.nominal import load_nominal
from qifreport.step.p21 import P21Model
from qifreport.step.reader import read_step
from qifreport.step.write import PMISpecDatum, PMISpecTolerance, write_step_with_pmi
from qifreport.step.write_tessellated import write_tessellated_with_pmi

EXE = Path(sys.executable).with_name("qifreport")
SIZE = (60.0, 40.0, 20.0)
# the faces of BRepPrimAPI_MakeBox in TopExp.MapShapes order
X0, X1, Y0, Y1, Z0, Z1 = range(6)


def _spec() -> tuple[list[PMISpecTolerance], list[PMISpecDatum]]:
    return (
        [
            PMISpecTolerance("flatness", 0.1, [Z1], name="FL1"),
            PMISpecTolerance("surface_profile", 0.4, [X1], ["A"], name="SP1"),
        ],
        [PMISpecDatum("A", [Z0])],
    )


@pytest.fixture(scope="module")
def editions(tmp_path_factory) -> dict[str, Path]:
    """The block as a B-rep file and as a tessellated file, one drawing."""
    d = tmp_path_factory.mktemp("tessellated")
    tolerances, datums = _spec()
    shape = BRepPrimAPI_MakeBox(*SIZE).Shape()
    write_step_with_pmi(shape, d / "block.stp", tolerances, datums, "block", timestamp="")
    tolerances, datums = _spec()
    write_tessellated_with_pmi(
        shape, d / "block_tg.stp", tolerances, datums, "block", notes=["1. MATERIAL: ABS"]
    )
    return {"brep": d / "block.stp", "tessellated": d / "block_tg.stp"}


def _scan(path: Path, bow: float = 0.0) -> Path:
    """A scan of the block (every face, 30k points, 5 um noise); the top face bowed up by
    ``bow`` mm at its middle (a parabola along x, zero at its two x edges)."""
    m = trimesh.creation.box(extents=SIZE)
    m.apply_translation(np.array(SIZE) / 2)
    P, _ = trimesh.sample.sample_surface_even(m, 30000, seed=3)
    P = P + np.random.default_rng(4).normal(0.0, 0.005, P.shape)
    top = P[:, 2] > SIZE[2] - 0.05
    u = P[top, 0] / SIZE[0]
    P[top, 2] += bow * 4.0 * u * (1.0 - u)
    trimesh.PointCloud(P).export(path)
    return path


def _inspect(step: Path, scan: Path, out: Path) -> tuple[int, dict]:
    r = subprocess.run(
        [str(EXE), str(step), str(scan), "--out", str(out), "--json", "--no-pdf"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode in (0, 1, 3), r.stderr
    return r.returncode, json.loads((out / f"{step.stem}.json").read_text())


def test_the_file_has_no_b_rep_and_its_pmi_names_triangulated_faces(editions):
    model = P21Model.read(editions["tessellated"])
    assert not model.by_type("ADVANCED_FACE") and not model.by_type("MANIFOLD_SOLID_BREP")
    part = read_step(editions["tessellated"])
    assert part.tessellated and part.n_solids == 0 and len(part.faces) == 6
    triangulated = {e.id for e in model.by_type("TRIANGULATED_FACE")}
    assert set(part.face_step_ids.tolist()) == triangulated
    by_name = {t.name: t for t in part.pmi.tolerances}
    index = part.face_index()
    # each item on the face it was written on: the top face for FL1, +x for SP1, bottom for A
    for ids, axis, value in (
        (by_name["FL1"].face_step_ids, 2, SIZE[2]),
        (by_name["SP1"].face_step_ids, 0, SIZE[0]),
        (part.pmi.datums[0].face_step_ids, 2, 0.0),
    ):
        (sid,) = ids
        assert sid in triangulated
        coords = model[model[sid].params[1]].params[2]
        assert np.allclose([p[axis] for p in coords], value)
        assert index[sid] >= 0
    # the B-rep edition reads the same items
    brep = read_step(editions["brep"])
    assert not brep.tessellated and brep.n_solids == 1
    assert [(t.type, t.value) for t in brep.pmi.tolerances] == [
        (t.type, t.value) for t in part.pmi.tolerances
    ]


def test_its_plan_is_the_b_rep_edition_s(editions, tmp_path):
    for step in editions.values():
        r = subprocess.run(
            [str(EXE), "plan", str(step), "--out", str(tmp_path)], capture_output=True, text=True
        )
        assert r.returncode == 0, r.stderr
        assert "2 characteristics; valid" in r.stdout
    r = subprocess.run(
        [
            str(EXE),
            "plan",
            str(editions["tessellated"]),
            "--out",
            str(tmp_path / "again"),
            "--compare",
            str(tmp_path / "block_plan.qif"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_inspected_on_its_own_triangles(editions, tmp_path):
    step = editions["tessellated"]
    # its drawing names a material: the virtual fixture's load would be measured on the
    # solid, which a tessellated part has not; the inspection goes on without it
    assert read_step(step).pmi.material.text == "ABS"
    rc, good = _inspect(step, _scan(tmp_path / "good.ply"), tmp_path / "good")
    assert rc == 0 and good["verdict"] == "PASS"
    assert good["nominal"]["tessellated"] is True
    (flat,) = good["characteristics"]
    assert flat["status"] == "PASS" and flat["value"] < 0.05
    (sp1,) = [t for t in good["tolerances"] if t["name"] == "SP1"]
    assert sp1["verdict"] == "PASS"
    # the top bowed 0.3 mm: its flatness reads the bow and fails
    rc, bowed = _inspect(step, _scan(tmp_path / "bowed.ply", bow=0.3), tmp_path / "bowed")
    assert rc == 1 and bowed["verdict"] == "FAIL"
    (flat,) = bowed["characteristics"]
    assert flat["status"] == "FAIL" and abs(flat["value"] - 0.3) < 0.03 + flat["uncertainty"]


def test_a_restrained_inspection_of_it_is_refused_by_name(editions):
    with pytest.raises(InputError, match="tessellated part .* needs its solid"):
        load_nominal(editions["tessellated"], None, solid_mesh=True)


def test_its_features_read_as_the_b_rep_edition_s(tmp_path):
    """A block with a through hole (position |A|B|C| 0.2, cylindricity 0.05), both editions
    inspected on one scan: the hole's characteristics are read the same within 5 um."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder
    from OCP.GeomAbs import GeomAbs_Cylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopoDS import TopoDS
    from OCP.TopTools import TopTools_IndexedMapOfShape

    block = BRepPrimAPI_MakeBox(60.0, 40.0, 10.0).Shape()
    hole = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(30, 20, -1), gp_Dir(0, 0, 1)), 5, 12).Shape()
    shape = BRepAlgoAPI_Cut(block, hole).Shape()
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    (bore,) = [
        i - 1
        for i in range(1, fmap.Size() + 1)
        if BRepAdaptor_Surface(TopoDS.Face_s(fmap.FindKey(i))).GetType() == GeomAbs_Cylinder
    ]

    def spec():
        return (
            [
                PMISpecTolerance("position", 0.2, [bore], ["A", "B", "C"], name="POS"),
                PMISpecTolerance("cylindricity", 0.05, [bore], name="CYL"),
            ],
            [PMISpecDatum("A", [Z0]), PMISpecDatum("B", [X0]), PMISpecDatum("C", [Y0])],
        )

    write_step_with_pmi(shape, tmp_path / "holed.stp", *spec(), "holed", timestamp="")
    write_tessellated_with_pmi(shape, tmp_path / "holed_tg.stp", *spec(), "holed")
    part, _ = load_nominal(tmp_path / "holed.stp", None)
    P, _ = trimesh.sample.sample_surface_even(trimesh.Trimesh(part.V, part.F), 40000, seed=1)
    P = P + np.random.default_rng(0).normal(0.0, 0.005, P.shape)
    scan = tmp_path / "holed_scan.ply"
    trimesh.PointCloud(P).export(scan)
    read = {}
    for step in (tmp_path / "holed.stp", tmp_path / "holed_tg.stp"):
        _, res = _inspect(step, scan, tmp_path / step.stem)
        read[step.stem] = {c["name"]: c for c in res["characteristics"]}
    for name in ("POS", "CYL"):
        brep, tess = read["holed"][name], read["holed_tg"][name]
        assert brep["status"] in ("PASS", "INDETERMINATE") and tess["status"] == brep["status"], (
            name
        )
        assert abs(tess["value"] - brep["value"]) < 0.005, name
