"""Exact surface normals at a tessellation's triangle corners, from the B-rep.

The deviation of a scan point from a curved face is its distance to the triangle it falls
on less the triangle's chord height there; the chord height is read from a quadratic patch
through the corners with the corners' normals
(:func:`qifreport.metrology.deviation.surface.curved_offset`). Normals averaged from the mesh's
own triangles are wrong where a face has few triangles across: at the edge of a fillet
meshed with three segments per quarter turn a corner's averaged normal is off by half a
segment (15 degrees), and a perfect scan of NIST CTC 02 read up to 0.28 mm off its fillets
(4 % of its points beyond 0.04 mm at 10 um noise). The B-rep knows the normal exactly.
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["corner_normals_exact", "corner_normals_of_faces"]

log = logging.getLogger(__name__)


def corner_normals_exact(
    faces: list, V: np.ndarray, F: np.ndarray, face_id: np.ndarray
) -> np.ndarray:
    """Outward unit normals (f, 3, 3) of each triangle's three corners on its B-rep face.

    Each (vertex, face) pair is projected onto the face's surface (OCP
    ``ShapeAnalysis_Surface.ValueOfUV``) and the surface normal evaluated there
    (``GeomLProp_SLProps``), turned to the face's orientation and to the side of the
    triangle's own normal. Where the surface has no normal (a cone's apex, a sphere's pole)
    the row is NaN: the caller falls back to the mesh's normals.

    Parameters
    ----------
    faces : the part's faces in face-id order (``StepPart.faces``).
    V : (n, 3) mm.  F : (f, 3) outward triangles.  face_id : (f,) face of each triangle.
    """
    from OCP.BRep import BRep_Tool
    from OCP.GeomAbs import GeomAbs_Plane
    from OCP.GeomAdaptor import GeomAdaptor_Surface
    from OCP.GeomLProp import GeomLProp_SLProps
    from OCP.gp import gp_Pnt
    from OCP.ShapeAnalysis import ShapeAnalysis_Surface
    from OCP.TopAbs import TopAbs_REVERSED

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    face_id = np.asarray(face_id, dtype=np.int64)
    out = np.full((len(F), 3, 3), np.nan)
    tri_n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    # one evaluation per (vertex, face) pair
    pv, pf, inverse = _corner_pairs(F, face_id)
    N = np.full((len(pv), 3), np.nan)
    order = np.argsort(pf, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(pf[order]) != 0])
    for group in np.split(order, starts[1:]):
        face = faces[int(pf[group[0]])]
        surf = BRep_Tool.Surface_s(face)
        sas = ShapeAnalysis_Surface(surf)
        sign = -1.0 if face.Orientation() == TopAbs_REVERSED else 1.0
        # a plane's normal is the same at every (u, v) (the cross product of its constant
        # axes): evaluated once, at the face's first corner
        planar = GeomAdaptor_Surface(surf).GetType() == GeomAbs_Plane
        for i in group[:1] if planar else group:
            uv = sas.ValueOfUV(gp_Pnt(*V[pv[i]]), 1e-7)
            props = GeomLProp_SLProps(surf, uv.X(), uv.Y(), 1, 1e-9)
            if props.IsNormalDefined():
                n = props.Normal()
                N[i] = (sign * n.X(), sign * n.Y(), sign * n.Z())
        if planar:
            N[group] = N[group[0]]
    out[:] = N[inverse].reshape(len(F), 3, 3)
    # the side of the triangle's own (outward) normal: a face whose orientation flag does
    # not match its surface's (a sewing artefact) still gets outward corners
    flip = np.einsum("fij,fj->fi", out, tri_n) < 0
    out[flip] *= -1.0
    bad = int(np.isnan(out[..., 0]).sum())
    if bad:
        log.info("no surface normal at %d triangle corners (apex or pole): mesh normals there", bad)
    return out


def corner_normals_of_faces(V: np.ndarray, F: np.ndarray, face_id: np.ndarray) -> np.ndarray:
    """Unit normals (f, 3, 3) at each triangle's corners, averaged (by area) over the
    triangles of the same face around the corner: a tessellated part's normals, whose faces
    have no surface to evaluate. An edge between two faces keeps each face's own normal.

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3) outward triangles.  face_id : (f,) face of each triangle.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    face_id = np.asarray(face_id, dtype=np.int64)
    tri_n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # length: 2 x area
    pv, _, inverse = _corner_pairs(F, face_id)
    N = np.zeros((len(pv), 3))
    np.add.at(N, inverse, np.repeat(tri_n, 3, axis=0))
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
    return N[inverse].reshape(len(F), 3, 3)


def _corner_pairs(F: np.ndarray, face_id: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct (vertex, face) pairs of the triangles' corners: their vertices (p,),
    faces (p,), and each corner's pair, ``inverse`` (3 f,) in ``F.ravel()`` order."""
    m = int(face_id.max()) + 1 if len(face_id) else 1
    pairs, inverse = np.unique((F * m + face_id[:, None]).ravel(), return_inverse=True)
    return pairs // m, pairs % m, inverse
