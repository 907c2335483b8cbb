"""The open rim of the nominal, or the trim creases of a closed one, with a frame at each vertex.

:func:`rim_frames` finds the open boundary of a mesh and gives every rim vertex a local frame:
the rim tangent, the surface normal and the outward in-plane normal, pointing away from the
material. A closed solid has no open boundary: :func:`crease_frames` cuts it along its sharp
creases into smooth patches (:func:`split_at_creases`) and frames the patches' rims where
they are trim edges. The trim-edge deviation
(:func:`qifreport.metrology.deviation.edges.edge_deviation`) is measured in these frames.

All lengths are mm; ``V`` (n, 3), ``F`` (f, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.closest import closest_points
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import edge_uses, face_normals, median_edge_length, vertex_normals

__all__ = [
    "RimFrames",
    "beyond_crease",
    "crease_frames",
    "rim_frames",
    "split_at_creases",
]


@dataclass
class RimFrames:
    """The open rim of a mesh and a local frame at each of its vertices.

    Attributes
    ----------
    vertices : (k,) int64, the rim (open-boundary) vertices, indices into ``V``.
    position : (k, 3) their positions, mm.
    edges : (e, 2) int64, the open boundary edges as pairs of *positions* in ``vertices``.
    tangent : (k, 3) unit rim tangents, along the boundary's direction of travel.
    normal : (k, 3) unit surface normals (vertex normals).
    outward : (k, 3) unit outward in-plane normals ``tangent x normal``: in the tangent
        plane, pointing away from the material.
    length : (k,) rim length attributed to each vertex (half its boundary edges), mm.
    loop : (k,) int, connected piece of the rim (outer rim, each hole) of each vertex.
    corner : (k,) bool, vertex at a corner of the rim (not measured).
    patch : (k,) int, the smooth patch the frame belongs to (crease mode: a vertex on a crease
        appears once per patch meeting there; open rims: all 0).
    mode : ``"rim"`` (open boundary) or ``"crease"`` (sharp creases of a closed mesh).
    """

    vertices: np.ndarray
    position: np.ndarray
    edges: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    outward: np.ndarray
    length: np.ndarray
    loop: np.ndarray
    corner: np.ndarray
    patch: np.ndarray | None = None
    mode: str = "rim"

    def __post_init__(self) -> None:
        if self.patch is None:
            self.patch = np.zeros(len(self.vertices), dtype=np.int64)

    @property
    def empty(self) -> bool:
        """True when the mesh has no open boundary."""
        return len(self.vertices) == 0


def _directed_boundary(F: np.ndarray) -> np.ndarray:
    """(e, 2) open boundary edges, directed as their one triangle traverses them."""
    _, count, of = edge_uses(F)
    out = []
    for k in range(3):
        sel = count[of[:, k]] == 1
        out.append(np.c_[F[sel, k], F[sel, (k + 1) % 3]])
    return np.concatenate(out).astype(np.int64)


def rim_frames(
    V: np.ndarray,
    F: np.ndarray,
    normals: np.ndarray | None = None,
    radius: float | None = None,
    corner_angle: float = 30.0,
) -> RimFrames:
    """The open rim of ``(V, F)`` and its local frames (see :class:`RimFrames`).

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int, consistently wound (outward normals).
    normals : (n, 3) unit vertex normals; default
        :func:`qifreport.registration.mesh.vertex_normals`.
    radius : neighbourhood of the corner test, mm; default 2 median edge lengths.
    corner_angle : a rim vertex is a corner when the outward normals of the rim vertices of
        its loop within ``radius`` turn by more than this, degrees.

    Returns
    -------
    :class:`RimFrames`, empty (``k = 0``) for a mesh without an open boundary.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    D = _directed_boundary(F)
    if len(D) == 0:
        z3 = np.zeros((0, 3))
        z = np.zeros(0, dtype=np.int64)
        return RimFrames(
            z, z3, np.zeros((0, 2), np.int64), z3, z3, z3, np.zeros(0), z, z.astype(bool)
        )
    verts, pos = np.unique(D, return_inverse=True)
    pos = pos.reshape(D.shape)
    k = len(verts)
    vec = V[D[:, 1]] - V[D[:, 0]]
    elen = np.linalg.norm(vec, axis=1)
    unit = vec / np.maximum(elen, 1e-300)[:, None]
    T = np.zeros((k, 3))
    np.add.at(T, pos[:, 0], unit)
    np.add.at(T, pos[:, 1], unit)
    length = np.zeros(k)
    np.add.at(length, pos[:, 0], 0.5 * elen)
    np.add.at(length, pos[:, 1], 0.5 * elen)
    N = (vertex_normals(V, F) if normals is None else np.asarray(normals, np.float64))[verts]
    T = T - np.einsum("ij,ij->i", T, N)[:, None] * N
    tn = np.linalg.norm(T, axis=1)
    degenerate = tn < 1e-9
    T = T / np.maximum(tn, 1e-300)[:, None]
    B = np.cross(T, N)
    B = B / np.maximum(np.linalg.norm(B, axis=1), 1e-300)[:, None]
    A = sp.coo_matrix((np.ones(len(pos)), (pos[:, 0], pos[:, 1])), shape=(k, k))
    _, loop = connected_components(A, directed=False)
    # corners: the outward normal turns by more than corner_angle within radius (same loop)
    r = 2.0 * median_edge_length(V, F) if radius is None else float(radius)
    pairs = cKDTree(V[verts]).query_pairs(r, output_type="ndarray")
    corner = degenerate.copy()
    if len(pairs):
        same = loop[pairs[:, 0]] == loop[pairs[:, 1]]
        pairs = pairs[same]
        turn = np.einsum("ij,ij->i", B[pairs[:, 0]], B[pairs[:, 1]]) < np.cos(
            np.deg2rad(corner_angle)
        )
        corner[pairs[turn].ravel()] = True
    return RimFrames(
        vertices=verts.astype(np.int64),
        position=V[verts],
        edges=pos.astype(np.int64),
        tangent=T,
        normal=N,
        outward=B,
        length=length,
        loop=loop.astype(np.int64),
        corner=corner,
    )


