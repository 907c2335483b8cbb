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
   directions (:mod:`qifreport.reports.render`), green inside the band, red proud / blue sunk outside,
   grey unscored, out-of-tolerance regions outlined and numbered as in the region table;
   the colour bar (mm, symmetric about 0) marks each distinct band.
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
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qifreport import __version__
from qifreport.metrology.inspection import InspectionResult, method_label
from qifreport.metrology.statistics import DeviationStats
from qifreport.qif.writer import Provenance, profile_value

from .render import (
    GREY,
    OUTLINE,
    RenderedView,
    ViewSpec,
    camera_frame,
    choose_views,
    color_scale,
    deviation_colors,
    render_views,
)

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

log = logging.getLogger(__name__)

FONT, FONT_BOLD = "DejaVuSans", "DejaVuSans-Bold"
#: page sizes, points (1/72 in)
PAGE_SIZES = {"A4": (595.2756, 841.8898), "LETTER": (612.0, 792.0)}
#: resolution of the map pictures, dots per inch of the page
MAP_DPI = 200
#: largest height of the map block (pictures and their captions), points
MAP_MAX_PT = 330.0
DASH = "\u2014"  # printed for a value that does not exist (NaN)
#: colours (RGB 0..1)
INK = (0.08, 0.08, 0.08)
MUTED = (0.38, 0.38, 0.38)
RULE = (0.72, 0.72, 0.72)
HEAD_BG = (0.90, 0.91, 0.93)
ZEBRA = (0.965, 0.965, 0.97)
PASS_BG = (0.11, 0.49, 0.20)
FAIL_BG = (0.78, 0.11, 0.11)
UNSURE_BG = (0.80, 0.45, 0.05)
FAIL_INK = (0.70, 0.05, 0.05)
#: SHA-256 digits printed (the QIF carries the full digests)
SHA_DIGITS = 16

_fonts_registered = False


# ---------------------------------------------------------------------------- formatting


def _finite(x) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def fmt_mm(x: float | None) -> str:
    """A length or unsigned deviation in mm, 3 decimals (``"0.399"``); NaN prints a dash."""
    return f"{float(x):.3f}" if _finite(x) else DASH


def fmt_smm(x: float | None) -> str:
    """A signed deviation in mm, 3 decimals with its sign (``"+0.896"``, ``"-2.259"``)."""
    if not _finite(x):
        return DASH
    s = f"{float(x):+.3f}"
    return s.replace("-", "+") if float(s) == 0.0 else s


def fmt_area(x: float | None) -> str:
    """An area in mm^2, 1 decimal (``"183.9"``)."""
    return f"{float(x):.1f}" if _finite(x) else DASH


def fmt_pct(f: float | None) -> str:
    """A fraction 0..1 as a percentage with 2 decimals, without the sign (``"76.21"``)."""
    return f"{100.0 * float(f):.2f}" if _finite(f) else DASH


def _fmt_band(v: float) -> str:
    """A band limit for labels: shortest of up to 3 decimals, signed (``"+0.25"``)."""
    s = f"{v:+.3f}".rstrip("0").rstrip(".")
    return "0" if float(s) == 0.0 else s


def _fmt1(x: float) -> str:
    """A coordinate in mm, 1 decimal, never ``-0.0``."""
    s = f"{float(x):.1f}"
    return "0.0" if s == "-0.0" else s


def _short(sha: str) -> str:
    return sha[:SHA_DIGITS] if sha else DASH


def _utc(t: datetime | None) -> str:
    if t is None:
        return DASH
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return t.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def _display(s: str) -> str:
    """Library text for print: ``mm^2`` as mm\u00b2."""
    return s.replace("mm^2", "mm\u00b2")


# ---------------------------------------------------------------------------------- fonts


def _register_fonts() -> None:
    """Register DejaVu Sans (regular, bold) from matplotlib's bundled fonts (embedded)."""
    global _fonts_registered
    if _fonts_registered:
        return
    import matplotlib
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont

    d = Path(matplotlib.get_data_path()) / "fonts" / "ttf"
    pdfmetrics.registerFont(TTFont(FONT, str(d / "DejaVuSans.ttf")))
    pdfmetrics.registerFont(TTFont(FONT_BOLD, str(d / "DejaVuSans-Bold.ttf")))
    _fonts_registered = True


def _width(text: str, size: float, bold: bool = False) -> float:
    from reportlab.pdfbase.pdfmetrics import stringWidth

    return stringWidth(text, FONT_BOLD if bold else FONT, size)


def _fit(text: str, width: float, size: float, bold: bool = False) -> str:
    """``text`` cut with an ellipsis to fit ``width`` points."""
    if _width(text, size, bold) <= width:
        return text
    lo, hi = 0, len(text)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _width(text[:mid].rstrip() + "\u2026", size, bold) <= width:
            lo = mid
        else:
            hi = mid - 1
    return text[:lo].rstrip() + "\u2026"


def _wrap(text: str, width: float, size: float, bold: bool = False) -> list[str]:
    from reportlab.lib.utils import simpleSplit

    return simpleSplit(text, FONT_BOLD if bold else FONT, size, width) or [""]


# --------------------------------------------------------------------------------- layout


@dataclass
class Box:
    """A rectangle on the page, points, origin at the bottom-left corner of the page."""

    x: float
    y: float
    w: float
    h: float

    @property
    def top(self) -> float:
        return self.y + self.h


@dataclass
class _Table:
    """A one-line-per-row table drawn with canvas primitives."""

    columns: list[tuple[str, float, str]]  # heading, width (pt), align "l"/"r"/"c"
    rows: list[list[str]]
    size: float = 6.8
    row_h: float = 8.6
    head_h: float = 10.0
    title: str = ""
    note: str = ""  # a last, full-width line (e.g. "+ 12 more ... see QIF")
    emphasis: list[bool] = field(default_factory=list)  # per row: print in the fail colour
    section_rows: set[int] = field(default_factory=set)  # rows that are sub-headings

    def __post_init__(self) -> None:
        if self.head_h > 0 and any("\n" in c[0] for c in self.columns):
            self.head_h = 17.0

    @property
    def height(self) -> float:
        return ((11.0 if self.title else 0.0) + self.head_h + self.row_h * len(self.rows)
                + (self.row_h if self.note else 0.0))

    @property
    def width(self) -> float:
        return sum(c[1] for c in self.columns)


@dataclass
class PageLayout:
    """Where everything goes on the page (points, origin bottom-left).

    Attributes
    ----------
    page : ``"A4"`` or ``"LETTER"``.  width, height : page size, points.
    views : the chosen camera directions, in the order of ``maps``.
    maps : one box per view (the picture).
    colorbar : the colour bar block.  histogram : the histogram block.
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
    histogram: Box
    regions_listed: int
    tolerances_listed: int
    reasons_listed: int
    scale: float
    blocks: dict = field(default_factory=dict, repr=False)  # internal: what the drawer uses


def _page_size(page: str) -> tuple[str, tuple[float, float]]:
    key = str(page).strip().upper()
    if key not in PAGE_SIZES:
        raise ValueError(f"page must be 'A4' or 'Letter', got {page!r}")
    return key, PAGE_SIZES[key]


def _bands(res: InspectionResult) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex band (lower, upper) of the combined map, mm."""
    n = len(res.V)
    if res.bands is not None:
        return np.asarray(res.bands.lower, float), np.asarray(res.bands.upper, float)
    tol = np.broadcast_to(np.asarray(res.acceptance.tolerance, dtype=float), (n,))
    return -tol, tol.copy()


