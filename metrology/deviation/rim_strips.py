"""The scan's edge in a strip about each rim vertex of the nominal.

For each rim vertex ``v`` (:class:`~qifreport.metrology.deviation.rim.RimFrames`: rim tangent
``t``, surface normal ``n``, outward in-plane normal ``b``) of the trim-edge deviation
(:mod:`qifreport.metrology.deviation.edges`), the scan points in a strip about ``v`` -- within
``radius`` of it along ``t``, within ``radius`` of its tangent plane along ``n`` -- are
projected on ``b``; ``u = (p - v) . b`` is how far beyond the nominal edge a point lies. The
scan's edge is where the strip's points end:

1. a coarse edge ``e0``, the 95th percentile of ``u`` over a wide window
   ``[-max_gap, +max_gap]``;
2. twice: a strip of depth ``D = radius`` behind the current estimate, ``u in [e - D,
   e + D / 2]`` (stray points farther out are ignored), and the end of its ``N`` values
   ``e = 2 u_(j) - u_(2j)``, ``u_(j)`` the ``j``-th largest, ``j = max(2, 2 % of N)``.

``u_(j)`` is the outermost points' position read past the ``j - 1`` outermost (a stray point
beyond the edge does not carry it); ``u_(j) - u_(2j)`` is the spacing of the points across
the edge measured there, so the estimate adds what the sampling leaves between the
outermost points and the end of the surface, as the points themselves show it, not as a
model of their spread assumes. Points in rows along the edge (a scanner's pixel grid, a
mesh's own vertices: the outermost row holds at least ``2j`` points) read the outermost
row exactly (``u_(j) = u_(2j)``); points spread at random over the surface read the true
edge without bias (the ``j``-th of ``N`` uniform points lies ``j`` mean gaps inside the
end, the ``2j``-th ``2j``). The sampling leaves the edge's position uncertain by up to one
point spacing across it (the true edge lies anywhere between the outermost row and the next,
unsampled one): :attr:`~qifreport.metrology.deviation.edge_statistics.EdgeDeviation.spacing`
reports it. Measured on a 100 x 60 mm plate, one side 1 mm long (0.02 mm noise across the
plate; median per side, standard deviation per rim vertex): points at random, 8 per mm^2,
within 0.03 mm (0.045 mm), 2 per mm^2 within 0.02 mm (0.13 mm); a square grid turned 7
degrees to the sides, pitch 0.35 mm, within 0.02 mm (0.02 mm), pitch 1.05 mm within 0.07
mm (0.08 mm); the same grids aligned with the sides read their outermost rows, 0.15 to 0.35
mm and 0.5 to 0.75 mm inside the true edges (the phase of the grid). A mesh nominal scanned
at its own vertices (the shell, 5 um noise) reads its rim within 0.02 mm (P05/P95).

All lengths are mm; ``P`` (m, 3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.rim import RimFrames
from qifreport.metrology.groups import sort_within_groups
from qifreport.registration.nearest import ball_pairs
from qifreport.registration.normals import pca_normals

__all__ = [
    "rim_strips",
]


#: quantile of the coarse first pass over the wide window
_COARSE_QUANTILE = 0.95
#: the edge's outermost order statistic ``j`` is this share of the strip's points (at least 2)
_TOP_SHARE = 0.02
#: each side of a rim vertex (along the rim) must hold this share of the strip's points
_MIN_SIDE_SHARE = 0.2
#: the edge estimates of the strip's two halves (centres ``radius`` apart) may differ by this
#: much x ``radius`` (a slope of 0.4, 22 degrees); more: the scan's edge is not the trim edge
_MAX_SLANT = 0.4
#: a seen strip holds at least this share of the median seen strip's points
_MIN_COUNT_SHARE = 0.5
#: crease mode: a scan point belongs to a patch's surface within 45 degrees of its normal
#: (a point on a right-angled crease, half its PCA neighbours on each face, tilts by 45)
_MIN_FACING_COS = float(np.cos(np.deg2rad(45.0)))
#: crease mode: the normal window, as a fraction of ``radius`` (the patch on the far side of
#: a thin wall lies one wall thickness away)
_CREASE_WINDOW = 0.25
#: rim vertices measured at once (bounds the temporary (point, vertex) pairs)
_CHUNK_VERTICES = 2000


def _group_top(group: np.ndarray, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group (0..k-1) its ``j``-th and ``2j``-th largest values ``x_(j), x_(2j)``
    (``j = max(2, _TOP_SHARE x count)``); NaN with fewer than 4 values."""
    xj, x2j = np.full(k, np.nan), np.full(k, np.nan)
    if len(x) == 0:
        return xj, x2j
    xs = x[sort_within_groups(group, x)]
    cnt = np.bincount(group, minlength=k)
    end = np.cumsum(cnt)  # one past each group's largest value
    has = cnt >= 4
    j = np.maximum(2, np.floor(_TOP_SHARE * cnt[has]).astype(np.int64))
    xj[has] = xs[end[has] - j]
    x2j[has] = xs[end[has] - 2 * j]
    return xj, x2j