def _manifold_edges(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The manifold edges of ``F`` (f, 3): (k, 2) their vertices and (k, 2) their two
    triangles, in the order of :func:`~qifreport.registration.mesh.edge_uses`'s edges."""
    E, count, of = edge_uses(F)
    slot_edge = of.ravel()
    slot_face = np.repeat(np.arange(len(F)), 3)
    manifold = count[slot_edge] == 2
    order = np.argsort(slot_edge[manifold], kind="stable")
    faces = slot_face[manifold][order].reshape(-1, 2)  # the two triangles of each edge
    return E[count == 2].astype(np.int64), faces


def split_at_creases(
    V: np.ndarray, F: np.ndarray, crease_angle: float = 60.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cut the mesh along its sharp creases into smooth patches with their own vertices.

    Two triangles sharing an edge stay in one patch when their normals differ by at most
    ``crease_angle`` degrees; non-manifold edges are cut too. Each patch gets its own copy
    of the vertices it uses, so a crease becomes an open boundary of both patches.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int, consistently wound.  crease_angle : degrees.

    Returns
    -------
    V2 : (n2, 3) the vertices, one copy per patch using it.  F2 : (f, 3) the triangles on
    them.  source : (n2,) index in ``V`` of each copy.  patch : (f,) patch of each triangle.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nf = len(F)
    fn = face_normals(V, F)
    faces = _manifold_edges(F)[1]
    smooth = np.einsum("ij,ij->i", fn[faces[:, 0]], fn[faces[:, 1]]) >= np.cos(
        np.deg2rad(crease_angle)
    )
    a, b = faces[smooth, 0], faces[smooth, 1]
    A = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(nf, nf))
    _, patch = connected_components(A, directed=False)
    key = patch[:, None].astype(np.int64) * len(V) + F
    uniq, inv = np.unique(key.ravel(), return_inverse=True)
    source = uniq % len(V)
    return V[source], inv.reshape(F.shape).astype(np.int64), source, patch.astype(np.int64)


def crease_frames(
    V: np.ndarray,
    F: np.ndarray,
    radius: float,
    crease_angle: float = 60.0,
    corner_angle: float = 30.0,
) -> RimFrames:
    """Trim edges of a closed mesh: the rims of its smooth patches (:func:`split_at_creases`).

    Each frame uses its own patch's normal (not the average across the crease) and points
    out of that patch, across the crease. A frame is kept only where its patch extends a
    full strip depth ``radius`` inward (the point ``radius`` inside the rim lies on the
    patch): the large face beside a thin side wall keeps its frames, the side wall (and the
    bottom skin's narrow strips) does not.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  radius : the strip depth, mm.
    crease_angle, corner_angle : degrees (:func:`split_at_creases`, :func:`rim_frames`).

    Returns
    -------
    :class:`RimFrames` with ``mode == "crease"``; ``vertices`` index ``V`` (a crease vertex
    may appear once per patch).
    """
    V2, F2, source, patch_f = split_at_creases(V, F, crease_angle)
    rf = rim_frames(V2, F2, radius=1.5 * radius, corner_angle=corner_angle)
    if rf.empty:
        return RimFrames(**{**vars(rf), "mode": "crease"})
    # the patch of each rim copy: that of any triangle using it
    vpatch = np.zeros(len(V2), dtype=np.int64)
    vpatch[F2.ravel()] = np.repeat(patch_f, 3)
    pv = vpatch[rf.vertices]
    probe = V2[rf.vertices] - radius * rf.outward
    _, face, dist = closest_points(V2, F2, probe)
    wide = (patch_f[np.maximum(face, 0)] == pv) & (np.abs(dist) <= 0.02 * radius) & (face >= 0)
    keep = np.flatnonzero(wide)
    pos = -np.ones(len(rf.vertices), dtype=np.int64)
    pos[keep] = np.arange(len(keep))
    e = rf.edges[(pos[rf.edges] >= 0).all(axis=1)]
    return RimFrames(
        vertices=source[rf.vertices[keep]],
        position=rf.position[keep],
        edges=pos[e],
        tangent=rf.tangent[keep],
        normal=rf.normal[keep],
        outward=rf.outward[keep],
        length=rf.length[keep],
        loop=rf.loop[keep],
        corner=rf.corner[keep],
        patch=pv[keep],
        mode="crease",
    )


#: :func:`beyond_crease` tests a point against a crease within this many times its
#: distance to its own patch (the points nearer the neighbour's extension lie within
#: ``1 / sin(angle / 2)`` of it: 2.6 at a 45 degree crease)
_CREASE_REACH = 3.0


def beyond_crease(
    V: np.ndarray,
    F: np.ndarray,
    patch: np.ndarray,
    P: np.ndarray,
    face: np.ndarray,
    dist: np.ndarray,
) -> np.ndarray:
    """The points (m,) bool that lie nearer the extension of a neighbouring patch across a
    crease than their own patch: not measurements of their own patch's surface.

    A point's closest triangle is not always on the surface it was measured on: where the
    nominal's crease lies inside the part's real one (a face the nominal sits too far in),
    the neighbouring face's points beyond the crease are closest to the face below it and
    read as material standing proud of it by their distance past the crease. Such a point
    lies on (near) the neighbouring patch's plane extended past the crease. A point counts
    for its own patch only when its distance to it, ``|dist|``, is at most its distance to
    the plane of the other patch's triangle at every crease edge of its patch within
    ``3 |dist|`` (a point on its own surface, ``dist`` ~ noise, passes everywhere but
    within the noise of the crease line). The comparison is the bisector of the two faces:
    beyond it the point is as much the neighbour's as its own.

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3).  patch : (f,) smooth patch of each triangle
        (:func:`split_at_creases`): its boundaries are the creases.
    P : (m, 3) scan points, mm.  face : (m,) their closest triangles (-1: none).
    dist : (m,) their signed distances to them, mm (NaN: not used).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    patch = np.asarray(patch, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    r = np.abs(np.asarray(dist, dtype=np.float64))
    out = np.zeros(len(face), dtype=bool)
    E, pair = _manifold_edges(F)
    crease = patch[pair[:, 0]] != patch[pair[:, 1]]
    E, pair = E[crease], pair[crease]
    pts = np.flatnonzero((face >= 0) & np.isfinite(r))
    if len(E) == 0 or len(pts) == 0:
        return out
    # samples along the crease edges, ``step`` apart at most: the candidate edges near a point
    A, B = V[E[:, 0]], V[E[:, 1]]
    step = 0.5 * median_edge_length(V, F)
    per = np.ceil(np.linalg.norm(B - A, axis=1) / step).astype(np.int64) + 1
    edge = np.repeat(np.arange(len(E)), per)
    t = (np.arange(len(edge)) - np.repeat(np.cumsum(per) - per, per)) / np.maximum(per[edge] - 1, 1)
    tree = cKDTree(A[edge] + t[:, None] * (B - A)[edge])
    near, _ = tree.query(P[pts], k=1)
    pts = pts[near <= _CREASE_REACH * r[pts] + step]
    if len(pts) == 0:
        return out
    k = min(8, len(edge))
    _, j = tree.query(P[pts], k=k)
    pid = np.repeat(pts, k)
    cand = unique_sorted(pid * len(E) + edge[j.reshape(-1)])
    pid, e = cand // len(E), cand % len(E)
    # the crease edges of the point's own patch within reach, and the other side's triangle
    own = patch[face[pid]]
    first = patch[pair[e, 0]] == own
    other = np.where(first, pair[e, 1], pair[e, 0])
    X = P[pid] - A[e]
    AB = B[e] - A[e]
    s = np.clip(
        np.einsum("ij,ij->i", X, AB) / np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300), 0, 1
    )
    reach = np.linalg.norm(X - s[:, None] * AB, axis=1) <= _CREASE_REACH * r[pid]
    fn = face_normals(V, F)[other]
    solid = np.einsum("ij,ij->i", fn, fn) > 0.5  # not a degenerate triangle
    mine = (first | (patch[pair[e, 1]] == own)) & reach & solid
    nearer = np.abs(np.einsum("ij,ij->i", X, fn)) < r[pid]
    out[pid[mine & nearer]] = True
    return out
