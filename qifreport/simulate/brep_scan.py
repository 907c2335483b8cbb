"""A perfect multiview scan of a STEP part, sampled on the exact B-rep surfaces.

The scan is independent of the inspection's own tessellation (gmsh or BRepMesh): a fine
BRepMesh of a *copy* of the shape only decides which surface a view sees (depth buffer,
:func:`qifreport.simulate.scanner.rasterize`); every hit is then moved onto the exact surface
of its B-rep face by evaluating that surface at the hit's parameters (the triangle's UV
nodes, interpolated with the hit's barycentric coordinates), so the points lie on the CAD
surface to the surface evaluator's precision, not to a chord height. Range noise is added
along the view direction.

Used by the tests and benchmarks of real CAD nominals: a part's own
perfect scan must PASS, and a bump on a toleranced face must FAIL that tolerance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from trimesh.triangles import points_to_barycentric

from .scanner import aim_views, rasterize

__all__ = [
    "BrepSurfaceMesh",
    "BrepScan",
    "brep_surface_mesh",
    "perfect_scan",
    "plan_views",
    "brep_scan",
    "exact_scan",
    "bump",
    "bump_site",
    "dome",
    "random_pose",
    "surface_sample",
    "toleranced_weight",
    "technician_scan",
]

log = logging.getLogger(__name__)


@dataclass
class BrepSurfaceMesh:
    """A fine triangulation of a B-rep that remembers every triangle's surface parameters.

    Attributes
    ----------
    V : (n, 3) float64, mm.  F : (f, 3) int64, outward triangles.
    UV : (f, 3, 2) float64, the surface parameters of each triangle's corners.
    face : (f,) int64, the B-rep face (index into the part's face list).
    normal : (f, 3) float64, outward unit normal of each triangle.
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    face: np.ndarray
    normal: np.ndarray


def brep_surface_mesh(shape, faces: list, deflection: float, angle: float = 0.1) -> BrepSurfaceMesh:
    """Fine BRepMesh of a copy of ``shape`` (the caller's shape is not touched), of the
    faces a scanner can see: a part with solids is its solids' faces (supplemental faces,
    :mod:`qifreport.step.supplemental`, are no material: NIST CTC 02's datum-target patch
    put 26 points 6-18 mm off the part).

    Parameters
    ----------
    shape : ``TopoDS_Shape`` (mm).  faces : its faces in face-id order.
    deflection : chord height of the fine mesh, mm (it only steers visibility).
    angle : angular deflection, rad.
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Copy
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS
    from OCP.TopTools import TopTools_IndexedMapOfShape

    from qifreport.step.supplemental import face_solids

    solid_of = face_solids(shape, faces)
    material = solid_of >= 0 if (solid_of >= 0).any() else np.ones(len(faces), dtype=bool)
    cp = BRepBuilderAPI_Copy(shape, True, False).Shape()
    BRepMesh_IncrementalMesh(cp, deflection, False, angle, True)
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(cp, TopAbs_FACE, fmap)
    if fmap.Size() != len(faces):
        raise ValueError(f"the copy has {fmap.Size()} faces, the part {len(faces)}")
    Vs, Fs, UVs, owner = [], [], [], []
    base = 0
    for i in range(1, fmap.Size() + 1):
        if not material[i - 1]:
            continue
        face = TopoDS.Face_s(fmap.FindKey(i))
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, loc)
        if tri is None or tri.NbTriangles() == 0:
            continue
        trsf = loc.Transformation()
        n = tri.NbNodes()
        P = np.empty((n, 3))
        UV = np.empty((n, 2))
        for j in range(n):
            p = tri.Node(j + 1).Transformed(trsf)
            P[j] = (p.X(), p.Y(), p.Z())
            if tri.HasUVNodes():
                uv = tri.UVNode(j + 1)
                UV[j] = (uv.X(), uv.Y())
        if not tri.HasUVNodes():
            UV[:] = np.nan
        T = np.array([tri.Triangle(j + 1).Get() for j in range(tri.NbTriangles())]) - 1
        if face.Orientation() == TopAbs_REVERSED:
            T = T[:, ::-1]
        Vs.append(P)
        Fs.append(T + base)
        UVs.append(UV[T])
        owner.append(np.full(len(T), i - 1, dtype=np.int64))
        base += n
    V = np.concatenate(Vs)
    F = np.concatenate(Fs).astype(np.int64)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    nrm = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
    return BrepSurfaceMesh(V=V, F=F, UV=np.concatenate(UVs), face=np.concatenate(owner), normal=nrm)


@dataclass
class BrepScan:
    """A simulated scan of the exact B-rep.

    Attributes
    ----------
    P : (m, 3) measured points (noise added), mm, in the part frame.
    face : (m,) B-rep face id of each point. SCORING ONLY.
    normal : (m, 3) outward unit normal at each point. SCORING ONLY.
    view : (m,) view index.  directions : (k, 3) view directions (camera -> part).
    """

    P: np.ndarray
    face: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    directions: np.ndarray


def _areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(f,) triangle areas, mm^2."""
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def _on_surface(faces: list, fid: np.ndarray, uv: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Evaluate each point's face surface at ``uv``; points without UV keep ``X``."""
    from OCP.BRep import BRep_Tool

    out = X.copy()
    order = np.argsort(fid, kind="stable")
    starts = np.flatnonzero(np.r_[True, fid[order][1:] != fid[order][:-1]])
    ends = np.r_[starts[1:], len(order)]
    for a, b in zip(starts, ends, strict=True):
        rows = order[a:b]
        surf = BRep_Tool.Surface_s(faces[int(fid[rows[0]])])
        for r in rows:
            u, v = uv[r]
            if not np.isfinite(u):
                continue
            p = surf.Value(float(u), float(v))
            out[r] = (p.X(), p.Y(), p.Z())
    return out


def brep_scan(
    shape,
    faces: list,
    *,
    views: int = 4,
    tilt_deg: float = 35.0,
    noise: float = 0.01,
    points: int = 60_000,
    grazing: float = 0.15,
    directions: np.ndarray | None = None,
    seed: int = 0,
    mesh: BrepSurfaceMesh | None = None,
) -> BrepScan:
    """A multiview range scan of the exact B-rep surfaces of ``shape``.

    Parameters
    ----------
    shape : ``TopoDS_Shape`` (mm).  faces : its faces in face-id order.
    views, tilt_deg : automatic view aiming (:func:`qifreport.simulate.scanner.aim_views`);
        ``directions`` (k, 3) overrides it.
    noise : sigma of the Gaussian range noise along the view direction, mm.
    points : about how many points all views give together (sets the pixel pitch).
    grazing : hits whose ``|n . v|`` is below this are dropped.
    seed : noise seed.  mesh : a :func:`brep_surface_mesh` to reuse.

    Returns
    -------
    :class:`BrepScan` in the part frame.
    """
    if mesh is None:
        mesh = brep_surface_mesh(shape, faces, deflection=2e-4 * _diagonal(shape))
    V, F = mesh.V, mesh.F
    dirs = (
        aim_views(V, F, views, tilt_deg)
        if directions is None
        else np.atleast_2d(np.asarray(directions, dtype=np.float64))
    )
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    area = _areas(V, F)
    # about half the surface faces one view: its projected area ~ area / 4 (a sphere's ratio)
    pixel = float(np.sqrt(area.sum() / 4.0 * len(dirs) / max(points, 1)))
    rng = np.random.default_rng(seed)
    Ps, fs, ns, vs = [], [], [], []
    for k, v in enumerate(dirs):
        hits = rasterize(V, F, v, pixel)
        n = mesh.normal[hits.face]
        ok = -(n @ v) >= grazing  # facing the camera (v points from camera into the part)
        X, tri, n = hits.X[ok], hits.face[ok], n[ok]
        B = np.clip(points_to_barycentric(V[F[tri]], X), 0.0, 1.0)
        B /= B.sum(axis=1, keepdims=True)
        uv = np.einsum("ij,ijk->ik", B, mesh.UV[tri])
        X = _on_surface(faces, mesh.face[tri], uv, X)
        P = X + (noise * rng.standard_normal(len(X)))[:, None] * v[None, :]
        Ps.append(P)
        fs.append(mesh.face[tri])
        ns.append(n)
        vs.append(np.full(len(P), k, dtype=np.int64))
    return BrepScan(
        P=np.concatenate(Ps),
        face=np.concatenate(fs),
        normal=np.concatenate(ns),
        view=np.concatenate(vs),
        directions=dirs,
    )


def _area_sample(
    mesh: BrepSurfaceMesh, density: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points over the fine mesh's area, ``density`` per mm^2 on average:
    the triangle of each point (m,) and its barycentric coordinates (m, 3)."""
    V, F = mesh.V, mesh.F
    n = rng.poisson(_areas(V, F) * density)
    tri = np.repeat(np.arange(len(F)), n)
    r1, r2 = rng.random(len(tri)), rng.random(len(tri))
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    return tri, np.c_[1 - r1 - r2, r1, r2]


def surface_sample(
    shape, faces: list, spacing: float, *, seed: int = 0, mesh: BrepSurfaceMesh | None = None
) -> BrepScan:
    """Points on every face of the exact B-rep, about one per ``spacing`` x ``spacing`` mm^2
    (a full-coverage sample, as a CT scan sees a part; no noise, no views).

    Returns a :class:`BrepScan` (``view`` -1, ``directions`` empty)."""
    if mesh is None:
        mesh = brep_surface_mesh(shape, faces, deflection=2e-4 * _diagonal(shape))
    tri, B = _area_sample(mesh, 1.0 / spacing**2, np.random.default_rng(seed))
    X = np.einsum("ij,ijk->ik", B, mesh.V[mesh.F[tri]])
    uv = np.einsum("ij,ijk->ik", B, mesh.UV[tri])
    X = _on_surface(faces, mesh.face[tri], uv, X)
    return BrepScan(
        P=X,
        face=mesh.face[tri],
        normal=mesh.normal[tri],
        view=np.full(len(X), -1, dtype=np.int64),
        directions=np.zeros((0, 3)),
    )


def exact_scan(
    shape,
    faces: list,
    density: float,
    *,
    noise: float = 0.005,
    seed: int = 0,
    mesh: BrepSurfaceMesh | None = None,
) -> BrepScan:
    """An exact all-faces scan of a B-rep: points area-sampled at ``density`` per mm^2 on
    average (Poisson per triangle of a fine mesh, uniform within it), each evaluated on its
    own face's surface at its interpolated surface parameters (so it lies on the CAD
    surface, not on a chord), then moved by Gaussian noise of sigma ``noise`` mm along the
    surface's exact outward normal there. Every face of material is seen (no views, no
    occlusion); the same ``seed`` gives the same scan.

    Parameters
    ----------
    shape : ``TopoDS_Shape`` (mm).  faces : its faces in face-id order.
    density : points per mm^2 of surface.  noise : normal noise sigma, mm.
    seed : sampling and noise seed.  mesh : a :func:`brep_surface_mesh` to reuse.

    Returns
    -------
    :class:`BrepScan`: ``P`` (m, 3), ``face``, ``normal`` the exact outward unit normal
    (SCORING ONLY), ``view`` -1, ``directions`` empty.
    """
    if mesh is None:
        mesh = brep_surface_mesh(shape, faces, deflection=2e-4 * _diagonal(shape))
    rng = np.random.default_rng(seed)
    tri, B = _area_sample(mesh, density, rng)
    uv = np.einsum("ij,ijk->ik", B, mesh.UV[tri])
    X, N = _on_surface_normal(faces, mesh.face[tri], uv, mesh.normal[tri])
    chord = ~np.isfinite(X).all(axis=1)  # no surface parameters: the chord's point
    X[chord] = np.einsum("ij,ijk->ik", B[chord], mesh.V[mesh.F[tri[chord]]])
    P = X + (noise * rng.standard_normal(len(X)))[:, None] * N
    return BrepScan(
        P=P,
        face=mesh.face[tri],
        normal=N,
        view=np.full(len(P), -1, dtype=np.int64),
        directions=np.zeros((0, 3)),
    )


def _on_surface_normal(
    faces: list, fid: np.ndarray, uv: np.ndarray, tri_normal: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's position (m, 3) and outward unit normal (m, 3) on its face's surface at
    ``uv`` (m, 2): the normal turned to the face's orientation and to the side of its
    triangle's (``tri_normal``, which also stands in where the surface has none, a cone's
    apex). Positions without surface parameters are NaN."""
    from OCP.BRep import BRep_Tool
    from OCP.GeomAbs import GeomAbs_Plane
    from OCP.GeomAdaptor import GeomAdaptor_Surface
    from OCP.GeomLProp import GeomLProp_SLProps
    from OCP.TopAbs import TopAbs_REVERSED

    X = np.full((len(fid), 3), np.nan)
    N = tri_normal.copy()
    order = np.argsort(fid, kind="stable")
    starts = np.flatnonzero(np.r_[True, fid[order][1:] != fid[order][:-1]])
    for rows in np.split(order, starts[1:]) if len(order) else []:
        face = faces[int(fid[rows[0]])]
        surf = BRep_Tool.Surface_s(face)
        sign = -1.0 if face.Orientation() == TopAbs_REVERSED else 1.0
        rows = rows[np.isfinite(uv[rows]).all(axis=1)]
        adaptor = GeomAdaptor_Surface(surf)
        if len(rows) and adaptor.GetType() == GeomAbs_Plane:
            pos = adaptor.Plane().Position()  # Value(u, v) = origin + u x + v y
            o, ax, ay = (
                np.array([d.X(), d.Y(), d.Z()])
                for d in (pos.Location(), pos.XDirection(), pos.YDirection())
            )
            X[rows] = o + uv[rows, :1] * ax + uv[rows, 1:] * ay
            N[rows] = sign * np.cross(ax, ay)  # dS/du x dS/dv, as GeomLProp's normal
            continue
        for r in rows:
            props = GeomLProp_SLProps(surf, float(uv[r, 0]), float(uv[r, 1]), 1, 1e-9)
            p = props.Value()
            X[r] = (p.X(), p.Y(), p.Z())
            if props.IsNormalDefined():
                n = props.Normal()
                N[r] = (sign * n.X(), sign * n.Y(), sign * n.Z())
    flip = np.einsum("ij,ij->i", N, tri_normal) < 0
    N[flip] *= -1.0
    return X, N


def plan_views(
    mesh: BrepSurfaceMesh,
    views: int = 4,
    *,
    face_weight: np.ndarray | None = None,
    candidates: int = 60,
    grazing: float = 0.15,
    pixel: float | None = None,
) -> np.ndarray:
    """View directions (views, 3) that together see as much of the part as they can.

    A scanning technician places the part so that the views see the surfaces that matter;
    this picks ``views`` directions greedily among ``candidates`` spread over the sphere
    (a Fibonacci lattice), each time the one that adds the most newly seen area, weighted per
    B-rep face by ``face_weight`` (e.g. higher on toleranced faces; default 1). A triangle
    counts as seen from a direction when a depth-buffer pixel lands on it facing the camera
    (``-n . v >= grazing``).
    """
    V, F = mesh.V, mesh.F
    area = _areas(V, F)
    w = area if face_weight is None else area * np.asarray(face_weight)[mesh.face]
    if pixel is None:
        pixel = float(np.sqrt(area.sum() / 20_000.0))
    k = np.arange(candidates) + 0.5
    z = 1.0 - 2.0 * k / candidates
    phi = np.pi * (1.0 + 5**0.5) * k
    D = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    seen = []
    for v in D:
        hits = rasterize(V, F, v, pixel)
        ok = -(mesh.normal[hits.face] @ v) >= grazing
        m = np.zeros(len(F), dtype=bool)
        m[hits.face[ok]] = True
        seen.append(m)
    got = np.zeros(len(F), dtype=bool)
    chosen: list[int] = []
    for _ in range(min(views, candidates)):
        gain = [-1.0 if i in chosen else float(w[s & ~got].sum()) for i, s in enumerate(seen)]
        best = int(np.argmax(gain))
        chosen.append(best)
        got |= seen[best]
    return D[chosen]


def perfect_scan(
    shape,
    faces: list,
    *,
    views: int = 4,
    noise: float = 0.01,
    points: int = 150_000,
    seed: int = 0,
    face_weight: np.ndarray | None = None,
) -> tuple[BrepScan, BrepSurfaceMesh]:
    """A part's perfect scan: ``views`` planned views (:func:`plan_views`, weighted per face
    by ``face_weight``, e.g. :func:`toleranced_weight`) of its exact B-rep
    (:func:`brep_scan`), ``noise`` mm range noise, about ``points`` points; and the fine
    surface mesh it was made with (for :func:`bump_site`)."""
    mesh = brep_surface_mesh(shape, faces, deflection=2e-4 * _diagonal(shape))
    dirs = plan_views(mesh, views, face_weight=face_weight)
    scan = brep_scan(
        shape, faces, directions=dirs, noise=noise, points=points, mesh=mesh, seed=seed
    )
    return scan, mesh


def toleranced_weight(part, boost: float = 10.0) -> np.ndarray:
    """Per-face view-planning weights (n_faces,) of a STEP part: ``boost`` on the faces of
    its surface-profile tolerances (not the whole-part ones), 1 elsewhere: the technician
    aims the views at the surfaces the drawing tolerances.

    ``part`` is a :class:`qifreport.step.reader.StepPart`.
    """
    w = np.ones(len(part.faces))
    index = part.face_index()
    for t in part.pmi.tolerances:
        if t.whole_part or "profile" not in t.type:
            continue
        for sid in t.face_step_ids:
            if sid in index:
                w[index[sid]] = boost
    return w


def technician_scan(
    part, *, noise: float = 0.01, points: int = 150_000, seed: int = 7
) -> tuple[BrepScan, BrepSurfaceMesh]:
    """:func:`perfect_scan` of a STEP part (:class:`qifreport.step.reader.StepPart`) with its
    four views aimed at the surfaces its drawing tolerances first
    (:func:`toleranced_weight`), as a technician would: the NIST tests' and benches' scan."""
    return perfect_scan(
        part.shape,
        part.faces,
        noise=noise,
        points=points,
        seed=seed,
        face_weight=toleranced_weight(part),
    )


def _diagonal(shape) -> float:
    from qifreport.step.tessellate import shape_diagonal

    return float(shape_diagonal(shape))


def bump_site(mesh: BrepSurfaceMesh, face: int) -> np.ndarray:
    """A point of B-rep face ``face`` as far from the face's boundary as it gets (mm, (3,)),
    so that a bump stays on the face where it can.

    The boundary is the face's own open edges in the fine mesh (edges used once among its
    triangles); the centre is the face's triangle centroid farthest from them.
    """
    from scipy.spatial import cKDTree

    tri = np.flatnonzero(mesh.face == face)
    if len(tri) == 0:
        raise ValueError(f"face {face} has no triangles")
    Ff = mesh.F[tri]
    e = np.sort(np.concatenate([Ff[:, [0, 1]], Ff[:, [1, 2]], Ff[:, [2, 0]]]), axis=1)
    uniq, cnt = np.unique(e, axis=0, return_counts=True)
    rim = np.unique(uniq[cnt == 1])
    cen = mesh.V[Ff].mean(axis=1)
    if len(rim) == 0:
        return cen[0]
    # rim sampled densely enough along its edges
    a, b = mesh.V[uniq[cnt == 1][:, 0]], mesh.V[uniq[cnt == 1][:, 1]]
    t = np.linspace(0.0, 1.0, 5)[:, None, None]
    R = (a[None] * (1 - t) + b[None] * t).reshape(-1, 3)
    d, _ = cKDTree(R).query(cen)
    return cen[int(np.argmax(d))]


def bump(
    P: np.ndarray,
    normal: np.ndarray,
    face: np.ndarray,
    centre: np.ndarray,
    on_face: int,
    height: float,
    sigma: float,
) -> np.ndarray:
    """Scan points with a Gaussian bump of ``height`` (mm, outward) and width ``sigma`` (mm)
    added on B-rep face ``on_face`` around ``centre``: ``h exp(-r^2 / 2 sigma^2)`` along each
    point's outward normal, for the points of that face only. Returns a new (m, 3) array."""
    r2 = np.sum((P - centre) ** 2, axis=1)
    w = height * np.exp(-r2 / (2.0 * sigma * sigma)) * (face == on_face)
    return P + w[:, None] * normal


def dome(
    P: np.ndarray, normal: np.ndarray, face: np.ndarray, on_face: int, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """Scan points with B-rep face ``on_face`` bowed outward by a parabolic dome: each of
    its points moved along its outward normal by ``height (1 - r^2 / r_max^2)`` mm, ``r``
    its distance in the face's tangent plane from the face points' centroid (``height``
    at the centroid, 0 at the farthest point); the other points as they are.

    Returns
    -------
    (m, 3) the new points, and (k,) the heights given to the face's k points, mm (their
    range bounds the face's flatness from above; a centred dome's is that range).
    """
    on = face == on_face
    n = normal[on]
    r = P[on] - P[on].mean(axis=0)
    r -= np.einsum("ij,ij->i", r, n)[:, None] * n
    r2 = np.einsum("ij,ij->i", r, r)
    h = height * (1.0 - r2 / r2.max())
    Q = P.copy()
    Q[on] += h[:, None] * n
    return Q, h


def random_pose(rng: np.random.Generator, centre: np.ndarray, shift: float) -> np.ndarray:
    """A random rigid motion (4, 4): uniform rotation about ``centre`` and a translation of
    length ``shift`` (mm) in a random direction."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=rng).as_matrix()
    d = rng.standard_normal(3)
    d *= shift / np.linalg.norm(d)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ centre + d
    return T
