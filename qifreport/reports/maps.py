"""The deviation maps of the inspection page and their colour bar.

The registered nominal from two or three automatically chosen directions
(:mod:`qifreport.reports.render`), green inside the band, red proud / blue sunk outside, grey
unscored, out-of-tolerance regions outlined and numbered as in the region table, and the
signed deviation called out at each numbered region's worst point and at a few points of
interest (:mod:`qifreport.reports.callouts`: a value beside the region's number, a leader
line to the point). Three views
are one large picture with the other two stacked on its right, or the three in a row,
whichever draws the part larger (:func:`map_boxes`); each has its axes and a scale bar. The
colour bar (mm, symmetric about 0) marks each distinct band.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from .callouts import MAX_PER_VIEW, Callout, LabelPlacer, leader_end
from .context import ReportContext
from .kit import (
    INK,
    MUTED,
    RULE,
    Box,
    draw_text,
    fit_text,
    fmt_band,
    join_names,
    text_width,
)
from .render import GREY, OUTLINE, RenderedView, deviation_colors

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

log = logging.getLogger(__name__)

__all__ = [
    "map_boxes",
    "layout_score",
    "map_margins",
    "colorbar_height",
    "draw_maps",
    "draw_colorbar",
]

# ------------------------------------------------------------------------------- layout


def map_boxes(ctx: ReportContext, area: Box) -> list[Box]:
    """The pictures inside ``area`` (a caption above each).

    Three views: one large picture with the other two stacked on its right, or the three
    in a row, whichever draws the part larger (the first view counting double); two
    views side by side.
    """
    n = len(ctx.views)
    gap, cap = 8.0, 11.0

    def row(k: int) -> list[Box]:
        w = (area.w - (k - 1) * gap) / k
        return [Box(area.x + i * (w + gap), area.y, w, area.h - cap) for i in range(k)]

    if n < 3:
        return row(max(n, 1))
    w_main = (area.w - gap) * 0.60
    w_side = area.w - gap - w_main
    h_side = (area.h - 2 * cap - gap) / 2
    xs = area.x + w_main + gap
    stack = [
        Box(area.x, area.y, w_main, area.h - cap),
        Box(xs, area.y + h_side + gap + cap, w_side, h_side),
        Box(xs, area.y, w_side, h_side),
    ]
    return max((stack, row(3)), key=lambda boxes: layout_score(ctx, boxes))


def layout_score(ctx: ReportContext, boxes: list[Box]) -> float:
    """Sum of the log drawing scales (pt per mm) of the views, the first counting double."""
    score = 0.0
    for k, (b, (sx, sy)) in enumerate(zip(boxes, ctx.spans, strict=False)):
        m = map_margins(b)
        pt_per_mm = min(b.w * (1 - m[0] - m[1]) / sx, b.h * (1 - m[2] - m[3]) / sy)
        score += (2.0 if k == 0 else 1.0) * math.log(max(pt_per_mm, 1e-9))
    return score


def map_margins(box: Box) -> tuple[float, float, float, float]:
    """Margins of a picture (fractions): room for the axes and scale bar at the bottom."""
    return (0.035, 0.035, 8.0 / box.h, 22.0 / box.h)


def colorbar_height(ctx: ReportContext) -> float:
    """Height of the colour bar block, points (a row per distinct band, at most three)."""
    rows = min(len(ctx.bands), 3)
    return 14.0 + 9.0 * rows + 16.0


# ------------------------------------------------------------------------------ drawing


def draw_maps(
    c: Canvas,
    boxes: list[Box],
    views: list[RenderedView],
    n_listed: int,
    calls: Sequence[Callout] = (),
) -> None:
    """The map pictures in ``boxes`` with their captions, axes, scale bars, the numbers of
    the first ``n_listed`` regions (the ones the region table lists) and the deviation
    ``calls`` (each in the first view that shows its point and has room for it; their keys
    are the names of the views' :attr:`~RenderedView.points`)."""
    from PIL import Image
    from reportlab.lib.utils import ImageReader

    done: set[str] = set()
    for k, (box, v) in enumerate(zip(boxes, views, strict=True)):
        img = ImageReader(Image.fromarray(v.image))
        c.drawImage(img, box.x, box.y, box.w, box.h)
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.5)
        c.rect(box.x, box.y, box.w, box.h, stroke=1, fill=0)
        x = box.x
        if k == 0:
            head = "Deviation map of the registered nominal" if box.w > 280 else "Deviation map"
            draw_text(c, x, box.top + 3, head, 8, True)
            x += text_width(head, 8, True) + 8
        draw_text(c, x, box.top + 3, f"{'ABC'[k]}: {v.name}", 7.5, True, MUTED)
        _draw_axes(c, box, v)
        avoid = [(box.x, box.y, box.x + 34.0, box.y + 26.0)]  # the axes
        if not v.name.startswith("oblique"):
            avoid.append(_draw_scale_bar(c, box, v))
        done |= _draw_labels(c, box, v, n_listed, calls, done)
        _draw_markers(c, box, v, avoid)


