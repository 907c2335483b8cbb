"""Triangle-mesh layer: loading, welding and the intrinsic operators.

Every function works on plain arrays: ``V`` (n, 3) float64 vertex positions in mm and
``F`` (f, 3) int64 triangle indices. The operators follow the paper's Section 4.3:
cotangent Laplacian ``L``, lumped (barycentric) mass ``M`` with ``M_ii`` one third of the
area of the incident triangles, and the bending operator ``Q = L M^-1 L``. The Hessian
energy of Stein et al. (2018), which has natural boundary conditions at open boundaries,
is offered beside it (``energy="hessian"``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from qifreport.errors import InputError, require_file

from .arrays import unique_sorted

__all__ = [
    "barycentric",
    "MESH_SUFFIXES",
    "adjacency",
    "bending_operator",
    "boundary_vertices",
    "bounding_diagonal",
    "NEARLY_CLOSED",
    "consistent_winding",
    "crease_band",
    "edge_uses",
    "edges",
    "face_normals",
    "label_boundary_vertices",
    "load_mesh",
    "median_edge_length",
    "MeshOperators",
    "remove_degenerate",
    "remove_unreferenced",
    "vertex_areas",
    "vertex_normals",
    "wall_thickness",
    "weld",
]

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".stl", ".ply", ".obj", ".off")


def bounding_diagonal(V: np.ndarray) -> float:
    """Length (mm) of the axis-aligned bounding-box diagonal of points ``V`` (n, 3)."""
    V = np.asarray(V, dtype=float)
    return float(np.linalg.norm(V.max(axis=0) - V.min(axis=0))) if len(V) else 0.0


def weld(V: np.ndarray, F: np.ndarray, rel_tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident vertices of a triangle soup and drop what welding makes degenerate.

    Parameters
    ----------
    V : (n, 3) float array, mm.
    F : (f, 3) int array.
    rel_tol : merge distance as a fraction of the bounding diagonal (paper Section 8.4.1).

    Returns
    -------
    V, F : the welded mesh; faces with a repeated index and exact duplicate faces are
        removed, unreferenced vertices are dropped.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    eps = rel_tol * max(bounding_diagonal(V), 1e-12)
    SV, _, SVJ, SF = igl.remove_duplicate_vertices(V, F, eps)
    SF = np.asarray(SF, dtype=np.int64)
    good = (SF[:, 0] != SF[:, 1]) & (SF[:, 1] != SF[:, 2]) & (SF[:, 0] != SF[:, 2])
    SF = SF[good]
    _, first = np.unique(np.sort(SF, axis=1), axis=0, return_index=True)
    SF = SF[np.sort(first)]
    return remove_unreferenced(np.asarray(SV, dtype=np.float64), SF)


def remove_unreferenced(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop vertices that no face uses; returns re-indexed ``(V, F)``."""
    used = np.zeros(len(V), dtype=bool)
    used[F.ravel()] = True
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(used.sum())
    return V[used], remap[F]


def remove_degenerate(V: np.ndarray, F: np.ndarray, rel_area: float = 1e-12) -> np.ndarray:
    """Faces of ``F`` whose area exceeds ``rel_area * diag^2`` (zero-area slivers removed)."""
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return F[area > rel_area * bounding_diagonal(V) ** 2]


