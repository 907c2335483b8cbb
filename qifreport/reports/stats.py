"""The statistics of the signed deviation on the inspection page: the table and the histogram.

* **Statistics** -- the whole part at the vertices (area-weighted) and at the scan points
  (data-referenced) and, when there are two or three tolerances, each tolerance on its own
  faces: RMS, mean, extremes, percentiles of |dev|, fractions beyond the threshold, in-band
  area, coverage and the areas (lengths mm, areas mm^2, fractions %).
* **Histogram** of the area-weighted signed deviation with the band limits and the
  data-referenced distribution of the scan points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from qifreport.metrology.acceptance.statistics import DeviationStats
from qifreport.metrology.inspection import InspectionResult
from qifreport.registration.mesh import vertex_areas

from .context import ReportContext
from .kit import (
    DASH,
    INK,
    MUTED,
    RULE,
    Box,
    Table,
    draw_text,
    fit_text,
    fmt_area,
    fmt_band,
    fmt_mm,
    fmt_pct,
    fmt_smm,
    text_width,
)
from .render import deviation_colors

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = ["MAX_ZONE_COLUMNS", "stats_table", "draw_histogram"]

#: per-tolerance columns in the statistics table (beyond that, the tolerance table)
MAX_ZONE_COLUMNS = 3


def stats_table(res: InspectionResult) -> Table:
    """Whole part (vertices, area-weighted), scan points (data-referenced) and, for two
    or three tolerances, each tolerance on its own faces."""
    v, p, a = res.vertex_stats, res.point_stats, res.acceptance
    zones = res.zones if 2 <= len(res.zones) <= MAX_ZONE_COLUMNS else []
    cols_stats: list[DeviationStats] = [v, p] + [z.stats for z in zones]
    accs = [a, None] + [z.acceptance for z in zones]

    def row(label: str, f) -> list[str]:
        return [label] + [f(s) for s in cols_stats]

    def acc_row(label: str, f) -> list[str]:
        return [label] + [DASH if x is None else f(x) for x in accs]

    ceiling = res.scan_area / a.nominal_area if a.nominal_area > 0 else math.nan
    rows: list[list[str]] = [
        row("Scored samples", lambda s: str(s.n)),
        row("RMS, mm", lambda s: fmt_mm(s.rms)),
        row("Mean, mm", lambda s: fmt_smm(s.mean)),
        row("Max (most proud), mm", lambda s: fmt_smm(s.max_pos)),
        row("Min (most sunk), mm", lambda s: fmt_smm(s.min_neg)),
        row("P95 of |dev|, mm", lambda s: fmt_mm(s.p95)),
        row("P99 of |dev|, mm", lambda s: fmt_mm(s.p99)),
        row("P99.9 of |dev|, mm", lambda s: fmt_mm(s.p999)),
        row("Threshold \u03c4, mm", lambda s: fmt_mm(s.threshold)),
        row("Beyond +\u03c4, %", lambda s: fmt_pct(s.frac_above)),
        row("Beyond \u2212\u03c4, %", lambda s: fmt_pct(s.frac_below)),
        row("Beyond \u00b1\u03c4, %", lambda s: fmt_pct(s.frac_beyond)),
        acc_row("In tolerance, % of scored area", lambda x: fmt_pct(x.in_tolerance_fraction)),
        acc_row("Coverage, % of nominal area", lambda x: fmt_pct(x.coverage)),
        acc_row("Scored area, mm\u00b2", lambda x: fmt_area(x.scored_area)),
        acc_row("Nominal area, mm\u00b2", lambda x: fmt_area(x.nominal_area)),
        ["Scanned area, mm\u00b2", DASH, fmt_area(res.scan_area)] + [DASH] * len(zones),
        [
            "Ceiling scanned/nominal, %",
            fmt_pct(ceiling),
            "ok" if res.coverage_ceiling_ok else "EXCEEDED",
        ]
        + [DASH] * len(zones),
    ]
    emph = [False] * len(rows)
    emph[12] = not a.area_ok or any(not z.acceptance.area_ok for z in zones)
    emph[-1] = not res.coverage_ceiling_ok
    w_val = 56.0 if not zones else 44.0
    columns = [
        ("Statistic", 122.0 if not zones else 114.0, "l"),
        ("Vertices\n(area-weighted)" if not zones else "Part\nvertices", w_val, "r"),
        ("Scan points\n(data-ref.)" if not zones else "Scan\npoints", w_val, "r"),
    ]
    columns += [
        (f"{fit_text(z.zone.key, w_val - 4, 6.8, True)}\nown faces", w_val, "r") for z in zones
    ]
    if not zones:  # two value columns: use the width they are given
        columns = [(h, w * 1.18, al) for h, w, al in columns]
    title = "Statistics of the signed deviation"
    if len(res.zones) > MAX_ZONE_COLUMNS:
        title = "Statistics, whole part (per tolerance: table below)"
    elif not zones:
        title += " (whole part)"
    return Table(columns=columns, rows=rows, title=title, emphasis=emph)


#: bins of the histogram across the colour scale
HIST_BINS = 60
#: the bars' colour when several bands are drawn (no single colour scale)
BAR_GREY = (0.62, 0.66, 0.74)


@dataclass
class _HistAxes:
    """The histogram's plot area ``pa`` and scales: deviation -``S``..``S`` mm across, %
    per bin ``ymin``..``ymax`` up (log)."""

    pa: Box
    S: float
    ymin: float
    ymax: float = 100.0

    def X(self, v: float) -> float:
        """Page x of a deviation ``v``, mm."""
        return self.pa.x + (v + self.S) / (2 * self.S) * self.pa.w

    def Y(self, p: float) -> float:
        """Page y of a percentage ``p`` (at least ``ymin``)."""
        p = max(p, self.ymin)
        lo, hi = math.log10(self.ymin), math.log10(self.ymax)
        return self.pa.y + (math.log10(p) - lo) / (hi - lo) * self.pa.h


def _histograms(res: InspectionResult, S: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bin edges (shape (HIST_BINS + 1,), mm) over -S..S, and per bin the % of the
    scored area (vertices, area-weighted) and of the scan points (data-referenced), values
    beyond the scale in the end bins."""
    dev = np.asarray(res.deviation, dtype=float)
    w = vertex_areas(np.asarray(res.V, float), np.asarray(res.F, np.int64))
    ok = np.isfinite(dev) & (w > 0)
    edges = np.linspace(-S, S, HIST_BINS + 1)
    hv, _ = np.histogram(np.clip(dev[ok], -S, S), bins=edges, weights=w[ok])
    hv = 100.0 * hv / max(hv.sum(), 1e-300)
    pdv = np.asarray(res.point_deviation, dtype=float)
    pdv = pdv[np.isfinite(pdv)]
    hp, _ = np.histogram(np.clip(pdv, -S, S), bins=edges)
    hp = 100.0 * hp / max(hp.sum(), 1)
    return edges, hv, hp


