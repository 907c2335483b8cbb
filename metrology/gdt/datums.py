"""Datum reference frames from measured datum features (ASME Y14.5-2018 section 4 and
Y14.5.1; ISO 5459): the datum feature simulators fitted to the scan points of each datum
feature, in the order of precedence, and the rigid motion that brings them onto the
nominal datums.

* A planar datum feature is simulated by the **constrained L-infinity tangent plane**: the
  plane outside the material that touches the feature's high points and, among such
  planes, lies closest to the farthest point (it rocks to the minimum-zone position: the
  outer plane of the feature's flatness zone). A secondary plane keeps its orientation
  perpendicular (or at its nominal angle) to the primary, a tertiary to both.
* A cylindrical datum feature (a hole or a pin, regardless of material boundary, RMB) is
  simulated by the largest inscribed cylinder (a hole) or the smallest circumscribed
  cylinder (a pin); as a secondary its axis keeps its nominal orientation to the primary.

The degrees of freedom the frame leaves free (a primary plane alone leaves two
translations and a rotation) are reported; the caller best-fits them.

All lengths mm, points (m, 3) in the nominal frame (the scan after the virtual fixture).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from qifreport.metrology.gdt.active_rows import linprog_active
from qifreport.metrology.gdt.form import (
    axis_frame,
    least_squares_circle,
    least_squares_cylinder,
    least_squares_plane,
)

__all__ = [
    "DatumFeature",
    "DatumFrame",
    "DatumSimulator",
    "datum_frame",
    "design_text",
    "largest_gap",
    "max_unseen_arc",
    "unseen_arc",
    "nominal_feature",
    "simulate_datum",
    "tangent_plane",
]

#: re-linearisations of a simulator's programme and the motion (mm at the feature's
#: extent) under which it has settled
_ROUNDS = 12
_SETTLED = 1e-9
#: a nominal face set is a plane when its normals lie within this of their mean, a
#: cylinder when they lie within it of a plane (the one perpendicular to the axis)
_KIND_TOL = 1e-3
#: the percentile of the points' heights a least-squares datum plane is moved out to: the
#: high points of the surface, not its single noisiest point (on a scan, the extremes of
#: thousands of values are noise: 16 um on the NIST FTC 06's datum A at 5 um noise)
HIGH_POINTS = 99.5
#: a mating cylinder (inscribed, circumscribed) needs points all around: no gap wider
MAX_GAP_DEG = 60.0
#: ... and no axis at all is established from less than half of it (the least-squares
#: axis of a narrower arc tilts and moves with the noise: 0.003 rad, 0.04 mm on the NIST
#: FTC 06's 7 mm holes seen over 140 deg)
MAX_OPEN_DEG = 180.0
#: a cylinder whose mesh corners leave a wider gap about its axis is a partial one by
#: design (a slot end, a half-cylinder, a fillet); a whole one's corners are a segment apart
PARTIAL_GAP_DEG = 90.0


@dataclass
class DatumFeature:
    """A datum feature's nominal geometry.

    Attributes
    ----------
    label : the datum's letter.
    kind : ``'plane'``, ``'cylinder'``, ``'sphere'`` or ``'cone'`` (a sphere is a feature
        only, not simulated as a datum; a cone's datum is its axis).
    origin : (3,) a point of the plane, of the cylinder's axis, the sphere's centre or the
        cone's apex, mm.
    direction : (3,) unit: the plane's outward normal, the cylinder's axis, or the cone's
        axis toward its wider end.
    half_angle : the cone's half angle, rad (None for the others).
    radius : the cylinder's radius, mm (None for a plane).
    internal : a hole (material outside the cylinder), else a pin (None for a plane).
    arc : a partial cylinder's design extent about its axis (the B-rep face's own
        parameter range, as its mesh corners span it): ``(start, span)`` degrees in
        :func:`~qifreport.metrology.gdt.form.axis_frame` of ``direction`` (a slot end
        ``(a, 180)``); None: the whole circumference.
    """

    label: str
    kind: str
    origin: np.ndarray
    direction: np.ndarray
    radius: float | None = None
    internal: bool | None = None
    half_angle: float | None = None
    arc: tuple[float, float] | None = None


@dataclass
class DatumSimulator:
    """A datum feature simulator fitted to its measured points.

    Attributes
    ----------
    feature : the nominal datum feature.
    origin, direction : (3,) the simulator's plane (point, outward normal) or axis.
    radius : the inscribed/circumscribed cylinder's radius, mm (None for a plane).
    n : points used.  form : the points' farthest distance from the simulator, mm.
    method : ``'tangent plane'``, ``'largest inscribed'``, ``'smallest circumscribed'``, or
        ``'least squares (open arc)'`` (a cylinder whose points leave more than
        :data:`MAX_GAP_DEG` of it unseen: no mating cylinder is bounded).
    """

    feature: DatumFeature
    origin: np.ndarray
    direction: np.ndarray
    radius: float | None
    n: int
    form: float
    method: str = "tangent plane"


@dataclass
class DatumFrame:
    """A datum reference frame established on measured points.

    Attributes
    ----------
    labels : the datums in precedence order.
    R, t : (3, 3), (3,): the rigid motion ``x -> R x + t`` that brings the measured part
        onto the frame (its simulators onto the nominal datums).
    simulators : one per datum.
    free : the motions the frame does not fix, e.g. ``['translation along x',
        'rotation about z']``, in the nominal frame.
    """

    labels: tuple[str, ...]
    R: np.ndarray
    t: np.ndarray
    simulators: list[DatumSimulator]
    free: list[str] = field(default_factory=list)

    def apply(self, P: np.ndarray) -> np.ndarray:
        """(m, 3) the points ``P`` in the frame."""
        return np.asarray(P, dtype=np.float64) @ self.R.T + self.t


def nominal_feature(label: str, V: np.ndarray, N: np.ndarray) -> DatumFeature:
    """The nominal datum feature of a datum's faces: their vertices ``V`` (k, 3) mm and
    outward unit normals ``N`` (k, 3). A plane when the normals agree, a cylinder when they
    all lie perpendicular to one axis; :class:`ValueError` else (a datum on another surface
    is not simulated here)."""
    V, N = np.asarray(V, float), np.asarray(N, float)
    n = N.mean(axis=0)
    if np.linalg.norm(n) > 0 and np.max(np.linalg.norm(N - n / np.linalg.norm(n), axis=1)) < (
        10 * _KIND_TOL
    ):
        o, normal = least_squares_plane(V)
        if normal @ n < 0:
            normal = -normal
        return DatumFeature(label, "plane", o, normal)
    _, sv, Vt = np.linalg.svd(N, full_matrices=False)
    axis = Vt[-1]
    if sv[-1] > _KIND_TOL * np.sqrt(len(N)) * 10:
        feat = _nominal_cone(label, V, N) or _nominal_sphere(label, V, N)
        if feat is None:
            raise ValueError(f"datum {label}: its faces are neither a plane nor a cylinder")
        return feat
    # the axis' point: least squares of the lines along the normals (x = V - s N)
    o = _axis_point(V, N, axis)
    E = np.eye(3) - np.outer(axis, axis)
    radial = (V - o) @ E
    r = float(np.mean(np.linalg.norm(radial, axis=1)))
    o, axis, r = least_squares_cylinder(V, o, axis, r)
    # a hole's outward normals point at its axis
    internal = bool(np.mean(np.einsum("ij,ij->i", N, (V - o) @ E)) < 0)
    return DatumFeature(label, "cylinder", o, axis, r, internal, arc=_design_arc(V, o, axis))


def _design_arc(V: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[float, float] | None:
    """A partial cylinder's design extent (start, span) degrees about ``axis``: its mesh
    corners ``V`` (k, 3) leave a gap wider than :data:`PARTIAL_GAP_DEG` (a face's
    corners lie on its boundary, so they span its parameter range); None: a whole one."""
    ang = np.sort(_angles(V, origin, axis))
    gaps = np.diff(np.r_[ang, ang[0] + 360.0])
    k = int(np.argmax(gaps))
    if gaps[k] <= PARTIAL_GAP_DEG:
        return None
    return float(ang[(k + 1) % len(ang)]), float(360.0 - gaps[k])


def _angles(P: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(m,) angle of each point about ``axis`` through ``origin``, degrees in (-180, 180]."""
    X = (np.asarray(P, float) - origin) @ axis_frame(axis).T
    return np.degrees(np.arctan2(X[:, 1], X[:, 0]))


