"""Residual-referenced deviation: each nominal vertex from a fit of its scan points' residuals.

:func:`residual_referenced` fits the scan points' own signed distances to the curved nominal
surface (:func:`~qifreport.metrology.deviation.surface.surface_distance`) about each vertex,
on the vertex's own B-rep faces, and reads the fit at the vertex: the nominal-referenced
measure of :func:`~qifreport.metrology.deviation.local_planes.nominal_referenced` without
its curvature bias.

Signs and arrays as in :mod:`qifreport.metrology.deviation.closest` (positive: material
proud of the nominal surface; ``V`` (n, 3) mm, ``F`` (f, 3), ``P`` (m, 3) mm).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.closest import as_mesh, as_points
from qifreport.metrology.deviation.pooled import pooled_variance
from qifreport.metrology.groups import sort_within_groups
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import median_edge_length
from qifreport.registration.nearest import ball_pairs
from qifreport.registration.scan import median_spacing

__all__ = [
    "ResidualReader",
    "ball_radius",
    "residual_referenced",
]


def residual_referenced(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    residual: np.ndarray,
    normals: np.ndarray,
    point_label: np.ndarray,
    labels: np.ndarray,
    *,
    radius: float | None = None,
    min_points: int = 4,
    max_centroid_offset: float | None = 0.5,
    variance: bool = False,
    point_normals: np.ndarray | None = None,
    robust: bool = True,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Signed deviation (n,) mm of every nominal vertex from the scan points' own residuals.

    The nominal-referenced measure of :func:`nominal_referenced` without its curvature
    bias: instead of fitting a plane to the scan points near a vertex (a plane through the
    points of a 5 mm hole, or across a fillet, is off the surface by tenths of a mm), it fits
    the points' signed distances to the nominal surface (``residual``, from
    :func:`closest_points` minus :func:`curved_offset`) with a linear function of their
    tangent-plane position about the vertex and reads it at the vertex. A point counts for a
    vertex when it is within ``radius`` and its closest triangle lies on one of the vertex's
    own B-rep faces (``labels``), so the far side of a crease never enters; a vertex on
    several faces is scored only when points of each of them are near. Unscored (NaN) as in
    :func:`nominal_referenced`: fewer than ``min_points`` points, or their centroid off the
    normal line by more than ``max_centroid_offset x radius``. A vertex left unscored with
    the first ball gets a second, twice as wide (surfaces seen at a grazing angle carry
    sparser points than the median spacing). A point whose residual lies more than 5 robust
    sigmas (1.4826 x MAD) from the median of the vertex's neighbourhood is left out
    (material the nominal does not model, a burr).

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3).  P : (m, 3) scan points, mm.
    residual : (m,) signed distance of each point to the nominal surface, mm (NaN: unused).
    normals : (n, 3) unit outward vertex normals.
    point_label : (m,) the B-rep face of each point's closest triangle (``labels[face]``;
        -1: none).  labels : (f,) B-rep face of each triangle.
    radius : mm; default 1.5 x the median edge, at least 2.5 x the scan's median point
        spacing.
    point_normals : (m, 3) unit normal of each point's closest triangle: a point counts only
        within 60 degrees of the vertex normal (not a thin wall's far skin); None: any.
    variance : also return each deviation's variance (n,) mm^2: the fitted value's,
        ``s^2 (1 + y . A0 y) / N`` with ``y = A^-1 c`` (``N`` points, centroid offset ``c``,
        ``A0`` their tangent covariance, ``A`` it regularised as in the fit; ``s^2 / N`` for
        points centred on the vertex), ``s^2`` the points' scatter about the fit pooled with
        the median of the vertex's B-rep face (its lowest-numbered one); NaN where unscored
        (:func:`qifreport.metrology.acceptance.decision.vertex_uncertainty`).
    robust : leave out the points more than 5 robust sigmas off their neighbourhood
        (False: every point counts, for residuals known to be clean, a probe's).
    """
    reader = ResidualReader(
        V,
        F,
        P,
        normals,
        point_label,
        labels,
        radius=radius,
        min_points=min_points,
        max_centroid_offset=max_centroid_offset,
        point_normals=point_normals,
        robust=robust,
        keep=False,
    )
    return reader(residual, variance=variance)


