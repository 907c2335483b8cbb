"""Files with several solids (issue 20, item 2): listed, refused when they overlap, one
picked with ``--solid NAME|INDEX``.

The files are written here with OCP's XCAF writer (named solids, as CAD exports name their
bodies): two disjoint boxes "bracket" and "plate"; a box "inner" inside a box "outer".
Real OCP reading and Boolean common, the real CLI.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qifreport.step.reader import read_step
from qifreport.step.solids import overlapping_pairs, pick_solid, solid_infos
from qifreport.step.write import write_step_solids

EXE = Path(sys.executable).with_name("qifreport")
PLATE = ((150.0, 0.0, 0.0), (60.0, 60.0, 3.0))  # corner, size, mm


def _box(corner, size):
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.gp import gp_Pnt

    return BRepPrimAPI_MakeBox(gp_Pnt(*corner), *size).Shape()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("solids")
    two, nested = d / "two.stp", d / "nested.stp"
    write_step_solids(two, [("bracket", _box((0, 0, 0), (100, 40, 5))), ("plate", _box(*PLATE))])
    write_step_solids(
        nested,
        [("outer", _box((0, 0, 0), (100, 100, 20))), ("inner", _box((20, 20, 5), (30, 30, 5)))],
    )
    # a scan of the plate: its six faces sampled at 0.5 mm, 5 um noise along the normal
    rng = np.random.default_rng(0)
    (x0, y0, z0), (dx, dy, dz) = PLATE
    pts = []
    for axis, size in ((2, (dx, dy)), (1, (dx, dz)), (0, (dy, dz))):
        u, v = np.meshgrid(np.arange(0.25, size[0], 0.5), np.arange(0.25, size[1], 0.5))
        for side in (0.0, 1.0):
            P = np.zeros((u.size, 3))
            others = [a for a in range(3) if a != axis]
            P[:, others[0]], P[:, others[1]] = u.ravel(), v.ravel()
            P[:, axis] = side * (dx, dy, dz)[axis] + rng.normal(0, 0.005, u.size)
            pts.append(P + (x0, y0, z0))
    scan = d / "plate_scan.npy"
    np.save(scan, np.vstack(pts))
    return {"two": two, "nested": nested, "scan": scan, "dir": d}


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True)


def test_solids_are_listed_with_names_volumes_and_overlaps(files):
    part = read_step(files["two"])
    infos = solid_infos(part.shape, part.solid_names)
    assert [(s.name, s.faces, round(s.volume)) for s in infos] == [
        ("bracket", 6, 20000),
        ("plate", 6, 10800),
    ]
    assert overlapping_pairs(part.shape, infos) == []
    nested = read_step(files["nested"])
    ninfo = solid_infos(nested.shape, nested.solid_names)
    ((a, b, v),) = overlapping_pairs(nested.shape, ninfo)
    assert (a, b) == (0, 1) and abs(v - 4500.0) < 1.0  # the inner box's volume
    assert pick_solid(infos, "PLATE") == 1 and pick_solid(infos, "0") == 0
    with pytest.raises(KeyError, match="no solid 2"):
        pick_solid(infos, "2")
    r = run("pmi", files["two"], "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert [s["name"] for s in doc["solids"]] == ["bracket", "plate"]
    assert doc["overlapping_solids"] == []
    r = run("pmi", files["nested"])
    assert r.returncode == 0 and "inner" in r.stdout and "overlap" in r.stdout


def test_several_solids_are_refused_with_a_request_to_pick_one(files):
    out = files["dir"] / "refused"
    r = run(files["two"], files["scan"], "--out", out, "--quiet")
    assert r.returncode == 2
    (line,) = r.stderr.strip().splitlines()
    assert "2 separate solids" in line and '"bracket"' in line and "--solid" in line
    assert not out.exists()
    r = run(files["nested"], files["scan"], "--out", out, "--quiet")
    assert r.returncode == 2
    (line,) = r.stderr.strip().splitlines()
    assert "overlap" in line and '"outer"' in line and '"inner"' in line
    assert not out.exists()
    r = run(files["two"], files["scan"], "--out", out, "--quiet", "--solid", "lid")
    assert r.returncode == 2 and "no solid named 'lid'" in r.stderr


def test_the_picked_solid_alone_is_inspected(files):
    out = files["dir"] / "plate"
    r = run(files["two"], files["scan"], "--out", out, "--json", "--no-pdf", "--solid", "plate")
    assert r.returncode in (0, 3), r.stdout + r.stderr
    doc = json.loads((out / "two.json").read_text())
    assert doc["nominal"]["solid"] == {"index": 1, "name": "plate", "of": 2}
    assert doc["verdict"] != "FAIL", doc["decided_by"]
    # the nominal is the plate's 6 faces only: the bracket's area is not in it
    assert abs(doc["coverage"]["nominal_area_mm2"] - 2 * (3600 + 180 + 180)) < 1.0


def _assembly(path: Path) -> None:
    """An XDE assembly "fixture" placing the part "plate" (60 x 60 x 3 mm) twice, at
    (0, 10, 0) and (200, 10, 0): what a CAD assembly export holds."""
    from OCP.gp import gp_Trsf, gp_Vec
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFApp import XCAFApp_Application
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    XCAFApp_Application.GetApplication_s().InitDocument(doc)
    XCAFDoc_DocumentTool.SetLengthUnit_s(doc, 0.001)
    st = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    plate = st.AddShape(_box((0, 0, 0), PLATE[1]), False)
    TDataStd_Name.Set_s(plate, TCollection_ExtendedString("plate"))
    asm = st.NewShape()
    TDataStd_Name.Set_s(asm, TCollection_ExtendedString("fixture"))
    for dx in (0.0, 200.0):
        t = gp_Trsf()
        t.SetTranslation(gp_Vec(dx, 10.0, 0.0))
        st.AddComponent(asm, plate, TopLoc_Location(t))
    st.UpdateAssemblies()
    w = STEPCAFControl_Writer()
    w.SetNameMode(True)
    assert w.Transfer(doc, STEPControl_AsIs) and int(w.Write(str(path))) == 1


def test_an_assembly_places_its_instances(files):
    """Both instances are where the assembly puts them (not one on the other, which would
    be refused as overlapping), named by the part they place; a name they share is
    ambiguous, so one is picked by index."""
    path = files["dir"] / "assembly.stp"
    _assembly(path)
    part = read_step(path)
    infos = solid_infos(part.shape, part.solid_names)
    assert [x.name for x in infos] == ["plate", "plate"]
    assert [x.lo.round(6).tolist() for x in infos] == [[0, 10, 0], [200, 10, 0]]
    assert overlapping_pairs(part.shape, infos) == []
    with pytest.raises(KeyError, match="2 solids are named 'plate'"):
        pick_solid(infos, "plate")
    # the second instance, inspected against the plate scan moved to its place
    scan = files["dir"] / "placed_scan.npy"
    np.save(scan, np.load(files["scan"]) + (200.0 - PLATE[0][0], 10.0, 0.0))
    out = files["dir"] / "placed"
    r = run(path, scan, "--out", out, "--json", "--no-pdf", "--solid", "1", "--prealign", "never")
    assert r.returncode in (0, 3), r.stdout + r.stderr
    doc = json.loads((out / "assembly.json").read_text())
    assert doc["nominal"]["solid"] == {"index": 1, "name": "plate", "of": 2}
    assert doc["verdict"] != "FAIL" and doc["vertex_deviation"]["max_abs"] < 0.1


def test_unnamed_solids_of_one_product_are_read_not_a_crash(tmp_path):
    """One product whose shape is two unnamed solids (as a SolidWorks multi-body export
    writes them): their XDE labels have no name, and OCP's ``FindAttribute`` on such a label
    killed ``pmi`` and ``plan`` with SIGSEGV (exit 139)."""
    from OCP.BRep import BRep_Builder
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopoDS import TopoDS_Compound
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    builder, compound = BRep_Builder(), TopoDS_Compound()
    builder.MakeCompound(compound)
    builder.Add(compound, _box((0, 0, 0), (100, 40, 5)))
    builder.Add(compound, _box(*PLATE))
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    XCAFDoc_DocumentTool.ShapeTool_s(doc.Main()).AddShape(compound, False, False)
    writer = STEPCAFControl_Writer()
    writer.Transfer(doc, STEPControl_AsIs)
    path = tmp_path / "bodies.stp"
    writer.Write(str(path))
    text = path.read_text()
    assert text.count("MANIFOLD_SOLID_BREP('',") == 2 and text.count("PRODUCT(") == 1
    r = run("pmi", path, "--json")
    assert r.returncode == 0, (r.returncode, r.stderr[-500:])
    part = read_step(path)
    assert part.n_solids == 2 and part.solid_names == ["", ""]
