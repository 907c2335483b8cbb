"""The one-page PDF conformance report an auditor signs (paper Section 10, Figures 27-28).

One page, A4 or US Letter, written with reportlab, every font embedded (DejaVu Sans from
matplotlib's bundled fonts). Top to bottom:

1. **Title block** -- part, input files with their SHA-256 (first 16 hex digits), time of the
   inspection, software version, serial number, operator, organization, author, units; and the
   **verdict**, large, with the criteria that decided it (area, region; whole part and per
   tolerance).
2. **Decision** -- the acceptance rule and, for a failing part, the reasons (the QIF's
   ``decided_by`` lines).
3. **Deviation maps** -- the registered nominal from two or three automatically chosen
   directions (:mod:`qifreport.reports.render`), green inside the band, red proud / blue
   sunk outside, grey unscored, out-of-tolerance regions outlined and numbered as in the
   region table, the signed deviation called out at each numbered region's worst point and
   at the part's extremes (:mod:`qifreport.reports.callouts`); the colour bar (mm,
   symmetric about 0) marks each distinct band.
4. **Histogram** of the area-weighted signed deviation with the band limits and the
   data-referenced distribution, beside the **statistics** (whole part at the vertices,
   scan points, and each tolerance on its own faces when there are two or three).
5. **Tolerances** -- one row per toleranced surface: band, verdict, in-band area, regions,
   profile value (as in the QIF ``Value``), RMS, P99.9 and the signed extremes.
6. **Regions** (largest first, the numbers of the maps) beside the **registration** facts
   (the virtual fixture's method, ``--method``, in the title and the first row).
7. With ``--seeds``, the repeatability row (regions persistent k of m, RMS and max spread);
   not-evaluated PMI, warnings, sign-off line and a footer naming the QIF results file.

Every number is the one the QIF writer stores (:mod:`qifreport.qif.writer`), printed at a fixed
precision: lengths in mm with 3 decimals (:func:`fmt_mm`), areas in mm^2 with 1 decimal
(:func:`fmt_area`), fractions as % with 2 decimals (:func:`fmt_pct`). Lists that do not fit
(many tolerances, many regions, many reasons) are cut and the cut is stated ("+ 12 more
regions ... see QIF"); the page never overflows: :func:`plan_layout` measures every block
and shrinks the lists and the maps until the page holds them.

This module lays the page out and draws it; each block is a module of its own:
:mod:`~qifreport.reports.header` (title block, verdict, decision),
:mod:`~qifreport.reports.maps` (maps and colour bar), :mod:`~qifreport.reports.stats`
(statistics table and histogram), :mod:`~qifreport.reports.tables` (tolerances and regions),
:mod:`~qifreport.reports.registration` (registration facts) and
:mod:`~qifreport.reports.notes` (notes, sign-off, footer), over the shared
:class:`~qifreport.reports.context.ReportContext` and the house style of
:mod:`~qifreport.reports.kit` (fonts, colours, number formats, tables).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qifreport import __version__
from qifreport.metrology.inspection import InspectionResult
from qifreport.qif.writer import Provenance

from .callouts import Callout, callouts
from .context import ReportContext, clamp_markers
from .header import HEADER_H, decision_lines, draw_decision, draw_header
from .kit import FONT, Box, Table, draw_table, fmt_area, fmt_mm, fmt_pct, fmt_smm
from .maps import colorbar_height, draw_colorbar, draw_maps, layout_score, map_boxes, map_margins
from .notes import draw_notes_footer, fit_notes, note_lines, notes_height
from .registration import registration_table
from .render import RenderedView, render_views
from .stats import draw_histogram, stats_table
from .tables import (
    characteristic_table,
    not_passing_characteristics,
    pick_tolerances,
    region_table,
    tolerance_table,
)
from .views import ViewSpec, picture_points

log = logging.getLogger(__name__)

# the number formats of the page (:mod:`qifreport.reports.kit`) are part of its contract
__all__ = [
    "MAP_DPI",
    "MAP_MAX_PT",
    "PageLayout",
    "map_points",
    "plan_layout",
    "write_pdf",
    "write_report",
    "fmt_mm",
    "fmt_smm",
    "fmt_area",
    "fmt_pct",
]

#: resolution of the map pictures, dots per inch of the page
MAP_DPI = 200
#: largest height of the map block (pictures and their captions), points
MAP_MAX_PT = 330.0
#: the smallest map block: a 100 pt picture under its 11 pt caption
MAP_MIN_PT = 111.0
#: the note that stands for the histogram and the statistics when they are left out
MID_LEFT_OUT = (
    "The histogram and the whole part's statistics are left out: the items that do not pass "
    "take their room (every figure is in the QIF file and the --json summary)."
)


@dataclass
class PageLayout:
    """Where everything goes on the page (points, origin bottom-left).

    Attributes
    ----------
    page : ``"A4"`` or ``"LETTER"``.  width, height : page size, points.
    views : the chosen camera directions, in the order of ``maps``.
    maps : one box per view (the picture).
    colorbar : the colour bar block.  histogram : the histogram block (None: left out, the
        items that do not pass took its room).
    regions_listed, tolerances_listed, reasons_listed : how many rows each list prints
        (the rest is summarised on the page and given in full in the QIF).
    scale : colour-scale limit, mm.
    """

    page: str
    width: float
    height: float
    views: list[ViewSpec]
    maps: list[Box]
    colorbar: Box
    histogram: Box | None
    regions_listed: int
    tolerances_listed: int
    reasons_listed: int
    scale: float
    blocks: dict = field(default_factory=dict, repr=False)  # internal: what the drawer uses


@dataclass
class _FixedBlocks:
    """The report's blocks that the fitting does not shrink (the notes are cut last, when
    nothing else can give) and the widths of the columns, points."""

    stats: Table
    regtab: Table
    notes: list
    reg_w: float
    regf_w: float
    hist_w: float


def shrink_steps(n_chr_fail: int) -> list[tuple[str, float, float]]:
    """The order in which the page's blocks are cut, as (block, floor, step): the maps'
    height (points) and the rows listed of the decision's reasons, the regions, the
    tolerances and the characteristics (the ``n_chr_fail`` that do not pass stay listed)."""
    return [
        ("map", 240.0, 5.0),
        ("dec", 6, 1),
        ("reg", 12, 1),
        ("tol", 10, 1),
        ("chr", 10, 1),
        ("map", 210.0, 5.0),
        ("dec", 3, 1),
        ("reg", 8, 1),
        ("tol", 6, 1),
        ("chr", 5, 1),
        ("map", 180.0, 5.0),
        ("reg", 5, 1),
        ("tol", 4, 1),
        ("dec", 2, 1),
        ("map", 140.0, 5.0),
        ("reg", 2, 1),
        ("tol", 2, 1),
        ("chr", 2, 1),
        ("dec", 1, 1),
        ("chr", min(2, n_chr_fail), 1),  # those that do not pass stay listed
        ("map", MAP_MIN_PT, 5.0),
        ("mid", 0, 1),  # last: the histogram and the whole part's statistics
    ]


class _Report(ReportContext):
    """Lays out and draws the page of one result (each block drawn by its module)."""

    GAP = 7.0

    def decision_lines(self, limit: int) -> tuple[list[tuple[str, bool]], int]:
        """The decision block's lines across the page, at most ``limit`` reasons."""
        return decision_lines(self.res, self.CW, limit)

    def tolerance_table(self, limit: int) -> Table:
        """The tolerance table across the page, at most ``limit`` rows."""
        return tolerance_table(self.res, self.CW, limit)

    def region_table(self, limit: int, width: float) -> Table:
        """The region table ``width`` points wide, at most ``limit`` rows."""
        return region_table(self.res, limit, width)

    def characteristic_table(self, limit: int) -> Table | None:
        """The feature characteristics across the page, at most ``limit`` rows (None:
        the drawing has none)."""
        return characteristic_table(self.res, self.CW, limit)

    def _chr_height(self, limit: int) -> float:
        t = self.characteristic_table(limit)
        return 0.0 if t is None else t.height + self.GAP

    def plan(self) -> PageLayout:
        """Measure every block and shrink the lists and the maps until the page holds them.

        The maps, the decision's reasons, the region and the tolerance lists are cut in
        turns; what was cut for nothing (a list beside a taller block) is given back, and
        the spare height goes to the maps as long as that draws the part larger.
        """
        fx = self._fixed_blocks()
        return self._geometry(self._fit(fx), fx)

    def _fixed_blocks(self) -> _FixedBlocks:
        """The blocks the fitting does not cut (the notes only last), and the widths."""
        reg_w = self.CW * 0.56
        regf_w = self.CW - reg_w - 12.0
        stats = stats_table(self.res)
        hist_w = self.CW - 12.0 - stats.width
        regtab = registration_table(self.res, self.chain_floor, regf_w)
        notes = note_lines(self.res, self.chain_floor)
        return _FixedBlocks(stats, regtab, notes, reg_w, regf_w, hist_w)

    def _total(self, s: dict, fx: _FixedBlocks) -> float:
        """Height of the page's content with the sizes ``s``, points."""
        dec, _ = self.decision_lines(s["dec"])
        h = HEADER_H + self.GAP
        h += 8.6 * len(dec) + self.GAP
        h += s["map"] + colorbar_height(self) + self.GAP
        if s["mid"]:
            h += max(fx.stats.height, 160.0) + self.GAP
        else:  # its note instead
            h += notes_height([(MID_LEFT_OUT, True)], self.CW)
        h += self.tolerance_table(s["tol"]).height + self.GAP
        h += self._chr_height(s["chr"])
        h += max(self.region_table(s["reg"], fx.reg_w).height, fx.regtab.height) + self.GAP
        h += notes_height(fx.notes, self.CW) + 34.0  # sign-off and footer
        return h

    def _fit(self, fx: _FixedBlocks) -> dict:
        """The sizes that fit the page: ``"map"`` (height, points) and the rows listed of
        ``"dec"``, ``"reg"``, ``"tol"``, ``"chr"``; cuts ``fx.notes`` when nothing else
        can give."""
        res = self.res
        avail = self.H - 2 * self.MT
        n_chr_fail = not_passing_characteristics(res)
        full = {
            "map": MAP_MAX_PT,
            "reg": len(res.acceptance.regions),
            "tol": len(res.zones),
            "dec": min(len(res.decided_by()), 8),
            "chr": len(res.characteristics),
            "mid": 1,
        }
        st = dict(full)
        history = []
        for key, floor, step in shrink_steps(n_chr_fail):
            if key == "mid":  # the notes are cut before the statistics go
                self._cut_notes(st, fx, avail)
            before = st[key]
            while self._total(st, fx) > avail and st[key] - step >= floor - 1e-9:
                st[key] -= step
            if st[key] != before:
                history.append((key, before, step))
        self._cut_notes(st, fx, avail)
        if self._total(st, fx) > avail:
            log.warning("report content exceeds the page by %.0f pt", self._total(st, fx) - avail)
        self._grow_back(st, fx, avail, history)
        # leftover height goes to the maps, but no more than makes them larger: a picture
        # whose width limits the part gains nothing from height
        spare = avail - self._total(st, fx)
        if spare > 0:
            st["map"] = min(MAP_MAX_PT, st["map"] + spare)

        def score(mh: float) -> float:
            return layout_score(self, map_boxes(self, Box(0.0, 0.0, self.CW, mh)))

        best = score(st["map"])
        while st["map"] - 5.0 >= MAP_MIN_PT and score(st["map"] - 5.0) >= best - 0.01:
            st["map"] -= 5.0
        self._grow_back(st, fx, avail, [(k, full[k], 1) for k in ("dec", "tol", "chr", "reg")])
        return st

    def _cut_notes(self, st: dict, fx: _FixedBlocks, avail: float) -> None:
        """Cut the notes (``fx.notes``) to the room left above the sign-off, if need be."""
        if self._total(st, fx) > avail:
            over = self._total(st, fx) - avail
            fx.notes = fit_notes(fx.notes, self.CW, notes_height(fx.notes, self.CW) - over)

    def _grow_back(
        self, st: dict, fx: _FixedBlocks, avail: float, history: list[tuple[str, float, float]]
    ) -> None:
        """Undo what was cut for nothing (a list beside a taller block), last cut first:
        ``history`` holds (key, size before, step); the maps are not grown here."""
        for key, before, step in reversed(history):
            if key == "map":
                continue
            while st[key] + step <= before + 1e-9:
                st[key] += step
                if self._total(st, fx) > avail:
                    st[key] -= step
                    break

    def _geometry(self, st: dict, fx: _FixedBlocks) -> PageLayout:
        """The blocks' boxes, top down, for the sizes ``st`` (:meth:`_fit`)."""
        res = self.res
        x0, y = self.M, self.H - self.MT
        blocks: dict = {}
        blocks["header"] = Box(x0, y - HEADER_H, self.CW, HEADER_H)
        y -= HEADER_H + self.GAP
        dec_lines, n_dec_shown = self.decision_lines(st["dec"])
        blocks["decision"] = (
            Box(x0, y - 8.6 * len(dec_lines), self.CW, 8.6 * len(dec_lines)),
            dec_lines,
        )
        y -= 8.6 * len(dec_lines) + self.GAP
        mh = st["map"]
        maps = map_boxes(self, Box(x0, y - mh, self.CW, mh))
        y -= mh
        cb = Box(x0, y - colorbar_height(self), self.CW, colorbar_height(self))
        y -= colorbar_height(self) + self.GAP
        hist = None
        if st["mid"]:
            mid_h = max(fx.stats.height, 160.0)
            hist = Box(x0, y - mid_h, fx.hist_w, mid_h)
            blocks["stats"] = (
                Box(x0 + fx.hist_w + 12.0, y - mid_h, fx.stats.width, mid_h),
                fx.stats,
            )
            y -= mid_h + self.GAP
        else:  # the items that do not pass took the room: say where the statistics are
            fx.notes.insert(0, (MID_LEFT_OUT, True))
        tol = self.tolerance_table(st["tol"])
        blocks["tolerances"] = (Box(x0, y - tol.height, self.CW, tol.height), tol)
        y -= tol.height + self.GAP
        chars = self.characteristic_table(st["chr"])
        if chars is not None:
            blocks["characteristics"] = (Box(x0, y - chars.height, self.CW, chars.height), chars)
            y -= chars.height + self.GAP
        regt = self.region_table(st["reg"], fx.reg_w)
        regtab = fx.regtab
        bottom_h = max(regt.height, regtab.height)
        blocks["regions"] = (Box(x0, y - regt.height, fx.reg_w, regt.height), regt)
        blocks["registration"] = (
            Box(x0 + fx.reg_w + 12.0, y - regtab.height, fx.regf_w, regtab.height),
            regtab,
        )
        y -= bottom_h + self.GAP
        blocks["notes"] = (y, fx.notes)
        return PageLayout(
            page=self.page,
            width=self.W,
            height=self.H,
            views=self.views,
            maps=maps,
            colorbar=cb,
            histogram=hist,
            regions_listed=min(st["reg"], len(res.acceptance.regions)),
            tolerances_listed=len(pick_tolerances(res, st["tol"])),
            reasons_listed=n_dec_shown,
            scale=self.scale,
            blocks=blocks,
        )

    def draw(
        self, path: Path, lay: PageLayout, views: list[RenderedView], calls: list[Callout]
    ) -> None:
        """Write the page laid out as ``lay``, with the rendered ``views`` and the deviation
        ``calls`` on them, to ``path``."""
        res, prov = self.res, self.prov
        c = self.new_canvas(path)
        c.setTitle(f"Surface deviation report: {prov.part_name}")
        c.setAuthor(prov.author or prov.organization or "qifreport")
        c.setSubject(
            f"{res.verdict}; nominal SHA-256 {prov.nominal_sha256}; scan SHA-256 {prov.scan_sha256}"
        )
        c.setCreator(f"qifreport {__version__}")
        c.setKeywords(["qifreport", "QIF 3.0", "surface profile", "virtual fixture"])
        c.setFont(FONT, 7)
        b = lay.blocks
        draw_header(c, self, b["header"])
        draw_decision(c, *b["decision"])
        draw_maps(c, lay.maps, views, lay.regions_listed, calls)
        draw_colorbar(c, self, lay.colorbar)
        if lay.histogram is not None:
            draw_histogram(c, self, lay.histogram)
            box, t = b["stats"]
            draw_table(c, box.x, box.top, t)
        for key in ("tolerances", "characteristics", "regions", "registration"):
            if key not in b:
                continue
            box, t = b[key]
            draw_table(c, box.x, box.top, t)
        draw_notes_footer(c, self, *b["notes"])
        c.showPage()
        c.save()


