"""Form by the minimum zone (metrology/gdt/form.py; issue 22): flatness, straightness, roundness,
cylindricity against closed forms, an independent search, and scikit-spatial's
least-squares fits."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from qifreport.metrology.gdt.form import (
    cylindricity,
    flatness,
    least_squares_circle,
    least_squares_cylinder,
    least_squares_plane,
    roundness,
    straightness,
)

RNG = np.random.default_rng(22)


def _posed(X: np.ndarray, seed: int) -> np.ndarray:
    """``X`` (m, 3) turned and moved somewhere arbitrary."""
    R = Rotation.random(random_state=seed).as_matrix()
    return X @ R.T + np.array([120.0, -35.0, 410.0])


def test_flatness_of_a_cubic_warp_is_chebyshevs():
    """w = k u^3 on [-L, L]: the minimum zone tilts to Chebyshev's T3 and is 0.5 k L^3
    (0.05 mm); the least-squares plane leaves about 0.8 k L^3."""
    L, k = 50.0, 0.05 / 50.0**3 * 2
    u, v = np.meshgrid(np.linspace(-L, L, 101), np.linspace(-20, 20, 21))
    X = np.c_[u.ravel(), v.ravel(), k * u.ravel() ** 3]
    fit = flatness(_posed(X, 1))
    assert fit.minimum_zone == pytest.approx(0.5 * k * L**3, abs=2e-5)
    # least squares on this grid: the slope sum(u^4) / sum(u^2) (0.8 k L^3 as the grid fills)
    g = u.ravel()
    ls = np.ptp(k * (g**3 - g * np.sum(g**4) / np.sum(g**2)))
    assert fit.least_squares == pytest.approx(ls, abs=1e-7)  # (orthogonal vs vertical)
    assert 0.77 < fit.least_squares / (k * L**3) < 0.8
    # the residuals span the zone, symmetric about its middle
    assert np.ptp(fit.residuals) == pytest.approx(fit.minimum_zone, abs=1e-12)


def _search_flatness(P: np.ndarray) -> float:
    """An independent minimum zone: the narrowest slab over plane normals (Nelder-Mead
    on two angles from many starts), no linear programme."""
    c = P.mean(axis=0)

    def width(ang):
        t, p = ang
        n = np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
        return float(np.ptp((P - c) @ n))

    _, n0 = least_squares_plane(P)
    t0, p0 = np.arccos(np.clip(n0[2], -1, 1)), np.arctan2(n0[1], n0[0])
    best = np.inf
    for dt, dp in RNG.normal(0, 0.01, (12, 2)):
        r = minimize(
            width,
            [t0 + dt, p0 + dp],
            method="Nelder-Mead",
            options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000},
        )
        best = min(best, r.fun)
    return best


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_flatness_matches_an_independent_search(seed):
    """A bumpy, noisy patch (sinusoids and two dents): the programme's zone equals the
    narrowest slab a direct search over normals finds, within 0.1 um, and is narrower than
    least squares."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-30, 30, (800, 2))
    w = (
        0.02 * np.sin(uv[:, 0] / 7.0)
        + 0.01 * np.cos(uv[:, 1] / 5.0 + 1.0)
        - 0.03 * np.exp(-((uv[:, 0] - 10) ** 2 + uv[:, 1] ** 2) / 20.0)
        + rng.normal(0, 0.002, len(uv))
    )
    P = _posed(np.c_[uv, w], seed)
    fit = flatness(P)
    assert fit.minimum_zone == pytest.approx(_search_flatness(P), abs=1e-4)
    assert fit.minimum_zone <= fit.least_squares + 1e-12


def test_least_squares_plane_agrees_with_scikit_spatial():
    from skspatial.objects import Plane

    P = _posed(np.c_[RNG.uniform(-20, 20, (300, 2)), RNG.normal(0, 0.05, 300)], 7)
    o, n = least_squares_plane(P)
    ref = Plane.best_fit(P)
    assert abs(abs(n @ np.asarray(ref.normal)) - 1) < 1e-12
    assert abs((np.asarray(ref.point) - o) @ n) < 1e-9


def test_straightness_of_a_cubic_line():
    L, k = 40.0, 0.03 / 40.0**3
    u = np.linspace(-L, L, 401)
    c, s = np.cos(0.7), np.sin(0.7)
    Q = np.c_[u, k * u**3] @ np.array([[c, s], [-s, c]]) + np.array([5.0, -8.0])
    fit = straightness(Q)
    assert fit.minimum_zone == pytest.approx(0.5 * k * L**3, abs=1e-6)
    assert fit.least_squares == pytest.approx(
        np.ptp(k * (u**3 - u * np.sum(u**4) / np.sum(u**2))), abs=1e-7
    )


@pytest.mark.parametrize("lobes", [2, 3, 5])
def test_roundness_of_a_lobed_circle_is_twice_its_lobe(lobes):
    """r = R + A cos(k theta) about an offset centre: the minimum radial zone is 2 A
    whatever the centre the least-squares fit starts from."""
    R, A = 12.0, 0.01
    t = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    r = R + A * np.cos(lobes * t)
    Q = np.c_[r * np.cos(t), r * np.sin(t)] + np.array([3.0, -4.0])
    fit = roundness(Q)
    assert fit.minimum_zone == pytest.approx(2 * A, abs=1e-7)
    assert np.linalg.norm(fit.origin - [3.0, -4.0]) < 1e-6
    assert fit.radius == pytest.approx(R, abs=1e-7)