def unseen_arc(P: np.ndarray, feature: DatumFeature) -> float:
    """The widest angle (degrees) of a cylinder's design extent (:attr:`DatumFeature.arc`,
    the whole circumference when None) with no point of ``P`` (m, 3) about its axis."""
    if feature.arc is None:
        return largest_gap(P, feature.origin, feature.direction)
    start, span = feature.arc
    phi = np.sort(np.mod(_angles(P, feature.origin, feature.direction) - start, 360.0))
    phi = phi[phi <= span]
    return float(np.max(np.diff(np.r_[0.0, phi, span])))


def max_unseen_arc(feature: DatumFeature) -> float:
    """The widest unseen arc (degrees) a cylinder's axis is established with:
    :data:`MAX_OPEN_DEG` of a whole circumference, the same share of a partial one's
    design extent (half of a slot end's 180 degrees)."""
    span = 360.0 if feature.arc is None else feature.arc[1]
    return MAX_OPEN_DEG * span / 360.0


def _axis_point(V: np.ndarray, N: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The point of an axis every normal line ``v + s n`` crosses (least squares across the
    axis), nearest the points' centroid."""
    E = np.eye(3) - np.outer(axis, axis)
    Nn = N @ E
    Nn /= np.linalg.norm(Nn, axis=1, keepdims=True)
    # sum over the lines of (E - m m^T) (x - v) = 0, m the normal across the axis
    A = len(V) * E - Nn.T @ Nn
    b = E @ V.sum(axis=0) - Nn.T @ np.einsum("ij,ij->i", Nn, V)
    o = np.linalg.lstsq(A, b, rcond=None)[0]
    return o - ((o - V.mean(axis=0)) @ axis) * axis


def _nominal_cone(label: str, V: np.ndarray, N: np.ndarray) -> DatumFeature | None:
    """The cone whose normals all make one angle with its axis and whose normal lines all
    cross it (None when they do not, within :data:`_KIND_TOL`): apex, axis toward the wider
    end, half angle; a countersink's material is outside (``internal``)."""
    C = np.cov(N.T)
    w, vec = np.linalg.eigh(C)
    axis = vec[:, 0]
    c = N @ axis
    s = float(np.mean(c))
    if np.std(c) > _KIND_TOL * 10 or abs(s) < 1e-3 or abs(s) > 1 - 1e-3:
        return None
    o = _axis_point(V, N, axis)
    E = np.eye(3) - np.outer(axis, axis)
    rho = np.linalg.norm((V - o) @ E, axis=1)
    z = (V - o) @ axis
    m, q = np.polyfit(z, rho, 1)  # rho = m z + q
    if abs(m) < 1e-6:
        return None
    if m < 0:  # the axis toward the wider end
        axis, z, m, q = -axis, -z, -m, q
    z0 = -q / m
    half = float(np.arctan(m))
    if np.max(np.abs(rho - m * z - q)) * np.cos(half) > 10 * _KIND_TOL * max(rho.max(), 1.0):
        return None
    apex = o + z0 * axis
    internal = bool(np.mean(np.einsum("ij,ij->i", N, (V - o) @ E)) < 0)
    return DatumFeature(label, "cone", apex, axis, None, internal, half)


def _nominal_sphere(label: str, V: np.ndarray, N: np.ndarray) -> DatumFeature | None:
    """The sphere whose centre every normal line ``v + s n`` passes through (None when
    they do not meet in one point, within :data:`_KIND_TOL` of the radius)."""
    M = np.einsum("ij,ik->ijk", N, N)
    A = len(N) * np.eye(3) - M.sum(axis=0)
    b = V.sum(axis=0) - np.einsum("ijk,ik->j", M, V)
    try:
        c = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
    d = V - c
    r = float(np.mean(np.linalg.norm(d, axis=1)))
    off = d - np.einsum("ij,ij->i", d, N)[:, None] * N  # each normal line's miss
    if r <= 0 or np.max(np.linalg.norm(off, axis=1)) > 10 * _KIND_TOL * r:
        return None
    internal = bool(np.mean(np.einsum("ij,ij->i", N, d)) < 0)
    return DatumFeature(label, "sphere", c, np.array([0.0, 0.0, 1.0]), r, internal)


def _lp(c, A_ub, b_ub, k, bounds=None):
    bounds = [(None, None)] * k if bounds is None else bounds
    res = linprog_active(c, A_ub, b_ub, bounds)
    if res.status != 0:
        raise RuntimeError(f"datum simulator programme failed: {res.message}")
    return res.x


def tangent_plane(
    P: np.ndarray, normal: np.ndarray, keep: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The constrained L-infinity tangent plane (point, outward normal) of ``P`` (m, 3):
    every point on the material side (``(p - o) . n <= 0``), the farthest as near as can
    be; its normal stays perpendicular to each of ``keep`` (unit vectors)."""
    n = normal / np.linalg.norm(normal)
    o = P[np.argmax(P @ n)]
    extent = float(np.linalg.norm(np.ptp(P, axis=0))) or 1.0
    for _ in range(_ROUNDS):
        # tilts of n that keep it perpendicular to every kept direction
        E = axis_frame(n)
        T = E[:2].T  # (3, 2) tilt directions
        if keep:
            K = np.array([k - (k @ n) * n for k in keep])
            T = T - K.T @ np.linalg.lstsq(K.T, T, rcond=None)[0]
            U, sv, _ = np.linalg.svd(T, full_matrices=False)
            T = U[:, sv > 1e-9]
        q = T.shape[1]
        X = P - o
        w = X @ n
        uv = X @ T  # (m, q)
        m = len(P)
        # plane: w = uv . a + c; points below it: w - uv a - c <= 0; the farthest:
        # uv a + c - w <= h; minimise h
        A_ub = np.vstack([np.c_[-uv, -np.ones(m), np.zeros(m)], np.c_[uv, np.ones(m), -np.ones(m)]])
        b_ub = np.r_[-w, w]
        x = _lp(np.r_[np.zeros(q + 1), 1.0], A_ub, b_ub, q + 2)
        a, c = x[:q], x[q]
        tilt = T @ a
        n_new = (n - tilt) / np.linalg.norm(n - tilt)
        o = o + c * n
        n = n_new
        if np.linalg.norm(a) * extent + abs(c) < _SETTLED * extent:
            break
    o = o + float(np.max((P - o) @ n)) * n  # exactly tangent
    return o, n


def _axis_fit(
    P: np.ndarray, feature: DatumFeature, fixed_axis: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, float]:
    """The largest inscribed (a hole) or smallest circumscribed (a pin) cylinder of
    ``P`` (m, 3): (axis point, axis, radius); the axis direction held at ``fixed_axis``
    when given (a secondary datum's orientation to the primary)."""
    a = feature.direction if fixed_axis is None else fixed_axis
    o, a_ls, r = least_squares_cylinder(P, feature.origin, a, feature.radius)
    a = a if fixed_axis is not None else a_ls  # a held axis keeps its direction
    a = a / np.linalg.norm(a)
    length = float(np.ptp(P @ a)) or 1.0
    sign = 1.0 if feature.internal else -1.0  # maximise r (hole) / minimise r (pin)
    for _ in range(_ROUNDS):
        E = axis_frame(a)
        X = (P - o) @ E.T
        z = X[:, 2]
        rho = np.hypot(X[:, 0], X[:, 1])
        cos, sin = X[:, 0] / rho, X[:, 1] / rho
        cols = [cos, sin] if fixed_axis is not None else [cos, sin, cos * z, sin * z]
        A = np.c_[tuple(cols)]
        q = A.shape[1]
        m = len(P)
        # hole: rho - A x >= r for all, maximise r: A x + r <= rho, minimise -r
        # pin:  rho - A x <= r for all, minimise r: -A x - r <= -rho
        if feature.internal:
            A_ub, b_ub = np.c_[A, np.ones(m)], rho
        else:
            A_ub, b_ub = np.c_[-A, -np.ones(m)], -rho
        # one round moves the axis by at most its radius and turns it by 0.2 rad
        step = [(-r, r)] * 2 + [(-0.2, 0.2)] * (q - 2) + [(None, None)]
        x = _lp(np.r_[np.zeros(q), -sign], A_ub, b_ub, q + 1, step)
        p, qq = x[0], x[1]
        o = o + p * E[0] + qq * E[1]
        moved = np.hypot(p, qq)
        if fixed_axis is None:
            s, t = x[2], x[3]
            a = a + s * E[0] + t * E[1]
            a /= np.linalg.norm(a)
            moved += np.hypot(s, t) * length
        r = x[-1]
        if moved < _SETTLED * max(abs(r), 1.0):
            break
    E = axis_frame(a)
    X = (P - o) @ E.T
    rho = np.hypot(X[:, 0], X[:, 1])
    r = float(rho.min() if feature.internal else rho.max())
    return o, a, r


def _ls_axis(
    P: np.ndarray, feature: DatumFeature, keep: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, float]:
    """The least-squares cylinder's axis point, axis and radius; the axis held at
    ``keep[0]`` when given (the circle fitted across it)."""
    if not keep:
        return least_squares_cylinder(P, feature.origin, feature.direction, feature.radius)
    a = keep[0] / np.linalg.norm(keep[0])
    E = axis_frame(a)
    X = P @ E.T
    c, r = least_squares_circle(X[:, :2])
    o = c[0] * E[0] + c[1] * E[1] + X[:, 2].mean() * a
    return o, a, r


def _ls_plane(P: np.ndarray, normal: np.ndarray, keep: list[np.ndarray]) -> np.ndarray:
    """The least-squares plane's unit normal (toward ``normal``), held perpendicular to
    each of ``keep``."""
    C = np.cov((P - P.mean(axis=0)).T)
    Q = np.eye(3)
    if keep:
        K = np.array(keep, dtype=np.float64)
        _, sv, Vt = np.linalg.svd(K)
        Q = Vt[int(np.sum(sv > 1e-9)) :].T  # (3, q) directions perpendicular to keep
    w, v = np.linalg.eigh(Q.T @ C @ Q)
    n = Q @ v[:, 0]
    n /= np.linalg.norm(n)
    return n if n @ normal >= 0 else -n


def simulate_datum(
    P: np.ndarray,
    feature: DatumFeature,
    keep: list[np.ndarray] | None = None,
    association: str = "tangent",
) -> DatumSimulator:
    """The datum feature simulator of ``feature`` on its measured points ``P`` (m, 3).

    ``keep``: for a plane, directions its normal stays perpendicular to (a secondary's
    primary normal, ...); for a cylinder, ``[axis]`` holds its axis' direction.

    ``association``: ``'tangent'`` (ASME Y14.5: the constrained L-infinity tangent plane,
    the largest inscribed / smallest circumscribed cylinder) or ``'least squares'`` (the
    plane's orientation by least squares, moved out to touch the high points; the
    least-squares cylinder's axis): on scanned points the tangent simulator rests on a
    few noisy extremes and tilts with them (1.4e-4 rad on the 35 mm faces of the NIST FTC
    06's datum B at 5 um noise), the least-squares one averages them.
    """
    if association not in ("tangent", "least squares"):
        raise ValueError(f"unknown datum association {association!r}")
    P = np.asarray(P, dtype=np.float64)
    keep = list(keep or [])
    if feature.kind == "plane":
        if len(P) < 3:
            raise ValueError(f"datum {feature.label}: fewer than 3 points on its feature")
        if association == "tangent":
            o, n = tangent_plane(P, feature.direction, keep)
            method = "tangent plane"
        else:
            n = _ls_plane(P, feature.direction, keep)
            # out to the high points: a surface's, not one noisy point's
            c = P.mean(axis=0)
            o = c + (np.percentile(P @ n, HIGH_POINTS) - c @ n) * n
            method = "least-squares plane, on the high points"
        form = float(np.max(-(P - o) @ n))
        return DatumSimulator(feature, o, n, None, len(P), form, method)
    if len(P) < 6:
        raise ValueError(f"datum {feature.label}: fewer than 6 points on its feature")
    unseen = unseen_arc(P, feature)
    if unseen > max_unseen_arc(feature):
        raise ValueError(
            f"datum {feature.label}: its points leave {unseen:.0f} deg of its "
            f"{design_text(feature)} unseen (at most {max_unseen_arc(feature):.0f}); "
            "no cylinder can be fitted"
        )
    gap = largest_gap(P, feature.origin, feature.direction)
    if association == "least squares" or gap > MAX_GAP_DEG:
        # (an open arc: no mating cylinder is bounded; the least-squares one stands in)
        o, a, r = _ls_axis(P, feature, keep)
        method = "least-squares cylinder" + (" (open arc)" if gap > MAX_GAP_DEG else "")
    else:
        o, a, r = _axis_fit(P, feature, keep[0] if keep else None)
        method = "largest inscribed" if feature.internal else "smallest circumscribed"
    E = np.eye(3) - np.outer(a, a)
    rho = np.linalg.norm((P - o) @ E, axis=1)
    return DatumSimulator(feature, o, a, r, len(P), float(np.max(np.abs(rho - r))), method)


def design_text(feature: DatumFeature) -> str:
    """``'circumference'``, or a partial cylinder's ``'180 deg design arc'``."""
    return "circumference" if feature.arc is None else f"{feature.arc[1]:.0f} deg design arc"


def largest_gap(P: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> float:
    """The widest angle (degrees) about ``axis`` through ``origin`` with no point of ``P``."""
    ang = np.sort(_angles(P, origin, axis))
    if len(ang) < 2:
        return 360.0
    return float(np.max(np.diff(np.r_[ang, ang[0] + 360.0])))


def _rotation_between(a: np.ndarray, b: np.ndarray, about: np.ndarray | None = None) -> np.ndarray:
    """The rotation taking unit ``a`` to unit ``b`` (about ``about`` when given: ``a`` and
    ``b`` are then taken in the plane perpendicular to it)."""
    if about is not None:
        k = about / np.linalg.norm(about)
        a = a - (a @ k) * k
        b = b - (b @ k) * k
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        ang = np.arctan2(np.cross(a, b) @ k, a @ b)
        return _rodrigues(k, ang)
    v = np.cross(a, b)
    s, c = np.linalg.norm(v), float(a @ b)
    if s < 1e-15:
        if c > 0:
            return np.eye(3)
        k = axis_frame(a)[0]
        return _rodrigues(k, np.pi)
    return _rodrigues(v / s, np.arctan2(s, c))


def _rodrigues(k: np.ndarray, ang: float) -> np.ndarray:
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def datum_frame(features: list[DatumFeature], points: list[np.ndarray]) -> DatumFrame:
    """The datum reference frame of ``features`` (precedence order) on their measured
    points ``points`` (one (m_i, 3) array each, the nominal frame).

    Orientation: the primary simulator's direction is turned onto its datum's; a later
    datum whose direction is not parallel to it turns the part about it (a secondary
    plane); two or more axes parallel to the primary's (a pattern of holes) clock it by
    the line between the first two. Location: each simulator in turn fixes the
    translations its predecessors left free (a secondary plane one, a hole two, a tertiary
    what remains). Returns the frame with the motions it leaves free.
    """
    if not features or len(features) != len(points):
        raise ValueError("a datum reference frame needs its features and their points")
    sims: list[DatumSimulator] = []
    R = np.eye(3)
    fixed: list[np.ndarray] = []  # nominal directions whose orientation is fixed
    for f, P in zip(features, points, strict=True):
        P = np.asarray(P, float) @ R.T  # in the orientation fixed so far
        if f.kind == "plane":
            keep = list(fixed)
        else:
            keep = [f.direction] if fixed else []
        sim = simulate_datum(P, f, keep)
        if not fixed:
            dR = _rotation_between(sim.direction, f.direction)
            fixed.append(f.direction)
        elif len(fixed) == 1 and abs(f.direction @ fixed[0]) < 1 - 1e-9:
            dR = _rotation_between(sim.direction, f.direction, about=fixed[0])
            fixed.append(f.direction)
        else:
            dR = np.eye(3)
        R = dR @ R
        for s in sims:
            s.origin, s.direction = dR @ s.origin, dR @ s.direction
        sim.origin, sim.direction = dR @ sim.origin, dR @ sim.direction
        sims.append(sim)
    if len(fixed) == 1:
        # clocking by a pattern: two axes parallel to the primary's direction
        axes = [s for s in sims[1:] if s.feature.kind == "cylinder"]
        if len(axes) >= 2:
            k = fixed[0]
            meas = axes[1].origin - axes[0].origin
            nom = axes[1].feature.origin - axes[0].feature.origin
            if np.linalg.norm(nom - (nom @ k) * k) > 1e-9:
                dR = _rotation_between(meas, nom, about=k)
                R = dR @ R
                for s in sims:
                    s.origin, s.direction = dR @ s.origin, dR @ s.direction
                fixed.append(np.cross(k, nom / np.linalg.norm(nom)))
    # location, in precedence: each simulator fixes the translations still free
    t = np.zeros(3)
    free_dirs = np.eye(3)  # (r, 3) orthonormal rows: translations not fixed yet
    for sim in sims:
        if len(free_dirs) == 0:
            break
        f = sim.feature
        rows = f.direction[None, :] if f.kind == "plane" else axis_frame(f.direction)[:2]
        # rows (sim.origin + t + U y - f.origin) = 0 for y over the free directions U
        A = rows @ free_dirs.T
        b = rows @ (f.origin - sim.origin - t)
        U_, sv, Vt = np.linalg.svd(A, full_matrices=True)
        r = int(np.sum(sv > 1e-9))
        if r == 0:
            continue
        y = np.linalg.lstsq(A, b, rcond=None)[0]
        t = t + free_dirs.T @ y
        free_dirs = Vt[r:] @ free_dirs
    free = ["translation along " + _name(v) for v in free_dirs]
    if len(fixed) == 1:
        free.append("rotation about " + _name(fixed[0]))
    return DatumFrame(tuple(f.label for f in features), R, t, sims, free)


def _name(v: np.ndarray) -> str:
    axes = "xyz"
    i = int(np.argmax(np.abs(v)))
    if abs(abs(v[i]) - 1) < 1e-6:
        return axes[i]
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"
