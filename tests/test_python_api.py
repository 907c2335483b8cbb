"""The Python API (:mod:`qifreport.api`): the example in ``docs/python-api.md`` runs as it
stands, and the report it gives agrees with the command line on the same part and scan.

The real sample STEP read by OCP, real XSD validation of the QIF the API writes.
"""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import qifreport
from qifreport.errors import InputError
from tests.conftest import ROOT
from tests.nist_scans import run_cli

DOC = ROOT / "docs" / "python-api.md"


def test_the_documented_example_runs_and_writes_what_it_says(tmp_path):
    (tmp_path / "samples").symlink_to(ROOT / "samples")
    code = "\n".join(re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S))
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    assert lines[0] == "PASS" and lines[1] == "0"
    out = tmp_path / "out" / "api"
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "panel_SN-0042.json",
        "panel_SN-0042.pdf",
        "panel_SN-0042.qif",
        "panel_plan.qif",
    ]
    qif = (out / "panel_SN-0042.qif").read_text()
    assert "SN-0042" in qif and (out / "panel_SN-0042.pdf").read_bytes()[:5] == b"%PDF-"


def test_the_report_agrees_with_the_command_line(tmp_path):
    panel = ROOT / "samples" / "panel.step"
    scan = ROOT / "samples" / "panel_scan_defect.ply"
    doc = run_cli(panel, scan, tmp_path / "cli")
    report = qifreport.inspect(panel, scan, cache_dir=tmp_path / "cache")
    assert report.verdict == doc["verdict"] and report.exit_code == doc["_rc"]
    table = report.characteristics()
    keys = [z["key"] for z in doc["tolerances"]] + [c["key"] for c in doc["characteristics"]]
    assert list(table.key) == keys
    by_key = {z["key"]: z for z in doc["tolerances"]}
    for row in table[table.source == "zone"].itertuples():
        assert row.status == by_key[row.key]["verdict"]
        assert row.value_mm == pytest.approx(by_key[row.key]["deviation"]["max_abs"], abs=1e-9)
    mesh = report.deviation_mesh()
    dev = mesh.vertex_attributes["deviation"]
    assert isinstance(mesh, trimesh.Trimesh) and len(dev) == len(mesh.vertices)
    # every scored vertex's deviation is on the mesh (unscored ones too, or NaN)
    assert np.nanmax(np.abs(dev)) >= doc["vertex_deviation"]["max_abs"] - 1e-9
    state = report.write_qif(tmp_path / "api" / "panel.qif")
    assert state["valid"] is True


def test_an_array_scan_and_bad_calls(tmp_path):
    P = qifreport.read_scan(ROOT / "samples" / "shell_scan.ply")
    assert P.ndim == 2 and P.shape[1] == 3 and len(P) > 1000
    shell = ROOT / "samples" / "shell_nominal.ply"
    a = qifreport.inspect(shell, P, tolerance=0.5, cache_dir=None)
    b = qifreport.inspect(shell, ROOT / "samples" / "shell_scan.ply", tolerance=0.5, cache_dir=None)
    assert a.verdict == b.verdict
    assert a.summary()["vertex_deviation"]["rms"] == pytest.approx(
        b.summary()["vertex_deviation"]["rms"], rel=1e-9
    )
    with pytest.raises(TypeError, match="tolerence"):
        qifreport.inspect(shell, P, tolerence=0.5)
    with pytest.raises(InputError, match=r"\(m, 3\)"):
        qifreport.inspect(shell, P[:, :2], tolerance=0.5)
    with pytest.raises(InputError):
        qifreport.inspect(tmp_path / "missing.step", P)