def _marker_extent(x: float, y: float, name: str) -> tuple[float, float, float, float]:
    """The rectangle ``(x0, y0, x1, y1)`` (points) a clamp's triangle at ``(x, y)`` and its
    ``name`` (empty: none) cover on the page (:func:`_draw_markers`)."""
    half = max(3.2, text_width(name, 5.5, True) / 2) if name else 3.2
    return x - half, y - (14.0 if name else 5.5), x + half, y


def _overlap(a: tuple, b: tuple) -> float:
    """The area two rectangles ``(x0, y0, x1, y1)`` share, points^2."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return max(w, 0.0) * max(h, 0.0)


def _name_spot(x: float, y: float, name: str, box: Box, taken: list[tuple]) -> tuple:
    """Where a clamp's ``name`` goes beside its triangle at ``(x, y)``: below, above, right
    or left, the first spot free of the rectangles ``taken`` and inside ``box`` (else the
    one overlapping least); ``(text x, text y, rectangle)``."""
    w = text_width(name, 5.5, True)
    spots = [
        (x, y - 12.0),  # below the triangle
        (x, y + 2.0),  # above its tip
        (x + 4.5 + w / 2, y - 5.0),  # right
        (x - 4.5 - w / 2, y - 5.0),  # left
    ]
    best, best_cost = None, math.inf
    for tx, ty in spots:
        rect = (tx - w / 2 - 0.5, ty - 1.5, tx + w / 2 + 0.5, ty + 5.0)
        inside = box.x <= rect[0] and rect[2] <= box.x + box.w and box.y <= rect[1]
        inside &= rect[3] <= box.top
        cost = sum(_overlap(rect, t) for t in taken) + (0.0 if inside else 1e3)
        if cost < best_cost:
            best, best_cost = (tx, ty, rect), cost
        if cost == 0.0:
            break
    return best


def _draw_markers(c: Canvas, box: Box, v: RenderedView, avoid: list[tuple]) -> None:
    """The clamps (RPS points): a triangle with the clamp's name (and force); hollow, grey
    and unnamed where the part hides it (a clamp on the far side: another view names it).
    The names are placed off each other, the triangles and the rectangles ``avoid`` (the
    scale bar, the axes)."""
    h_px, w_px = v.image.shape[:2]
    sx, sy = box.w / w_px, box.h / h_px
    at = [(box.x + m.x * sx, box.top - m.y * sy) for m in v.markers]
    taken = list(avoid) + [(x - 3.2, y - 5.5, x + 3.2, y) for x, y in at]
    for m, (x, y) in zip(v.markers, at, strict=True):
        colour = INK if m.visible else MUTED
        c.setStrokeColorRGB(*colour)
        c.setFillColorRGB(*colour)
        c.setLineWidth(0.7)
        p = c.beginPath()
        p.moveTo(x, y)
        p.lineTo(x - 3.2, y - 5.5)
        p.lineTo(x + 3.2, y - 5.5)
        p.close()
        c.drawPath(p, stroke=1, fill=1 if m.visible else 0)
        if m.visible:
            tx, ty, rect = _name_spot(x, y, m.name, box, taken)
            draw_text(c, tx, ty, m.name, 5.5, True, colour, "c")
            taken.append(rect)


def _draw_axes(c: Canvas, box: Box, v: RenderedView) -> None:
    ox, oy, L = box.x + 12, box.y + 9, 9.0
    c.setLineWidth(0.7)
    c.setStrokeColorRGB(*INK)
    for i, name in enumerate("xyz"):
        dx, dy = v.axes[i]
        n = math.hypot(dx, dy)
        if n < 0.2:  # along the line of sight: the view's name says which way
            continue
        c.line(ox, oy, ox + L * dx, oy + L * dy)
        draw_text(
            c, ox + (L + 4) * dx / max(n, 1e-9) * n - 2, oy + (L + 4) * dy - 2, name, 6.0, True
        )


def _draw_scale_bar(c: Canvas, box: Box, v: RenderedView) -> tuple:
    """The scale bar at the bottom right of ``box``; returns the rectangle it covers."""
    h_px, w_px = v.image.shape[:2]
    mm_per_pt = v.mm_per_px * w_px / box.w
    target = 0.22 * box.w * mm_per_pt
    e = 10 ** math.floor(math.log10(target))
    length = max(m * e for m in (1, 2, 5) if m * e <= target)
    Lp = length / mm_per_pt
    x1, y1 = box.x + box.w - 8, box.y + 8
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(1.0)
    c.line(x1 - Lp, y1, x1, y1)
    c.line(x1 - Lp, y1 - 2, x1 - Lp, y1 + 2)
    c.line(x1, y1 - 2, x1, y1 + 2)
    draw_text(c, x1 - Lp / 2, y1 + 3, f"{length:g} mm", 6.0, False, INK, "c")
    return (x1 - Lp - 1.0, y1 - 3.0, x1 + 1.0, y1 + 9.5)


#: callout text: size (points) of the region numbers and of the values
_NUMBER_PT, _VALUE_PT = 6.3, 6.0


def _number_radius(number: int) -> float:
    """Radius of a region number's circle, points."""
    return 5.2 if number < 10 else 6.2


