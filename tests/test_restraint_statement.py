"""Restraint is stated, never chosen silently: the drawing's restraint note read from the
AP242 text (NIST FTC 08's note 5, the sample panel's ISO 10579-NR note; none in FTC 06 and
the CTC files), the condition decided once from the drawing and the operator's options,
and a STEP part whose drawing states no restraint judged in the free state only, said so
in its JSON and QIF.

Real NIST files, the real sample STEP read by OCP, the real command line.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from qifreport.errors import InputError
from qifreport.metrology.acceptance.bands import symmetric_zone
from qifreport.metrology.model import Drawing, RestraintStatement
from qifreport.metrology.params import InspectionParams
from qifreport.options import InspectOptions
from qifreport.step.notes import restraint_note
from qifreport.step.p21 import P21Model
from qifreport.step.semantic import read_pmi_text
from tests.conftest import NIST, shared_file

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("qifreport")
Q = "{http://qifstandards.org/xsd/qif3}"


def test_ftc08_restraint_note_is_read_and_no_other_nist_file_states_one():
    """FTC 08's note 5 states the restrained condition (its tolerances carry the free-state
    modifier (F) too); FTC 06 and the CTC files state none."""
    found = {name: read_pmi_text(shared_file(f"step/nist/{name}")) for name in NIST}
    ftc08 = next(n for n in found if n.startswith("nist_ftc_08"))
    note = found[ftc08].restraint
    assert note is not None and note.phrase == "RESTRAINED" and note.step_id == 12880
    assert note.text.startswith("5. DIMENSIONING AND TOLERANCING APPLY WITH PART RESTRAINED")
    assert note.text.endswith("DETAILED INSPECTION PLAN NEEDED TO COMPLETELY DEFINE RESTRAINT.")
    assert "6. UNITS" not in note.text  # the note, not the next one
    free = [t for t in found[ftc08].tolerances if "free_state" in t.modifiers]
    assert len(free) == 5
    assert [n for n, pmi in found.items() if pmi.restraint is not None] == [ftc08]
    assert any(n.startswith("nist_ftc_06") for n in found)


def test_a_denied_restraint_states_none_and_a_text_literal_is_read():
    def note(text: str, entity: str = "DESCRIPTIVE_REPRESENTATION_ITEM('note',{})"):
        return restraint_note(P21Model.from_text(f"DATA; #1 = {entity.format(text)}; ENDSEC;"))

    assert note("'INSPECT IN THE FREE STATE, UNRESTRAINED.'") is None
    assert note("'PART NOT RESTRAINED'") is None
    assert note("'NO RESTRAINT APPLIES'") is None
    lit = note("'ISO 10579 - NR'", "TEXT_LITERAL('n',{},$,'baseline left',.RIGHT.)")
    assert lit is not None and lit.phrase == "ISO 10579 - NR" and lit.step_id == 1


def test_the_sample_panel_declares_its_restraint():
    pmi = read_pmi_text(ROOT / "samples/panel.step")
    note = pmi.restraint
    assert note is not None and note.phrase == "ISO 10579-NR"
    assert "APPLY WITH PART RESTRAINED" in note.text and "20 N" in note.text
    # "AT TARGETS A1-A4, DATUM FEATURES B AND C ENGAGED AT TARGETS B1, C1-C2"
    assert note.targets == ("A1", "A2", "A3", "A4", "B1", "C1", "C2")
    assert pmi.held_targets() == (note.targets, ())


@pytest.mark.parametrize(
    "text, targets",
    [
        (
            "HELD AT TARGETS A1 THRU A4 AND B1 & C1 TO C2.",
            ("A1", "A2", "A3", "A4", "B1", "C1", "C2"),
        ),
        ("AT DATUM TARGETS A1, A2 AND A3; FORCE MAX 5 N", ("A1", "A2", "A3")),
        ("PART HELD AT THE DATUM TARGETS.", ("*",)),
        # FTC 08's note 5: held against the simulators, at no target
        ("PLACE DATUM FEATURE A AGAINST DATUM FEATURE SIMULATOR A.", ()),
        ("TARGET A1-B3", ()),  # no range across datums
        ("TARGETS A1-A400", ()),  # nor one of 400 targets
    ],
)
def test_the_targets_a_restraint_note_holds_the_part_at(text, targets):
    from qifreport.step.notes import restraint_targets

    assert restraint_targets(text) == targets


def test_ftc08_note_holds_at_no_target():
    pmi = read_pmi_text(next((ROOT.parent / "shared/step/nist").glob("*ftc_08*")))
    assert pmi.restraint is not None and pmi.restraint.targets == ()
    assert pmi.held_targets() == ((), ())


def _drawing(said: RestraintStatement) -> Drawing:
    return Drawing([symmetric_zone(0.5, "general")], restraint=said)


NOTE = RestraintStatement(True, "1. ISO 10579-NR. ...", "drawing note")
AT_TARGETS = RestraintStatement(True, "... AT TARGETS A1-A3, B1, C1", "drawing note", ("A1",))
UNPLACED = RestraintStatement(True, "... AT TARGETS A1-A3", "drawing note", ("A1",), ("A2",))
NONE = RestraintStatement(False, "", "drawing")
MESH = RestraintStatement()


@pytest.mark.parametrize(
    ("options", "said", "expected"),
    [
        ({}, NOTE, ("virtual", "drawing note")),
        ({}, AT_TARGETS, ("clamps", "drawing note")),
        ({}, UNPLACED, ("virtual", "drawing note")),
        ({"restraint": "virtual"}, AT_TARGETS, ("virtual", "operator")),
        ({"rigid_only": True}, AT_TARGETS, ("free", "operator")),
        ({}, NONE, ("free", "drawing")),
        ({}, MESH, ("virtual", "default")),
        ({"restraint": "free"}, NOTE, ("free", "operator")),
        ({"restraint": "virtual"}, NONE, ("virtual", "operator")),
        ({"rigid_only": True}, NOTE, ("free", "operator")),
        ({"always_fixture": True}, NONE, ("virtual", "operator")),
        ({"fixture": "free"}, NONE, ("virtual", "operator")),
        ({"clamps": Path("pmi")}, NONE, ("clamps", "operator")),
        ({"restraint": "clamps", "clamps": Path("pmi")}, MESH, ("clamps", "operator")),
    ],
)
def test_the_condition_is_decided_once_and_says_who_stated_it(options, said, expected):
    o = InspectOptions(**options)
    o.check()
    got = o.restraint_condition(_drawing(said))
    assert (got.condition, got.stated_by) == expected
    assert got.statement  # the note, the option, or why the default applies
    params = InspectionParams(restraint=got)
    assert params.held_condition == got


def test_a_note_naming_targets_the_file_does_not_place_says_so():
    got = InspectOptions().restraint_condition(_drawing(UNPLACED))
    assert "does not place its target(s) A2" in got.statement


def test_the_drawing_s_targets_are_the_clamps_unless_the_operator_says_otherwise():
    """The sample panel's note names its placed targets: with no option they are the
    clamps, each limited by the note's 20 N (``--max-clamp-force`` overrides it); an
    operator's condition (virtual, free, another clamps file) replaces them."""
    panel = ROOT / "samples/panel.step"
    spec = InspectOptions().restraint_spec(panel)
    assert [c.name for c in spec.clamps] == ["A1", "A2", "A3", "A4", "B1", "C1", "C2"]
    assert {c.max_force for c in spec.clamps} == {20.0}
    assert spec.source.startswith("the drawing's restraint note (#1549)")
    assert {
        c.max_force for c in InspectOptions(max_clamp_force=5.0).restraint_spec(panel).clamps
    } == {5.0}
    for options in ({"restraint": "virtual"}, {"rigid_only": True}, {"fixture": "free"}):
        assert InspectOptions(**options).restraint_spec(panel) is None
    csv = InspectOptions(clamps=ROOT / "samples/panel_clamps.csv").restraint_spec(panel)
    assert csv.source == "clamps file panel_clamps.csv"
    assert InspectOptions().restraint_spec(ROOT / "samples/shell_nominal.ply") is None


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"restraint": "free", "clamps": Path("pmi")}, "--restraint free and --clamps pmi"),
        ({"restraint": "virtual", "rigid_only": True}, "--restraint virtual and --rigid-only"),
        ({"restraint": "free", "always_fixture": True}, "--restraint free and --always-fixture"),
        ({"restraint": "clamps"}, "--restraint clamps needs the clamps"),
        ({"restraint": "held"}, "--restraint must be one of free, virtual, clamps"),
    ],
)
def test_contradicting_statements_are_refused(options, message):
    with pytest.raises(InputError, match=message):
        InspectOptions(**options).check()


