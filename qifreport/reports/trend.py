"""The one-page trend report of a batch: how the value of each characteristic runs over scans.

``qifreport batch`` inspects many scans of one part; its summary table (one row per scan, in
batch order) is drawn here on one page, A4 or US Letter, in the house style of the per-scan
report (:mod:`qifreport.reports.kit`: DejaVu Sans embedded, the same colours, number formats
and tables). The characteristics (:class:`TrendCharacteristic`) are the toleranced surfaces
(their profile value, mm) and the drawing's feature characteristics: geometric tolerances
(flatness, position ...: a zone width, mm, one-sided like a profile) and dimensions (a size,
mm, or an angle, degrees, between a lower and an upper limit). Top to bottom:

1. **Header** -- part, nominal SHA-256 (first 16 hex digits), creation time (UTC), number of
   scans and the count of each verdict (PASS, FAIL, NOT ESTABLISHED, ERROR); on the right the
   **pass rate**, PASS over the scans that produced a verdict, with the number that errored.
2. **Legend** of the run charts.
3. **Run charts**, one per characteristic (up to :data:`MAX_CHARTS`): the value of every
   scan against its sequence number, coloured by that characteristic's verdict on the scan
   (green PASS, red FAIL, grey NOT ESTABLISHED, dark for a basic dimension, which has none;
   without a verdict, by the value against the limits), joined by a thin line where the
   scans are at least a point apart (denser, the line would only grey the cloud of points);
   the limits and the mean as horizontal lines labelled on the right: for a profile or a
   geometric tolerance the tolerance (the upper limit; the lower limit of a zone width is 0,
   the axis starts there), for a dimension its lower and upper limits (``LSL``, ``USL``) about
   its nominal (a thin line, ``nom``) on an axis around them; scans that errored as grey
   crosses in a strip below the axis; values far beyond the rest as triangles at the top
   (or bottom) edge. Above each chart one line of statistics: n, mean, sigma, max (and min
   for a dimension), the capability -- the one-sided Cpk = (tolerance - mean) / (3 sigma) of
   a tolerance, Cp = (USL - LSL) / (6 sigma) and Cpk = min(USL - mean, mean - LSL) / (3 sigma)
   of a dimension -- and the pass count. With more characteristics than fit, the most
   critical are drawn, those with the smallest margin (the room between the worst value and
   its limit, relative to the tolerance: a tolerance's width, half a dimension's tolerance
   range), and the others named.
4. **Pass rate** against sequence (cumulative, and rolling for long batches) with the
   failed and errored scans marked below it, beside the **table of the scans that did not
   pass** (failed, not established or errored: sequence, serial or scan, verdict, deciding
   criterion or error), cut to :data:`MAX_FAILURE_ROWS` with the rest counted.
5. Definitions and a footer.

Nothing is labelled per point and the axis ticks are chosen from the page space, so the page
reads the same for 3 scans and for 2000. :func:`plan_trend` returns where everything goes
(used by :func:`write_trend_pdf`, and by the tests to find the points on a rasterized page).

The statistics (mean, sigma, Cp, Cpk, pass rates) are computed by
:mod:`qifreport.metrology.spc`, the axes and marks of the charts drawn with
:mod:`qifreport.reports.charts`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from qifreport import __version__
from qifreport.metrology import spc
from qifreport.metrology.spc import CharacteristicStats

from .charts import (
    ChartGeometry,
    decimals,
    draw_frame,
    draw_marker,
    draw_polyline,
    draw_y_title,
    nice_step,
    seq_ticks,
)
from .failures import MAX_FAILURE_ROWS, failure_table
from .kit import (
    DASH,
    FAIL_BG,
    FAIL_INK,
    HEAD_BG,
    INK,
    MUTED,
    PASS_BG,
    RULE,
    UNSURE_BG,
    Box,
    ReportPage,
    draw_table,
    draw_text,
    fit_text,
    fmt_mm,
    fmt_utc,
    short_sha,
    text_width,
    wrap_text,
)
from .render import GREEN_ZERO

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

log = logging.getLogger(__name__)

__all__ = [
    "TrendCharacteristic",
    "TrendLayout",
    "ChartGeometry",
    "plan_trend",
    "write_trend_pdf",
    "characteristic_stats",
    "CharacteristicStats",
    "seq_ticks",
    "MAX_CHARTS",
    "MAX_FAILURE_ROWS",
    "VERDICTS",
]

#: run charts on the page at most; the rest are named (smallest margin drawn first)
MAX_CHARTS = 6
#: verdicts of the summary table, in the order they are counted
VERDICTS = spc.VERDICTS
#: point colours by the characteristic's verdict on the scan (RGB 0..1)
POINT_COLORS = {"PASS": GREEN_ZERO, "FAIL": FAIL_BG, "NOT ESTABLISHED": (0.62, 0.62, 0.62)}
#: points of a basic dimension (a value without a verdict)
BASIC_COLOR = (0.22, 0.22, 0.22)
#: the tolerance (upper limit) line, a dimension's limits, and the mean line
TOL_COLOR = FAIL_INK
MEAN_COLOR = (0.18, 0.33, 0.62)
#: a dimension's nominal
NOMINAL_COLOR = (0.35, 0.35, 0.35)
#: the kinds of :class:`TrendCharacteristic`
KINDS = ("profile", "geometric", "dimension")
#: the line joining the points, and the marks of scans that errored
JOIN_COLOR = (0.70, 0.70, 0.70)
ERROR_COLOR = (0.45, 0.45, 0.45)
#: the rolling pass rate
ROLL_COLOR = (0.50, 0.63, 0.86)
#: height of the strip below zero that holds the error marks, points
ERROR_STRIP = 7.0


# ------------------------------------------------------------------------------ the data


@dataclass
class TrendCharacteristic:
    """A toleranced characteristic of the part, a column pair of the batch summary.

    Attributes
    ----------
    key : zone key, e.g. ``"T1"`` or ``"general"``, or a feature characteristic's key
        (``"G1"``, ``"D3"``); the summary columns are :attr:`value_column` and
        ``status_<key>``.
    description : what the tolerance is, e.g. ``"surface profile 1 mm |A|B|C| ..."``.
    tolerance_mm : a profile's or geometric tolerance's tolerance (the zone width), the
        upper limit of its value, mm; NaN for a dimension (its limits are ``lower`` and
        ``upper``).
    kind : ``"profile"`` (a toleranced surface, the default), ``"geometric"`` (a geometric
        tolerance of the drawing: flatness, position ...; one-sided like a profile) or
        ``"dimension"`` (two-sided: between ``lower`` and ``upper``).
    lower, upper : a dimension's limits, in ``unit``; None for a side without one (both
        None: a basic dimension, charted without limits or verdict).
    nominal : a dimension's nominal, in ``unit`` (None if not known).
    unit : of the values: ``"mm"``, or ``"deg"`` for an angle.
    quantity : what the value is, for the axis title (``"profile"``, ``"flatness"``,
        ``"diameter"`` ...).
    column : the summary column of the value; default ``profile_<key>_mm`` for a profile,
        ``value_<key>_<unit>`` otherwise (:func:`qifreport.batch.task.characteristic_columns`).
    """

    key: str
    description: str
    tolerance_mm: float
    kind: str = "profile"
    lower: float | None = None
    upper: float | None = None
    nominal: float | None = None
    unit: str = "mm"
    quantity: str = "profile"
    column: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind {self.kind!r} is not one of {KINDS}")

    @property
    def value_column(self) -> str:
        """The summary column of the value."""
        if self.column:
            return self.column
        if self.kind == "profile":
            return f"profile_{self.key}_mm"
        return f"value_{self.key}_{self.unit}"

    @property
    def two_sided(self) -> bool:
        """A dimension (its axis around its limits), not a one-sided tolerance from 0."""
        return self.kind == "dimension"

    def limits(self) -> list[tuple[str, float]]:
        """The limit lines of its chart, (label, value): ``tol`` or ``LSL``/``USL``."""
        if not self.two_sided:
            tol = float(self.tolerance_mm)
            return [("tol", tol)] if math.isfinite(tol) and tol > 0 else []
        out = []
        for label, x in (("USL", self.upper), ("LSL", self.lower)):
            if x is not None and math.isfinite(x):
                out.append((label, float(x)))
        return out


def _column(df: pd.DataFrame, name: str, kind: type) -> np.ndarray:
    """Column ``name`` as floats (NaN where missing) or strings ("" where missing)."""
    if name not in df.columns:
        return np.full(len(df), np.nan) if kind is float else np.full(len(df), "", dtype=object)
    col = df[name]
    if kind is float:
        return pd.to_numeric(col, errors="coerce").to_numpy(dtype=float)
    return col.fillna("").astype(str).str.strip().to_numpy(dtype=object)


def characteristic_stats(df: pd.DataFrame, ch: TrendCharacteristic) -> CharacteristicStats:
    """The statistics printed above a characteristic's run chart: those of
    :func:`qifreport.metrology.spc.characteristic_stats` (a profile or geometric tolerance)
    or :func:`qifreport.metrology.spc.dimension_stats` (a dimension) on its columns of the
    summary.

    Parameters
    ----------
    df : the batch summary (one row per scan).
    ch : the characteristic.

    Returns
    -------
    CharacteristicStats
        Over every scan with a finite value (NOT ESTABLISHED ones included).
    """
    values = _column(df, ch.value_column, float)
    status = _column(df, f"status_{ch.key}", str)
    if ch.two_sided:
        return spc.dimension_stats(values, status, ch.lower, ch.upper, ch.nominal)
    return spc.characteristic_stats(values, status, ch.tolerance_mm)


def _fmt_rate(rate: float) -> str:
    return f"{100.0 * rate:.1f} %" if math.isfinite(rate) else DASH


@dataclass
class TrendLayout:
    """Where :func:`write_trend_pdf` puts everything (points, origin bottom-left).

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


