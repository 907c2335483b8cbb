"""The trend page of one batch: its header (part, verdict counts, the pass rate), the run
charts' legend, the run charts, the pass-rate chart beside the table of scans that did not
pass, the definitions and the footer; :func:`plan_trend` and :func:`write_trend_pdf`."""

from __future__ import annotations

import logging
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from qifreport import __version__

from ..charts import ChartGeometry, draw_marker
from ..failures import failure_table
from ..kit import (
    DASH,
    FAIL_BG,
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
    fmt_utc,
    short_sha,
    text_width,
    wrap_text,
)
from .colors import BASIC_COLOR, ERROR_COLOR, MEAN_COLOR, NOMINAL_COLOR, POINT_COLORS, TOL_COLOR
from .data import TrendCharacteristic, TrendData, fmt_rate
from .layout import MAX_CHARTS, TrendLayout, plan_layout
from .pass_rate import draw_pass_rate
from .run_chart import draw_run_chart

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

log = logging.getLogger("qifreport.reports.trend")

__all__ = ["FEATURE_DEFINITIONS", "plan_trend", "write_trend_pdf"]

#: the footer's definitions when only surface profiles are charted (three lines at most)
PROFILE_DEFINITIONS = (
    "Profile value: width of the smallest zone about the band centre that holds "
    "every scored point of the surface (as in the QIF). The verdict applies the "
    "area and region criteria, so a value above the tolerance may still pass. "
    "Cpk = (tolerance \u2212 mean) / (3\u03c3), one-sided (a profile value is at "
    "least 0), \u03c3 the sample standard deviation (n \u2212 1) of the measured "
    "scans; Cpk [its 0.95 confidence interval], stated from 25 scans; pass rate = PASS / "
    "(PASS + FAIL + NOT ESTABLISHED)."
)
#: the footer's definitions when feature characteristics are charted (three lines at most)
FEATURE_DEFINITIONS = (
    "Value as in the QIF: a surface's profile value (smallest zone about the band centre "
    "holding every scored point), a geometric tolerance's zone, a dimension's size. A "
    "profile's verdict applies the area and region criteria (a value above the tolerance may "
    "pass). Tolerance: Cpk = (tol \u2212 mean) / (3\u03c3), one-sided; dimension: "
    "Cp = (USL \u2212 LSL) / (6\u03c3), Cpk = min(USL \u2212 mean, mean \u2212 LSL) / (3\u03c3); "
    "\u03c3 the sample deviation (n \u2212 1); Cpk [0.95 interval] from 25 scans; pass "
    "rate = PASS / (PASS + FAIL + NOT ESTABLISHED)."
)
#: the header's pass-rate box width, and the indent of its facts' values, points
RATE_BOX_W = 172.0
FACT_INDENT = 46.0
WHITE = (1.0, 1.0, 1.0)


