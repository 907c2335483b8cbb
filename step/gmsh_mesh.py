"""A registration-quality surface mesh of a B-rep through gmsh, with per-triangle face ids.

The alternative to :func:`qifreport.step.tessellate.tessellate` : the same
result type (:class:`~qifreport.step.tessellate.FaceMesh`), so a caller switches by calling
:func:`gmsh_tessellate` instead. gmsh meshes every B-rep surface with isotropic, good-quality
triangles (Frontal-Delaunay in the surface's parameter plane) on a conforming discretisation
of the shared curves, so the mesh is welded across faces by construction (one gmsh node per
point on a shared edge), manifold, and free of the needles BRepMesh makes on planar faces
with holes.

How the shape gets to gmsh: the PyPI ``gmsh`` wheel links its own OpenCASCADE (7.8.1), which
is not ABI compatible with OCP's (7.9.3): handing it the OCP ``TopoDS_Shape`` by address
(``gmsh.model.occ.importShapesNativePointer``) raised ``GeomAdaptor_Surface::UContinuity``
on the sample panel. The shape is therefore written with OCP to a temporary BREP file (format
version 1, no triangulation; the geometry is exact, no conversion) and imported by gmsh
without healing. gmsh numbers the surfaces in the order of a ``TopExp_Explorer`` over faces,
which is the order of ``TopExp.MapShapes(shape, TopAbs_FACE)``, i.e. the reader's face ids;
this is checked face by face (area and centre of mass, to 1e-5 of the diagonal; gmsh's
bounding boxes are looser than OCP's and are not compared). If the order ever differs,
the surfaces are matched to the faces by those properties instead, and a match that is not a
bijection raises :class:`~qifreport.errors.InputError`.

Sizes: no edge is meant to be longer than ``max_edge`` (mm, gmsh ``Mesh.MeshSizeMax``); on
curved surfaces the size also follows the curvature (``Mesh.MeshSizeFromCurvature``, ``N``
elements per 2 pi radians) with ``N`` chosen so that the chord height stays within the
``deflection`` where ``max_edge`` stops binding: on a doubly curved surface (a sphere of
radius ``R``) an equilateral triangle of edge ``h`` sags ``h^2 / 6R`` at its centre, i.e.
``pi max_edge / 3N`` at ``h = max_edge = 2 pi R / N``; gmsh's sizes are targets that its
triangles exceed by up to about 1.2x, hence a factor 1.25 (measured: without it the sphere
of FTC 06 came out at 1.03 deflections, with it below 1). And not below the angular
deflection of BRepMesh (``N >= 2 pi / angle``). A size floor of ``2 x
deflection`` keeps small fillets from exploding the triangle count (the sag on a radius
below the floor is at most about the radius itself, i.e. about the deflection).

Orientation: every face's triangles are turned to the B-rep face's outward normal (the
surface normal, reversed for a ``TopAbs_REVERSED`` face), by a vote of sampled triangles
against OCP's surface normal at their projection.

gmsh holds global state: the calls run inside :class:`_GmshSession`, which initialises gmsh
without signal handlers or configuration files, silences its terminal output (messages go to
this module's logger at DEBUG level), uses one meshing thread, and always finalises (or, if
gmsh was already initialised by someone else, removes only its own model).
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from qifreport.errors import InputError

from .tessellate import (
    DEFAULT_ANGLE,
    DEFAULT_REL_DEFLECTION,
    FaceMesh,
    checked_mesh,
    resolve_deflection,
)

__all__ = [
    "SolidMesh",
    "brep_pieces",
    "gmsh_solid_mesh",
    "curvature_elements",
    "gmsh_tessellate",
    "match_surfaces",
    "mesh_stats",
]

log = logging.getLogger(__name__)

_LOCK = threading.Lock()  # gmsh is one global instance per process


class _GmshSession:
    """Context: an initialised, silent, single-threaded gmsh with a model of our own."""

    def __init__(self, threads: int = 1) -> None:
        self.threads = int(threads)
        self._owner = False

    def __enter__(self):
        import gmsh

        _LOCK.acquire()
        try:
            if gmsh.isInitialized():
                self._owner = False
            else:
                gmsh.initialize(readConfigFiles=False, run=False, interruptible=False)
                self._owner = True
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("General.Verbosity", 2)
            gmsh.option.setNumber("General.NumThreads", self.threads)
            gmsh.option.setNumber("Mesh.MaxNumThreads2D", self.threads)
            gmsh.logger.start()
            self._model = f"qifreport-{os.getpid()}-{id(self)}"
            gmsh.model.add(self._model)
        except BaseException:
            self._close(gmsh)
            raise
        return gmsh

    def _close(self, gmsh) -> None:
        try:
            if gmsh.isInitialized():
                try:
                    for ln in gmsh.logger.get():
                        log.debug("gmsh: %s", ln)
                    gmsh.logger.stop()
                except Exception:  # pragma: no cover - logging only
                    pass
                if self._owner:
                    gmsh.finalize()
                else:
                    try:
                        gmsh.model.setCurrent(self._model)
                        gmsh.model.remove()
                    except Exception:  # pragma: no cover - someone else's session
                        pass
        finally:
            _LOCK.release()

    def __exit__(self, *exc) -> bool:
        import gmsh

        self._close(gmsh)
        return False


@contextmanager
def _brep_file(shape):
    """The shape written to a temporary OCCT B-rep file (gmsh's own kernel reads it), removed
    on exit."""
    from OCP.BRepTools import BRepTools
    from OCP.TopTools import TopTools_FormatVersion

    fd, brep = tempfile.mkstemp(prefix="qifreport-gmsh-", suffix=".brep")
    os.close(fd)
    try:
        if not BRepTools.Write_s(
            shape, brep, False, False, TopTools_FormatVersion.TopTools_FormatVersion_VERSION_1
        ):
            raise InputError("could not write the B-rep for gmsh")
        yield brep
    finally:
        try:
            os.unlink(brep)
        except OSError:  # pragma: no cover
            pass


def curvature_elements(max_edge: float, deflection: float, angle: float = DEFAULT_ANGLE) -> int:
    """Elements per 2 pi radians so that the chord height stays within ``deflection``.

    Parameters
    ----------
    max_edge : largest edge length, mm.
    deflection : largest chord height wanted, mm.
    angle : largest normal turn across an element, rad (BRepMesh's angular deflection).

    Returns
    -------
    ``N`` for gmsh's ``Mesh.MeshSizeFromCurvature`` (at least 6).
    """
    n_chord = math.ceil(1.25 * math.pi * max_edge / (3.0 * deflection))
    n_angle = math.ceil(2.0 * math.pi / angle) if angle > 0 else 0
    return int(max(6, n_chord, n_angle))


def _face_props(face) -> np.ndarray:
    """Area (mm^2) and centre of mass (mm) of an OCP face: (4,)."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    g = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, g)
    c = g.CentreOfMass()
    return np.array([g.Mass(), c.X(), c.Y(), c.Z()], dtype=np.float64)


def _gmsh_props(gmsh, tag: int) -> np.ndarray:
    """The same properties as :func:`_face_props` of gmsh surface ``tag``: (4,)."""
    a = gmsh.model.occ.getMass(2, tag)
    c = gmsh.model.occ.getCenterOfMass(2, tag)
    return np.array([a, *c], dtype=np.float64)


def match_surfaces(face_props: np.ndarray, surf_props: np.ndarray, diag: float) -> np.ndarray:
    """Match gmsh surfaces to OCP faces by area and centre of mass.

    Parameters
    ----------
    face_props : (n, 4) float64, :func:`_face_props` of each OCP face (face-id order).
    surf_props : (n, 4) float64, the same of each gmsh surface (gmsh order).
    diag : the part's bounding diagonal, mm (sets the tolerances).

    Returns
    -------
    (n,) int64: for each face id, the row of its gmsh surface.

    Raises
    ------
    InputError
        When the counts differ or the match is not one to one.
    """
    n = len(face_props)
    if len(surf_props) != n:
        raise InputError(f"gmsh read {len(surf_props)} surfaces for the part's {n} B-rep faces")
    tol_l = 1e-5 * diag
    tol_a = 1e-5 * diag * diag

    def close(fp: np.ndarray, sp: np.ndarray) -> np.ndarray:
        da = np.abs(fp[..., 0] - sp[..., 0]) <= tol_a + 1e-6 * np.abs(fp[..., 0])
        dc = np.max(np.abs(fp[..., 1:4] - sp[..., 1:4]), axis=-1) <= tol_l
        return da & dc

    same = close(face_props, surf_props)
    if same.all():
        return np.arange(n, dtype=np.int64)
    log.info("gmsh surface order differs from the face order on %d faces", int((~same).sum()))
    ok = close(face_props[:, None, :], surf_props[None, :, :])
    out = np.full(n, -1, dtype=np.int64)
    used = np.zeros(n, dtype=bool)
    # unambiguous candidates first, then the closest centre among the rest
    order = np.argsort(ok.sum(axis=1), kind="stable")
    for k in order:
        cand = np.flatnonzero(ok[k] & ~used)
        if len(cand) == 0:
            raise InputError(f"B-rep face {k} has no matching gmsh surface")
        j = cand[np.argmin(np.linalg.norm(surf_props[cand, 1:4] - face_props[k, 1:4], axis=1))]
        out[k] = j
        used[j] = True
    if not used.all():  # pragma: no cover - n == n and all assigned
        raise InputError("the gmsh surfaces do not match the B-rep faces one to one")
    return out


def _orient_faces(
    V: np.ndarray, F: np.ndarray, fid: np.ndarray, faces: list, per_face: int = 9
) -> tuple[np.ndarray, int]:
    """Turn each face's triangles to the B-rep face's outward normal; (F, faces flipped)."""
    from OCP.BRep import BRep_Tool
    from OCP.GeomLProp import GeomLProp_SLProps
    from OCP.gp import gp_Pnt
    from OCP.ShapeAnalysis import ShapeAnalysis_Surface
    from OCP.TopAbs import TopAbs_REVERSED

    F = F.copy()
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    nrm = np.cross(e1, e2)
    cen = V[F].mean(axis=1)
    order = np.argsort(fid, kind="stable")
    starts = np.searchsorted(fid[order], np.arange(len(faces) + 1))
    flipped = 0
    for k, face in enumerate(faces):
        tri = order[starts[k] : starts[k + 1]]
        if len(tri) == 0:
            continue
        surf = BRep_Tool.Surface_s(face)
        sas = ShapeAnalysis_Surface(surf)
        rev = face.Orientation() == TopAbs_REVERSED
        pick = tri[np.linspace(0, len(tri) - 1, min(per_face, len(tri))).astype(np.int64)]
        vote = 0.0
        for t in pick:
            p = gp_Pnt(*cen[t])
            uv = sas.ValueOfUV(p, 1e-7)
            props = GeomLProp_SLProps(surf, uv.X(), uv.Y(), 1, 1e-9)
            if not props.IsNormalDefined():
                continue
            n = props.Normal()
            s = float(np.dot(nrm[t], (n.X(), n.Y(), n.Z())))
            vote += -s if rev else s
        if vote < 0:
            F[tri] = F[tri][:, ::-1]
            flipped += 1
    return F, flipped


def gmsh_tessellate(
    shape,
    faces: list,
    *,
    deflection: float | None = None,
    rel_deflection: float = DEFAULT_REL_DEFLECTION,
    angle: float = DEFAULT_ANGLE,
    max_edge: float | None = None,
    min_edge: float | None = None,
    algorithm: int = 6,
    threads: int = 1,
) -> FaceMesh:
    """Mesh ``shape`` with gmsh and tag every triangle with the index of its face in ``faces``.

    Parameters
    ----------
    shape : ``TopoDS_Shape`` (mm), e.g. ``StepPart.shape``.
    faces : the shape's faces in face-id order (``StepPart.faces``: the order of
        ``TopExp.MapShapes(shape, TopAbs_FACE)``).
    deflection : largest chord height wanted, mm; default ``rel_deflection`` x bounding
        diagonal (as :func:`qifreport.step.tessellate.tessellate`).
    angle : largest normal turn across a triangle on curved faces, rad.
    max_edge : target (largest) edge length, mm; default diagonal / 60 (as the nominal).
    min_edge : size floor, mm; default ``2 x deflection``.
    algorithm : gmsh's 2-D algorithm (6 Frontal-Delaunay; 5 Delaunay and 1 MeshAdapt are
        tried on faces it leaves empty).
    threads : gmsh meshing threads.

    Returns
    -------
    :class:`~qifreport.step.tessellate.FaceMesh`: ``V`` (n, 3) mm, ``F`` (f, 3) outward,
    ``face_id`` (f,) into ``faces``, ``n_faces``, ``deflection`` mm, ``seconds``.

    Raises
    ------
    InputError
        Zero extent, gmsh's surfaces not matching the faces one to one, or a face that no
        algorithm could mesh.
    """
    t0 = time.perf_counter()
    diag, deflection = resolve_deflection(shape, deflection, rel_deflection)
    if max_edge is None or not max_edge > 0:
        max_edge = diag / 60.0
    if min_edge is None:
        min_edge = 2.0 * deflection
    min_edge = min(float(min_edge), float(max_edge))
    n_curv = curvature_elements(float(max_edge), float(deflection), angle)
    face_props = np.array([_face_props(f) for f in faces])

    with _brep_file(shape) as brep, _GmshSession(threads) as gmsh:
        tag_of_face = _import_surfaces(gmsh, brep, face_props, diag)
        t_read = time.perf_counter() - t0
        _surface_mesh_options(gmsh, float(max_edge), min_edge, n_curv, int(algorithm))
        V, F, fid = _mesh_and_collect(gmsh, tag_of_face, algorithm)

    F, flipped = _orient_faces(V, F, fid, faces)
    dt = time.perf_counter() - t0
    log.info(
        "gmsh tessellated %d faces: %d vertices, %d triangles (max edge %.3g mm, "
        "curvature %d/2pi, floor %.3g mm; %d faces turned; import %.2f s) in %.2f s",
        len(faces),
        len(V),
        len(F),
        max_edge,
        n_curv,
        min_edge,
        flipped,
        t_read,
        dt,
    )
    return checked_mesh(V, F, fid, len(faces), deflection, dt)


def _surface_mesh_options(
    gmsh, max_edge: float, min_edge: float, n_curv: int, algorithm: int
) -> None:
    """gmsh's options of the surface mesh: sizes between ``min_edge`` and ``max_edge`` (mm),
    ``n_curv`` elements per 2 pi radians of curvature, 2-D ``algorithm``, linear triangles."""
    gmsh.option.setNumber("Mesh.MeshSizeMax", max_edge)
    gmsh.option.setNumber("Mesh.MeshSizeMin", min_edge)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", n_curv)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.Algorithm", algorithm)
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    gmsh.option.setNumber("Mesh.RecombineAll", 0)


def _import_surfaces(gmsh, brep: str, face_props: np.ndarray, diag: float) -> list[int]:
    """Import the BREP file into gmsh (no healing, no sewing) and match its surfaces to the
    B-rep faces (:func:`match_surfaces`): the gmsh surface tag of each face id.

    Parameters
    ----------
    face_props : (n_faces, 4) area and centre of mass of each face (:func:`_face_props`).
    diag : the shape's bounding diagonal, mm.
    """
    for opt in ("OCCFixDegenerated", "OCCFixSmallEdges", "OCCFixSmallFaces"):
        gmsh.option.setNumber(f"Geometry.{opt}", 0)
    gmsh.option.setNumber("Geometry.OCCSewFaces", 0)
    gmsh.option.setNumber("Geometry.OCCMakeSolids", 0)
    gmsh.model.occ.importShapes(brep, highestDimOnly=False)
    gmsh.model.occ.synchronize()
    tags = [t for _, t in gmsh.model.getEntities(2)]
    surf_props = np.array([_gmsh_props(gmsh, t) for t in tags])
    row = match_surfaces(face_props, surf_props, diag)
    return [tags[r] for r in row]


@dataclass
class SolidMesh:
    """A tetrahedral mesh of a part's solid (:func:`gmsh_solid_mesh`).

    Attributes
    ----------
    X : (n, 3) vertices, mm.  T : (k, 4) linear tetrahedra.  seconds : meshing time.
    """

    X: np.ndarray
    T: np.ndarray
    seconds: float


def gmsh_solid_mesh(shape, max_edge: float, *, min_edge: float | None = None) -> SolidMesh:
    """Tetrahedra filling the solids of ``shape`` (gmsh's Delaunay 3-D mesher), for the
    part's elastic model (:mod:`qifreport.registration.restraint.elastic`).

    Parameters
    ----------
    shape : ``TopoDS_Shape`` holding at least one solid, mm.
    max_edge : target edge length, mm (a thin wall gets at least one element through its
        thickness; quadratic elements carry its bending).
    min_edge : size floor, mm; default ``max_edge / 20``.

    Raises
    ------
    InputError
        No solid in the shape, or gmsh produced no tetrahedra.
    """
    t0 = time.perf_counter()
    if not max_edge > 0:
        raise ValueError(f"max_edge must be positive, got {max_edge}")
    min_edge = max_edge / 20.0 if min_edge is None else min(float(min_edge), float(max_edge))
    with _brep_file(shape) as brep, _GmshSession() as gmsh:
        gmsh.model.occ.importShapes(brep, highestDimOnly=True)
        gmsh.model.occ.synchronize()
        if not gmsh.model.getEntities(3):
            raise InputError("the part has no solid to fill with tetrahedra")
        gmsh.option.setNumber("Mesh.MeshSizeMax", float(max_edge))
        gmsh.option.setNumber("Mesh.MeshSizeMin", float(min_edge))
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        types, _, nodes = gmsh.model.mesh.getElements(3)
    tets = [
        np.asarray(n, dtype=np.int64).reshape(-1, 4)
        for t, n in zip(types, nodes, strict=True)
        if t == 4
    ]
    if not tets:
        raise InputError("gmsh produced no tetrahedra for the part's solid")
    T = np.concatenate(tets)
    X = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    index = np.full(int(np.max(tags)) + 1, -1, dtype=np.int64)
    index[np.asarray(tags, dtype=np.int64)] = np.arange(len(tags))
    T = index[T]
    used = np.unique(T)  # gmsh keeps the surface-only nodes of other entities
    remap = np.full(len(X), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    dt = time.perf_counter() - t0
    log.info("gmsh tetrahedra: %d vertices, %d tetrahedra in %.2f s", len(used), len(T), dt)
    return SolidMesh(X=X[used], T=remap[T], seconds=dt)


def _collect(gmsh, tag_of_face: list[int]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Nodes (n, 3) mm with gmsh node tags as row + 1, and the (t, 3) node tags per face."""
    node_tags, xyz, _ = gmsh.model.mesh.getNodes()
    node_tags = np.asarray(node_tags, dtype=np.int64)
    n_max = int(node_tags.max()) if len(node_tags) else 0
    P = np.full((n_max + 1, 3), np.nan)
    P[node_tags] = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    tris = []
    for tag in tag_of_face:
        types, _, enodes = gmsh.model.mesh.getElements(2, tag)
        t = [
            np.asarray(en, dtype=np.int64).reshape(-1, 3)
            for ty, en in zip(types, enodes, strict=True)
            if ty == 2
        ]
        tris.append(np.concatenate(t) if t else np.empty((0, 3), dtype=np.int64))
    return P, tris


def _mesh_and_collect(
    gmsh, tag_of_face: list[int], algorithm: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Generate the 2-D mesh, retrying empty faces with other algorithms; welded V, F, fid."""
    gmsh.model.mesh.generate(2)
    P, tris = _collect(gmsh, tag_of_face)
    for alt in (5, 1):
        empty = [k for k, t in enumerate(tris) if len(t) == 0]
        if not empty or alt == algorithm:
            continue
        log.info("gmsh left %d faces empty; retrying them with algorithm %d", len(empty), alt)
        for k in empty:
            gmsh.model.mesh.setAlgorithm(2, tag_of_face[k], alt)
        gmsh.model.mesh.clear()
        gmsh.model.mesh.generate(2)
        P, tris = _collect(gmsh, tag_of_face)
    empty = [k for k, t in enumerate(tris) if len(t) == 0]
    if empty:
        raise InputError(f"gmsh could not mesh {len(empty)} B-rep face(s), e.g. face {empty[0]}")
    T = np.concatenate(tris)
    fid = np.concatenate([np.full(len(t), k, dtype=np.int64) for k, t in enumerate(tris)])
    used = np.unique(T.ravel())
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    V = P[used]
    F = remap[T]
    good = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
    return V, F[good], fid[good]


def mesh_stats(V: np.ndarray, F: np.ndarray) -> dict:
    """Quality figures of a triangle mesh (for benches and tests).

    Parameters
    ----------
    V : (n, 3) float64, mm.
    F : (f, 3) int64.

    Returns
    -------
    dict with ``triangles``; ``min_angle_p1``, ``min_angle_p50`` (degrees, percentiles of
    each triangle's smallest angle); ``share_under_5deg`` (fraction of triangles with an
    angle under 5 degrees); ``duplicate_triangles`` (triangles on the same three vertices as
    an earlier one); ``non_manifold_edges`` (edges on more than two triangles);
    ``boundary_edges`` (edges on one triangle); ``pieces`` (edge-connected components).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    a = V[F[:, 1]] - V[F[:, 0]]
    b = V[F[:, 2]] - V[F[:, 1]]
    c = V[F[:, 0]] - V[F[:, 2]]

    def ang(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        nu = np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1)
        cs = np.einsum("ij,ij->i", u, w) / np.where(nu > 0, nu, 1.0)
        return np.degrees(np.arccos(np.clip(cs, -1.0, 1.0)))

    angles = np.stack([ang(a, -c), ang(b, -a), ang(c, -b)], axis=1)
    amin = angles.min(axis=1)
    dup = len(F) - len(np.unique(np.sort(F, axis=1), axis=0))
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    eu, inv, cnt = np.unique(E, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    tri = np.tile(np.arange(len(F)), 3)
    # triangles sharing an edge are connected
    order = np.argsort(inv, kind="stable")
    same = inv[order][1:] == inv[order][:-1]
    r, s = tri[order][1:][same], tri[order][:-1][same]
    g = coo_matrix((np.ones(len(r)), (r, s)), shape=(len(F), len(F)))
    pieces = connected_components(g, directed=False)[0] if len(F) else 0
    return {
        "triangles": int(len(F)),
        "min_angle_p1": float(np.percentile(amin, 1)) if len(F) else float("nan"),
        "min_angle_p50": float(np.percentile(amin, 50)) if len(F) else float("nan"),
        "share_under_5deg": float(np.mean(amin < 5.0)) if len(F) else float("nan"),
        "duplicate_triangles": int(dup),
        "non_manifold_edges": int(np.sum(cnt > 2)),
        "boundary_edges": int(np.sum(cnt == 1)),
        "pieces": int(pieces),
    }


def brep_pieces(shape, faces: list) -> tuple[int, int]:
    """The B-rep's own connectivity: (pieces, free edges).

    Parameters
    ----------
    shape : ``TopoDS_Shape``.
    faces : its faces in face-id order.

    Returns
    -------
    ``pieces``: components of the faces connected through shared edges; ``free_edges``:
    edges (not degenerate, not seams) bounding a single face. A watertight single solid gives
    ``(1, 0)``; a mesh of it can have no fewer pieces and open edges where the B-rep has.
    """
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopoDS import TopoDS
    from OCP.TopTools import (
        TopTools_IndexedDataMapOfShapeListOfShape,
        TopTools_IndexedMapOfShape,
    )
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    emap = TopTools_IndexedDataMapOfShapeListOfShape()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, emap)
    r, s = [], []
    free = 0
    for i in range(1, emap.Size() + 1):
        edge = TopoDS.Edge_s(emap.FindKey(i))
        if BRep_Tool.Degenerated_s(edge):
            continue
        ids = sorted({fmap.FindIndex(f) - 1 for f in emap.FindFromIndex(i)})
        if len(ids) == 1:
            if not BRep_Tool.IsClosed_s(edge, TopoDS.Face_s(fmap.FindKey(ids[0] + 1))):
                free += 1
            continue
        for a in ids[1:]:
            r.append(ids[0])
            s.append(a)
    n = len(faces)
    g = coo_matrix((np.ones(len(r)), (r, s)), shape=(n, n))
    return int(connected_components(g, directed=False)[0]), int(free)