# ---------------------------------------------------------------------------- the report


class _Trend(ReportPage):
    """Measures and draws the trend page of one batch."""

    GAP = 8.0
    HEADER_H = 74.0
    LEGEND_H = 12.0
    BOTTOM_H = 122.0
    FOOTER_H = 36.0
    #: run chart: title and statistics lines above the frame, tick labels below, y labels
    #: on the left, tolerance and mean labels on the right (points)
    CHART_TOP, CHART_BOTTOM, CHART_LEFT, CHART_RIGHT = 21.0, 11.0, 30.0, 30.0
    #: tallest run chart (a lone characteristic does not fill the page)
    CHART_MAX_H = 300.0

    def __init__(
        self,
        df: pd.DataFrame,
        characteristics: list[TrendCharacteristic],
        part_name: str,
        created: datetime,
        nominal_sha256: str | None,
        page: str,
    ):
        super().__init__(page)
        self.df = df.reset_index(drop=True)
        self.chars = list(characteristics)
        self.part_name = part_name
        self.created = created
        self.sha = nominal_sha256 or ""
        self.n = len(self.df)
        if "seq" in self.df.columns:
            self.seq = pd.to_numeric(self.df["seq"], errors="coerce").to_numpy(dtype=float)
        else:
            self.seq = np.arange(1, self.n + 1, dtype=float)
        # positions on the x axis: the batch order (seq is 1..n in the summary)
        self.pos = np.arange(1, self.n + 1, dtype=float)
        self.verdict = _column(self.df, "verdict", str)
        self.counts = spc.verdict_counts(self.verdict)
        self.rate = spc.pass_rate(self.counts)
        self.stats = {ch.key: characteristic_stats(self.df, ch) for ch in self.chars}
        self.values = {ch.key: _column(self.df, ch.value_column, float) for ch in self.chars}
        self.status = {ch.key: _column(self.df, f"status_{ch.key}", str) for ch in self.chars}
        #: only surface profiles: the page reads as before feature characteristics were charted
        self.profiles_only = all(ch.kind == "profile" for ch in self.chars)
        missing = [
            name
            for ch in self.chars
            for name in (ch.value_column, f"status_{ch.key}")
            if name not in self.df.columns
        ]
        if missing:
            log.warning("batch summary has no column %s: read as not measured", ", ".join(missing))

    # ------------------------------------------------------------------------- layout

    def _chosen(self) -> tuple[list[TrendCharacteristic], list[str]]:
        """The characteristics drawn (caller's order) and the keys left out."""
        if len(self.chars) <= MAX_CHARTS:
            return self.chars, []
        order = sorted(
            range(len(self.chars)), key=lambda i: (self.stats[self.chars[i].key].margin, i)
        )
        keep = sorted(order[:MAX_CHARTS])
        return (
            [self.chars[i] for i in keep],
            [self.chars[i].key for i in range(len(self.chars)) if i not in set(keep)],
        )

    def _top(self, ch: TrendCharacteristic) -> float:
        """Value at the top of a one-sided run chart (from 0), mm: a round number above the
        tolerance and the values, except for values far above the rest (drawn at the top
        edge)."""
        v = self.values[ch.key]
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

    def _span(self, ch: TrendCharacteristic) -> tuple[float, float]:
        """(bottom, top) of a dimension's run chart, in its unit: round numbers around its
        limits, nominal and values, except for values beyond the limits by more than the
        tolerance range (drawn at the edge)."""
        v = self.values[ch.key]
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
        return step * math.floor((lo - pad) / step + 1e-9), step * math.ceil(
            (hi + pad) / step - 1e-9
        )

    def plan(self) -> TrendLayout:
        """Where everything goes: header, legend, the grid of run charts (one or two
        columns), the pass-rate chart beside the table of scans that did not pass, footer."""
        chosen, omitted = self._chosen()
        x0, top = self.M, self.H - self.MT
        blocks: dict = {}
        blocks["header"] = Box(x0, top - self.HEADER_H, self.CW, self.HEADER_H)
        y = top - self.HEADER_H - self.GAP
        blocks["legend"] = Box(x0, y - self.LEGEND_H, self.CW, self.LEGEND_H)
        y -= self.LEGEND_H + 4.0
        omitted_h = 10.0 if omitted else 0.0
        grid_h = y - omitted_h - self.GAP - self.BOTTOM_H - self.GAP - self.FOOTER_H - self.MT
        k = len(chosen)
        cols = 1 if k <= 3 else 2
        rows = max(1, math.ceil(k / cols))
        col_gap, row_gap = 14.0, 6.0
        cell_w = (self.CW - (cols - 1) * col_gap) / cols
        cell_h = min((grid_h - (rows - 1) * row_gap) / rows, self.CHART_MAX_H)
        charts: list[ChartGeometry] = []
        cells: list[Box] = []
        for i, ch in enumerate(chosen):
            r, q = divmod(i, cols)
            cell = Box(
                x0 + q * (cell_w + col_gap), y - (r + 1) * cell_h - r * row_gap, cell_w, cell_h
            )
            plot = Box(
                cell.x + self.CHART_LEFT,
                cell.y + self.CHART_BOTTOM,
                cell.w - self.CHART_LEFT - self.CHART_RIGHT,
                cell.h - self.CHART_TOP - self.CHART_BOTTOM,
            )
            cells.append(cell)
            if ch.two_sided:
                bottom, top = self._span(ch)
                geo = ChartGeometry(ch.key, plot, self.n, plot.y + ERROR_STRIP, top, bottom)
            else:
                geo = ChartGeometry(ch.key, plot, self.n, plot.y + ERROR_STRIP, self._top(ch))
            charts.append(geo)
        y -= rows * cell_h + (rows - 1) * row_gap if k else 40.0
        blocks["cells"] = cells
        if omitted:
            blocks["omitted"] = Box(x0, y - omitted_h, self.CW, omitted_h)
            y -= omitted_h
        y -= self.GAP
        bottom = Box(x0, y - self.BOTTOM_H, self.CW, self.BOTTOM_H)
        rate_w = round(self.CW * 0.40)
        rate_cell = Box(bottom.x, bottom.y, rate_w, bottom.h)
        rate_plot = Box(
            rate_cell.x + 30.0,
            rate_cell.y + 20.0,
            rate_cell.w - 30.0 - 30.0,
            rate_cell.h - 20.0 - 24.0,
        )
        blocks["rate_cell"] = rate_cell
        failures = Box(bottom.x + rate_w + 16.0, bottom.y, self.CW - rate_w - 16.0, bottom.h)
        low = self._rate_bottom()  # and headroom above 100 %, where a good batch runs
        pass_rate = ChartGeometry(
            "pass rate",
            rate_plot,
            self.n,
            rate_plot.y + ERROR_STRIP,
            100.0 + 0.05 * (100.0 - low),
            low,
        )
        blocks["footer_top"] = bottom.y - self.GAP
        return TrendLayout(
            page=self.page,
            width=self.W,
            height=self.H,
            charts=charts,
            omitted=omitted,
            pass_rate=pass_rate,
            failures=failures,
            blocks=blocks,
        )

    # ------------------------------------------------------------------------ drawing

    def draw(self, path: Path, lay: TrendLayout) -> None:
        """Write the page laid out as ``lay`` to ``path``."""
        c = self.new_canvas(path)
        c.setTitle(f"Batch trend report: {self.part_name}")
        c.setAuthor("qifreport")
        c.setSubject(
            f"{self.n} scans; pass rate {_fmt_rate(self.rate)}; nominal SHA-256 {self.sha or DASH}"
        )
        c.setCreator(f"qifreport {__version__}")
        keywords = ["qifreport", "batch", "trend", "surface profile"]
        if not self.profiles_only:
            keywords.append("feature characteristics")
        c.setKeywords(keywords)
        b = lay.blocks
        self._draw_header(c, b["header"])
        self._draw_legend(c, b["legend"], lay)
        by_key = {ch.key: ch for ch in self.chars}
        for cell, geo in zip(b["cells"], lay.charts, strict=True):
            self._draw_run_chart(c, cell, geo, by_key[geo.key])
        if not lay.charts:
            draw_text(c, self.M, b["legend"].y - 20, "No characteristic to chart.", 8, False, MUTED)
        if lay.omitted:
            box = b["omitted"]
            keys = ", ".join(lay.omitted)
            room = "below the tolerance" if self.profiles_only else "to their limits"
            draw_text(
                c,
                box.x,
                box.y + 2,
                fit_text(
                    f"+ {len(lay.omitted)} more characteristic"
                    f"{'s' if len(lay.omitted) != 1 else ''} not charted (the "
                    f"{MAX_CHARTS} with the smallest margin {room} are "
                    f"shown): {keys}",
                    box.w,
                    6.8,
                ),
                6.8,
                False,
                MUTED,
            )
        self._draw_pass_rate(c, b["rate_cell"], lay.pass_rate)
        self._draw_failures(c, lay.failures)
        self._draw_footer(c, b["footer_top"])
        c.showPage()
        c.save()

    def _draw_header(self, c: Canvas, box: Box) -> None:
        counts, rate = self.counts, self.rate
        # the pass rate, large, on the right
        vw = 172.0
        vx = box.x + box.w - vw
        # red if any failed, green if every scan passed, amber otherwise
        color = (
            FAIL_BG if counts["FAIL"] else PASS_BG if counts["PASS"] == self.n > 0 else UNSURE_BG
        )
        judged = counts["PASS"] + counts["FAIL"] + counts["NOT ESTABLISHED"]
        c.setFillColorRGB(*color)
        c.roundRect(vx, box.y, vw, box.h, 4, stroke=0, fill=1)
        white = (1.0, 1.0, 1.0)
        draw_text(c, vx + vw / 2, box.top - 13, "PASS RATE", 7.5, True, white, "c")
        draw_text(c, vx + vw / 2, box.top - 41, _fmt_rate(rate), 26, True, white, "c")
        draw_text(
            c,
            vx + vw / 2,
            box.top - 55,
            f"{counts['PASS']} PASS of {judged} scan{'s' if judged != 1 else ''} with a verdict",
            6.8,
            False,
            white,
            "c",
        )
        err = counts["ERROR"]
        draw_text(
            c,
            vx + vw / 2,
            box.top - 64,
            f"{err} errored (no verdict, not counted)" if err else "none errored",
            6.8,
            False,
            white,
            "c",
        )
        # title and facts
        tw = box.w - vw - 12
        what = "PROFILE" if self.profiles_only else "VALUE"
        draw_text(
            c,
            box.x,
            box.top - 8,
            f"BATCH TREND REPORT \u2014 {what} OF EACH CHARACTERISTIC BY SCAN",
            7.0,
            True,
            MUTED,
        )
        draw_text(c, box.x, box.top - 24, fit_text(self.part_name, tw, 16, True), 16, True)
        seq = self.seq[np.isfinite(self.seq)]
        span = f" (sequence {int(seq.min())} to {int(seq.max())})" if len(seq) else ""
        rows = [
            ("Nominal", f"SHA-256 {short_sha(self.sha)}\u2026" if self.sha else DASH),
            ("Created", fmt_utc(self.created)),
            (
                "Scans",
                f"{self.n}{span}; {len(self.chars)} characteristic"
                f"{'s' if len(self.chars) != 1 else ''}, "
                + (
                    "profile values in mm"
                    if self.profiles_only
                    else "values in mm"
                    + (", angles in degrees" if any(ch.unit == "deg" for ch in self.chars) else "")
                ),
            ),
        ]
        yy = box.top - 35
        for k, v in rows:
            draw_text(c, box.x, yy, k, 7.0, True, MUTED)
            draw_text(c, box.x + 46, yy, fit_text(v, tw - 46, 7.0), 7.0)
            yy -= 8.6
        # verdict counts as coloured chips
        draw_text(c, box.x, yy - 2, "Verdicts", 7.0, True, MUTED)
        x = box.x + 46
        chips = {
            "PASS": PASS_BG,
            "FAIL": FAIL_BG,
            "NOT ESTABLISHED": UNSURE_BG,
            "ERROR": ERROR_COLOR,
        }
        for v, col in chips.items():
            s = f"{v} {counts[v]}"
            w = text_width(s, 7.0, True) + 8
            c.setFillColorRGB(*(col if counts[v] else HEAD_BG))  # none: a quiet chip
            c.roundRect(x, yy - 5, w, 10.5, 2, stroke=0, fill=1)
            draw_text(c, x + 4, yy - 2, s, 7.0, True, white if counts[v] else MUTED)
            x += w + 5
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.6)
        c.line(box.x, box.y - 4, box.x + box.w, box.y - 4)

    def _legend_items(self, lay: TrendLayout) -> list[tuple[str, str, tuple[float, float, float]]]:
        """The legend's (mark, label, colour), for the charts drawn (short labels beside
        feature characteristics: their legend has more items)."""
        by_key = {ch.key: ch for ch in self.chars}
        drawn = {g.key: by_key[g.key] for g in lay.charts}
        items: list[tuple[str, str, tuple[float, float, float]]] = [
            ("dot", "PASS", POINT_COLORS["PASS"]),
            ("dot", "FAIL", POINT_COLORS["FAIL"]),
            ("dot", "not established", POINT_COLORS["NOT ESTABLISHED"]),
        ]
        above = any(np.any(self.values[g.key] > g.top) for g in lay.charts)
        if self.profiles_only:
            items += [
                ("line", "tolerance (upper limit)", TOL_COLOR),
                ("dash", "mean", MEAN_COLOR),
                ("cross", "scan errored", ERROR_COLOR),
            ]
            if above:
                items.append(("tri", "above the scale", INK))
            return items
        if any(np.any(self.status[k] == "BASIC") for k in drawn):
            items.append(("dot", "basic", BASIC_COLOR))
        items.append(("line", "limits", TOL_COLOR))
        if any(ch.two_sided and ch.nominal is not None for ch in drawn.values()):
            items.append(("dot-line", "nominal", NOMINAL_COLOR))
        items += [("dash", "mean", MEAN_COLOR), ("cross", "scan errored", ERROR_COLOR)]
        below = any(np.any(self.values[k] < geo.bottom) for k, geo in self._two_sided(lay))
        if above or below:
            items.append(("tri", "off the scale", INK))
        return items

    def _two_sided(self, lay: TrendLayout) -> list[tuple[str, ChartGeometry]]:
        """(key, geometry) of the dimensions' charts drawn."""
        two = {ch.key for ch in self.chars if ch.two_sided}
        return [(g.key, g) for g in lay.charts if g.key in two]

    def _draw_legend(self, c: Canvas, box: Box, lay: TrendLayout) -> None:
        y = box.y + 3
        x = box.x
        items = self._legend_items(lay)
        head = "Run charts \u2014 point colour: the characteristic\u2019s verdict"
        if not self.profiles_only:
            # the longest heading with which the legend fits its line
            width = sum(
                (15 if kind in ("line", "dash", "dot-line") else 7.5) + text_width(label, 6.8) + 9
                for kind, label, _ in items
            )
            heads = (head, "Run charts \u2014 colour: verdict", "Run charts")
            head = next(
                (h for h in heads if text_width(h, 6.8, True) + 10 + width <= box.w), heads[-1]
            )
        draw_text(c, x, y, head, 6.8, True)
        x += text_width(head, 6.8, True) + 10
        for kind, label, col in items:
            if kind in ("line", "dash", "dot-line"):
                c.setStrokeColorRGB(*col)
                c.setLineWidth({"line": 1.1, "dash": 0.8, "dot-line": 0.6}[kind])
                if kind == "dash":
                    c.setDash(2.5, 1.5)
                elif kind == "dot-line":
                    c.setDash(0.8, 1.2)
                c.line(x, y + 2.3, x + 12, y + 2.3)
                c.setDash()
                x += 15
            else:
                draw_marker(c, kind, x + 2.5, y + 2.3, 2.3 if kind != "cross" else 1.8, col)
                x += 7.5
            draw_text(c, x, y, label, 6.8)
            x += text_width(label, 6.8) + 9

    def _seq_label(self, pos: int) -> str:
        """The sequence number printed under x position ``pos`` (1-based batch order)."""
        if pos <= self.n and math.isfinite(self.seq[pos - 1]):
            return str(int(self.seq[pos - 1]))
        return str(pos)

    def _stats_line(self, ch: TrendCharacteristic, st: CharacteristicStats, width: float) -> str:
        """The line of statistics above a run chart ``width`` points wide: a dimension's
        smallest and largest values are left out when the line would not fit."""
        cpk = f"{st.cpk:.2f}" if math.isfinite(st.cpk) else DASH
        sigma = fmt_mm(st.sigma)
        if not ch.two_sided:
            return (
                f"n {st.n}   mean {fmt_mm(st.mean)}   \u03c3 {sigma}   max {fmt_mm(st.max)} mm"
                f"   Cpk {cpk}   PASS {st.n_pass} of {st.n_judged}"
            )
        u = ch.unit
        head = f"n {st.n}   mean {fmt_mm(st.mean)}"
        extremes = f"min {fmt_mm(st.min)}   max {fmt_mm(st.max)}"
        if ch.limits():
            cp = f"{st.cp:.2f}" if math.isfinite(st.cp) else DASH
            tail = f"Cp {cp}   Cpk {cpk}   PASS {st.n_pass} of {st.n_judged}"
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

    def _draw_run_chart(
        self, c: Canvas, cell: Box, geo: ChartGeometry, ch: TrendCharacteristic
    ) -> None:
        pa = geo.plot
        st = self.stats[ch.key]
        # title and statistics
        title = f"{ch.key} \u2014 {ch.description}" if ch.description else ch.key
        draw_text(c, cell.x, cell.top - 7.5, fit_text(title, cell.w, 7.5, True), 7.5, True)
        line = self._stats_line(ch, st, cell.w)
        draw_text(c, cell.x, cell.top - 16.5, fit_text(line, cell.w, 6.6), 6.6, False, MUTED)
        # grid and value axis (from 0 for a one-sided value, around the limits for a dimension)
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
        # the limits (the tolerance, or a dimension's LSL and USL), its nominal, the mean
        right = pa.x + pa.w
        y_limits = []
        for label, x in ch.limits():
            if not geo.bottom <= x <= geo.top:
                continue
            y_lim = float(geo.y(x))
            y_limits.append(y_lim)
            _rule(c, pa.x, right, y_lim, TOL_COLOR, 1.1)
            draw_text(c, right + 3, y_lim + 1.2, label, 6.0, True, TOL_COLOR)
            draw_text(c, right + 3, y_lim - 5.6, fmt_mm(x), 6.0, False, TOL_COLOR)
        y_nominal = math.nan
        if ch.two_sided and ch.nominal is not None and geo.bottom < ch.nominal < geo.top:
            y_nominal = float(geo.y(ch.nominal))
            _rule(c, pa.x, right, y_nominal, NOMINAL_COLOR, 0.6, (0.8, 1.2))
        y_mean = math.nan
        if math.isfinite(st.mean):
            y_mean = float(geo.y(st.mean))
            _rule(c, pa.x, right, y_mean, MEAN_COLOR, 0.7, (2.5, 1.5))
            if all(not abs(y_mean - y) < 14.0 for y in y_limits) and y_mean < pa.top - 2:
                draw_text(c, right + 3, y_mean - 2.2, "mean", 6.0, False, MEAN_COLOR)
            else:
                y_mean = math.nan  # not labelled
        if math.isfinite(y_nominal) and all(
            not abs(y_nominal - y) < 10.0 for y in [*y_limits, y_mean]
        ):
            draw_text(c, right + 3, y_nominal - 2.2, "nom", 6.0, False, NOMINAL_COLOR)
        self._draw_points(c, geo, ch)
        draw_frame(c, geo, self._seq_label)

    def _radius(self, geo: ChartGeometry) -> float:
        return float(np.clip(0.32 * geo.plot.w / max(self.n, 1), 0.65, 2.3))

    def _point_kinds(self, ch: TrendCharacteristic) -> np.ndarray:
        """Each scan's point colour (a key of :data:`POINT_COLORS`, or ``"BASIC"``): the
        characteristic's verdict; a value without one by its limits."""
        v, status = self.values[ch.key], self.status[ch.key]
        if not ch.two_sided:
            tol = float(ch.tolerance_mm)
            return np.where(
                np.isin(status, tuple(POINT_COLORS)),
                status,
                np.where(np.isfinite(tol) & (v > tol), "FAIL", "PASS"),
            )
        beyond = np.zeros(len(v), dtype=bool)
        if ch.upper is not None:
            beyond |= v > ch.upper
        if ch.lower is not None:
            beyond |= v < ch.lower
        by_value = np.where(beyond, "FAIL", "PASS" if ch.limits() else "BASIC")
        return np.where(
            np.isin(status, tuple(POINT_COLORS)),
            status,
            np.where(status == "BASIC", "BASIC", by_value),
        )

    def _draw_points(self, c: Canvas, geo: ChartGeometry, ch: TrendCharacteristic) -> None:
        v = self.values[ch.key]
        ok = np.isfinite(v)
        xs, ys = geo.x(self.pos), geo.y(np.where(ok, v, geo.bottom))
        r = self._radius(geo)
        # the joining line, broken where a scan has no value; not where the scans are
        # closer than a point (it would only grey the cloud of points)
        if geo.plot.w / max(self.n, 1) >= 1.0:
            c.setStrokeColorRGB(*JOIN_COLOR)
            c.setLineWidth(0.45 if r > 1.2 else 0.25)
            draw_polyline(c, xs, ys, ok)
        # the points: the characteristic's verdict; a value without one by the tolerance
        kind = self._point_kinds(ch)
        clipped = ok & (v > geo.top)
        below = ok & (v < geo.bottom) if ch.two_sided else np.zeros(len(v), dtype=bool)
        colors = {"BASIC": BASIC_COLOR, **POINT_COLORS}
        c.setStrokeColorRGB(1, 1, 1)
        c.setLineWidth(0.35)
        for name in ("BASIC", "PASS", "NOT ESTABLISHED", "FAIL"):
            # the rare ones on top, and no smaller than a readable dot however many scans
            rr = r if name in ("PASS", "BASIC") else max(r, 1.5)
            c.setFillColorRGB(*colors[name])
            for i in np.flatnonzero(ok & (kind == name)):
                if clipped[i]:
                    draw_marker(
                        c, "tri", float(xs[i]), geo.plot.top - 1.2 * rr, 1.2 * rr, colors[name]
                    )
                elif below[i]:
                    _down_triangle(c, float(xs[i]), geo.y_low + 1.2 * rr, 1.2 * rr, colors[name])
                else:
                    c.circle(float(xs[i]), float(ys[i]), rr, stroke=int(rr >= 1.5), fill=1)
        # scans that errored: crosses in the strip below the axis
        err = np.flatnonzero(self.verdict == "ERROR")
        size = 1.6
        for i in err:
            draw_marker(c, "cross", float(xs[i]), geo.plot.y + ERROR_STRIP / 2, size, ERROR_COLOR)

    def rates(self) -> tuple[np.ndarray, np.ndarray | None, int]:
        """Cumulative and rolling pass rate (%) after each scan, and the rolling window.

        NaN until a scan has a verdict; the rolling rate (over the last ``window`` scans)
        only for batches of :data:`~qifreport.metrology.spc.ROLLING_MIN_SCANS` scans or more
        (else None and window 0).
        """
        cum = spc.cumulative_pass_rate(self.verdict)
        window = spc.rolling_window(self.n)
        if not window:
            return cum, None, 0
        return cum, spc.rolling_pass_rate(self.verdict, window), window

    def _rate_bottom(self) -> float:
        """Lowest % of the pass-rate axis: 0, or 50, 80, 90, 95 when every rate is above it
        (a batch passing at 99 % shows its dips)."""
        cum, roll, _ = self.rates()
        vals = np.concatenate([cum, roll if roll is not None else []])
        vals = vals[np.isfinite(vals)]
        low = float(vals.min()) if len(vals) else 0.0
        return max(b for b in (0.0, 50.0, 80.0, 90.0, 95.0) if b <= low - 1.0 or b == 0.0)

    def _draw_pass_rate(self, c: Canvas, cell: Box, geo: ChartGeometry) -> None:
        pa = geo.plot
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
        cum, roll, window = self.rates()
        # grid and value axis
        step = (
            25.0
            if geo.bottom == 0
            else 10.0
            if geo.bottom == 50
            else 5.0
            if geo.bottom == 80
            else 2.0
            if geo.bottom == 90
            else 1.0
        )
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
        xs = geo.x(self.pos)
        for vals, color, width in ((cum, INK, 1.0), (roll, ROLL_COLOR, 0.8)):
            if vals is None:
                continue
            ok = np.isfinite(vals)
            ys = geo.y(np.where(ok, vals, geo.bottom))
            c.setStrokeColorRGB(*color)
            c.setLineWidth(width)
            draw_polyline(c, xs, ys, ok)
            if self.n <= 40:  # few scans: the values as dots
                c.setFillColorRGB(*color)
                for i in np.flatnonzero(ok):
                    c.circle(float(xs[i]), float(ys[i]), 1.1, stroke=0, fill=1)
        # the scans that did not pass, along the bottom
        ym = pa.y + ERROR_STRIP / 2
        weight = float(np.clip(0.6 * pa.w / max(self.n, 1), 0.3, 1.0))  # dense: thin
        for name, kind, col in (
            ("NOT ESTABLISHED", "tick", UNSURE_BG),
            ("FAIL", "tick", FAIL_BG),
            ("ERROR", "cross", ERROR_COLOR),
        ):
            for i in np.flatnonzero(self.verdict == name):
                draw_marker(c, kind, float(xs[i]), ym, 2.6 if kind == "tick" else 1.6, col, weight)
        last = cum[np.isfinite(cum)]
        if len(last):
            draw_text(
                c, pa.x + pa.w + 3, float(geo.y(last[-1])) - 2.2, f"{last[-1]:.1f}", 6.0, True, INK
            )
        draw_frame(c, geo, self._seq_label)
        # legend under the ticks
        y = cell.y + 1.5
        x = pa.x
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

    def _draw_failures(self, c: Canvas, box: Box) -> None:
        t = failure_table(
            self.verdict,
            self.seq,
            _column(self.df, "serial", str),
            _column(self.df, "scan", str),
            _column(self.df, "decided_by", str),
            _column(self.df, "error", str),
            box.w,
        )
        draw_table(c, box.x, box.top, t)

    def _draw_footer(self, c: Canvas, top: float) -> None:
        defs = (
            "Profile value: width of the smallest zone about the band centre that holds "
            "every scored point of the surface (as in the QIF). The verdict applies the "
            "area and region criteria, so a value above the tolerance may still pass. "
            "Cpk = (tolerance \u2212 mean) / (3\u03c3), one-sided (a profile value is at "
            "least 0), \u03c3 the sample standard deviation (n \u2212 1) of the measured "
            "scans; pass rate = PASS / (PASS + FAIL + NOT ESTABLISHED)."
        )
        if not self.profiles_only:
            defs = FEATURE_DEFINITIONS
        y = top - 1
        for s in wrap_text(defs, self.CW, 6.2)[:3]:
            draw_text(c, self.M, y - 6, s, 6.2, False, MUTED)
            y -= 7.4
        foot = (
            f"qifreport {__version__} \u00b7 batch trend \u00b7 page 1 of 1 \u00b7 "
            f"{self.n} scans of {self.part_name} \u00b7 created {fmt_utc(self.created)}"
        )
        draw_text(c, self.M, self.MT, fit_text(foot, self.CW, 6.2), 6.2, False, MUTED)


