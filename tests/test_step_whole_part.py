"""Whole-part profile tolerances and older PMI encodings (issue 20, items 3 and 4).

A general profile on "all surfaces" is, in real CAD exports (NIST FTC 07 #16292, FTC 10
#18552), a tolerance whose toleranced shape aspect is the PRODUCT_DEFINITION_SHAPE itself: no
shape aspect links it to a face. It applies to every face and is the inspection's general zone,
with its PMI source. The older (AP214) encodings -- face links through PROPERTY_DEFINITION ->
SHAPE_DEFINITION_REPRESENTATION, a plain MEASURE_REPRESENTATION_ITEM value, VALUE_RANGE limits,
a complex DIMENSIONAL_LOCATION -- are read; what is still unreadable is listed with its entity
id and why.

Real files, real OCP parsing, no mocks: the panel sample written with
:func:`qifreport.step.write.write_step_with_pmi` (its 1.0 mm profile given as whole part),
inspected end to end with the CLI on a simulated scan; the NIST FTC 07 / FTC 10 AP242 files
when ``../shared/step/nist`` holds them; minimal Part 21 texts for the AP214 encodings no
shared file has.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from lxml import etree

from qifreport.errors import InputError
from qifreport.metrology.acceptance.bands import zones_from_pmi
from qifreport.step.p21 import P21Model
from qifreport.step.reader import read_step
from qifreport.step.semantic import pmi_from_model
from qifreport.step.write import write_step_with_pmi
from tests.conftest import assert_valid_summary

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
NIST = ROOT.parent / "shared" / "step" / "nist"
EXE = Path(sys.executable).with_name("qifreport")
QIF_NS = {"q": "http://qifstandards.org/xsd/qif3"}


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True)


# ------------------------------------------------------------------ the whole-part sample


@pytest.fixture(scope="module")
def whole_part_step(tmp_path_factory) -> Path:
    """The panel sample with its 1.0 mm |A|B|C| profile written as whole part (faces=[])."""
    sys.path.insert(0, str(SAMPLES))
    from make_step_sample import PROFILE_ALL, TIMESTAMP, build_part, sample_spec

    shape = build_part()
    datums, tolerances = sample_spec(shape)
    assert tolerances[0].name == "profile_all" and tolerances[0].value == PROFILE_ALL
    tolerances[0].faces = []
    path = tmp_path_factory.mktemp("whole_part") / "panel_wp.step"
    write_step_with_pmi(shape, path, tolerances, datums, "curved_cover", timestamp=TIMESTAMP)
    return path


def test_written_whole_part_profile_is_encoded_like_the_cad_exports(whole_part_step):
    """The tolerance's toleranced_shape_aspect is the PRODUCT_DEFINITION_SHAPE (no face link)."""
    model = P21Model.read(whole_part_step)
    (tol,) = [
        e
        for e in model.by_type("SURFACE_PROFILE_TOLERANCE")
        if e.part("GEOMETRIC_TOLERANCE")[0] == "profile_all"
    ]
    target = tol.part("GEOMETRIC_TOLERANCE")[3]
    assert model.type_names(target.id) == ("PRODUCT_DEFINITION_SHAPE",)


def test_whole_part_profile_is_read_with_every_face(whole_part_step):
    part = read_step(whole_part_step)
    tol = {t.name: t for t in part.pmi.tolerances}
    wp = tol["profile_all"]
    assert wp.whole_part and wp.value == pytest.approx(1.0)
    assert [d.label for d in wp.datums] == ["A", "B", "C"]
    assert set(wp.face_step_ids) == set(part.face_index()) and len(wp.face_step_ids) == 15
    assert wp.problems == [] and "whole part" in wp.face_notes[0]
    assert not tol["profile_skin"].whole_part and len(tol["profile_skin"].face_step_ids) == 1

    zones, skipped = zones_from_pmi(part.pmi, part.face_index(), None)
    general = zones[-1]
    assert (general.key, general.source, general.name) == ("general", "pmi", "profile_all")
    assert general.faces is None and general.width == pytest.approx(1.0)
    assert general.step_id == wp.step_id and general.datums == ["A", "B", "C"]
    assert [z.key for z in zones] == ["T1", "general"]
    assert all(s.step_id != wp.step_id for s in skipped)
    # the command line agreeing with the drawing is accepted; a different value is refused
    assert zones_from_pmi(part.pmi, part.face_index(), 0.5)[0][-1].source == "pmi"
    with pytest.raises(InputError, match=r"--tolerance 0\.3 .*'profile_all' #\d+ \(1 mm"):
        zones_from_pmi(part.pmi, part.face_index(), 0.3)


