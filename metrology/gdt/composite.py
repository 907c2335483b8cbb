"""The lower segment of a composite feature control frame (ASME Y14.5-2018 10.5.1, 11.6):
its zone relates the features of a pattern (or the faces of a profile) to **each other**;
its datums, when it cites any, control the orientation only, and the zone may translate
(and turn about what the cited datums leave free) as a whole.

So a lower segment is read in the **orientation** of its datum reference frame
(:func:`orientation_only`: the frame's rotation, its translation free) at the common small
motion that best fits the zone: the minimax placement (the smallest zone, not a least-squares
one, as a functional gauge would find it), found by linear programming
(:func:`minimax_offsets` for a pattern's axes, :func:`minimax_shift` for a profile's
deviations).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import linprog

from qifreport.metrology.gdt.frames import DatumFrameResult

__all__ = [
    "composite_zone_frame",
    "free_rotations",
    "least_squares_shift",
    "minimax_offsets",
    "minimax_shift",
    "orientation_only",
    "shift_frame",
]

#: sides of the polygon standing for a circle in the pattern's linear programme (its
#: solution is then evaluated exactly: the value is within 1 - cos(pi / 32) = 0.5 % of the
#: true minimum, never below it)
POLYGON_SIDES = 32
#: a profile's minimax placement is solved on the largest deviations first, this many,
#: then again with every point that the placement leaves out of the zone so found
ACTIVE_POINTS = 4000


def orientation_only(frame: DatumFrameResult) -> DatumFrameResult:
    """The frame's orientation: its rotation ``w`` kept, its translation free (``t = 0``:
    the best fit's location, to be fitted by the caller), the translation's share of the
    covariance dropped."""
    cov = None
    if frame.covariance is not None:
        cov = frame.covariance.copy()
        cov[3:, :] = 0.0
        cov[:, 3:] = 0.0
    free = [f for f in frame.free if not f.startswith("translation")]
    free = ["translation (composite lower segment)", *free]
    basis = None
    if frame.free_basis is not None:
        keep = np.linalg.norm(frame.free_basis[:3], axis=0) > 1e-12
        basis = np.c_[frame.free_basis[:, keep], np.r_[np.zeros((3, 3)), np.eye(3)]]
    return replace(frame, t=np.zeros(3), covariance=cov, free=free, free_basis=basis)


def free_rotations(frame: DatumFrameResult | None) -> np.ndarray:
    """(k, 3) unit axes of the rotations ``frame`` leaves free (all three without one)."""
    if frame is None:
        return np.eye(3)
    if frame.free_basis is None or frame.free_basis.shape[1] == 0:
        return np.zeros((0, 3))
    W = frame.free_basis[:3]
    U_, sv, _ = np.linalg.svd(W, full_matrices=False)
    k = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1e-300)))
    return U_[:, :k].T


def minimax_offsets(
    Q: np.ndarray,
    P: np.ndarray,
    axes: np.ndarray,
    rotations: np.ndarray,
    allowance: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The common small motion of a pattern that minimises its worst member's offset.

    Parameters
    ----------
    Q : (m, 3) each member end's offset from its true position, across its axis, mm.
    P : (m, 3) where each end is (the motion's lever), mm.
    axes : (m, 3) unit axis of each end's member (the offset is across it).
    rotations : (k, 3) unit axes of the rotations allowed besides any translation.
    allowance : (m,) what each end may have beyond the common zone (half its member's
        bonus), mm; zeros without.

    Returns
    -------
    t : (3,) translation, mm.  theta : (k,) rotations, rad.
    offsets : (m,) each end's offset after the motion, exactly, mm.
    """
    Q = np.asarray(Q, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    m, k = len(Q), len(rotations)
    allowance = np.zeros(m) if allowance is None else np.asarray(allowance, dtype=np.float64)
    # the motion's effect on each end: G x, x = (t, theta)
    G = np.zeros((m, 3, 3 + k))
    G[:, :, :3] = np.eye(3)
    for j, om in enumerate(rotations):
        G[:, :, 3 + j] = np.cross(om, P)
    # across each axis only
    Eax = np.eye(3)[None] - np.einsum("mi,mj->mij", axes, axes)
    G = np.einsum("mij,mjk->mik", Eax, G)
    Q = np.einsum("mij,mj->mi", Eax, Q)
    # two directions spanning the plane across each axis, and the polygon's normals
    ref = np.where(np.abs(axes[:, :1]) < 0.9, np.eye(3)[0], np.eye(3)[1])
    e1 = np.cross(axes, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axes, e1)
    ang = np.linspace(0.0, 2 * np.pi, POLYGON_SIDES, endpoint=False)
    Udir = np.cos(ang)[None, :, None] * e1[:, None] + np.sin(ang)[None, :, None] * e2[:, None]
    # u . (Q - G x) <= r + allowance  ->  -u.G x - r <= allowance - u.Q
    A = np.concatenate(
        [-np.einsum("mpd,mdj->mpj", Udir, G), -np.ones((m, POLYGON_SIDES, 1))], axis=2
    ).reshape(m * POLYGON_SIDES, 4 + k)
    b = (allowance[:, None] - np.einsum("mpd,md->mp", Udir, Q)).reshape(-1)
    c = np.zeros(4 + k)
    c[-1] = 1.0
    res = linprog(c, A_ub=A, b_ub=b, bounds=[(None, None)] * (4 + k), method="highs")
    if res.status != 0:
        raise RuntimeError(f"the pattern's minimax placement failed: {res.message}")
    x = res.x[: 3 + k]
    off = np.linalg.norm(Q - np.einsum("mdj,j->md", G, x), axis=1)
    return x[:3], x[3:], off


def minimax_shift(
    d: np.ndarray, V: np.ndarray, N: np.ndarray, rotations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The small motion ``(t, theta)`` that minimises ``max |d_i + N_i . (t + theta x V_i)|``:
    a profile's zone placed at its minimax position. Motions the zone's normals do not see
    (a flat face's own plane, a rotation about its normal) are left at 0.

    Parameters
    ----------
    d : (n,) deviations from the zone's centre, mm (finite).
    V : (n, 3) where, mm.  N : (n, 3) unit normals along which ``d`` is measured.
    rotations : (k, 3) unit axes of the rotations allowed besides any translation.

    Returns
    -------
    t : (3,) mm.  theta : (k,) rad.  half : the zone's half width then, mm.
    """
    d = np.asarray(d, dtype=np.float64)
    A, to_motion = _motion_columns(V, N, rotations)
    active = np.argsort(-np.abs(d))[:ACTIVE_POINTS]
    for _ in range(8):
        y, half = _minimax_linear(d[active], A[active])
        r = np.abs(d + A @ y)
        out = np.flatnonzero(r > half + 1e-9)
        if not len(out):
            break
        active = np.union1d(active, out[np.argsort(-r[out])][:ACTIVE_POINTS])
    t, theta = to_motion(y)
    return t, theta, float(np.abs(d + A @ y).max())


def _minimax_linear(d: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float]:
    """``min_y max |d + A y|`` (a linear programme)."""
    m, k = A.shape
    c = np.zeros(k + 1)
    c[-1] = 1.0
    A_ub = np.r_[np.c_[A, -np.ones(m)], np.c_[-A, -np.ones(m)]]
    b_ub = np.r_[-d, d]
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * (k + 1), method="highs")
    if res.status != 0:
        raise RuntimeError(f"the zone's minimax placement failed: {res.message}")
    return res.x[:k], float(res.x[-1])


def shift_frame(
    frame: DatumFrameResult, t: np.ndarray, theta: np.ndarray, rotations: np.ndarray
) -> DatumFrameResult:
    """``frame`` moved further by ``(t, theta)``: its rotation plus the free rotations'
    ``theta``, its translation ``t``."""
    w = frame.w + (theta @ rotations if len(theta) else 0.0)
    return replace(frame, w=np.asarray(w, dtype=np.float64), t=frame.t + t)


def composite_zone_frame(
    frame: DatumFrameResult | None,
    V: np.ndarray,
    N: np.ndarray,
    d: np.ndarray,
    governed: np.ndarray,
    half_width: float | None = None,
) -> DatumFrameResult | None:
    """The placement of a composite profile's lower segment (:mod:`.composite`): the
    orientation of its datum frame (none: the best fit's), the zone moved as a whole
    (translation, and rotation about what its datums leave free) to its minimax position
    over the vertices it governs.

    Parameters
    ----------
    frame : the segment's datum frame (None: it cites no datum).
    V, N : (n, 3) nominal vertices and unit normals.  d : (n,) deviation from the zone's
        centre, mm (NaN unscored).  governed : (n,) the zone's vertices.
    half_width : the zone's half width, mm: when no placement keeps the surface within it,
        the zone is laid at the surface's trimmed least-squares placement instead (the
        failing regions then where the surface departs from the rest), None: minimax always.

    Returns the frame to lay the zone in (not established: ``frame`` as it is).
    """
    if frame is not None and not frame.established:
        return frame
    if frame is None:
        f0 = DatumFrameResult(
            (),
            np.zeros(3),
            np.zeros(3),
            True,
            free=["every motion (no datum)"],
            free_basis=np.eye(6),
        )
    else:
        f0 = orientation_only(frame)
    sel = governed & np.isfinite(d)
    if sel.sum() < 6:
        return f0
    rot = free_rotations(f0)
    d0 = d[sel] + f0.normal_shift(V[sel], N[sel])
    t, theta, half = minimax_shift(d0, V[sel], N[sel], rot)
    if half_width is not None and half > half_width:
        # no placement contains the surface: the part fails whatever the placement, and the
        # minimax one would share a local defect's excess with the far side of the zone (a
        # bump's region reported half at the bump, half where nothing is wrong); lay it
        # where the surface mostly is instead (trimmed least squares), the defect alone out
        t, theta = least_squares_shift(d0, V[sel], N[sel], rot)
    return shift_frame(f0, t, theta, rot)


def least_squares_shift(
    d: np.ndarray, V: np.ndarray, N: np.ndarray, rotations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The small motion ``(t, theta)`` that brings ``d + N . (t + theta x V)`` nearest 0 in
    least squares, refitted once without the values beyond 3 robust standard deviations
    (a local defect does not move it). Same arguments as :func:`minimax_shift`."""
    A, to_motion = _motion_columns(V, N, rotations)
    keep = np.ones(len(d), dtype=bool)
    y = np.zeros(A.shape[1])
    for _ in range(2):
        y = np.linalg.lstsq(A[keep], -d[keep], rcond=None)[0]
        r = d + A @ y
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        keep = np.abs(r - np.median(r)) <= 3 * max(mad, 1e-6)
        if keep.sum() < A.shape[1] + 1:
            break
    return to_motion(y)


#: a motion that moves a zone's surface less than this share of its best-seen one (each
#: as the displacement it makes across the zone) is not observable: left at 0
_OBSERVABLE = 1e-3


def _motion_columns(V: np.ndarray, N: np.ndarray, rotations: np.ndarray):
    """The columns ``A`` (n, r) of the motions the zone's normals observe, and the map from
    their coefficients back to ``(t, theta)`` (translation mm, rotations rad about the
    origin). Rotations are taken about the zone's centroid and scaled by its extent, so a
    rotation is weighed as the displacement it makes across the zone (a millionth of a
    normal's tilt times a 600 mm lever is no information: about the origin it made a
    rotation of 236 rad on CTC 04's flat face)."""
    c = V.mean(axis=0)
    L = max(float(np.linalg.norm(np.ptp(V, axis=0))), 1e-6)
    cols = [N] + [np.einsum("ij,ij->i", N, np.cross(om, V - c))[:, None] / L for om in rotations]
    A = np.column_stack(cols)
    _, sv, Vt = np.linalg.svd(A[:: max(1, len(A) // 2000)], full_matrices=False)
    rank = int(np.sum(sv > _OBSERVABLE * max(sv.max(initial=0.0), 1e-300)))
    B = Vt[:rank].T

    def to_motion(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = B @ y
        theta = x[3:] / L
        t = x[:3] - (theta @ np.cross(rotations, c) if len(theta) else 0.0)
        return np.asarray(t, dtype=np.float64), theta

    return A @ B, to_motion
