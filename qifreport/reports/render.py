"""Offscreen pictures of the deviation map for the one-page report (paper Section 10).

The registered nominal is drawn from two or three automatically chosen directions, every
vertex coloured by its signed deviation:

* **inside its tolerance band**: green, yellow-green toward the proud (+) limit and teal
  toward the sunk (-) limit, so the sign reads even inside the band;
* **outside, proud** (material above the nominal, ``dev > upper``): red, darker with ``|dev|``;
* **outside, sunk** (``dev < lower``): blue, darker with ``|dev|``;
* **unscored** (NaN: the scan did not observe the vertex): neutral grey.

The scale is symmetric about 0 (:func:`color_scale`): red and blue intensities mean the same
``|dev|`` in mm on both sides and saturate at ``+-scale``. Bands always contain 0 (a profile
zone ``[d - t, d]`` with ``0 <= d <= t``), so zero deviation is always the middle green. The
band edge is where the colour jumps from green to red/blue, and every out-of-tolerance
region is outlined by the iso-line ``|dev - centre| = half-width`` (drawn in black, the exact
band edge interpolated along the triangle edges). Region numbers are not burnt into the
images: each :class:`RenderedView` carries the pixel anchor of every region visible in it,
so the caller draws the numbers as vector text on top (:mod:`qifreport.reports.pdf`); the same
way, any named 3-D point (a region's worst point, the part's extremes: the deviation callouts
of :mod:`qifreport.reports.callouts`) comes back as its pixel and whether the view shows it
(:attr:`RenderedView.points`, the region anchors' visibility rule).

Rendering uses VTK offscreen through EGL (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``,
no display needed) with a parallel (orthographic) camera; if VTK cannot render (not
installed, no EGL), matplotlib's Agg backend draws the same views (painter's algorithm on
projected triangles) and a warning is logged.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "GREEN_PROUD",
    "GREEN_SUNK",
    "GREEN_ZERO",
    "GREY",
    "OUTLINE",
    "band_outline",
    "camera_frame",
    "choose_views",
    "color_scale",
    "deviation_colors",
    "nice_ceil",
    "picture_points",
    "RegionLabel",
    "render_views",
    "RenderedView",
    "view_from_direction",
    "ViewSpec",
]

log = logging.getLogger(__name__)

#: RGB (0..1) of unscored surface
GREY = (0.78, 0.78, 0.78)
#: inside the band: sunk limit, zero, proud limit
GREEN_SUNK = (0.10, 0.60, 0.52)
GREEN_ZERO = (0.27, 0.70, 0.27)
GREEN_PROUD = (0.66, 0.82, 0.22)
#: outside the band: from just beyond the band edge (|dev| small) to |dev| >= scale
RED_LIGHT, RED_DARK = (0.98, 0.52, 0.42), (0.55, 0.0, 0.04)
BLUE_LIGHT, BLUE_DARK = (0.50, 0.66, 1.0), (0.04, 0.12, 0.50)
#: outline of the out-of-tolerance regions
OUTLINE = (0.05, 0.05, 0.05)
#: "nice" mantissas of the colour scale
_NICE = (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0)
#: camera names of the world axes (the side the camera is on)
_AXIS_NAMES = {
    (2, 1): "top (+z)",
    (2, -1): "bottom (-z)",
    (1, -1): "front (-y)",
    (1, 1): "back (+y)",
    (0, 1): "right (+x)",
    (0, -1): "left (-x)",
}


@dataclass
class ViewSpec:
    """A camera direction.

    Attributes
    ----------
    name : e.g. ``"top (+z)"`` or ``"oblique (+x-y+z)"``.
    direction : (3,) unit vector from the part toward the camera (world frame).
    up : (3,) unit vector that is up on the picture.
    """

    name: str
    direction: np.ndarray
    up: np.ndarray


@dataclass
class RegionLabel:
    """Where a region's number goes in a view.

    Attributes
    ----------
    number : region number (1 = the first region of the list, the largest).
    x, y : anchor in pixels, origin at the top-left corner of the image.
    visible_fraction : share of the region's vertices visible in this view (0..1).
    extent : distance (pixels) from the anchor to the farthest visible vertex of the region
        (a label placed farther than this does not cover the region).
    """

    number: int
    x: float
    y: float
    visible_fraction: float
    extent: float = 0.0


@dataclass
class Marker:
    """Where a clamp (an RPS point) is in a view: its ``name``, pixel ``x, y`` (origin at
    the top-left corner) and whether the part hides it (``visible``: False, a clamp on
    the far side)."""

    name: str
    x: float
    y: float
    visible: bool


@dataclass
class RenderedView:
    """One picture of the deviation map.

    Attributes
    ----------
    image : (h, w, 3) uint8 RGB, white background.
    name : e.g. ``"top (+z)"``.
    direction : (3,) unit vector from the part toward the camera.
    up : (3,) picture-up vector.
    labels : anchors of the regions visible in this view (numbers from 1).
    axes : (3, 2) picture directions of world x, y, z (unit length when seen face-on,
        shorter when foreshortened; picture y points up).
    mm_per_px : scale of the picture (parallel projection), mm per pixel.
    backend : ``"vtk"`` or ``"matplotlib"``.
    markers : the clamps in this picture (:class:`Marker`).
    points : the named points asked for (``render_views(points=...)``) that fall inside the
        picture, each with its pixel and whether the view shows it (:class:`Marker`; the
        visibility rule of the region anchors, :attr:`labels`).
    """

    image: np.ndarray
    name: str
    direction: np.ndarray
    up: np.ndarray
    labels: list[RegionLabel] = field(default_factory=list)
    axes: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))
    mm_per_px: float = math.nan
    backend: str = "vtk"
    markers: list[Marker] = field(default_factory=list)
    points: list[Marker] = field(default_factory=list)


# ------------------------------------------------------------------------------- colours


def nice_ceil(x: float) -> float:
    """The smallest "nice" number (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 x 10^k) >= ``x`` > 0."""
    if not (math.isfinite(x) and x > 0):
        return 1.0
    e = math.floor(math.log10(x))
    for m in _NICE:
        v = m * 10.0**e
        if v >= x * (1 - 1e-9):
            return float(f"{v:.6g}")
    return 10.0 ** (e + 1)


def color_scale(dev: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """Symmetric colour-scale limit ``S`` (mm): red/blue saturate at ``|dev| >= S``.

    ``S`` is the 99.9th percentile of ``|dev|`` kept between 1.5 and 8 times the widest band
    limit ``max |lower|, |upper|``, rounded up to a nice number (:func:`nice_ceil`), so the
    band occupies a readable part of the colour bar and one outlier does not wash out the map.
    """
    lo = np.abs(np.asarray(lower, dtype=float))
    hi = np.abs(np.asarray(upper, dtype=float))
    ext = np.nanmax(np.r_[lo.ravel(), hi.ravel(), 0.0])
    if not ext > 0:
        ext = 0.1
    a = np.abs(np.asarray(dev, dtype=float))
    a = a[np.isfinite(a)]
    p = float(np.percentile(a, 99.9)) if len(a) else 0.0
    return nice_ceil(min(max(p, 1.5 * ext), 8.0 * ext))


def _lerp(c0, c1, t: np.ndarray) -> np.ndarray:
    c0, c1 = np.asarray(c0, dtype=float), np.asarray(c1, dtype=float)
    return c0 + (c1 - c0) * np.asarray(t, dtype=float)[..., None]


def deviation_colors(dev: np.ndarray, lower, upper, scale: float) -> np.ndarray:
    """RGB colours (n, 3) float in 0..1 of signed deviations under their bands.

    Parameters
    ----------
    dev : (n,) signed deviation, mm; NaN is unscored (grey).
    lower, upper : scalar or (n,) band limits, mm (``lower <= 0 <= upper``); NaN is grey.
    scale : colour-scale limit ``S``, mm (:func:`color_scale`).

    Inside the band the green shade goes from teal (at ``lower``) through green (0) to
    yellow-green (at ``upper``); outside it red (proud) or blue (sunk) darkens linearly with
    ``|dev| / S``, saturating at ``S``.
    """
    dev = np.asarray(dev, dtype=float)
    lo = np.broadcast_to(np.asarray(lower, dtype=float), dev.shape)
    hi = np.broadcast_to(np.asarray(upper, dtype=float), dev.shape)
    out = np.empty(dev.shape + (3,))
    out[:] = GREY
    ok = np.isfinite(dev) & np.isfinite(lo) & np.isfinite(hi)
    d, lo, hi = dev[ok], lo[ok], hi[ok]
    col = np.empty(d.shape + (3,))
    with np.errstate(invalid="ignore", divide="ignore"):
        above, below = d > hi, d < lo
        inside = ~above & ~below
        s = np.clip(np.abs(d) / float(scale), 0.0, 1.0)
        col[above] = _lerp(RED_LIGHT, RED_DARK, s[above])
        col[below] = _lerp(BLUE_LIGHT, BLUE_DARK, s[below])
        pos = inside & (d >= 0)
        neg = inside & (d < 0)
        tp = np.where(hi[pos] > 0, d[pos] / hi[pos], 0.0)
        tn = np.where(lo[neg] < 0, d[neg] / lo[neg], 0.0)
    col[pos] = _lerp(GREEN_ZERO, GREEN_PROUD, np.clip(tp, 0, 1))
    col[neg] = _lerp(GREEN_ZERO, GREEN_SUNK, np.clip(tn, 0, 1))
    out[ok] = col
    return out


# ------------------------------------------------------------------------------ geometry


def _face_normals_areas(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a2 = np.linalg.norm(c, axis=1)
    n = c / np.where(a2 > 0, a2, 1.0)[:, None]
    return n, 0.5 * a2


def _vertex_normals_areas(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fn, fa = _face_normals_areas(V, F)
    N = np.zeros_like(V)
    A = np.zeros(len(V))
    for k in range(3):
        np.add.at(N, F[:, k], fn * fa[:, None])
        np.add.at(A, F[:, k], fa / 3.0)
    N /= np.maximum(np.linalg.norm(N, axis=1), 1e-300)[:, None]
    return N, A


def _is_open(F: np.ndarray) -> bool:
    """Whether the mesh has boundary edges (an open sheet, seen from both sides)."""
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key = e[:, 0].astype(np.int64) * (int(F.max()) + 1) + e[:, 1]
    _, counts = np.unique(key, return_counts=True)
    return bool(np.any(counts == 1))


def _principal_frame(V: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, 3) rows = principal axes (largest variance first), snapped to the world axes
    when every axis lies within 20 degrees of one (CAD parts are usually axis-aligned)."""
    c = (w[:, None] * V).sum(0) / w.sum()
    X = V - c
    C = (w[:, None] * X).T @ X / w.sum()
    _, vecs = np.linalg.eigh(C)
    R = vecs[:, ::-1].T
    idx = np.argmax(np.abs(R), axis=1)
    if len(set(idx.tolist())) == 3 and np.all(
        np.abs(R[np.arange(3), idx]) > math.cos(math.radians(20))
    ):
        return np.eye(3)[idx]
    return R


