"""The run chart of one characteristic on the trend page: its title and line of
statistics, the value axis, the limit, nominal and mean lines, and each scan's point
coloured by its verdict."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from qifreport.metrology.spc import MIN_CAPABILITY_N, CharacteristicStats

from ..charts import (
    ChartGeometry,
    decimals,
    draw_frame,
    draw_marker,
    draw_polyline,
    draw_y_title,
    nice_step,
)
from ..kit import DASH, MUTED, RULE, Box, draw_text, fit_text, fmt_mm, text_width
from .colors import (
    BASIC_COLOR,
    ERROR_COLOR,
    JOIN_COLOR,
    MEAN_COLOR,
    NOMINAL_COLOR,
    POINT_COLORS,
    TOL_COLOR,
)
from .data import POINT_KINDS, TrendCharacteristic, TrendData
from .layout import ERROR_STRIP

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = ["draw_run_chart", "stats_line"]


def draw_run_chart(
    c: Canvas, data: TrendData, cell: Box, geo: ChartGeometry, ch: TrendCharacteristic
) -> None:
    """One characteristic's run chart in ``cell`` (its plot and scale ``geo``)."""
    st = data.stats[ch.key]
    # title and statistics
    title = f"{ch.key} \u2014 {ch.description}" if ch.description else ch.key
    draw_text(c, cell.x, cell.top - 7.5, fit_text(title, cell.w, 7.5, True), 7.5, True)
    line = stats_line(ch, st, cell.w)
    draw_text(c, cell.x, cell.top - 16.5, fit_text(line, cell.w, 6.6), 6.6, False, MUTED)
    _draw_value_axis(c, cell, geo, ch)
    _draw_reference_lines(c, geo, ch, st)
    _draw_points(c, data, geo, ch)
    draw_frame(c, geo, data.seq_label)


def _draw_value_axis(c: Canvas, cell: Box, geo: ChartGeometry, ch: TrendCharacteristic) -> None:
    """Grid and value axis (from 0 for a one-sided value, around the limits for a
    dimension), and the axis title."""
    pa = geo.plot
    step = nice_step((geo.top - geo.bottom) / 4.2)
    d = decimals(step)
    c.setLineWidth(0.3)
    for k in range(math.ceil(geo.bottom / step - 1e-9), math.floor(geo.top / step + 1e-9) + 1):
        v = k * step
        y = float(geo.y(v))
        c.setStrokeColorRGB(*RULE)
        if geo.bottom + 1e-9 < v < geo.top - 1e-9:
            c.line(pa.x, y, pa.x + pa.w, y)
        draw_text(c, pa.x - 3, y - 2.2, f"{v:.{d}f}", 6.0, False, MUTED, "r")
    c.setStrokeColorRGB(*RULE)
    c.setLineWidth(0.5)
    c.line(pa.x, geo.y_low, pa.x + pa.w, geo.y_low)  # the axis' bottom: 0 for a zone
    draw_y_title(c, cell.x + 5, pa, f"{ch.quantity}, {ch.unit}")


def _draw_reference_lines(
    c: Canvas, geo: ChartGeometry, ch: TrendCharacteristic, st: CharacteristicStats
) -> None:
    """The limits (the tolerance, or a dimension's LSL and USL), its nominal and the mean,
    labelled on the right where the labels do not collide."""
    pa = geo.plot
    right = pa.x + pa.w
    y_limits = []
    for label, x in ch.limits():
        if not geo.bottom <= x <= geo.top:
            continue
        y_lim = float(geo.y(x))
        y_limits.append(y_lim)
        _hline(c, pa.x, right, y_lim, TOL_COLOR, 1.1)
        draw_text(c, right + 3, y_lim + 1.2, label, 6.0, True, TOL_COLOR)
        draw_text(c, right + 3, y_lim - 5.6, fmt_mm(x), 6.0, False, TOL_COLOR)
    y_nominal = math.nan
    if ch.two_sided and ch.nominal is not None and geo.bottom < ch.nominal < geo.top:
        y_nominal = float(geo.y(ch.nominal))
        _hline(c, pa.x, right, y_nominal, NOMINAL_COLOR, 0.6, (0.8, 1.2))
    y_mean = math.nan
    if math.isfinite(st.mean):
        y_mean = float(geo.y(st.mean))
        _hline(c, pa.x, right, y_mean, MEAN_COLOR, 0.7, (2.5, 1.5))
        if all(not abs(y_mean - y) < 14.0 for y in y_limits) and y_mean < pa.top - 2:
            draw_text(c, right + 3, y_mean - 2.2, "mean", 6.0, False, MEAN_COLOR)
        else:
            y_mean = math.nan  # not labelled
    if math.isfinite(y_nominal) and all(not abs(y_nominal - y) < 10.0 for y in [*y_limits, y_mean]):
        draw_text(c, right + 3, y_nominal - 2.2, "nom", 6.0, False, NOMINAL_COLOR)


def _radius(data: TrendData, geo: ChartGeometry) -> float:
    """Radius of a point, points: smaller the more scans share the width."""
    return float(np.clip(0.32 * geo.plot.w / max(data.n, 1), 0.65, 2.3))


