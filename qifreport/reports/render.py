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
projected triangles) and a warning is logged. The views are chosen and projected in
:mod:`qifreport.reports.views`, the two backends are in :mod:`qifreport.reports.raster`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .raster import Scene, render_mpl, render_vtk
from .views import (
    Projection,
    ViewSpec,
    choose_views,
    project_view,
    view_margins,
)

__all__ = [
    "GREEN_PROUD",
    "GREEN_SUNK",
    "GREEN_ZERO",
    "GREY",
    "OUTLINE",
    "band_outline",
    "color_scale",
    "deviation_colors",
    "nice_ceil",
    "RegionLabel",
    "render_views",
    "RenderedView",
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


# ----------------------------------------------------------------------- band outline


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
    margins = view_margins(margin, len(views))
    projs = [
        project_view(V, v, w, h, tuple(mg))
        for v, (w, h), mg in zip(views, sizes, margins, strict=True)
    ]

    images, depths, used = _rasterize(V, F, rgb, outline, projs, backend)
    return [
        _rendered(view, pj, img, zb, used, V, regions, markers, points)
        for view, pj, img, zb in zip(views, projs, images, depths, strict=True)
    ]


def _rendered(
    view: ViewSpec,
    pj: Projection,
    img: np.ndarray,
    zb: np.ndarray,
    backend: str,
    V: np.ndarray,
    regions: list,
    markers: Sequence,
    points: Sequence,
) -> RenderedView:
    """One view's picture ``img`` with its region anchors, clamps and named points, seen
    through its distance buffer ``zb``."""
    axes = np.array([[pj.r[i], pj.u[i]] for i in range(3)])
    seen = _Visibility(V, pj, zb)
    return RenderedView(
        image=img,
        name=view.name,
        direction=pj.d.copy(),
        up=pj.u.copy(),
        labels=_labels(V, regions, seen),
        axes=axes,
        mm_per_px=1.0 / pj.k,
        backend=backend,
        markers=_markers(V, markers, pj, zb),
        points=_points(points, seen),
    )


def _rasterize(
    V: np.ndarray,
    F: np.ndarray,
    rgb: np.ndarray,
    outline: np.ndarray,
    projs: list[Projection],
    backend: str | None,
) -> tuple[list[np.ndarray], list[np.ndarray], str]:
    """The pictures and distance buffers of every view, and the backend that drew them:
    VTK, or matplotlib when asked or when VTK cannot render (``backend`` None: with a
    logged warning)."""
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
        images, depths = render_mpl(Scene(V, F, rgb, outline, OUTLINE), projs)
    return images, depths, used


def _markers(V: np.ndarray, markers, pj: Projection, zbuf: np.ndarray) -> list[Marker]:
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

    ``zbuf`` (h, w) is the distance (mm, :meth:`.Projection.distance`) of the nearest
    surface at each pixel (inf on background). A point is seen when it falls inside the
    picture and is no farther than the nearest surface in its 3x3 pixel neighbourhood (the
    farthest of the nine: grazing surfaces) plus a tolerance of two pixels or 1e-3 of the
    part's extent, whichever is larger.
    """

    def __init__(self, V: np.ndarray, pj: Projection, zbuf: np.ndarray):
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
    """Render every view with VTK offscreen (:func:`~qifreport.reports.raster.render_vtk`);
    returns (images, distance buffers)."""
    return render_vtk(Scene(V, F, rgb, outline, OUTLINE), projs)