class TrendPage(ReportPage):
    """Measures and draws the trend page of one batch (``data``) on a ``page``-size sheet."""

    def __init__(self, data: TrendData, page: str):
        super().__init__(page)
        self.data = data

    def plan(self) -> TrendLayout:
        """Where everything goes (:func:`~.layout.plan_layout`)."""
        return plan_layout(self.data, self)

    def draw(self, path: Path, lay: TrendLayout) -> None:
        """Write the page laid out as ``lay`` to ``path``."""
        d = self.data
        c = self.new_canvas(path)
        c.setTitle(f"Batch trend report: {d.part_name}")
        c.setAuthor("qifreport")
        c.setSubject(f"{d.n} scans; pass rate {fmt_rate(d.rate)}; nominal SHA-256 {d.sha or DASH}")
        c.setCreator(f"qifreport {__version__}")
        keywords = ["qifreport", "batch", "trend", "surface profile"]
        if not d.profiles_only:
            keywords.append("feature characteristics")
        c.setKeywords(keywords)
        b = lay.blocks
        self._draw_header(c, b["header"])
        self._draw_legend(c, b["legend"], lay)
        by_key = d.by_key()
        for cell, geo in zip(b["cells"], lay.charts, strict=True):
            draw_run_chart(c, d, cell, geo, by_key[geo.key])
        if not lay.charts:
            draw_text(c, self.M, b["legend"].y - 20, "No characteristic to chart.", 8, False, MUTED)
        if lay.omitted:
            self._draw_omitted(c, b["omitted"], lay.omitted)
        draw_pass_rate(c, d, b["rate_cell"], lay.pass_rate)
        self._draw_failures(c, lay.failures)
        self._draw_footer(c, b["footer_top"])
        c.showPage()
        c.save()

    # -------------------------------------------------------------------------- header

    def _draw_header(self, c: Canvas, box: Box) -> None:
        """The pass rate, large, on the right; the title, facts and verdict counts."""
        self._draw_rate_box(c, box)
        tw = box.w - RATE_BOX_W - 12
        what = "PROFILE" if self.data.profiles_only else "VALUE"
        draw_text(
            c,
            box.x,
            box.top - 8,
            f"BATCH TREND REPORT \u2014 {what} OF EACH CHARACTERISTIC BY SCAN",
            7.0,
            True,
            MUTED,
        )
        draw_text(c, box.x, box.top - 24, fit_text(self.data.part_name, tw, 16, True), 16, True)
        yy = box.top - 35
        for k, v in self._facts():
            draw_text(c, box.x, yy, k, 7.0, True, MUTED)
            draw_text(c, box.x + FACT_INDENT, yy, fit_text(v, tw - FACT_INDENT, 7.0), 7.0)
            yy -= 8.6
        self._draw_verdict_chips(c, box.x, yy)
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.6)
        c.line(box.x, box.y - 4, box.x + box.w, box.y - 4)

    def _draw_rate_box(self, c: Canvas, box: Box) -> None:
        """The pass rate in a box on the header's right: red if any scan failed, green if
        every scan passed, amber otherwise."""
        d = self.data
        counts = d.counts
        vw = RATE_BOX_W
        vx = box.x + box.w - vw
        color = FAIL_BG if counts["FAIL"] else PASS_BG if counts["PASS"] == d.n > 0 else UNSURE_BG
        judged = counts["PASS"] + counts["FAIL"] + counts["NOT ESTABLISHED"]
        c.setFillColorRGB(*color)
        c.roundRect(vx, box.y, vw, box.h, 4, stroke=0, fill=1)
        xc = vx + vw / 2
        draw_text(c, xc, box.top - 13, "PASS RATE", 7.5, True, WHITE, "c")
        draw_text(c, xc, box.top - 41, fmt_rate(d.rate), 26, True, WHITE, "c")
        draw_text(
            c,
            xc,
            box.top - 55,
            f"{counts['PASS']} PASS of {judged} scan{'s' if judged != 1 else ''} with a verdict",
            6.8,
            False,
            WHITE,
            "c",
        )
        err = counts["ERROR"]
        line = f"{err} errored (no verdict, not counted)" if err else "none errored"
        draw_text(c, xc, box.top - 64, line, 6.8, False, WHITE, "c")

    def _facts(self) -> list[tuple[str, str]]:
        """The header's (label, value) rows: nominal, creation time, scans."""
        d = self.data
        seq = d.seq[np.isfinite(d.seq)]
        span = f" (sequence {int(seq.min())} to {int(seq.max())})" if len(seq) else ""
        n_chars = len(d.chars)
        if d.profiles_only:
            units = "profile values in mm"
        else:
            deg = ", angles in degrees" if any(ch.unit == "deg" for ch in d.chars) else ""
            units = "values in mm" + deg
        return [
            ("Nominal", f"SHA-256 {short_sha(d.sha)}\u2026" if d.sha else DASH),
            ("Created", fmt_utc(d.created)),
            (
                "Scans",
                f"{d.n}{span}; {n_chars} characteristic{'s' if n_chars != 1 else ''}, {units}",
            ),
        ]

    def _draw_verdict_chips(self, c: Canvas, x0: float, yy: float) -> None:
        """The verdict counts as coloured chips (a quiet chip for none) at height ``yy``."""
        counts = self.data.counts
        draw_text(c, x0, yy - 2, "Verdicts", 7.0, True, MUTED)
        x = x0 + FACT_INDENT
        chips = {
            "PASS": PASS_BG,
            "FAIL": FAIL_BG,
            "NOT ESTABLISHED": UNSURE_BG,
            "ERROR": ERROR_COLOR,
        }
        for v, col in chips.items():
            s = f"{v} {counts[v]}"
            w = text_width(s, 7.0, True) + 8
            c.setFillColorRGB(*(col if counts[v] else HEAD_BG))
            c.roundRect(x, yy - 5, w, 10.5, 2, stroke=0, fill=1)
            draw_text(c, x + 4, yy - 2, s, 7.0, True, WHITE if counts[v] else MUTED)
            x += w + 5

    # -------------------------------------------------------------------------- legend

    def _legend_items(self, lay: TrendLayout) -> list[tuple[str, str, tuple[float, float, float]]]:
        """The legend's (mark, label, colour), for the charts drawn (short labels beside
        feature characteristics: their legend has more items)."""
        by_key = self.data.by_key()
        drawn = {g.key: by_key[g.key] for g in lay.charts}
        items: list[tuple[str, str, tuple[float, float, float]]] = [
            ("dot", "PASS", POINT_COLORS["PASS"]),
            ("dot", "FAIL", POINT_COLORS["FAIL"]),
            ("dot", "not established", POINT_COLORS["NOT ESTABLISHED"]),
        ]
        above = any(np.any(self.data.values[g.key] > g.top) for g in lay.charts)
        if self.data.profiles_only:
            items += [
                ("line", "tolerance (upper limit)", TOL_COLOR),
                ("dash", "mean", MEAN_COLOR),
                ("cross", "scan errored", ERROR_COLOR),
            ]
            if above:
                items.append(("tri", "above the scale", INK))
            return items
        if any(np.any(self.data.status[k] == "BASIC") for k in drawn):
            items.append(("dot", "basic", BASIC_COLOR))
        items.append(("line", "limits", TOL_COLOR))
        if any(ch.two_sided and ch.nominal is not None for ch in drawn.values()):
            items.append(("dot-line", "nominal", NOMINAL_COLOR))
        items += [("dash", "mean", MEAN_COLOR), ("cross", "scan errored", ERROR_COLOR)]
        below = any(np.any(self.data.values[k] < geo.bottom) for k, geo in self._two_sided(lay))
        if above or below:
            items.append(("tri", "off the scale", INK))
        return items

    def _two_sided(self, lay: TrendLayout) -> list[tuple[str, ChartGeometry]]:
        """(key, geometry) of the dimensions' charts drawn."""
        two = {ch.key for ch in self.data.chars if ch.two_sided}
        return [(g.key, g) for g in lay.charts if g.key in two]

    def _draw_legend(self, c: Canvas, box: Box, lay: TrendLayout) -> None:
        """The run charts' legend on one line: a heading that fits, then the marks."""
        y = box.y + 3
        x = box.x
        items = self._legend_items(lay)
        head = "Run charts \u2014 point colour: the characteristic\u2019s verdict"
        if not self.data.profiles_only:
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

    # ------------------------------------------------------------------- the rest

    def _draw_omitted(self, c: Canvas, box: Box, omitted: list[str]) -> None:
        """The line naming the characteristics not charted."""
        keys = ", ".join(omitted)
        room = "below the tolerance" if self.data.profiles_only else "to their limits"
        draw_text(
            c,
            box.x,
            box.y + 2,
            fit_text(
                f"+ {len(omitted)} more characteristic"
                f"{'s' if len(omitted) != 1 else ''} not charted (the "
                f"{MAX_CHARTS} with the smallest margin {room} are "
                f"shown): {keys}",
                box.w,
                6.8,
            ),
            6.8,
            False,
            MUTED,
        )

    def _draw_failures(self, c: Canvas, box: Box) -> None:
        """The table of the scans that did not pass."""
        d = self.data
        t = failure_table(
            d.verdict,
            d.seq,
            d.column("serial", str),
            d.column("scan", str),
            d.column("decided_by", str),
            d.column("error", str),
            box.w,
        )
        draw_table(c, box.x, box.top, t)

    def _draw_footer(self, c: Canvas, top: float) -> None:
        """The definitions (three lines at most) and the footer line."""
        defs = PROFILE_DEFINITIONS if self.data.profiles_only else FEATURE_DEFINITIONS
        y = top - 1
        for s in wrap_text(defs, self.CW, 6.2)[:3]:
            draw_text(c, self.M, y - 6, s, 6.2, False, MUTED)
            y -= 7.4
        foot = (
            f"qifreport {__version__} \u00b7 batch trend \u00b7 page 1 of 1 \u00b7 "
            f"{self.data.n} scans of {self.data.part_name} \u00b7 created "
            f"{fmt_utc(self.data.created)}"
        )
        draw_text(c, self.M, self.MT, fit_text(foot, self.CW, 6.2), 6.2, False, MUTED)


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
    data = TrendData(df, characteristics, part_name, created or datetime.now(), nominal_sha256)
    return TrendPage(data, page).plan()


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
    rep = TrendPage(TrendData(df, characteristics, part_name, created, nominal_sha256), page)
    lay = rep.plan()
    rep.draw(Path(path), lay)
    log.info(
        "trend report %s: %d scans, %d of %d characteristics charted, %.2f s",
        Path(path).name,
        rep.data.n,
        len(lay.charts),
        len(characteristics),
        time.perf_counter() - t0,
    )