def _distinct_bands(res: InspectionResult) -> list[tuple[float, float, list[str]]]:
    """Distinct bands ``(lower, upper, zone keys)`` in zone order."""
    out: list[tuple[float, float, list[str]]] = []
    for z in res.zones:
        for b in out:
            if math.isclose(b[0], z.zone.lower, abs_tol=1e-9) and math.isclose(
                    b[1], z.zone.upper, abs_tol=1e-9):
                b[2].append(z.zone.key)
                break
        else:
            out.append((z.zone.lower, z.zone.upper, [z.zone.key]))
    if not out:
        lo, hi = _bands(res)
        out.append((float(np.nanmin(lo)), float(np.nanmax(hi)), ["part"]))
    return out


def _vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric vertex areas, mm^2 (the weights of the statistics)."""
    a = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    out = np.zeros(len(V))
    for k in range(3):
        np.add.at(out, F[:, k], a / 3.0)
    return out


def _criteria(res: InspectionResult) -> tuple[list[str], list[str], list[str]]:
    """Who failed the area criterion, the region criterion, and who had nothing scored."""
    area, region, empty = [], [], []
    items = [("whole part", res.acceptance)] + [(z.zone.key, z.acceptance) for z in res.zones]
    for name, acc in items:
        if not acc.scored_area > 0:
            empty.append(name)
            continue
        if not acc.area_ok:
            area.append(name)
        if not acc.region_ok:
            region.append(name)
    return area, region, empty


def _names(names: list[str], limit: int = 4) -> str:
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit]) + f" +{len(names) - limit} more"


# ----------------------------------------------------------------------------- the blocks


class _Report:
    """Measures and draws the page for one result."""

    GAP = 7.0

    def __init__(self, res: InspectionResult, prov: Provenance, page: str,
                 chain_floor: float | None, qif_name: str | None):
        _register_fonts()
        self.res, self.prov = res, prov
        self.page, (self.W, self.H) = _page_size(page)
        self.M = 28.0 if self.page == "A4" else 30.0  # side margin
        self.MT = 26.0  # top/bottom margin
        self.CW = self.W - 2 * self.M  # content width
        self.chain_floor = chain_floor
        self.qif_name = qif_name
        self.lower, self.upper = _bands(res)
        self.scale = color_scale(res.deviation, self.lower, self.upper)
        self.bands = _distinct_bands(res)
        self.views = choose_views(res.V_registered, res.F, res.deviation,
                                  res.acceptance.regions, n_views=3)
        Vr = np.asarray(res.V_registered, dtype=float)
        self.spans = []
        for v in self.views:
            r, u, _ = camera_frame(v)
            self.spans.append((max(float(np.ptp(Vr @ r)), 1e-6),
                               max(float(np.ptp(Vr @ u)), 1e-6)))

    # ------------------------------------------------------------------ content (strings)

    def verdict_lines(self, width: float = 1e9, size: float = 6.8) -> list[str]:
        """Which criteria decided the verdict, for whom (names cut to fit ``width``)."""
        res = self.res
        area, region, empty = _criteria(res)
        if res.passed:
            n = len(res.zones)
            if res.verdict != "PASS":
                return ["criteria met, but the registration", "cannot be trusted (warnings below)"]
            return [f"whole part and {n} tolerance{'s' if n != 1 else ''}:",
                    "area and region criteria met"]

        def line(head: str, names: list[str]) -> str:
            for limit in range(4, 0, -1):
                s = f"{head}: {_names(names, limit)}"
                if _width(s, size) <= width:
                    return s
            return s

        out = []
        if area:
            out.append(line("area criterion", area))
        if region:
            out.append(line("region criterion", region))
        if empty:
            out.append(line("nothing scored", empty))
        if res.added is not None and not res.added.passed:
            out.append(f"added material: {res.added.largest_area:.0f} mm\u00b2 proud")
        return out

    def rule_text(self) -> str:
        p = self.res.params
        return (f"Acceptance rule (whole part and each tolerance on its own faces): at least "
                f"{100 * p.min_fraction:g} % of the scored area inside the band (area "
                f"criterion) and no connected out-of-tolerance region larger than "
                f"{p.max_region_area:g} mm\u00b2 (region criterion).")

    def reasons(self) -> list[str]:
        return [_display(s) for s in self.res.decided_by()]

    #: per-tolerance columns in the statistics table (beyond that, the tolerance table)
    MAX_ZONE_COLUMNS = 3

    def stats_table(self) -> _Table:
        """Whole part (vertices, area-weighted), scan points (data-referenced) and, for two
        or three tolerances, each tolerance on its own faces."""
        res = self.res
        v, p, a = res.vertex_stats, res.point_stats, res.acceptance
        zones = res.zones if 2 <= len(res.zones) <= self.MAX_ZONE_COLUMNS else []
        cols_stats: list[DeviationStats] = [v, p] + [z.stats for z in zones]
        accs = [a, None] + [z.acceptance for z in zones]

        def row(label: str, f) -> list[str]:
            return [label] + [f(s) for s in cols_stats]

        def acc_row(label: str, f) -> list[str]:
            return [label] + [DASH if x is None else f(x) for x in accs]

        ceiling = (res.scan_area / a.nominal_area if a.nominal_area > 0 else math.nan)
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
            ["Ceiling scanned/nominal, %", fmt_pct(ceiling),
             "ok" if res.coverage_ceiling_ok else "EXCEEDED"] + [DASH] * len(zones),
        ]
        emph = [False] * len(rows)
        emph[12] = not a.area_ok or any(not z.acceptance.area_ok for z in zones)
        emph[-1] = not res.coverage_ceiling_ok
        w_val = 56.0 if not zones else 44.0
        columns = [("Statistic", 122.0 if not zones else 114.0, "l"),
                   ("Vertices\n(area-weighted)" if not zones else "Part\nvertices", w_val, "r"),
                   ("Scan points\n(data-ref.)" if not zones else "Scan\npoints", w_val, "r")]
        columns += [(f"{_fit(z.zone.key, w_val - 4, 6.8, True)}\nown faces", w_val, "r")
                    for z in zones]
        if not zones:  # two value columns: use the width they are given
            columns = [(h, w * 1.18, al) for h, w, al in columns]
        title = "Statistics of the signed deviation"
        if len(res.zones) > self.MAX_ZONE_COLUMNS:
            title = "Statistics, whole part (per tolerance: table below)"
        elif not zones:
            title += " (whole part)"
        return _Table(columns=columns, rows=rows, title=title, emphasis=emph)

    def tolerance_table(self, limit: int) -> _Table:
        res = self.res
        cols = [("Key", 30), ("Tolerance", 152), ("Band, mm", 58), ("Result", 30),
                ("In band,\n%", 38), ("Regions /\nlargest, mm\u00b2", 60), ("Profile,\nmm", 34),
                ("RMS,\nmm", 32), ("P99.9,\nmm", 34), ("Max,\nmm", 35), ("Min,\nmm", 35)]
        scale = self.CW / sum(c[1] for c in cols)
        cols = [(h, w * scale, "l" if i < 3 else ("c" if i == 3 else "r"))
                for i, (h, w) in enumerate(cols)]
        zones = res.zones
        shown = self._pick_tolerances(limit)
        rows, emph = [], []
        untrusted = not res.established  # a zone's criteria met: "n/e", not PASS
        for i in shown:
            z = zones[i]
            zone, acc, s = z.zone, z.acceptance, z.stats
            desc = zone.describe()
            cut = desc.find(" [")
            if cut > 0:  # the band has its own column
                desc = desc[:cut] + desc[desc.find("]", cut) + 1:]
            if not z.fixtured:
                desc += ", free state"
            status = ("n/a" if not acc.scored_area > 0 else "FAIL" if not acc.passed
                      else "PASS" if not untrusted else "n/e")
            nreg = len(acc.regions)
            rows.append([
                zone.key, _fit(desc, cols[1][1] - 4, 6.8),
                f"[{_fmt_band(zone.lower)}, {_fmt_band(zone.upper)}]", status,
                fmt_pct(acc.in_tolerance_fraction),
                f"{nreg} / {fmt_area(acc.largest_region_area)}" if nreg else "0",
                fmt_mm(profile_value(z)), fmt_mm(s.rms), fmt_mm(s.p999), fmt_smm(s.max_pos),
                fmt_smm(s.min_neg)])
            emph.append(not acc.passed)
        note = ""
        rest = [i for i in range(len(zones)) if i not in set(shown)]
        if rest:
            nf = sum(1 for i in rest if not zones[i].acceptance.passed)
            keys = _names([zones[i].zone.key for i in rest], 8)
            note = (f"+ {len(rest)} more tolerance{'s' if len(rest) != 1 else ''} not listed "
                    f"({nf} FAIL, {len(rest) - nf} PASS): {keys} \u2014 every tolerance is in "
                    "the QIF file")
        if untrusted:
            note = ("n/e = criteria met, not established (registration not trusted; see the "
                    "warning). " + note).strip()
        return _Table(columns=cols, rows=rows, note=note, emphasis=emph,
                      title=f"Tolerances ({len(zones)}), each on its own faces; profile = "
                            "width of the smallest zone about the band centre holding all "
                            "points")

    def _pick_tolerances(self, limit: int) -> list[int]:
        """Indices of the tolerances to list: failing ones first, then in file order."""
        zones = self.res.zones
        if len(zones) <= limit:
            return list(range(len(zones)))
        fail = [i for i, z in enumerate(zones) if not z.acceptance.passed]
        ok = [i for i, z in enumerate(zones) if z.acceptance.passed]
        return sorted((fail + ok)[:max(limit, 0)])

    def region_table(self, limit: int, width: float) -> _Table:
        acc = self.res.acceptance
        cols = [("#", 16), ("Area, mm\u00b2", 46), ("Peak, mm", 44), ("Kind", 34),
                ("Centroid x, y, z, mm", 118), ("Criterion", 42)]
        scale = width / sum(c[1] for c in cols)
        cols = [(h, w * scale, "r" if i in (0, 1, 2) else ("l" if i in (3, 4) else "c"))
                for i, (h, w) in enumerate(cols)]
        regs = acc.regions
        rows, emph = [], []
        for k, r in enumerate(regs[:limit], start=1):
            c = r.centroid
            over = r.area > acc.max_region_area
            rows.append([str(k), fmt_area(r.area), fmt_smm(r.peak),
                         "proud" if r.sign > 0 else "sunk",
                         ", ".join(_fmt1(v) for v in c[:3]),
                         "> limit" if over else "ok"])
            emph.append(over)
        note = ""
        if len(regs) > limit:
            rest = regs[limit:]
            nover = sum(1 for r in rest if r.area > acc.max_region_area)
            note = (f"+ {len(rest)} more regions ({fmt_area(sum(r.area for r in rest))} mm\u00b2 "
                    f"in all, {nover} above the limit), see QIF")
        if not regs:
            rows = [["", "none", "", "", "no vertex outside its band", ""]]
            emph = [False]
        title = (f"Out-of-tolerance regions, whole part ({len(regs)}; limit "
                 f"{acc.max_region_area:g} mm\u00b2)")
        return _Table(columns=cols, rows=rows, note=note, emphasis=emph, title=title)

    def registration_table(self, width: float) -> _Table:
        res = self.res
        rg, fit = res.rigid, res.fit
        R = np.asarray(rg.R, dtype=float)
        angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))
        t = np.asarray(rg.t, dtype=float)
        rows: list[list[str]] = [
            ["Pose search: starts agreeing", _pose_text(res.prealign)],
            ["Rigid residual RMS, mm", fmt_mm(rg.rms)],
            ["Rigid inliers, % / iterations", f"{fmt_pct(rg.inlier_fraction)} / {rg.iterations}"],
            ["Rigid rotation, deg / shift, mm", f"{angle:.3f} / {np.linalg.norm(t):.3f}"],
        ]
        if fit is None:
            rows.append(["Non-rigid (virtual fixture)", "none: rigid only"])
        else:
            fp = fit.params
            rows += [
                ["Virtual fixture method", method_label(fit.method)],
                ["Non-rigid residual (robust), mm", fmt_mm(fit.scale)],
                ["Iterations / passes / fallback",
                 f"{fit.iterations} / {fit.passes} / {'YES' if fit.fallback else 'no'}"],
            ]
            if fit.method == "gbcicp":
                rows.append(["Flagged as defect candidates, %", fmt_pct(fit.flagged_fraction)])
            rows.append(["Max fixture displacement, mm",
                         fmt_mm(float(np.linalg.norm(fit.e, axis=1).max()))
                         if len(fit.e) else DASH])
            if fit.method == "gbcicp":
                rows += [
                    ["Energy; band limits l1, l2, mm",
                     f"{res.params.energy}; {_num(fp.band_limit)}, "
                     f"{_num(fp.band_limit_refit)}"],
                    ["Start length; coverage radius, mm",
                     f"{_num(fp.band_limit_start)}; {_num(fp.coverage_radius)}"],
                ]
            else:
                rows.append([f"{method_label(fit.method)} parameters", _params_text(fp)])
        rows.append(["Chain floor, mm",
                     fmt_mm(self.chain_floor) if self.chain_floor is not None
                     else "not measured"])
        rows.append(["Vertices / triangles / points",
                     f"{len(res.V)} / {len(res.F)} / {len(res.P)}"])
        w2 = width * 0.42
        emph = [False] * len(rows)
        for k, row in enumerate(rows):
            emph[k] = bool((row[0] == "Iterations / passes / fallback" and fit is not None
                            and fit.fallback)
                           or (row[0].startswith("Pose") and res.prealign is not None
                               and (res.prealign.ambiguous
                                    or res.prealign.weakly_constrained)))
        title = (f"Registration: rigid ICP + virtual fixture ({method_label(fit.method)})"
                 if fit is not None else "Registration: rigid ICP only (free state)")
        return _Table(columns=[("", width - w2, "l"), ("", w2, "r")], rows=rows,
                      title=title, head_h=0.0, emphasis=emph)

    def notes(self) -> list[tuple[str, bool]]:
        """(text, warning) lines below the tables."""
        res = self.res
        out: list[tuple[str, bool]] = []
        rep = res.repeatability
        if rep is not None:
            out.append((f"{rep.describe()}. Only persistent regions are findings (listed, "
                        "outlined and judged); each resampling keeps every scan point with "
                        f"probability {rep.keep_fraction:g} (seeds 0 to {rep.seeds - 1}).",
                        False))
        ne = res.not_evaluated
        if ne:
            items = [f"{n.kind} \u201c{n.name}\u201d" + (f" #{n.step_id}" if n.step_id else "")
                     for n in ne]
            head = ", ".join(items[:6]) + (f" and {len(items) - 6} more" if len(items) > 6
                                            else "")
            reasons = sorted({n.reason.split(":")[0] for n in ne})
            out.append((f"PMI not scored ({len(ne)}): {head} \u2014 "
                        f"{'; '.join(reasons)[:160]} (each listed with its reason in the QIF).",
                        False))
        h = res.hygiene
        if h is not None and (h.boundary_edges or h.non_manifold_edges or h.degenerate_faces
                              or h.duplicate_faces):
            out.append((f"Nominal mesh: {h.describe()}.", bool(h.non_manifold_edges
                                                                or h.degenerate_faces
                                                                or h.duplicate_faces)))
        for w in res.trust_warnings():
            tail = (" A pass is therefore not claimed (NOT ESTABLISHED)." if res.passed
                    else "")
            out.append((f"Warning: {w}.{tail}", True))
        a = res.added
        if a is not None and a.regions:
            judged = ("fails the part" if not a.passed
                      else "reported, not judged (--fail-on-added-material)")
            out.append((f"Added material (scan points proud of the nominal, data-referenced): "
                        f"{a.describe()}; P99.9 signed {a.p999_signed:+.3f} mm, "
                        f"{100 * a.frac_above:.3f} % beyond +{a.threshold:g} mm; {judged}.",
                        a.found))
        if self.chain_floor is not None:
            tight = min((z.zone.half_width for z in res.zones), default=math.nan)
            if _finite(tight) and tight <= self.chain_floor:
                out.append((f"Warning: the tightest band half-width {fmt_mm(tight)} mm does not "
                            f"exceed the chain floor {fmt_mm(self.chain_floor)} mm: it cannot "
                            "be verified with this chain.", True))
        return out

    # --------------------------------------------------------------------------- layout

    def header_height(self) -> float:
        return 72.0

    def decision_lines(self, limit: int) -> tuple[list[tuple[str, bool]], int]:
        """Wrapped lines of the decision block (text, bold) and how many reasons it lists."""
        width = self.CW
        lines = [(s, False) for s in _wrap(self.rule_text(), width, 7.0)]
        reasons = self.reasons()
        shown = reasons[:limit]
        for r in shown:
            for j, s in enumerate(_wrap(r, width - 10, 7.0)):
                lines.append((("\u2022 " if j == 0 else "   ") + s, True))
        if len(reasons) > len(shown):
            lines.append((f"+ {len(reasons) - len(shown)} more reason"
                          f"{'s' if len(reasons) - len(shown) != 1 else ''}: see the QIF file "
                          "(decided_by attributes)", False))
        return lines, len(shown)

    def colorbar_height(self) -> float:
        rows = min(len(self.bands), 3)
        return 14.0 + 9.0 * rows + 16.0

    def plan(self) -> PageLayout:
        res = self.res
        avail = self.H - 2 * self.MT
        n_reg, n_tol, n_dec = len(res.acceptance.regions), len(res.zones), len(res.decided_by())
        full = {"map": MAP_MAX_PT, "reg": n_reg, "tol": n_tol, "dec": min(n_dec, 8)}
        st = dict(full)
        reg_w = self.CW * 0.56
        regf_w = self.CW - reg_w - 12.0
        stats = self.stats_table()
        hist_w = self.CW - 12.0 - stats.width
        regtab = self.registration_table(regf_w)
        notes = self.notes()

        def note_h() -> float:
            return sum(8.2 * len(_wrap(t, self.CW, 6.8, w)) for t, w in notes) + 2.0

        def total(s: dict) -> float:
            dec, _ = self.decision_lines(s["dec"])
            h = self.header_height() + self.GAP
            h += 8.6 * len(dec) + self.GAP
            h += s["map"] + self.colorbar_height() + self.GAP
            h += max(stats.height, 160.0) + self.GAP
            h += self.tolerance_table(s["tol"]).height + self.GAP
            h += max(self.region_table(s["reg"], reg_w).height, regtab.height) + self.GAP
            h += note_h() + 34.0  # sign-off and footer
            return h

        steps = [("map", 240.0, 5.0), ("dec", 6, 1), ("reg", 12, 1), ("tol", 10, 1),
                 ("map", 210.0, 5.0), ("dec", 3, 1), ("reg", 8, 1), ("tol", 6, 1),
                 ("map", 180.0, 5.0), ("reg", 5, 1), ("tol", 4, 1), ("dec", 2, 1),
                 ("map", 140.0, 5.0), ("reg", 2, 1), ("tol", 2, 1), ("dec", 1, 1),
                 ("map", 110.0, 5.0)]
        history = []
        for key, floor, step in steps:
            before = st[key]
            while total(st) > avail and st[key] - step >= floor - 1e-9:
                st[key] -= step
            if st[key] != before:
                history.append((key, before, step))
        if total(st) > avail:
            log.warning("report content exceeds the page by %.0f pt", total(st) - avail)

        def grow_back() -> None:
            # undo what was cut for nothing (a list beside a taller block), last cut first
            for key, before, step in reversed(history):
                if key == "map":
                    continue
                while st[key] + step <= before + 1e-9:
                    st[key] += step
                    if total(st) > avail:
                        st[key] -= step
                        break

        grow_back()
        # leftover height goes to the maps, but no more than makes them larger: a picture
        # whose width limits the part gains nothing from height
        spare = avail - total(st)
        if spare > 0:
            st["map"] = min(MAP_MAX_PT, st["map"] + spare)

        def score(mh: float) -> float:
            return self._layout_score(self._map_boxes(Box(0.0, 0.0, self.CW, mh)))

        best = score(st["map"])
        while st["map"] - 5.0 >= 110.0 and score(st["map"] - 5.0) >= best - 0.01:
            st["map"] -= 5.0
        history = [(k, full[k], 1) for k in ("dec", "tol", "reg")]
        grow_back()

        # -- geometry, top down
        x0, y = self.M, self.H - self.MT
        blocks: dict = {}
        blocks["header"] = Box(x0, y - self.header_height(), self.CW, self.header_height())
        y -= self.header_height() + self.GAP
        dec_lines, n_dec_shown = self.decision_lines(st["dec"])
        blocks["decision"] = (Box(x0, y - 8.6 * len(dec_lines), self.CW, 8.6 * len(dec_lines)),
                              dec_lines)
        y -= 8.6 * len(dec_lines) + self.GAP
        mh = st["map"]
        maps = self._map_boxes(Box(x0, y - mh, self.CW, mh))
        y -= mh
        cb = Box(x0, y - self.colorbar_height(), self.CW, self.colorbar_height())
        y -= self.colorbar_height() + self.GAP
        mid_h = max(stats.height, 160.0)
        hist = Box(x0, y - mid_h, hist_w, mid_h)
        blocks["stats"] = (Box(x0 + hist_w + 12.0, y - mid_h, stats.width, mid_h), stats)
        y -= mid_h + self.GAP
        tol = self.tolerance_table(st["tol"])
        blocks["tolerances"] = (Box(x0, y - tol.height, self.CW, tol.height), tol)
        y -= tol.height + self.GAP
        regt = self.region_table(st["reg"], reg_w)
        bottom_h = max(regt.height, regtab.height)
        blocks["regions"] = (Box(x0, y - regt.height, reg_w, regt.height), regt)
        blocks["registration"] = (Box(x0 + reg_w + 12.0, y - regtab.height, regf_w,
                                      regtab.height), regtab)
        y -= bottom_h + self.GAP
        blocks["notes"] = (y, notes)
        return PageLayout(page=self.page, width=self.W, height=self.H, views=self.views,
                          maps=maps, colorbar=cb, histogram=hist,
                          regions_listed=min(st["reg"], n_reg), tolerances_listed=len(
                              self._pick_tolerances(st["tol"])),
                          reasons_listed=n_dec_shown, scale=self.scale, blocks=blocks)

    def _map_boxes(self, area: Box) -> list[Box]:
        """The pictures inside ``area`` (a caption above each).

        Three views: one large picture with the other two stacked on its right, or the three
        in a row, whichever draws the part larger (the first view counting double); two
        views side by side.
        """
        n = len(self.views)
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
        stack = [Box(area.x, area.y, w_main, area.h - cap),
                 Box(xs, area.y + h_side + gap + cap, w_side, h_side),
                 Box(xs, area.y, w_side, h_side)]
        return max((stack, row(3)), key=self._layout_score)

    def _layout_score(self, boxes: list[Box]) -> float:
        """Sum of the log drawing scales (pt per mm) of the views, the first counting double."""
        score = 0.0
        for k, (b, (sx, sy)) in enumerate(zip(boxes, self.spans, strict=False)):
            m = self.map_margins(b)
            pt_per_mm = min(b.w * (1 - m[0] - m[1]) / sx, b.h * (1 - m[2] - m[3]) / sy)
            score += (2.0 if k == 0 else 1.0) * math.log(max(pt_per_mm, 1e-9))
        return score

    def map_margins(self, box: Box) -> tuple[float, float, float, float]:
        """Margins of a picture (fractions): room for the axes and scale bar at the bottom."""
        return (0.035, 0.035, 8.0 / box.h, 22.0 / box.h)

    # ---------------------------------------------------------------------------- drawing

    def draw(self, path: Path, lay: PageLayout, views: list[RenderedView]) -> None:
        from reportlab.pdfgen.canvas import Canvas

        res, prov = self.res, self.prov
        # the initial font too: otherwise reportlab references (unembedded) Helvetica
        c = Canvas(str(path), pagesize=(self.W, self.H), pageCompression=1,
                   initialFontName=FONT, initialFontSize=7)
        c.setTitle(f"Surface deviation report: {prov.part_name}")
        c.setAuthor(prov.author or prov.organization or "qifreport")
        c.setSubject(f"{res.verdict}; nominal SHA-256 "
                     f"{prov.nominal_sha256}; scan SHA-256 {prov.scan_sha256}")
        c.setCreator(f"qifreport {__version__}")
        c.setKeywords(["qifreport", "QIF 3.0", "surface profile", "virtual fixture"])
        c.setFont(FONT, 7)
        b = lay.blocks
        self._draw_header(c, b["header"])
        self._draw_decision(c, *b["decision"])
        self._draw_maps(c, lay, views)
        self._draw_colorbar(c, lay.colorbar)
        self._draw_histogram(c, lay.histogram)
        box, t = b["stats"]
        self._draw_table(c, box.x, box.top, t)
        for key in ("tolerances", "regions", "registration"):
            box, t = b[key]
            self._draw_table(c, box.x, box.top, t)
        self._draw_notes_footer(c, *b["notes"])
        c.showPage()
        c.save()

    def _text(self, c: Canvas, x: float, y: float, s: str, size: float = 7.0,
              bold: bool = False, color: tuple[float, float, float] = INK,
              align: str = "l") -> None:
        c.setFillColorRGB(*color)
        c.setFont(FONT_BOLD if bold else FONT, size)
        if align == "r":
            c.drawRightString(x, y, s)
        elif align == "c":
            c.drawCentredString(x, y, s)
        else:
            c.drawString(x, y, s)

    def _draw_header(self, c: Canvas, box: Box) -> None:
        res, prov = self.res, self.prov
        vw = 172.0
        # verdict
        word = res.verdict
        vx = box.x + box.w - vw
        c.setFillColorRGB(*{"PASS": PASS_BG, "FAIL": FAIL_BG}.get(word, UNSURE_BG))
        c.roundRect(vx, box.y, vw, box.h, 4, stroke=0, fill=1)
        if word in ("PASS", "FAIL"):
            self._text(c, vx + vw / 2, box.top - 36, word, 34, True, (1, 1, 1), "c")
        else:  # NOT ESTABLISHED
            self._text(c, vx + vw / 2, box.top - 32, word, 16, True, (1, 1, 1), "c")
        lines = self.verdict_lines(vw - 10, 6.8)
        yy = box.top - 50
        for s in lines[:3]:
            self._text(c, vx + vw / 2, yy, _fit(s, vw - 10, 6.8), 6.8, False, (1, 1, 1), "c")
            yy -= 8.4
        # title
        tw = box.w - vw - 12
        self._text(c, box.x, box.top - 8, "SURFACE DEVIATION REPORT \u2014 VIRTUAL FIXTURE "
                   "INSPECTION", 7.0, True, MUTED)
        self._text(c, box.x, box.top - 24, _fit(prov.part_name, tw, 16, True), 16, True)
        dur = (prov.finished - prov.started).total_seconds() if prov.finished else math.nan
        people = [prov.operator or DASH, f"organization {prov.organization or DASH}"]
        if prov.author:
            people.append(f"author {prov.author}")
        vw_ = tw - 46

        def file_line(path: str, sha: str) -> str:
            tail = f"   SHA-256 {_short(sha)}\u2026"
            return _fit(Path(path).name, vw_ - _width(tail, 7.0), 7.0) + tail

        rows = [
            ("Nominal", file_line(prov.nominal_path, prov.nominal_sha256)),
            ("Scan", file_line(prov.scan_path, prov.scan_sha256)),
            ("Inspected", f"{_utc(prov.started)}" + (f" ({dur:.0f} s)" if _finite(dur) else "")
             + f"   serial number {prov.serial_number or DASH}"),
            ("Operator", "    ".join(people)),
            ("Software", f"qifreport {__version__}; units mm, mm\u00b2, %; deviation along "
                         "the normal, + proud / \u2212 sunk"),
        ]
        yy = box.top - 35
        for k, v in rows:
            self._text(c, box.x, yy, k, 7.0, True, MUTED)
            self._text(c, box.x + 46, yy, _fit(v, vw_, 7.0), 7.0)
            yy -= 8.6
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.6)
        c.line(box.x, box.y - 3, box.x + box.w, box.y - 3)

    def _draw_decision(self, c: Canvas, box: Box, lines) -> None:
        yy = box.top - 6.5
        for s, bold in lines:
            self._text(c, box.x, yy, s, 7.0, False, FAIL_INK if bold else INK)
            yy -= 8.6

    def _draw_maps(self, c: Canvas, lay: PageLayout, views: list[RenderedView]) -> None:
        from PIL import Image
        from reportlab.lib.utils import ImageReader

        n_listed = lay.regions_listed
        for k, (box, v) in enumerate(zip(lay.maps, views, strict=True)):
            img = ImageReader(Image.fromarray(v.image))
            c.drawImage(img, box.x, box.y, box.w, box.h)
            c.setStrokeColorRGB(*RULE)
            c.setLineWidth(0.5)
            c.rect(box.x, box.y, box.w, box.h, stroke=1, fill=0)
            x = box.x
            if k == 0:
                head = ("Deviation map of the registered nominal" if box.w > 280
                        else "Deviation map")
                self._text(c, x, box.top + 3, head, 8, True)
                x += _width(head, 8, True) + 8
            self._text(c, x, box.top + 3, f"{'ABC'[k]}: {v.name}", 7.5, True, MUTED)
            self._draw_axes(c, box, v)
            if not v.name.startswith("oblique"):
                self._draw_scale_bar(c, box, v)
            self._draw_labels(c, box, v, n_listed)

    def _draw_axes(self, c: Canvas, box: Box, v: RenderedView) -> None:
        ox, oy, L = box.x + 12, box.y + 9, 9.0
        c.setLineWidth(0.7)
        c.setStrokeColorRGB(*INK)
        for i, name in enumerate("xyz"):
            dx, dy = v.axes[i]
            n = math.hypot(dx, dy)
            if n < 0.2:  # along the line of sight: the view's name says which way
                continue
            c.line(ox, oy, ox + L * dx, oy + L * dy)
            self._text(c, ox + (L + 4) * dx / max(n, 1e-9) * n - 2, oy + (L + 4) * dy - 2,
                       name, 6.0, True)

    def _draw_scale_bar(self, c: Canvas, box: Box, v: RenderedView) -> None:
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
        self._text(c, x1 - Lp / 2, y1 + 3, f"{length:g} mm", 6.0, False, INK, "c")

    def _draw_labels(self, c: Canvas, box: Box, v: RenderedView, n_listed: int) -> None:
        """Region numbers beside their regions (a leader line to the anchor), never on top of
        the region they name nor of another number."""
        h_px, w_px = v.image.shape[:2]
        sx, sy = box.w / w_px, box.h / h_px
        labels = sorted((lb for lb in v.labels if lb.number <= n_listed),
                        key=lambda lb: lb.number)
        anchors = [(box.x + lb.x * sx, box.top - lb.y * sy) for lb in labels]
        placed: list[tuple[float, float, float]] = []
        for lb, (ax, ay) in zip(labels, anchors, strict=True):
            r = 5.2 if lb.number < 10 else 6.2
            ext = min(lb.extent * sx, 40.0)
            spot = None
            for dist in (ext + r + 3, ext + r + 10, ext + r + 18, r + 3, 2 * r + 12,
                         2 * r + 24):
                for ang in (45, 135, -45, -135, 90, -90, 0, 180, 22, 158, -22, -158):
                    px = ax + dist * math.cos(math.radians(ang))
                    py = ay + dist * math.sin(math.radians(ang))
                    if not (box.x + r + 1 <= px <= box.x + box.w - r - 1
                            and box.y + r + 1 <= py <= box.top - r - 1):
                        continue
                    if any(math.hypot(px - qx, py - qy) < r + qr + 1.5 for qx, qy, qr in placed):
                        continue
                    if any(math.hypot(px - qx, py - qy) < r + 1.0 for qx, qy in anchors):
                        continue
                    spot = (px, py)
                    break
                if spot:
                    break
            if spot is None:
                log.debug("no room for the label of region %d in view %s", lb.number, v.name)
                continue
            px, py = spot
            d = math.hypot(px - ax, py - ay)
            c.setStrokeColorRGB(*INK)
            c.setFillColorRGB(*INK)
            c.setLineWidth(0.6)
            c.line(ax, ay, px - (px - ax) * r / d, py - (py - ay) * r / d)
            c.circle(ax, ay, 1.0, stroke=0, fill=1)
            c.setFillColorRGB(1, 1, 1)
            c.setLineWidth(0.7)
            c.circle(px, py, r, stroke=1, fill=1)
            self._text(c, px, py - 2.3, str(lb.number), 6.3, True, INK, "c")
            placed.append((px, py, r))

    def _draw_colorbar(self, c: Canvas, box: Box) -> None:
        S = self.scale
        bands = self.bands[:3]
        label_w = 118.0
        legend_w = 150.0
        x0 = box.x + label_w
        bw = box.w - label_w - legend_w - 12
        yy = box.top - 12
        self._text(c, box.x, yy + 2, "Colour scale: signed deviation, mm", 7.0, True)
        xs = np.linspace(-S, S, 241)
        mids = 0.5 * (xs[1:] + xs[:-1])

        def xpos(v: float) -> float:
            return x0 + (v + S) / (2 * S) * bw

        row_h = 9.0
        for lo, hi, keys in bands:
            y = yy - row_h
            cols = deviation_colors(mids, lo, hi, S)
            start = 0
            for i in range(1, len(mids) + 1):
                if i == len(mids) or not np.allclose(cols[i], cols[start], atol=1e-3):
                    c.setFillColorRGB(*cols[start])
                    c.rect(xpos(xs[start]), y + 1, xpos(xs[i]) - xpos(xs[start]) + 0.3,
                           row_h - 2, stroke=0, fill=1)
                    start = i
            c.setStrokeColorRGB(*INK)
            c.setLineWidth(0.8)
            for v in (lo, hi):
                c.line(xpos(v), y, xpos(v), y + row_h)
            c.setLineWidth(0.4)
            c.rect(x0, y + 1, bw, row_h - 2, stroke=1, fill=0)
            self._text(c, x0 - 4, y + 2.4,
                       _fit(f"{_names(keys, 3)} [{_fmt_band(lo)}, {_fmt_band(hi)}]",
                            label_w - 6, 6.5), 6.5, False, INK, "r")
            yy = y
        if len(self.bands) > 3:
            self._text(c, x0 - 4, yy - 17, f"+ {len(self.bands) - 3} more bands (tolerances)",
                       6.2, False, MUTED, "r")
        # ticks: the scale ends, 0 and the band limits
        ticks: list[tuple[float, str, int]] = [(-S, f"\u2264{_fmt_band(-S)}", 0),
                                               (S, f"\u2265{_fmt_band(S)}", 0), (0.0, "0", 1)]
        for lo, hi, _ in bands:
            ticks += [(lo, _fmt_band(lo), 2), (hi, _fmt_band(hi), 2)]
        for v in np.linspace(-S, S, 9)[1:-1]:
            ticks.append((float(v), _fmt_band(float(v)), 3))
        used: list[tuple[float, float]] = []
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.5)
        for v, s, _ in sorted(ticks, key=lambda t: t[2]):
            x = xpos(v)
            w = _width(s, 6.2)
            lo_x, hi_x = x - w / 2 - 4, x + w / 2 + 4
            if any(not (hi_x < a or lo_x > b) for a, b in used):
                continue
            used.append((lo_x, hi_x))
            c.line(x, yy, x, yy - 2.5)
            self._text(c, x, yy - 9, s, 6.2, False, INK, "c")
        self._text(c, x0, yy - 17, "\u2190 sunk (material below nominal)", 6.2, False, MUTED)
        self._text(c, x0 + bw, yy - 17, "proud (material above nominal) \u2192", 6.2, False,
                   MUTED, "r")
        # legend
        lx = box.x + box.w - legend_w
        ly = box.top - 20
        c.setFillColorRGB(*GREY)
        c.rect(lx, ly, 10, 6, stroke=0, fill=1)
        self._text(c, lx + 14, ly + 0.8, "not scanned (unscored)", 6.5)
        ly -= 10
        c.setStrokeColorRGB(*OUTLINE)
        c.setLineWidth(1.0)
        c.line(lx, ly + 3, lx + 10, ly + 3)
        self._text(c, lx + 14, ly + 0.8, "band edge (region outline)", 6.5)
        ly -= 11
        c.setFillColorRGB(1, 1, 1)
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.7)
        c.circle(lx + 5, ly + 3, 4.6, stroke=1, fill=1)
        self._text(c, lx + 5, ly + 0.9, "1", 5.8, True, INK, "c")
        self._text(c, lx + 14, ly + 0.8, "region number (region table)", 6.5)

    def _draw_histogram(self, c: Canvas, box: Box) -> None:
        res = self.res
        S = self.scale
        title_h, left, bottom, right = 12.0, 30.0, 24.0, 4.0
        pa = Box(box.x + left, box.y + bottom, box.w - left - right,
                 box.h - bottom - title_h - 25)
        self._text(c, box.x, box.top - 9, "Histogram of the signed deviation", 8, True)
        dev = np.asarray(res.deviation, dtype=float)
        w = _vertex_areas(np.asarray(res.V, float), np.asarray(res.F, np.int64))
        ok = np.isfinite(dev) & (w > 0)
        nb = 60
        edges = np.linspace(-S, S, nb + 1)
        hv, _ = np.histogram(np.clip(dev[ok], -S, S), bins=edges, weights=w[ok])
        hv = 100.0 * hv / max(hv.sum(), 1e-300)
        pdv = np.asarray(res.point_deviation, dtype=float)
        pdv = pdv[np.isfinite(pdv)]
        hp, _ = np.histogram(np.clip(pdv, -S, S), bins=edges)
        hp = 100.0 * hp / max(hp.sum(), 1)
        pos = np.r_[hv[hv > 0], hp[hp > 0]]
        ymin = 10.0 ** max(-3, math.floor(math.log10(pos.min()))) if len(pos) else 0.01
        ymax = 100.0

        def X(v):
            return pa.x + (v + S) / (2 * S) * pa.w

        def Y(p):
            p = max(p, ymin)
            return pa.y + (math.log10(p) - math.log10(ymin)) / (
                math.log10(ymax) - math.log10(ymin)) * pa.h

        # grid and axes
        c.setLineWidth(0.3)
        c.setStrokeColorRGB(*RULE)
        e = int(math.log10(ymin))
        for k in range(e, 3):
            y = Y(10.0**k)
            c.line(pa.x, y, pa.x + pa.w, y)
            lab = f"{10.0**k:g}"
            self._text(c, pa.x - 3, y - 2.2, lab, 6.0, False, MUTED, "r")
        single = len(self.bands) == 1
        lo1, hi1 = self.bands[0][0], self.bands[0][1]
        mids = 0.5 * (edges[1:] + edges[:-1])
        cols = (deviation_colors(mids, lo1, hi1, S) if single
                else np.tile([0.62, 0.66, 0.74], (nb, 1)))
        for i in range(nb):
            if hv[i] <= 0:
                continue
            c.setFillColorRGB(*cols[i])
            c.rect(X(edges[i]), pa.y, X(edges[i + 1]) - X(edges[i]), Y(hv[i]) - pa.y,
                   stroke=0, fill=1)
        # data-referenced distribution: step line
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.8)
        path = c.beginPath()
        started = False
        for i in range(nb):
            y = Y(hp[i]) if hp[i] > 0 else pa.y
            if not started:
                path.moveTo(X(edges[i]), y)
                started = True
            else:
                path.lineTo(X(edges[i]), y)
            path.lineTo(X(edges[i + 1]), y)
        c.drawPath(path, stroke=1, fill=0)
        # band limits
        c.setDash(2, 1.5)
        c.setLineWidth(0.7)
        rows_used: list[list[float]] = [[], []]
        for lo, hi, _keys in self.bands[:3]:
            for v in (lo, hi):
                if abs(v) < 1e-12:
                    continue
                x = X(v)
                c.setStrokeColorRGB(*INK)
                c.line(x, pa.y, x, pa.y + pa.h)
                for k, used in enumerate(rows_used):
                    if all(abs(x - q) > 20 for q in used):
                        self._text(c, x, pa.y + pa.h + 2 + 7 * k, _fmt_band(v), 5.8, False,
                                   INK, "c")
                        used.append(x)
                        break
        c.setDash()
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.5)
        c.rect(pa.x, pa.y, pa.w, pa.h, stroke=1, fill=0)
        # x ticks
        for v in np.linspace(-S, S, 5):
            x = X(v)
            c.line(x, pa.y, x, pa.y - 2)
            s = _fmt_band(float(v))
            if abs(v) == S:
                s = ("\u2264" if v < 0 else "\u2265") + s
            self._text(c, x, pa.y - 8.5, s, 6.0, False, INK, "c")
        self._text(c, pa.x + pa.w / 2, box.y + 1, "signed deviation, mm (end bins collect "
                   "everything beyond)", 6.2, False, MUTED, "c")
        c.saveState()
        c.translate(box.x + 6, pa.y + pa.h / 2)
        c.rotate(90)
        self._text(c, 0, 0, "% per bin (log)", 6.2, False, MUTED, "c")
        c.restoreState()
        # legend
        ly = box.top - 20
        c.setFillColorRGB(*(cols[nb // 2] if single else (0.62, 0.66, 0.74)))
        c.rect(pa.x, ly, 9, 5.5, stroke=0, fill=1)
        first = "vertices, % of scored area"
        self._text(c, pa.x + 12, ly + 0.6, first, 6.2)
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.8)
        lx = pa.x + 12 + _width(first, 6.2) + 10
        c.line(lx, ly + 2.8, lx + 9, ly + 2.8)
        self._text(c, lx + 12, ly + 0.6, _fit("scan points (data-ref.), %",
                                               box.x + box.w - lx - 12, 6.2), 6.2)

    def _draw_table(self, c: Canvas, x: float, top: float, t: _Table) -> None:
        y = top
        if t.title:
            self._text(c, x, y - 8, _fit(t.title, t.width, 8, True), 8, True)
            y -= 11.0
        if t.head_h > 0:
            c.setFillColorRGB(*HEAD_BG)
            c.rect(x, y - t.head_h, t.width, t.head_h, stroke=0, fill=1)
            cx = x
            for head, w, align in t.columns:
                parts = head.split("\n")
                for j, part in enumerate(parts):
                    s = _fit(part, w - 4, t.size, True)
                    yy = y - t.head_h + 2.8 + 7.6 * (len(parts) - 1 - j)
                    if align == "r":
                        self._text(c, cx + w - 2, yy, s, t.size, True, INK, "r")
                    elif align == "c":
                        self._text(c, cx + w / 2, yy, s, t.size, True, INK, "c")
                    else:
                        self._text(c, cx + 2, yy, s, t.size, True)
                cx += w
            y -= t.head_h
        for i, row in enumerate(t.rows):
            section = i in t.section_rows
            if section:
                c.setFillColorRGB(*HEAD_BG)
                c.rect(x, y - t.row_h, t.width, t.row_h, stroke=0, fill=1)
            elif i % 2 == 1:
                c.setFillColorRGB(*ZEBRA)
                c.rect(x, y - t.row_h, t.width, t.row_h, stroke=0, fill=1)
            emph = bool(t.emphasis[i]) if i < len(t.emphasis) else False
            color = FAIL_INK if emph else INK
            cx = x
            for (_, w, align), cell in zip(t.columns, row, strict=True):
                s = _fit(cell, w - 4, t.size, section)
                bold = section or (emph and cell in ("FAIL", "> limit", "EXCEEDED"))
                if align == "r":
                    self._text(c, cx + w - 2, y - t.row_h + 2.4, s, t.size, bold, color, "r")
                elif align == "c":
                    self._text(c, cx + w / 2, y - t.row_h + 2.4, s, t.size, bold, color, "c")
                else:
                    self._text(c, cx + 2, y - t.row_h + 2.4, s, t.size, bold, color)
                cx += w
            y -= t.row_h
        if t.note:
            self._text(c, x + 2, y - t.row_h + 2.4, _fit(t.note, t.width - 4, t.size), t.size,
                       False, MUTED)
            y -= t.row_h
        c.setStrokeColorRGB(*RULE)
        c.setLineWidth(0.5)
        c.line(x, y, x + t.width, y)

    def _draw_notes_footer(self, c: Canvas, y: float, notes) -> None:
        for text, warn in notes:
            for s in _wrap(text, self.CW, 6.8, warn):
                self._text(c, self.M, y - 7, s, 6.8, warn, FAIL_INK if warn else INK)
                y -= 8.2
        # sign-off and footer at the bottom margin
        yb = self.MT
        c.setStrokeColorRGB(*INK)
        c.setLineWidth(0.5)
        head = "Reviewed / approved by"
        x = self.M + _width(head, 7.0, True) + 6
        self._text(c, self.M, yb + 16, head, 7.0, True)
        c.line(x, yb + 15, x + 170, yb + 15)
        self._text(c, x + 185, yb + 16, "Date", 7.0, True)
        x2 = x + 185 + _width("Date", 7.0, True) + 6
        c.line(x2, yb + 15, x2 + 90, yb + 15)
        qif = self.qif_name
        foot = (f"qifreport {__version__} \u00b7 page 1 of 1 \u00b7 "
                + (f"every number of this page is in {qif} (QIF 3.0, exact values) \u00b7 "
                   if qif else "")
                + f"printed {_utc(self.prov.finished)}")
        self._text(c, self.M, yb + 2, _fit(foot, self.CW, 6.2), 6.2, False, MUTED)


def _num(x) -> str:
    return f"{float(x):.2f}" if _finite(x) else DASH


def _params_text(params, limit: int = 4) -> str:
    """The first ``limit`` set scalar fields of a method's parameter dataclass, ``k=v``."""
    if not dataclasses.is_dataclass(params) or isinstance(params, type):
        return "defaults"
    items = []
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, (int, float, np.integer, np.floating)):
            items.append(f"{f.name}={float(v):.3g}")
        elif isinstance(v, str):
            items.append(f"{f.name}={v}")
        if len(items) == limit:
            break
    return ", ".join(items) or "defaults"


