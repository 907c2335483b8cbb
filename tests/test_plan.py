"""``qifreport plan``: the QIF plan of a STEP part, valid (lxml, xmlschema, DMSC checks, PyXB,
Xerces-C), compared item by item with the independent QIF translations of five NIST models
(../shared/qif/nist-models, made by others): every item of theirs has its partner in ours,
and each field that differs is one of the differences listed below with its reason."""

from __future__ import annotations

from pathlib import Path

import pytest
from lxml import etree

from qifreport.cache import sha256 as sha256_file
from qifreport.qif.mbd import compare_items, read_items
from qifreport.qif.plan import plan_file_name, plan_qpid
from qifreport.qif.validate import validate

from .conftest import ROOT, shared_file
from .consumers import assert_read_by_independent_consumers

Q = "{http://qifstandards.org/xsd/qif3}"

#: STEP file -> the independent translation of the same drawing
MODELS = {
    "nist_ctc_01_asme1_ap242-e1.stp": "nist_ctc_01_asme1_ap242.qif",
    "nist_ctc_03_asme1_ap242-e2.stp": "nist_ctc_03_asme1_ap242.qif",
    "nist_ctc_05_asme1_ap242-e1.stp": "nist_ctc_05_asme1_ap242.qif",
    "nist_ftc_06_asme1_ap242-e1.stp": "nist_ftc_06_asme1_ap242.qif",
    "nist_ftc_08_asme1_ap242-e1.stp": "nist_ftc_08_asme1_ap242-1.qif",
}

INCH = "their value is the inch value, labelled mm"
#: (model, their item, field) -> why ours differs; every other field of every item matches
KNOWN = {
    # the STEP file's angle is a DIMENSIONAL_LOCATION between two faces: QIF AngleBetween
    # (their Angle is an angular size)
    ("ctc_01", "Angular Size.1", "type"): "location",
    # 12 tolerances of CTC 03: the translation writes the inch value with linearUnit="mm"
    **{
        ("ctc_03", n, "tolerance"): INCH
        for n in (
            "Perpendicularity.1",
            "Perpendicularity.2",
            "Position.1",
            "Position.3",
            "Position.4",
            "Position.5",
            "Position.6",
            "Position.8",
            "Position Surfacic Profile.1",
            "Position Surfacic Profile.2",
            "Angularity.1",
            "Profile Tolerance af any Surface.1",
        )
    },
    ("ctc_03", "Linear Size.11", "type"): "location",  # DIMENSIONAL_LOCATION: DistanceBetween
    ("ctc_03", "Linear Size.9", "type"): "thickness",  # DIMENSIONAL_SIZE 'thickness': Thickness
    # CTC 05: the runouts cite the common datum A-B; the translation cites no datum
    ("ctc_05", "Feature Control Frame (32)", "datums"): "common datum",
    ("ctc_05", "Feature Control Frame (44)", "datums"): "common datum",
    ("ctc_05", "Feature Control Frame (45)", "datums"): "common datum",
    ("ctc_05", "Vertical Dimension (41)", "type"): "location",
    ("ctc_05", "Horizontal Dimension (8)", "type"): "location",
    # FTC 06: 8 dimensions written in inch without a unit (the document's unit is mm), 3 of
    # them as Width where the STEP file has a location between two faces
    **{
        ("ftc_06", n, f): INCH
        for n in (
            "Linear Size.38",
            "Linear Size.31",
            "Oriented Linear Dimension.4",
            "Linear Size.1",
            "Linear Size.15",
            "Linear Size.14",
            "Oriented Linear Dimension.1",
            "Oriented Linear Dimension.2",
        )
        for f in ("target", "lower", "upper")
    },
    # FTC 06's composite profiles: the lower segment's 0.01 is the inch value (0.254 mm)
    **{
        ("ftc_06", f"Position surfacic profile.{k}", "segment 2 tolerance"): INCH
        for k in (9, 10, 11, 12)
    },
    # FTC 08's composite positions: the STEP file gives both segments
    # MAXIMUM_MATERIAL_REQUIREMENT (e.g. #11468 and #11483 of FCF (28)); the translation
    # writes the lower segment's MaterialCondition NONE
    **{
        ("ftc_08", f"Feature Control Frame ({k})", "segment 2 material"): "MMC in the STEP file"
        for k in (28, 38, 41, 46, 50)
    },
    ("ftc_06", "Linear Size.1", "type"): "location",
    ("ftc_06", "Linear Size.15", "type"): "location",
    ("ftc_06", "Linear Size.14", "type"): "location",
}


