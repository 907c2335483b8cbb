"""The top of the inspection page: the title block with the verdict, and the decision.

* **Title block** -- part, input files with their SHA-256 (first 16 hex digits), time of the
  inspection, software version, serial number, operator, organization, author, units; on the
  right the **verdict**, large, with the criteria that decided it (area, region; whole part
  and per tolerance).
* **Decision** -- the acceptance rule and, for a failing part, the reasons (the QIF's
  ``decided_by`` lines), cut to a number of reasons with the rest counted.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING

from qifreport import __version__
from qifreport.metrology.inspection import InspectionResult

from .context import ReportContext
from .kit import (
    DASH,
    FAIL_BG,
    FAIL_INK,
    INK,
    MUTED,
    PASS_BG,
    RULE,
    UNSURE_BG,
    Box,
    draw_text,
    finite,
    fit_text,
    fmt_utc,
    join_names,
    short_sha,
    text_width,
    wrap_text,
)

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = [
    "HEADER_H",
    "criteria",
    "verdict_lines",
    "rule_text",
    "reasons",
    "decision_lines",
    "condition_line",
    "draw_header",
    "title_condition",
    "draw_decision",
]

#: height of the title block, points
HEADER_H = 72.0


def criteria(res: InspectionResult) -> tuple[list[str], list[str], list[str]]:
    """Who failed the area criterion, the region criterion, and who had nothing scored.

    Returns
    -------
    area, region, empty : names (``"whole part"`` or zone keys), in that order.
    """
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


def verdict_lines(res: InspectionResult, width: float = 1e9, size: float = 6.8) -> list[str]:
    """Which criteria decided the verdict, for whom (names cut to fit ``width`` points),
    and the virtual fixture's load when it was measured."""
    load = res.fixture_load
    tail = [] if load is None or not load.established else [fit_text(load.short(), width, size)]
    return _criteria_lines(res, width, size) + tail


def _criteria_lines(res: InspectionResult, width: float, size: float) -> list[str]:
    """:func:`verdict_lines` without the fixture's load."""
    area, region, empty = criteria(res)
    if res.passed:
        n = len(res.zones)
        if res.verdict == "NOT ESTABLISHED" and res.established:
            names = (
                (["whole part"] if res.acceptance.decision == "UNCERTAIN" else [])
                + [z.zone.key for z in res.zones if z.uncertain]
                + [c.spec.key for c in res.characteristics if c.status == "INDETERMINATE"]
            )
            return [
                "neither in nor out within the",
                fit_text(f"measurement uncertainty: {join_names(names, 4)}", width, size),
            ]
        if res.verdict == "NOT ESTABLISHED":
            return ["criteria met, but the registration", "cannot be trusted (warnings below)"]
        if res.verdict == "NOT MEASURED":
            names = (["whole part"] if res.coverage and not res.coverage.measured else []) + [
                z.zone.key for z in res.zones if not z.measured
            ]
            return [
                "criteria met on what was scored;",
                fit_text(f"not measured: {join_names(names, 4)}", width, size),
            ]
        judged = [c for c in res.characteristics if c.status in ("PASS", "FAIL")]
        if judged:
            k = len(judged)
            return [
                f"whole part, {n} profile{'s' if n != 1 else ''} and {k} feature",
                f"characteristic{'s' if k != 1 else ''}: all within their limits",
            ]
        return [
            f"whole part and {n} tolerance{'s' if n != 1 else ''}:",
            "area and region criteria met",
        ]

    def line(head: str, names: list[str]) -> str:
        for limit in range(4, 0, -1):
            s = f"{head}: {join_names(names, limit)}"
            if text_width(s, size) <= width:
                return s
        return s

    out = []
    if area:
        out.append(line("area criterion", area))
    if region:
        out.append(line("region criterion", region))
    if empty:
        out.append(line("nothing scored", empty))
    failed = [c.spec.key for c in res.characteristics if c.status == "FAIL"]
    if failed:
        out.append(line("beyond its limit", failed))
    if res.added is not None and not res.added.passed:
        out.append(f"added material: {res.added.largest_area:.0f} mm\u00b2 proud")
    size = res.judged_size  # a solid's size check is a note, never what failed it
    if size is not None and size.flagged:
        out.append(f"size: scale {size.scale:.4f} ({size.size_deviation:+.2f} mm at the edge)")
    if res.not_restrainable():
        out.append(f"not restrainable at {', '.join(res.restraint.over_limit)}")
    return out


