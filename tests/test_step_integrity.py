"""STEP integrity and tolerance plausibility: a damaged or solid-less STEP file is refused with
one line naming the entity and the reason (library and CLI, exit 2, nothing written); every
real file passes; implausible tolerance values are named.

The damaged inputs are made from the real files, as copies in ``tmp_path``.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from qifreport.errors import InputError
from qifreport.step.integrity import SOLID_TYPES, check_integrity, integrity_problems
from qifreport.step.p21 import P21Model
from qifreport.step.plausibility import implausible_tolerances
from qifreport.step.pmi import PMI, Dimension, GeometricTolerance
from tests.conftest import NIST, ROOT, shared_file

PANEL = ROOT / "samples" / "panel.step"
PANEL_SCAN = ROOT / "samples" / "panel_scan.ply"
EXE = Path(sys.executable).parent / "qifreport"
CLOSE = "ENDSEC;\nEND-ISO-10303-21;\n"
#: the panel's wall (samples/make_step_sample.py, WALL)
PANEL_WALL = 1.8
#: a record from its ``#id =`` at the start of a line to its final ``;`` (records may span
#: lines; the panel and NIST files have no ';' inside strings)
RECORD = r"(?ms)^#{id} = .*?;\n"


def _records_of_type(text: str, type_name: str) -> list[re.Match]:
    return list(re.finditer(rf"(?ms)^#(\d+) = {type_name}\(.*?;\n", text))


def _drop(text: str, matches: list[re.Match]) -> str:
    for m in sorted(matches, key=lambda m: m.start(), reverse=True):
        text = text[: m.start()] + text[m.end() :]
    return text


def _panel_without_three_faces(tmp: Path) -> tuple[Path, list[int]]:
    text = PANEL.read_text()
    faces = _records_of_type(text, "ADVANCED_FACE")[1:4]
    f = tmp / "panel_3_faces_deleted.step"
    f.write_text(_drop(text, faces))
    return f, [int(m.group(1)) for m in faces]


def _nist_cut_at_70(tmp: Path, name: str) -> Path:
    data = shared_file("step/nist/" + name).read_bytes()
    f = tmp / ("cut70_" + name)
    f.write_bytes(data[: int(0.7 * len(data))] + CLOSE.encode())
    return f


def _panel_without_solid(tmp: Path) -> Path:
    """Every solid record deleted and its id taken out of the representations' item lists."""
    text = PANEL.read_text()
    solids = [m for t in SOLID_TYPES for m in _records_of_type(text, t)]
    assert solids
    text = _drop(text, solids)
    for m in solids:
        sid = m.group(1)
        text = re.sub(rf",\s*#{sid}(?!\d)|#{sid}(?!\d)\s*,", "", text)
    f = tmp / "panel_no_solid.step"
    f.write_text(text)
    return f


def _points_and_pmi_only(tmp: Path) -> Path:
    """The panel's points, directions and PMI measures with their units, nothing else: a
    well-formed file (every reference resolves) with no solid, shell or face."""
    text = PANEL.read_text()
    head, data = text.split("DATA;\n", 1)
    keep = {"CARTESIAN_POINT", "DIRECTION", "LENGTH_MEASURE_WITH_UNIT"}
    body = "".join(
        m.group(0)
        for m in re.finditer(r"(?ms)^#\d+ = (\(?\s*[A-Z_]+).*?;\n", data)
        if m.group(1).lstrip("( ") in keep or "UNIT()" in m.group(0)
    )
    f = tmp / "points_only.step"
    f.write_text(head + "DATA;\n" + body + CLOSE)
    return f


# ------------------------------------------------------------------------------------------
# the real files pass


@pytest.mark.parametrize("name", [*NIST, "panel.step"])
def test_every_real_file_passes_the_integrity_check(name):
    path = PANEL if name == "panel.step" else shared_file("step/nist/" + name)
    model = P21Model.read(path)
    assert model.data_closed and model.terminated
    assert not model.fragments and not model.duplicates
    assert model.dangling() == []
    assert integrity_problems(model) == []
    assert check_integrity(model, path.name) >= 0.0