def _view_name(d: np.ndarray) -> str:
    k = int(np.argmax(np.abs(d)))
    if abs(d[k]) > math.cos(math.radians(10)):
        return _AXIS_NAMES[(k, 1 if d[k] > 0 else -1)]
    parts = "".join(f"{'+' if d[i] > 0 else '-'}{'xyz'[i]}" for i in range(3) if abs(d[i]) > 0.2)
    return f"oblique ({parts})"


def _up_for(d: np.ndarray) -> np.ndarray:
    """Picture-up vector: world +z projected, or +y for views along z."""
    ref = np.array([0.0, 1.0, 0.0]) if abs(d[2]) > 0.9 else np.array([0.0, 0.0, 1.0])
    u = ref - (ref @ d) * d
    return u / np.linalg.norm(u)


def view_from_direction(direction, name: str | None = None) -> ViewSpec:
    """A :class:`ViewSpec` for a camera on the side ``direction`` (from the part)."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    return ViewSpec(name=name or _view_name(d), direction=d, up=_up_for(d))


def choose_views(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    regions: Sequence = (),
    n_views: int = 3,
) -> list[ViewSpec]:
    """Two or three camera directions that together show the most scored surface.

    Candidates are the 14 directions of the principal frame's cube faces (axis views) and
    corners (oblique views); the frame is snapped to the world axes for axis-aligned parts.
    Views are at least 50 degrees apart. A vertex seen from direction ``d`` is shown with
    weight ``n . d`` (its projected area; for an open sheet, whose back is the same surface,
    0.85 ``|n . d|`` from behind). Greedy choice: each next view
    maximises the gain in shown scored area, counting the vertices of out-of-tolerance
    regions five times, so views that show the regions win. Unless one of the first two is
    already oblique, the third is the most informative corner (oblique) direction, which
    gives the depth cue the axis views lack. When a view would add less than 2 % (an open
    sheet is seen whole from one side), the oblique view showing the most is taken.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) triangles.  dev : (n,) deviation, NaN unscored.
    regions : out-of-tolerance regions (objects with ``vertices``).
    n_views : number of views (1 to 3).

    Returns
    -------
    list of :class:`ViewSpec`, the most informative first.
    """
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    N, A = _vertex_normals_areas(V, F)
    w = A * np.isfinite(dev)
    if not w.sum() > 0:
        w = A.copy()
    for r in regions:
        w[np.asarray(r.vertices, dtype=np.int64)] *= 5.0
    R = _principal_frame(V, np.maximum(A, 1e-12))
    cands = []
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            for k in (-1, 0, 1):
                if i or j or k:
                    v = i * R[0] + j * R[1] + k * R[2]
                    cands.append(v / np.linalg.norm(v))
    D = np.array(cands)
    corner = np.sum(np.abs(D @ R.T) > 0.5, axis=1) == 3
    face = np.sum(np.abs(D @ R.T) > 0.99, axis=1) == 1
    proj = N @ D.T  # (n, 26 candidates; edges are never chosen)
    if _is_open(F):  # both sides show the surface; its front (normal side) slightly better
        proj = np.maximum(proj, 0.0) + 0.85 * np.maximum(-proj, 0.0)
    else:
        proj = np.maximum(proj, 0.0)
    best = np.zeros(len(V))
    chosen: list[int] = []
    shown = (w[:, None] * proj).sum(axis=0)
    for step in range(max(1, min(int(n_views), 3))):
        gain = (w[:, None] * (np.maximum(proj, best[:, None]) - best[:, None])).sum(axis=0)
        # edge directions (neither face-on nor a clear oblique) are not used, nor any
        # direction within 50 degrees of a chosen one (nearly the same picture)
        ok = face | corner
        if chosen:
            ok &= np.all(D @ D[chosen].T < math.cos(math.radians(50)), axis=1)
        if step == 2 and not corner[chosen].any():
            ok &= corner  # the third view is oblique: the depth cue axis views lack
        if not ok.any():
            break
        if step > 0 and gain[ok].max() < 0.02 * shown.max():
            # nothing new to show (an open sheet seen whole from the first view): an
            # oblique view showing the most, for the shape
            ok &= corner if (ok & corner).any() else ok
            score = shown
        else:
            # near ties go to the view showing more in all, then to face views (cleaner)
            score = (gain + 0.01 * shown) * np.where(face, 1.02, 1.0)
        k = int(np.argmax(np.where(ok, score, -np.inf)))
        chosen.append(k)
        best = np.maximum(best, proj[:, k])
    return [view_from_direction(D[k]) for k in chosen]


def camera_frame(view: ViewSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors ``(right, up, toward the camera)`` of a view's picture (world frame)."""
    d = np.asarray(view.direction, dtype=float)
    d = d / np.linalg.norm(d)
    u = np.asarray(view.up, dtype=float)
    u = u - (u @ d) * d
    u = u / np.linalg.norm(u)
    r = np.cross(u, d)
    return r, u, d


