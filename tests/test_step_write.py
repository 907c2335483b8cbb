"""STEP AP242 with semantic PMI: the sample cover, its file text, and the XDE round trip.

The file text is checked with a small Part 21 parser written here, independently of OCCT:
each tolerance's magnitude is followed to its measure entity and unit entity, and
``value * unit_scale`` must equal the requested value in mm exactly.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import pytest

pytest.importorskip("OCP")
pytest.importorskip("cadquery")

from OCP.BRep import BRep_Tool  # noqa: E402
from OCP.BRepAdaptor import BRepAdaptor_Surface  # noqa: E402
from OCP.BRepCheck import BRepCheck_Analyzer  # noqa: E402
from OCP.BRepGProp import BRepGProp  # noqa: E402
from OCP.GeomAbs import GeomAbs_Plane  # noqa: E402
from OCP.GProp import GProp_GProps  # noqa: E402
from OCP.IFSelect import IFSelect_ReturnStatus  # noqa: E402
from OCP.Interface import Interface_Static  # noqa: E402
from OCP.STEPCAFControl import STEPCAFControl_Reader  # noqa: E402
from OCP.TCollection import TCollection_ExtendedString  # noqa: E402
from OCP.TDF import TDF_LabelSequence  # noqa: E402
from OCP.TDocStd import TDocStd_Document  # noqa: E402
from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL, TopAbs_SOLID  # noqa: E402
from OCP.TopExp import TopExp, TopExp_Explorer  # noqa: E402
from OCP.TopoDS import TopoDS  # noqa: E402
from OCP.TopTools import TopTools_IndexedMapOfShape  # noqa: E402
from OCP.XCAFApp import XCAFApp_Application  # noqa: E402
from OCP.XCAFDoc import (  # noqa: E402
    XCAFDoc_Datum,
    XCAFDoc_DimTolTool,
    XCAFDoc_DocumentTool,
    XCAFDoc_GeomTolerance,
    XCAFDoc_ShapeTool,
)

import qifreport.step.write as stepwrite  # noqa: E402
from qifreport.step.write import (  # noqa: E402
    TOLERANCE_TYPES,
    PMISpecDatum,
    PMISpecTolerance,
    write_step_with_pmi,
)
from samples.make_step_sample import (  # noqa: E402
    LENGTH,
    SKIN_RADIUS,
    WALL,
    WIDTH,
    build_part,
    build_sample,
)

# ----------------------------------------------------------------- Part 21 text parsing

_ENTITY = re.compile(r"#(\d+)\s*=\s*(.*)", re.S)
_REF = re.compile(r"#\d+")
_TOL = re.compile(r"([A-Z_]*TOLERANCE)\('((?:[^']|'')*)','(?:[^']|'')*',(#\d+),(#\d+)\)")
_SI_PREFIX_MM = {
    "$": 1000.0,
    "KILO": 1e6,
    "DECI": 100.0,
    "CENTI": 10.0,
    "MILLI": 1.0,
    "MICRO": 1e-3,
    "NANO": 1e-6,
}


def parse_part21(text: str) -> dict[str, str]:
    """``{"#id": body}`` of the DATA section; whitespace outside strings collapsed."""
    data = text.split("DATA;", 1)[1].rsplit("ENDSEC;", 1)[0]
    entities, buf, in_str = {}, [], False
    for ch in data:
        if ch == "'":
            in_str = not in_str  # a doubled quote toggles twice
        if ch == ";" and not in_str:
            m = _ENTITY.match("".join(buf).strip())
            if m:
                body = re.sub(r"\s+", " ", m.group(2)).strip()
                entities[f"#{m.group(1)}"] = re.sub(r"\s*([(),])\s*", r"\1", body)
            buf = []
        elif ch in "\r\n" and not in_str:
            buf.append(" ")
        else:
            buf.append(ch)
    return entities


def length_unit_scale_mm(ents: dict[str, str], ref: str) -> float:
    """Millimetres per unit of the length unit entity ``ref`` (SI or conversion-based)."""
    body = ents[ref]
    assert "LENGTH_UNIT()" in body, f"{ref} is not a length unit: {body}"
    m = re.search(r"SI_UNIT\(([^,]*),\.METRE\.\)", body)
    if m:
        return _SI_PREFIX_MM[m.group(1).strip(".")]
    m = re.search(r"CONVERSION_BASED_UNIT\('[^']*',(#\d+)\)", body)
    assert m, f"unsupported length unit {ref}: {body}"
    value, unit = measure_value(ents, m.group(1))
    return value * length_unit_scale_mm(ents, unit)


def measure_value(ents: dict[str, str], ref: str) -> tuple[float, str]:
    """``(value, unit ref)`` of a LENGTH_MEASURE_WITH_UNIT (plain or complex with a
    MEASURE_REPRESENTATION_ITEM)."""
    body = ents[ref]
    m = re.fullmatch(r"LENGTH_MEASURE_WITH_UNIT\(LENGTH_MEASURE\(([^)]*)\),(#\d+)\)", body)
    if m is None:  # ( LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM() ... )
        m = re.search(r"MEASURE_WITH_UNIT\(LENGTH_MEASURE\(([^)]*)\),(#\d+)\)", body)
    assert m, f"{ref} is not a length measure: {body}"
    return float(m.group(1)), m.group(2)


def tolerances_in_text(ents: dict[str, str]) -> dict[str, dict]:
    """Each geometric tolerance: name -> kind, magnitude text/value/unit, aspect, datum ref."""
    out = {}
    for ref, body in ents.items():
        m = _TOL.search(body)
        if not m:
            continue
        kind, name, mag, aspect = m.groups()
        value, unit = measure_value(ents, mag)
        dsys = re.search(r"GEOMETRIC_TOLERANCE_WITH_DATUM_REFERENCE\(\((#\d+)\)\)", body)
        out[name] = {
            "ref": ref,
            "body": body,
            "kind": kind,
            "measure": mag,
            "value": value,
            "unit": unit,
            "aspect": aspect,
            "datum_system": dsys.group(1) if dsys else None,
        }
    return out


def aspect_faces(ents: dict[str, str], aspect: str) -> list[str]:
    """ADVANCED_FACE refs named by a shape aspect, directly or through its components."""
    gisu = re.compile(rf"GEOMETRIC_ITEM_SPECIFIC_USAGE\('[^']*','[^']*',{aspect},#\d+,(#\d+)\)")
    faces = [m.group(1) for b in ents.values() if (m := gisu.fullmatch(b))]
    if "COMPOSITE_SHAPE_ASPECT" in ents[aspect]:
        rel = re.compile(rf"SHAPE_ASPECT_RELATIONSHIP\('[^']*',(?:\$|'[^']*'),{aspect},(#\d+)\)")
        for b in ents.values():
            if m := rel.fullmatch(b):
                if "DATUM(" not in ents[m.group(1)]:
                    faces += aspect_faces(ents, m.group(1))
    for f in faces:
        assert ents[f].startswith("ADVANCED_FACE("), f"{f}: {ents[f]}"
    return faces


def datum_system_labels(ents: dict[str, str], dsys: str) -> list[str]:
    """Datum letters of a DATUM_SYSTEM, in compartment (precedence) order."""
    m = re.fullmatch(r"DATUM_SYSTEM\('[^']*','[^']*',#\d+,\.[TF]\.,\(([^)]*)\)\)", ents[dsys])
    assert m, ents[dsys]
    letters = []
    for comp in _REF.findall(m.group(1)):
        c = re.fullmatch(
            r"DATUM_REFERENCE_COMPARTMENT\('[^']*','[^']*',#\d+,\.[TF]\.,(#\d+),\$\)", ents[comp]
        )
        assert c, ents[comp]
        d = re.fullmatch(r"DATUM\('[^']*','[^']*',#\d+,\.[TF]\.,'([^']*)'\)", ents[c.group(1)])
        assert d, ents[c.group(1)]
        letters.append(d.group(1))
    return letters


def context_length_unit(ents: dict[str, str]) -> str:
    units = [b for b in ents.values() if "GLOBAL_UNIT_ASSIGNED_CONTEXT" in b]
    assert len(units) == 1
    refs = _REF.findall(re.search(r"GLOBAL_UNIT_ASSIGNED_CONTEXT\(\(([^)]*)\)\)", units[0])[1])
    (unit,) = [r for r in refs if "LENGTH_UNIT()" in ents[r]]
    return unit


# ----------------------------------------------------------------- XDE / geometry helpers


def face_key(face) -> tuple:
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props)
    c = props.CentreOfMass()
    return BRepAdaptor_Surface(TopoDS.Face_s(face)).GetType(), props.Mass(), (c.X(), c.Y(), c.Z())


def faces_of(shape) -> list:
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    return [fmap.FindKey(i) for i in range(1, fmap.Extent() + 1)]


def index_of(face, originals: list[tuple]) -> int:
    """Index of the original face with the same surface type, area and centroid.

    Loose tolerances: GProp integrates trimmed faces numerically (the holed skin's area
    differs by ~1e-5 relative after a STEP round trip); the part's faces are millimetres
    apart.
    """
    kind, area, c = face_key(face)
    hits = [
        i
        for i, (k, a, o) in enumerate(originals)
        if k == kind and math.isclose(a, area, rel_tol=1e-3) and math.dist(c, o) < 1e-2
    ]
    assert len(hits) == 1, f"face matches originals {hits}"
    return hits[0]


def read_xde(path: Path) -> TDocStd_Document:
    reader = STEPCAFControl_Reader()
    reader.SetGDTMode(True)
    reader.SetNameMode(True)
    assert reader.ReadFile(str(path)) == IFSelect_ReturnStatus.IFSelect_RetDone
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    XCAFApp_Application.GetApplication_s().InitDocument(doc)
    assert reader.Transfer(doc)
    return doc


def seq_list(seq: TDF_LabelSequence) -> list:
    return [seq.Value(i) for i in range(1, seq.Length() + 1)]


def xde_tolerances(doc) -> list[dict]:
    """Each geometric tolerance of an XDE document: type, value, faces, datums."""
    dimtol = XCAFDoc_DocumentTool.DimTolTool_s(doc.Main())
    labels = TDF_LabelSequence()
    dimtol.GetGeomToleranceLabels(labels)
    out = []
    for lab in seq_list(labels):
        # label.FindAttribute(GUID, attr) does not fill attr in OCP 7.9: Set_s returns the
        # existing attribute.
        obj = XCAFDoc_GeomTolerance.Set_s(lab).GetObject()
        firsts, seconds = TDF_LabelSequence(), TDF_LabelSequence()
        linked = XCAFDoc_DimTolTool.GetRefShapeLabel_s(lab, firsts, seconds)
        dls = TDF_LabelSequence()
        XCAFDoc_DimTolTool.GetDatumWithObjectOfTolerLabels_s(lab, dls)
        datums = []
        for d in seq_list(dls):
            dobj = XCAFDoc_Datum.Set_s(d).GetObject()
            datums.append((dobj.GetPosition(), dobj.GetName().ToCString()))
        out.append(
            {
                "type": obj.GetType(),
                "value": obj.GetValue(),
                "linked": linked,
                "faces": [XCAFDoc_ShapeTool.GetShape_s(f) for f in seq_list(firsts)],
                "datums": [name for _, name in sorted(datums)],
            }
        )
    return out


def xde_datums(doc, targets: bool = False) -> dict[str, list]:
    """Datum name -> faces of its datum feature (the reader makes one label per use), or
    with ``targets`` of its datum targets (one label each)."""
    dimtol = XCAFDoc_DocumentTool.DimTolTool_s(doc.Main())
    labels = TDF_LabelSequence()
    dimtol.GetDatumLabels(labels)
    out: dict[str, list] = {}
    for lab in seq_list(labels):
        obj = XCAFDoc_Datum.Set_s(lab).GetObject()
        if obj.IsDatumTarget() != targets:
            continue
        name = obj.GetName().ToCString()
        firsts, seconds = TDF_LabelSequence(), TDF_LabelSequence()
        assert XCAFDoc_DimTolTool.GetRefShapeLabel_s(lab, firsts, seconds)
        out.setdefault(name, []).append([XCAFDoc_ShapeTool.GetShape_s(f) for f in seq_list(firsts)])
    return out


# ----------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    out = tmp_path_factory.mktemp("step") / "panel.step"
    spec = build_sample(out)
    return spec, out, out.read_text()


@pytest.fixture(scope="module")
def originals():
    return [face_key(f) for f in faces_of(build_part())]


@pytest.fixture(scope="module")
def roundtrip(sample):
    return read_xde(sample[1])


# ----------------------------------------------------------------- (a) the file text


def test_sample_is_small_ap242_with_a_moderate_part(sample):
    spec, path, text = sample
    schema = re.search(r"FILE_SCHEMA\s*\(\s*\(\s*'([^']*)'", text).group(1)
    assert "AP242" in schema and "442" in schema
    assert path.stat().st_size < 300_000
    assert 10 <= spec["n_faces"] < 60
    assert {d["label"] for d in spec["datums"]} == {"A", "B", "C"}
    assert [(t["type"], t["value"], t["datums"]) for t in spec["tolerances"]] == [
        ("surface_profile", 1.0, ["A", "B", "C"]),
        ("surface_profile", 0.5, ["A", "B"]),
        ("flatness", 0.2, []),
        ("flatness", 0.2, []),
    ]
    assert spec["tolerances"][0]["faces"] == list(range(spec["n_faces"]))
    assert spec["tolerances"][1]["faces"] == [spec["functional_face"]]


def test_each_magnitude_is_stated_exactly_in_millimetres(sample):
    """value * unit scale == requested mm, with the unit of the geometry (MILLI METRE)."""
    spec, _, text = sample
    ents = parse_part21(text)
    tols = tolerances_in_text(ents)
    assert sorted(tols) == sorted(t["name"] for t in spec["tolerances"])
    ctx_unit = context_length_unit(ents)
    assert ents[ctx_unit] == "(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.MILLI.,.METRE.))"
    for t in spec["tolerances"]:
        got = tols[t["name"]]
        assert got["value"] * length_unit_scale_mm(ents, got["unit"]) == t["value"]
        assert ents[got["unit"]] == ents[ctx_unit], "tolerance unit differs from geometry unit"
        text_value = re.search(r"LENGTH_MEASURE\(([^)]*)\)", ents[got["measure"]]).group(1)
        v = t["value"]
        assert text_value == (f"{v:.0f}." if v.is_integer() else repr(v))  # "1.", "0.5"
    # The defect corrected by write_step_with_pmi: no bare METRE length unit anywhere.
    assert not any("SI_UNIT($,.METRE.)" in b for b in ents.values())


def test_tolerance_kinds_faces_and_datum_systems_in_text(sample):
    spec, _, text = sample
    ents = parse_part21(text)
    tols = tolerances_in_text(ents)
    kinds = {"surface_profile": "SURFACE_PROFILE_TOLERANCE()", "flatness": "FLATNESS_TOLERANCE("}
    for t in spec["tolerances"]:
        got = tols[t["name"]]
        assert kinds[t["type"]] in got["body"]
        faces = aspect_faces(ents, got["aspect"])
        assert len(faces) == len(set(faces)) == len(t["faces"])
        if t["datums"]:
            assert datum_system_labels(ents, got["datum_system"]) == t["datums"]
        else:
            assert got["datum_system"] is None
    # the functional face is the cylindrical outer skin of radius SKIN_RADIUS
    (skin,) = aspect_faces(ents, tols["profile_skin"]["aspect"])
    surf = re.fullmatch(r"ADVANCED_FACE\('[^']*',\([^)]*\),(#\d+),\.[TF]\.\)", ents[skin])[1]
    cyl = re.fullmatch(r"CYLINDRICAL_SURFACE\('[^']*',#\d+,([^)]*)\)", ents[surf])
    assert cyl and float(cyl[1]) == SKIN_RADIUS


def test_datum_features_link_faces_in_text(sample):
    spec, _, text = sample
    ents = parse_part21(text)
    datum_re = re.compile(r"DATUM\('[^']*','[^']*',#\d+,\.F\.,'([^']*)'\)")
    datums = {m[1]: ref for ref, b in ents.items() if (m := datum_re.fullmatch(b))}
    assert sorted(datums) == ["A", "B", "C"]
    for d in spec["datums"]:
        rel = re.compile(rf"SHAPE_ASPECT_RELATIONSHIP\('[^']*',\$,(#\d+),{datums[d['label']]}\)")
        related = [m[1] for b in ents.values() if (m := rel.fullmatch(b))]
        (feature,) = [r for r in related if "DATUM_FEATURE" in ents[r]]
        assert len(aspect_faces(ents, feature)) == len(d["faces"])
        # and its datum targets (the RPS points), one placed target feature each
        targets = [r for r in related if "PLACED_DATUM_TARGET_FEATURE" in ents[r]]
        assert len(targets) == len(d["targets"]) and len(related) == 1 + len(targets)


# ----------------------------------------------------------------- (b) XDE round trip


def test_roundtrip_types_values_and_faces(sample, roundtrip, originals):
    """STEPCAFControl_Reader gets back every tolerance with its type, value and faces.

    Recorded: after the round trip XDE's GetValue() returns the requested mm value exactly
    (0.5, not 500). 500 was what OCCT 7.9's *writer* produced on its own (a METRE unit on
    a mm value; see test_uncorrected_occt_writer_states_metres); the reader is right.
    """
    spec = sample[0]
    tols = xde_tolerances(roundtrip)
    assert len(tols) == len(spec["tolerances"])
    for got, want in zip(tols, spec["tolerances"], strict=True):
        assert got["type"] == TOLERANCE_TYPES[want["type"]]
        assert got["value"] == want["value"]
        assert got["linked"] and got["faces"]
        assert sorted(index_of(f, originals) for f in got["faces"]) == sorted(want["faces"])
        assert got["datums"] == want["datums"]


def test_roundtrip_datums(sample, roundtrip, originals):
    spec = sample[0]
    datums = xde_datums(roundtrip)
    assert sorted(datums) == sorted(d["label"] for d in spec["datums"])
    for d in spec["datums"]:
        for faces in datums[d["label"]]:  # every use of the datum names the same faces
            assert sorted(index_of(f, originals) for f in faces) == sorted(d["faces"])
    # each datum target on its own face
    targets = xde_datums(roundtrip, targets=True)
    for d in spec["datums"]:
        got = {index_of(f, originals) for faces in targets[d["label"]] for f in faces}
        assert got == {t["face"] for t in d["targets"]}  # (XDE may repeat a target's label)


def test_sample_datums_are_mutually_perpendicular_planes(sample):
    spec = sample[0]
    part_faces = faces_of(build_part())
    normals = {}
    for d in spec["datums"]:
        dirs = set()
        for k in d["faces"]:
            surf = BRepAdaptor_Surface(TopoDS.Face_s(part_faces[k]))
            assert surf.GetType() == GeomAbs_Plane
            n = surf.Plane().Axis().Direction()
            dirs.add(tuple(round(abs(v), 9) for v in (n.X(), n.Y(), n.Z())))
        assert len(dirs) == 1
        normals[d["label"]] = dirs.pop()
    assert normals == {"A": (0.0, 0.0, 1.0), "B": (1.0, 0.0, 0.0), "C": (0.0, 1.0, 0.0)}


def test_uncorrected_occt_writer_states_metres(tmp_path, monkeypatch):
    """Documents the OCCT 7.9 writer defect that write_step_with_pmi corrects.

    Without the correction, STEPCAFControl_Writer states the 0.5 mm tolerance as 0.5 with
    a bare SI_UNIT($,.METRE.) (the representation context it should use is null when no
    dimension is written), and the reader, correctly, returns 500 mm. If this test fails,
    OCCT has changed (fixed?) the writer: the correction is then a no-op; review it.
    """
    monkeypatch.setattr(stepwrite, "_correct_tolerance_units", lambda model: 0)
    monkeypatch.setattr(stepwrite, "_check_magnitudes", lambda model, tols, names: None)
    shape = build_part()
    path = tmp_path / "raw.step"
    tol = PMISpecTolerance("surface_profile", 0.5, [0], [], "p")
    write_step_with_pmi(shape, path, [tol], [])
    ents = parse_part21(path.read_text())
    got = tolerances_in_text(ents)["p"]
    assert got["value"] == 0.5
    assert ents[got["unit"]] == "(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT($,.METRE.))"
    assert length_unit_scale_mm(ents, got["unit"]) * got["value"] == 500.0
    assert [t["value"] for t in xde_tolerances(read_xde(path))] == [500.0]


# ----------------------------------------------------------------- (c) solid, atomicity


def test_written_part_is_one_valid_closed_solid(roundtrip):
    shape_tool = XCAFDoc_DocumentTool.ShapeTool_s(roundtrip.Main())
    free = TDF_LabelSequence()
    shape_tool.GetFreeShapes(free)
    assert free.Length() == 1
    shape = XCAFDoc_ShapeTool.GetShape_s(free.Value(1))
    assert BRepCheck_Analyzer(shape).IsValid()
    solids, shells = TopExp_Explorer(shape, TopAbs_SOLID), []
    n_solids = 0
    while solids.More():
        n_solids += 1
        exp = TopExp_Explorer(solids.Current(), TopAbs_SHELL)
        while exp.More():
            shells.append(exp.Current())
            exp.Next()
        solids.Next()
    assert n_solids == 1 and len(shells) == 1
    assert BRep_Tool.IsClosed_s(shells[0])
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, props)
    # the wall is a vertical offset: volume = projected area x wall, minus the holes
    assert 0.95 * LENGTH * WIDTH * WALL < props.Mass() < LENGTH * WIDTH * WALL
    assert 10 <= len(faces_of(shape)) < 60


def test_write_is_atomic_and_leaves_no_temp_files(tmp_path):
    path = tmp_path / "panel.step"
    build_sample(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["panel.step"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_failed_write_keeps_previous_file_and_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "panel.step"
    path.write_text("previous")

    def boom(src, dst):
        raise OSError("simulated rename failure")

    monkeypatch.setattr(stepwrite.os, "replace", boom)
    with pytest.raises(OSError, match="simulated"):
        build_sample(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["panel.step"]
    assert path.read_text() == "previous"


def test_static_parameters_are_restored(tmp_path):
    from OCP.STEPCAFControl import STEPCAFControl_Controller

    STEPCAFControl_Controller.Init_s()
    schema = Interface_Static.IVal_s("write.step.schema")
    unit = Interface_Static.CVal_s("write.step.unit")
    assert Interface_Static.SetIVal_s("write.step.schema", 1)  # AP214CD
    assert Interface_Static.SetCVal_s("write.step.unit", "INCH")
    try:
        build_sample(tmp_path / "panel.step")
        assert Interface_Static.IVal_s("write.step.schema") == 1
        assert Interface_Static.CVal_s("write.step.unit") == "INCH"
    finally:
        Interface_Static.SetIVal_s("write.step.schema", schema)
        Interface_Static.SetCVal_s("write.step.unit", unit)


def test_sample_is_reproducible(tmp_path):
    a, b = tmp_path / "a" / "panel.step", tmp_path / "b" / "panel.step"
    build_sample(a)
    build_sample(b)
    assert a.read_bytes() == b.read_bytes()


# ----------------------------------------------------------------- API behaviour


def test_located_shape_keeps_face_indices(tmp_path):
    """A shape with a top-level location is baked; indices still name the same faces."""
    from OCP.gp import gp_Trsf, gp_Vec
    from OCP.TopLoc import TopLoc_Location

    base = build_part()
    trsf = gp_Trsf()
    trsf.SetTranslation(gp_Vec(10.0, -5.0, 3.0))
    moved = base.Moved(TopLoc_Location(trsf))
    assert not moved.Location().IsIdentity()
    expected = []
    for f in faces_of(base):
        kind, area, (x, y, z) = face_key(f)
        expected.append((kind, area, (x + 10.0, y - 5.0, z + 3.0)))
    path = tmp_path / "moved.step"
    tols = [PMISpecTolerance("surface_profile", 0.5, [k], ["A"], f"t{k}") for k in (3, 11)]
    write_step_with_pmi(moved, path, tols, [PMISpecDatum("A", [0, 8])])
    doc = read_xde(path)
    got = xde_tolerances(doc)
    assert [[index_of(f, expected) for f in t["faces"]] for t in got] == [[3], [11]]
    (datum_a,) = {tuple(sorted(index_of(f, expected) for f in fs)) for fs in xde_datums(doc)["A"]}
    assert datum_a == (0, 8)


@pytest.mark.parametrize(
    ("tols", "datums", "match"),
    [
        ([PMISpecTolerance("wobble", 0.5, [0])], [], "unknown type"),
        ([PMISpecTolerance("surface_profile", 0.5, [99])], [], "face index"),
        ([PMISpecTolerance("flatness", 0.5, [])], [], "no faces"),
        ([PMISpecTolerance("surface_profile", 0.0, [0])], [], "value"),
        ([PMISpecTolerance("surface_profile", math.nan, [0])], [], "value"),
        ([PMISpecTolerance("surface_profile", 0.5, [0], ["Z"])], [], "not defined"),
        ([PMISpecTolerance("flatness", 0.2, [0], ["A"])], [PMISpecDatum("A", [0])], "no datum"),
        ([PMISpecTolerance("perpendicularity", 0.2, [1])], [], "needs a datum"),
        ([], [PMISpecDatum("A", [0]), PMISpecDatum("A", [1])], "duplicate datum"),
        (
            [
                PMISpecTolerance("flatness", 0.2, [0], [], "x"),
                PMISpecTolerance("flatness", 0.2, [8], [], "x"),
            ],
            [],
            "duplicate tolerance",
        ),
    ],
)
def test_invalid_specification_is_rejected_before_writing(tmp_path, tols, datums, match):
    with pytest.raises(ValueError, match=match):
        write_step_with_pmi(build_part(), tmp_path / "x.step", tols, datums)
    assert list(tmp_path.iterdir()) == []