def rule_text(res: InspectionResult) -> str:
    """The acceptance rule in one sentence, with this inspection's limits."""
    p = res.params
    return (
        f"Acceptance (whole part and each tolerance on its own faces): at least "
        f"{100 * p.min_fraction:g} % of the scored area inside the band and no connected "
        f"out-of-tolerance region over {p.max_region_area:g} mm\u00b2; NOT MEASURED when less "
        f"than {100 * p.min_coverage:g} % of a surface is scored or a hole in the scan could "
        f"hide such a region. {_RULE_TEXT.get(p.decision_rule, p.decision_rule)}"
        + (
            f" (U median {res.acceptance.uncertainty_mm[0]:.4f} mm)."
            if res.acceptance.proven_in is not None
            else "."
        )
    )


#: the decision rules of :mod:`qifreport.metrology.acceptance.decision`, as the report states them
_RULE_TEXT = {
    "iso14253": "Decision ISO 14253-1: conformance or non-conformance proven with each "
    "deviation's expanded uncertainty U, otherwise not established",
    "guarded-acceptance": "Decision: guarded acceptance (accepted only when proven with U)",
    "guarded-rejection": "Decision: guarded rejection (rejected only when proven with U)",
    "simple": "Decision: simple acceptance (U not used)",
}


def _display(s: str) -> str:
    """Library text for print: ``mm^2`` as mm\u00b2."""
    return s.replace("mm^2", "mm\u00b2")


def reasons(res: InspectionResult) -> list[str]:
    """The reasons of the decision (the QIF's ``decided_by`` lines), as printed."""
    return [_display(s) for s in res.decided_by()]


def condition_line(res: InspectionResult) -> str:
    """The verdict box's line on the condition: where the verdict holds, who stated it and,
    when a restraint was applied, the free state's verdict."""
    if res.restraint is not None:
        where = "restrained at clamps"
    else:
        where = "virtually restrained" if res.fit is not None else "in the free state"
    free = f"; free state {res.free_state}" if res.restraint_applied and res.free_state else ""
    return f"{where} ({res.condition.stated_by}){free}"


def more_reasons(rest: list[str]) -> str:
    """The reasons not listed, counted by what they are on (the part, or a tolerance's
    key): ``+ 5 more reasons: whole part 2, T1 3 (each in the QIF file)``."""
    on: dict[str, int] = {}
    for r in rest:
        r = re.sub(r"^(not established|not measured|failed|fail)\s*:\s*", "", r, flags=re.I)
        subject = r.split(":", 1)[0].strip()
        key = "whole part" if subject.startswith("whole part") else subject.split(" ", 1)[0]
        on[key] = on.get(key, 0) + 1
    listing = ", ".join(f"{k} {n}" for k, n in on.items())
    s = "s" if len(rest) != 1 else ""
    return f"+ {len(rest)} more reason{s} of the same verdict: {listing} (each in the QIF file)"


def decision_lines(
    res: InspectionResult, width: float, limit: int
) -> tuple[list[tuple[str, bool]], int]:
    """Wrapped lines of the decision block ``width`` points wide and how many reasons it lists.

    Returns
    -------
    lines : ``(text, reason)`` per line; reasons print in the fail colour.
    shown : the number of reasons listed (at most ``limit``; the rest are counted).
    """
    lines = [(s, False) for s in wrap_text(f"Judged {res.condition_text()}.", width, 7.0)]
    lines += [(s, False) for s in wrap_text(rule_text(res), width, 7.0)]
    rs = reasons(res)
    shown = rs[:limit]
    for r in shown:
        for j, s in enumerate(wrap_text(r, width - 10, 7.0)):
            lines.append((("\u2022 " if j == 0 else "   ") + s, True))
    if len(rs) > len(shown):
        lines.append((more_reasons(rs[len(shown) :]), False))
    # what the operator relaxed qualifies every verdict: said here, where no note can
    # push it off the page
    relaxed = res.relaxed_guards()
    if relaxed:
        more = f"; + {len(relaxed) - 1} more (notes, QIF)" if len(relaxed) > 1 else ""
        text = _display(f"Relaxed guard{'s' if len(relaxed) > 1 else ''}: {relaxed[0]}{more}")
        lines += [(s, True) for s in wrap_text(text, width, 7.0)]
    return lines, len(shown)