@dataclass
class _Projection:
    """Parallel projection of one view onto a ``w x h`` picture."""

    r: np.ndarray
    u: np.ndarray
    d: np.ndarray
    cx: float
    cy: float
    k: float  # pixels per mm
    w: int
    h: int
    depth_max: float  # largest V . d (nearest to the camera)

    def pixels(self, X: np.ndarray) -> np.ndarray:
        """(m, 2) pixel coordinates (origin top-left) of points X (m, 3)."""
        x = self.w / 2 + (X @ self.r - self.cx) * self.k
        y = self.h / 2 - (X @ self.u - self.cy) * self.k
        return np.c_[x, y]

    def distance(self, X: np.ndarray) -> np.ndarray:
        """Distance (mm) in front of the nearest point of the part (0 = nearest)."""
        return self.depth_max - X @ self.d


def _projection(
    V: np.ndarray, view: ViewSpec, w: int, h: int, margin: tuple[float, float, float, float]
) -> _Projection:
    """Fit the part into the picture inside the margins ``(left, right, top, bottom)``
    (fractions of the picture's width and height)."""
    ml, mr, mt, mb = margin
    r, u, d = camera_frame(view)
    x, y = V @ r, V @ u
    x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
    span_x = max(x1 - x0, 1e-9)
    span_y = max(y1 - y0, 1e-9)
    k = min(w * (1 - ml - mr) / span_x, h * (1 - mt - mb) / span_y)
    # the centre of the free area maps to the centre of the part's extent
    cx = 0.5 * (x0 + x1) - (w * (ml - mr) / 2) / k
    cy = 0.5 * (y0 + y1) + (h * (mt - mb) / 2) / k
    return _Projection(
        r=r,
        u=u,
        d=d,
        cx=float(cx),
        cy=float(cy),
        k=float(k),
        w=int(w),
        h=int(h),
        depth_max=float((V @ d).max()),
    )


