"""Tests of metrology: signed deviations, statistics, acceptance criteria, scan area."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point as triangle_closest_point

from qifreport.metrology.acceptance.criteria import (
    DEFAULT_MAX_REGION_AREA,
    evaluate,
    find_regions,
)
from qifreport.metrology.acceptance.scan_area import coverage_ceiling_ok, scan_area
from qifreport.metrology.acceptance.statistics import deviation_statistics, tail_fractions
from qifreport.metrology.deviation.closest import closest_points, data_referenced
from qifreport.metrology.deviation.local_planes import nominal_referenced
from qifreport.registration.mesh import vertex_areas


def grid_mesh(nx: int, ny: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Planar grid z = 0, vertex (i, j) = index j * nx + i; every quad split along v00-v11.

    Triangles are counter-clockwise seen from +z (outward normal +z).
    """
    x, y = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h)
    V = np.c_[x.ravel(), y.ravel(), np.zeros(nx * ny)]
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    v00 = (j * nx + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + nx, v00 + nx + 1
    F = np.concatenate([np.c_[v00, v10, v11], np.c_[v00, v11, v01]]).astype(np.int64)
    return V, F


def brute_distance(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    T = V[F]
    out = np.empty(len(P))
    for i, p in enumerate(P):
        C = triangle_closest_point(T, np.repeat(p[None], len(F), axis=0))
        out[i] = np.linalg.norm(C - p, axis=1).min()
    return out


# ----------------------------------------------------------------------------- deviation


def test_closest_points_plane_exact_and_signed():
    rng = np.random.default_rng(0)
    V, F = grid_mesh(21, 21, 1.0)
    V[:, :2] += rng.uniform(-0.2, 0.2, (len(V), 2))  # irregular in-plane, still flat
    P = np.c_[rng.uniform(1, 19, 2000), rng.uniform(1, 19, 2000), rng.normal(0, 1.0, 2000)]
    C, face, signed = closest_points(V, F, P)
    assert np.abs(signed - P[:, 2]).max() < 1e-9
    assert np.abs(C[:, 2]).max() < 1e-9
    assert np.abs(C[:, :2] - P[:, :2]).max() < 1e-9
    # the reported face contains the closest point
    assert face.dtype == np.int64
    bary = trimesh.triangles.points_to_barycentric(V[F[face]], C)
    assert bary.min() > -1e-9
    assert np.array_equal(data_referenced(V, F, P), signed)
    # a non-finite point gets NaN without disturbing the others
    P[5] = np.nan
    _, face, signed2 = closest_points(V, F, P)
    assert np.isnan(signed2[5]) and face[5] == -1
    assert np.array_equal(np.delete(signed2, 5), np.delete(signed, 5))


def test_closest_points_sphere_sign_and_exactness():
    rng = np.random.default_rng(1)
    tm = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    V, F = np.asarray(tm.vertices), np.asarray(tm.faces, dtype=np.int64)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.uniform(5.0, 15.0, 3000)
    P = d * r[:, None]
    _, _, signed = closest_points(V, F, P)
    # the polyhedron lies within 0.1 mm of the sphere (sagitta of 0.6 mm edges)
    sagitta = 10.0 - np.linalg.norm(V[F].mean(axis=1), axis=1).min()
    assert np.abs(signed - (r - 10.0)).max() <= sagitta + 1e-9
    far = np.abs(r - 10.0) > sagitta
    assert np.all(np.sign(signed[far]) == np.sign(r[far] - 10.0))
    # exact against brute force on a subset
    sub = slice(0, 150)
    assert np.abs(np.abs(signed[sub]) - brute_distance(V, F, P[sub])).max() < 1e-12


def test_closest_points_agrees_with_trimesh():
    rng = np.random.default_rng(2)
    tm = trimesh.creation.annulus(r_min=3.0, r_max=10.0, height=5.0, sections=24)
    V, F = np.asarray(tm.vertices), np.asarray(tm.faces, dtype=np.int64)
    P = rng.uniform(-12, 12, (2000, 3))
    C, _, signed = closest_points(V, F, P)
    C2, dist2, _ = trimesh.proximity.closest_point(tm, P)
    # trimesh's own search carries ~1e-7 mm of tolerance slack; ours is exact
    assert np.abs(np.abs(signed) - dist2).max() < 1e-6
    assert np.all((signed < 0) == tm.contains(P))


def test_closest_points_fallback_with_large_triangles():
    """A 12-triangle box next to a fine sphere: the 3 nearest vertices are often the wrong
    ones, so the certified fallback must find the far box face."""
    rng = np.random.default_rng(3)
    box = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=3.0)
    ball.apply_translation([0.0, 0.0, 26.0])  # just above the top face (z = 20)
    tm = trimesh.util.concatenate([box, ball])
    V, F = np.asarray(tm.vertices), np.asarray(tm.faces, dtype=np.int64)
    P = np.c_[rng.uniform(-8, 8, 300), rng.uniform(-8, 8, 300), rng.uniform(19, 21.5, 300)]
    _, _, signed = closest_points(V, F, P)
    assert np.abs(np.abs(signed) - brute_distance(V, F, P)).max() < 1e-12
    top = np.abs(P[:, 2] - 20.0) < 1.0  # these are nearest to the box top
    assert np.all(np.sign(signed[top]) == np.sign(P[top, 2] - 20.0))


def test_closest_points_sign_at_sharp_ridge():
    """Points in the normal cone of a sharp ridge are outside; a face-normal sign fails."""
    # tent z = -3 |x| over a strip, outward normal up: ridge along y at x = 0
    xs = np.array([-2.0, 0.0, 2.0])
    ys = np.linspace(0.0, 10.0, 11)
    X, Y = np.meshgrid(xs, ys)
    V = np.c_[X.ravel(), Y.ravel(), -3.0 * np.abs(X.ravel())]
    V, F = _strip_faces(V, len(xs), len(ys))
    nA = np.array([-3.0, 0.0, 1.0]) / np.sqrt(10.0)  # normal of the x < 0 side
    nB = np.array([3.0, 0.0, 1.0]) / np.sqrt(10.0)
    assert nA @ nB < -0.7
    rng = np.random.default_rng(4)
    w = rng.uniform(0.02, 0.98, 400)
    d = w[:, None] * nA + (1 - w[:, None]) * nB
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    base = np.c_[np.zeros(400), rng.uniform(2, 8, 400), np.zeros(400)]
    P = base + rng.uniform(0.1, 1.0, (400, 1)) * d
    C, _, signed = closest_points(V, F, P)
    assert np.abs(C[:, 0]).max() < 1e-9  # the closest point is on the ridge
    assert np.all(signed > 0)
    _, _, inner = closest_points(V, F, base - 0.5 * np.array([0.0, 0.0, 1.0]))
    assert np.all(inner < 0)


def _strip_faces(V: np.ndarray, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    v00 = (j * nx + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + nx, v00 + nx + 1
    F = np.concatenate([np.c_[v00, v10, v11], np.c_[v00, v11, v01]]).astype(np.int64)
    return V, F


def test_nominal_referenced_offset_plane_and_unscored():
    rng = np.random.default_rng(5)
    V, F = grid_mesh(41, 41, 1.5)  # 60 x 60 mm, median edge 1.5 mm
    m = 12000  # 5 points / mm^2 over the scanned 60 x 40 mm
    P = np.c_[rng.uniform(0, 60, m), rng.uniform(0, 40, m), 0.3 + rng.normal(0, 0.02, m)]
    dev = nominal_referenced(V, F, P)
    radius = 1.5 * 1.5
    scored = ~np.isnan(dev)
    x, y = V[:, 0], V[:, 1]
    inner = (x >= radius) & (x <= 60 - radius) & (y >= radius) & (y <= 40 - radius)
    assert np.all(scored[inner])
    assert np.abs(dev[inner] - 0.3).max() < 0.01
    # the scan's edge rows are mostly scored too (half-disk neighbourhoods, centroid offset
    # 0.42 radius against the 0.5 limit, so sampling scatter drops a few), a little noisier
    assert scored[(y <= 40.0) & (x > 0) & (x < 60)].mean() > 0.95
    assert np.abs(dev[scored] - 0.3).max() < 0.05
    # beyond the scan edge: unscored, not extrapolated
    assert not np.any(scored[y > 40.0 + 0.5 * radius])
    # reversed winding flips the outward normal and so the sign
    dev_rev = nominal_referenced(V, F[:, ::-1], P)
    assert np.abs(dev_rev[inner] + 0.3).max() < 0.01
    # the scan's own tree, given (the inspection's, built once): the same field, bit for
    # bit, and it is the tree that is searched (one of the scan moved 1 m away: no partner)
    both = nominal_referenced(V, F, P, variance=True)
    given = nominal_referenced(V, F, P, variance=True, tree=cKDTree(P))
    assert all(np.array_equal(u, v, equal_nan=True) for u, v in zip(both, given, strict=True))
    assert np.isnan(nominal_referenced(V, F, P, tree=cKDTree(P + [1000.0, 0.0, 0.0]))).all()


def test_nominal_referenced_intersects_tilted_plane():
    """On a tilted scan the deviation is where the normal line meets the local plane; at
    the scan edge a centroid offset (c - v).n would be biased by slope x centroid shift."""
    rng = np.random.default_rng(6)
    V, F = grid_mesh(31, 21, 1.5)
    m = 8000
    xy = np.c_[rng.uniform(0, 7.5, m), rng.uniform(0, 30, m)]
    P = np.c_[xy, 0.3 + 0.2 * xy[:, 0] + rng.normal(0, 0.01, m)]  # deviation up to 1.8 mm
    dev = nominal_referenced(V, F, P)
    scored = ~np.isnan(dev)
    expected = 0.3 + 0.2 * V[:, 0]
    edge = scored & (V[:, 0] == 7.5)
    assert scored.sum() >= 100 and edge.sum() >= 15
    assert np.abs(dev[scored] - expected[scored]).max() < 0.02


def test_nominal_referenced_deep_dent_needs_cylinder():
    """A deviation beyond the search radius is unscored with the ball neighbourhood and
    measured with the cylinder (max_distance)."""
    rng = np.random.default_rng(12)
    V, F = grid_mesh(21, 21, 1.5)
    m = 8000
    P = np.c_[rng.uniform(0, 30, m), rng.uniform(0, 30, m), -3.0 + rng.normal(0, 0.02, m)]
    assert np.all(np.isnan(nominal_referenced(V, F, P)))
    dev = nominal_referenced(V, F, P, max_distance=5.0)
    inner = np.all((V[:, :2] >= 2.25) & (V[:, :2] <= 27.75), axis=1)
    assert np.abs(dev[inner] + 3.0).max() < 0.01


# ---------------------------------------------------------------------------- statistics


def test_statistics_hand_values():
    dev = np.array([1.0, -2.0, 3.0, -4.0, np.nan])
    s = deviation_statistics(dev, threshold=2.5)
    assert s.n == 4 and not s.weighted
    assert s.rms == pytest.approx(np.sqrt(30.0 / 4.0), abs=1e-15)
    assert s.mean == pytest.approx(-0.5, abs=1e-15)
    assert (s.max_abs, s.max_pos, s.min_neg) == (4.0, 3.0, -4.0)
    assert (s.frac_above, s.frac_below, s.frac_beyond) == (0.25, 0.25, 0.5)
    assert s.p95 == 4.0
    json.dumps(s.to_dict(), allow_nan=False)


def test_statistics_percentiles_match_inverted_cdf():
    rng = np.random.default_rng(7)
    for n in (1, 2, 7, 20, 101, 1000):
        dev = rng.normal(0, 0.1, n)
        a = np.abs(dev)
        ref = np.percentile(a, [95, 99, 99.9], method="inverted_cdf")
        s = deviation_statistics(dev)
        assert (s.p95, s.p99, s.p999) == tuple(ref)
        w = deviation_statistics(dev, weights=np.full(n, 0.731))  # equal weights
        assert (w.p95, w.p99, w.p999) == tuple(ref)
        assert w.rms == pytest.approx(s.rms, rel=1e-12)


def test_statistics_weight_two_equals_duplicate():
    rng = np.random.default_rng(8)
    dev = rng.normal(0, 0.2, 300)
    dev[::17] = np.nan
    w = np.where(rng.random(300) < 0.4, 2.0, 1.0)
    dup = np.concatenate([dev, dev[w == 2.0]])
    a = deviation_statistics(dev, weights=w, threshold=0.25)
    b = deviation_statistics(dup, threshold=0.25)
    assert a.weighted and a.n == int((~np.isnan(dev)).sum())
    for key in ("rms", "mean", "frac_above", "frac_below", "frac_beyond"):
        assert getattr(a, key) == pytest.approx(getattr(b, key), rel=1e-12, abs=1e-15)
    for key in ("p95", "p99", "p999", "max_abs", "max_pos", "min_neg"):
        assert getattr(a, key) == getattr(b, key)
    fa = tail_fractions(dev, [0.1, 0.3], weights=w)
    fb = tail_fractions(dup, [0.1, 0.3])
    assert fa.keys() == {0.1, 0.3}
    assert fa[0.1] == pytest.approx(fb[0.1], rel=1e-12)
    assert fa[0.3] == pytest.approx(fb[0.3], rel=1e-12)


def test_statistics_area_weighting_changes_result():
    dev = np.array([0.0, 1.0])
    s = deviation_statistics(dev, weights=np.array([3.0, 1.0]), threshold=0.5)
    assert s.mean == pytest.approx(0.25)
    assert s.rms == pytest.approx(0.5)
    assert s.frac_beyond == pytest.approx(0.25)
    assert s.p95 == 1.0 and deviation_statistics(dev, weights=[3.0, 1.0]).p95 == 1.0
    assert deviation_statistics(np.array([0.0, 0.0, 0.0, 1.0])).p95 == 1.0


def test_statistics_empty():
    for dev in (np.array([]), np.array([np.nan, np.nan])):
        s = deviation_statistics(dev, threshold=1.0)
        assert s.n == 0 and np.isnan(s.rms) and np.isnan(s.p999) and np.isnan(s.frac_beyond)
        d = s.to_dict()
        assert d["rms"] is None and d["n"] == 0
        json.dumps(d, allow_nan=False)
    assert np.isnan(tail_fractions(np.array([]), [1.0])[1.0])


# ---------------------------------------------------------------------------- acceptance


def test_two_blobs_two_regions_with_areas_and_centroids():
    V, F = grid_mesh(30, 30, 1.0)
    A = vertex_areas(V, F)
    dev = np.zeros(len(V))
    ij = np.c_[np.arange(len(V)) % 30, np.arange(len(V)) // 30]
    blob1 = (np.abs(ij[:, 0] - 6) <= 2) & (np.abs(ij[:, 1] - 6) <= 2)  # 5 x 5 vertices
    blob2 = (np.abs(ij[:, 0] - 20) <= 1) & (np.abs(ij[:, 1] - 22) <= 1)  # 3 x 3
    dev[blob1] = 0.8
    dev[blob2] = -0.9
    dev[np.flatnonzero(blob2)[4]] = -1.4  # the peak
    dev[0] = np.nan  # unscored is never out
    regions = find_regions(V, F, dev, 0.5)
    assert len(regions) == 2
    r1, r2 = regions
    assert r1.area == pytest.approx(A[blob1].sum(), rel=1e-12)
    assert r2.area == pytest.approx(A[blob2].sum(), rel=1e-12)
    assert r1.area == pytest.approx(25.0) and r2.area == pytest.approx(9.0)
    assert np.allclose(r1.centroid, [6.0, 6.0, 0.0]) and np.allclose(r2.centroid, [20, 22, 0])
    assert (r1.sign, r2.sign) == (1, -1)
    assert r2.peak == -1.4 and r2.peak_vertex == np.flatnonzero(blob2)[4]
    assert np.array_equal(r1.vertices, np.flatnonzero(blob1))
    d = r1.to_dict()
    assert d["n_vertices"] == 25 and "vertices" not in d
    json.dumps(d, allow_nan=False)


def test_regions_follow_mesh_edges_not_diagonals():
    """Connectivity is the triangulation's: the grid's quads are split along (i, j)-(i+1, j+1),
    so a pair touching along that diagonal is one region, the other diagonal two."""
    V, F = grid_mesh(10, 10, 1.0)
    dev = np.zeros(len(V))
    dev[[3 * 10 + 3, 4 * 10 + 4]] = 1.0  # (3,3)-(4,4): a mesh edge
    assert len(find_regions(V, F, dev, 0.5)) == 1
    dev[:] = 0.0
    dev[[3 * 10 + 4, 4 * 10 + 3]] = 1.0  # (4,3)-(3,4): no edge between them
    assert len(find_regions(V, F, dev, 0.5)) == 2
    # proud and sunk vertices that touch are one region, signed by the peak
    dev[:] = 0.0
    dev[[5 * 10 + 5, 5 * 10 + 6]] = [0.7, -0.9]
    (r,) = find_regions(V, F, dev, 0.5)
    assert r.sign == -1 and r.peak == -0.9
    # an unscored vertex breaks the connection
    dev[:] = 0.0
    dev[[2 * 10 + 2, 2 * 10 + 4]] = 1.0
    dev[2 * 10 + 3] = np.nan
    assert len(find_regions(V, F, dev, 0.5)) == 2


def test_per_vertex_tolerance():
    V, F = grid_mesh(20, 20, 1.0)
    dev = np.zeros(len(V))
    left, right = 5 * 20 + 4, 5 * 20 + 15
    dev[[left, right]] = 0.8
    tol = np.full(len(V), 0.5)
    tol[right] = 1.0  # a looser band on that feature
    regions = find_regions(V, F, dev, tol)
    assert [r.peak_vertex for r in regions] == [left]
    acc = evaluate(V, F, dev, tol)
    assert len(acc.regions) == 1
    d = acc.to_dict()
    assert d["tolerance"] is None and d["tolerance_min"] == 0.5 and d["tolerance_max"] == 1.0
    with pytest.raises(ValueError):
        find_regions(V, F, dev, np.ones(3))


def test_area_criterion_boundary():
    V, F = grid_mesh(40, 25, 1.0)  # 1000 vertices
    area = np.ones(len(V))
    rng = np.random.default_rng(9)
    order = rng.permutation(len(V))
    for n_out, ok in ((50, True), (51, False)):  # 95.0 % passes, 94.9 % fails
        dev = np.zeros(len(V))
        dev[order[:n_out]] = 1.0
        acc = evaluate(V, F, dev, 0.5, area=area, max_region_area=np.inf)
        assert acc.in_tolerance_fraction == pytest.approx(1 - n_out / 1000, abs=1e-15)
        assert acc.area_ok is ok and acc.passed is ok and acc.region_ok
        assert bool(acc.reasons) is (not ok)
    assert "94.9 %" in acc.reasons[0]
    # unscored vertices are out of the scored area, not out of tolerance
    dev = np.full(len(V), np.nan)
    dev[:100] = 0.0
    acc = evaluate(V, F, dev, 0.5, area=area)
    assert acc.passed and acc.scored_area == 100 and acc.coverage == pytest.approx(0.1)


def test_no_scored_vertex_fails():
    V, F = grid_mesh(5, 5, 1.0)
    acc = evaluate(V, F, np.full(len(V), np.nan), 0.5)
    assert not acc.passed and acc.scored_area == 0 and acc.reasons
    json.dumps(acc.to_dict(), allow_nan=False)


def test_gaussian_bump_fails_region_not_area():
    """A 1 mm bump, sigma 7 mm (paper convention a exp(-r^2 / sigma^2)), on a 1.5 mm grid:
    |dev| > 0.5 on a disk of pi sigma^2 ln 2 = 107 mm^2, under 1 % of the part."""
    V, F = grid_mesh(81, 81, 1.5)  # 120 x 120 mm
    c = np.array([60.4, 59.3, 0.0])
    r2 = ((V - c) ** 2).sum(axis=1)
    rng = np.random.default_rng(10)
    dev = 1.0 * np.exp(-r2 / 7.0**2) + rng.normal(0, 0.05, len(V))
    acc = evaluate(V, F, dev, 0.5)
    assert len(acc.regions) == 1
    (r,) = acc.regions
    assert 60.0 <= r.area <= 160.0
    assert np.linalg.norm(r.centroid - c) < 1.0
    assert r.sign == 1 and r.peak > 0.9
    assert acc.area_ok and not acc.region_ok and not acc.passed
    assert acc.largest_region_area == r.area > DEFAULT_MAX_REGION_AREA
    assert acc.reasons[0].startswith(f"region of {r.area:.1f} mm^2 at (")
    assert "exceeds 25.0 mm^2" in acc.reasons[0]
    json.dumps(acc.to_dict(), allow_nan=False)


# ----------------------------------------------------------------------- area and ceiling


def _lattice_plane(L: float, W: float, s: float, angle: float, offset: float, rng):
    n = int(2 * max(L, W) / s) + 4
    i, j = np.meshgrid(np.arange(-n, n), np.arange(-n, n))
    g = np.c_[i.ravel(), j.ravel()] * s + offset
    c, sn = np.cos(angle), np.sin(angle)
    g = g @ np.array([[c, -sn], [sn, c]]).T
    g = g[(g[:, 0] >= 0) & (g[:, 0] <= L) & (g[:, 1] >= 0) & (g[:, 1] <= W)]
    return np.c_[g, rng.normal(0, 0.02, len(g))]


def test_scan_area_independent_of_overlap():
    rng = np.random.default_rng(11)
    true = 60.0 * 50.0
    view1 = _lattice_plane(60, 50, 1.0, 0.0, 0.0, rng)
    view2 = _lattice_plane(60, 50, 1.0, 0.45, 0.3, rng)  # another view, rotated grid
    for P in (view1, np.r_[view1, view2], np.r_[view1, view1]):
        assert abs(scan_area(P) / true - 1) < 0.10
    # random (Poisson) sampling on a sphere, one view and two overlapping views
    R = 20.0
    true = 4 * np.pi * R**2
    d = rng.normal(size=(10000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    one = d[:5000] * R
    two = np.r_[one, d[5000:] * (R + rng.normal(0, 0.02, (5000, 1)))]
    a1, a2 = scan_area(one), scan_area(two)
    assert abs(a1 / true - 1) < 0.10 and abs(a2 / true - 1) < 0.10
    # half the sphere
    assert abs(scan_area(two[two[:, 2] > 0]) / (true / 2) - 1) < 0.10


def test_scan_area_keeps_the_two_skins_of_a_thin_wall_apart():
    """A 1.5 mm wall seen from both sides at 1.2 mm point spacing (sparser than the wall is
    thick): without normals the far skin's points share each cell of the near skin's and
    the area reads about half the two skins' (a sparse scan of a thin part then looked
    over-fitted); with the signed normals each skin keeps its own cells."""
    rng = np.random.default_rng(5)
    true = 2 * 60.0 * 50.0
    top = _lattice_plane(60, 50, 1.2, 0.3, 0.0, rng) + [0.0, 0.0, 1.5]
    bottom = _lattice_plane(60, 50, 1.2, 0.8, 0.5, rng)
    P = np.r_[top, bottom]
    N = np.r_[np.tile([0.0, 0.0, 1.0], (len(top), 1)), np.tile([0.0, 0.0, -1.0], (len(bottom), 1))]
    assert scan_area(P) / true < 0.75  # the skins merged (0.64)
    # each skin as if scanned alone (both read 6 % over the patch: its boundary's share)
    alone = scan_area(top) + scan_area(bottom)
    assert abs(scan_area(P, normals=N) / alone - 1) < 0.01
    assert abs(alone / true - 1) < 0.08


def test_coverage_ceiling():
    assert coverage_ceiling_ok(0.50, 600.0, 1000.0)
    assert coverage_ceiling_ok(0.63, 600.0, 1000.0)  # 0.6 * 1.05
    assert not coverage_ceiling_ok(0.64, 600.0, 1000.0)
    assert not coverage_ceiling_ok(0.61, 600.0, 1000.0, slack=0.0)
    with pytest.raises(ValueError):
        coverage_ceiling_ok(0.5, 1.0, 0.0)
