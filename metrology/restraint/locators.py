"""Where a locator's face went: a local rigid fit of the nominal around the contact.

A locator on a narrow face (a stop on a panel's 1.8 mm end face) is read from the scan
points on that face. When the free state moved the face across its own width (a flange
lowered 0.9 mm beside a 1.8 mm face), proximity alone reads the neighbouring faces: the
points on the edge between them lie as close to the locator's face as to their own, and a
scan normal estimated across the edge faces both ways. The sample panel's locator C1 then
read -0.71 mm where its face had moved +0.02 mm, and the held part was pushed 0.5-0.6 mm
along it (bench/fixture.py, flange springback cases).

A gauge does not measure a face alone: it seats on the feature. :func:`patch_offset` fits
the nominal patch around the contact (the locator's face and its neighbours, within a few
pad radii) to the scan points there by a point-to-plane rigid fit (Gauss-Newton, scan
normals compatible with the patch's), so the neighbouring faces place the patch in the
directions the locator's face cannot, and reads the contact's free-state offset from the
fitted motion.

Public API
----------
:func:`patch_offset`
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.closest import closest_points
from qifreport.registration.restraint.restrained import rigid_motion

__all__ = ["patch_offset"]

log = logging.getLogger(__name__)

#: degrees: a scan point pairs with a patch triangle whose normal is within this of its own
NORMAL_ANGLE = 45.0
#: Gauss-Newton rounds of the local fit and the step (mm, rad x radius) below which it stops
ROUNDS = 10
SETTLED = 1e-4


def patch_offset(
    V: np.ndarray,
    F: np.ndarray,
    tri_normals: np.ndarray,
    P: np.ndarray,
    Ns: np.ndarray,
    position: np.ndarray,
    normal: np.ndarray,
    radius: float,
    gate: float,
    *,
    tree: cKDTree | None = None,
    min_points: int = 12,
) -> float:
    """A contact's free-state offset along its surface normal from a local rigid fit.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles; ``tri_normals`` (f, 3) their
        outward unit normals.
    P : (m, 3) the seated scan, mm; ``Ns`` (m, 3) its outward unit normals.
    position : (3,) the contact on the nominal, mm; ``normal`` (3,) the outward unit normal
        of its face there.
    radius : mm, the patch fitted: the scan points within ``radius`` of the contact, the
        nominal triangles within ``radius + gate``.
    gate : mm, the largest distance of a pair (the free state's largest plausible motion
        there).
    tree : ``cKDTree(P)``, when at hand.
    min_points : pairs needed, besides a few on the contact's own face.

    Returns
    -------
    The offset, mm (outward positive, as the clamp readings); NaN when the patch is not
    seen (too few pairs, or too few on faces facing the contact's normal).
    """
    c = np.asarray(position, dtype=np.float64)
    n0 = np.asarray(normal, dtype=np.float64)
    n0 = n0 / np.linalg.norm(n0)
    tree = cKDTree(P) if tree is None else tree
    idx = np.asarray(tree.query_ball_point(c, radius), dtype=np.int64)
    if len(idx) < min_points:
        return float("nan")
    cent = V[F].mean(axis=1)
    tris = np.flatnonzero(np.linalg.norm(cent - c, axis=1) <= radius + gate + _edge(V, F))
    if len(tris) == 0:
        return float("nan")
    Fp, Np = F[tris], tri_normals[tris]
    Q0, Nq0 = P[idx], Ns[idx]
    cos = np.cos(np.radians(NORMAL_ANGLE))
    R, T = np.eye(3), np.zeros(3)  # the scan's motion so far: q -> R q + T
    keep = own = np.zeros(len(idx), dtype=bool)
    for _ in range(ROUNDS):
        Q = Q0 @ R.T + T
        C, local, _ = closest_points(V, Fp, Q)
        n = Np[local]
        r = np.einsum("ij,ij->i", Q - C, n)
        keep = (np.einsum("ij,ij->i", Nq0 @ R.T, n) >= cos) & (np.abs(r) <= gate)
        own = keep & (n @ n0 >= cos)
        if keep.sum() < min_points or own.sum() < 3:
            return float("nan")
        q, nk, rk = Q[keep] - c, n[keep], r[keep]
        J = np.c_[np.cross(q, nk), nk]  # d r / d (omega, tau) of the scan's motion about c
        H = J.T @ J
        H += 1e-6 * np.trace(H) / 6.0 * np.eye(6)  # a direction no face constrains stays 0
        x = -np.linalg.solve(H, J.T @ rk)
        dR, dT = rigid_motion(x, c)
        R, T = dR @ R, dR @ T + dT
        if np.linalg.norm(x[3:]) + np.linalg.norm(x[:3]) * radius < SETTLED:
            break
    # the free state's point at the contact is where the scan's motion takes onto it
    p_free = R.T @ (c - T)
    off = float((p_free - c) @ n0)
    log.debug(
        "patch at (%.1f, %.1f, %.1f): %d pairs (%d on the contact's face), offset %+.3f mm",
        *c,
        int(keep.sum()),
        int(own.sum()),
        off,
    )
    return off


def _edge(V: np.ndarray, F: np.ndarray) -> float:
    """The longest triangle edge, mm (a triangle whose centroid is that far outside the
    patch may still reach into it)."""
    E = V[F[:, [1, 2, 0]]] - V[F]
    return float(np.linalg.norm(E, axis=2).max())