class ResidualReader:
    """:func:`residual_referenced` of one mesh and one set of points, for residual after
    residual (the detectable-dent probe reads several dents on the same points).

    The arguments are :func:`residual_referenced`'s but ``residual`` and ``variance``, and
    ``keep``: whether the residual-free part of the fits (the ball pairs on their own
    faces, the tangent offsets and the normal equations' matrices) is kept for the next
    residual. Without outlier removal (``robust=False``) it does not depend on the
    residuals, only on which of them are finite, so a kept one is reused for residuals
    finite at the same points; the numbers read are :func:`residual_referenced`'s, bit
    for bit.
    """

    def __init__(
        self,
        V: np.ndarray,
        F: np.ndarray,
        P: np.ndarray,
        normals: np.ndarray,
        point_label: np.ndarray,
        labels: np.ndarray,
        *,
        radius: float | None = None,
        min_points: int = 4,
        max_centroid_offset: float | None = 0.5,
        point_normals: np.ndarray | None = None,
        robust: bool = True,
        keep: bool = True,
    ) -> None:
        self.V, self.F = as_mesh(V, F)
        self.P = as_points(P)
        self.normals, self.point_label, self.labels = normals, point_label, labels
        self.radius, self.min_points = radius, min_points
        self.max_centroid_offset, self.point_normals = max_centroid_offset, point_normals
        self.robust = robust
        self.keep = keep and not robust
        self._state: tuple | None = None  # (use, its leading fit arguments, the radius)
        self._plans: dict = {}

    def __call__(
        self, residual: np.ndarray, variance: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """The deviations (n,) mm of the points' ``residual`` (m,) mm, and their variance
        factors (n,) with ``variance`` (:func:`residual_referenced`)."""
        V, P = self.V, self.P
        r = np.asarray(residual, dtype=np.float64)
        N = np.asarray(self.normals, dtype=np.float64)
        use = np.isfinite(P).all(axis=1) & np.isfinite(r)
        n = len(V)
        dev, h, sse, dof = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n), np.zeros(n)
        if not use.any():
            return (dev, h) if variance else dev
        lead, radius = self._lead(use, N)
        own, m = lead[3], lead[4]
        args = (V, P, r, N, *lead, self.robust)
        plans = self._plans if self.keep else None
        # a second, twice as wide ball for the vertices the first left unscored (surfaces
        # seen at a grazing angle, where the points are sparser than the median spacing)
        for ball in (radius, 2.0 * radius):
            if not _fit_unscored(args, ball, self.max_centroid_offset, dev, h, sse, dof, plans):
                break
        return (dev, pooled_variance(h, sse, dof, _first_faces(own, m, n))) if variance else dev

    def _lead(self, use: np.ndarray, N: np.ndarray) -> tuple[tuple, float]:
        """The fit arguments that depend on the points ``use`` (m,) bool only (their ids,
        tree, the fewest points, the (vertex, face) keys ...) and the first ball radius;
        kept (with ``keep``) while ``use`` stays the same."""
        if self._state is not None and np.array_equal(self._state[0], use):
            return self._state[1], self._state[2]
        V, F, P = self.V, self.F, self.P
        sel = np.flatnonzero(use)
        tree = cKDTree(P[sel])
        radius = _ball_radius(V, F, P[sel], tree, self.radius)
        min_points = max(int(self.min_points), 1)
        # the (vertex, B-rep face) pairs of the mesh, as sorted keys vertex * m + face; a
        # point may be labelled with a face the mesh does not hold (a patch of a part)
        point_label, labels = self.point_label, self.labels
        m = int(max(np.max(labels), np.max(point_label, initial=-1))) + 1
        own = unique_sorted(F.astype(np.int64) * m + np.asarray(labels, dtype=np.int64)[:, None])
        pn = self.point_normals
        facing = None if pn is None else np.asarray(pn, dtype=np.float64)
        lead = (sel, tree, min_points, own, m, np.asarray(point_label), facing)
        if self.keep:
            self._state, self._plans = (use, lead, radius), {}
        return lead, radius


