"""A placement of the scan never changes a verdict. A compliant shell slides along itself at
almost no cost, so the rigid fit stops where its start leaves it: the conforming shell once
PASSed in the nominal frame and was NOT MEASURED turned and shifted (its nominal's corner
overhung the scan's rim by 4 mm: an unmeasured patch of 176 mm^2). The rim now decides the
slide (``metrology/stages/rim_seat.py``); a partial view, whose rim is seen over less than
half its length, is left where the rigid fit put it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qifreport.metrology.inspection import InspectionParams, inspect
from qifreport.simulate.cases import make_case
from qifreport.simulate.shapes import thin_shell


@pytest.fixture(scope="module")
def conforming():
    V, F = thin_shell()
    case = make_case(V, F, generator="analytic", amplitude=0.02, seed=1)
    return V, F, case.P


@pytest.mark.slow
def test_a_turned_and_shifted_conforming_shell_is_judged_as_in_the_nominal_frame(conforming):
    V, F, P = conforming
    params = InspectionParams(tolerance=0.5)
    here = inspect(V, F, P, params)
    R = Rotation.random(random_state=0).as_matrix()
    there = inspect(V, F, P @ R.T + np.array([37.0, -21.0, 55.0]), params)
    assert (here.verdict, there.verdict) == ("PASS", "PASS"), there.decided_by()
    assert abs(here.acceptance.coverage - there.acceptance.coverage) < 0.002
    assert abs(here.vertex_stats.rms - there.vertex_stats.rms) < 0.002
    # the slide the rim took back: about 1 mm from the nominal frame, 4 mm through the search
    assert 0.5 < np.linalg.norm(here.rim_seat["slide_mm"]) < 2.0, here.rim_seat
    assert 3.0 < np.linalg.norm(there.rim_seat["slide_mm"]) < 6.0, there.rim_seat


def test_a_corner_view_leaves_the_seat_to_the_rigid_fit(conforming):
    V, F, P = conforming
    d = np.linalg.norm(P[:, :2] - P.min(axis=0)[:2], axis=1)
    res = inspect(V, F, P[d <= np.quantile(d, 0.3)], InspectionParams(tolerance=0.5))
    assert res.rim_seat["rounds"] == 0 and res.rim_seat["slide_mm"] == [0.0, 0.0, 0.0]
    assert res.verdict == "NOT ESTABLISHED", res.decided_by()


@pytest.mark.slow
def test_a_turned_panel_scan_is_refused_not_judged_in_another_pose(tmp_path):
    """The panel sample's scan (a 1.8 mm wall, both skins) turned and shifted: the search
    finds two poses 180 deg apart that fit alike (the panel is nearly symmetric) and cannot
    tell the part's. It refuses (exit 2, one line naming both reasons) rather than judge
    the part in a pose it cannot back."""
    import subprocess
    import sys
    from pathlib import Path

    import trimesh

    from tests.conftest import ROOT

    P = np.asarray(trimesh.load(ROOT / "samples" / "panel_scan.ply").vertices)
    R = Rotation.from_euler("xyz", [35, -20, 110], degrees=True).as_matrix()
    scan = tmp_path / "turned.ply"
    trimesh.PointCloud(P @ R.T + np.array([120.0, -45.0, 300.0])).export(scan)
    exe = Path(sys.executable).with_name("qifreport")
    r = subprocess.run(
        [str(exe), str(ROOT / "samples" / "panel.step"), str(scan), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 2, r.stdout + r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert "1.80 mm wall" in line and "fits as well (a near-symmetric part)" in line, line
    assert "--prealign never" in line
    assert not list(tmp_path.glob("panel.*")), "no output of a refused run"