def test_roundness_is_narrower_than_least_squares_on_a_one_sided_flat():
    """A circle with a flat ground on one side: the least-squares centre is pulled off
    and reads a wider zone than the minimum zone; the zone matches a direct search."""
    R = 10.0
    t = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    P = np.c_[R * np.cos(t), R * np.sin(t)]
    P[:, 0] = np.minimum(P[:, 0], R - 0.05)  # a 0.05 mm flat
    fit = roundness(P)

    def width(c):
        return float(np.ptp(np.linalg.norm(P - c, axis=1)))

    best = min(
        minimize(width, x0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-13}).fun
        for x0 in RNG.normal(0, 0.01, (10, 2))
    )
    assert fit.minimum_zone == pytest.approx(best, abs=2e-6)
    assert fit.least_squares > fit.minimum_zone + 5e-5  # 0.1 um of 50 here


def test_least_squares_circle_agrees_with_scikit_spatial():
    from skspatial.objects import Circle

    t = RNG.uniform(0, 2 * np.pi, 200)
    Q = np.c_[7 + 20 * np.cos(t), -2 + 20 * np.sin(t)] + RNG.normal(0, 0.02, (200, 2))
    c, r = least_squares_circle(Q)
    ref = Circle.best_fit(Q)
    assert np.linalg.norm(c - np.asarray(ref.point)) < 1e-5
    assert r == pytest.approx(ref.radius, abs=1e-5)

    # ours minimises the orthogonal residuals: never more than the reference leaves
    def ss(c, r):
        return float(np.sum((np.linalg.norm(Q - c, axis=1) - r) ** 2))

    assert ss(c, r) <= ss(np.asarray(ref.point), ref.radius) + 1e-12


def _cylinder_points(R, A, lobes, length, seed, taper=0.0, around=180, along=41):
    t, z = np.meshgrid(
        np.linspace(0, 2 * np.pi, around, endpoint=False), np.linspace(0, length, along)
    )
    t, z = t.ravel(), z.ravel()
    r = R + A * np.cos(lobes * t) + taper * (z / length - 0.5)
    return _posed(np.c_[r * np.cos(t), r * np.sin(t), z], seed)


def test_cylindricity_of_a_lobed_and_of_a_tapered_cylinder():
    """Three lobes of 5 um: the zone is 10 um; a 20 um taper over the length adds to it
    (a cone is not a cylinder); each from a start 0.3 mm and 1 deg off."""
    seed, R, L = 11, 8.0, 40.0
    Rm = Rotation.random(random_state=seed).as_matrix()
    axis = Rm[:, 2]
    origin = np.array([120.0, -35.0, 410.0])
    off = Rotation.from_rotvec(np.radians(1.0) * Rm[:, 0]).apply(axis)
    start = (origin + 0.3 * Rm[:, 1], off, R + 0.1)
    fit = cylindricity(_cylinder_points(R, 0.005, 3, L, seed), *start)
    assert fit.minimum_zone == pytest.approx(0.010, abs=2e-6)
    assert abs(fit.direction @ axis) == pytest.approx(1.0, abs=1e-10)
    conical = cylindricity(_cylinder_points(R, 0.0, 3, L, seed, taper=0.02), *start)
    assert conical.minimum_zone == pytest.approx(0.02, abs=2e-4)


def test_least_squares_cylinder_agrees_with_scikit_spatial():
    from skspatial.objects import Cylinder

    seed = 12
    P = _cylinder_points(6.0, 0.0, 3, 30.0, seed, around=48, along=9)
    P = P + RNG.normal(0, 0.003, P.shape)
    Rm = Rotation.random(random_state=seed).as_matrix()
    o, a, r = least_squares_cylinder(P, np.array([120.0, -35.0, 410.0]), Rm[:, 2], 6.2)
    ref = Cylinder.best_fit(P)
    ref_axis = np.asarray(ref.vector) / np.linalg.norm(ref.vector)
    assert abs(abs(a @ ref_axis) - 1) < 1e-8
    assert r == pytest.approx(ref.radius, abs=1e-5)
    d = np.asarray(ref.point) - o
    assert np.linalg.norm(d - (d @ a) * a) < 1e-4


def test_zone_uncertainty_is_continuous_where_extremes_tie():
    """A zone's U comes from its extreme points; where two points nearly tie for the
    extreme, a change far below U (round-off) must not swap one point's U for the other's."""
    from qifreport.metrology.gdt.characteristic_types import zone_uncertainty

    rng = np.random.default_rng(0)
    r = rng.uniform(-0.05, 0.05, 200)
    U = np.full(200, 0.006)
    r[10], U[10] = 0.1, 0.004  # the highest point ...
    r[11], U[11] = 0.1 - 1e-13, 0.012  # ... and a rival 1e-13 mm below it, another U
    r[12], U[12] = -0.1, 0.006  # the lowest point stands out alone
    a = zone_uncertainty(r, U)
    r2 = r.copy()
    r2[11] += 2e-13  # the rival becomes the highest
    b = zone_uncertainty(r2, U)
    assert abs(a - b) < 1e-9, (a, b)
    # the tie counts both: between the U of either point alone with the low extreme
    assert np.hypot(0.004, 0.006) < a < np.hypot(0.012, 0.006)
    # extremes that stand out by more than the median U keep their own U exactly
    r3 = r.copy()
    r3[11] = 0.0
    assert zone_uncertainty(r3, U) == pytest.approx(np.hypot(0.004, 0.006), rel=1e-12)