def ball_radius(V: np.ndarray, F: np.ndarray, P: np.ndarray, tree: cKDTree | None = None) -> float:
    """The first ball radius, mm, :func:`residual_referenced` reads the vertices of
    ``(V, F)`` with from the points ``P`` (m, 3) mm by default (``tree``: ``cKDTree(P)``)."""
    P = as_points(P)
    return _ball_radius(V, F, P, cKDTree(P) if tree is None else tree, None)


def _ball_radius(
    V: np.ndarray, F: np.ndarray, P: np.ndarray, tree: cKDTree, radius: float | None
) -> float:
    """:func:`residual_referenced`'s first ball radius, mm: ``radius``, by default 1.5 x the
    median edge and never under 2.5 point spacings of ``P`` (about 20 points in the ball: a
    curvature-refined CAD mesh can be finer than the scan); ``tree``: ``cKDTree(P)``.

    Raises
    ------
    ValueError
        When the radius is not positive.
    """
    if radius is None:
        spacing = median_spacing(P, tree, probes=2000) if len(P) > 1 else 0.0
        radius = max(1.5 * median_edge_length(V, F), 2.5 * spacing)
    radius = float(radius)
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    return radius


def _first_faces(own: np.ndarray, m: int, n: int) -> np.ndarray:
    """(n,) each vertex's lowest-numbered B-rep face (-1: none), from the sorted
    (vertex, face) keys ``own`` (vertex * m + face)."""
    first_face = np.full(n, -1, dtype=np.int64)
    vo, fo = own // m, own % m
    first = np.r_[True, vo[1:] != vo[:-1]]  # ``own`` is sorted: vertex-major
    first_face[vo[first]] = fo[first]
    return first_face


#: with ``point_normals``, a point belongs to a vertex's surface only within 60 degrees
_MIN_FACING_COS = 0.5


#: vertices per call of :func:`_residual_fit` (its ball search holds every (vertex, point)
#: pair of the call: ~10^2 per vertex)
_FIT_BLOCK = 16384


#: (vertex, B-rep face) pairs up to which :func:`_residual_fit` looks them up in a table
_PAIR_TABLE_MAX = 1 << 26


def _residual_fit(args: tuple, verts, radius, max_centroid_offset, plans=None):
    """:func:`residual_referenced` on the vertices ``verts`` with one ball ``radius``:
    (scored vertex ids, their deviations, their variance factors, the sums of squared
    residuals of their fits and those residuals' degrees of freedom). ``args``: the fits'
    leading arguments ``(V, P, r, N, sel, tree, min_points, own, m, point_label, facing,
    robust)`` (:meth:`_FitPlan.of`; ``facing``: the points' normals of
    :func:`residual_referenced`, ``point_normals``, or None). ``plans``: the
    :class:`_FitPlan` made so far for these points (a dict by ball and first vertex, not
    robust), to reuse and add to; None: none kept."""
    key = (float(radius), int(verts[0]) if len(verts) else -1)
    if plans is not None and key in plans and np.array_equal(plans[key][0], verts):
        plan, rr = plans[key][1], None
    else:
        plan, rr = _FitPlan.of(*args, verts, radius, max_centroid_offset)
        if plans is not None:
            plans[key] = (verts, plan)
    if plan is None:
        return (np.empty(0, dtype=np.int64),) + (np.empty(0),) * 4
    r = args[2]
    return plan.fit(r[plan.idx] if rr is None else rr)


