"""Where the trend page puts everything: the header, the legend, the grid of run charts
with their value axes, the pass-rate chart beside the table of scans that did not pass, and
the footer (points, origin bottom-left)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..charts import ChartGeometry, nice_step
from ..kit import Box, ReportPage
from .data import TrendCharacteristic, TrendData

__all__ = [
    "ERROR_STRIP",
    "MAX_CHARTS",
    "TrendLayout",
    "chart_span",
    "chart_top",
    "choose_charts",
    "plan_layout",
    "rate_bottom",
]

#: run charts on the page at most; the rest are named (smallest margin drawn first)
MAX_CHARTS = 6
#: height of the strip below zero that holds the error marks, points
ERROR_STRIP = 7.0
#: vertical gap between blocks, and the heights of the header, legend, bottom row (pass
#: rate and failures) and footer, points
GAP = 8.0
HEADER_H = 74.0
LEGEND_H = 12.0
BOTTOM_H = 122.0
FOOTER_H = 36.0
#: run chart: title and statistics lines above the frame, tick labels below, y labels on
#: the left, tolerance and mean labels on the right (points)
CHART_TOP, CHART_BOTTOM, CHART_LEFT, CHART_RIGHT = 21.0, 11.0, 30.0, 30.0
#: tallest run chart (a lone characteristic does not fill the page)
CHART_MAX_H = 300.0
#: gaps between the run charts' columns and rows, points
COL_GAP, ROW_GAP = 14.0, 6.0


@dataclass
class TrendLayout:
    """Where :func:`~qifreport.reports.trend.write_trend_pdf` puts everything (points,
    origin bottom-left).

    Attributes
    ----------
    page : ``"A4"`` or ``"LETTER"``.  width, height : page size, points.
    charts : the run charts drawn, in page order (row by row).
    omitted : keys of the characteristics not drawn (no room), in the caller's order.
    pass_rate : the pass-rate chart.
    failures : the box of the table of scans that did not pass.
    """

    page: str
    width: float
    height: float
    charts: list[ChartGeometry]
    omitted: list[str]
    pass_rate: ChartGeometry
    failures: Box
    blocks: dict = field(default_factory=dict, repr=False)  # internal: what the drawer uses


def choose_charts(data: TrendData) -> tuple[list[TrendCharacteristic], list[str]]:
    """The characteristics drawn (caller's order) and the keys left out: beyond
    :data:`MAX_CHARTS`, those with the smallest margin are drawn."""
    chars = data.chars
    if len(chars) <= MAX_CHARTS:
        return chars, []
    order = sorted(range(len(chars)), key=lambda i: (data.stats[chars[i].key].margin, i))
    keep = sorted(order[:MAX_CHARTS])
    return (
        [chars[i] for i in keep],
        [chars[i].key for i in range(len(chars)) if i not in set(keep)],
    )


def chart_top(ch: TrendCharacteristic, values: np.ndarray) -> float:
    """Value at the top of a one-sided run chart (from 0), mm: a round number above the
    tolerance and the values, except for values far above the rest (drawn at the top
    edge)."""
    v = values
    v = v[np.isfinite(v)]
    tol = float(ch.tolerance_mm) if math.isfinite(ch.tolerance_mm) else 0.0
    typical = max(tol, float(np.quantile(v, 0.9)) if len(v) >= 10 else 0.0)
    hi = max(tol, float(v.max()) if len(v) else 0.0)
    if typical > 0 and hi > 3.0 * typical:
        hi = 1.5 * typical
    if hi <= 0:
        hi = 1.0
    step = nice_step(hi / 8.0)
    return step * math.ceil(1.06 * hi / step - 1e-9)


def chart_span(ch: TrendCharacteristic, values: np.ndarray) -> tuple[float, float]:
    """(bottom, top) of a dimension's run chart, in its unit: round numbers around its
    limits, nominal and values, except for values beyond the limits by more than the
    tolerance range (drawn at the edge)."""
    v = values
    v = v[np.isfinite(v)]
    refs = [x for _, x in ch.limits()]
    if ch.nominal is not None and math.isfinite(ch.nominal):
        refs.append(float(ch.nominal))
    width = max(refs) - min(refs) if len(refs) >= 2 else 0.0
    if width <= 0 and len(v):
        width = float(np.ptp(v)) or 0.01 * max(abs(float(v.mean())), 1.0)
    width = width if width > 0 else 1.0
    marks = refs + ([float(v.min()), float(v.max())] if len(v) else [])
    if not marks:  # nothing measured, no limit, no nominal
        return 0.0, 1.0
    lo, hi = min(marks), max(marks)
    if len(ch.limits()) == 2:  # far-off values do not squash the limits
        lo = max(lo, min(refs) - width)
        hi = min(hi, max(refs) + width)
    pad = 0.06 * (hi - lo) or 0.5 * width
    step = nice_step((hi - lo + 2 * pad) / 6.0)
    return step * math.floor((lo - pad) / step + 1e-9), step * math.ceil((hi + pad) / step - 1e-9)


def rate_bottom(data: TrendData) -> float:
    """Lowest % of the pass-rate axis: 0, or 50, 80, 90, 95 when every rate is above it
    (a batch passing at 99 % shows its dips)."""
    cum, roll, _ = data.rates()
    vals = np.concatenate([cum, roll if roll is not None else []])
    vals = vals[np.isfinite(vals)]
    low = float(vals.min()) if len(vals) else 0.0
    return max(b for b in (0.0, 50.0, 80.0, 90.0, 95.0) if b <= low - 1.0 or b == 0.0)


def plan_layout(data: TrendData, page: ReportPage) -> TrendLayout:
    """Where everything goes on ``page``: header, legend, the grid of run charts (one or two
    columns), the pass-rate chart beside the table of scans that did not pass, footer."""
    chosen, omitted = choose_charts(data)
    x0, top = page.M, page.H - page.MT
    blocks: dict = {}
    blocks["header"] = Box(x0, top - HEADER_H, page.CW, HEADER_H)
    y = top - HEADER_H - GAP
    blocks["legend"] = Box(x0, y - LEGEND_H, page.CW, LEGEND_H)
    y -= LEGEND_H + 4.0
    omitted_h = 10.0 if omitted else 0.0
    grid_h = y - omitted_h - GAP - BOTTOM_H - GAP - FOOTER_H - page.MT
    blocks["cells"], charts, y = _plan_grid(data, chosen, x0, y, page.CW, grid_h)
    if omitted:
        blocks["omitted"] = Box(x0, y - omitted_h, page.CW, omitted_h)
        y -= omitted_h
    y -= GAP
    bottom = Box(x0, y - BOTTOM_H, page.CW, BOTTOM_H)
    blocks["rate_cell"], pass_rate, failures = _plan_bottom(data, bottom)
    blocks["footer_top"] = bottom.y - GAP
    return TrendLayout(
        page=page.page,
        width=page.W,
        height=page.H,
        charts=charts,
        omitted=omitted,
        pass_rate=pass_rate,
        failures=failures,
        blocks=blocks,
    )


def _plan_grid(
    data: TrendData,
    chosen: list[TrendCharacteristic],
    x0: float,
    y: float,
    width: float,
    grid_h: float,
) -> tuple[list[Box], list[ChartGeometry], float]:
    """The run charts' cells and geometries, in one column (up to 3) or two, from ``y``
    down within ``grid_h`` points; returns them and the y below the grid."""
    k = len(chosen)
    cols = 1 if k <= 3 else 2
    rows = max(1, math.ceil(k / cols))
    cell_w = (width - (cols - 1) * COL_GAP) / cols
    cell_h = min((grid_h - (rows - 1) * ROW_GAP) / rows, CHART_MAX_H)
    charts: list[ChartGeometry] = []
    cells: list[Box] = []
    for i, ch in enumerate(chosen):
        r, q = divmod(i, cols)
        cell = Box(x0 + q * (cell_w + COL_GAP), y - (r + 1) * cell_h - r * ROW_GAP, cell_w, cell_h)
        plot = Box(
            cell.x + CHART_LEFT,
            cell.y + CHART_BOTTOM,
            cell.w - CHART_LEFT - CHART_RIGHT,
            cell.h - CHART_TOP - CHART_BOTTOM,
        )
        cells.append(cell)
        values = data.values[ch.key]
        if ch.two_sided:
            bottom, top = chart_span(ch, values)
            geo = ChartGeometry(ch.key, plot, data.n, plot.y + ERROR_STRIP, top, bottom)
        else:
            geo = ChartGeometry(ch.key, plot, data.n, plot.y + ERROR_STRIP, chart_top(ch, values))
        charts.append(geo)
    y -= rows * cell_h + (rows - 1) * ROW_GAP if k else 40.0
    return cells, charts, y


def _plan_bottom(data: TrendData, bottom: Box) -> tuple[Box, ChartGeometry, Box]:
    """The bottom row: the pass-rate chart's cell and geometry (left, 40 %), and the box of
    the table of scans that did not pass (right)."""
    rate_w = round(bottom.w * 0.40)
    rate_cell = Box(bottom.x, bottom.y, rate_w, bottom.h)
    rate_plot = Box(
        rate_cell.x + 30.0,
        rate_cell.y + 20.0,
        rate_cell.w - 30.0 - 30.0,
        rate_cell.h - 20.0 - 24.0,
    )
    failures = Box(bottom.x + rate_w + 16.0, bottom.y, bottom.w - rate_w - 16.0, bottom.h)
    low = rate_bottom(data)  # and headroom above 100 %, where a good batch runs
    pass_rate = ChartGeometry(
        "pass rate",
        rate_plot,
        data.n,
        rate_plot.y + ERROR_STRIP,
        100.0 + 0.05 * (100.0 - low),
        low,
    )
    return rate_cell, pass_rate, failures