def _draw_labels(
    c: Canvas,
    box: Box,
    v: RenderedView,
    n_listed: int,
    calls: Sequence[Callout],
    done: set[str],
) -> set[str]:
    """Region numbers and deviation callouts of one view, each beside its point with a
    leader line, never over the region it names, another label or a named point.

    A region whose worst point this view shows (and is not called out in an earlier view)
    gets its value after its number, the leader to the worst point; other regions their
    number alone, the leader to the region's middle. Then the points of interest the view
    shows, as long as fewer than :data:`~qifreport.reports.callouts.MAX_PER_VIEW` values
    are on it.

    Returns
    -------
    set of str
        The keys of the callouts drawn here.
    """
    h_px, w_px = v.image.shape[:2]
    sx, sy = box.w / w_px, box.h / h_px

    def page(x: float, y: float) -> tuple[float, float]:
        return box.x + x * sx, box.top - y * sy

    seen = {p.name: page(p.x, p.y) for p in v.points if p.visible}
    todo = [cl for cl in calls if cl.key in seen and cl.key not in done]
    labels = sorted((lb for lb in v.labels if lb.number <= n_listed), key=lambda lb: lb.number)
    worst = {cl.region: cl for cl in todo if cl.region is not None}
    anchors = [page(lb.x, lb.y) for lb in labels] + [seen[cl.key] for cl in todo]
    placer = LabelPlacer(box, anchors)
    for m in v.markers:  # the clamps' triangles and names (drawn after the labels)
        placer.reserve(*_marker_extent(*page(m.x, m.y), m.name if m.visible else ""))
    drawn: set[str] = set()
    for lb in labels:
        mid = page(lb.x, lb.y)
        cl = worst.get(lb.number) if len(drawn) < MAX_PER_VIEW else None
        if cl is not None:
            at = seen[cl.key]
            w, h = _region_label_size(lb.number, cl)
            ext = math.dist(at, mid) + lb.extent * sx
            spot = placer.place(*at, w, h, ext)
            if spot is not None:
                _leader(c, at, spot, w, h)
                _draw_region_label(c, spot, w, lb.number, cl)
                drawn.add(cl.key)
                continue
        r = _number_radius(lb.number)
        spot = placer.place(*mid, 2 * r, 2 * r, lb.extent * sx)
        if spot is None:
            log.debug("no room for the label of region %d in view %s", lb.number, v.name)
            continue
        _leader(c, mid, spot, 2 * r, 2 * r, round_end=True)
        _draw_region_label(c, spot, 2 * r, lb.number, None)
    for cl in todo:
        if cl.region is not None or len(drawn) >= MAX_PER_VIEW:
            continue
        at = seen[cl.key]
        w, h = text_width(cl.text, _VALUE_PT) + 6.0, 9.0
        spot = placer.place(*at, w, h)
        if spot is None:
            log.debug("no room for the callout %r in view %s", cl.key, v.name)
            continue
        _leader(c, at, spot, w, h)
        _draw_value_label(c, spot, w, h, cl.text)
        drawn.add(cl.key)
    return drawn


