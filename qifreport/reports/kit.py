"""The report kit: house style and drawing primitives shared by the one-page reports.

Both the per-scan inspection report (:mod:`qifreport.reports.pdf`) and the batch trend report
(:mod:`qifreport.reports.trend`) are one page, A4 or US Letter, drawn with reportlab canvas
primitives in DejaVu Sans (from matplotlib's bundled fonts, embedded). This module holds what
they share:

* **Style** -- the fonts (:data:`FONT`, :data:`FONT_BOLD`), page sizes (:data:`PAGE_SIZES`,
  :func:`page_size`), margins (:class:`ReportPage`) and colours (:data:`INK`, :data:`MUTED`,
  :data:`RULE`, :data:`HEAD_BG`, :data:`ZEBRA`, :data:`PASS_BG`, :data:`FAIL_BG`,
  :data:`UNSURE_BG`, :data:`FAIL_INK`).
* **Number and text formats** -- lengths in mm with 3 decimals (:func:`fmt_mm`,
  :func:`fmt_smm`), areas in mm^2 with 1 decimal (:func:`fmt_area`), fractions as % with 2
  decimals (:func:`fmt_pct`), band limits (:func:`fmt_band`), digests (:func:`short_sha`),
  times in UTC (:func:`fmt_utc`) and name lists (:func:`join_names`); a value that does not
  exist prints :data:`DASH`.
* **Text metrics** -- :func:`register_fonts`, :func:`text_width`, :func:`fit_text` (cut with
  an ellipsis) and :func:`wrap_text`.
* **Layout and drawing** -- :class:`Box` (a rectangle on the page), :class:`Table` (a
  one-line-per-row table), :func:`draw_text` and :func:`draw_table`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = [
    "FONT",
    "FONT_BOLD",
    "PAGE_SIZES",
    "DASH",
    "SHA_DIGITS",
    "INK",
    "MUTED",
    "RULE",
    "HEAD_BG",
    "ZEBRA",
    "PASS_BG",
    "FAIL_BG",
    "UNSURE_BG",
    "FAIL_INK",
    "finite",
    "fmt_mm",
    "fmt_smm",
    "fmt_area",
    "fmt_pct",
    "fmt_band",
    "short_sha",
    "fmt_utc",
    "join_names",
    "register_fonts",
    "text_width",
    "fit_text",
    "wrap_text",
    "Box",
    "Table",
    "page_size",
    "ReportPage",
    "draw_text",
    "draw_table",
]

FONT, FONT_BOLD = "DejaVuSans", "DejaVuSans-Bold"
#: page sizes, points (1/72 in)
PAGE_SIZES = {"A4": (595.2756, 841.8898), "LETTER": (612.0, 792.0)}
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


def finite(x: object) -> bool:
    """Whether ``x`` is a finite number (None, NaN, inf and non-numbers are not)."""
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def fmt_mm(x: float | None) -> str:
    """A length or unsigned deviation in mm, 3 decimals (``"0.399"``); NaN prints a dash."""
    return f"{float(x):.3f}" if finite(x) else DASH


def fmt_smm(x: float | None) -> str:
    """A signed deviation in mm, 3 decimals with its sign (``"+0.896"``, ``"-2.259"``)."""
    if not finite(x):
        return DASH
    s = f"{float(x):+.3f}"
    return s.replace("-", "+") if float(s) == 0.0 else s


def fmt_area(x: float | None) -> str:
    """An area in mm^2, 1 decimal (``"183.9"``)."""
    return f"{float(x):.1f}" if finite(x) else DASH


def fmt_pct(f: float | None) -> str:
    """A fraction 0..1 as a percentage with 2 decimals, without the sign (``"76.21"``)."""
    return f"{100.0 * float(f):.2f}" if finite(f) else DASH


def fmt_band(v: float) -> str:
    """A band limit in mm for labels: shortest of up to 3 decimals, signed (``"+0.25"``)."""
    s = f"{v:+.3f}".rstrip("0").rstrip(".")
    return "0" if float(s) == 0.0 else s


def short_sha(sha: str) -> str:
    """The first :data:`SHA_DIGITS` hex digits of a digest; a dash for none."""
    return sha[:SHA_DIGITS] if sha else DASH


def fmt_utc(t: datetime | None) -> str:
    """A time in UTC to the second (``"2025-01-02 03:04:05 UTC"``); naive means UTC."""
    if t is None:
        return DASH
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return t.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def join_names(names: list[str], limit: int = 4) -> str:
    """``names`` joined by commas, the first ``limit`` of them and ``+k more``."""
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit]) + f" +{len(names) - limit} more"


# ---------------------------------------------------------------------------------- fonts


def _matplotlib_fonts() -> Path:
    """matplotlib's bundled TrueType folder, found without importing matplotlib (a slow import)."""
    import importlib.util

    spec = importlib.util.find_spec("matplotlib")
    if spec is not None and spec.origin is not None:
        d = Path(spec.origin).parent / "mpl-data" / "fonts" / "ttf"
        if (d / "DejaVuSans.ttf").is_file():
            return d
    import matplotlib  # a relocated data path: ask matplotlib

    return Path(matplotlib.get_data_path()) / "fonts" / "ttf"