# ----------------------------------------------------------------------------- public API


def plan_layout(res: InspectionResult, prov: Provenance, *, page: str = "A4",
                chain_floor: float | None = None) -> PageLayout:
    """Where :func:`write_pdf` puts everything for this result (no rendering, no file).

    Deterministic: :func:`write_pdf` uses exactly this layout. Useful to find the maps on a
    rasterized page (tests) or to know how many regions and tolerances the page lists.
    """
    return _Report(res, prov, page, chain_floor, None).plan()


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
    backend : renderer of the maps (:func:`qifreport.reports.render.render_views`), default VTK with a
        matplotlib fallback.
    """
    write_report(path, res, prov, page=page, chain_floor=chain_floor, qif_name=qif_name,
                 backend=backend)


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
    px_per_pt = MAP_DPI / 72.0
    sizes = [(max(16, int(round(b.w * px_per_pt))), max(16, int(round(b.h * px_per_pt))))
             for b in lay.maps]
    t1 = time.perf_counter()
    views = render_views(res.V_registered, res.F, res.deviation, rep.lower, rep.upper,
                         res.acceptance.regions, size=sizes, views=lay.views, scale=lay.scale,
                         backend=backend, margin=[rep.map_margins(b) for b in lay.maps])
    t2 = time.perf_counter()
    rep.draw(path, lay, views)
    t3 = time.perf_counter()
    log.info("PDF report %s: layout %.2f s, maps %.2f s (%s), drawing %.2f s", path.name,
             t1 - t0, t2 - t1, views[0].backend if views else "-", t3 - t2)
    return {"layout": t1 - t0, "render": t2 - t1, "draw": t3 - t2}


def _pose_text(a) -> str:
    """One cell: how the rigid ICP was started (the pose search's confidence in short)."""
    if a is None or a.method == "identity":
        return "none: scan in part frame"
    text = f"{a.restart_agreement}/{a.n_starts}"
    if a.ambiguous:
        text += " AMBIGUOUS"
    elif a.weakly_constrained:
        text += " (slides)"
    return text