def _group_quantile(group: np.ndarray, x: np.ndarray, q: float, k: int) -> np.ndarray:
    """Per group (0..k-1) the ``q`` quantile (linear interpolation) of ``x``; NaN if empty."""
    out = np.full(k, np.nan)
    if len(x) == 0:
        return out
    order = sort_within_groups(group, x)
    xs = x[order]
    cnt = np.bincount(group, minlength=k)
    start = np.cumsum(cnt) - cnt
    has = cnt > 0
    posf = (cnt[has] - 1) * q
    lo = np.floor(posf).astype(np.int64)
    hi = np.minimum(lo + 1, cnt[has] - 1)
    frac = posf - lo
    s = start[has]
    out[has] = xs[s + lo] * (1.0 - frac) + xs[s + hi] * frac
    return out


def _strip_edges(
    P: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    T: np.ndarray,
    N: np.ndarray,
    B: np.ndarray,
    radius: float,
    window: float,
    max_gap: float,
    min_points: int,
    crease: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scan's edge along ``B`` at each rim point ``X`` (j, 3) (module docstring).

    Returns the edge estimate (NaN: too few points), the final strip's point count, the
    share of them on the ``+T`` side, and the disagreement of the strip's two halves (their
    outermost points ``u_(j)``), mm.
    """
    km = len(X)
    e = np.full(km, np.nan)
    n2 = np.zeros(km, dtype=np.int64)
    share = np.zeros(km)
    slant = np.full(km, np.inf)
    reach = float(np.sqrt(radius**2 + max_gap**2 + window**2))
    # every (rim point, scan point) pair within reach, as flat arrays from one dual-tree
    # search (their order does not matter: each rim point's values are sorted or counted)
    grp, idx = ball_pairs(X, tree, reach)
    if len(grp) == 0:
        return e, n2, share, slant
    # rows gathered by np.take (qifreport.registration.arrays)
    Q = np.take(P, idx, axis=0) - np.take(X, grp, axis=0)
    along = np.einsum("ij,ij->i", Q, np.take(T, grp, axis=0))
    u = np.einsum("ij,ij->i", Q, np.take(B, grp, axis=0))
    z = np.einsum("ij,ij->i", Q, np.take(N, grp, axis=0))
    keep = (np.abs(along) <= radius) & (np.abs(z) <= window) & (np.abs(u) <= max_gap)
    if crease and keep.any():
        # only points of the patch's own surface: not the side wall or the next face
        cand, back = np.unique(idx[keep], return_inverse=True)
        Ns = pca_normals(P[cand])
        facing = np.abs(np.einsum("ij,ij->i", Ns[back], N[grp[keep]])) >= _MIN_FACING_COS
        keep[np.flatnonzero(keep)[~facing]] = False
    grp, along, u = grp[keep], along[keep], u[keep]

    # pass 1: coarse edge over the wide window
    n1 = np.bincount(grp, minlength=km)
    e = _group_quantile(grp, u, _COARSE_QUANTILE, km)
    e[n1 < min_points] = np.nan
    # pass 2 (twice): where the points end in a strip of depth `radius` behind it
    for _ in range(2):
        lo = e - radius
        sel = np.isfinite(e[grp]) & (u >= lo[grp]) & (u <= (e + 0.5 * radius)[grp])
        g2, a2, u2 = grp[sel], along[sel], u[sel]
        n2 = np.bincount(g2, minlength=km)
        uj, u2j = _group_top(g2, u2, km)
        e = 2.0 * uj - u2j
        e[n2 < min_points] = np.nan
    plus = a2 > 0
    share = np.divide(
        np.bincount(g2, weights=plus.astype(float), minlength=km),
        n2,
        out=np.zeros(km),
        where=n2 > 0,
    )
    # the scan's edge must run along the rim: the two halves of the strip agree (a dropout
    # hole's boundary crossing the rim gives a slanted "edge")
    halves = [_group_top(g2[m], u2[m], km)[0] for m in (~plus, plus)]
    slant = np.abs(halves[1] - halves[0])
    return e, n2, share, np.where(np.isfinite(slant), slant, np.inf)


def rim_strips(
    P: np.ndarray,
    tree: cKDTree,
    rim: RimFrames,
    measured: np.ndarray,
    radius: float,
    max_gap: float,
    min_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scan's edge in the strip of each ``measured`` rim vertex (k,), mm along its
    outward direction, the strip's points (k,), and whether the edge is seen (k,) bool:
    enough points, on both halves of the strip and agreeing (no dropout hole's boundary
    crossing the rim), and not a strip a hole cut (:func:`_strip_edges`)."""
    window = _CREASE_WINDOW * radius if rim.mode == "crease" else radius
    parts = []
    for c0 in range(0, len(measured), _CHUNK_VERTICES):
        sl = measured[c0 : c0 + _CHUNK_VERTICES]
        parts.append(
            _strip_edges(
                P,
                tree,
                rim.position[sl],
                rim.tangent[sl],
                rim.normal[sl],
                rim.outward[sl],
                radius,
                window,
                max_gap,
                min_points,
                crease=rim.mode == "crease",
            )
        )
    e, n2, share, slant = (np.concatenate(x) for x in zip(*parts, strict=True))
    ok = (
        np.isfinite(e)
        & (n2 >= min_points)
        & (share >= _MIN_SIDE_SHARE)
        & (share <= 1.0 - _MIN_SIDE_SHARE)
        & (slant <= _MAX_SLANT * radius)
    )
    if ok.any():  # a strip cut by a dropout hole holds fewer points than a full one
        ok &= n2 >= _MIN_COUNT_SHARE * np.median(n2[ok])
    return e, n2, ok
