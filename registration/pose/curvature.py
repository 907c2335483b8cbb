"""Curvature fields on the nominal mesh and on the scan (paper Section 5.1.1).

Four scalar fields per sample feed the pre-registration descriptor:

* ``H`` signed mean curvature (1/mm), positive where the surface is convex with respect to
  its outward normal (a sphere with outward normals has ``H = +1/r``);
* ``K`` Gaussian curvature (1/mm^2);
* ``S`` Koenderink shape index in [-1, 1], ``S = (2/pi) arctan((k1 + k2) / (k1 - k2))`` with
  ``k1 >= k2``; evaluated as ``(2/pi) atan2(k1 + k2, k1 - k2)``, which is the paper's ratio
  wherever it is defined and its limit ``sign(H)`` at non-planar umbilics (``S = +1`` on a
  convex sphere cap, ``-1`` in a cup); ``S = 0`` at planar points (curvedness below
  ``planar_tol``), where the ratio carries no information;
* ``C`` curvedness (1/mm), ``C = sqrt((k1^2 + k2^2) / 2)``.

The principal curvatures come from ``H`` and ``K`` as ``k1,2 = H +- sqrt(max(H^2 - K, 0))``:
the radicand is floored at zero because ``H`` and ``K`` are estimated by different discrete
formulas (paper Section 5.1.1).

On the mesh ``H`` is the projection of the cotangent mean-curvature normal on the outward
vertex normal and ``K`` the angle defect, both divided by the mixed Voronoi area. On the scan,
which has no connectivity, the local surface is a least-squares quadric ``z = a x^2 + b x y +
c y^2 + d x + e y + f`` fitted to the ``k`` nearest neighbours in the PCA frame of each
neighbourhood (a moving-least-squares style height-field fit); ``H`` and ``K`` are those of
the fitted graph at the query point. Scan normals are made consistent by propagation along a
minimum spanning tree of the k-NN graph (Hoppe et al. 1992); the global sign of a one-sided
scan cannot be known from points alone, so the pre-registration tries both signs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from qifreport.registration.mesh import (
    adjacency,
    boundary_vertices,
    bounding_diagonal,
    vertex_normals,
)

__all__ = [
    "PLANAR_REL",
    "CurvatureFields",
    "mesh_curvatures",
    "orient_normals",
    "principal_from_hk",
    "scan_curvatures",
    "ScanCurvatures",
    "shape_fields",
]

log = logging.getLogger(__name__)

#: Curvedness below ``PLANAR_REL / diagonal`` counts as planar (radius > 1000 diagonals).
PLANAR_REL = 1e-3


@dataclass
class CurvatureFields:
    """Per-sample curvature fields (all (n,) float64).

    Attributes
    ----------
    H : signed mean curvature, 1/mm (outward-normal convention, sphere ``+1/r``).
    K : Gaussian curvature, 1/mm^2.
    S : shape index in [-1, 1] (0 at planar points).
    C : curvedness, 1/mm.
    """

    H: np.ndarray
    K: np.ndarray
    S: np.ndarray
    C: np.ndarray

    def stack(self) -> np.ndarray:
        """The fields as columns ``[H, K, S, C]``, shape (n, 4)."""
        return np.column_stack([self.H, self.K, self.S, self.C])

    def flipped(self) -> CurvatureFields:
        """The same fields for the opposite normal orientation (``H, S -> -H, -S``)."""
        return CurvatureFields(H=-self.H, K=self.K.copy(), S=-self.S, C=self.C.copy())


@dataclass
class ScanCurvatures(CurvatureFields):
    """:class:`CurvatureFields` of a point cloud plus what the local fit also gives.

    Attributes
    ----------
    normals : (m, 3) unit normals, consistently oriented over each connected component of the
        k-NN graph (global sign arbitrary, see module docstring).
    residual : (m,) RMS residual of the local quadric fit (``k - 6`` degrees of freedom), mm:
        range noise plus unmodelled shape.
    spacing : (m,) local sample spacing ``sqrt(area / k)`` of the neighbourhood, mm; ``spacing^2``
        is the surface area a sample stands for.
    """

    normals: np.ndarray | None = None
    residual: np.ndarray | None = None
    spacing: np.ndarray | None = None

    @property
    def noise(self) -> float:
        """Robust estimate of the scan's range noise (mm): median quadric-fit residual."""
        return float(np.median(self.residual)) if self.residual is not None else 0.0


