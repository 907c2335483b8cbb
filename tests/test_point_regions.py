"""The region criterion on the scan points (:mod:`qifreport.metrology.acceptance.point_regions`): a
defect narrower than the mesh is found where the scan samples it, a perfect surface gives
no region, a surface on its limit is not proven out, and a defect both samplings see is
reported once.

A 100 x 100 mm plate meshed with 8 mm edges (its vertices' deviation is fitted over a
12 mm ball) under a scan at 0.7 mm spacing with 10 um noise, the deviation measured by
the product's own functions (:func:`qifreport.metrology.deviation.closest.closest_points`,
:func:`~qifreport.metrology.deviation.local_planes.nominal_referenced`).
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.acceptance.criteria import Region, evaluate
from qifreport.metrology.acceptance.point_regions import SurfacePoints, scan_samples
from qifreport.metrology.deviation.closest import closest_points
from qifreport.metrology.deviation.local_planes import nominal_referenced
from tests.test_metrology import grid_mesh

NOISE = 0.01  # mm
TOL = 0.25  # mm, half-width
CENTRE = np.array([47.0, 51.0])  # between vertices of the 8 mm grid


def plate_scan(depth: float, sigma: float, seed: int = 2, offset: float = 0.0):
    """(V, F, P) of the plate and its scan: a Gaussian bump ``depth`` mm x ``sigma`` mm at
    :data:`CENTRE`, ``offset`` mm added everywhere (a face sitting away from nominal)."""
    V, F = grid_mesh(13, 13, 100.0 / 12)
    rng = np.random.default_rng(seed)
    g = np.arange(0.35, 100.0, 0.7)
    X, Y = np.meshgrid(g, g)
    xy = np.c_[X.ravel(), Y.ravel()] + rng.normal(0.0, 0.05, (X.size, 2))
    r2 = ((xy - CENTRE) ** 2).sum(axis=1)
    z = depth * np.exp(-r2 / (2.0 * sigma**2)) + offset + rng.normal(0.0, NOISE, len(xy))
    return V, F, np.c_[xy, z]


def judge(V, F, P, rule: str = "iso14253", center: float = 0.0, points: bool = True):
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    C, cface, pdev = closest_points(V, F, P)
    dev, var = nominal_referenced(V, F, P, normals=N, variance=True)
    s = scan_samples(V, F, P, pdev, C, cface, None)
    pts = SurfacePoints(
        s, np.flatnonzero(np.isfinite(s.value)), np.full(len(P), TOL), np.full(len(P), center)
    )
    return (
        evaluate(
            V,
            F,
            dev,
            TOL,
            center=center,
            uncertainty=2.0 * np.sqrt(var),
            decision_rule=rule,
            points=pts if points else None,
        ),
        dev,
    )


def test_a_bump_narrower_than_the_mesh_fails_on_the_points():
    """0.5 mm x sigma 3 mm stands beyond 0.25 mm over a disk of pi 2 sigma^2 ln 2 =
    39.2 mm^2 (> 25): the vertices read at most about 0.2 mm and pass; the points find the
    region, its area within 25 % and its centroid within 1 mm of the bump, proven out."""
    V, F, P = plate_scan(0.5, 3.0)
    on_vertices, dev = judge(V, F, P, points=False)
    assert np.nanmax(dev) < TOL and on_vertices.decision == "PASS"
    acc, _ = judge(V, F, P)
    assert acc.decision == "FAIL" and acc.proven_out
    r = acc.regions[0]
    assert r.sampling == "scan points" and r.sign == 1
    assert r.area == pytest.approx(2 * np.pi * 9.0 * np.log(2.0), rel=0.25)
    assert np.linalg.norm(r.centroid[:2] - CENTRE) < 1.0
    assert 0.4 < r.peak < 0.55
    assert np.linalg.norm(r.peak_at(V)[:2] - CENTRE) < 1.5
    assert "on the scan points" in acc.reasons[0]


def test_a_perfect_plate_and_one_on_its_limit():
    """Noise only: no region on either sampling. A face on the limit of a unilateral zone
    [0, 0.5] (centre 0.25): half its points read outside (one region over most of the
    plate), but no region of points is proven outside (band enlarged by each point's U at
    k = 4)
    larger than the 25 mm^2 limit: the points alone would not FAIL it."""
    V, F, P = plate_scan(0.0, 3.0)
    acc, _ = judge(V, F, P)
    assert acc.decision == "PASS" and not acc.regions
    C, cface, pdev = closest_points(V, F, P)
    s = scan_samples(V, F, P, pdev, C, cface, None)
    assert np.nanmedian(s.U) == pytest.approx(2.0 * 1.2533 * NOISE / 3.0, rel=0.2)
    idx = np.flatnonzero(np.isfinite(s.value))
    on_limit = SurfacePoints(s, idx, np.full(len(idx), TOL), np.full(len(idx), TOL))
    measured = on_limit.regions(0.0, Region)
    assert measured[0].area > 4000.0  # about half the plate's 10,000 mm^2, connected
    proven = on_limit.regions(1.0, Region)
    assert not proven or proven[0].area < 25.0
    assert on_limit.regions(-1.0, Region)[0].area > measured[0].area


def test_a_wide_defect_is_reported_once():
    """A 0.6 mm x sigma 12 mm bump: both samplings see it; one region, the larger."""
    V, F, P = plate_scan(0.6, 12.0)
    acc, _ = judge(V, F, P)
    both, _ = judge(V, F, P, points=False)
    assert acc.decision == "FAIL"
    near = [r for r in acc.regions if np.linalg.norm(r.centroid[:2] - CENTRE) < 10.0]
    assert len(near) == 1
    assert near[0].area >= both.regions[0].area
    assert abs(near[0].peak) >= abs(both.regions[0].peak)  # the larger peak of the two
    assert near[0].peak == pytest.approx(0.6, rel=0.03)
    # the analytic area beyond 0.25 mm: 2 pi sigma^2 ln(0.6 / 0.25) = 792 mm^2
    assert near[0].area == pytest.approx(2 * np.pi * 144.0 * np.log(0.6 / 0.25), rel=0.2)