class _FitPlan:
    """The part of :func:`_residual_fit`'s fits that does not depend on the residuals,
    once its pairs are chosen: the (point, vertex) pairs ``idx`` (p,) with each one's
    ``row`` (p,) among the vertices ``vid`` (v,), their ``counts`` (v,), centroids ``c``
    (v, 3) and centred tangent offsets ``R`` (p, 3) mm, the regularised normal matrices
    ``A`` (v, 3, 3), the variance factors ``hv`` (v,) and the vertices read (``enough``,
    (v,) bool)."""

    def __init__(self, idx, row, vid, counts, c, R, A, hv, enough):
        self.idx, self.row, self.vid, self.counts = idx, row, vid, counts
        self.c, self.R, self.A, self.hv, self.enough = c, R, A, hv, enough

    @classmethod
    def of(
        cls,
        V,
        P,
        r,
        N,
        sel,
        tree,
        min_points,
        own,
        m,
        point_label,
        facing,
        robust,
        verts,
        radius,
        max_centroid_offset,
    ) -> tuple[_FitPlan | None, np.ndarray | None]:
        """The plan of :func:`_residual_fit` (its arguments) and the pairs' residuals
        (p,) mm in its order; (None, None) when no vertex has pairs."""
        n = len(V)
        # every (vertex, point) pair within the ball, of the vertices with enough points
        pi, pj = ball_pairs(V[verts], tree, radius, min_points)
        if len(pi) == 0:
            return None, None
        idx, vrt = _own_face_pairs(sel[pj], verts[pi], point_label, own, m, n)
        if facing is not None:
            same_side = np.einsum("ij,ij->i", facing[idx], N[vrt]) >= _MIN_FACING_COS
            idx, vrt = idx[same_side], vrt[same_side]
        if len(idx) == 0:
            return None, None
        idx, vrt, rr = _without_outliers(idx, vrt, r) if robust else _by_vertex(idx, vrt, r)
        # rows gathered by np.take (qifreport.registration.arrays)
        Q = np.take(P, idx, axis=0)
        Q -= np.take(V, vrt, axis=0)
        nv = np.take(N, vrt, axis=0)
        Q -= np.einsum("ij,ij->i", Q, nv)[:, None] * nv  # tangent-plane offsets
        # the vertices (ascending) and each pair's row among them: ``vrt`` is sorted
        first = np.flatnonzero(np.r_[True, vrt[1:] != vrt[:-1]])
        vid = vrt[first]
        counts = np.diff(np.r_[first, len(vrt)])
        row = np.repeat(np.arange(len(vid)), counts)
        enough = counts >= min_points
        c = np.stack([_group_sum(row, Q[:, a], len(vid)) for a in range(3)], axis=1)
        c /= counts[:, None]
        R = Q - np.take(c, row, axis=0)
        # weighted least squares r = rbar + g . (q - c) in the tangent plane: 3x3 normal
        # equations on the centred offsets (rank 2; regularised along the normal)
        A0 = np.empty((len(vid), 3, 3))
        for a in range(3):
            for b in range(a, 3):
                A0[:, a, b] = A0[:, b, a] = _group_sum(row, R[:, a] * R[:, b], len(vid)) / counts
        # ridge (0.2 radius)^2: a gradient the points' spread cannot carry (a sliver, a line
        # of points at a scan edge) shrinks towards 0 instead of extrapolating noise; and
        # the normal direction (no spread at all) is held at 0
        ridge = (0.2 * radius) ** 2
        A = A0 + ridge * np.eye(3)[None] + np.einsum("ij,ik->ijk", N[vid], N[vid]) * radius**2
        # var(t) / var(r) = (1 + c . A^-1 A0 A^-1 c) / N: the mean and the slope are
        # uncorrelated (centred offsets), the slope's covariance is A^-1 A0 A^-1 / N
        y = np.linalg.solve(A, c[..., None])[..., 0]
        hv = (1.0 + np.einsum("ij,ijk,ik->i", y, A0, y)) / counts
        if max_centroid_offset is not None:
            enough &= np.linalg.norm(c, axis=1) <= float(max_centroid_offset) * radius
        return cls(idx, row, vid, counts, c, R, A, hv, enough), rr

    def fit(self, rr: np.ndarray) -> tuple[np.ndarray, ...]:
        """:func:`_residual_fit`'s answer for the pairs' residuals ``rr`` (p,) mm."""
        row, counts, c, R, nv = self.row, self.counts, self.c, self.R, len(self.vid)
        rbar = _group_sum(row, rr, nv) / counts
        dr = rr - rbar[row]
        rhs = np.stack([_group_sum(row, R[:, a] * dr, nv) for a in range(3)], axis=1)
        rhs /= counts[:, None]
        g = np.linalg.solve(self.A, rhs[..., None])[..., 0]
        t = rbar - np.einsum("ij,ij->i", g, c)  # the linear fit at the vertex (q = 0)
        e = dr - np.einsum("ij,ij->i", R, np.take(g, row, axis=0))  # residuals about the fit
        sse = _group_sum(row, e * e, nv)
        dof = counts - 3.0
        ok = self.enough
        return self.vid[ok], t[ok], self.hv[ok], sse[ok], dof[ok]