def load_mesh(path: str | Path, weld_tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Read a nominal triangle mesh (STL, PLY, OBJ, OFF) and weld it.

    Units are taken as mm (mesh formats carry none).

    Parameters
    ----------
    path : the mesh file.
    weld_tol : merge distance of coincident vertices, as a fraction of the bounding diagonal.

    Returns
    -------
    V : (n, 3) float64, mm.  F : (f, 3) int64, every index in ``[0, n)``.

    Raises
    ------
    InputError
        Missing, unsupported or unreadable file (whatever the third-party reader raised is
        wrapped), no triangles, face indices out of range, or non-finite coordinates; one
        line naming the file.
    """
    import warnings

    from .pointcloud import check_declared_counts, one_line, read_trimesh

    path = Path(path)
    require_file(path, "nominal mesh")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(
            f"{path.name}: unsupported nominal format {path.suffix!r} (use STL, PLY, OBJ or OFF)"
        )
    try:
        with warnings.catch_warnings():  # reader noise; problems are reported below, once
            warnings.simplefilter("ignore")
            tm = read_trimesh(path, force="mesh")
            if not isinstance(tm, trimesh.Trimesh) or len(tm.faces) == 0:
                raise InputError(f"nominal mesh {path.name} has no triangles")
            V, F = np.asarray(tm.vertices), np.asarray(tm.faces)
            if V.ndim != 2 or V.shape[1] != 3 or V.dtype.kind not in "iuf":
                raise InputError(
                    f"nominal mesh {path.name}: vertices of shape {V.shape} "
                    f"and type {V.dtype}, expected (n, 3) numbers"
                )
            if F.ndim != 2 or F.shape[1] != 3 or F.dtype.kind not in "iu":
                raise InputError(
                    f"nominal mesh {path.name}: faces of shape {F.shape} "
                    f"and type {F.dtype}, expected (f, 3) vertex indices"
                )
            V = np.ascontiguousarray(V, dtype=np.float64)
            F = np.ascontiguousarray(F, dtype=np.int64)
            check_declared_counts(path, len(V), faces=True)
            if not np.isfinite(V).all():
                raise InputError(f"nominal mesh {path.name} has non-finite vertex coordinates")
            bad = (F < 0) | (F >= len(V))
            if bad.any():
                raise InputError(
                    f"nominal mesh {path.name}: {int(bad.any(axis=1).sum())} "
                    f"faces index vertices outside 0..{len(V) - 1}"
                )
            if not np.isfinite(bounding_diagonal(V)):
                raise InputError(
                    f"nominal mesh {path.name}: coordinates too large (the extent overflows)"
                )
            n_in = len(V)
            V, F = weld(V, F, weld_tol)
            F = remove_degenerate(V, F)
            V, F = remove_unreferenced(V, F)
    except InputError:
        raise
    except Exception as exc:  # trimesh raises many types on corrupt input
        raise InputError(f"cannot read nominal mesh {path.name}: {one_line(exc)}") from None
    if len(F) == 0:
        raise InputError(f"nominal mesh {path.name} has no non-degenerate triangles")
    if len(V) < n_in:
        log.info("welded %s: %d -> %d vertices", path.name, n_in, len(V))
    return V, F


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (n, 3); follows the winding of ``F``."""
    N = igl.per_vertex_normals(
        np.ascontiguousarray(V, dtype=np.float64),
        np.ascontiguousarray(F, dtype=np.int64),
        igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA,
    )
    N = np.asarray(N, dtype=np.float64)
    bad = ~np.isfinite(N).all(axis=1)
    N[bad] = 0.0
    return N


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit face normals (f, 3)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric area per vertex (n,), mm^2: one third of the incident triangles' area."""
    a = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    out = np.zeros(len(V))
    for k in range(3):
        np.add.at(out, F[:, k], a / 3.0)
    return out


def _half_edges(F: np.ndarray) -> np.ndarray:
    """(3f, 2) the triangles' edges 01, 12, 20 (all of the first, then the second, ...),
    each as a sorted vertex pair."""
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)


def _edge_keys(half: np.ndarray) -> tuple[np.ndarray, int]:
    """One int64 key per sorted pair of ``half`` (non-empty), in the pairs' lexicographic
    order, and the base that decodes it (:func:`_edge_pairs`): a 1-D unique of the keys is
    ~10x faster than ``np.unique(half, axis=0)``."""
    base = int(half.max()) + 1
    return half[:, 0].astype(np.int64) * base + half[:, 1], base