def _margins(margin, n: int) -> np.ndarray:
    """(n, 4) margins ``(left, right, top, bottom)`` of ``n`` views from one number, one
    tuple for all views or one tuple per view."""
    m = np.asarray(margin, dtype=float)
    if m.ndim == 0:
        return np.full((n, 4), float(m))
    return np.tile(m, (n, 1)) if m.ndim == 1 else m[:n]


def picture_points(
    V: np.ndarray,
    view: ViewSpec,
    size: tuple[int, int],
    X: np.ndarray,
    margin: float | Sequence[float] = 0.04,
) -> np.ndarray:
    """Where points fall in the picture :func:`render_views` draws of ``V`` from ``view``.

    Parameters
    ----------
    V : (n, 3) vertices of the registered nominal, mm (they fix the picture's scale).
    view : the camera direction.  size : picture ``(width, height)``, pixels.
    X : (m, 3) points, mm.  margin : as :func:`render_views` (one view's).

    Returns
    -------
    (m, 2) pixel coordinates, origin at the top-left corner (no visibility test).
    """
    V = np.asarray(V, dtype=np.float64)
    pj = _projection(V, view, int(size[0]), int(size[1]), tuple(_margins(margin, 1)[0]))
    return pj.pixels(np.asarray(X, dtype=np.float64).reshape(-1, 3))


