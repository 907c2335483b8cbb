"""A scan too sparse to read its part decides nothing: the panel sample's scans thinned to
every 40th point (0.05 points/mm^2 against the 0.36 a 25 mm^2 region needs).

Thinned so, the conforming panel FAILed: two of its restraint pads were read from three or
four points each, on the far skin of the thin wall (-0.41 mm against +0.51 at full
density), and the hold bent the part into a 2,092 mm^2 region. A surface that fails the
density rule now neither passes nor fails (NOT MEASURED); at
full density the verdicts are unchanged (the demo's PASS and FAIL)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tests.conftest import ROOT

SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).with_name("qifreport")


def _thinned(name: str, out: Path, every: int = 40) -> Path:
    P = np.asarray(trimesh.load(SAMPLES / name).vertices)
    path = out / f"sparse_{name}"
    trimesh.PointCloud(P[::every]).export(path)
    return path


def _inspect(scan: Path, out: Path) -> tuple[int, dict]:
    r = subprocess.run(
        [str(EXE), str(SAMPLES / "panel.step"), str(scan), "--out", str(out), "--json"]
        + ["--no-pdf", "--no-qif"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode in (0, 1, 3), r.stderr
    return r.returncode, json.loads((out / "panel.json").read_text())


@pytest.mark.parametrize("name", ["panel_scan.ply", "panel_scan_defect.ply"])
def test_a_scan_too_sparse_to_read_the_part_decides_nothing(name, tmp_path):
    rc, doc = _inspect(_thinned(name, tmp_path), tmp_path / "out")
    assert rc == 3 and doc["verdict"] == "NOT MEASURED", doc["decided_by"]
    cov = doc["coverage"]["measured"]
    assert cov["points_per_mm2"] < 0.1 and cov["min_points_per_mm2"] == pytest.approx(0.36)
    assert any("scan too sparse" in r for r in cov["reasons"])
    for zone in doc["tolerances"]:
        assert zone["verdict"] in ("NOT MEASURED", "REPORTED"), zone["key"]