#: the footer's definitions when feature characteristics are charted (three lines at most)
FEATURE_DEFINITIONS = (
    "Value as in the QIF: a surface's profile value (smallest zone about the band centre "
    "holding every scored point), a geometric tolerance's zone, a dimension's size. A "
    "profile's verdict applies the area and region criteria (a value above the tolerance may "
    "pass). Tolerance: Cpk = (tol \u2212 mean) / (3\u03c3), one-sided; dimension: "
    "Cp = (USL \u2212 LSL) / (6\u03c3), Cpk = min(USL \u2212 mean, mean \u2212 LSL) / (3\u03c3); "
    "\u03c3 the sample deviation (n \u2212 1); pass rate = PASS / (PASS + FAIL + NOT ESTABLISHED)."
)


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


# ----------------------------------------------------------------------------- public API


def plan_trend(
    df: pd.DataFrame,
    characteristics: list[TrendCharacteristic],
    *,
    part_name: str = "",
    created: datetime | None = None,
    nominal_sha256: str | None = None,
    page: str = "A4",
) -> TrendLayout:
    """Where :func:`write_trend_pdf` puts everything for this batch (no file written).

    Deterministic: :func:`write_trend_pdf` draws exactly this layout. Tests use it to find the
    points on a rasterized page.
    """
    return _Trend(
        df, characteristics, part_name, created or datetime.now(), nominal_sha256, page
    ).plan()