def band_outline(V: np.ndarray, F: np.ndarray, dev: np.ndarray, lower, upper) -> np.ndarray:
    """Segments (s, 2, 3) of the band edge ``|dev - c| = h`` (marching triangles).

    The zero set of ``g = |dev - c| - h`` (``c``, ``h``: per-vertex band centre and
    half-width), interpolated linearly along the triangle edges; triangles with an unscored
    vertex are skipped. It encloses every out-of-tolerance region.
    """
    dev = np.asarray(dev, dtype=float)
    lo = np.broadcast_to(np.asarray(lower, dtype=float), dev.shape)
    hi = np.broadcast_to(np.asarray(upper, dtype=float), dev.shape)
    with np.errstate(invalid="ignore"):
        g = np.abs(dev - 0.5 * (lo + hi)) - 0.5 * (hi - lo)
    gs = g[F]
    valid = np.all(np.isfinite(gs), axis=1)
    s = gs > 0
    mixed = valid & s.any(axis=1) & ~s.all(axis=1)
    Fm, gm, sm = F[mixed], gs[mixed], s[mixed]
    if len(Fm) == 0:
        return np.zeros((0, 2, 3))
    pts = np.zeros((len(Fm), 2, 3))
    slot = np.zeros(len(Fm), dtype=np.int64)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        cross = sm[:, a] != sm[:, b]
        ga, gb = gm[cross, a], gm[cross, b]
        t = (ga / (ga - gb))[:, None]
        P = V[Fm[cross, a]] + t * (V[Fm[cross, b]] - V[Fm[cross, a]])
        rows = np.flatnonzero(cross)
        pts[rows, np.minimum(slot[rows], 1)] = P
        slot[rows] += 1
    return pts[slot == 2]


# ------------------------------------------------------------------------------ rendering


