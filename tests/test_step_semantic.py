"""Semantic PMI read from the Part 21 text: the parser, units, and the NIST MBE PMI test cases.

The expected values below were read from the file text by hand (``grep`` of the records named in
the comments), not produced by the reader: each geometric tolerance's magnitude instance and
unit, each dimension's SHAPE_DIMENSION_REPRESENTATION and TOLERANCE_VALUE. Unit instances:
CTC 01 ``#4361``, CTC 02 ``#22285``, CTC 04 ``#3`` are SI_UNIT(.MILLI.,.METRE.); CTC 03
``#5918`` ``'inch'`` = 25.4 x ``#5895`` (mm) in a millimetre file; CTC 05 ``#13402``
``'inch'``, FTC 06 ``#16260`` ``'INCH'`` (in a millimetre file) and FTC 08 ``#6`` ``'INCH'``
are 25.4 mm.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from qifreport.step.p21 import (
    DERIVED,
    Binary,
    Entity,
    Enum,
    P21Error,
    P21Model,
    Ref,
    Typed,
    parse_params,
)
from qifreport.step.pmi import PMI
from qifreport.step.semantic import pmi_from_model, read_pmi_text
from tests.conftest import NIST, shared_file

#: where the NIST files live (read-only, never copied into the repository)
NIST_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "step" / "nist"
IN = 25.4
FACE_TYPES = {"ADVANCED_FACE", "FACE_SURFACE", "FACE", "ORIENTED_FACE", "SUBFACE"}
GT_TYPES = {
    "surface_profile", "line_profile", "flatness", "straightness", "roundness", "cylindricity",
    "position", "perpendicularity", "parallelism", "angularity", "circular_runout",
    "total_runout", "coaxiality", "concentricity", "symmetry",
}  # fmt: skip


@cache
def _read(name: str) -> tuple[PMI, P21Model]:
    path = shared_file("step/nist/" + name)
    return read_pmi_text(path), P21Model.read(path)


def _pmi(name: str) -> PMI:
    return _read(name)[0]


def _model(name: str) -> P21Model:
    return _read(name)[1]


# ============================================================================================
# (c) the Part 21 parser on small inline texts
# ============================================================================================


def test_parse_params_values():
    vals = parse_params("'a;b', 'it''s', #12, .T., .F., .MILLI., $, *, 1, -2.5E-1, 3., .5")
    assert vals == [
        "a;b", "it's", Ref(12), Enum("T"), Enum("F"), Enum("MILLI"), None, DERIVED, 1, -0.25,
        3.0, 0.5,
    ]  # fmt: skip
    assert isinstance(vals[8], int) and isinstance(vals[10], float)
    assert vals[3].value is True and vals[4].value is False and vals[5].value is None
    assert parse_params("LENGTH_MEASURE(0.75), (1, (2, 3)), ()") == [
        Typed("LENGTH_MEASURE", (0.75,)),
        (1, (2, 3)),
        (),
    ]
    # typed parameters nest; a binary literal
    assert parse_params('POSITIVE_LENGTH_MEASURE(LENGTH_MEASURE(1.)), "0AF"') == [
        Typed("POSITIVE_LENGTH_MEASURE", (Typed("LENGTH_MEASURE", (1.0,)),)),
        Binary("0AF"),
    ]
    # control directives inside strings
    assert parse_params(r"'\X2\00B1\X0\0.1', '\X\E9', 'a\\b'") == ["\u00b10.1", "\u00e9", "a\\b"]


@pytest.mark.parametrize(
    "bad", ["(1, 2", "1, 2)", "#1 = 2", "1.2.3.4", "-", "(1,,2)", "(1,)", "A 1", "1 2", "A"]
)
def test_parse_params_rejects_malformed(bad):
    with pytest.raises(P21Error):
        parse_params(bad)


TEXT = """ISO-10303-21;
HEADER;
FILE_DESCRIPTION(('semicolons; in; the header'),'2;1');
FILE_NAME('t.stp','2024-01-01',(''),(''),'','','');
FILE_SCHEMA(('AP242_MANAGED_MODEL_BASED_3D_ENGINEERING_MIM_LF { 1 0 10303 442 1 1 4 }'));
ENDSEC;
DATA;
/* a comment with #99 = FAKE('x'); inside */
#1 = PRODUCT('part;1', 'it''s ''quoted''; ENDSEC;', '', (#2));
#2=PRODUCT_CONTEXT('',#3,
  'mechanical');