def write_trend_pdf(
    path: Path,
    df: pd.DataFrame,
    characteristics: list[TrendCharacteristic],
    *,
    part_name: str,
    created: datetime,
    nominal_sha256: str | None = None,
    page: str = "A4",
) -> None:
    """Write the one-page trend report of a batch.

    Parameters
    ----------
    path : the PDF to write (the caller makes it atomic).
    df : the batch summary, one row per scan in batch order, with the columns ``seq``,
        ``scan``, ``serial``, ``verdict``, ``decided_by``, ``error`` and, per characteristic
        key K, ``profile_<K>_mm`` and ``status_<K>`` (a missing column reads as empty).
    characteristics : the characteristics to chart, in the order of the report; beyond
        :data:`MAX_CHARTS` the ones with the smallest margin are charted.
    part_name : printed as the title.  created : time of the batch (printed in UTC; naive
        means UTC).  nominal_sha256 : digest of the nominal (its first 16 digits printed).
    page : ``"A4"`` or ``"Letter"`` (case-insensitive).
    """
    t0 = time.perf_counter()
    rep = _Trend(df, characteristics, part_name, created, nominal_sha256, page)
    lay = rep.plan()
    rep.draw(Path(path), lay)
    log.info(
        "trend report %s: %d scans, %d of %d characteristics charted, %.2f s",
        Path(path).name,
        rep.n,
        len(lay.charts),
        len(characteristics),
        time.perf_counter() - t0,
    )


def _rule(
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