def _group_sum(row: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    """(n,) the sums of ``w`` (p,) over each ``row`` (p,) of ``n``, in the pairs' order."""
    return np.bincount(row, weights=w, minlength=n)


def _fit_unscored(
    args: tuple,
    ball: float,
    max_centroid_offset: float | None,
    dev: np.ndarray,
    h: np.ndarray,
    sse: np.ndarray,
    dof: np.ndarray,
    plans: dict | None = None,
) -> bool:
    """:func:`_residual_fit` (``args``: its leading arguments) with the ball ``ball``, mm,
    on the vertices ``dev`` (n,) leaves unscored (NaN), filling in ``dev``, ``h``, ``sse``
    and ``dof`` (n,) where it scores them; False: none was left unscored. ``plans``: as
    :func:`_residual_fit`'s."""
    todo = np.flatnonzero(np.isnan(dev))
    if len(todo) == 0:
        return False
    # in blocks of vertices: each vertex's fit is its own (the same numbers), and the
    # (vertex, point) pairs of a large part's ball search stay a bounded size
    for s in range(0, len(todo), _FIT_BLOCK):
        block = todo[s : s + _FIT_BLOCK]
        vid, t, hv, ev, dv = _residual_fit(args, block, ball, max_centroid_offset, plans)
        dev[vid] = t
        h[vid] = hv
        sse[vid] = ev
        dof[vid] = dv
    return True


def _own_face_pairs(
    idx: np.ndarray,
    vrt: np.ndarray,
    point_label: np.ndarray,
    own: np.ndarray,
    m: int,
    n: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The (point ``idx``, vertex ``vrt``) pairs whose point lies on one of the vertex's
    own B-rep faces (``own``: sorted keys vertex * m + face; ``n`` vertices), of the
    vertices with points on every one of their faces."""
    pl = point_label[idx]
    key = vrt * m + np.maximum(pl, 0)
    # (vertex, face) pairs looked up in a table of them where it is small, else by bisection
    table = n * m <= _PAIR_TABLE_MAX
    if table:
        is_own = np.zeros(n * m, dtype=bool)
        is_own[own] = True
        keep = (pl >= 0) & is_own[key]
    else:
        pos = np.clip(np.searchsorted(own, key), 0, len(own) - 1)
        keep = (pl >= 0) & (own[pos] == key)
    idx, vrt = idx[keep], vrt[keep]
    # a vertex on several faces (a crease) is measured only where every one of its faces
    # was: the back skin of a sheet is not scored from its edge face's points
    faces_of = np.bincount(own // m, minlength=n)
    if table:
        seen = np.zeros(n * m, dtype=bool)
        seen[key[keep]] = True
        seen_of = seen.reshape(n, m).sum(axis=1)
    else:
        seen_of = np.bincount(unique_sorted(key[keep]) // m, minlength=n)
    whole = (seen_of == faces_of)[vrt]
    return idx[whole], vrt[whole]


def _by_vertex(
    idx: np.ndarray, vrt: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs sorted by vertex, every point kept: points, vertices, residuals (mm)."""
    order = np.argsort(vrt, kind="stable")
    return idx[order], vrt[order], r[idx[order]]


def _without_outliers(
    idx: np.ndarray, vrt: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs sorted by vertex, then by residual, without a point whose residual is more
    than 5 robust sigmas from its neighbourhood's median (material the nominal does not
    have: a rib standing on the surface, a burr): points, vertices, residuals (mm)."""
    order = sort_within_groups(vrt, r[idx])
    idx, vrt = idx[order], vrt[order]  # from here on by vertex, then by residual
    rr = r[idx]
    first = np.flatnonzero(np.r_[True, vrt[1:] != vrt[:-1]])
    size = np.diff(np.r_[first, len(vrt)])
    med = np.repeat(rr[first + size // 2], size)
    dev_abs = np.abs(rr - med)
    o2 = sort_within_groups(vrt, dev_abs)
    mad = np.repeat(dev_abs[o2][first + size // 2], size)
    keep = dev_abs <= np.maximum(5.0 * 1.4826 * mad, 1e-9)
    idx, vrt, rr = idx[keep], vrt[keep], rr[keep]
    return idx, vrt, rr
