"""Geodesic bilateral curvature descriptors (paper Sections 5.1.2-5.1.3).

Each curvature field ``f`` in ``{H, K, S, C}`` (:mod:`qifreport.registration.pose.curvature`) is
smoothed by a bilateral filter whose spatial weight is a Gaussian of the geodesic distance
``g(i, j)`` and whose range weight is a Gaussian of the field difference,

    B[f]_i = sum_j a_j exp(-g^2 / (2 s^2)) exp(-(f_i - f_j)^2 / (2 r_f^2)) f_j / Z_i,

over the geodesic ball ``g(i, j) <= 3 s``, at ``L`` spatial scales ``s = rho_l h`` (``h`` the
model's mean edge length, the same length in mm on both sides so the descriptors compare).
``a_j`` is the surface area a sample stands for (mesh: barycentric vertex area; scan:
``spacing^2`` of its neighbourhood), so the filter approximates the same surface integral on
a non-uniform mesh and on a uniformly sampled scan; the paper's formula is the ``a_j = 1``
case on a uniform sampling.

Before filtering, :func:`presmooth` brings both sides to one resolution: the mesh puts a
crease's curvature on the crease vertices (a spike ~ angle / edge length), a quadric fit
spreads it over its neighbourhood; a small area-weighted Gaussian average of ``H`` and ``K``
(sigma ~ one edge length) turns both into the same smooth curvature measure, and ``S, C`` are
recomputed from the averages.

Geodesic distances are Dijkstra distances on the mesh edge graph and on the scan's symmetric
k-NN graph (``scipy.sparse.csgraph.dijkstra`` with ``limit = 3 s_max``), computed only from
*keypoints*: a farthest-point sample of a few hundred to ~2000 samples per side
(:func:`geodesic_balls`, reusable across range bandwidths). Every sample is still used as a
neighbour ``j``; only the filtered value is evaluated at keypoints.

Range bandwidth (paper: ``sigma_r = max(sigma_r0, c eta)``, :func:`range_bandwidths`):
``eta_f`` is the scan noise measured in the units of each field, the robust spread
(1.4826 MAD) of ``f_i`` minus the mean of ``f`` over its k nearest scan neighbours
(:func:`field_noise`, on the raw scan fields); ``sigma_r0`` is a floor, ``r0`` times the
robust spread of the model field, so a clean scan does not collapse the range gate. The
descriptor of a keypoint is the ``4 L`` filtered values, field-major
(``H_1..H_L, K_1..K_L, S_1..S_L, C_1..C_L``). :func:`joint_normalize` z-scores model and scan
descriptors with one shared mean and variance per feature (paper Section 5.1.4).

Measured on the fandisk (100 mm, subdivided once, 2 views, 0.02 mm noise): descriptors of
corresponding points correlate 0.6-0.9 per feature, but flat faces and repeated creases make
most descriptors non-unique: of the paper's mutual nearest neighbours with a ratio test only
~3-8 % land within 2 % of the diagonal of the true correspondence (the paper reports 103 of
209). :mod:`qifreport.registration.pose.prealign` therefore matches only the salient half of the
keypoints, keeps 3 candidates per scan keypoint and lets a compatibility-guided RANSAC find
the consistent few.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from itertools import chain

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import edges
from qifreport.registration.pose.curvature import CurvatureFields, shape_fields

__all__ = [
    "FIELDS",
    "SCALES",
    "bilateral_descriptors",
    "bilateral_filter",
    "DescriptorSet",
    "farthest_points",
    "field_noise",
    "geodesic_balls",
    "GeodesicBalls",
    "joint_normalize",
    "knn_graph",
    "mesh_graph",
    "presmooth",
    "range_bandwidths",
    "robust_spread",
]

log = logging.getLogger(__name__)

#: Default spatial scales, in mean edge lengths (paper Section 8.1).
SCALES: tuple[float, ...] = (1.5, 2.4, 3.8, 6.0)
FIELDS = ("H", "K", "S", "C")


@dataclass
class DescriptorSet:
    """Descriptors of one surface, evaluated at its keypoints.

    Attributes
    ----------
    index : (k,) int64 sample index of each keypoint (mesh vertex or scan point).
    X : (k, 3) keypoint positions, mm.
    D : (k, 4 L) raw (unnormalised) descriptors, field-major.
    scales : (L,) spatial bandwidths ``sigma_s``, mm.
    sigma_r : (4,) range bandwidths of H (1/mm), K (1/mm^2), S (1), C (1/mm).
    """

    index: np.ndarray
    X: np.ndarray
    D: np.ndarray
    scales: np.ndarray
    sigma_r: np.ndarray

    def flipped(self) -> DescriptorSet:
        """The descriptors of the oppositely oriented surface (``H`` and ``S`` negated).

        The bilateral filter commutes with negating a field, so flipping the normals only
        changes the sign of the ``H`` and ``S`` blocks.
        """
        L = len(self.scales)
        D = self.D.copy()
        D[:, 0:L] *= -1.0
        D[:, 2 * L : 3 * L] *= -1.0
        return DescriptorSet(self.index, self.X, D, self.scales, self.sigma_r)


def farthest_points(
    X: np.ndarray, k: int, seed: int = 0, tree: cKDTree | None = None
) -> np.ndarray:
    """Indices (k,) of a farthest-point sample of ``X`` (n, 3), starting at a random point.

    Each new sample ``p`` lies at the largest distance ``D`` of any point from the samples
    so far, so only points within ``D`` of ``p`` can come closer to the sample: they are
    found with a k-d tree (``tree``: ``cKDTree(X)``, built when not given) instead of
    measuring all ``n`` points at each step. The squared distances are the same numbers as
    the full sweep's, so the sample is the same, index for index.
    """
    n = len(X)
    if k >= n:
        return np.arange(n, dtype=np.int64)
    if k <= 0:
        return np.empty(0, dtype=np.int64)
    rng = np.random.default_rng(seed)
    out = np.empty(k, dtype=np.int64)
    out[0] = rng.integers(n)
    X = np.ascontiguousarray(X, dtype=np.float64)
    x, y, z = X[:, 0].copy(), X[:, 1].copy(), X[:, 2].copy()
    tree = cKDTree(X) if tree is None else tree
    d = np.full(n, np.inf)  # squared distance to the nearest sample so far, mm^2
    for i in range(k):
        if i:
            out[i] = int(np.argmax(d))
        p = X[out[i]]
        if i:
            # the ball of radius sqrt(D) (a hair wider, for the tree's rounding) holds every
            # point whose distance can drop
            r = float(np.sqrt(d[out[i]])) * (1.0 + 1e-9)
            near = np.asarray(tree.query_ball_point(p, r, return_sorted=False), dtype=np.intp)
        else:
            near = slice(None)
        dd = (x[near] - p[0]) ** 2
        dd += (y[near] - p[1]) ** 2
        dd += (z[near] - p[2]) ** 2
        d[near] = np.minimum(d[near], dd)
    return out


def mesh_graph(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    """Symmetric edge graph (n, n) of the mesh weighted by edge length, mm."""
    E = edges(F)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    n = len(V)
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    return (G + G.T).tocsr()


def knn_graph(P: np.ndarray, k: int = 8, tree: cKDTree | None = None) -> sp.csr_matrix:
    """Symmetric k-NN graph (m, m) of the points weighted by Euclidean distance, mm."""
    tree = tree or cKDTree(P)
    k = min(k + 1, len(P))
    d, idx = tree.query(P, k=k, workers=-1)
    m = len(P)
    rows = np.repeat(np.arange(m), k - 1)
    G = sp.coo_matrix((d[:, 1:].ravel(), (rows, idx[:, 1:].ravel())), shape=(m, m)).tocsr()
    return G.maximum(G.T).tocsr()


def field_noise(
    fields: np.ndarray, P: np.ndarray, k: int = 10, tree: cKDTree | None = None
) -> np.ndarray:
    """Noise (4,) of each field column of ``fields`` (m, 4) on the point cloud ``P``.

    ``1.4826 median |f_i - mean_{j in kNN(i)} f_j|``: the point-to-point scatter of the field
    that the surface itself does not explain (robust to creases, which are a minority).
    """
    tree = tree or cKDTree(P)
    _, idx = tree.query(P, k=min(k + 1, len(P)), workers=-1)
    nb = fields[idx[:, 1:]].mean(axis=1)
    return 1.4826 * np.median(np.abs(fields - nb), axis=0)


def robust_spread(f: np.ndarray) -> np.ndarray:
    """Robust spread per column: ``(P90 - P10) / 2.563`` (a Gaussian's sigma)."""
    lo, hi = np.percentile(f, [10, 90], axis=0)
    return (hi - lo) / 2.563


def range_bandwidths(
    model_fields: np.ndarray, scan_noise: np.ndarray, c: float = 3.0, r0: float = 0.05
) -> np.ndarray:
    """``sigma_r = max(r0 * spread(model field), c * eta_f)`` per field (4,) (paper Eq. 6)."""
    floor = r0 * robust_spread(model_fields)
    sig = np.maximum(floor, c * np.asarray(scan_noise, dtype=float))
    return np.maximum(sig, 1e-12)


@dataclass
class GeodesicBalls:
    """Geodesic neighbourhoods of some source samples, as flat arrays.

    Attributes
    ----------
    sources : (k,) int64 sample index of each source.
    rows : (e,) int32 source number (0..k-1) of each entry.  cols : (e,) int32 neighbour index.
    g2 : (e,) float32 squared geodesic distance, mm^2.  radius : the Dijkstra limit, mm.
    """

    sources: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    g2: np.ndarray
    radius: float

    def __getstate__(self) -> dict:
        """Pickled compactly (the per-part cache): ``rows`` (sorted, as built) as
        the count of each source's entries, ``cols`` in the narrowest unsigned integer type
        that holds them; :meth:`__setstate__` restores the same arrays exactly."""
        state = dict(self.__dict__)
        rows, cols = np.asarray(self.rows), np.asarray(self.cols)
        if len(rows) and np.all(rows[1:] >= rows[:-1]) and rows[0] >= 0:
            state["rows"] = None
            state["row_counts"] = np.bincount(rows, minlength=len(self.sources)).astype(np.int32)
        if len(cols) and cols.min() >= 0:
            small = np.min_scalar_type(int(cols.max()))
            state["cols"] = cols.astype(small)
        return state

    def __setstate__(self, state: dict) -> None:
        counts = state.pop("row_counts", None)
        if counts is not None:
            state["rows"] = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
        state["cols"] = np.asarray(state["cols"]).astype(np.int32)
        self.__dict__.update(state)


def geodesic_balls(
    G: sp.csr_matrix,
    sources: np.ndarray,
    radius: float,
    chunk: int = 64,
    tree: cKDTree | None = None,
) -> GeodesicBalls:
    """Dijkstra distances from each source up to ``radius`` (mm) on the graph ``G``.

    ``scipy.sparse.csgraph.dijkstra`` with ``limit=radius``, ``chunk`` sources per call (each
    call holds a dense ``chunk x n`` array). With ``tree``, a ``cKDTree`` of the graph's
    node positions (its edges weighted by their Euclidean lengths, as :func:`mesh_graph` and
    :func:`knn_graph` are), each call runs on the nodes within ``radius`` of its sources
    only: a path no longer than ``radius`` never leaves that Euclidean ball, so the
    distances are the same numbers, in the same order, and the dense array is
    ``chunk x (nodes near the sources)`` instead of ``chunk x n``.
    """
    sources = np.asarray(sources, dtype=np.int64)
    G = sp.csr_matrix(G)
    # with the node positions, the sources go through in compact groups (sorted by a grid
    # of 4 radii), so that a group's balls cover a small share of the nodes
    order = np.arange(len(sources))
    if tree is not None and len(sources):
        cell = np.floor(tree.data[sources] / (4.0 * radius + 1e-300)).astype(np.int64)
        order = np.lexsort(cell.T[::-1])
    rows_l, cols_l, g2_l = [], [], []
    for start in range(0, len(sources), chunk):
        pos = order[start : start + chunk]
        src = sources[pos]
        if tree is None:
            Dg = dijkstra(G, directed=False, indices=src, limit=radius)
            r, c = np.nonzero(np.isfinite(Dg))
            d = Dg[r, c]
        else:
            # a hair wider than the limit, for the rounding of the edge lengths
            near = tree.query_ball_point(tree.data[src], radius * (1.0 + 1e-9) + 1e-12)
            nodes = unique_sorted(np.fromiter(chain.from_iterable(near), dtype=np.int64))
            Dg = dijkstra(
                G[nodes][:, nodes],
                directed=False,
                indices=np.searchsorted(nodes, src),
                limit=radius,
            )
            r, sub = np.nonzero(np.isfinite(Dg))
            c = nodes[sub]  # ``nodes`` ascending: each row's columns in the graph's order
            d = Dg[r, sub]
        rows_l.append(pos[r].astype(np.int32))
        cols_l.append(c.astype(np.int32))
        g2_l.append((d**2).astype(np.float32))
    if tree is not None and rows_l:
        # back to the order of the sources (each source's entries keep their column order)
        back = np.argsort(np.concatenate(rows_l), kind="stable")
        rows_l, cols_l, g2_l = ([np.concatenate(x)[back]] for x in (rows_l, cols_l, g2_l))
    cat = np.concatenate if rows_l else (lambda _x: np.zeros(0))
    return GeodesicBalls(
        sources=sources,
        rows=cat(rows_l).astype(np.int32),
        cols=cat(cols_l).astype(np.int32),
        g2=cat(g2_l).astype(np.float32),
        radius=float(radius),
    )


def bilateral_filter(
    balls: GeodesicBalls,
    fields: np.ndarray,
    area: np.ndarray,
    scales_mm: np.ndarray,
    sigma_r: np.ndarray,
) -> np.ndarray:
    """Geodesic bilateral filter (paper Eq. 6) of every field at every scale, at the sources.

    Parameters
    ----------
    balls : neighbourhoods from :func:`geodesic_balls` with ``radius >= 3 max(scales_mm)``.
    fields : (n, 4) raw ``[H, K, S, C]``.  area : (n,) surface area per sample, mm^2.
    scales_mm : (L,) spatial bandwidths ``sigma_s``, mm.  sigma_r : (4,) range bandwidths.

    Returns
    -------
    (k, 4 L) filtered values, field-major.
    """
    scales_mm = np.asarray(scales_mm, dtype=float)
    L = len(scales_mm)
    k = len(balls.sources)
    rows, cols = balls.rows, balls.cols
    g2 = balls.g2.astype(np.float64)
    fj = fields[cols]
    fi = fields[balls.sources[rows]]
    wr = np.exp(-0.5 * ((fj - fi) / np.asarray(sigma_r, dtype=float)) ** 2)
    out = np.zeros((k, 4 * L))
    a = area[cols]
    for s_i, s in enumerate(scales_mm):
        ws = a * np.exp(-0.5 * g2 / s**2) * (g2 <= (3.0 * s) ** 2)
        for f_i in range(4):
            w = ws * wr[:, f_i]
            den = np.bincount(rows, weights=w, minlength=k)
            num = np.bincount(rows, weights=w * fj[:, f_i], minlength=k)
            out[:, f_i * L + s_i] = num / np.maximum(den, 1e-300)
    return out


def bilateral_descriptors(
    G: sp.csr_matrix,
    X: np.ndarray,
    fields: np.ndarray,
    area: np.ndarray,
    keypoints: np.ndarray,
    scales_mm: np.ndarray,
    sigma_r: np.ndarray,
    chunk: int = 64,
) -> DescriptorSet:
    """Geodesic bilateral descriptors (paper Eq. 6-7) of the samples ``keypoints``.

    Parameters
    ----------
    G : (n, n) symmetric sparse graph with edge lengths, mm (mesh edges or scan k-NN).
    X : (n, 3) sample positions, mm.  fields : (n, 4) raw ``[H, K, S, C]``.
    area : (n,) surface area per sample, mm^2.  keypoints : (k,) sample indices.
    scales_mm : (L,) spatial bandwidths ``sigma_s``, mm.  sigma_r : (4,) range bandwidths.
    chunk : Dijkstra sources per call.

    Returns
    -------
    DescriptorSet with ``D`` of shape (k, 4 L).
    """
    keypoints = np.asarray(keypoints, dtype=np.int64)
    scales_mm = np.asarray(scales_mm, dtype=float)
    balls = geodesic_balls(G, keypoints, 3.0 * float(scales_mm.max()), chunk)
    D = bilateral_filter(balls, fields, area, scales_mm, sigma_r)
    return DescriptorSet(
        index=keypoints,
        X=X[keypoints].copy(),
        D=D,
        scales=scales_mm.copy(),
        sigma_r=np.asarray(sigma_r, dtype=float).copy(),
    )


def presmooth(
    X: np.ndarray,
    H: np.ndarray,
    K: np.ndarray,
    area: np.ndarray,
    sigma: float,
    planar_tol: float,
    tree: cKDTree | None = None,
) -> CurvatureFields:
    """Area-weighted Gaussian average of ``H`` and ``K`` over Euclidean balls of ``3 sigma``.

    Brings the mesh and the scan to one resolution before the bilateral filter: a discrete
    mesh concentrates a crease's curvature on the crease vertices (a spike ~ angle / edge),
    while a quadric fit spreads it over its neighbourhood; both integrate to the same
    curvature measure, which this average (a small ``sigma``, ~ one edge length, where
    Euclidean and geodesic balls coincide) turns into the same smooth field. ``S`` and ``C``
    are recomputed from the averaged ``H, K``
    (:func:`qifreport.registration.pose.curvature.shape_fields`).
    """
    if sigma <= 0:
        S, C = shape_fields(H, K, planar_tol)
        return CurvatureFields(H=H.copy(), K=K.copy(), S=S, C=C)
    tree = tree or cKDTree(X)
    n = len(X)
    M = tree.sparse_distance_matrix(tree, 3.0 * sigma, output_type="coo_matrix")
    w = np.exp(-0.5 * (M.data / sigma) ** 2) * area[M.col]
    W = sp.coo_matrix((w, (M.row, M.col)), shape=(n, n)).tocsr() + sp.diags(area)
    Z = W @ np.ones(n)
    Hs = (W @ H) / Z
    Ks = (W @ K) / Z
    S, C = shape_fields(Hs, Ks, planar_tol)
    return CurvatureFields(H=Hs, K=Ks, S=S, C=C)


def joint_normalize(
    DM: np.ndarray, DP: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Z-score model ``DM`` (k1, d) and scan ``DP`` (k2, d) with one shared mean and std.

    Returns
    -------
    DM_n, DP_n : normalised descriptors.  mean, std : (d,) the shared statistics.
    """
    U = np.vstack([DM, DP])
    mu = U.mean(axis=0)
    sd = U.std(axis=0)
    sd = np.where(sd > 1e-12 * max(float(np.abs(mu).max()), 1.0), sd, 1.0)
    return (DM - mu) / sd, (DP - mu) / sd, mu, sd
