"""The trend page's pass-rate chart: the cumulative (and, for long batches, rolling) pass
rate against the scans' sequence, the scans that did not pass marked along the bottom, and
its legend."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..charts import ChartGeometry, draw_frame, draw_marker, draw_polyline, draw_y_title
from ..kit import FAIL_BG, INK, MUTED, RULE, UNSURE_BG, Box, draw_text, fit_text, text_width
from .colors import ERROR_COLOR, ROLL_COLOR
from .data import TrendData
from .layout import ERROR_STRIP

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = ["draw_pass_rate"]

#: grid step of the pass-rate axis, %, by its lowest value
RATE_STEPS = {0.0: 25.0, 50.0: 10.0, 80.0: 5.0, 90.0: 2.0}


def draw_pass_rate(c: Canvas, data: TrendData, cell: Box, geo: ChartGeometry) -> None:
    """The pass-rate chart in ``cell`` (its plot and scale ``geo``)."""
    head = "Pass rate by scan"
    draw_text(c, cell.x, cell.top - 8, head, 8, True)
    x = cell.x + text_width(head, 8, True) + 6
    draw_text(
        c,
        x,
        cell.top - 8,
        fit_text("(% PASS of the scans with a verdict)", cell.x + cell.w - x, 6.4),
        6.4,
        False,
        MUTED,
    )
    cum, roll, window = data.rates()
    _draw_rate_axis(c, cell, geo)
    _draw_rate_curves(c, data, geo, cum, roll)
    _draw_not_passed(c, data, geo)
    last = cum[np.isfinite(cum)]
    pa = geo.plot
    if len(last):
        draw_text(
            c, pa.x + pa.w + 3, float(geo.y(last[-1])) - 2.2, f"{last[-1]:.1f}", 6.0, True, INK
        )
    draw_frame(c, geo, data.seq_label)
    _draw_rate_legend(c, cell, geo, window)


def _draw_rate_axis(c: Canvas, cell: Box, geo: ChartGeometry) -> None:
    """Grid and value axis, %, from the axis' lowest value to 100."""
    pa = geo.plot
    step = RATE_STEPS.get(geo.bottom, 1.0)
    for v in np.arange(geo.bottom, 100.0 + 1e-9, step):
        y = float(geo.y(v))
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.3)
        if v > geo.bottom:
            c.line(pa.x, y, pa.x + pa.w, y)
        draw_text(c, pa.x - 3, y - 2.2, f"{v:g}", 6.0, False, MUTED, "r")
    c.setLineWidth(0.5)
    c.line(pa.x, geo.y_low, pa.x + pa.w, geo.y_low)
    draw_y_title(c, cell.x + 5, pa, "pass rate, %")


def _draw_rate_curves(
    c: Canvas,
    data: TrendData,
    geo: ChartGeometry,
    cum: np.ndarray,
    roll: np.ndarray | None,
) -> None:
    """The cumulative and rolling pass rates, shape (n,) each, % (with dots for few
    scans)."""
    xs = geo.x(data.pos)
    for vals, color, width in ((cum, INK, 1.0), (roll, ROLL_COLOR, 0.8)):
        if vals is None:
            continue
        ok = np.isfinite(vals)
        ys = geo.y(np.where(ok, vals, geo.bottom))
        c.setStrokeColorRGB(*color)
        c.setLineWidth(width)
        draw_polyline(c, xs, ys, ok)
        if data.n <= 40:  # few scans: the values as dots
            c.setFillColorRGB(*color)
            for i in np.flatnonzero(ok):
                c.circle(float(xs[i]), float(ys[i]), 1.1, stroke=0, fill=1)


def _draw_not_passed(c: Canvas, data: TrendData, geo: ChartGeometry) -> None:
    """The scans that did not pass, marked along the bottom."""
    pa = geo.plot
    xs = geo.x(data.pos)
    ym = pa.y + ERROR_STRIP / 2
    weight = float(np.clip(0.6 * pa.w / max(data.n, 1), 0.3, 1.0))  # dense: thin
    for name, kind, col in (
        ("NOT ESTABLISHED", "tick", UNSURE_BG),
        ("FAIL", "tick", FAIL_BG),
        ("ERROR", "cross", ERROR_COLOR),
    ):
        for i in np.flatnonzero(data.verdict == name):
            draw_marker(c, kind, float(xs[i]), ym, 2.6 if kind == "tick" else 1.6, col, weight)


def _draw_rate_legend(c: Canvas, cell: Box, geo: ChartGeometry, window: int) -> None:
    """The legend under the ticks (the rolling rate's when ``window`` is not 0)."""
    y = cell.y + 1.5
    x = geo.plot.x
    items = [("line", "cumulative", INK)]
    if window:
        items.append(("line", f"rolling, {window} scans", ROLL_COLOR))
    items += [
        ("tick", "FAIL", FAIL_BG),
        ("tick", "not established", UNSURE_BG),
        ("cross", "error", ERROR_COLOR),
    ]
    for kind, label, col in items:
        if kind == "line":
            c.setStrokeColorRGB(*col)
            c.setLineWidth(1.0)
            c.line(x, y + 2.2, x + 10, y + 2.2)
            x += 13
        else:
            draw_marker(c, kind, x + 2, y + 2.2, 2.4 if kind == "tick" else 1.6, col)
            x += 6.5
        draw_text(c, x, y, label, 6.0)
        x += text_width(label, 6.0) + 7
