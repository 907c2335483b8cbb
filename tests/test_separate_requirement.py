"""A separate requirement (SEP REQT, ASME Y14.5-2018 7.19): written in a STEP file by
``step/write.py`` on the panel sample (its skin profile |A|B| and its flange flatness),
read back as the tolerance's modifier, applied (the datum features are simulated regardless
of material boundary, so each characteristic of a frame has that frame's one placement:
separate and simultaneous read the same), and stated in the QIF plan as QIF's
``SimultaneousRequirementGroup`` with ``Requirement`` ``SEP_REQ`` naming its characteristic
nominal. The file's other profile (every face, |A|B|C|) stays simultaneous: no group."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from qifreport.metrology.acceptance.bands import zones_from_pmi
from qifreport.qif.mbd import read_items
from qifreport.qif.validate import validate
from qifreport.step.p21 import P21Model
from qifreport.step.reader import read_step
from qifreport.step.write import write_step_with_pmi
from tests.conftest import ROOT

SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).with_name("qifreport")
Q = "{http://qifstandards.org/xsd/qif3}"


@pytest.fixture(scope="module")
def sep_step(tmp_path_factory) -> Path:
    """The panel sample, its skin profile a separate requirement."""
    sys.path.insert(0, str(SAMPLES))
    from make_step_sample import TIMESTAMP, build_part, sample_spec

    shape = build_part()
    datums, tolerances = sample_spec(shape)
    skin = next(t for t in tolerances if t.name == "profile_skin")
    skin.modifiers = ["separate_requirement"]
    path = tmp_path_factory.mktemp("sep") / "panel_sep.step"
    write_step_with_pmi(shape, path, tolerances, datums, "curved_cover", timestamp=TIMESTAMP)
    return path


def test_written_and_read_as_the_tolerance_s_modifier(sep_step):
    model = P21Model.read(sep_step)
    (tol,) = [
        e
        for e in model.by_type("SURFACE_PROFILE_TOLERANCE")
        if e.part("GEOMETRIC_TOLERANCE")[0] == "profile_skin"
    ]
    assert "SEPARATE_REQUIREMENT" in str(tol.part("GEOMETRIC_TOLERANCE_WITH_MODIFIERS"))
    part = read_step(sep_step)
    by_name = {t.name: t for t in part.pmi.tolerances}
    assert by_name["profile_skin"].modifiers == ["separate_requirement"]
    assert by_name["profile_all"].modifiers == []
    # applied: the band is laid, not left out naming the modifier
    zones, skipped = zones_from_pmi(part.pmi, part.face_index(), None)
    skin = next(z for z in zones if z.name == "profile_skin")
    assert skin.modifiers == ["separate_requirement"] and skin.datums == ["A", "B"]
    assert not [s for s in skipped if "separate" in s.reason]


def test_plan_states_it_as_a_simultaneous_requirement_group(sep_step, tmp_path):
    r = subprocess.run(
        [str(EXE), "plan", str(sep_step), "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    plan = tmp_path / "panel_sep_plan.qif"
    rep = validate(plan, strict=True, checks=True)
    assert rep.valid, rep.format()
    root = etree.parse(str(plan)).getroot()
    (group,) = root.iter(f"{Q}SimultaneousRequirementGroup")
    assert group.findtext(f"{Q}Requirement") == "SEP_REQ"
    (cn,) = [x.text for x in group.iterfind(f"{Q}CharacteristicNominalIds/{Q}Id")]
    nominal = next(e for e in root.iter() if e.get("id") == cn)
    assert etree.QName(nominal).localname == "SurfaceProfileCharacteristicNominal"
    assert nominal.findtext(f"{Q}Name") == "profile_skin"
    # the comparison reads it as the item's modifier
    flags = {it.name: it.flags for it in read_items(plan)}
    assert "SeparateRequirement" in flags["profile_skin"]
    assert "SeparateRequirement" not in flags["profile_all"]
