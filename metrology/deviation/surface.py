"""Distance of scan points to the curved surface that the nominal's triangles are chords of.

A tessellation's triangles are chords of the B-rep surface: :func:`curved_offset` is the
surface's height above a triangle at a point, from the normals at the triangle's corners
(:func:`corner_normals`, or the B-rep's exact normals turned with the triangles by
:func:`follow_triangles`); :func:`surface_distance` is a point's signed distance to the
closest triangle less that height, measured over the B-rep faces around it
(:func:`nearest_face_distance`).

Signs and arrays as in :mod:`qifreport.metrology.deviation.closest` (positive: material
proud of the nominal surface; ``V`` (n, 3) mm, ``F`` (f, 3), ``P`` (m, 3) mm).
"""

from __future__ import annotations

import numpy as np

from qifreport.metrology.deviation.closest import as_mesh, as_points, vertex_face_csr
from qifreport.metrology.groups import sort_within_groups
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import barycentric

__all__ = [
    "corner_normals",
    "curved_offset",
    "follow_triangles",
    "nearest_face_distance",
    "point_faces",
    "surface_distance",
]


def corner_normals(V: np.ndarray, F: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Unit normal of the surface at every triangle corner, (f, 3, 3).

    The area-weighted normal of the triangles around the corner's vertex that carry the
    same ``labels`` value (``(f,)``, the B-rep face of a STEP nominal): on a crease each side
    keeps its own normal. A corner whose normal turns more than 30 degrees from its
    triangle's takes the triangle's normal.
    """
    V, F = as_mesh(V, F)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # 2 x area x normal
    nt = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
    lab = np.asarray(labels, dtype=np.int64)
    # key (vertex, label): sum of the area-weighted normals of its triangles
    key = F.astype(np.int64) * (int(lab.max()) + 1) + lab[:, None]
    uk, inv = np.unique(key.ravel(), return_inverse=True)
    S = np.zeros((len(uk), 3))
    np.add.at(S, inv, np.repeat(cross, 3, axis=0))
    S /= np.maximum(np.linalg.norm(S, axis=1, keepdims=True), 1e-300)
    out = S[inv].reshape(len(F), 3, 3)
    cos = np.einsum("fij,fj->fi", out, nt)
    return np.where((cos >= np.cos(np.radians(30.0)))[..., None], out, nt[:, None, :])


def follow_triangles(N: np.ndarray, V0: np.ndarray, V1: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Per-corner normals (f, 3, 3) turned with their triangles from ``V0`` to ``V1``
    (n, 3) mm: each triangle's corners by the rotation taking its frame (first edge,
    normal) in ``V0`` to its frame in ``V1`` (exact for a rigid motion; for the exact
    normals of a nominal a fixture has bent smoothly). NaN rows stay NaN."""
    F = np.asarray(F, dtype=np.int64)

    def frame(V):
        V = np.asarray(V, dtype=np.float64)
        e = V[F[:, 1]] - V[F[:, 0]]
        n = np.cross(e, V[F[:, 2]] - V[F[:, 0]])
        e = e / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return np.stack([e, n, np.cross(e, n)], axis=2)  # (f, 3, 3): columns e, n, e x n

    R = frame(V1) @ np.transpose(frame(V0), (0, 2, 1))  # (f, 3, 3)
    return np.einsum("fab,fkb->fka", R, N)


def curved_offset(
    V: np.ndarray, F: np.ndarray, C: np.ndarray, face: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """Height (m,) mm of the curved surface above the flat triangle at closest points ``C``.

    A tessellation's triangles are chords of the surface: a scan point exactly on a
    cylinder of radius ``R`` lies up to ``h^2 / 8R`` off the triangle of edge ``h``. The
    surface over a triangle is taken as the quadratic patch that passes through its corners
    with the corners' normals (Phong tessellation with shape factor 1/2, Boubekeur & Alexa
    2008; exact to second order on spheres and cylinders):
    ``delta = 1/2 sum_i b_i ((V_i - C) . n_i)``, ``b`` the barycentrics of ``C``. Subtract
    it from a signed distance to the triangle to get the distance to the surface.

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3).  C : (m, 3) closest points on the mesh, mm.
    face : (m,) their triangles (-1: none; offset 0).  normals : (f, 3, 3)
        :func:`corner_normals`.
    """
    face = np.asarray(face, dtype=np.int64)
    out = np.zeros(len(face))
    ok = (face >= 0) & np.isfinite(C).all(axis=1)
    if not ok.any():
        return out
    t = face[ok]
    T = V[F[t]]  # (k, 3, 3)
    X = C[ok]
    B = np.clip(barycentric(V, F, t, X), 0.0, 1.0)
    B /= np.maximum(B.sum(axis=1, keepdims=True), 1e-300)
    h = np.einsum("kij,kij->ki", T - X[:, None, :], normals[t])  # (k, 3)
    out[ok] = 0.5 * np.einsum("ki,ki->k", B, h)
    return out


def nearest_face_distance(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    labels: np.ndarray,
    cface: np.ndarray,
    dist: np.ndarray,
    normals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's distance to the curved surface over the B-rep faces around its closest
    triangle: (m,) distance, mm, and (m,) the triangle it is measured on.

    The closest *chord* is not always on the point's own face: near the tangent edge of a
    coarsely meshed fillet a point of the fillet lies nearer the plane's chord and reads the
    plane's distance (tens of micrometres to 0.5 mm on NIST CTC 02). For a point whose
    closest triangle ``cface`` touches another face (``labels``: B-rep face per triangle),
    every triangle of another face sharing a vertex with it is tried: the point's
    projection inside it (barycentric >= -0.05), its signed distance to the plane less the
    curved offset there (:func:`curved_offset` with ``normals`` (f, 3, 3)); the smallest
    magnitude among them and ``dist`` (m,) (the closest triangle's) is kept.
    """
    V, F = as_mesh(V, F)
    P = as_points(P)
    cface = np.asarray(cface, dtype=np.int64)
    lab = np.asarray(labels, dtype=np.int64)
    out_d = np.asarray(dist, dtype=np.float64).copy()
    out_f = cface.copy()
    vf = vertex_face_csr(F, len(V))
    # triangles touching another face: a vertex of theirs has triangles of two faces
    vlab_min = np.full(len(V), np.iinfo(np.int64).max)
    vlab_max = np.full(len(V), -1)
    np.minimum.at(vlab_min, F.ravel(), np.repeat(lab, 3))
    np.maximum.at(vlab_max, F.ravel(), np.repeat(lab, 3))
    border_v = vlab_min != vlab_max
    pts = np.flatnonzero((cface >= 0) & np.isfinite(out_d))
    pts = pts[border_v[F[cface[pts]]].any(axis=1)]
    if len(pts) == 0:
        return out_d, out_f
    # candidate (point, triangle) pairs: the triangles around the closest one's vertices
    rows = vf[F[cface[pts]].ravel()]  # (3k, f)
    coo = rows.tocoo()
    pid = pts[coo.row // 3]
    tri = coo.col.astype(np.int64)
    other = lab[tri] != lab[cface[pid]]
    pid, tri = pid[other], tri[other]
    if len(pid) == 0:
        return out_d, out_f
    key = unique_sorted(pid * len(F) + tri)
    pid, tri = key // len(F), key % len(F)
    A, B, Cc = V[F[tri, 0]], V[F[tri, 1]], V[F[tri, 2]]
    n = np.cross(B - A, Cc - A)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    h = np.einsum("ij,ij->i", P[pid] - A, n)
    X = P[pid] - h[:, None] * n
    lam = barycentric(V, F, tri, X)
    inside = lam.min(axis=1) >= -0.05
    pid, tri, h, X = pid[inside], tri[inside], h[inside], X[inside]
    d = h - curved_offset(V, F, X, tri, normals)
    order = sort_within_groups(pid, np.abs(d))
    first = np.r_[True, pid[order][1:] != pid[order][:-1]]
    best = order[first]
    better = np.abs(d[best]) < np.abs(out_d[pid[best]])
    out_d[pid[best][better]] = d[best][better]
    out_f[pid[best][better]] = tri[best][better]
    return out_d, out_f


def point_faces(cface: np.ndarray, face_id: np.ndarray) -> np.ndarray:
    """(m,) int: the B-rep face of each scan point's closest triangle ``cface`` (-1 where
    it has none)."""
    return np.where(cface >= 0, face_id[np.maximum(cface, 0)], -1)


def surface_distance(
    V: np.ndarray,
    F: np.ndarray,
    C: np.ndarray,
    cface: np.ndarray,
    pdev: np.ndarray,
    face_id: np.ndarray,
    normals: np.ndarray | None = None,
    P: np.ndarray | None = None,
) -> np.ndarray:
    """(m,) signed distance, mm, of each scan point to the curved B-rep surface: its signed
    distance ``pdev`` to the closest triangle (at ``C`` on triangle ``cface``) less the
    triangle's chord height there (:func:`~qifreport.metrology.deviation.surface.curved_offset`):
    a perfect scan of a cylinder meshed with coarse chords reads 0, not the chord sag.
    With the points ``P`` (m, 3), a point whose closest chord borders another B-rep face
    takes the smallest distance over the faces around it
    (:func:`~qifreport.metrology.deviation.surface.nearest_face_distance`).

    ``normals`` (f, 3, 3): the surface's normals at the triangle corners (the B-rep's,
    :func:`qifreport.step.normals.corner_normals_exact`; NaN rows take the mesh's); without
    them each B-rep face's mesh normals
    (:func:`~qifreport.metrology.deviation.surface.corner_normals`), off by half a segment at the
    edge of a coarsely meshed fillet."""
    cn = normals
    if cn is None or np.isnan(cn).any():
        mesh = corner_normals(V, F, face_id)
        cn = mesh if cn is None else np.where(np.isnan(cn[..., :1]), mesh, cn)
    d = pdev - curved_offset(V, F, C, cface, cn)
    if P is not None:
        d, _ = nearest_face_distance(V, F, P, face_id, cface, d, cn)
    return d
