"""Form of a feature from its measured points: flatness, straightness, roundness and
cylindricity, by the minimum zone (ASME Y14.5-2018 and ISO 1101: the narrowest zone of the
tolerance's shape that contains every point) with the least-squares reading beside it.

Each minimum zone is a linear programme (Chebyshev fit, :func:`scipy.optimize.linprog`)
in the small parameters of the feature about its least-squares fit (a plane's tilt, a
circle's centre, an axis' position and direction), re-linearised about the new feature
until it stops moving; the width reported is then measured exactly (orthogonal distances
to the final plane or line, radii about the final centre or axis). Least squares is the
Gaussian fit (orthogonal distances, Gauss-Newton for circles and cylinders); its
peak-to-valley is never narrower than the minimum zone.

All lengths mm; points are rows of ``P`` (m, 3) or (m, 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.metrology.gdt.active_rows import linprog_active

__all__ = [
    "FormFit",
    "axis_frame",
    "cylindricity",
    "flatness",
    "least_squares_circle",
    "least_squares_cone",
    "cone_draws",
    "least_squares_cylinder",
    "least_squares_plane",
    "least_squares_sphere",
    "roundness",
    "straightness",
]

#: re-linearisations of a minimum-zone fit, and the parameter change (mm, or rad x the
#: feature's extent) under which it has settled
_ROUNDS = 12
_SETTLED = 1e-9


@dataclass
class FormFit:
    """A form measurement.

    Attributes
    ----------
    kind : ``'flatness'``, ``'straightness'``, ``'roundness'`` or ``'cylindricity'``.
    minimum_zone : width of the minimum zone, mm (the tolerance's value).
    least_squares : peak-to-valley about the least-squares feature, mm (>= minimum_zone).
    n : points used.
    origin : (d,) a point of the minimum-zone feature (a plane's or line's point, a
        circle's centre, a point of the cylinder's axis), mm.
    direction : (d,) unit: a plane's normal, a line's direction, a circle's or cylinder's
        axis (None in 2-D for a circle).
    radius : the zone's mid radius, mm (circles and cylinders; None else).
    residuals : (m,) signed distance of each point from the zone's middle, mm.
    """

    kind: str
    minimum_zone: float
    least_squares: float
    n: int
    origin: np.ndarray
    direction: np.ndarray | None
    radius: float | None
    residuals: np.ndarray


# ------------------------------------------------------------------- least squares


def least_squares_plane(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), unit normal (3,)) of the orthogonal least-squares plane of ``P`` (m, 3)."""
    P = np.asarray(P, dtype=np.float64)
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
    return c, Vt[-1]


def _line_2d(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = Q.mean(axis=0)
    _, _, Vt = np.linalg.svd(Q - c, full_matrices=False)
    return c, Vt[0]


def _least_squares_ball(Q: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (d,), radius) of the geometric least-squares circle (d = 2) or sphere
    (d = 3) of ``Q`` (m, d): the algebraic (Kasa) fit refined by Gauss-Newton on the
    orthogonal distances."""
    Q = np.asarray(Q, dtype=np.float64)
    d = Q.shape[1]
    A = np.c_[2 * Q, np.ones(len(Q))]
    sol, *_ = np.linalg.lstsq(A, np.einsum("ij,ij->i", Q, Q), rcond=None)
    c = sol[:d]
    r = float(np.sqrt(max(sol[d] + c @ c, 0.0)))
    for _ in range(50):
        x = Q - c
        rho = np.linalg.norm(x, axis=1)
        u = x / np.maximum(rho, 1e-300)[:, None]
        J = np.c_[-u, -np.ones(len(Q))]  # d(rho - r)/d(c, r)
        step, *_ = np.linalg.lstsq(J, -(rho - r), rcond=None)
        c, r = c + step[:d], r + step[d]
        if np.abs(step).max() < 1e-12 * max(1.0, abs(r)):
            break
    return c, float(r)


def least_squares_circle(Q: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (2,), radius) of the geometric least-squares circle of ``Q`` (m, 2), mm."""
    return _least_squares_ball(Q)


def least_squares_sphere(P: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of the geometric least-squares sphere of ``P`` (m, 3), mm."""
    return _least_squares_ball(P)


def _cone_model(P: np.ndarray, apex: np.ndarray, axis: np.ndarray, half_angle: float):
    """A cone's six small parameters about ``(apex, axis, half_angle)`` (apex shift, mm; axis
    tilt across it; half-angle change, rad): ``unpack(x) -> (apex, unit axis, half angle)``
    and ``residual(x)``, each point of ``P`` (m, 3) its distance to the cone's surface."""
    E = axis_frame(axis)  # rows: two across, the axis

    def unpack(x):
        a = E[2] + x[3] * E[0] + x[4] * E[1]
        return apex + x[:3], a / np.linalg.norm(a), half_angle + x[5]

    def residual(x):
        o, a, h = unpack(x)
        v = P - o
        z = v @ a
        rho = np.linalg.norm(v - np.outer(z, a), axis=1)
        return rho * np.cos(h) - z * np.sin(h)

    return unpack, residual


def least_squares_cone(
    P: np.ndarray, apex: np.ndarray, axis: np.ndarray, half_angle: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """The least-squares cone of the points ``P`` (m, 3), from a nominal one: apex (3,),
    unit axis toward the wider end, half angle (rad); the distance to the cone's surface
    minimised in least squares (Gauss-Newton, ``scipy.optimize.least_squares``)."""
    from scipy.optimize import least_squares

    P = np.asarray(P, dtype=np.float64)
    if len(P) < 7:
        raise ValueError("a cone needs at least 7 points")
    unpack, residual = _cone_model(P, apex, axis, half_angle)
    scale = max(float(np.linalg.norm(np.ptp(P, axis=0))), 1.0)
    res = least_squares(residual, np.zeros(6), x_scale=[scale] * 3 + [1.0, 1.0, 0.1])
    return unpack(res.x)


def cone_draws(
    P: np.ndarray, apex: np.ndarray, axis: np.ndarray, half_angle: float, n: int = 200
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``n`` cones drawn from the least-squares cone's parameter distribution (its
    Jacobian and residual scatter, ``s^2 (J^T J)^-1``; a poorly seen cone, e.g. a few dozen
    points on a narrow countersink, spreads widely): for the uncertainty of any quantity
    derived from the fit. The least-squares cone first."""
    from scipy.optimize import least_squares

    P = np.asarray(P, dtype=np.float64)
    fit = least_squares_cone(P, apex, axis, half_angle)
    unpack, residual = _cone_model(P, *fit)
    res = least_squares(residual, np.zeros(6), max_nfev=20)
    J = res.jac
    dof = max(len(P) - 6, 1)
    s2 = float(res.fun @ res.fun) / dof
    cov = s2 * np.linalg.pinv(J.T @ J)
    rng = np.random.default_rng(0)
    xs = rng.multivariate_normal(res.x, cov, size=n, check_valid="ignore")
    return [unpack(res.x)] + [unpack(x) for x in xs]


def axis_frame(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rows e1, e2, axis: an orthonormal frame whose third row is ``axis``."""
    a = axis / np.linalg.norm(axis)
    t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, t)
    e1 /= np.linalg.norm(e1)
    return np.vstack([e1, np.cross(a, e1), a])


def least_squares_cylinder(
    P: np.ndarray, origin: np.ndarray, axis: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(point on the axis (3,), unit axis (3,), radius) of the orthogonal least-squares
    cylinder of ``P`` (m, 3), by Gauss-Newton from a start (e.g. the nominal cylinder)."""
    P = np.asarray(P, dtype=np.float64)
    o, a, r = np.asarray(origin, float), np.asarray(axis, float), float(radius)
    for _ in range(50):
        E = axis_frame(a)
        X = (P - o) @ E.T  # x, y across the axis, z along it
        z = X[:, 2]
        rho = np.hypot(X[:, 0], X[:, 1])
        cos, sin = X[:, 0] / np.maximum(rho, 1e-300), X[:, 1] / np.maximum(rho, 1e-300)
        # rho after moving the axis by (p, q) + z (s, t) across it: rho - cos (p + s z) - ...
        J = np.c_[-cos, -sin, -cos * z, -sin * z, -np.ones(len(P))]
        step, *_ = np.linalg.lstsq(J, -(rho - r), rcond=None)
        p, q, s, t, dr = step
        o = o + p * E[0] + q * E[1]
        a = a + s * E[0] + t * E[1]
        a /= np.linalg.norm(a)
        r += dr
        if np.abs(step).max() < 1e-12 * max(1.0, abs(r)):
            break
    return o, a, r


# ------------------------------------------------------------------- minimum zones


def _chebyshev(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """The parameters ``x`` minimising ``max |b - A x|``, and that maximum (HiGHS, on the
    active rows: :func:`~qifreport.metrology.gdt.active_rows.linprog_active`)."""
    m, k = A.shape
    # variables (x, h): minimise h subject to -h <= b - A x <= h
    c = np.r_[np.zeros(k), 1.0]
    ones = np.ones((m, 1))
    A_ub = np.vstack([np.c_[A, -ones], np.c_[-A, -ones]])
    b_ub = np.r_[b, -b]
    res = linprog_active(c, A_ub, b_ub, [(None, None)] * (k + 1))
    if res.status != 0:
        raise RuntimeError(f"minimum-zone programme failed: {res.message}")
    return res.x[:k], float(res.x[k])


def _band(A: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The parameters ``x`` and radii ``r_in <= rho - A x <= r_out`` with the narrowest
    ``r_out - r_in`` (concentric zones: circles, cylinders)."""
    m, k = A.shape
    # variables (x, r_in, r_out)
    c = np.r_[np.zeros(k), -1.0, 1.0]
    ones = np.ones((m, 1))
    zeros = np.zeros((m, 1))
    # rho - A x <= r_out  ->  -A x - r_out <= -rho ; r_in <= rho - A x -> A x + r_in <= rho
    A_ub = np.vstack([np.c_[-A, zeros, -ones], np.c_[A, ones, zeros]])
    b_ub = np.r_[-rho, rho]
    res = linprog_active(c, A_ub, b_ub, [(None, None)] * (k + 2))
    if res.status != 0:
        raise RuntimeError(f"minimum-zone programme failed: {res.message}")
    return res.x[:k], float(res.x[k]), float(res.x[k + 1])


def _slab(
    kind: str, w: np.ndarray, ls: float, o: np.ndarray, normal: np.ndarray, direction: np.ndarray
) -> FormFit:
    """A zone between two parallel planes (lines): ``w`` (m,) the points' distances from
    the plane (line) through ``o`` with unit ``normal``; ``ls`` the least-squares width."""
    mid = 0.5 * (w.max() + w.min())
    return FormFit(
        kind=kind,
        minimum_zone=min(float(np.ptp(w)), ls),
        least_squares=ls,
        n=len(w),
        origin=o + mid * normal,
        direction=direction,
        radius=None,
        residuals=w - mid,
    )


def _annulus(
    kind: str, rho: np.ndarray, ls: float, centre: np.ndarray, axis: np.ndarray | None
) -> FormFit:
    """A zone between two concentric circles (coaxial cylinders): ``rho`` (m,) the points'
    radii about ``centre`` (a point of ``axis``); ``ls`` the least-squares width."""
    mid = 0.5 * (rho.max() + rho.min())
    return FormFit(
        kind=kind,
        minimum_zone=min(float(np.ptp(rho)), ls),
        least_squares=ls,
        n=len(rho),
        origin=centre,
        direction=axis,
        radius=float(mid),
        residuals=rho - mid,
    )


def flatness(P: np.ndarray) -> FormFit:
    """Flatness of the points ``P`` (m, 3), mm: the minimum zone between two parallel
    planes, and the least-squares plane's peak-to-valley."""
    P = np.asarray(P, dtype=np.float64)
    if len(P) < 4:
        raise ValueError("flatness needs at least 4 points")
    o, n = least_squares_plane(P)
    w_ls = (P - o) @ n
    ls = float(np.ptp(w_ls))
    extent = float(np.linalg.norm(np.ptp(P, axis=0)))
    for _ in range(_ROUNDS):
        E = axis_frame(n)
        X = (P - o) @ E.T
        # w = a u + b v + c: the plane's tilt (a, b) and offset c about the current one
        x, _ = _chebyshev(np.c_[X[:, 0], X[:, 1], np.ones(len(P))], X[:, 2])
        a, b, c = x
        n_new = (E[2] - a * E[0] - b * E[1]) / np.sqrt(1 + a * a + b * b)
        o = o + c * E[2]
        moved = np.hypot(a, b) * extent + abs(c)
        n = n_new
        if moved < _SETTLED * max(extent, 1.0):
            break
    return _slab("flatness", (P - o) @ n, ls, o, n, n)


def straightness(Q: np.ndarray) -> FormFit:
    """Straightness of a line element ``Q`` (m, 2) (points in the plane of the element,
    mm): the minimum zone between two parallel lines, and the least-squares line's
    peak-to-valley."""
    Q = np.asarray(Q, dtype=np.float64)
    if len(Q) < 3:
        raise ValueError("straightness needs at least 3 points")
    o, d = _line_2d(Q)
    nrm = np.array([-d[1], d[0]])
    ls = float(np.ptp((Q - o) @ nrm))
    extent = float(np.linalg.norm(np.ptp(Q, axis=0)))
    for _ in range(_ROUNDS):
        u, v = (Q - o) @ d, (Q - o) @ nrm
        (a, c), _ = _chebyshev(np.c_[u, np.ones(len(Q))], v)
        d = (d + a * nrm) / np.hypot(1.0, a)
        o = o + c * nrm
        nrm = np.array([-d[1], d[0]])
        if abs(a) * extent + abs(c) < _SETTLED * max(extent, 1.0):
            break
    return _slab("straightness", (Q - o) @ nrm, ls, o, nrm, d)


def roundness(Q: np.ndarray) -> FormFit:
    """Roundness (circularity) of a circular element ``Q`` (m, 2) (points in its plane,
    mm): the minimum radial zone between two concentric circles, and the least-squares
    circle's peak-to-valley."""
    Q = np.asarray(Q, dtype=np.float64)
    if len(Q) < 4:
        raise ValueError("roundness needs at least 4 points")
    c, r = least_squares_circle(Q)
    ls = float(np.ptp(np.linalg.norm(Q - c, axis=1)))
    for _ in range(_ROUNDS):
        d = Q - c
        rho = np.linalg.norm(d, axis=1)
        u = d / np.maximum(rho, 1e-300)[:, None]
        # rho after moving the centre by x: rho - u . x (the limacon, exact to first order)
        x, _, _ = _band(u, rho)
        c = c + x
        if np.linalg.norm(x) < _SETTLED * max(r, 1.0):
            break
    return _annulus("roundness", np.linalg.norm(Q - c, axis=1), ls, c, None)


def cylindricity(P: np.ndarray, origin: np.ndarray, axis: np.ndarray, radius: float) -> FormFit:
    """Cylindricity of the points ``P`` (m, 3), mm: the minimum radial zone between two
    coaxial cylinders, and the least-squares cylinder's peak-to-valley; from a start near
    the cylinder (``origin`` on its axis, unit ``axis``, ``radius``: e.g. the nominal's)."""
    P = np.asarray(P, dtype=np.float64)
    if len(P) < 6:
        raise ValueError("cylindricity needs at least 6 points")
    o, a, r = least_squares_cylinder(P, origin, axis, radius)

    def radii(o, a):
        X = (P - o) @ axis_frame(a).T
        return X, np.hypot(X[:, 0], X[:, 1])

    X, rho = radii(o, a)
    ls = float(np.ptp(rho))
    length = float(np.ptp(X[:, 2])) or 1.0
    for _ in range(_ROUNDS):
        E = axis_frame(a)
        X, rho = radii(o, a)
        z = X[:, 2]
        cos, sin = X[:, 0] / np.maximum(rho, 1e-300), X[:, 1] / np.maximum(rho, 1e-300)
        (p, q, s, t), _, _ = _band(np.c_[cos, sin, cos * z, sin * z], rho)
        o = o + p * E[0] + q * E[1]
        a = a + s * E[0] + t * E[1]
        a /= np.linalg.norm(a)
        if np.hypot(p, q) + np.hypot(s, t) * length < _SETTLED * max(r, 1.0):
            break
    return _annulus("cylindricity", radii(o, a)[1], ls, o, a)