#3 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );
#4 = ( GEOMETRIC_TOLERANCE('p', $, #5, #6) /* inline */ POSITION_TOLERANCE() );
#5 = ( LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM()
       MEASURE_WITH_UNIT(LENGTH_MEASURE(0.75), #3) REPRESENTATION_ITEM('') );
#6=SHAPE_ASPECT('',$,#1,.F.);
ENDSEC;
END-ISO-10303-21;
"""


def test_model_records_complex_instances_and_referrers():
    m = P21Model.from_text(TEXT)
    assert sorted(m) == [1, 2, 3, 4, 5, 6]  # the commented-out #99 is not a record
    assert m.schema == "AP242_MANAGED_MODEL_BASED_3D_ENGINEERING_MIM_LF { 1 0 10303 442 1 1 4 }"
    assert m.header["FILE_DESCRIPTION"][0] == ("semicolons; in; the header",)
    e1 = m[1]
    assert isinstance(e1, Entity) and e1.type == "PRODUCT" and not e1.is_complex
    assert e1.params == ("part;1", "it's 'quoted'; ENDSEC;", "", (Ref(2),))
    assert m[2].params[2] == "mechanical"  # the record spans two lines
    e3 = m[3]
    assert e3.type is None and e3.types == ("LENGTH_UNIT", "NAMED_UNIT", "SI_UNIT")
    assert e3.has("si_unit") and not e3.has("PLANE_ANGLE_UNIT")
    assert e3.part("NAMED_UNIT") == (DERIVED,)
    assert e3.part("SI_UNIT") == (Enum("MILLI"), Enum("METRE"))
    assert e3.part("LENGTH_UNIT") == () and e3.part("MASS_UNIT") is None
    assert m[4].part("GEOMETRIC_TOLERANCE") == ("p", None, Ref(5), Ref(6))
    assert m[5].part("MEASURE_WITH_UNIT") == (Typed("LENGTH_MEASURE", (0.75,)), Ref(3))
    # simple instances answer has()/part() for their own type
    assert m[6].has("SHAPE_ASPECT") and m[6].part("SHAPE_ASPECT") == ("", None, Ref(1), Enum("F"))
    # reverse references, built once
    assert m.referrers(3) == [2, 5]
    assert m.referrers(Ref(1)) == [6]
    assert m.referrers(5) == [4] and m.referrers(4) == []
    assert [e.id for e in m.by_type("POSITION_TOLERANCE")] == [4]
    assert [e.id for e in m.by_type("product")] == [1]
    assert m[4].refs() == [5, 6]
    assert m.get(Ref(77)) is None and m.get(None) is None
    with pytest.raises(KeyError):
        m[77]


def test_model_without_data_section():
    with pytest.raises(P21Error):
        P21Model.from_text("ISO-10303-21; HEADER; ENDSEC; END-ISO-10303-21;")


# ============================================================================================
# semantic reading of a small synthetic file: units, old and new datum forms, modifiers
# ============================================================================================

SYNTH = """ISO-10303-21; HEADER; FILE_SCHEMA(('AP214')); ENDSEC; DATA;
#1 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.CENTI.,.METRE.) );
#2 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(2.54), #1);
#3 = ( CONVERSION_BASED_UNIT('INCH', #2) LENGTH_UNIT() NAMED_UNIT(#4) );
#4 = DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.);
#5 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(12.), #3);
#6 = ( CONVERSION_BASED_UNIT('FOOT', #5) LENGTH_UNIT() NAMED_UNIT(#4) );
#7 = ( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) );
#8 = PLANE_ANGLE_MEASURE_WITH_UNIT(PLANE_ANGLE_MEASURE(0.0174532925199433), #7);
#9 = ( CONVERSION_BASED_UNIT('DEGREE', #8) NAMED_UNIT(#4) PLANE_ANGLE_UNIT() );
#10 = ( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNIT_ASSIGNED_CONTEXT((#1,#7))
        REPRESENTATION_CONTEXT('','') );