def render_views(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    lower,
    upper,
    regions: Sequence = (),
    *,
    size: tuple[int, int] | Sequence[tuple[int, int]] = (800, 600),
    views: Sequence[ViewSpec] | int | None = None,
    scale: float | None = None,
    backend: str | None = None,
    margin: float | Sequence[float] | Sequence[Sequence[float]] = 0.04,
    markers: Sequence[tuple[str, Sequence[float]]] = (),
    points: Sequence[tuple[str, Sequence[float]]] = (),
) -> list[RenderedView]:
    """Pictures of the deviation map from two or three directions.

    Parameters
    ----------
    V : (n, 3) vertices of the registered nominal, mm.  F : (f, 3) triangles.
    dev : (n,) signed deviation, mm; NaN = unscored (grey).
    lower, upper : scalar or (n,) per-vertex band, mm (the governing zone's band; may be
        asymmetric, ``lower <= 0 <= upper``).
    regions : out-of-tolerance regions (:class:`qifreport.metrology.acceptance.criteria.Region`:
        ``vertices``, ``centroid``), numbered 1, 2, ... in list order; outlined in every view and
        returned as label anchors (:attr:`RenderedView.labels`) where visible.
    size : picture size ``(width, height)`` in pixels, one for all views or one per view
        (extra sizes are ignored when fewer views are chosen).
    views : :class:`ViewSpec` list, or the number of views to choose, or None: up to three
        chosen by :func:`choose_views`.
    scale : colour-scale limit, mm (default :func:`color_scale`).
    backend : ``"vtk"``, ``"matplotlib"`` or None (VTK, falling back to matplotlib with a
        logged warning when VTK cannot render).
    margin : empty border around the part, fraction of the picture size: one number, or
        ``(left, right, top, bottom)``, or one such tuple per view.
    markers : ``(name, (x, y, z) mm)`` of the clamps to mark (:attr:`RenderedView.markers`).
    points : ``(name, (x, y, z) mm)`` of points on the surface to locate in every view
        (:attr:`RenderedView.points`), e.g. the worst point of each region.

    Returns
    -------
    list of :class:`RenderedView`, in the order of ``views``.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    dev = np.asarray(dev, dtype=np.float64)
    if dev.shape != (len(V),):
        raise ValueError(f"dev must have shape ({len(V)},), got {dev.shape}")
    regions = list(regions)
    if views is None or isinstance(views, int):
        views = choose_views(V, F, dev, regions, n_views=3 if views is None else views)
    views = list(views)
    sizes = [tuple(size)] * len(views) if np.ndim(size) == 1 else [tuple(s) for s in size]
    if len(sizes) < len(views):
        raise ValueError(f"{len(sizes)} sizes for {len(views)} views")
    sizes = sizes[: len(views)]
    if scale is None:
        scale = color_scale(dev, lower, upper)
    rgb = (deviation_colors(dev, lower, upper, scale) * 255 + 0.5).astype(np.uint8)
    outline = band_outline(V, F, dev, lower, upper)
    margins = _margins(margin, len(views))
    projs = [
        _projection(V, v, w, h, tuple(mg))
        for v, (w, h), mg in zip(views, sizes, margins, strict=True)
    ]

    if backend not in (None, "vtk", "matplotlib"):
        raise ValueError(f"unknown backend {backend!r}")
    images = depths = None
    used = "vtk"
    if backend in (None, "vtk"):
        try:
            images, depths = _render_vtk(V, F, rgb, outline, projs)
        except Exception as exc:  # no VTK, no EGL, no OpenGL: draw with matplotlib
            if backend == "vtk":
                raise
            log.warning(
                "VTK offscreen rendering failed (%s: %s); drawing the deviation map "
                "with matplotlib instead",
                type(exc).__name__,
                exc,
            )
    if images is None:
        used = "matplotlib"
        images, depths = _render_mpl(V, F, rgb, outline, projs)

    out = []
    for view, pj, img, zb in zip(views, projs, images, depths, strict=True):
        axes = np.array([[pj.r[i], pj.u[i]] for i in range(3)])
        seen = _Visibility(V, pj, zb)
        out.append(
            RenderedView(
                image=img,
                name=view.name,
                direction=pj.d.copy(),
                up=pj.u.copy(),
                labels=_labels(V, regions, seen),
                axes=axes,
                mm_per_px=1.0 / pj.k,
                backend=used,
                markers=_markers(V, markers, pj, zb),
                points=_points(points, seen),
            )
        )
    return out


def _markers(V: np.ndarray, markers, pj: _Projection, zbuf: np.ndarray) -> list[Marker]:
    """The clamps inside a view, each visible when no surface is nearer the camera at its
    pixel (beyond a tolerance of two pixels or 1 % of the part)."""
    if not len(markers):
        return []
    h, w = zbuf.shape
    X = np.array([np.asarray(p, dtype=np.float64) for _, p in markers]).reshape(-1, 3)
    px = pj.pixels(X)
    tol = max(2.0 / pj.k, 1e-2 * float(np.ptp(V, axis=0).max()))
    out = []
    for (name, _), q, d in zip(markers, px, pj.distance(X), strict=True):
        if not (0 <= q[0] < w and 0 <= q[1] < h):
            continue
        ix, iy = int(round(q[0])), int(round(q[1]))
        near = zbuf[max(iy - 1, 0) : iy + 2, max(ix - 1, 0) : ix + 2]
        front = float(np.min(near)) if near.size else math.inf
        out.append(Marker(str(name), float(q[0]), float(q[1]), bool(d <= front + tol)))
    return out


class _Visibility:
    """Which points of the surface a view shows, from its distance buffer.

    ``zbuf`` (h, w) is the distance (mm, :meth:`_Projection.distance`) of the nearest surface
    at each pixel (inf on background). A point is seen when it falls inside the picture and
    is no farther than the nearest surface in its 3x3 pixel neighbourhood (the farthest of
    the nine: grazing surfaces) plus a tolerance of two pixels or 1e-3 of the part's
    extent, whichever is larger.
    """

    def __init__(self, V: np.ndarray, pj: _Projection, zbuf: np.ndarray):
        h, w = zbuf.shape
        z = np.where(np.isfinite(zbuf), zbuf, -np.inf)
        pad = np.pad(z, 1, mode="edge")
        zmax = np.max([pad[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)
        self.zmax = np.where(np.isfinite(zmax), zmax, np.inf)
        self.tol = max(2.0 / pj.k, 1e-3 * float(np.ptp(V, axis=0).max()))
        self.pj = pj

    def __call__(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (m, 2) of the points X (m, 3) mm, whether each falls inside the picture
        and whether each is seen (both (m,) bool)."""
        h, w = self.zmax.shape
        px = self.pj.pixels(X)
        ix = np.clip(np.round(px[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.round(px[:, 1]).astype(int), 0, h - 1)
        inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        seen = inside & (self.pj.distance(X) <= self.zmax[iy, ix] + self.tol)
        return px, inside, seen


def _points(points, seen: _Visibility) -> list[Marker]:
    """The named points inside a view, with their pixels and whether the view shows them."""
    if not len(points):
        return []
    X = np.array([np.asarray(p, dtype=np.float64) for _, p in points]).reshape(-1, 3)
    px, inside, vis = seen(X)
    return [
        Marker(str(name), float(q[0]), float(q[1]), bool(v))
        for (name, _), q, i, v in zip(points, px, inside, vis, strict=True)
        if i
    ]


def _labels(V: np.ndarray, regions: list, seen: _Visibility) -> list[RegionLabel]:
    """Label anchors of the regions visible in a view (:class:`_Visibility`).

    The anchor is the visible vertex nearest to the visible vertices' mean, so it lies on
    the region.
    """
    labels = []
    for num, reg in enumerate(regions, start=1):
        idx = np.asarray(reg.vertices, dtype=np.int64)
        if len(idx) == 0:
            continue
        px, _, vis = seen(V[idx])
        if not vis.any():
            continue
        pv = px[vis]
        m = pv.mean(axis=0)
        j = int(np.argmin(((pv - m) ** 2).sum(axis=1)))
        ext = float(np.sqrt(((pv - pv[j]) ** 2).sum(axis=1)).max())
        labels.append(
            RegionLabel(
                number=num,
                x=float(pv[j, 0]),
                y=float(pv[j, 1]),
                visible_fraction=float(vis.mean()),
                extent=ext,
            )
        )
    return labels


def _render_vtk(V, F, rgb, outline, projs):
    """Render every view with VTK offscreen; returns (images, distance buffers)."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL factories)
    from vtkmodules.util.numpy_support import (
        numpy_to_vtk,
        numpy_to_vtkIdTypeArray,
        vtk_to_numpy,
    )
    from vtkmodules.vtkCommonCore import vtkFloatArray, vtkPoints, vtkUnsignedCharArray
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
    from vtkmodules.vtkRenderingCore import (
        vtkActor,
        vtkPolyDataMapper,
        vtkRenderer,
        vtkRenderWindow,
    )

    def polydata(points: np.ndarray, cells: np.ndarray, lines: bool) -> vtkPolyData:
        pd = vtkPolyData()
        pts = vtkPoints()
        pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
        pd.SetPoints(pts)
        ca = vtkCellArray()
        k = cells.shape[1]
        offsets = np.arange(0, k * len(cells) + 1, k, dtype=np.int64)
        ca.SetData(
            numpy_to_vtkIdTypeArray(offsets, deep=True),
            numpy_to_vtkIdTypeArray(np.ascontiguousarray(cells.ravel(), dtype=np.int64), deep=True),
        )
        if lines:
            pd.SetLines(ca)
        else:
            pd.SetPolys(ca)
        return pd

    surf = polydata(V, F, lines=False)
    colors = numpy_to_vtk(
        np.ascontiguousarray(rgb), deep=True, array_type=vtkUnsignedCharArray().GetDataType()
    )
    colors.SetName("rgb")
    surf.GetPointData().SetScalars(colors)
    mapper = vtkPolyDataMapper()
    mapper.SetInputData(surf)
    mapper.SetColorModeToDirectScalars()
    mapper.SetScalarModeToUsePointData()
    mapper.SetResolveCoincidentTopologyToPolygonOffset()
    mapper.SetRelativeCoincidentTopologyPolygonOffsetParameters(1.5, 1.5)
    actor = vtkActor()
    actor.SetMapper(mapper)
    prop = actor.GetProperty()
    prop.SetAmbient(0.35)
    prop.SetDiffuse(0.65)
    prop.SetSpecular(0.0)
    prop.SetInterpolationToGouraud()

    ren = vtkRenderer()
    ren.SetBackground(1.0, 1.0, 1.0)
    ren.AddActor(actor)
    if len(outline):
        segs = outline.reshape(-1, 3)
        lines = polydata(segs, np.arange(len(segs)).reshape(-1, 2), lines=True)
        lmapper = vtkPolyDataMapper()
        lmapper.SetInputData(lines)
        lmapper.ScalarVisibilityOff()
        lactor = vtkActor()
        lactor.SetMapper(lmapper)
        lp = lactor.GetProperty()
        lp.SetColor(*OUTLINE)
        lp.SetLighting(False)
        lp.SetLineWidth(max(1.5, max(pj.w for pj in projs) / 500.0))
        ren.AddActor(lactor)

    win = vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(8)
    win.AddRenderer(ren)
    cam = ren.GetActiveCamera()
    cam.ParallelProjectionOn()
    diag = float(np.linalg.norm(np.ptp(V, axis=0))) or 1.0
    images, depths = [], []
    try:
        for pj in projs:
            win.SetSize(pj.w, pj.h)
            focal = pj.cx * pj.r + pj.cy * pj.u + pj.depth_max * pj.d
            pos = focal + 2.0 * diag * pj.d
            cam.SetFocalPoint(*focal)
            cam.SetPosition(*pos)
            cam.SetViewUp(*pj.u)
            cam.SetParallelScale(0.5 * pj.h / pj.k)
            near, far = 0.5 * diag, 4.0 * diag
            cam.SetClippingRange(near, far)
            win.Render()
            pix = vtkUnsignedCharArray()
            win.GetPixelData(0, 0, pj.w - 1, pj.h - 1, 0, pix, 0)
            img = vtk_to_numpy(pix).reshape(pj.h, pj.w, -1)[::-1, :, :3].copy()
            zb = vtkFloatArray()
            win.GetZbufferData(0, 0, pj.w - 1, pj.h - 1, zb)
            z = vtk_to_numpy(zb).reshape(pj.h, pj.w)[::-1].astype(np.float64)
            # window depth (parallel projection: linear) -> mm in front of the nearest point
            dist_cam = near + z * (far - near)
            zmm = np.where(z < 1.0, dist_cam - 2.0 * diag, np.inf)
            images.append(img)
            depths.append(zmm)
    finally:
        win.Finalize()
    return images, depths


def _render_mpl(V, F, rgb, outline, projs):
    """Fallback: painter's algorithm with matplotlib Agg; returns (images, distance buffers)."""
    # the Agg canvas directly (no pyplot): the process's matplotlib backend is left alone
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    fn, _ = _face_normals_areas(V, F)
    base = rgb[F].astype(float).mean(axis=1) / 255.0
    images, depths = [], []
    for pj in projs:
        px = pj.pixels(V)
        dist = pj.distance(V)
        shade = 0.35 + 0.65 * np.abs(fn @ pj.d)
        fc = np.clip(base * shade[:, None], 0, 1)
        order = np.argsort(-dist[F].mean(axis=1), kind="stable")  # far first
        fig = Figure(figsize=(pj.w / 100.0, pj.h / 100.0), dpi=100)
        canvas = FigureCanvasAgg(fig)
        ax = fig.add_axes((0, 0, 1, 1))
        ax.set_xlim(0, pj.w)
        ax.set_ylim(pj.h, 0)
        ax.axis("off")
        pc = PolyCollection(
            px[F[order]], facecolors=fc[order], edgecolors="none", antialiased=False
        )
        ax.add_collection(pc)
        # vertex z-buffer with cells of about one projected edge, depth tolerance one edge
        e = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)
        edge = float(np.median(e)) if len(e) else 1.0
        cell = int(np.clip(round(edge * pj.k), 3, 24))
        zbuf = _vertex_zbuffer(px, dist, pj.w, pj.h, cell=cell)
        if len(outline):
            a, b = outline[:, 0], outline[:, 1]
            pa, pb = pj.pixels(a), pj.pixels(b)
            mid = 0.5 * (a + b)
            pm = pj.pixels(mid)
            ix = np.clip(np.round(pm[:, 0]).astype(int), 0, pj.w - 1)
            iy = np.clip(np.round(pm[:, 1]).astype(int), 0, pj.h - 1)
            vis = pj.distance(mid) <= zbuf[iy, ix] + max(edge, 3.0 / pj.k)
            segs = np.stack([pa[vis], pb[vis]], axis=1)
            ax.add_collection(LineCollection(segs, colors=[OUTLINE], linewidths=1.2))
        canvas.draw()
        img = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
        images.append(img)
        depths.append(zbuf)
    return images, depths


def _vertex_zbuffer(px: np.ndarray, dist: np.ndarray, w: int, h: int, cell: int = 3) -> np.ndarray:
    """Approximate per-pixel nearest distance (mm) from the vertices alone: the nearest
    vertex in each ``cell`` x ``cell`` block; inf where no vertex projects."""
    gw, gh = (w + cell - 1) // cell, (h + cell - 1) // cell
    gx = np.clip((px[:, 0] // cell).astype(int), 0, gw - 1)
    gy = np.clip((px[:, 1] // cell).astype(int), 0, gh - 1)
    g = np.full((gh, gw), np.inf)
    np.minimum.at(g, (gy, gx), dist)
    return np.repeat(np.repeat(g, cell, axis=0), cell, axis=1)[:h, :w]
