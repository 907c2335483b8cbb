"""The bottom of the inspection page: the notes, the sign-off line and the footer.

The notes state what qualifies the result: with ``--seeds`` the repeatability (regions
persistent k of m), the PMI not scored, the nominal mesh's hygiene, every trust warning of
the registration (a pass is then not claimed), added material and a band too tight for the
measured chain floor. The footer names the software, the QIF results file and the time.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from qifreport import __version__
from qifreport.metrology.inspection import InspectionResult

from .context import ReportContext
from .kit import (
    FAIL_INK,
    INK,
    MUTED,
    draw_text,
    finite,
    fit_text,
    fmt_mm,
    fmt_utc,
    text_width,
    wrap_text,
)

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = ["note_lines", "notes_height", "fit_notes", "draw_notes_footer"]


def note_lines(res: InspectionResult, chain_floor: float | None) -> list[tuple[str, bool]]:
    """The notes below the tables, ``(text, warning)``: repeatability, PMI not scored, the
    nominal mesh's hygiene, the trust warnings, added material and a band the chain floor
    (mm, or None: not measured) cannot verify. Warnings print bold in the fail colour."""
    out: list[tuple[str, bool]] = []
    rep = res.repeatability
    if rep is not None:
        out.append(
            (
                f"{rep.describe()}. Only persistent regions are findings (listed, "
                "outlined and judged); each resampling keeps every scan point with "
                f"probability {rep.keep_fraction:g} (seeds 0 to {rep.seeds - 1}).",
                False,
            )
        )
    ne = res.not_evaluated
    if ne:
        items = [
            f"{n.kind} \u201c{n.name}\u201d" + (f" #{n.step_id}" if n.step_id else "") for n in ne
        ]
        head = ", ".join(items[:6]) + (f" and {len(items) - 6} more" if len(items) > 6 else "")
        reasons = sorted({n.reason.split(":")[0] for n in ne})
        out.append(
            (
                f"PMI not scored ({len(ne)}): {head} \u2014 "
                f"{'; '.join(reasons)[:160]} (each listed with its reason in the QIF).",
                False,
            )
        )
    h = res.hygiene
    if h is not None and (
        h.boundary_edges or h.non_manifold_edges or h.degenerate_faces or h.duplicate_faces
    ):
        out.append(
            (
                f"Nominal mesh: {h.describe()}.",
                bool(h.non_manifold_edges or h.degenerate_faces or h.duplicate_faces),
            )
        )
    for w in res.drawing_warnings:
        out.append((f"Drawing read with a correction: {w}.", True))
    for w in res.trust_warnings():
        tail = " A pass is therefore not claimed (NOT ESTABLISHED)." if res.passed else ""
        out.append((f"Warning: {w}.{tail}", True))
    for w in res.not_measured():
        tail = " A pass is therefore not claimed (NOT MEASURED)." if res.passed else ""
        out.append((f"Not measured: {w}.{tail}".replace("mm^2", "mm\u00b2"), True))
    if res.size is not None and res.size.status != "no rim":
        edge = res.edges.reasons()[0] if res.edges is not None else ""
        s = res.size.reasons()[0]
        judged = res.judged_size is not None
        solid = "" if judged else f" ({res.edges.part.describe()}: reported, not judged)"
        out.append(
            (
                f"Size from the trim edges{solid}: {s}; {edge}.",
                judged and res.size.status != "conforming",
            )
        )
    for w in res.coverage_notes():
        if not w.startswith("size (a solid"):  # said in the size line above
            out.append((f"Left out by design: {w}.", False))
    for w in res.relaxed_guards():
        out.append((f"Relaxed guard: {w}.".replace("mm^2", "mm\u00b2"), True))
    a = res.added
    if a is not None and a.regions:
        judged = (
            "fails the part" if not a.passed else "reported, not judged (--fail-on-added-material)"
        )
        out.append(
            (
                f"Added material (scan points proud of the nominal, data-referenced): "
                f"{a.describe()}; P99.9 signed {a.p999_signed:+.3f} mm, "
                f"{100 * a.frac_above:.3f} % beyond +{a.threshold:g} mm; {judged}.",
                a.found,
            )
        )
    if chain_floor is not None:
        tight = min((z.zone.half_width for z in res.zones), default=math.nan)
        if finite(tight) and tight <= chain_floor:
            out.append(
                (
                    f"Warning: the tightest band half-width {fmt_mm(tight)} mm does not "
                    f"exceed the chain floor {fmt_mm(chain_floor)} mm: it cannot "
                    "be verified with this chain.",
                    True,
                )
            )
    return out


def notes_height(lines: list[tuple[str, bool]], width: float) -> float:
    """Height of the notes (:func:`note_lines`) wrapped to ``width`` points, points."""
    return sum(8.2 * len(wrap_text(t, width, 6.8, w)) for t, w in lines) + 2.0


def fit_notes(lines: list[tuple[str, bool]], width: float, height: float) -> list[tuple[str, bool]]:
    """The notes (:func:`note_lines`) cut to fit ``height`` points at ``width`` points.

    As they are when they fit. Else each note is cut to its first two lines (ending in an
    ellipsis); if that is still too tall, notes are left out from the end, those that are
    not warnings first, and a last line says how many and where they all are (the command's
    summary and ``--json``). Never text drawn over the sign-off line.
    """
    if notes_height(lines, width) <= height:
        return lines
    short = []
    for text, warn in lines:
        wrapped = wrap_text(text, width, 6.8, warn)
        if len(wrapped) > 2:
            text = " ".join(wrapped[:2])
            while len(wrap_text(text + "…", width, 6.8, warn)) > 2:
                text = text[: text.rstrip().rfind(" ")] if " " in text.rstrip() else text[:-1]
            text += "…"
        short.append((text, warn))
    if notes_height(short, width) <= height:
        return short
    # left out last: the warnings, and of each kind the notes nearer the top
    order = [i for i in range(len(short)) if short[i][1]]
    order = [i for i in range(len(short)) if not short[i][1]][::-1] + order[::-1]
    keep = set(range(len(short)))
    for i in order:
        keep.discard(i)
        n = len(short) - len(keep)
        cut = [short[j] for j in sorted(keep)] + [
            (
                f"+ {n} more note{'s' if n > 1 else ''}, left out for lack of room: the "
                "command's summary and its --json summary give every note.",
                False,
            )
        ]
        if notes_height(cut, width) <= height:
            return cut
    return cut


def draw_notes_footer(
    c: Canvas, ctx: ReportContext, y: float, lines: list[tuple[str, bool]]
) -> None:
    """The notes (:func:`note_lines`) from ``y`` down, then the sign-off line and the footer
    at the bottom margin."""
    for text, warn in lines:
        for s in wrap_text(text, ctx.CW, 6.8, warn):
            draw_text(c, ctx.M, y - 7, s, 6.8, warn, FAIL_INK if warn else INK)
            y -= 8.2
    # sign-off and footer at the bottom margin
    yb = ctx.MT
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.5)
    head = "Reviewed / approved by"
    x = ctx.M + text_width(head, 7.0, True) + 6
    draw_text(c, ctx.M, yb + 16, head, 7.0, True)
    c.line(x, yb + 15, x + 170, yb + 15)
    draw_text(c, x + 185, yb + 16, "Date", 7.0, True)
    x2 = x + 185 + text_width("Date", 7.0, True) + 6
    c.line(x2, yb + 15, x2 + 90, yb + 15)
    qif = ctx.qif_name
    foot = (
        f"qifreport {__version__} \u00b7 page 1 of 1 \u00b7 "
        + (f"every number of this page is in {qif} (QIF 3.0, exact values) \u00b7 " if qif else "")
        + f"printed {fmt_utc(ctx.prov.finished)}"
    )
    draw_text(c, ctx.M, yb + 2, fit_text(foot, ctx.CW, 6.2), 6.2, False, MUTED)