def test_a_step_part_without_a_restraint_note_is_judged_in_its_free_state(tmp_path):
    """The sample panel with its restraint note taken out: the drawing states no restraint,
    so no fixture is applied and the part FAILs in its free state (the virtual fixture of
    the noted drawing hides it: PASS); the JSON's restraint block and the QIF say so."""
    text = (ROOT / "samples/panel.step").read_text()
    plain = tmp_path / "plain.step"
    plain.write_text(
        text.replace("ISO 10579-NR. ", "")
        .replace("RESTRAINED", "INSPECTED")
        .replace("RESTRAINT FORCE", "FORCE")
    )
    assert read_pmi_text(plain).restraint is None
    out = tmp_path / "out"
    cmd = [str(EXE), str(plain), str(ROOT / "samples/panel_scan.ply"), "--max-edge", "6"]
    r = subprocess.run(
        cmd + ["--no-cache", "--json", "--no-pdf", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 1, r.stdout + r.stderr[-2000:]
    assert "condition: FAIL in the free state (stated by: drawing); no restraint applied" in (
        r.stdout
    )
    doc = json.loads((out / "plain.json").read_text())
    held = doc["restraint"]
    assert (held["condition"], held["stated_by"], held["applied"]) == ("free", "drawing", False)
    assert held["free_state"]["verdict"] == doc["verdict"] == "FAIL"
    assert doc["registration"]["fit"] is None
    assert doc["parameters"]["restraint"]["condition"] == "free"
    # the free state's deviation is what a virtual fixture would have bent away: the
    # crown's skin (T2, +/-0.25 mm) lies 0.5-0.9 mm off its nominal
    t2 = next(z for z in doc["tolerances"] if z["key"] == "T2")
    assert t2["verdict"] == "FAIL" and t2["deviation"]["max_abs"] > 0.5
    attrs = {
        a.get("name"): a.get("value")
        for a in etree.parse(str(out / "plain.qif")).iter(f"{Q}AttributeStr")
    }
    assert attrs["restraint_condition"] == "free" and attrs["restraint_stated_by"] == "drawing"
    assert attrs["judged_condition"].startswith("FAIL in the free state")
    assert doc["qif"]["valid"] is True


@pytest.mark.parametrize(
    "note, force",
    [
        ("RESTRAINT FORCE AT MOST 20 N PER TARGET.", 20.0),
        ("CLAMPING FORCES NOT TO EXCEED 0.5 KN.", 500.0),
        ("APPLY A FORCE OF MAX. 10 lbf AT EACH CLAMP", 44.482216152605),
        ("LOAD THE PART. FORCE AS REQUIRED. MAX 5 N", None),  # another sentence's bound
        ("PART RESTRAINED AT DATUM TARGETS", None),
    ],
)
def test_the_note_s_force_limit(note, force):
    """A restraint note's force limit per contact (:func:`qifreport.step.notes.restraint_force`):
    a force word, a bound and a value in N, kN or lbf within one sentence."""
    from qifreport.step.notes import restraint_force

    got = restraint_force(note)
    assert (got is None) if force is None else got[0] == pytest.approx(force)