def principal_from_hk(H: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal curvatures ``k1 >= k2`` (1/mm) from ``H`` and ``K`` with the floored radicand."""
    r = np.sqrt(np.maximum(H * H - K, 0.0))
    return H + r, H - r


def shape_fields(H: np.ndarray, K: np.ndarray, planar_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Shape index ``S`` and curvedness ``C`` from ``H`` (1/mm) and ``K`` (1/mm^2).

    ``S`` uses ``atan2`` so a non-planar umbilic (``k1 = k2 != 0``) gets its limit
    ``sign(H)``; points with ``C < planar_tol`` (1/mm) get ``S = 0``.
    """
    k1, k2 = principal_from_hk(H, K)
    C = np.sqrt(0.5 * (k1 * k1 + k2 * k2))
    S = (2.0 / np.pi) * np.arctan2(k1 + k2, k1 - k2)
    S[C < planar_tol] = 0.0
    return S, C


def _fill_from_neighbours(
    values: np.ndarray, bad: np.ndarray, A: sp.csr_matrix, passes: int = 8
) -> np.ndarray:
    """Replace ``values[bad]`` by the mean of their good neighbours, growing inward."""
    out = values.copy()
    good = ~bad
    for _ in range(passes):
        if good.all():
            break
        cnt = A @ good.astype(float)
        tot = A @ np.where(good, out, 0.0)
        fix = (~good) & (cnt > 0)
        out[fix] = tot[fix] / cnt[fix]
        good = good | fix
    out[~good] = 0.0
    return out


def mesh_curvatures(
    V: np.ndarray, F: np.ndarray, planar_tol: float | None = None
) -> CurvatureFields:
    """Curvature fields ``H, K, S, C`` on the vertices of a triangle mesh (paper Eq. 4-5).

    ``H_i = -((L x)_i . n_i) / (2 A_i)`` with libigl's (negative semi-definite) cotangent
    Laplacian ``L``, the mixed Voronoi area ``A_i`` and the area-weighted outward vertex normal
    ``n_i`` (the sign follows the winding of ``F``); ``K_i = (2 pi - sum_t theta_i^t) / A_i``.
    On open boundaries neither formula measures the surface (the angle defect there is the
    boundary's turning angle, and ``L x`` has an in-plane component), so boundary vertices take
    the mean of their interior neighbours, propagated inward over a few rings.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    planar_tol : curvedness (1/mm) below which ``S = 0``; default ``1e-3 / diagonal``.

    Returns
    -------
    CurvatureFields with (n,) arrays.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    n = len(V)
    L = sp.csr_matrix(igl.cotmatrix(V, F))
    M = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)
    A = np.asarray(M.diagonal()).ravel()
    A = np.maximum(A, 1e-12 * max(float(A.max()), 1e-300))
    N = vertex_normals(V, F)
    H = -np.einsum("ij,ij->i", L @ V, N) / (2.0 * A)
    K = np.asarray(igl.gaussian_curvature(V, F), dtype=np.float64) / A
    bnd = boundary_vertices(F, n)
    if bnd.any():
        adj = adjacency(F, n).astype(float)
        H = _fill_from_neighbours(H, bnd, adj)
        K = _fill_from_neighbours(K, bnd, adj)
    tol = PLANAR_REL / max(bounding_diagonal(V), 1e-300) if planar_tol is None else planar_tol
    S, C = shape_fields(H, K, tol)
    return CurvatureFields(H=H, K=K, S=S, C=C)


def orient_normals(P: np.ndarray, N: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Consistently orient unit normals ``N`` (m, 3) by propagation over a k-NN graph.

    The graph has an edge from each point to its neighbours ``idx`` (m, k) weighted by
    ``1 - |n_i . n_j|`` (plus a tiny distance term); normals are flipped along a minimum
    spanning tree from a root in each connected component (Hoppe et al. 1992). Per component
    the global sign is chosen so that normals point, on balance, away from the component's
    centroid (outward for a convex-ish view of a solid); it remains a guess, see the module
    docstring.
    """
    m, k = idx.shape
    rows = np.repeat(np.arange(m), k)
    cols = idx.ravel()
    keep = rows != cols
    rows, cols = rows[keep], cols[keep]
    w = 1.0 - np.abs(np.einsum("ij,ij->i", N[rows], N[cols])) + 1e-6
    G = sp.coo_matrix((w, (rows, cols)), shape=(m, m)).tocsr()
    G = G.maximum(G.T)
    T = minimum_spanning_tree(G)
    T = (T + T.T).tocsr()
    ncomp, labels = connected_components(T, directed=False)
    out = N.copy()
    for c in range(ncomp):
        members = np.flatnonzero(labels == c)
        root = int(members[0])
        order, pred = breadth_first_order(T, root, directed=False, return_predecessors=True)
        # sign of each node relative to its parent, accumulated in BFS order
        sign = np.ones(m)
        for v in order[1:]:
            p = pred[v]
            s = 1.0 if out[v] @ out[p] * sign[p] >= 0 else -1.0
            sign[v] = s
        out[order] *= sign[order, None]
        ctr = P[members].mean(axis=0)
        if np.einsum("ij,ij->", out[members], P[members] - ctr) < 0:
            out[members] *= -1.0
    return out


def scan_curvatures(
    P: np.ndarray,
    k: int = 20,
    tree: cKDTree | None = None,
    planar_tol: float | None = None,
) -> ScanCurvatures:
    """Curvature fields ``H, K, S, C`` on a point cloud from local quadric (MLS) fits.

    For every point its ``k`` nearest neighbours (itself included) define a PCA frame
    ``(e1, e2, n)``; the neighbours' offsets from the point, in that frame, are fitted by
    ``z = a x^2 + b x y + c y^2 + d x + e y + f`` (ordinary least squares, batched). The fitted
    graph's curvatures at ``(0, 0)``, ``K = (4 a c - b^2) / W^2`` and
    ``H_graph = ((1 + e^2) 2a - 2 d e b + (1 + d^2) 2c) / (2 W^1.5)``, ``W = 1 + d^2 + e^2``,
    are converted to the mesh convention (``H = -H_graph`` for a normal ``n`` that is outward;
    see :func:`mesh_curvatures`).

    The neighbourhood radius should be comparable to the mesh's one-ring for the fields on
    both sides to be comparable: with the scanner sampling at ~0.7 edge lengths, ``k = 20``
    spans about 1.5-2 edge lengths.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  k : neighbourhood size (>= 10).
    tree : optional prebuilt ``cKDTree(P)``.
    planar_tol : curvedness (1/mm) below which ``S = 0``; default ``1e-3 / diagonal``.

    Returns
    -------
    ScanCurvatures (fields (m,), normals (m, 3), fit residual and spacing (m,), mm).
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    m = len(P)
    k = int(min(max(k, 10), m))
    tree = tree or cKDTree(P)
    dist, idx = tree.query(P, k=k, workers=-1)
    Q = P[idx] - P[:, None, :]  # (m, k, 3) offsets from the query point
    Qc = Q - Q.mean(axis=1, keepdims=True)
    C3 = np.einsum("mki,mkj->mij", Qc, Qc)
    _, vecs = np.linalg.eigh(C3)  # ascending: vecs[..., 0] is the normal
    N = vecs[:, :, 0]
    N = orient_normals(P, N, idx[:, : min(k, 10)])
    E1 = vecs[:, :, 2]
    E2 = np.cross(N, E1)
    x = np.einsum("mki,mi->mk", Q, E1)
    y = np.einsum("mki,mi->mk", Q, E2)
    z = np.einsum("mki,mi->mk", Q, N)
    r = np.maximum(dist[:, -1:], 1e-12)  # scale for conditioning
    xs, ys = x / r, y / r
    A = np.stack([xs * xs, xs * ys, ys * ys, xs, ys, np.ones_like(xs)], axis=2)  # (m, k, 6)
    AtA = np.einsum("mki,mkj->mij", A, A) + 1e-10 * np.eye(6)
    Atz = np.einsum("mki,mk->mi", A, z)
    coef = np.linalg.solve(AtA, Atz[:, :, None])[:, :, 0]
    res = z - np.einsum("mki,mi->mk", A, coef)
    rr = r[:, 0]
    a = coef[:, 0] / rr**2
    b = coef[:, 1] / rr**2
    c = coef[:, 2] / rr**2
    d = coef[:, 3] / rr
    e = coef[:, 4] / rr
    W = 1.0 + d * d + e * e
    K = (4.0 * a * c - b * b) / W**2
    H = -((1.0 + e * e) * 2.0 * a - 2.0 * d * e * b + (1.0 + d * d) * 2.0 * c) / (2.0 * W**1.5)
    diag = bounding_diagonal(P)
    tol = PLANAR_REL / max(diag, 1e-300) if planar_tol is None else planar_tol
    S, Cv = shape_fields(H, K, tol)
    spacing = np.sqrt(np.pi * rr**2 / k)
    return ScanCurvatures(
        H=H,
        K=K,
        S=S,
        C=Cv,
        normals=N,
        residual=np.sqrt(np.sum(res**2, axis=1) / (k - 6)),
        spacing=spacing,
    )
