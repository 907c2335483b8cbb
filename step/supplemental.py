"""Supplemental faces: B-rep faces that belong to no solid of a part.

CAD exports carry faces outside the part's solid: datum target areas and tolerance sub-areas
drawn as a free face lying on the solid's surface (NIST CTC 02, CTC 04, FTC 08: a disk or
a patch on a planar face, with no shared edges), and construction faces off the part. They
are not material: a scan cannot see them apart from the solid's face beneath, and meshed
with the solid they double its surface (the scan points go to one face or the other).

:func:`face_solids` tells which faces are free; :func:`footprints` finds, for each free face
lying on the solid, the solid's triangles beneath it, so a tolerance that names the free
face is judged on the solid's surface there. A free face off the solid has no footprint:
its tolerance cannot be measured on a scan of the part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Footprint", "face_solids", "footprints"]


def face_solids(shape, faces: list) -> np.ndarray:
    """(n_faces,) int64: the index of the solid each face belongs to (the order of
    ``TopExp.MapShapes(shape, TopAbs_SOLID)``), -1 for a face in no solid.

    Parameters
    ----------
    shape : ``TopoDS_Shape``.  faces : its faces in face-id order (``TopoDS_Face``, the
        order of ``TopExp.MapShapes(shape, TopAbs_FACE)``, as the reader lists them).
    """
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
    from OCP.TopExp import TopExp
    from OCP.TopTools import TopTools_IndexedMapOfShape

    allf = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, allf)
    if allf.Size() != len(faces):
        raise ValueError(f"{len(faces)} faces given, the shape has {allf.Size()}")
    out = np.full(len(faces), -1, dtype=np.int64)
    solids = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_SOLID, solids)
    for s in range(1, solids.Size() + 1):
        fmap = TopTools_IndexedMapOfShape()
        TopExp.MapShapes_s(solids.FindKey(s), TopAbs_FACE, fmap)
        for k in range(1, fmap.Size() + 1):
            i = allf.FindIndex(fmap.FindKey(k)) - 1
            if i >= 0 and out[i] < 0:
                out[i] = s - 1
    return out


@dataclass
class Footprint:
    """Where a free face lies on the part.

    Attributes
    ----------
    face : the free face's id.
    triangles : (k,) int64 triangles of the solid's mesh beneath it (empty: off the part).
    on_faces : (j,) int64 the solid faces those triangles belong to.
    area : mm^2, of those triangles.  free_area : mm^2, of the free face's own triangles.
    """

    face: int
    triangles: np.ndarray
    on_faces: np.ndarray
    area: float
    free_area: float


def footprints(
    V: np.ndarray,
    F: np.ndarray,
    face_id: np.ndarray,
    free: np.ndarray,
    tol: float,
) -> list[Footprint]:
    """The footprint of every free face on the solid's mesh.

    A solid triangle is beneath a free face when its centroid lies within ``tol`` of the
    free face's triangles along their normal (the closest point is inside the free face:
    a centroid beside its rim, whose closest point is on the rim, is not beneath it).

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3) triangles.  face_id : (f,) face of each triangle.
    free : (n_faces,) bool, the free faces (``face_solids(...) < 0``).
    tol : mm, how far from the free face a centroid may lie (about the tessellations' chord
        error: two meshings of one surface differ by up to both deflections).
    """
    import trimesh

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    face_id = np.asarray(face_id, dtype=np.int64)
    on_free = free[face_id]
    solid_tris = np.flatnonzero(~on_free)
    C = V[F[solid_tris]].mean(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    out = []
    for face in np.flatnonzero(free):
        mine = face_id == face
        if not mine.any():
            continue
        Fm = F[mine]
        lo = V[Fm].reshape(-1, 3).min(axis=0) - tol
        hi = V[Fm].reshape(-1, 3).max(axis=0) + tol
        box = np.flatnonzero(np.all((C >= lo) & (C <= hi), axis=1))
        under = np.zeros(0, dtype=np.int64)
        if len(box):
            m = trimesh.Trimesh(V, Fm, process=False)
            Q, d, tri = trimesh.proximity.closest_point(m, C[box])
            # beneath: off the free face along its normal only (a centroid beside its rim
            # has its closest point on the rim, off to the side)
            off = C[box] - Q
            n = m.face_normals[tri]
            side = np.linalg.norm(off - np.einsum("ij,ij->i", off, n)[:, None] * n, axis=1)
            under = solid_tris[box[(d <= tol) & (side <= 0.05 * tol)]]
        out.append(
            Footprint(
                face=int(face),
                triangles=under,
                on_faces=np.unique(face_id[under]),
                area=float(area[under].sum()),
                free_area=float(area[mine].sum()),
            )
        )
    return out