#20 = ADVANCED_FACE('', (), $, .T.);
#21 = ADVANCED_FACE('', (), $, .T.);
#22 = EDGE_CURVE('', $, $, $, .T.);
#30 = SHAPE_ASPECT('', $, $, .T.);
#31 = GEOMETRIC_ITEM_SPECIFIC_USAGE('', '', #30, $, #20);
#32 = SHAPE_ASPECT('', $, $, .T.);
#33 = ITEM_IDENTIFIED_REPRESENTATION_USAGE('', '', #32, $, (#21, #22));
#34 = COMPOSITE_SHAPE_ASPECT('', $, $, .T.);
#35 = SHAPE_ASPECT_RELATIONSHIP('', $, #34, #30);
#36 = SHAPE_ASPECT_RELATIONSHIP('', $, #34, #32);
#37 = SHAPE_ASPECT_RELATIONSHIP('', $, #34, #34);
#40 = DATUM('', $, $, .F., 'A');
#41 = DATUM_FEATURE('', $, $, .T.);
#42 = SHAPE_ASPECT_RELATIONSHIP('', $, #41, #40);
#43 = GEOMETRIC_ITEM_SPECIFIC_USAGE('', '', #41, $, #21);
#44 = DATUM('', $, $, .F., 'B');
#45 = DATUM_REFERENCE(1, #40);
#46 = REFERENCED_MODIFIED_DATUM(2, #44, .MAXIMUM_MATERIAL_CONDITION.);
#47 = DATUM_TARGET('', $, $, .T., '3');
#48 = SHAPE_ASPECT_RELATIONSHIP('', $, #47, #44);
#49 = FEATURE_FOR_DATUM_TARGET_RELATIONSHIP('', $, #30, #47);
#50 = MEASURE_WITH_UNIT(LENGTH_MEASURE(0.002), #6);
#51 = PERPENDICULARITY_TOLERANCE('perp', '', #50, #34, (#45, #46));
#52 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.01), #3);
#53 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.004), #3);
#54 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.), #3);
#55 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.02), #3);
#56 = ( GEOMETRIC_TOLERANCE('prof', '', #52, #30) SURFACE_PROFILE_TOLERANCE()
        GEOMETRIC_TOLERANCE_WITH_DEFINED_UNIT(#54)
        GEOMETRIC_TOLERANCE_WITH_MAXIMUM_TOLERANCE(#55)
        GEOMETRIC_TOLERANCE_WITH_MODIFIERS((.STATISTICAL_TOLERANCE.,.EACH_RADIAL_ELEMENT.))
        UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE(#53) );
#57 = MODIFIED_GEOMETRIC_TOLERANCE('mod', '', #52, #32, .MAXIMUM_MATERIAL_CONDITION.);
#58 = DESCRIPTIVE_MEASURE_WITH_UNIT(DESCRIPTIVE_MEASURE('see note'), #3);
#59 = FLATNESS_TOLERANCE('no value', '', #58, #30);
#60 = FLATNESS_TOLERANCE('no aspect', '', #52, $);
#70 = ANGULAR_SIZE(#30, 'angle', .EQUAL.);
#71 = ( MEASURE_REPRESENTATION_ITEM() MEASURE_WITH_UNIT(PLANE_ANGLE_MEASURE(45.), #9)
        PLANE_ANGLE_MEASURE_WITH_UNIT() REPRESENTATION_ITEM('nominal value') );
#72 = SHAPE_DIMENSION_REPRESENTATION('', (#71), #10);
#73 = DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#70, #72);
#74 = PLANE_ANGLE_MEASURE_WITH_UNIT(PLANE_ANGLE_MEASURE(-0.5), #9);
#75 = PLANE_ANGLE_MEASURE_WITH_UNIT(PLANE_ANGLE_MEASURE(0.25), #9);
#76 = TOLERANCE_VALUE(#74, #75);
#77 = PLUS_MINUS_TOLERANCE(#76, #70);
#80 = DIMENSIONAL_SIZE(#32, 'diameter');
#81 = MEASURE_REPRESENTATION_ITEM('nominal value', LENGTH_MEASURE(0.5), #3);
#82 = DESCRIPTIVE_REPRESENTATION_ITEM('dimensional note', 'theoretical');
#83 = SHAPE_DIMENSION_REPRESENTATION('', (#81, #82), #10);
#84 = DIMENSIONAL_CHARACTERISTIC_REPRESENTATION(#80, #83);
#85 = LIMITS_AND_FITS('H', '', '7', '');
#86 = PLUS_MINUS_TOLERANCE(#85, #80);
#90 = DIMENSIONAL_LOCATION('linear distance', $, #30, #80);
ENDSEC; END-ISO-10303-21;
"""


@pytest.fixture(scope="module")
def synth():
    return pmi_from_model(P21Model.from_text(SYNTH))


def test_synthetic_units_and_context(synth):
    assert synth.schema == "AP214"
    assert synth.length_unit == "cm" and synth.length_scale == pytest.approx(10.0)
    json.dumps(dataclasses.asdict(synth))  # JSON-serialisable as promised


def test_synthetic_old_datum_reference_and_recursive_units(synth):
    t = {g.name: g for g in synth.tolerances}
    perp = t["perp"]
    # FOOT = 12 x INCH, INCH = 2.54 x CENTI METRE: 0.002 ft = 0.6096 mm
    assert perp.type == "perpendicularity" and perp.value == pytest.approx(0.6096)
    assert perp.value_text == "0.002 FOOT"
    assert [(d.label, d.precedence, d.modifiers) for d in perp.datums] == [
        ("A", 1, []),
        ("B", 2, ["maximum_material_condition"]),
    ]
    # composite #34 -> #30 (face #20) and #32 (face #21 and an edge); the self-loop is harmless
    assert perp.face_step_ids == [20, 21]
    assert any("EDGE_CURVE" in n for n in perp.face_notes)


def test_synthetic_complex_tolerance_parts(synth):
    prof = {g.name: g for g in synth.tolerances}["prof"]
    assert prof.type == "surface_profile" and prof.value == pytest.approx(0.254)
    assert prof.unequal_displacement == pytest.approx(0.1016)
    assert prof.max_value == pytest.approx(0.508)
    assert prof.unit_basis == "per unit length 25.4 mm"
    assert prof.modifiers == ["statistical_tolerance", "each_radial_element"]
    assert prof.datums == [] and prof.face_step_ids == [20] and prof.problems == []
    mod = {g.name: g for g in synth.tolerances}["mod"]
    assert mod.type == "unknown" and mod.modifiers == ["maximum_material_condition"]
    assert mod.problems  # no characteristic: said so


def test_synthetic_missing_values_are_none_with_a_problem(synth):
    t = {g.name: g for g in synth.tolerances}
    assert t["no value"].value is None and t["no value"].problems
    assert t["no aspect"].value == pytest.approx(0.254)
    assert t["no aspect"].face_step_ids == [] and t["no aspect"].problems


def test_synthetic_datums_and_targets(synth):
    d = {x.label: x for x in synth.datums}
    assert d["A"].face_step_ids == [21] and d["A"].targets == []
    # datum B <- target B3 -> FEATURE_FOR_DATUM_TARGET_RELATIONSHIP -> #30 -> face #20
    assert d["B"].targets == ["B3"] and d["B"].face_step_ids == [20]


def test_synthetic_dimensions(synth):
    d = {x.step_id: x for x in synth.dimensions}
    ang = d[70]
    assert (ang.kind, ang.type, ang.unit) == ("size", "angle", "deg")
    assert (ang.nominal, ang.lower, ang.upper) == pytest.approx((45.0, -0.5, 0.25))
    dia = d[80]
    assert dia.nominal == pytest.approx(12.7) and dia.fit == "H7"
    assert dia.lower is None and dia.upper is None
    assert "basic" in dia.qualifiers and "diameter" in dia.qualifiers
    assert dia.face_step_ids == [21]
    loc = d[90]
    assert loc.kind == "location" and loc.type == "linear distance"
    assert loc.origin_face_step_ids == [20] and loc.target_face_step_ids == [21]
    assert loc.nominal is None and any("no value" in p for p in loc.problems)


# ============================================================================================
# (a) every NIST file: complete, positive, associated with faces
# ============================================================================================


def test_every_nist_file_is_covered():
    if NIST_DIR.is_dir():
        assert sorted(p.name for p in NIST_DIR.glob("*.stp")) == sorted(NIST)
    else:
        shared_file("step/nist")  # skips, or fails under CI


def _check_faces(model: P21Model, ids: list[int], what: str) -> None:
    assert ids, f"{what}: no faces"
    assert ids == sorted(set(ids)), f"{what}: face ids not sorted unique"
    for i in ids:
        assert i in model, f"{what}: #{i} not in the file"
        assert FACE_TYPES.intersection(model.type_names(i)), f"{what}: #{i} is not a face"


@pytest.mark.parametrize("name", NIST)
def test_nist_file_invariants(name):
    pmi, model = _read(name)
    assert pmi.schema.startswith("AP242_MANAGED_MODEL_BASED_3D_ENGINEERING_MIM_LF")
    assert pmi.tolerances and pmi.datums and pmi.dimensions
    for t in pmi.tolerances:
        what = f"{name} tolerance #{t.step_id}"
        assert t.type in GT_TYPES, what
        assert t.value is not None and t.value > 0, what
        assert t.value_text, what
        _check_faces(model, t.face_step_ids, what)
        assert [d.precedence for d in t.datums] == sorted(d.precedence for d in t.datums)
        assert all(d.label and d.label != "?" for d in t.datums), what
    for d in pmi.datums:
        _check_faces(model, d.face_step_ids, f"{name} datum {d.label} #{d.step_id}")
    for d in pmi.dimensions:
        if d.nominal is not None:
            _check_faces(model, d.face_step_ids, f"{name} dimension #{d.step_id}")
            assert d.unit in ("mm", "deg")
    json.dumps(dataclasses.asdict(pmi))


# ============================================================================================
# (b) expected values, read from the file text
# ============================================================================================

#: file -> (mm per unit of the magnitudes, {type: magnitudes as written in the file})
#: magnitude instance ids as ``GT -> magnitude``
TOLERANCES = {
    "nist_ctc_01_asme1_ap242-e1.stp": (1.0, {  # all complex LENGTH_MEASURE_WITH_UNIT instances
        "position": [0.75, 0.75],          # #21 -> #95, #22 -> #96 (OCCT reads 0.0)
        "surface_profile": [1.25, 0.5],    # #26 -> #90, #27 -> #94
        "perpendicularity": [1.5],         # #56 -> #83
        "flatness": [0.2],                 # #57 -> #82
    }),
    "nist_ctc_02_asme1_ap242-e2.stp": (1.0, {
        # #53 -> #383, #56..#58 -> #373 #375 #378, #59..#61 -> #365..#367, #62..#65 -> #368..#371,
        # #66 -> #372, #67 -> #382
        "surface_profile": [0.1, 2.5, 2.5, 2.5, 0.8, 0.8, 0.8, 0.5, 0.5, 0.5, 0.5, 0.75, 0.8],
        "flatness": [0.05],                        # #54 -> #381
        "perpendicularity": [0.1, 0.05, 0.254],    # #68 -> #363, #81 -> #361, #82 -> #380
        "position": [0.05, 1.5, 1.0, 0.15],        # #69 -> #362, #183..#185 -> #354 #355 #364
        "line_profile": [0.25],                    # #83 -> #356
    }),
    "nist_ctc_03_asme1_ap242-e2.stp": (IN, {  # inch (#5918) in a mm file; '0.0500000000002' etc.
        "surface_profile": [0.01, 0.06, 0.03],     # #35 -> #238, #38 -> #231, #39 -> #237
        "angularity": [0.04],                      # #36 -> #235
        "flatness": [0.005],                       # #37 -> #232
        "position": [0.05, 0.05, 0.02, 0.06, 0.08, 0.03],  # #40..#45 -> #226 #227 #225 #228..#230
        "perpendicularity": [0.01, 0.01],          # #79 -> #224, #80 -> #240
    }),
    "nist_ctc_04_asme1_ap242-e1.stp": (1.0, {
        "position": [0.35, 1.5, 0.3, 0.75],  # #18608 -> #18605, #18715, #18730, #18891 -> #18888
        "surface_profile": [2.0, 0.2, 0.5],  # #18781 -> #18778, #18793 -> #18790, #18835
    }),
    "nist_ctc_05_asme1_ap242-e1.stp": (IN, {  # simple subtypes, inch #13402
        "circular_runout": [0.035, 0.025, 0.025],  # #946..#948 -> #987..#989
        "perpendicularity": [0.01, 0.01],          # #955 -> #985, #956 -> #986
        "straightness": [0.005],                   # #957 -> #984
        "concentricity": [0.03],                   # #960 -> #983
        "roundness": [0.002],                      # #961 -> #982
        "total_runout": [0.002, 0.015],            # #962 -> #980, #963 -> #981
    }),
    "nist_ftc_06_asme1_ap242-e1.stp": (IN, {  # 'INCH' #16260 in a mm file
        "flatness": [0.01, 0.01, 0.01],            # #16263, #16280, #16706
        "surface_profile": [0.02, 0.05, 0.01, 0.05, 0.01, 0.02, 0.04, 0.05, 0.01, 0.05, 0.01],
        "position": [0.015, 0.015, 0.025, 0.025, 0.02, 0.025, 0.025, 0.015, 0.015, 0.025, 0.025],
        "perpendicularity": [0.012, 0.012],        # #16671 -> #16670, #16692 -> #16691
    }),
    "nist_ftc_08_asme1_ap242-e1.stp": (IN, {  # inch file, #6
        "parallelism": [0.015, 0.03, 0.015, 0.03, 0.02],  # #10819 #10891 #11046 #11081 #12195
        "surface_profile": [0.035, 0.06, 0.06, 0.05, 0.04, 0.04, 0.005, 0.015, 0.015, 0.015,
                            0.06],  # #10856 #10928 #10968 #11118 #11395 #11534 #11547 ...
        "flatness": [0.015, 0.03, 0.015],          # #11008, #12126, #12158
        "position": [0.04, 0.02, 0.03, 0.05, 0.02, 0.05, 0.02, 0.05, 0.02, 0.05, 0.02, 0.023,
                     0.02],  # #11468 #11483 #11586 #11800 ... #12277 #12314
        "perpendicularity": [0.015],               # #12092 -> #12090
    }),
}  # fmt: skip


@pytest.mark.parametrize("name", NIST)
def test_nist_tolerance_values(name):
    scale, table = TOLERANCES[name]
    expected = Counter((typ, round(v * scale, 6)) for typ, vals in table.items() for v in vals)
    got = Counter((t.type, round(t.value, 6)) for t in _pmi(name).tolerances)
    assert got == expected


#: (file, dimension id, type, nominal, lower, upper, qualifiers that must be present), in mm /
#: degrees: SHAPE_DIMENSION_REPRESENTATION 'nominal value' and TOLERANCE_VALUE bounds
DIMENSIONS = [
    # CTC 01: #120 -> SDR #104 (#70: 35.) ; PLUS_MINUS #64 -> #58 (-0.2, 0.)
    ("nist_ctc_01_asme1_ap242-e1.stp", 120, "diameter", 35.0, -0.2, 0.0, ["diameter"]),
    # CTC 01: ANGULAR_LOCATION #33 -> #30 PLANE_ANGLE 60. 'degree' #4359; #62 -> (-0.5, 0.5)
    ("nist_ctc_01_asme1_ap242-e1.stp", 33, "angle", 60.0, -0.5, 0.5, []),
    ("nist_ctc_02_asme1_ap242-e2.stp", 403, "diameter", 100.0, -0.15, 0.15, []),  # #352, #324
    ("nist_ctc_02_asme1_ap242-e2.stp", 405, "diameter", 12.0, -0.05, 0.05, []),  # #357, #326
    # CTC 03 (inch #5918): #270 -> #236 0.82000000000328 ; #191 (-0.06, 0.06)
    ("nist_ctc_03_asme1_ap242-e2.stp", 270, "thickness", 0.82 * IN, -0.06 * IN, 0.06 * IN, []),
    ("nist_ctc_03_asme1_ap242-e2.stp", 267, "diameter", 2.0 * IN, -0.01 * IN, 0.01 * IN, []),
    # CTC 04: ANGULAR_SIZE #19921 -> #19919 90.0 'DEGREE' #17426 ; #19925 (-1., 1.)
    ("nist_ctc_04_asme1_ap242-e1.stp", 19921, "angle", 90.0, -1.0, 1.0, []),
    # CTC 04: #18992 -> 75.0 and DESCRIPTIVE_REPRESENTATION_ITEM 'theoretical' (basic)
    ("nist_ctc_04_asme1_ap242-e1.stp", 18992, "linear distance", 75.0, None, None, ["basic"]),
    ("nist_ctc_04_asme1_ap242-e1.stp", 19037, "diameter", 6.65, -0.12, 0.12, []),
    # CTC 05 (inch #13402): #888 -> #918 10. ; #934 (-0.001, 0.001)
    ("nist_ctc_05_asme1_ap242-e1.stp", 888, "diameter", 10 * IN, -0.001 * IN, 0.001 * IN, []),
    # CTC 05: #941 -> #915 5. + note 'statistical' ; #933 (-0.008, 0.008)
    ("nist_ctc_05_asme1_ap242-e1.stp", 941, "linear distance", 5 * IN, -0.008 * IN,
     0.008 * IN, ["statistical"]),
    # FTC 06 (INCH #16260): #16678 -> 12. ; #16685 (-0.01, 0.01)
    ("nist_ftc_06_asme1_ap242-e1.stp", 16678, "linear distance", 12 * IN, -0.01 * IN,
     0.01 * IN, []),
    ("nist_ftc_06_asme1_ap242-e1.stp", 16379, "radius", 0.5 * IN, -0.02 * IN, 0.02 * IN, []),
    # FTC 08 (INCH #6): #12424 -> #12422 0.213 ; #12428 (-0.001, 0.005)
    ("nist_ftc_08_asme1_ap242-e1.stp", 12424, "diameter", 0.213 * IN, -0.001 * IN, 0.005 * IN,
     []),
    ("nist_ftc_08_asme1_ap242-e1.stp", 12789, "diameter", 0.25 * IN, -0.001 * IN, 0.006 * IN,
     []),
]  # fmt: skip


@pytest.mark.parametrize(("name", "sid", "typ", "nominal", "lower", "upper", "quals"), DIMENSIONS)
def test_nist_dimension_values(name, sid, typ, nominal, lower, upper, quals):
    dims = {d.step_id: d for d in _pmi(name).dimensions}
    d = dims[sid]
    assert d.type == typ
    assert d.unit == ("deg" if typ == "angle" else "mm")
    assert d.nominal == pytest.approx(nominal, abs=1e-9)
    for got, want in ((d.lower, lower), (d.upper, upper)):
        assert (got is None) if want is None else got == pytest.approx(want, abs=1e-9)
    assert set(quals) <= set(d.qualifiers)


def test_ctc01_limits_and_valueless_dimensions():
    dims = {d.step_id: d for d in _pmi(NIST[0]).dimensions}
    # #124 -> SDR #108: #84 nominal 35., #85 upper limit 35.2, #86 lower limit 34.8
    d = dims[124]
    assert (d.nominal, d.lower_limit, d.upper_limit) == pytest.approx((35.0, 34.8, 35.2))
    # #126 has no DIMENSIONAL_CHARACTERISTIC_REPRESENTATION at all: None, never 0
    assert dims[126].nominal is None and dims[126].problems


#: datum labels per file (DATUM identification attributes)
DATUM_LABELS = {
    "nist_ctc_01_asme1_ap242-e1.stp": "ABC",
    "nist_ctc_02_asme1_ap242-e2.stp": "ABCDEFGHJK",
    "nist_ctc_03_asme1_ap242-e2.stp": "ABCDEF",
    "nist_ctc_04_asme1_ap242-e1.stp": "ABCDEFGH",
    "nist_ctc_05_asme1_ap242-e1.stp": "ABCD",
    "nist_ftc_06_asme1_ap242-e1.stp": "ABCDEFGHJK",
    "nist_ftc_08_asme1_ap242-e1.stp": "ABCDEFGHJKL",
}

#: (file, tolerance id, [(label, precedence, modifiers)]) from DATUM_SYSTEM -> compartments
DRFS = [
    # #21 -> DATUM_SYSTEM #52 (#41 #42 #43) -> DATUM #37 'A', #38 'B', #39 'C'
    ("nist_ctc_01_asme1_ap242-e1.stp", 21, [("A", 1, []), ("B", 2, []), ("C", 3, [])]),
    # #62 -> #177 (#153 #154 #155): D, E (MMR), F (MMR)
    ("nist_ctc_02_asme1_ap242-e2.stp", 62, [
        ("D", 1, []), ("E", 2, ["maximum_material_requirement"]),
        ("F", 3, ["maximum_material_requirement"])]),
    # #67 -> G, H (LMR), J (LMR)
    ("nist_ctc_02_asme1_ap242-e2.stp", 67, [
        ("G", 1, []), ("H", 2, ["least_material_requirement"]),
        ("J", 3, ["least_material_requirement"])]),
    # #40 -> #75 (#63 #64 #65): A, B (MMR), C (MMR)
    ("nist_ctc_03_asme1_ap242-e2.stp", 40, [
        ("A", 1, []), ("B", 2, ["maximum_material_requirement"]),
        ("C", 3, ["maximum_material_requirement"])]),
    ("nist_ctc_04_asme1_ap242-e1.stp", 18781, [("D", 1, []), ("G", 2, []), ("H", 3, [])]),
    # #946 -> #969 -> #977 COMMON_DATUM_LIST((#949, #950)) -> DATUM #1161 'A', #1162 'B'
    ("nist_ctc_05_asme1_ap242-e1.stp", 946, [("A-B", 1, [])]),
    ("nist_ftc_06_asme1_ap242-e1.stp", 16775, [("D", 1, []), ("C", 2, []), ("J", 3, [])]),
    # #11945 -> #11944 (#11939 D, #11942 COMMON_DATUM_LIST(#11940 H (MMR), #11941 J (MMR)))
    ("nist_ftc_08_asme1_ap242-e1.stp", 11945, [
        ("D", 1, []), ("H-J", 2, ["maximum_material_requirement"])]),
]  # fmt: skip


@pytest.mark.parametrize("name", NIST)
def test_nist_datum_labels(name):
    assert "".join(sorted(d.label for d in _pmi(name).datums)) == DATUM_LABELS[name]


@pytest.mark.parametrize(("name", "sid", "drf"), DRFS)
def test_nist_datum_reference_frames(name, sid, drf):
    t = {g.step_id: g for g in _pmi(name).tolerances}[sid]
    assert [(d.label, d.precedence, d.modifiers) for d in t.datums] == drf


def test_nist_modifiers_zones_and_composites():
    t = {g.step_id: g for g in _pmi(NIST[6]).tolerances}
    # #11081: GEOMETRIC_TOLERANCE_WITH_MODIFIERS((.FREE_STATE.,.TANGENT_PLANE.))
    assert t[11081].modifiers == ["free_state", "tangent_plane"]
    # #11395: toleranced aspect is an ALL_AROUND_SHAPE_ASPECT
    assert "all_around" in t[11395].modifiers
    assert t[11468].zone_form == "cylindrical or circular"
    assert t[11468].composite_with == [11483]  # GEOMETRIC_TOLERANCE_RELATIONSHIP 'composite'
    t2 = {g.step_id: g for g in _pmi(NIST[1]).tolerances}
    # UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE: #57 -> #376 (0.5), #56 -> #374 (0., a real zero)
    assert t2[57].unequal_displacement == pytest.approx(0.5)
    assert t2[56].unequal_displacement == 0.0
    assert t2[66].unequal_displacement is None
    t3 = {g.step_id: g for g in _pmi(NIST[2]).tolerances}
    # #37 flatness: WITH_DEFINED_AREA_UNIT(.RECTANGULAR.,#...) of 0.25 x 0.25 inch
    assert t3[37].unit_basis == "per rectangular area 6.35 mm x 6.35 mm"
    t4 = {g.step_id: g for g in _pmi(NIST[3]).tolerances}
    # #18891: PROJECTED_ZONE_DEFINITION of 50 mm
    assert "projected 50 mm" in t4[18891].modifiers


# ============================================================================================
# (d) units: inch conversion, per-measure units, complex magnitudes
# ============================================================================================


def test_inch_conversion():
    ftc06 = {t.step_id: t for t in _pmi(NIST[5]).tolerances}
    # #16263 FLATNESS_TOLERANCE -> #16262 LENGTH_MEASURE(0.01) in 'INCH' (#16260, 25.4 mm),
    # in a file whose context unit is the millimetre
    assert ftc06[16263].value_text == "0.01 INCH"
    assert ftc06[16263].value == pytest.approx(0.254, abs=1e-12)
    assert _pmi(NIST[5]).length_unit == "mm"
    ftc08 = _pmi(NIST[6])
    assert (ftc08.length_unit, ftc08.length_scale) == ("inch", 25.4)
    # #12277 position 0.023 inch
    assert {t.step_id: t for t in ftc08.tolerances}[12277].value == pytest.approx(0.5842)
    ctc05 = _pmi(NIST[4])
    assert (ctc05.length_unit, ctc05.length_scale) == ("inch", 25.4)
    # CTC 03 is a millimetre file with tolerances in a second, 'inch' unit (#5918)
    ctc03 = {t.step_id: t for t in _pmi(NIST[2]).tolerances}
    assert ctc03[40].value_text.endswith(" inch") and ctc03[40].value == pytest.approx(1.27)


def test_complex_magnitude_is_not_zero():
    # CTC 01 #21: magnitude #95 = (LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM()
    # MEASURE_WITH_UNIT(LENGTH_MEASURE(0.75),#4361) REPRESENTATION_ITEM('')); OCCT reads 0.0
    t = {g.step_id: g for g in _pmi(NIST[0]).tolerances}[21]
    assert t.type == "position" and t.value == 0.75 and t.value_text == "0.75 MILLI METRE"


# ============================================================================================
# faces that OCCT loses, checked against the geometry in the file
# ============================================================================================


def _surface(model: P21Model, face: int) -> tuple[str, np.ndarray, np.ndarray, tuple]:
    """Surface type, placement origin and axis, other parameters of a face (file text)."""
    surf = model[model[face].params[2]]
    place = model[surf.params[1]]
    origin = np.array(model[place.params[1]].params[1], dtype=float)
    axis = np.array(model[place.params[2]].params[1], dtype=float)
    return surf.type, origin, axis / np.linalg.norm(axis), surf.params[2:]


def test_datum_faces_through_iiru_and_targets():
    """CTC 03 links datums through ITEM_IDENTIFIED_REPRESENTATION_USAGE; FTC 06 through
    PLACED_DATUM_TARGET_FEATURE (line and circle targets on supplemental geometry)."""
    for name in (NIST[2], NIST[5]):
        for d in _pmi(name).datums:
            assert d.face_step_ids, f"{name} datum {d.label}"
    m = _model(NIST[5])
    d = {x.label: x for x in _pmi(NIST[5]).datums}
    assert d["K"].targets == ["K1", "K2"] and d["J"].targets == ["J1", "J2"]
    # target K2 is the TRIMMED_CURVE #15544 on LINE #15543: x = -96.5962, y = 82.5445542,
    # z from -31.75 to 0 (mm); each face found must be a plane containing that segment
    ends = np.array([[-96.5962, 82.5445542, -31.75], [-96.5962, 82.5445542, 0.0]])
    k_faces = d["K"].face_step_ids
    hits = 0
    for f in k_faces:
        typ, origin, axis, _ = _surface(m, f)
        assert typ == "PLANE"
        hits += bool(np.all(np.abs((ends - origin) @ axis) < 1e-3))
    assert hits >= 1
    # G and H are 'circular curve' targets (circles of radius 0.5 in) on conical seats
    assert all(_surface(m, f)[0] == "CONICAL_SURFACE" for f in d["G"].face_step_ids)


def test_point_targets_lie_on_their_faces():
    # CTC 02 datum A: PLACED_DATUM_TARGET_FEATURE #102..#104 -> SHAPE_ASPECT #1555..#1557 ->
    # CARTESIAN_POINT #20071..#20073, all at z = -330
    m = _model(NIST[1])
    a = {x.label: x for x in _pmi(NIST[1]).datums}["A"]
    assert a.targets == ["A1", "A2", "A3"]
    for f in a.face_step_ids:
        typ, origin, axis, _ = _surface(m, f)
        assert typ == "PLANE" and abs(abs(axis[2]) - 1.0) < 1e-9 and origin[2] == -330.0


def test_thread_geometry_maps_to_the_tapped_holes():
    # CTC 04 #18891 (projected position on 4 threads): COMPOSITE_GROUP_SHAPE_ASPECT -> 4 x
    # GEOMETRIC_CURVE_SET 'Thread Cylinder.1' (a 6 mm circle and two lines on the thread
    # cylinder, axis (0, -0.3746, 0.9272)); the B-rep holes are the 5.1 mm tap-drill cylinders
    m = _model(NIST[3])
    t = {g.step_id: g for g in _pmi(NIST[3]).tolerances}[18891]
    axis = np.array([0.0, -0.3746065934, 0.9271838546])
    assert len(t.face_step_ids) >= 4
    for f in t.face_step_ids:
        typ, _, z, rest = _surface(m, f)
        assert typ == "CYLINDRICAL_SURFACE" and rest[0] == pytest.approx(5.1)
        assert abs(abs(z @ axis) - 1.0) < 1e-6


def test_dimensions_of_threads_and_of_drawn_lines_say_what_they_are():
    """CTC 04's M12 thread size and 25 mm thread depth are given on supplemental geometry
    named 'Thread Cylinder.1' / 'Upper Thread Plane.1' (the B-rep holds the 10.2 mm tap
    drill): not measured, with that reason; FTC 06's 1.106 in REF between two lines drawn
    on the faces of a V: its reason says so."""
    from qifreport.metrology.gdt.characteristics import measure_characteristics
    from qifreport.metrology.gdt.measured_surface import MeasuredSurface
    from qifreport.metrology.gdt.pmi_plan import specs_from_pmi

    dims = {d.step_id: d for d in _pmi(NIST[3]).dimensions}
    assert "'Thread Cylinder.1'" in dims[18938].face_notes[0]
    assert "'Upper Thread Plane.1'" in dims[20263].face_notes[0]
    plan = specs_from_pmi(_pmi(NIST[3]), {})
    thread = {s.step_id: s for s in plan.specs if s.thread}
    assert sorted(thread) == [18938, 20263]
    e = np.empty(0)
    surf = MeasuredSurface(
        np.eye(3),
        np.array([[0, 1, 2]]),
        np.zeros(1, dtype=np.int64),
        np.ones((1, 3, 3)),
        np.zeros(3),
        np.zeros(3),
        np.empty((0, 3)),
        e.astype(np.int64),
        e,
        e,
    )
    res, _ = measure_characteristics(list(thread.values()), {}, surf, "iso14253")
    for r in res:
        assert r.status == "NOT_MEASURED" and "a thread's dimension" in r.reason, r.reason
    drawn = [s.step_id for s in specs_from_pmi(_pmi(NIST[5]), {}).specs if s.drawn]
    assert {16846, 16853} <= set(drawn)


# ============================================================================================
# speed
# ============================================================================================


def test_the_largest_file_parses_whole():
    """Every entity of the largest shared file parses (its speed: bench/io_speed.py)."""
    path = shared_file("step/nist/nist_ftc_06_asme1_ap242-e1.stp")  # 3.2 MB
    model = P21Model.read(path)
    model.parse_all()
    assert len(model) == 16954
    assert read_pmi_text(path).tolerances