def title_condition(res) -> str:
    """The condition the part was judged in, as the title says it: held at its clamps,
    in the virtual fixture (when one was applied), or in its free state (a rigid fit)."""
    if res.restraint is not None:
        return "RESTRAINED INSPECTION (ISO 10579)"
    if res.fit is not None:
        return "VIRTUAL FIXTURE INSPECTION"
    return "FREE-STATE INSPECTION (RIGID FIT)"


def draw_header(c: Canvas, ctx: ReportContext, box: Box) -> None:
    """The title block in ``box``: facts on the left, the verdict on the right."""
    res, prov = ctx.res, ctx.prov
    vw = 172.0
    # verdict
    word = res.verdict
    vx = box.x + box.w - vw
    c.setFillColorRGB(*{"PASS": PASS_BG, "FAIL": FAIL_BG}.get(word, UNSURE_BG))
    c.roundRect(vx, box.y, vw, box.h, 4, stroke=0, fill=1)
    if word in ("PASS", "FAIL"):
        draw_text(c, vx + vw / 2, box.top - 36, word, 34, True, (1, 1, 1), "c")
    else:  # NOT ESTABLISHED
        draw_text(c, vx + vw / 2, box.top - 32, word, 16, True, (1, 1, 1), "c")
    # the criteria, then the condition the verdict holds in and who stated it
    lines = verdict_lines(res, vw - 10, 6.8)[:2] + [condition_line(res)]
    yy = box.top - 50
    for s in lines:
        draw_text(c, vx + vw / 2, yy, fit_text(s, vw - 10, 6.8), 6.8, False, (1, 1, 1), "c")
        yy -= 8.4
    # title
    tw = box.w - vw - 12
    draw_text(
        c,
        box.x,
        box.top - 8,
        "SURFACE DEVIATION REPORT \u2014 " + title_condition(res),
        7.0,
        True,
        MUTED,
    )
    trace = prov.trace or {}
    ident = "   ".join(
        f"{k} {v}"
        for k, v in (
            ("part number", trace.get("part_number")),
            ("revision", trace.get("revision")),
            ("serial number", prov.serial_number),
        )
        if v
    )
    name = fit_text(prov.part_name, tw * (0.55 if ident else 1.0), 16, True)
    draw_text(c, box.x, box.top - 24, name, 16, True)
    if ident:
        x = box.x + text_width(name, 16, True) + 10
        draw_text(c, x, box.top - 24, fit_text(ident, box.x + tw - x, 8.0), 8.0, False, MUTED)
    dur = (prov.finished - prov.started).total_seconds() if prov.finished else math.nan
    people = [prov.operator or DASH, f"organization {prov.organization or DASH}"]
    if prov.author:
        people.append(f"author {prov.author}")
    vw_ = tw - 46

    def file_line(path: str, sha: str) -> str:
        tail = f"   SHA-256 {short_sha(sha)}\u2026"
        return fit_text(Path(path).name, vw_ - text_width(tail, 7.0), 7.0) + tail

    temp = trace.get("temperature_C")
    if trace.get("instrument"):
        people.append(f"instrument {trace['instrument']}")
    rows = [
        ("Nominal", file_line(prov.nominal_path, prov.nominal_sha256)),
        ("Scan", file_line(prov.scan_path, prov.scan_sha256)),
        (
            "Inspected",
            f"{fmt_utc(prov.started)}"
            + (f" ({dur:.0f} s)" if finite(dur) else "")
            + f"   serial number {prov.serial_number or DASH}"
            + (f"   part at {temp:g} \u00b0C" if temp is not None else ""),
        ),
        ("Operator", "    ".join(people)),
        (
            "Software",
            f"qifreport {__version__}; units mm, mm\u00b2, %; deviation along "
            "the normal, + proud / \u2212 sunk",
        ),
    ]
    yy = box.top - 35
    for k, v in rows:
        draw_text(c, box.x, yy, k, 7.0, True, MUTED)
        draw_text(c, box.x + 46, yy, fit_text(v, vw_, 7.0), 7.0)
        yy -= 8.6
    c.setStrokeColorRGB(*RULE)
    c.setLineWidth(0.6)
    c.line(box.x, box.y - 3, box.x + box.w, box.y - 3)


def draw_decision(c: Canvas, box: Box, lines: list[tuple[str, bool]]) -> None:
    """The decision block's lines (:func:`decision_lines`) from the top of ``box``."""
    yy = box.top - 6.5
    for s, bold in lines:
        draw_text(c, box.x, yy, s, 7.0, False, FAIL_INK if bold else INK)
        yy -= 8.6