def test_a_clean_file_reads():
    from qifreport.step.reader import read_step

    part = read_step(PANEL)
    assert part.n_solids == 1 and len(part.faces) == 15
    assert (part.face_step_ids >= 0).all()
    assert len(part.pmi.tolerances) == 4 and not part.pmi.problems
    assert {"p21_read", "integrity", "xde_read"} <= set(part.timings)


def test_section_keywords_in_mixed_case_read_as_in_capitals(tmp_path):
    """OCCT's own test file ``bug31000_InSensitive.stp`` writes ``Header;``, ``Data;``,
    ``EndSec;`` and ``End-ISO-10303-21;``: OCCT reads it, and so does the text check before
    it (it once refused it as having "no DATA section")."""
    from qifreport.step.reader import read_step

    text = PANEL.read_text(encoding="utf-8")
    for kw, mixed in (("HEADER;", "Header;"), ("DATA;", "Data;"), ("ENDSEC;", "EndSec;")):
        text = re.sub(rf"^{kw}", mixed, text, flags=re.M)
    text = text.replace("END-ISO-10303-21;", "End-ISO-10303-21;")
    assert "DATA;" not in text and "Data;" in text
    p = tmp_path / "mixed.step"
    p.write_text(text, encoding="utf-8")
    part = read_step(p)
    assert part.n_solids == 1 and len(part.faces) == 15 and len(part.pmi.tolerances) == 4


# ------------------------------------------------------------------------------------------
# damaged files are refused by read_step


def test_deleted_faces_are_named_as_dangling_references(tmp_path):
    from qifreport.step.reader import read_step

    f, deleted = _panel_without_three_faces(tmp_path)
    with pytest.raises(InputError) as exc:
        read_step(f)
    msg = str(exc.value)
    assert msg.startswith(f"{f.name}: STEP file damaged: #16 CLOSED_SHELL refers to #")
    assert "which the file does not define" in msg
    assert all(f"#{i}" in msg for i in deleted), msg
    assert "\n" not in msg
    pairs = P21Model.read(f).dangling()
    assert {t for _, t in pairs} == set(deleted)
    assert (16, deleted[0]) in pairs  # the shell, and the PMI that named the faces


@pytest.mark.parametrize("name", NIST)
def test_nist_file_cut_at_70_percent_and_closed_is_refused(tmp_path, name):
    from qifreport.step.reader import read_step

    f = _nist_cut_at_70(tmp_path, name)
    with pytest.raises(InputError, match=rf"^{re.escape(f.name)}: STEP file damaged: ") as exc:
        read_step(f)
    assert "unexpected end of file" in str(exc.value) or "does not define" in str(exc.value)


@pytest.mark.parametrize("name", NIST)
def test_cut_at_a_record_boundary_and_closed_is_refused(tmp_path, name):
    """Cut after the last whole record before 70 %: no fragment, the closing lines proper;
    what is lost shows as dangling references or as a solid that nothing uses."""
    from qifreport.step.reader import read_step

    text = shared_file("step/nist/" + name).read_text(encoding="latin-1")
    end = text.rfind(";\n", 0, int(0.7 * len(text))) + 2
    f = tmp_path / ("cut_" + name)
    f.write_text(text[:end] + CLOSE, encoding="latin-1")
    model = P21Model.read(f)
    assert model.data_closed and model.terminated and not model.fragments
    with pytest.raises(InputError, match=r"STEP file damaged: .*does not define|no solid"):
        read_step(f)