def _draw_points(c: Canvas, data: TrendData, geo: ChartGeometry, ch: TrendCharacteristic) -> None:
    """The joining line, each scan's point (off-scale ones as triangles at the edge) and
    the errored scans' crosses in the strip below the axis."""
    v = data.values[ch.key]
    ok = np.isfinite(v)
    xs, ys = geo.x(data.pos), geo.y(np.where(ok, v, geo.bottom))
    r = _radius(data, geo)
    # the joining line, broken where a scan has no value; not where the scans are
    # closer than a point (it would only grey the cloud of points)
    if geo.plot.w / max(data.n, 1) >= 1.0:
        c.setStrokeColorRGB(*JOIN_COLOR)
        c.setLineWidth(0.45 if r > 1.2 else 0.25)
        draw_polyline(c, xs, ys, ok)
    # the points: the characteristic's verdict; a value without one by the tolerance
    kind = data.point_kinds(ch)
    clipped = ok & (v > geo.top)
    below = ok & (v < geo.bottom) if ch.two_sided else np.zeros(len(v), dtype=bool)
    colors = {"BASIC": BASIC_COLOR, **POINT_COLORS}
    c.setStrokeColorRGB(1, 1, 1)
    c.setLineWidth(0.35)
    for name in POINT_KINDS:
        # the rare ones on top, and no smaller than a readable dot however many scans
        rr = r if name in ("PASS", "BASIC") else max(r, 1.5)
        c.setFillColorRGB(*colors[name])
        for i in np.flatnonzero(ok & (kind == name)):
            if clipped[i]:
                draw_marker(c, "tri", float(xs[i]), geo.plot.top - 1.2 * rr, 1.2 * rr, colors[name])
            elif below[i]:
                _down_triangle(c, float(xs[i]), geo.y_low + 1.2 * rr, 1.2 * rr, colors[name])
            else:
                c.circle(float(xs[i]), float(ys[i]), rr, stroke=int(rr >= 1.5), fill=1)
    # scans that errored: crosses in the strip below the axis
    err = np.flatnonzero(data.verdict == "ERROR")
    size = 1.6
    for i in err:
        draw_marker(c, "cross", float(xs[i]), geo.plot.y + ERROR_STRIP / 2, size, ERROR_COLOR)


def capability_text(st: CharacteristicStats, two_sided: bool) -> str:
    """The capability indices as the chart states them: Cpk (and a dimension's Cp) with
    the 95 % interval of Cpk from :data:`~qifreport.metrology.spc.MIN_CAPABILITY_N` values;
    "n too small" below."""
    if not math.isfinite(st.cpk):
        return f"Cp {DASH}   Cpk {DASH}" if two_sided else f"Cpk {DASH}"
    if not st.capable_n:
        return f"Cp, Cpk: n < {MIN_CAPABILITY_N}" if two_sided else f"Cpk: n < {MIN_CAPABILITY_N}"
    lo, hi = st.cpk_interval()
    cpk = f"Cpk {st.cpk:.2f} [{lo:.2f}, {hi:.2f}]"
    if not two_sided:
        return cpk
    cp = f"{st.cp:.2f}" if math.isfinite(st.cp) else DASH
    return f"Cp {cp}   {cpk}"


def stats_line(ch: TrendCharacteristic, st: CharacteristicStats, width: float) -> str:
    """The line of statistics above a run chart ``width`` points wide: a dimension's
    smallest and largest values are left out when the line would not fit."""
    sigma = fmt_mm(st.sigma)
    if not ch.two_sided:
        return (
            f"n {st.n}   mean {fmt_mm(st.mean)}   \u03c3 {sigma}   max {fmt_mm(st.max)} mm"
            f"   {capability_text(st, False)}   PASS {st.n_pass} of {st.n_judged}"
        )
    u = ch.unit
    head = f"n {st.n}   mean {fmt_mm(st.mean)}"
    extremes = f"min {fmt_mm(st.min)}   max {fmt_mm(st.max)}"
    if ch.limits():
        tail = f"{capability_text(st, True)}   PASS {st.n_pass} of {st.n_judged}"
        lines = [
            f"{head}   \u03c3 {sigma}   {extremes} {u}   {tail}",
            f"{head} {u}   \u03c3 {sigma}   {tail}",
        ]
    else:
        lines = [
            f"{head}   \u03c3 {sigma}   {extremes} {u}   basic: no limits, no verdict",
            f"{head} {u}   \u03c3 {sigma}   {extremes}   basic, no verdict",
        ]
    return next((x for x in lines if text_width(x, 6.6) <= width), lines[-1])


def _down_triangle(
    c: Canvas, x: float, y: float, size: float, color: tuple[float, float, float]
) -> None:
    """A triangle pointing down at (x, y): a value below the chart's scale."""
    c.setFillColorRGB(*color)
    p = c.beginPath()
    p.moveTo(x - size, y + size * 0.8)
    p.lineTo(x + size, y + size * 0.8)
    p.lineTo(x, y - size * 0.9)
    p.close()
    c.drawPath(p, stroke=0, fill=1)


def _hline(
    c: Canvas,
    x0: float,
    x1: float,
    y: float,
    rgb: tuple[float, float, float],
    width: float,
    dash: tuple[float, float] | None = None,
) -> None:
    """A horizontal line across a chart from ``x0`` to ``x1`` at ``y`` (points)."""
    c.setStrokeColorRGB(*rgb)
    c.setLineWidth(width)
    if dash is not None:
        c.setDash(*dash)
    c.line(x0, y, x1, y)
    if dash is not None:
        c.setDash()