def _region_label_size(number: int, cl: Callout) -> tuple[float, float]:
    """Width and height (points) of a region's number circle followed by its value."""
    r = _number_radius(number)
    return 2 * r + text_width(cl.text, _VALUE_PT, True) + 4.0, 2 * r


def _leader(
    c: Canvas,
    at: tuple[float, float],
    spot: tuple[float, float],
    w: float,
    h: float,
    round_end: bool = False,
) -> None:
    """The leader line from the point ``at`` to the edge of the ``w`` x ``h`` label centred
    at ``spot`` (to its circle's edge with ``round_end``), and a dot on the point."""
    ax, ay = at
    px, py = spot
    if round_end:
        d = max(math.hypot(px - ax, py - ay), 1e-9)
        ex, ey = px - (px - ax) * (w / 2) / d, py - (py - ay) * (w / 2) / d
    else:
        ex, ey = leader_end(ax, ay, px, py, w, h)
    c.setStrokeColorRGB(*INK)
    c.setFillColorRGB(*INK)
    c.setLineWidth(0.6)
    c.line(ax, ay, ex, ey)
    c.circle(ax, ay, 1.0, stroke=0, fill=1)


def _draw_region_label(
    c: Canvas, spot: tuple[float, float], w: float, number: int, cl: Callout | None
) -> None:
    """A region's number in its circle, its worst value after it in a rounded box when
    ``cl`` is given; ``spot`` is the centre of the whole label, ``w`` its width."""
    r = _number_radius(number)
    x0, cy = spot[0] - w / 2, spot[1]
    c.setStrokeColorRGB(*INK)
    c.setFillColorRGB(1, 1, 1)
    c.setLineWidth(0.7)
    if cl is not None:
        c.roundRect(x0, cy - r, w, 2 * r, r, stroke=1, fill=1)
        draw_text(c, x0 + 2 * r + 1.5, cy - 2.1, cl.text, _VALUE_PT, True, INK)
        c.setFillColorRGB(1, 1, 1)
    c.circle(x0 + r, cy, r, stroke=1, fill=1)
    draw_text(c, x0 + r, cy - 2.3, str(number), _NUMBER_PT, True, INK, "c")


def _draw_value_label(c: Canvas, spot: tuple[float, float], w: float, h: float, text: str) -> None:
    """A point of interest's value (with its tag) in a rounded box centred at ``spot``."""
    c.setStrokeColorRGB(*INK)
    c.setFillColorRGB(1, 1, 1)
    c.setLineWidth(0.5)
    c.roundRect(spot[0] - w / 2, spot[1] - h / 2, w, h, 2.0, stroke=1, fill=1)
    draw_text(c, spot[0], spot[1] - 2.1, text, _VALUE_PT, False, INK, "c")


def draw_colorbar(c: Canvas, ctx: ReportContext, box: Box) -> None:
    """The colour bar in ``box``: one row per distinct band (at most three), the ticks and the
    legend of the map's marks."""
    S = ctx.scale
    bands = ctx.bands[:3]
    label_w = 118.0
    legend_w = 150.0
    x0 = box.x + label_w
    bw = box.w - label_w - legend_w - 12
    yy = box.top - 12
    draw_text(c, box.x, yy + 2, "Colour scale: signed deviation, mm", 7.0, True)

    def xpos(v: float) -> float:
        return x0 + (v + S) / (2 * S) * bw

    for lo, hi, keys in bands:
        yy = _draw_band_row(c, S, (lo, hi), keys, yy, x0, bw, label_w, xpos)
    if len(ctx.bands) > 3:
        draw_text(
            c,
            x0 - 4,
            yy - 17,
            f"+ {len(ctx.bands) - 3} more bands (tolerances)",
            6.2,
            False,
            MUTED,
            "r",
        )
    _draw_colorbar_ticks(c, S, bands, yy, xpos)
    draw_text(c, x0, yy - 17, "\u2190 sunk (material below nominal)", 6.2, False, MUTED)
    draw_text(c, x0 + bw, yy - 17, "proud (material above nominal) \u2192", 6.2, False, MUTED, "r")
    _draw_mark_legend(c, box.x + box.w - legend_w, box.top - 20)