# ----------------------------------------------------------------------------- public API


def plan_layout(
    res: InspectionResult, prov: Provenance, *, page: str = "A4", chain_floor: float | None = None
) -> PageLayout:
    """Where :func:`write_pdf` puts everything for this result (no rendering, no file).

    Deterministic: :func:`write_pdf` uses exactly this layout. Useful to find the maps on a
    rasterized page (tests) or to know how many regions and tolerances the page lists.
    """
    return _Report(res, prov, page, chain_floor, None).plan()


def _picture_sizes(lay: PageLayout) -> list[tuple[int, int]]:
    """The pixel size ``(width, height)`` of each map picture (:data:`MAP_DPI`)."""
    px_per_pt = MAP_DPI / 72.0
    return [
        (max(16, int(round(b.w * px_per_pt))), max(16, int(round(b.h * px_per_pt))))
        for b in lay.maps
    ]


def map_points(res: InspectionResult, lay: PageLayout, k: int, X: np.ndarray) -> np.ndarray:
    """Where points of the registered nominal fall on the page, in map ``k`` (0 = A).

    Parameters
    ----------
    res : the inspection result.  lay : its layout (:func:`plan_layout`).
    k : the map.  X : (m, 3) points, mm, in the registered nominal's frame.

    Returns
    -------
    (m, 2) page coordinates, points, origin at the bottom-left corner of the page (no
    visibility test: a point may be hidden in that view, or outside the picture).
    """
    box = lay.maps[k]
    w, h = _picture_sizes(lay)[k]
    px = picture_points(res.V_registered, lay.views[k], (w, h), X, margin=map_margins(box))
    return np.c_[box.x + px[:, 0] * box.w / w, box.top - px[:, 1] * box.h / h]