def test_file_cut_without_closing_lines(tmp_path):
    from qifreport.step.reader import read_step

    data = PANEL.read_bytes()
    f = tmp_path / "half.step"
    f.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="STEP file damaged: unexpected end of file: .*ENDSEC"):
        read_step(f)
    # closed again, with the cut record left in: the fragment is named
    g = tmp_path / "half_closed.step"
    g.write_bytes(data[: len(data) // 2] + b"\n" + CLOSE.encode())
    with pytest.raises(InputError, match=r"ends inside a record .*closed again"):
        read_step(g)


def test_missing_trailer_and_duplicate_ids(tmp_path):
    text = PANEL.read_text()
    assert text.rstrip().endswith("END-ISO-10303-21;")
    no_end = P21Model.from_text(text.rstrip()[: -len("END-ISO-10303-21;")])
    assert [p.kind for p in integrity_problems(no_end)] == ["structure"]
    assert "no END-ISO-10303-21;" in integrity_problems(no_end)[0].message
    dup = P21Model.from_text(
        text.replace("ENDSEC;\nEND", "#12 = DIRECTION('',(1.,0.,0.));\nENDSEC;\nEND")
    )
    problems = integrity_problems(dup)
    assert [p.kind for p in problems] == ["duplicate"]
    assert problems[0].message.startswith("#12 is defined more than once")
    garbled = P21Model.from_text(text.replace("#13 = DIRECTION", "junk #13 = DIRECTION", 1))
    assert integrity_problems(garbled)[0].message.startswith(
        "text that is not a complete record (after #12 CARTESIAN_POINT: 'junk')"
    )


# ------------------------------------------------------------------------------------------
# no solid


def test_no_solid_record_is_refused(tmp_path):
    from qifreport.step.reader import read_step

    f = _panel_without_solid(tmp_path)
    model = P21Model.read(f)
    assert model.dangling() == []  # well formed, only the solid is gone
    with pytest.raises(InputError, match=r"^panel_no_solid.step: no solid in the STEP file") as e:
        read_step(f)
    assert "only surfaces" in str(e.value)


def test_points_and_pmi_only_is_no_solid(tmp_path):
    from qifreport.step.reader import read_step

    f = _points_and_pmi_only(tmp_path)
    assert P21Model.read(f).dangling() == []
    with pytest.raises(InputError, match=r"no solid in the STEP file.*no shape to inspect"):
        read_step(f)


def test_shell_based_surface_model_is_no_solid(tmp_path):
    """OCCT reads a SHELL_BASED_SURFACE_MODEL of a CLOSED_SHELL as a shell: no solid."""
    from qifreport.step.reader import read_step

    text = PANEL.read_text().replace(
        "#15 = MANIFOLD_SOLID_BREP('',#16)", "#15 = SHELL_BASED_SURFACE_MODEL('',(#16))"
    )
    f = tmp_path / "sbsm.step"
    f.write_text(text)
    with pytest.raises(InputError, match="no solid in the STEP file"):
        read_step(f)


def test_solid_that_no_product_uses_is_refused(tmp_path):
    from qifreport.step.reader import read_step

    text = PANEL.read_text()
    # the solid outside every representation (the shell in its place)
    f = tmp_path / "orphan_solid.step"
    f.write_text(text.replace("(#11,#15),#1369", "(#11,#16),#1369"))
    with pytest.raises(InputError, match=r"no solid in use: #15 MANIFOLD_SOLID_BREP is an item"):
        read_step(f)
    # the representation of no product (its SHAPE_DEFINITION_REPRESENTATION deleted)
    g = tmp_path / "no_product.step"
    g.write_text(_drop(text, list(re.finditer(RECORD.format(id=3), text))))
    assert P21Model.read(g).dangling() == []
    with pytest.raises(InputError, match=r"#10 ADVANCED_BREP_SHAPE_REPRESENTATION.*no product"):
        read_step(g)


# ------------------------------------------------------------------------------------------
# the CLI: exit 2, one line, nothing written


#: case -> (maker of the bad file in a directory, a word of the expected message)
BAD = {
    "three faces deleted": (lambda d: _panel_without_three_faces(d)[0], "does not define"),
    "NIST cut at 70 % and closed": (
        lambda d: _nist_cut_at_70(d, "nist_ftc_06_asme1_ap242-e1.stp"),
        "unexpected end of file",
    ),
    "no solid": (_panel_without_solid, "no solid"),
}


def _assert_one_line_exit_2(r: subprocess.CompletedProcess, word: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qifreport: error:"), r.stderr
    assert word in lines[0], lines[0]


@pytest.mark.parametrize("case", list(BAD))
def test_cli_refuses_a_damaged_file_with_one_line_and_writes_nothing(tmp_path, case):
    make, word = BAD[case]
    f = make(tmp_path)
    r = subprocess.run([str(EXE), "pmi", f], capture_output=True, text=True)
    _assert_one_line_exit_2(r, word)
    assert r.stdout == ""
    out = tmp_path / "D"
    r = subprocess.run([str(EXE), f, PANEL_SCAN, "--out", out], capture_output=True, text=True)
    _assert_one_line_exit_2(r, word)
    assert not out.exists() or not any(out.iterdir()), list(out.iterdir())


# ------------------------------------------------------------------------------------------
# plausibility of the tolerance values


def _profile(value: float, step_id: int = 7, type_: str = "surface_profile") -> GeometricTolerance:
    return GeometricTolerance(step_id, "skin", type_, value, f"{value} MILLI METRE")


def test_a_1000_mm_profile_on_a_300_mm_part_is_flagged():
    pmi = PMI("AP242", "mm", 1.0, tolerances=[_profile(1000.0), _profile(0.5, 8)])
    reasons = implausible_tolerances(pmi, 300.0)
    assert len(reasons) == 1
    assert reasons[0].startswith("#7 surface_profile 'skin': 1000 mm")
    assert "10% of the part's diagonal (limit 30 mm)" in reasons[0]
    assert implausible_tolerances(pmi, 300.0, fraction=5.0) == []


def test_wall_rule_applies_to_profiles_only_and_bad_values():
    pmi = PMI(
        "AP242",
        "mm",
        1.0,
        tolerances=[_profile(2.0, 1), _profile(2.0, 2, "position"), _profile(-1.0, 3)],
        dimensions=[Dimension(4, "", "size", "thickness", "mm", 2.0, -25.0, 25.0)],
    )
    reasons = implausible_tolerances(pmi, 300.0, thickness_mm=1.5)
    assert [r.split(" ", 1)[0] for r in reasons] == ["#1", "#3", "#4"]
    assert "wider than the wall (1.5 mm thick)" in reasons[0]
    assert "not a tolerance width" in reasons[1]
    assert "tolerance band -25..25: 50 mm" in reasons[2]
    assert implausible_tolerances(None, 300.0) == []
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="diagonal_mm"):
            implausible_tolerances(pmi, bad)
    with pytest.raises(ValueError, match="thickness_mm"):
        implausible_tolerances(pmi, 300.0, thickness_mm=0.0)


def test_the_panel_tolerances_are_plausible_and_in_metres_they_are_not(tmp_path):
    from qifreport.step.reader import read_step
    from qifreport.step.semantic import read_pmi_text
    from qifreport.step.tessellate import shape_diagonal

    part = read_step(PANEL)
    diagonal = shape_diagonal(part.shape)
    assert 150.0 < diagonal < 250.0
    assert implausible_tolerances(part.pmi, diagonal, PANEL_WALL) == []
    # the same file with its tolerance units declared as metres (the shape's unit stays mm)
    text = PANEL.read_text()
    head, pmi_units = text.split("#1372 = ", 1)
    f = tmp_path / "panel_metres.step"
    f.write_text(
        head + "#1372 = " + pmi_units.replace("SI_UNIT(.MILLI.,.METRE.)", "SI_UNIT($,.METRE.)")
    )
    pmi = read_pmi_text(f)
    assert sorted(t.value for t in pmi.tolerances) == [200.0, 200.0, 500.0, 1000.0]
    reasons = implausible_tolerances(pmi, diagonal, PANEL_WALL)
    assert len(reasons) == 4
    assert all("diagonal" in r and "METRE" in r for r in reasons), reasons


@pytest.mark.slow
def test_cli_refuses_implausible_tolerances_unless_accepted(tmp_path):
    """The panel with its tolerance unit declared as metres (profiles of 1000 mm): exit 2 with
    one line naming the value and the flag; ``--accept-tolerance-as-read`` inspects it and
    records what was accepted."""
    text = PANEL.read_text()
    head, pmi_units = text.split("#1372 = ", 1)
    f = tmp_path / "panel_metres.step"
    f.write_text(
        head + "#1372 = " + pmi_units.replace("SI_UNIT(.MILLI.,.METRE.)", "SI_UNIT($,.METRE.)")
    )
    exe = Path(sys.executable).parent / "qifreport"
    scan = PANEL.parent / "panel_scan.ply"
    out = tmp_path / "o"
    r = subprocess.run(
        [str(exe), str(f), str(scan), "--out", str(out), "--quiet"], capture_output=True, text=True
    )
    err = r.stderr.strip()
    assert r.returncode == 2 and len(err.splitlines()) == 1, err
    assert "implausible tolerance" in err and "--accept-tolerance-as-read" in err
    assert "1000 mm" in err and not out.exists()
    r = subprocess.run(
        [
            str(exe),
            str(f),
            str(scan),
            "--out",
            str(out),
            "--quiet",
            "--json",
            "--no-pdf",
            "--accept-tolerance-as-read",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode in (0, 1, 3), r.stdout + r.stderr
    doc = json.loads((out / "panel_metres.json").read_text())
    assert len(doc["nominal"]["implausible_tolerances"]) == 4


def _ctc03_inch_numbers_under_mm(tmp_path: Path) -> Path:
    """NIST CTC 03 with its geometric tolerances' unit turned from its inch (#5918) into
    its millimetre conversion unit (#5917): the inch numbers stay, under a mm unit (an
    edition of that file was exported so)."""
    text = shared_file("step/nist/nist_ctc_03_asme1_ap242-e2.stp").read_text(errors="replace")
    magnitudes = set(re.findall(r"_TOLERANCE\('[^']*','[^']*',#(\d+)", text))
    assert len(magnitudes) == 13
    for i in magnitudes:
        text = re.sub(
            rf"#{i}=\((?:.|\n)*?\);", lambda m: m.group(0).replace(",#5918)", ",#5917)"), text
        )
    path = tmp_path / "ctc03_mm.stp"
    path.write_text(text)
    return path


def test_inch_numbers_under_a_mm_unit_are_refused_unless_accepted(tmp_path):
    """Tolerances 0.005-0.08 "mm" beside inch dimensions: the values are the drawing's inch
    numbers (0.127-2.03 mm). ``pmi`` and ``plan`` warn, the inspection refuses with one line
    naming the flag that reads them as stated; no shared NIST file is flagged."""
    from qifreport.step.plausibility import inch_numbers_under_mm
    from qifreport.step.semantic import read_pmi_text

    for name in NIST:
        assert inch_numbers_under_mm(read_pmi_text(shared_file(f"step/nist/{name}"))) == ""
    step = _ctc03_inch_numbers_under_mm(tmp_path)
    why = inch_numbers_under_mm(read_pmi_text(step))
    assert "13 geometric tolerances are stated in mm (0.005-0.08 mm)" in why
    assert "all 9 length dimensions are in inch" in why and "0.127-2.032 mm" in why
    r = subprocess.run([str(EXE), "pmi", str(step)], capture_output=True, text=True)
    assert r.returncode == 0 and "warning: the 13 geometric tolerances" in r.stdout
    r = subprocess.run(
        [str(EXE), "plan", str(step), "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert r.returncode == 0 and "25.4 times too tight" in r.stdout, r.stdout + r.stderr
    out = tmp_path / "o"
    scan = ROOT / "samples" / "shell_scan.ply"
    r = subprocess.run(
        [str(EXE), str(step), str(scan), "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
    )
    err = r.stderr.strip()
    assert r.returncode == 2 and len(err.splitlines()) == 1, err
    assert "inch numbers under a millimetre unit" in err and "--accept-tolerance-as-read" in err
    assert not out.exists()
