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
    V, F = as_mesh(V, F)
    P = as_points(P)
    r = np.asarray(residual, dtype=np.float64)
    N = np.asarray(normals, dtype=np.float64)
    use = np.isfinite(P).all(axis=1) & np.isfinite(r)
    n = len(V)
    dev, h, sse, dof = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n), np.zeros(n)
    if not use.any():
        return (dev, h) if variance else dev
    sel = np.flatnonzero(use)
    tree = cKDTree(P[sel])
    radius = _ball_radius(V, F, P[sel], tree, radius)
    min_points = max(int(min_points), 1)
    # the (vertex, B-rep face) pairs of the mesh, as sorted keys vertex * m + face; a
    # point may be labelled with a face the mesh does not hold (a patch of a part)
    m = int(max(np.max(labels), np.max(point_label, initial=-1))) + 1
    own = unique_sorted(F.astype(np.int64) * m + np.asarray(labels, dtype=np.int64)[:, None])
    facing = None if point_normals is None else np.asarray(point_normals, dtype=np.float64)
    args = (V, P, r, N, sel, tree, min_points, own, m, np.asarray(point_label), facing, robust)
    # a second, twice as wide ball for the vertices the first left unscored (surfaces seen
    # at a grazing angle, where the points are sparser than the median spacing)
    for ball in (radius, 2.0 * radius):
        if not _fit_unscored(args, ball, max_centroid_offset, dev, h, sse, dof):
            break
    return (dev, pooled_variance(h, sse, dof, _first_faces(own, m, n))) if variance else dev


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


def _residual_fit(
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
):
    """:func:`residual_referenced` on the vertices ``verts`` with one ball ``radius``:
    (scored vertex ids, their deviations, their variance factors, the sums of squared
    residuals of their fits and those residuals' degrees of freedom). ``facing``: the
    points' normals of :func:`residual_referenced` (``point_normals``), or None."""
    n = len(V)
    none = (np.empty(0, dtype=np.int64),) + (np.empty(0),) * 4
    # every (vertex, point) pair within the ball, of the vertices with enough points
    pi, pj = ball_pairs(V[verts], tree, radius, min_points)
    if len(pi) == 0:
        return none
    idx, vrt = _own_face_pairs(sel[pj], verts[pi], point_label, own, m, n)
    if facing is not None:
        same_side = np.einsum("ij,ij->i", facing[idx], N[vrt]) >= _MIN_FACING_COS
        idx, vrt = idx[same_side], vrt[same_side]
    if len(idx) == 0:
        return none
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

    def _sum(w: np.ndarray) -> np.ndarray:
        return np.bincount(row, weights=w, minlength=len(vid))

    c = np.stack([_sum(Q[:, a]) for a in range(3)], axis=1) / counts[:, None]
    rbar = _sum(rr) / counts
    R = Q - np.take(c, row, axis=0)
    dr = rr - rbar[row]
    # weighted least squares r = rbar + g . (q - c) in the tangent plane: 3x3 normal
    # equations on the centred offsets (rank 2; regularised along the normal)
    A0 = np.empty((len(vid), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            A0[:, a, b] = A0[:, b, a] = _sum(R[:, a] * R[:, b]) / counts
    # ridge (0.2 radius)^2: a gradient the points' spread cannot carry (a sliver, a line of
    # points at a scan edge) shrinks towards 0 instead of extrapolating noise; and the
    # normal direction (no spread at all) is held at 0
    ridge = (0.2 * radius) ** 2
    A = A0 + ridge * np.eye(3)[None] + np.einsum("ij,ik->ijk", N[vid], N[vid]) * radius**2
    rhs = np.stack([_sum(R[:, a] * dr) for a in range(3)], axis=1) / counts[:, None]
    g = np.linalg.solve(A, rhs[..., None])[..., 0]
    t = rbar - np.einsum("ij,ij->i", g, c)  # the linear fit at the vertex (q = 0)
    # var(t) / var(r) = (1 + c . A^-1 A0 A^-1 c) / N: the mean and the slope are uncorrelated
    # (centred offsets), the slope's covariance is A^-1 A0 A^-1 / N
    y = np.linalg.solve(A, c[..., None])[..., 0]
    hv = (1.0 + np.einsum("ij,ijk,ik->i", y, A0, y)) / counts
    e = dr - np.einsum("ij,ij->i", R, np.take(g, row, axis=0))  # residuals about the fit
    sse = _sum(e * e)
    dof = counts - 3.0
    if max_centroid_offset is not None:
        enough &= np.linalg.norm(c, axis=1) <= float(max_centroid_offset) * radius
    return vid[enough], t[enough], hv[enough], sse[enough], dof[enough]


def _fit_unscored(
    args: tuple,
    ball: float,
    max_centroid_offset: float | None,
    dev: np.ndarray,
    h: np.ndarray,
    sse: np.ndarray,
    dof: np.ndarray,
) -> bool:
    """:func:`_residual_fit` (``args``: its leading arguments) with the ball ``ball``, mm,
    on the vertices ``dev`` (n,) leaves unscored (NaN), filling in ``dev``, ``h``, ``sse``
    and ``dof`` (n,) where it scores them; False: none was left unscored."""
    todo = np.flatnonzero(np.isnan(dev))
    if len(todo) == 0:
        return False
    # in blocks of vertices: each vertex's fit is its own (the same numbers), and the
    # (vertex, point) pairs of a large part's ball search stay a bounded size
    for s in range(0, len(todo), _FIT_BLOCK):
        block = todo[s : s + _FIT_BLOCK]
        vid, t, hv, ev, dv = _residual_fit(*args, block, ball, max_centroid_offset)
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