def _edge_pairs(key: np.ndarray, base: int) -> np.ndarray:
    """(e, 2) the vertex pairs of the keys of :func:`_edge_keys`."""
    return np.stack([key // base, key % base], axis=1)


def edges(F: np.ndarray) -> np.ndarray:
    """Unique undirected edges (e, 2) of the triangles ``F``, sorted lexicographically."""
    E = _half_edges(np.asarray(F, dtype=np.int64))
    if len(E) == 0:
        return E.reshape(0, 2)
    key, base = _edge_keys(E)
    return _edge_pairs(unique_sorted(key), base)


def median_edge_length(V: np.ndarray, F: np.ndarray) -> float:
    """Median edge length (mm)."""
    E = edges(F)
    return float(np.median(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)))


def adjacency(F: np.ndarray, n: int) -> sp.csr_matrix:
    """Symmetric vertex adjacency (n, n) over mesh edges, boolean CSR.

    Built from the triangles' six directed pairs, the duplicates merged by the CSR
    conversion: the same matrix as from the unique edges, ~10x faster (no sort of the
    edges).
    """
    F = np.asarray(F, dtype=np.int64)
    i = F.ravel()
    j = F[:, [1, 2, 0]].ravel()
    A = sp.csr_matrix((np.ones(2 * len(i), dtype=bool), (np.r_[i, j], np.r_[j, i])), shape=(n, n))
    A.sum_duplicates()
    return A


def edge_uses(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges of the triangles ``F`` and how many triangles use each.

    Returns
    -------
    E : (e, 2) unique edges (sorted vertex pairs).  count : (e,) triangles using each
    (1: open boundary, 2: manifold, > 2: non-manifold).  of : (f, 3) index into ``E`` of each
    triangle's edges 01, 12, 20.
    """
    F = np.asarray(F)
    half = _half_edges(F)
    if len(half) == 0:
        E, inv, count = np.unique(half, axis=0, return_inverse=True, return_counts=True)
        return E, count, inv.ravel().reshape(3, len(F)).T
    # the same unique edges, counts and inverse as ``np.unique(half, axis=0)``
    key, base = _edge_keys(half)
    key, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    E = _edge_pairs(key, base).astype(half.dtype, copy=False)
    return E, count, inv.ravel().reshape(3, len(F)).T


#: a piece with open edges whose area vectors sum to less than this share of its area is
#: closed but for holes, and is turned outward (:func:`consistent_winding`)
NEARLY_CLOSED = 0.1


def consistent_winding(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Make the triangles' winding consistent across every manifold edge.

    Two triangles sharing an edge are consistent when they traverse it in opposite
    directions. Each connected piece is oriented by the choice that flips the least area,
    then a *closed* piece (no open or non-manifold edge) is turned outward (positive signed
    volume), and so is a *nearly closed* one: a surface with holes (a scanned reconstruction
    open where the scanner did not see) whose area vectors sum to under
    :data:`NEARLY_CLOSED` of its area (a closed surface's sum to zero, an open sheet's to
    most of its area), its volume taken about its own centroid. A piece that cannot be
    oriented (a Moebius-like strip) is left as it is.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) triangles.

    Returns
    -------
    F : (f, 3) the triangles, some with two indices swapped.  flipped : how many were.
    unorientable : triangles in pieces that cannot be oriented (left unchanged).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nf = len(F)
    if nf == 0:
        return F.copy(), 0, 0
    _, count, of = edge_uses(F)
    # each manifold edge's two uses: which triangles, and the direction each traverses it
    directed = np.stack([F, np.roll(F, -1, axis=1)], axis=2)  # (f, 3, 2): 0->1, 1->2, 2->0
    forward = directed[..., 0] < directed[..., 1]  # (f, 3)
    e = of.ravel()
    face = np.repeat(np.arange(nf), 3)
    fwd = forward.ravel()
    manifold = count[e] == 2
    order = np.argsort(e[manifold], kind="stable")
    ff, fd = face[manifold][order], fwd[manifold][order]
    a, b = ff[0::2], ff[1::2]
    same = fd[0::2] != fd[1::2]  # opposite directions: consistent, same orientation
    # the double cover: node f (kept) and f + nf (flipped)
    rows = np.concatenate([a, a + nf])
    cols = np.concatenate([np.where(same, b, b + nf), np.where(same, b + nf, b)])
    G = sp.coo_matrix((np.ones(len(rows), dtype=bool), (rows, cols)), shape=(2 * nf, 2 * nf))
    _, label = connected_components(G, directed=False)
    keep_l, flip_l = label[:nf], label[nf:]
    bad = keep_l == flip_l
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    # per component pair {L, L'}: orient as the label with more kept area says
    n_lab = label.max() + 1
    kept_area = np.bincount(keep_l, weights=area, minlength=n_lab)
    flip = (kept_area[flip_l] > kept_area[keep_l]) & ~bad
    tie = (kept_area[flip_l] == kept_area[keep_l]) & ~bad
    flip[tie] = keep_l[tie] > flip_l[tie]  # a fixed choice
    out = F.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    # closed pieces outward: signed volume of each piece (pieces = components of the
    # undirected face graph, i.e. min of the two labels)
    piece = np.minimum(keep_l, flip_l)
    open_edge = np.zeros(nf, dtype=bool)
    np.logical_or.at(open_edge, face, count[e] != 2)
    has_open = np.bincount(piece, weights=open_edge, minlength=n_lab) > 0
    piece_vol, closed = _pieces_volume(V, out, piece, n_lab, area, has_open)
    inward = closed[piece] & (piece_vol[piece] < 0) & ~bad
    out[inward] = out[inward][:, [0, 2, 1]]
    changed = np.any(out != F, axis=1)
    return out, int(changed.sum()), int(bad.sum())


def _pieces_volume(
    V: np.ndarray, F: np.ndarray, piece: np.ndarray, n: int, area: np.ndarray, has_open: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each of the ``n`` pieces' signed volume (mm^3) about its own area centroid (an open
    piece's depends on the origin), and whether it is closed or nearly so (no open edge, or
    area vectors summing to under :data:`NEARLY_CLOSED` of its area)."""
    X0, X1, X2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    piece_area = np.bincount(piece, weights=area, minlength=n)
    mid = area[:, None] * (X0 + X1 + X2) / 3.0
    centroid = np.stack([np.bincount(piece, weights=mid[:, k], minlength=n) for k in range(3)], 1)
    c = (centroid / np.maximum(piece_area, 1e-300)[:, None])[piece]
    vol = np.einsum("ij,ij->i", X0 - c, np.cross(X1 - c, X2 - c)) / 6.0
    A = 0.5 * np.cross(X1 - X0, X2 - X0)
    vec = np.stack([np.bincount(piece, weights=A[:, k], minlength=n) for k in range(3)], axis=1)
    closed = ~has_open | (np.linalg.norm(vec, axis=1) < NEARLY_CLOSED * piece_area)
    return np.bincount(piece, weights=vol, minlength=n), closed


def boundary_vertices(F: np.ndarray, n: int) -> np.ndarray:
    """Boolean mask (n,) of vertices on an open boundary (edges used by one face)."""
    E, count, _ = edge_uses(F)
    mask = np.zeros(n, dtype=bool)
    mask[E[count == 1].ravel()] = True
    return mask


def label_boundary_vertices(F: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Boolean mask (n,) of vertices shared by triangles of different ``labels`` (f,):
    the edges between a B-rep's faces (or any labelled patches)."""
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1)
    fid = np.repeat(np.asarray(labels, dtype=np.int64), 3)
    np.minimum.at(lo, F.ravel(), fid)
    np.maximum.at(hi, F.ravel(), fid)
    return lo < hi


@dataclass(frozen=True)
class MeshOperators:
    """Intrinsic operators of one mesh (all (n, n) sparse unless noted).

    Attributes
    ----------
    L : cotangent Laplacian (libigl sign: negative semi-definite), 1/mm^0.
    M : lumped barycentric mass, diagonal, mm^2.
    Q : bending operator (symmetric positive semi-definite), 1/mm^2.
    energy : ``"laplacian"`` for ``L M^-1 L`` or ``"hessian"`` for Stein et al.'s Hessian energy.
    normals : (n, 3) unit vertex normals.
    area : (n,) vertex areas, mm^2 (diagonal of ``M``).
    """

    L: sp.csc_matrix
    M: sp.csc_matrix
    Q: sp.csc_matrix
    energy: str
    normals: np.ndarray
    area: np.ndarray


def wall_thickness(
    V: np.ndarray,
    N: np.ndarray,
    at: np.ndarray,
    radius: float,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Distance (mm) from vertices to the opposite skin of the solid behind them.

    For each vertex ``i`` in ``at``: the nearest vertex ``w`` within ``radius`` whose normal
    faces the other way (``n_w . n_i < -0.5``) and that lies behind ``i``
    (``(v_w - v_i) . n_i < 0``): the other skin of a thin wall. ``inf`` where there is none
    (an open sheet, a thick solid at this radius).

    Parameters
    ----------
    V, N : (n, 3) vertices (mm) and unit outward normals.  at : (k,) vertex indices.
    radius : search radius, mm.  tree : optional ``cKDTree(V)``.

    Returns
    -------
    (k,) float64, mm.
    """
    tree = tree or cKDTree(V)
    at = np.asarray(at, dtype=np.int64)
    out = np.full(len(at), np.inf)
    for k, (i, near) in enumerate(
        zip(at, tree.query_ball_point(V[at], radius, workers=-1), strict=True)
    ):
        w = np.asarray(near, dtype=np.int64)
        D = V[w] - V[i]
        opposite = (N[w] @ N[i] < -0.5) & (D @ N[i] < 0.0)
        if opposite.any():
            out[k] = float(np.sqrt(np.min(np.einsum("ij,ij->i", D[opposite], D[opposite]))))
    return out


def bending_operator(V: np.ndarray, F: np.ndarray, energy: str = "laplacian") -> MeshOperators:
    """Assemble ``L``, ``M`` and the bending operator ``Q`` of the mesh ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    energy : ``"laplacian"`` -> ``Q = L M^-1 L`` (paper Eq. 2, 12);
        ``"hessian"`` -> ``igl.hessian_energy`` (natural boundary conditions).
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    L = sp.csc_matrix(igl.cotmatrix(V, F))
    area = vertex_areas(V, F)
    M = sp.diags(area).tocsc()
    if energy == "laplacian":
        inv = 1.0 / np.maximum(area, 1e-12 * max(area.max(), 1e-300))
        Q = (L.T @ sp.diags(inv) @ L).tocsc()
    elif energy == "hessian":
        Q = sp.csc_matrix(igl.hessian_energy(V, F))
    else:
        raise ValueError(f"unknown bending energy {energy!r} (laplacian or hessian)")
    Q = (0.5 * (Q + Q.T)).tocsc()
    return MeshOperators(L=L, M=M, Q=Q, energy=energy, normals=vertex_normals(V, F), area=area)


def crease_band(V: np.ndarray, F: np.ndarray, width: float, angle_deg: float = 45.0) -> np.ndarray:
    """(n,) bool: vertices within ``width`` (mm, shortest path along the edges) of a sharp
    crease, an edge whose two triangles' normals differ by more than ``angle_deg`` degrees.
    """
    import scipy.sparse.csgraph as csg

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    tri = np.tile(np.arange(len(F)), 3)
    Es = np.sort(E, axis=1)
    order = np.lexsort((Es[:, 1], Es[:, 0]))
    Es, tri = Es[order], tri[order]
    same = np.all(Es[1:] == Es[:-1], axis=1)
    a, b = tri[:-1][same], tri[1:][same]
    cos = np.einsum("ij,ij->i", fn[a], fn[b])
    sharp = Es[:-1][same][cos < np.cos(np.radians(angle_deg))]
    out = np.zeros(len(V), dtype=bool)
    if len(sharp) == 0:
        return out
    seeds = unique_sorted(sharp.ravel())
    out[seeds] = True
    if width <= 0:
        return out
    Eu = edges(F)
    w = np.linalg.norm(V[Eu[:, 0]] - V[Eu[:, 1]], axis=1)
    G = sp.coo_matrix((w, (Eu[:, 0], Eu[:, 1])), shape=(len(V), len(V))).tocsr()
    d = csg.dijkstra(G, directed=False, indices=seeds, limit=width, min_only=True)
    out |= np.isfinite(d)
    return out


def barycentric(V: np.ndarray, F: np.ndarray, face: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(m, 3) barycentric coordinates of points ``X`` (m, 3) in the triangles ``F[face]``
    of vertices ``V`` (n, 3) (a degenerate triangle gives its first corner's weight 1)."""
    a, b, c = V[F[face, 0]], V[F[face, 1]], V[F[face, 2]]
    v0, v1, v2 = b - a, c - a, X - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 0, den, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.c_[1.0 - v - w, v, w]
