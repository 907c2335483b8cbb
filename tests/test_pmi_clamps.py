"""``qifreport pmi --clamps``: the clamps of a restrained inspection listed with the B-rep
face and datum feature each sits on (issue 21: "listed by qifreport pmi"), on the real
sample panel read by OCP."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).parent / "qifreport"
STEP = ROOT / "samples" / "panel.step"
CLAMPS = ROOT / "samples" / "panel_clamps.csv"


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([os.fsencode(EXE), *map(str, args)], capture_output=True, text=True)


def test_pmi_lists_the_clamps_on_their_datum_features():
    out = run("pmi", STEP, "--clamps", CLAMPS, "--max-clamp-force", "50", "--json")
    assert out.returncode == 0, out.stderr
    rows = {r["name"]: r for r in json.loads(out.stdout)["clamps"]}
    assert sorted(rows) == ["A1", "A2", "A3", "A4", "B1", "C1", "C2"]
    # the file's datums: A the flange undersides, B the left end face, C the front side face
    assert {k: rows[k]["datum"] for k in rows} == {
        "A1": "A",
        "A2": "A",
        "A3": "A",
        "A4": "A",
        "B1": "B",
        "C1": "C",
        "C2": "C",
    }
    assert all(r["off_surface_mm"] < 0.01 for r in rows.values())
    assert rows["A1"]["max_force_N"] == 20 and rows["B1"]["max_force_N"] == 50
    assert rows["C1"]["directions"] == "y" and rows["A2"]["directions"] == "n"
    text = run("pmi", STEP, "--clamps", CLAMPS)
    assert "7 clamp(s) from panel_clamps.csv" in text.stdout
    assert "B1" in text.stdout and "datum B feature" in text.stdout


def test_pmi_refuses_a_missing_clamps_file(tmp_path):
    out = run("pmi", STEP, "--clamps", tmp_path / "none.csv")
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "clamps file not found" in out.stderr