def register_fonts() -> None:
    """Register DejaVu Sans (regular, bold) from matplotlib's bundled fonts (embedded)."""
    global _fonts_registered
    if _fonts_registered:
        return
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont

    d = _matplotlib_fonts()
    pdfmetrics.registerFont(TTFont(FONT, str(d / "DejaVuSans.ttf")))
    pdfmetrics.registerFont(TTFont(FONT_BOLD, str(d / "DejaVuSans-Bold.ttf")))
    _fonts_registered = True


def text_width(text: str, size: float, bold: bool = False) -> float:
    """Width of ``text`` at ``size`` points in the house font, points."""
    from reportlab.pdfbase.pdfmetrics import stringWidth

    return stringWidth(text, FONT_BOLD if bold else FONT, size)


def fit_text(text: str, width: float, size: float, bold: bool = False) -> str:
    """``text`` cut with an ellipsis to fit ``width`` points."""
    if text_width(text, size, bold) <= width:
        return text
    lo, hi = 0, len(text)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if text_width(text[:mid].rstrip() + "\u2026", size, bold) <= width:
            lo = mid
        else:
            hi = mid - 1
    return text[:lo].rstrip() + "\u2026"


def wrap_text(text: str, width: float, size: float, bold: bool = False) -> list[str]:
    """``text`` broken into lines no wider than ``width`` points (at least one line)."""
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
        """Page y of the upper edge, points."""
        return self.y + self.h


@dataclass
class Table:
    """A one-line-per-row table drawn with canvas primitives (:func:`draw_table`).

    Attributes
    ----------
    columns : per column ``(heading, width in points, align "l"/"r"/"c")``; a heading with
        ``"\\n"`` takes two lines.
    rows : the cells, one list of strings per row.
    size, row_h, head_h : font size, row height and heading height, points (``head_h`` 0:
        no heading row).
    title : a bold line above the table.  note : a last, full-width line (e.g. ``"+ 12
        more ... see QIF"``).
    emphasis : per row, print in the fail colour.  section_rows : rows that are sub-headings.
    """

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

    #: lines the note wraps onto, at most (the last one cut)
    NOTE_LINES = 3

    def note_lines(self) -> list[str]:
        """The note wrapped to the table's width (at most :attr:`NOTE_LINES` lines)."""
        if not self.note:
            return []
        lines = wrap_text(self.note, self.width - 4, self.size)
        if len(lines) > self.NOTE_LINES:
            lines = lines[: self.NOTE_LINES]
            lines[-1] = fit_text(lines[-1] + " \u2026", self.width - 4, self.size)
        return lines

    @property
    def height(self) -> float:
        """Height of the drawn table (title, heading, rows and note), points."""
        return (
            (11.0 if self.title else 0.0)
            + self.head_h
            + self.row_h * len(self.rows)
            + self.row_h * len(self.note_lines())
        )

    @property
    def width(self) -> float:
        """Sum of the column widths, points."""
        return sum(c[1] for c in self.columns)