def draw_histogram(c: Canvas, ctx: ReportContext, box: Box) -> None:
    """The histogram in ``box``: the area-weighted signed deviation of the vertices (bars,
    % of the scored area per bin, log scale) and the data-referenced deviation of the scan
    points (step line), over the colour scale, with the band limits."""
    S = ctx.scale
    title_h, left, bottom, right = 12.0, 30.0, 24.0, 4.0
    pa = Box(box.x + left, box.y + bottom, box.w - left - right, box.h - bottom - title_h - 25)
    draw_text(c, box.x, box.top - 9, "Histogram of the signed deviation", 8, True)
    edges, hv, hp = _histograms(ctx.res, S)
    pos = np.r_[hv[hv > 0], hp[hp > 0]]
    ymin = 10.0 ** max(-3, math.floor(math.log10(pos.min()))) if len(pos) else 0.01
    ax = _HistAxes(pa, S, ymin)
    _draw_hist_grid(c, ax)
    single = len(ctx.bands) == 1
    lo1, hi1 = ctx.bands[0][0], ctx.bands[0][1]
    mids = 0.5 * (edges[1:] + edges[:-1])
    cols = deviation_colors(mids, lo1, hi1, S) if single else np.tile(BAR_GREY, (HIST_BINS, 1))
    for i in range(HIST_BINS):
        if hv[i] <= 0:
            continue
        c.setFillColorRGB(*cols[i])
        x0, x1 = ax.X(edges[i]), ax.X(edges[i + 1])
        c.rect(x0, pa.y, x1 - x0, ax.Y(hv[i]) - pa.y, stroke=0, fill=1)
    _draw_point_steps(c, ax, edges, hp)
    _draw_band_limits(c, ax, ctx.bands)
    _draw_hist_axes(c, ax, box)
    _draw_hist_legend(c, ax, box, tuple(cols[HIST_BINS // 2]) if single else BAR_GREY)


def _draw_hist_grid(c: Canvas, ax: _HistAxes) -> None:
    """The decades of the log axis: grid lines and labels."""
    pa = ax.pa
    c.setLineWidth(0.3)
    c.setStrokeColorRGB(*RULE)
    e = int(math.log10(ax.ymin))
    for k in range(e, 3):
        y = ax.Y(10.0**k)
        c.line(pa.x, y, pa.x + pa.w, y)
        lab = f"{10.0**k:g}"
        draw_text(c, pa.x - 3, y - 2.2, lab, 6.0, False, MUTED, "r")


def _draw_point_steps(c: Canvas, ax: _HistAxes, edges: np.ndarray, hp: np.ndarray) -> None:
    """The data-referenced distribution of the scan points: a step line."""
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.8)
    path = c.beginPath()
    started = False
    for i in range(HIST_BINS):
        y = ax.Y(hp[i]) if hp[i] > 0 else ax.pa.y
        if not started:
            path.moveTo(ax.X(edges[i]), y)
            started = True
        else:
            path.lineTo(ax.X(edges[i]), y)
        path.lineTo(ax.X(edges[i + 1]), y)
    c.drawPath(path, stroke=1, fill=0)


def _draw_band_limits(c: Canvas, ax: _HistAxes, bands: list) -> None:
    """The limits of the first three bands, dashed, labelled above the plot on one of two
    rows where they do not collide."""
    pa = ax.pa
    c.setDash(2, 1.5)
    c.setLineWidth(0.7)
    rows_used: list[list[float]] = [[], []]
    for lo, hi, _keys in bands[:3]:
        for v in (lo, hi):
            if abs(v) < 1e-12:
                continue
            x = ax.X(v)
            c.setStrokeColorRGB(*INK)
            c.line(x, pa.y, x, pa.y + pa.h)
            for k, used in enumerate(rows_used):
                if all(abs(x - q) > 20 for q in used):
                    draw_text(c, x, pa.y + pa.h + 2 + 7 * k, fmt_band(v), 5.8, False, INK, "c")
                    used.append(x)
                    break
    c.setDash()


def _draw_hist_axes(c: Canvas, ax: _HistAxes, box: Box) -> None:
    """The frame, the deviation ticks (the end ones as <= and >=) and the axis titles."""
    pa, S = ax.pa, ax.S
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.5)
    c.rect(pa.x, pa.y, pa.w, pa.h, stroke=1, fill=0)
    for v in np.linspace(-S, S, 5):
        x = ax.X(v)
        c.line(x, pa.y, x, pa.y - 2)
        s = fmt_band(float(v))
        if abs(v) == S:
            s = ("\u2264" if v < 0 else "\u2265") + s
        draw_text(c, x, pa.y - 8.5, s, 6.0, False, INK, "c")
    draw_text(
        c,
        pa.x + pa.w / 2,
        box.y + 1,
        "signed deviation, mm (end bins collect everything beyond)",
        6.2,
        False,
        MUTED,
        "c",
    )
    c.saveState()
    c.translate(box.x + 6, pa.y + pa.h / 2)
    c.rotate(90)
    draw_text(c, 0, 0, "% per bin (log)", 6.2, False, MUTED, "c")
    c.restoreState()


def _draw_hist_legend(c: Canvas, ax: _HistAxes, box: Box, bar_color: tuple) -> None:
    """The legend above the plot: a bar of ``bar_color`` for the vertices, a line for the
    scan points."""
    pa = ax.pa
    ly = box.top - 20
    c.setFillColorRGB(*bar_color)
    c.rect(pa.x, ly, 9, 5.5, stroke=0, fill=1)
    first = "vertices, % of scored area"
    draw_text(c, pa.x + 12, ly + 0.6, first, 6.2)
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.8)
    lx = pa.x + 12 + text_width(first, 6.2) + 10
    c.line(lx, ly + 2.8, lx + 9, ly + 2.8)
    draw_text(
        c,
        lx + 12,
        ly + 0.6,
        fit_text("scan points (data-ref.), %", box.x + box.w - lx - 12, 6.2),
        6.2,
    )
