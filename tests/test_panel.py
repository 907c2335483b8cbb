"""The STEP demo panel, a thin solid (1.8 mm wall, about 3 mm of elastic free-state
deflection): the conforming scan passes and the injected defect fails the functional
skin's profile.

This is the regression test of the thin-solid fix: signed normal compatibility with
consistently oriented scan normals (the hidden back skin gets no data), the Laplacian energy
on closed solids (B-rep needle triangles degrade the Hessian energy), and the edge band along
sharp creases (not scored: the vertex normal there is the average of two faces).
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.inspection import InspectionInputs, InspectionParams, inspect
from qifreport.nominal import load_nominal
from qifreport.pipeline import part_inputs
from qifreport.registration.pointcloud import read_scan
from tests.conftest import ROOT

#: where samples/make_samples.py puts the defect (0.45 mm proud, sigma 6 mm) on the crown
DEFECT_AT = np.array([25.0, 10.0, 9.3])


@pytest.fixture(scope="module")
def panel_results():
    part, drawing = load_nominal(ROOT / "samples/panel.step", None)
    out = {}
    for name in ("panel_scan", "panel_scan_defect"):
        P = read_scan(ROOT / f"samples/{name}.ply").points
        out[name] = inspect(
            part.V,
            part.F,
            P,
            InspectionParams(),
            InspectionInputs(
                face_id=part.face_id, zones=drawing.zones, not_evaluated=drawing.not_evaluated
            ),
        )
    return out


def test_conforming_thin_solid_passes(panel_results):
    res = panel_results["panel_scan"]
    assert res.energy == "laplacian"  # a closed solid
    assert res.passed, res.decided_by()
    assert res.vertex_stats.rms < 0.06  # was 0.21 with |n . n_scan| and the Hessian energy
    assert not res.fit.fallback and res.fit.flagged_fraction < 0.05
    assert 0 < res.edge_excluded_area < 0.25 * res.acceptance.nominal_area


def test_defect_fails_the_functional_skin_where_it_was_put(panel_results):
    res = panel_results["panel_scan_defect"]
    assert not res.passed
    t1, t2 = res.zones[:2]
    assert t1.acceptance.passed and not t2.acceptance.passed
    top = t2.acceptance.regions[0]
    assert top.sign == +1 and top.area > 25.0
    assert np.linalg.norm(top.centroid - DEFECT_AT) < 3.0
    assert 0.25 < top.peak < 0.5  # 0.45 mm injected; the fixture keeps most of it


def test_posed_thin_solid_is_refused_not_misjudged(tmp_path):
    """The panel's scan delivered at the paper's pose: a one-sided scan of a 1.8 mm wall
    under 2.8 mm of deflection fits the inner skin better than the outer one (measured: rms
    0.43 against 0.62 mm), and seated there the outer skin's profile T2 would fail as 'not
    observed'. Which side was scanned is not in the points: the pose search must refuse
    (one line, exit 2, nothing written) instead of judging the wrong skin."""
    import subprocess
    import sys
    from pathlib import Path

    import trimesh
    from scipy.spatial.transform import Rotation

    P = read_scan(ROOT / "samples/panel_scan.ply").points
    R = Rotation.from_euler("xyz", (120.0, 45.0, 10.0), degrees=True).as_matrix()
    posed = tmp_path / "posed.ply"
    trimesh.PointCloud(P @ R.T + [300.0, -150.0, 80.0]).export(posed)
    out = tmp_path / "out"
    exe = Path(sys.executable).parent / "qifreport"
    r = subprocess.run(
        [str(exe), ROOT / "samples/panel.step", posed, "--out", out, "--json", "--quiet"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "wall" in lines[0] and "--prealign never" in lines[0], lines
    assert not out.exists() or not any(out.iterdir())


def test_half_the_scan_gives_the_same_verdict(panel_results):
    """Density invariance: a seeded random half of the scan's points (what a scanner set to
    a coarser pitch delivers) is judged as the full scan is, with the virtual fixture
    applied in both. The scan normals were fitted on each point's k nearest neighbours:
    on the half scan they mixed the wall's two skins or lay along one scan line, the fit
    lost a third of its data and the panel read RMS 0.073 mm, NOT ESTABLISHED."""
    part, drawing = load_nominal(ROOT / "samples/panel.step", None)
    P = read_scan(ROOT / "samples/panel_scan.ply").points
    rng = np.random.default_rng(0)
    half = P[np.sort(rng.choice(len(P), len(P) // 2, replace=False))]
    res = inspect(
        part.V,
        part.F,
        half,
        InspectionParams(always_fixture=True),
        InspectionInputs(
            face_id=part.face_id, zones=drawing.zones, not_evaluated=drawing.not_evaluated
        ),
    )
    full = panel_results["panel_scan"]
    assert res.passed == full.passed, res.decided_by()
    assert res.vertex_stats.rms < 0.045  # 0.073 with the k-neighbour normals
    assert res.fit.scale < 0.03  # the fit's robust residual: 0.067 before, 0.020 in full


def test_a_third_of_the_scan_gives_the_same_verdict(panel_results):
    """Density invariance at a third of the points (seeded), the virtual fixture applied.
    The refit passes flagged as defect candidates whatever exceeded 3 robust scales of
    their own residual (the scanner's noise): chance flags on the right flange's corner,
    5.6 mm withheld around each, left the fit unsupported there and G2 read 0.288 FAIL
    (0.146 in full); the thin wall's two skins merged in the scan-area estimate (69.6 %
    of the nominal against 81.4 % scored: an over-fit, NOT ESTABLISHED). On the elastic
    free state (about 3 mm of warp on the 1.8 mm wall) the scan's sheets were propagated
    over its 12-nearest normals, which at a third of the points reach 2.1 mm, across the
    wall: 67 % of them turned over 18 degrees, the scan fell into 13,026 sheets (142 in
    full), each sided by its nearest nominal vertex, on the other skin where the wall is
    deflected; the bottom skin of both flanges lost its data (859 vertices uncovered), the
    fit stopped at 1.9 mm of displacement (3.2 in full) and read 64.9 % in tolerance, FAIL.
    The sheets now follow the normals refitted on one skin at a length of the part."""
    part, drawing = load_nominal(ROOT / "samples/panel.step", None)
    P = read_scan(ROOT / "samples/panel_scan.ply").points
    rng = np.random.default_rng(0)
    third = P[np.sort(rng.choice(len(P), round(0.33 * len(P)), replace=False))]
    res = inspect(
        part.V, part.F, third, InspectionParams(always_fixture=True), part_inputs(part, drawing)
    )
    assert res.passed and panel_results["panel_scan"].passed, res.decided_by()
    # in the virtual fixture the rim bands are unscored, where datum target C2 lies: the
    # all-over profile |A|B|C| is not measured (never read best fit); the rest passes
    assert res.verdict == "NOT MEASURED"
    assert [w for w in res.not_measured() if "datum frame |A|B|C| not established" in w]
    g2 = next(c for c in res.characteristics if c.spec.key == "G2")
    assert g2.value < 0.16, g2.value  # 0.134; 0.288 before
    assert res.scan_area > 0.9 * 32214  # the full scan's; 23,017 with the skins merged
    # the fit follows the warp as in full: 3.29 mm against 3.26 (1.93 with the sheets
    # propagated over the 12-nearest normals)
    assert res.fit.max_displacement > 0.9 * panel_results["panel_scan"].fit.max_displacement