def _draw_band_row(
    c: Canvas,
    S: float,
    band: tuple[float, float],
    keys: Sequence[str],
    yy: float,
    x0: float,
    bw: float,
    label_w: float,
    xpos: Callable[[float], float],
) -> float:
    """One band's row of the colour bar below ``yy`` (its colours over -S..S mm, its limits,
    its tolerances named on the left); returns the row's bottom."""
    lo, hi = band
    row_h = 9.0
    xs = np.linspace(-S, S, 241)
    mids = 0.5 * (xs[1:] + xs[:-1])
    y = yy - row_h
    cols = deviation_colors(mids, lo, hi, S)
    start = 0
    for i in range(1, len(mids) + 1):
        if i == len(mids) or not np.allclose(cols[i], cols[start], atol=1e-3):
            c.setFillColorRGB(*cols[start])
            c.rect(
                xpos(xs[start]),
                y + 1,
                xpos(xs[i]) - xpos(xs[start]) + 0.3,
                row_h - 2,
                stroke=0,
                fill=1,
            )
            start = i
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.8)
    for v in (lo, hi):
        c.line(xpos(v), y, xpos(v), y + row_h)
    c.setLineWidth(0.4)
    c.rect(x0, y + 1, bw, row_h - 2, stroke=1, fill=0)
    draw_text(
        c,
        x0 - 4,
        y + 2.4,
        fit_text(f"{join_names(keys, 3)} [{fmt_band(lo)}, {fmt_band(hi)}]", label_w - 6, 6.5),
        6.5,
        False,
        INK,
        "r",
    )
    return y


def _draw_colorbar_ticks(
    c: Canvas, S: float, bands: list, yy: float, xpos: Callable[[float], float]
) -> None:
    """The colour bar's ticks below ``yy``: the scale ends, 0, the band limits, then even
    steps, each where its label does not collide with one drawn before."""
    ticks: list[tuple[float, str, int]] = [
        (-S, f"\u2264{fmt_band(-S)}", 0),
        (S, f"\u2265{fmt_band(S)}", 0),
        (0.0, "0", 1),
    ]
    for lo, hi, _ in bands:
        ticks += [(lo, fmt_band(lo), 2), (hi, fmt_band(hi), 2)]
    for v in np.linspace(-S, S, 9)[1:-1]:
        ticks.append((float(v), fmt_band(float(v)), 3))
    used: list[tuple[float, float]] = []
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.5)
    for v, s, _ in sorted(ticks, key=lambda t: t[2]):
        x = xpos(v)
        w = text_width(s, 6.2)
        lo_x, hi_x = x - w / 2 - 4, x + w / 2 + 4
        if any(not (hi_x < a or lo_x > b) for a, b in used):
            continue
        used.append((lo_x, hi_x))
        c.line(x, yy, x, yy - 2.5)
        draw_text(c, x, yy - 9, s, 6.2, False, INK, "c")


def _draw_mark_legend(c: Canvas, lx: float, ly: float) -> None:
    """The legend of the map's marks from (``lx``, ``ly``) down: unscanned grey, the band
    edge, a region's number and worst deviation."""
    c.setFillColorRGB(*GREY)
    c.rect(lx, ly, 10, 6, stroke=0, fill=1)
    draw_text(c, lx + 14, ly + 0.8, "not scanned (unscored)", 6.5)
    ly -= 10
    c.setStrokeColorRGB(*OUTLINE)
    c.setLineWidth(1.0)
    c.line(lx, ly + 3, lx + 10, ly + 3)
    draw_text(c, lx + 14, ly + 0.8, "band edge (region outline)", 6.5)
    ly -= 11
    c.setFillColorRGB(1, 1, 1)
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.7)
    c.roundRect(lx, ly - 1.6, 25.0, 9.2, 4.6, stroke=1, fill=1)
    draw_text(c, lx + 10.8, ly + 0.9, "dev", 5.2, True, INK)
    c.setFillColorRGB(1, 1, 1)
    c.circle(lx + 4.6, ly + 3, 4.6, stroke=1, fill=1)
    draw_text(c, lx + 4.6, ly + 0.9, "1", 5.8, True, INK, "c")
    draw_text(c, lx + 29, ly + 0.8, "region no., worst deviation (mm)", 6.5)