def main(argv: list[str]) -> int:
    """The command's exit code."""
    from qifreport.cli import main as cli

    with pytest.raises(SystemExit) as exc:
        cli(argv)
    return exc.value.code


def _model(step: str) -> str:
    return step.split("nist_")[1][:6]


@pytest.fixture(scope="module")
def plans(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("plans")
    paths = {}
    for step in [*MODELS, "nist_ctc_04_asme1_ap242-e1.stp", "panel.step"]:
        src = ROOT / "samples" / step if step == "panel.step" else shared_file(f"step/nist/{step}")
        assert main(["plan", str(src), "--out", str(out)]) == 0
        paths[step] = out / plan_file_name(src.stem)
    return paths


@pytest.mark.parametrize("step", list(MODELS))
def test_plan_matches_the_independent_translation(plans, step):
    theirs = read_items(shared_file(f"qif/nist-models/{MODELS[step]}"))
    ours = read_items(plans[step])
    matches = compare_items(ours, theirs)
    model = _model(step)
    seen = set()
    for m in matches:
        if m.theirs is None:
            continue  # ours only: an item without a value
        assert m.ours is not None, f"{model}: {m.theirs.name} has no partner in the plan"
        for d in m.differences:
            key = (model, m.theirs.name, d.field)
            assert key in KNOWN, f"{model} {m.theirs.name}: {d.field} {d.ours} vs {d.theirs}"
            if KNOWN[key] == INCH:
                # the same value once their inch is read as inch (the comparator checks it)
                assert d.note == INCH
            seen.add(key)
    assert seen == {k for k in KNOWN if k[0] == model}, "a known difference is gone"
    # every PMI item of the file is in the plan (each datum-bearing item with its frame)
    assert len(ours) >= len(theirs)


def test_composite_segments_and_datum_modifiers_in_ftc_08(plans):
    ours = read_items(plans["nist_ftc_08_asme1_ap242-e1.stp"])
    by_name = {}
    for it in ours:
        by_name.setdefault(it.name, []).append(it)
    # a datum at its maximum material boundary, as drawn (|D|G(M)|)
    assert by_name["Feature Control Frame (34)"][0].datums == (("D", "NONE"), ("G", "MAXIMUM"))
    # a composite position: one characteristic, its lower segment QIF's second segment
    (frame,) = by_name["Feature Control Frame (28)"]
    assert frame.tolerance == pytest.approx(1.016)
    (lower,) = frame.segments
    assert lower.tolerance == pytest.approx(0.508)
    assert frame.material == lower.material == "MAXIMUM"
    assert lower.datums == frame.datums == (("D", "NONE"), ("B", "NONE"), ("C", "NONE"))
    # every composite frame of the file: 5 positions and a profile, each with one segment
    composite = [it for it in ours if it.segments]
    assert sorted(it.type for it in composite) == ["Position"] * 5 + ["SurfaceProfile"]
    assert all(len(it.segments) == 1 for it in composite)


def test_modifiers_are_written_as_qif_elements(plans):
    """The drawing's modifiers as QIF's elements, not only as free-text attributes: a
    projected zone's height (CTC 04: position 0.75 (P) 50), tangent plane, free state and
    all around (FTC 08), a statistical dimension (CTC 05)."""
    ctc04 = read_items(plans["nist_ctc_04_asme1_ap242-e1.stp"])
    assert [(it.type, it.projected) for it in ctc04 if it.projected] == [("Position", 50.0)]
    ftc08 = read_items(plans["nist_ftc_08_asme1_ap242-e1.stp"])
    flags = [f for it in ftc08 for f in it.flags]
    assert flags.count("TangentPlane") == 3 and flags.count("FreeState") == 5
    around = [it for it in ftc08 if it.extent == "ALL_AROUND"]
    assert len(around) == 5 and {it.type for it in around} == {"SurfaceProfile"}
    ctc05 = read_items(plans["nist_ctc_05_asme1_ap242-e1.stp"])
    (st,) = [it for it in ctc05 if "StatisticalCharacteristic" in it.flags]
    assert st.upper - st.lower == pytest.approx(2 * 0.008 * 25.4)


def test_per_unit_area_flatness_in_ctc_03(plans):
    root = etree.parse(str(plans["nist_ctc_03_asme1_ap242-e2.stp"])).getroot()
    (flat,) = root.iter(f"{Q}FlatnessCharacteristicDefinition")
    per = flat.find(f"{Q}ToleranceZonePerUnitArea")
    assert per is not None and flat.find(f"{Q}ToleranceValue") is None
    assert float(per.findtext(f"{Q}ToleranceValuePerUnit")) == pytest.approx(0.127)
    area = per.find(f"{Q}RectangularUnitArea")
    assert float(area.findtext(f"{Q}RectangularUnitAreaLength")) == pytest.approx(6.35)


@pytest.mark.parametrize("step", [*MODELS, "panel.step"])
def test_plan_is_valid_and_names_its_faces(plans, step):
    path = plans[step]
    rep = validate(path, strict=True, checks=True)
    assert rep.valid, rep.format()
    root = etree.parse(str(path)).getroot()
    assert root.find(f"{Q}Plan") is not None and root.find(f"{Q}Results") is None
    src = ROOT / "samples" / step if step == "panel.step" else shared_file(f"step/nist/{step}")
    assert root.findtext(f"{Q}QPId") == plan_qpid(sha256_file(src))
    # each feature names its B-rep faces by STEP entity id
    step_text = src.read_text(errors="replace")
    feats = list(root.iter(f"{Q}OtherSurfaceFeatureNominal"))
    assert feats
    for f in feats:
        names = {a.get("name"): a.get("value") for a in f.iter(f"{Q}AttributeStr")}
        if names.get("b_rep_faces", "none") == "none":
            continue
        for sid in names["step_faces"].split()[:3]:
            assert f"#{sid}=" in step_text.replace(" ", "")
    # every datum of a frame has its datum feature
    for d in root.iter(f"{Q}DatumDefinition"):
        if "-" not in d.findtext(f"{Q}DatumLabel"):
            assert d.find(f"{Q}FeatureNominalIds") is not None, d.findtext(f"{Q}DatumLabel")


def test_plan_read_by_independent_consumers(plans, pyxb_qif, qif_xsd):
    assert_read_by_independent_consumers(plans["nist_ftc_08_asme1_ap242-e1.stp"], pyxb_qif, qif_xsd)


def test_plan_refuses_a_mesh_and_an_existing_file(plans, tmp_path, capsys):
    assert main(["plan", str(ROOT / "samples/shell_nominal.ply"), "--out", str(tmp_path)]) == 2
    assert "not a STEP file" in capsys.readouterr().err
    out = plans["panel.step"].parent
    assert main(["plan", str(ROOT / "samples/panel.step"), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


def test_compare_pairs_by_content_not_by_a_duplicate_name():
    """Two position tolerances of one name (a translator's, or an exporter's duplicate):
    each pairs with the one of the same value and frame, whatever their order; a
    dimension pairs by its limits before its nominal alone."""
    from qifreport.qif.mbd import MbdItem

    a1 = MbdItem("Position.1", "Position", tolerance=0.1, datums=(("A", "NONE"),))
    a2 = MbdItem("Position.1", "Position", tolerance=0.3, datums=(("A", "NONE"), ("B", "NONE")))
    d1 = MbdItem("D1", "Diameter", target=10.0, lower=9.9, upper=10.1)
    d2 = MbdItem("D2", "Diameter", target=10.0, lower=9.95, upper=10.05)
    theirs = [a2, a1, d2, d1]
    matches = compare_items([a1, a2, d1, d2], theirs)
    assert [(m.theirs, m.ours) for m in matches] == [(a2, a2), (a1, a1), (d2, d2), (d1, d1)]
    assert all(not m.differences for m in matches)
