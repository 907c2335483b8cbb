"""Virtual multiview range scanner (paper Section 4.2).

Each view projects the surface orthographically along its direction ``v`` onto an image grid,
keeps the nearest surface sample per pixel (depth buffer: self-occluded surface is removed),
discards grazing samples (``|n . v| < tau_g``), perturbs every sample along ``v`` with Gaussian
range noise, thins at random and cuts a dropout disk around each clamp. The views are
concatenated into one unordered cloud: a :class:`~qifreport.registration.scan.Scan`, as the
inspection reads one from a file. The generator vertex and the true normal of every sample
are recorded beside it (:class:`SimulatedScan`) for scoring only; they must never reach a
registration algorithm.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from qifreport.registration.mesh import face_normals, median_edge_length
from qifreport.registration.scan import Scan

from .deform import pca_frame

__all__ = [
    "aim_views",
    "turntable_views",
    "rasterize",
    "ScanSpec",
    "SimulatedScan",
    "virtual_scan",
    "with_stray_points",
]

log = logging.getLogger(__name__)

# Upper bound on (triangle, pixel) candidates rasterised at once (bounds memory to ~100 MB).
_CHUNK = 1_000_000


def turntable_views(k: int = 3, tilt_deg: float = 25.0, both_sides: bool = False) -> np.ndarray:
    """(k, 3) camera -> part directions: looking down -z, tilted ``tilt_deg`` at ``k``
    azimuths; ``both_sides`` adds the same views from below (the part scanned, turned over,
    scanned): (2k, 3)."""
    t = np.deg2rad(tilt_deg)
    phi = 2 * np.pi * np.arange(k) / k
    d = np.c_[np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), -np.cos(t) * np.ones(k)]
    if both_sides:
        d = np.vstack([d, d * np.array([1.0, 1.0, -1.0])])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class ScanSpec:
    """Acquisition parameters of :func:`virtual_scan`.

    Attributes
    ----------
    views : number of automatically aimed views (ignored when ``directions`` is given).
    tilt_deg : tilt of each view away from the main axis, degrees (see :func:`aim_views`).
    pixel : image-grid pitch, mm; ``None`` -> 0.7 x the mesh's median edge length.
    noise : sigma of the Gaussian range noise along the view direction, mm.
    grazing : ``tau_g``; samples whose face normal has ``|n . v| < tau_g`` are dropped.
    thinning : fraction of samples removed at random (each kept with prob. 1 - thinning).
    dropout_radius : radius (mm) of the no-data ball around each clamp centre.
    clamp_centers : (k, 3) clamp positions, mm (e.g. ``Handles.centers``).
    directions : (k, 3) view directions (camera -> part); overrides automatic aiming.
    seed : seed of ``np.random.default_rng`` for noise and thinning.
    """

    views: int = 3
    tilt_deg: float = 25.0
    pixel: float | None = None
    noise: float = 0.02
    grazing: float = 0.2
    thinning: float = 0.1
    dropout_radius: float = 0.0
    clamp_centers: np.ndarray | None = None
    directions: np.ndarray | None = None
    seed: int = 0


@dataclass
class SimulatedScan:
    """A simulated scan: the :class:`~qifreport.registration.scan.Scan` an inspection gets
    (points only, format ``"simulated"``) and its truth.

    Attributes
    ----------
    scan : the measured points, mm.
    vertex : (m,) int64 generator vertex (nearest vertex of the hit triangle). SCORING ONLY.
    view : (m,) int index of the view that produced each point.
    directions : (k, 3) unit view directions (camera -> part).
    true_normals : (m, 3) true unit surface normal (of the hit triangle). SCORING ONLY.
    """

    scan: Scan
    vertex: np.ndarray
    view: np.ndarray
    directions: np.ndarray
    true_normals: np.ndarray

    @property
    def P(self) -> np.ndarray:
        """(m, 3) the measured points, mm (``scan.points``)."""
        return self.scan.points


def _perpendicular_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic orthonormal ``e1, e2`` with ``e1 x e2 = a`` for a unit vector ``a``."""
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def aim_views(V: np.ndarray, F: np.ndarray, views: int, tilt_deg: float) -> np.ndarray:
    """Automatic view directions (k, 3), unit vectors from the camera into the part.

    The main axis ``a`` is minus the area-weighted mean face normal when that mean has norm
    > 0.3 (an open shell: look at its front face), else minus the PCA mid-plane normal ``u3``
    (a closed solid, whose mean normal vanishes). View ``k`` is ``a`` tilted by ``tilt_deg``
    about the axis ``cos(phi) e1 + sin(phi) e2`` perpendicular to ``a``, ``phi = 2 pi k / views``;
    a single view is not tilted. Two views are therefore a pair of opposing tilted poses.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if views < 1:
        raise ValueError("views must be >= 1")
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # 2 x area x normal
    mean_n = cross.sum(axis=0) / max(np.linalg.norm(cross, axis=1).sum(), 1e-300)
    if np.linalg.norm(mean_n) > 0.3:
        a = -mean_n / np.linalg.norm(mean_n)
    else:
        area = np.zeros(len(V))
        for k in range(3):
            np.add.at(area, F[:, k], np.linalg.norm(cross, axis=1))
        a = -pca_frame(V, area)[1][:, 2]
    if views == 1:
        return a[None, :].copy()
    e1, e2 = _perpendicular_basis(a)
    t = np.deg2rad(tilt_deg)
    phi = 2.0 * np.pi * np.arange(views) / views
    axes = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    # Rodrigues for an axis perpendicular to a: a cos t + (axis x a) sin t
    dirs = np.cos(t) * a[None, :] + np.sin(t) * np.cross(axes, a)
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


@dataclass
class _Hits:
    """Nearest surface sample per pixel of one view (noise-free)."""

    X: np.ndarray  # (m, 3) hit points, mm
    face: np.ndarray  # (m,) hit triangle


def rasterize(V: np.ndarray, F: np.ndarray, direction: np.ndarray, pixel: float) -> _Hits:
    """Orthographic depth-buffer rendering of ``(V, F)`` along ``direction``.

    Pixel centres lie on a grid of pitch ``pixel`` (mm) in the plane perpendicular to the
    unit ``direction``. For each triangle every pixel centre in its 2D bounding box is tested
    with barycentric coordinates; of all hits on a pixel the one nearest the camera (smallest
    depth ``x . direction``) is kept, so occluded surface is removed. Triangles seen exactly
    edge-on cover no pixel.
    """
    v = np.asarray(direction, dtype=np.float64)
    v = v / np.linalg.norm(v)
    e1, e2 = _perpendicular_basis(v)
    uv = V @ np.column_stack([e1, e2])
    depth = V @ v
    origin = uv.min(axis=0)
    grid = (uv - origin) / pixel - 0.5  # pixel-centre units: centre (i, j) at integer (i, j)
    width = int(np.floor(grid[:, 0].max())) + 2

    T = grid[F]  # (f, 3, 2)
    # the corners' least and greatest (x, y): pairwise, the same numbers as T.min(axis=1)
    # and T.max(axis=1), several times faster than a reduction along a 3-long axis
    lo = np.ceil(np.minimum(np.minimum(T[:, 0], T[:, 1]), T[:, 2])).astype(np.int64)
    hi = np.floor(np.maximum(np.maximum(T[:, 0], T[:, 1]), T[:, 2])).astype(np.int64)
    span = np.maximum(hi - lo + 1, 0)
    count = span[:, 0] * span[:, 1]
    d1 = T[:, 1] - T[:, 0]
    d2 = T[:, 2] - T[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    count[np.abs(det) < 1e-12] = 0  # edge-on: zero projected area
    faces = np.flatnonzero(count > 0)
    cum = np.cumsum(count[faces])

    pix_l, dep_l, face_l, bary_l = [], [], [], []
    start = 0
    while start < len(faces):
        base = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, base + _CHUNK, side="right")), start + 1)
        fc = faces[start:stop]
        cnt = count[fc]
        fid = np.repeat(fc, cnt)
        local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        nxs = span[fid, 0]
        ix = lo[fid, 0] + local % nxs
        iy = lo[fid, 1] + local // nxs
        qx = ix - T[fid, 0, 0]
        qy = iy - T[fid, 0, 1]
        b1 = (qx * d2[fid, 1] - qy * d2[fid, 0]) / det[fid]
        b2 = (d1[fid, 0] * qy - d1[fid, 1] * qx) / det[fid]
        b0 = 1.0 - b1 - b2
        tol = -1e-9
        inside = (b0 >= tol) & (b1 >= tol) & (b2 >= tol)
        fid, ix, iy = fid[inside], ix[inside], iy[inside]
        b = np.column_stack([b0[inside], b1[inside], b2[inside]])
        pix_l.append(iy * width + ix)
        dep_l.append(np.einsum("ij,ij->i", b, depth[F[fid]]))
        face_l.append(fid)
        bary_l.append(b)
        start = stop
    if not pix_l:
        return _Hits(X=np.zeros((0, 3)), face=np.zeros(0, dtype=np.int64))
    pix = np.concatenate(pix_l)
    dep = np.concatenate(dep_l)
    face = np.concatenate(face_l)
    bary = np.concatenate(bary_l)
    order = np.lexsort((dep, pix))
    first = np.ones(len(order), dtype=bool)
    first[1:] = pix[order[1:]] != pix[order[:-1]]
    keep = order[first]
    face = face[keep]
    bary = np.clip(bary[keep], 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    X = np.einsum("ij,ijk->ik", bary, V[F[face]])
    return _Hits(X=X, face=face.astype(np.int64))


def virtual_scan(V: np.ndarray, F: np.ndarray, spec: ScanSpec | None = None) -> SimulatedScan:
    """Simulate a multiview range scan of the surface ``(V, F)`` (paper Section 4.2).

    Per view: depth-buffered orthographic rasterisation (:func:`rasterize`), grazing cutoff
    on the hit triangle's normal, range noise ``p = x + eta v``, ``eta ~ N(0, noise^2)``,
    random thinning, then removal of samples (noisy positions) within ``dropout_radius`` of
    any clamp centre. The random draws per view are one normal and one uniform variate per
    retained sample, in that order, from ``np.random.default_rng(spec.seed)``, so two scans
    with the same seed differing only in ``noise`` contain the same samples.

    Parameters
    ----------
    V : (n, 3) float, mm (typically the deformed free state).  F : (f, 3) int.
    spec : :class:`ScanSpec` (defaults when ``None``).

    Returns
    -------
    SimulatedScan, points of all views concatenated in view order.
    """
    spec = ScanSpec() if spec is None else spec
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if spec.directions is not None:
        dirs = np.atleast_2d(np.asarray(spec.directions, dtype=np.float64))
        dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    else:
        dirs = aim_views(V, F, spec.views, spec.tilt_deg)
    pixel = spec.pixel if spec.pixel is not None else 0.7 * median_edge_length(V, F)
    if pixel <= 0:
        raise ValueError("pixel pitch must be positive")
    centers = (
        np.zeros((0, 3))
        if spec.clamp_centers is None
        else np.atleast_2d(np.asarray(spec.clamp_centers, dtype=np.float64))
    )
    rng = np.random.default_rng(spec.seed)
    fn = face_normals(V, F)

    out_P, out_vert, out_view, out_n = [], [], [], []
    for k, v in enumerate(dirs):
        hits = rasterize(V, F, v, pixel)
        n = fn[hits.face]
        ok = np.abs(n @ v) >= spec.grazing
        X, face, n = hits.X[ok], hits.face[ok], n[ok]
        eta = spec.noise * rng.standard_normal(len(X))
        kept = rng.random(len(X)) >= spec.thinning
        P = X + eta[:, None] * v[None, :]
        if spec.dropout_radius > 0 and len(centers):
            d2 = ((P[:, None, :] - centers[None, :, :]) ** 2).sum(axis=2)
            kept &= d2.min(axis=1) > spec.dropout_radius**2
        X, face, n, P = X[kept], face[kept], n[kept], P[kept]
        tri = V[F[face]]  # (m, 3, 3)
        nearest = np.argmin(((tri - X[:, None, :]) ** 2).sum(axis=2), axis=1)
        out_P.append(P)
        out_vert.append(F[face, nearest])
        out_view.append(np.full(len(P), k, dtype=np.int64))
        out_n.append(n)
        log.debug("view %d %s: %d samples", k, np.round(v, 3), len(P))
    return SimulatedScan(
        scan=Scan(np.concatenate(out_P), format="simulated"),
        vertex=np.concatenate(out_vert).astype(np.int64),
        view=np.concatenate(out_view),
        directions=dirs,
        true_normals=np.concatenate(out_n),
    )


def with_stray_points(P: np.ndarray, share: float, seed: int) -> np.ndarray:
    """``P`` with ``share * len(P)`` stray points added, uniform in its bounding box grown
    40 % (reflections, dust, fixture parts a real scan holds), in shuffled order.

    Parameters
    ----------
    P : (m, 3) float, scan points, mm.
    share : stray points per scan point (0.01: 1 %).
    seed : random seed.

    Returns
    -------
    (m + round(share * m), 3) float, mm.
    """
    rng = np.random.default_rng(seed)
    lo, hi = P.min(axis=0), P.max(axis=0)
    c, h = (lo + hi) / 2, (hi - lo) / 2 * 1.4
    Q = np.vstack([P, rng.uniform(c - h, c + h, size=(int(round(share * len(P))), 3))])
    rng.shuffle(Q)
    return Q