def write_pdf(
    path: Path,
    res: InspectionResult,
    prov: Provenance,
    *,
    page: str = "A4",
    chain_floor: float | None = None,
    qif_name: str | None = None,
    backend: str | None = None,
) -> None:
    """Write the one-page PDF report of an inspection.

    Parameters
    ----------
    path : the PDF to write (the caller makes it atomic).
    res : the inspection result.  prov : its provenance (as written to the QIF file).
    page : ``"A4"`` or ``"Letter"`` (case-insensitive).
    chain_floor : measured chain floor of this part and scanner, mm (the pipeline's own
        minimum error, paper Section 9), or None: printed as "not measured".
    qif_name : the QIF results file named in the footer; default ``<part_name>.qif`` (the
        name ``qifreport`` gives it); ``""`` names none (no QIF written).
    backend : renderer of the maps (:func:`qifreport.reports.render.render_views`), default
        VTK with a matplotlib fallback.
    """
    write_report(
        path, res, prov, page=page, chain_floor=chain_floor, qif_name=qif_name, backend=backend
    )


def write_report(
    path: Path,
    res: InspectionResult,
    prov: Provenance,
    *,
    page: str = "A4",
    chain_floor: float | None = None,
    qif_name: str | None = None,
    backend: str | None = None,
) -> dict[str, float]:
    """:func:`write_pdf`, returning the seconds spent: ``layout`` (measuring the page and
    choosing the views), ``render`` (the map pictures) and ``draw`` (writing the PDF)."""
    t0 = time.perf_counter()
    path = Path(path)
    if qif_name is None:  # not from ``path``: the caller writes through a temp file
        qif_name = f"{prov.part_name}.qif"
    rep = _Report(res, prov, page, chain_floor, qif_name or None)
    lay = rep.plan()
    calls = callouts(res, lay.regions_listed)
    t1 = time.perf_counter()
    views = render_views(
        res.V_registered,
        res.F,
        res.deviation,
        rep.lower,
        rep.upper,
        res.acceptance.regions,
        size=_picture_sizes(lay),
        views=lay.views,
        scale=lay.scale,
        backend=backend,
        margin=[map_margins(b) for b in lay.maps],
        markers=clamp_markers(res),
        points=[(cl.key, cl.position) for cl in calls],
    )
    t2 = time.perf_counter()
    rep.draw(path, lay, views, calls)
    t3 = time.perf_counter()
    log.info(
        "PDF report %s: layout %.2f s, maps %.2f s (%s), drawing %.2f s",
        path.name,
        t1 - t0,
        t2 - t1,
        views[0].backend if views else "-",
        t3 - t2,
    )
    return {"layout": t1 - t0, "render": t2 - t1, "draw": t3 - t2}