def test_whole_part_profile_inspected_end_to_end(whole_part_step, tmp_path):
    """CLI on a scan of the panel: the general band is the drawing's 1.0 mm whole-part profile
    with its PMI source in the JSON and the QIF characteristic; `qifreport pmi` lists it."""
    from make_samples import panel_scan_set

    (P,) = panel_scan_set(whole_part_step, [{}])
    scan = tmp_path / "scan.ply"
    trimesh.PointCloud(P).export(scan)
    out = tmp_path / "o"
    # this copy of the panel's drawing has no restraint note: the operator states the
    # virtual restraint the sample panel is inspected in (its free state fails)
    r = run(
        whole_part_step, scan, "--out", out, "--json", "--no-pdf", "--no-cache", "--quiet",
        "--restraint", "virtual",
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "(pmi #" in r.stdout and "(default)" not in r.stdout
    doc = json.loads((out / "panel_wp.json").read_text())
    assert_valid_summary(doc)
    tol = {t["key"]: t for t in doc["tolerances"]}
    g = tol["general"]
    assert (g["source"], g["name"], g["width_mm"]) == ("pmi", "profile_all", 1.0)
    assert g["faces"] is None and isinstance(g["step_id"], int)
    assert (g["lower_mm"], g["upper_mm"], g["datums"]) == (-0.5, 0.5, ["A", "B", "C"])
    assert tol["T1"]["name"] == "profile_skin"
    assert all(t["source"] != "default" for t in doc["tolerances"])

    q = etree.parse(str(out / "panel_wp.qif"))
    (cdef,) = [
        c
        for c in q.iterfind(".//q:SurfaceProfileCharacteristicDefinition", QIF_NS)
        if c.find("q:Attributes/q:AttributeStr[@name='key']", QIF_NS).get("value") == "general"
    ]
    attrs = {a.get("name"): a.get("value") for a in cdef.find("q:Attributes", QIF_NS)}
    assert attrs["source"] == "pmi" and int(attrs["step_entity_id"]) == g["step_id"]
    assert float(cdef.findtext("q:ToleranceValue", namespaces=QIF_NS)) == pytest.approx(1.0)
    assert cdef.findtext("q:Name", namespaces=QIF_NS) == "profile_all"

    r = run("pmi", whole_part_step, "--json")
    assert r.returncode == 0, r.stderr
    (row,) = [x for x in json.loads(r.stdout)["items"] if x["name"] == "profile_all"]
    assert row["whole_part"] is True and row["n_faces"] == 15 and row["problems"] == []

    # a --tolerance that contradicts the drawing: one line naming both, exit 2
    r = run(whole_part_step, scan, "--out", tmp_path / "o2", "--tolerance", "0.3", "--quiet")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "--tolerance 0.3" in r.stderr and "profile_all" in r.stderr


# ------------------------------------------------------------------ minimal Part 21 texts

_HEAD = """ISO-10303-21;
HEADER;
FILE_DESCRIPTION((''),'2;1');
FILE_NAME('mini.stp','2009-01-19T16:59:58',(''),(''),'','','');
FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));
ENDSEC;
DATA;
#1=PRODUCT_DEFINITION_SHAPE('','',$);
#4=(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.MILLI.,.METRE.));
#5=(GEOMETRIC_REPRESENTATION_CONTEXT(3)GLOBAL_UNIT_ASSIGNED_CONTEXT((#4))
REPRESENTATION_CONTEXT('',''));
#10=CARTESIAN_POINT('',(0.,0.,0.));
#11=DIRECTION('',(0.,0.,1.));
#12=AXIS2_PLACEMENT_3D('',#10,#11,$);
#13=PLANE('',#12);
#14=ADVANCED_FACE('',(),#13,.T.);
#15=ADVANCED_FACE('',(),#13,.T.);
#16=ADVANCED_FACE('',(),#13,.T.);
#17=CLOSED_SHELL('',(#14,#15,#16));
#18=MANIFOLD_SOLID_BREP('',#17);
#19=ADVANCED_BREP_SHAPE_REPRESENTATION('',(#18),#5);
#20=SHAPE_DEFINITION_REPRESENTATION(#1,#19);
"""
_TAIL = "ENDSEC;\nEND-ISO-10303-21;\n"


def _pmi(body: str):
    return pmi_from_model(P21Model.from_text(_HEAD + body + _TAIL))


#: the AP214 encodings of older exports (I-DEAS; Theorem CADDS5 / UG translations)
_AP214 = """#30=SHAPE_ASPECT('flat face','',#1,.T.);
#31=PROPERTY_DEFINITION('','',#30);
#32=SHAPE_REPRESENTATION('',(#14,#15),#5);
#33=SHAPE_DEFINITION_REPRESENTATION(#31,#32);
#34=MEASURE_REPRESENTATION_ITEM('magnitude',LENGTH_MEASURE(0.05),#4);
#35=FLATNESS_TOLERANCE('flatness 1','',#34,#30);
#40=SHAPE_ASPECT('hole','',#1,.T.);
#41=PROPERTY_DEFINITION('','',#40);
#42=SHAPE_REPRESENTATION('',(#16),#5);
#43=SHAPE_DEFINITION_REPRESENTATION(#41,#42);
#44=DIMENSIONAL_SIZE(#40,'diameter');
#45=MEASURE_REPRESENTATION_ITEM('diameter',LENGTH_MEASURE(40.),#4);
#46=SHAPE_DIMENSION_REPRESENTATION('',(#45),#5);
#47=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#44,#46);
#50=MEASURE_REPRESENTATION_ITEM('',LENGTH_MEASURE(10.1),#4);
#51=MEASURE_REPRESENTATION_ITEM('',LENGTH_MEASURE(9.9),#4);
#52=VALUE_RANGE('',SET_REPRESENTATION_ITEM((#50,#51)));
#53=DIMENSIONAL_SIZE(#30,'thickness');
#54=SHAPE_DIMENSION_REPRESENTATION('',(#52),#5);
#55=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#53,#54);
#60=(DIMENSIONAL_LOCATION()SHAPE_ASPECT_RELATIONSHIP('linear distance','',#30,#40));
#61=MEASURE_REPRESENTATION_ITEM('nominal value',LENGTH_MEASURE(25.),#4);
#62=SHAPE_DIMENSION_REPRESENTATION('',(#61),#5);
#63=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#60,#62);
#90=DATUM_FEATURE('datum A','',#1,.T.);
#91=PROPERTY_DEFINITION('','',#90);
#92=SHAPE_REPRESENTATION('',(#14,#12),#5);
#93=SHAPE_DEFINITION_REPRESENTATION(#91,#92);
#94=DATUM('','',#1,.F.,'A');
#95=SHAPE_ASPECT_RELATIONSHIP('','',#90,#94);
"""


def test_ap214_face_links_through_property_definition():
    pmi = _pmi(_AP214)
    (flat,) = pmi.tolerances
    assert flat.face_step_ids == [14, 15] and not flat.whole_part and flat.problems == []
    dims = {d.step_id: d for d in pmi.dimensions}
    assert dims[44].face_step_ids == [16]
    # a datum through its datum feature (the placement in the representation is not geometry)
    (datum,) = pmi.datums
    assert (datum.label, datum.face_step_ids, datum.problems) == ("A", [14], [])


def test_ap214_plain_measure_representation_item_values():
    pmi = _pmi(_AP214)
    (flat,) = pmi.tolerances
    assert flat.value == pytest.approx(0.05) and flat.value_text == "0.05 MILLI METRE"
    dia = {d.step_id: d for d in pmi.dimensions}[44]
    assert dia.nominal == pytest.approx(40.0) and dia.value_text == "40 MILLI METRE"
    assert dia.problems == ["#45: measure 'diameter' taken as the nominal value"]


def test_ap214_value_range_limits():
    thk = {d.step_id: d for d in _pmi(_AP214).dimensions}[53]
    assert (thk.lower_limit, thk.upper_limit) == (pytest.approx(9.9), pytest.approx(10.1))
    assert thk.nominal is None and thk.problems == [] and thk.face_step_ids == [14, 15]


def test_ap214_complex_dimensional_location():
    loc = {d.step_id: d for d in _pmi(_AP214).dimensions}[60]
    assert (loc.name, loc.type, loc.nominal) == ("linear distance", "linear distance", 25.0)
    assert loc.origin_face_step_ids == [14, 15] and loc.target_face_step_ids == [16]
    assert loc.problems == []


def test_all_around_profile_without_faces_is_whole_part():
    pmi = _pmi(
        """#30=ALL_AROUND_SHAPE_ASPECT('all around','',#1,.F.);
#31=LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.8),#4);
#32=SURFACE_PROFILE_TOLERANCE('profile','',#31,#30);
#40=SHAPE_ASPECT('unlinked','',#1,.T.);
#41=LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.1),#4);
#42=FLATNESS_TOLERANCE('flatness','',#41,#40);
"""
    )
    prof, flat = pmi.tolerances
    assert prof.whole_part and prof.face_step_ids == [14, 15, 16] and prof.problems == []
    assert "all-around shape aspect #30 has no face link" in prof.face_notes[0]
    # a form tolerance on an unlinked aspect is not guessed to be whole part
    assert not flat.whole_part and flat.face_step_ids == []
    assert flat.problems == ["#40: no associated geometry found"]
    zones, skipped = zones_from_pmi(pmi, {14: 0, 15: 1, 16: 2}, None)
    assert [(z.key, z.source, z.step_id, z.width) for z in zones] == [("general", "pmi", 32, 0.8)]
    assert skipped == []  # the flatness is a feature characteristic (issue 22)
    from qifreport.metrology.gdt.pmi_plan import specs_from_pmi

    (spec,) = specs_from_pmi(pmi, {14: 0, 15: 1, 16: 2}).specs
    assert spec.step_id == 42 and len(spec.faces) == 0


def test_two_whole_part_profiles_the_tighter_governs():
    pmi = _pmi(
        """#31=LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(2.),#4);
#32=SURFACE_PROFILE_TOLERANCE('loose','',#31,#1);
#33=LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.6),#4);
#34=SURFACE_PROFILE_TOLERANCE('tight','',#33,#1);
"""
    )
    zones, skipped = zones_from_pmi(pmi, {14: 0, 15: 1, 16: 2}, None)
    assert [(z.key, z.name, z.width) for z in zones] == [("general", "tight", 0.6)]
    (s,) = skipped
    assert s.step_id == 32 and "tight #34 (0.6 mm) governs every face" in s.reason


def test_unreadable_items_are_listed_with_entity_id_and_reason():
    pmi = _pmi(
        _AP214
        + """#70=MEASURE_REPRESENTATION_ITEM('',LENGTH_MEASURE(1.),#4);
#71=VALUE_RANGE('',SET_REPRESENTATION_ITEM((#70)));
#72=DIMENSIONAL_SIZE(#30,'width');
#73=SHAPE_DIMENSION_REPRESENTATION('',(#71,#74),#5);
#74=DESCRIPTIVE_REPRESENTATION_ITEM('remark','see note');
#75=MEASURE_REPRESENTATION_ITEM('nominal value',LENGTH_MEASURE(5.),#4);
#76=MEASURE_REPRESENTATION_ITEM('spread',LENGTH_MEASURE(0.2),#4);
#77=SHAPE_DIMENSION_REPRESENTATION('',(#75,#76,#78),#5);
#78=CARTESIAN_POINT('',(0.,0.,0.));
#79=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#72,#73);
#80=DIMENSIONAL_SIZE(#40,'depth');
#81=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#80,#77);
#82=TOLERANCE_VALUE(#70,#70);
#83=PLUS_MINUS_TOLERANCE(#82,#40);
#84=DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#30,#77);
"""
    )
    dims = {d.step_id: d for d in pmi.dimensions}
    assert "#71: VALUE_RANGE with 1 readable limit(s) of 1" in dims[72].problems
    assert "#72: no value found" in dims[72].problems
    assert "#74: descriptive item 'remark' not understood ('see note')" in dims[72].problems
    assert dims[80].nominal == 5.0
    assert "#76: measure 'spread' not understood (0.2 MILLI METRE)" in dims[80].problems
    assert "#78: value item CARTESIAN_POINT not understood" in dims[80].problems
    assert (
        "#83: PLUS_MINUS_TOLERANCE refers to #40 (SHAPE_ASPECT), "
        "not a dimension that could be read" in pmi.problems
    )
    assert any(p.startswith("#84: DIMENSIONAL_CHARACTERISTIC_REPRESENTATION") for p in pmi.problems)


def test_pmi_json_keeps_unit_basis_and_file_problems():
    """`qifreport pmi --json` on CTC 03: the per-area flatness keeps its unit basis."""
    path = NIST / "nist_ctc_03_asme1_ap242-e2.stp"
    r = run("pmi", path, "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["items"]
    (flat,) = [x for x in rows if x["item"] == "tolerance" and x["step_id"] == 37]
    assert flat["unit_basis"] == "per rectangular area 6.35 mm x 6.35 mm"
    assert flat["whole_part"] is False and "max_value" in flat
    assert not [x for x in rows if x["item"] == "problem"]
    assert np.isclose(flat["value"], 0.127)