def page_size(page: str) -> tuple[str, tuple[float, float]]:
    """The page key (``"A4"`` or ``"LETTER"``) and its size ``(width, height)``, points.

    Raises
    ------
    ValueError
        For any other page (case-insensitive).
    """
    key = str(page).strip().upper()
    if key not in PAGE_SIZES:
        raise ValueError(f"page must be 'A4' or 'Letter', got {page!r}")
    return key, PAGE_SIZES[key]


class ReportPage:
    """Geometry of a one-page report (points, origin bottom-left); registers the fonts.

    Attributes
    ----------
    page : ``"A4"`` or ``"LETTER"``.  W, H : page width and height.
    M : side margin.  MT : top and bottom margin.  CW : content width ``W - 2 M``.
    """

    def __init__(self, page: str) -> None:
        register_fonts()
        self.page, (self.W, self.H) = page_size(page)
        self.M = 28.0 if self.page == "A4" else 30.0  # side margin
        self.MT = 26.0  # top/bottom margin
        self.CW = self.W - 2 * self.M  # content width

    def new_canvas(self, path: Path) -> Canvas:
        """A compressed reportlab canvas of this page size writing ``path``."""
        from reportlab.pdfgen.canvas import Canvas

        # the initial font too: otherwise reportlab references (unembedded) Helvetica
        return Canvas(
            str(path),
            pagesize=(self.W, self.H),
            pageCompression=1,
            initialFontName=FONT,
            initialFontSize=7,
        )


# -------------------------------------------------------------------------------- drawing


def draw_text(
    c: Canvas,
    x: float,
    y: float,
    s: str,
    size: float = 7.0,
    bold: bool = False,
    color: tuple[float, float, float] = INK,
    align: str = "l",
) -> None:
    """One line of text with its baseline at ``y``; ``align`` ``"l"``, ``"r"`` or ``"c"``
    places ``x`` at its left end, right end or centre."""
    c.setFillColorRGB(*color)
    c.setFont(FONT_BOLD if bold else FONT, size)
    if align == "r":
        c.drawRightString(x, y, s)
    elif align == "c":
        c.drawCentredString(x, y, s)
    else:
        c.drawString(x, y, s)


def draw_table(c: Canvas, x: float, top: float, t: Table) -> None:
    """Draw ``t`` with its upper left corner at ``(x, top)``, points; it takes ``t.height``."""
    y = top
    if t.title:
        draw_text(c, x, y - 8, fit_text(t.title, t.width, 8, True), 8, True)
        y -= 11.0
    if t.head_h > 0:
        c.setFillColorRGB(*HEAD_BG)
        c.rect(x, y - t.head_h, t.width, t.head_h, stroke=0, fill=1)
        cx = x
        for head, w, align in t.columns:
            parts = head.split("\n")
            for j, part in enumerate(parts):
                s = fit_text(part, w - 4, t.size, True)
                yy = y - t.head_h + 2.8 + 7.6 * (len(parts) - 1 - j)
                if align == "r":
                    draw_text(c, cx + w - 2, yy, s, t.size, True, INK, "r")
                elif align == "c":
                    draw_text(c, cx + w / 2, yy, s, t.size, True, INK, "c")
                else:
                    draw_text(c, cx + 2, yy, s, t.size, True)
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
            s = fit_text(cell, w - 4, t.size, section)
            bold = section or (emph and cell in ("FAIL", "> limit", "EXCEEDED"))
            if align == "r":
                draw_text(c, cx + w - 2, y - t.row_h + 2.4, s, t.size, bold, color, "r")
            elif align == "c":
                draw_text(c, cx + w / 2, y - t.row_h + 2.4, s, t.size, bold, color, "c")
            else:
                draw_text(c, cx + 2, y - t.row_h + 2.4, s, t.size, bold, color)
            cx += w
        y -= t.row_h
    for line in t.note_lines():
        draw_text(c, x + 2, y - t.row_h + 2.4, line, t.size, False, MUTED)
        y -= t.row_h
    c.setStrokeColorRGB(*RULE)
    c.setLineWidth(0.5)
    c.line(x, y, x + t.width, y)
