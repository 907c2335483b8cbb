"""The tables of the inspection page that list the part: tolerances and regions.

* **Tolerances** -- one row per toleranced surface: band, verdict, in-band area, regions,
  profile value (as in the QIF ``Value``), RMS, P99.9 and the signed extremes; failing ones
  are listed first when they do not all fit.
* **Regions** -- the whole part's out-of-tolerance regions, largest first, numbered as on the
  maps.
"""

from __future__ import annotations

import re

from qifreport.kinds import kind_label
from qifreport.metrology.inspection import InspectionResult, ZoneResult
from qifreport.qif.profile_characteristics import profile_value

from .kit import (
    Table,
    fit_text,
    fmt_area,
    fmt_band,
    fmt_mm,
    fmt_pct,
    fmt_smm,
    join_names,
    wrap_text,
)

__all__ = [
    "characteristic_table",
    "not_passing_characteristics",
    "not_passing_tolerances",
    "pick_characteristics",
    "pick_tolerances",
    "region_table",
    "tolerance_table",
    "used_share",
    "wrapped_row",
    "zone_status",
]


def _fmt_coord(x: float) -> str:
    """A coordinate in mm, 1 decimal, never ``-0.0``."""
    s = f"{float(x):.1f}"
    return "0.0" if s == "-0.0" else s


def zone_status(res: InspectionResult, z: ZoneResult) -> str:
    """A toleranced surface's result as the reports print it: ``PASS``, ``FAIL``, ``n/m``
    (not measured: too little of it scored, or its datum frame not established) or ``n/e``
    (its criteria are met but the registration is not trusted, or it lies on a limit
    within the uncertainty); ``info`` for a zone the verdict does not judge (qifreport's
    default band beside a drawing)."""
    if not z.judged:
        return "info"
    if not z.acceptance.scored_area > 0:
        return "n/m"
    if z.failed:
        return "FAIL"
    if not z.measured:
        return "n/m"
    return "n/e" if (not res.established or z.uncertain) else "PASS"


def tolerance_table(res: InspectionResult, width: float, limit: int) -> Table:
    """One row per toleranced surface, ``width`` points wide: band, verdict, in-band area,
    regions, profile value (as in the QIF ``Value``), RMS, P99.9 and the signed extremes;
    at most ``limit`` rows (:func:`pick_tolerances`), the rest counted in the note."""
    cols = [
        ("Key", 30),
        ("Tolerance", 152),
        ("Band, mm", 58),
        ("Result", 30),
        ("In band,\n%", 38),
        ("Regions /\nlargest, mm\u00b2", 60),
        ("Profile,\nmm", 34),
        ("RMS,\nmm", 32),
        ("P99.9,\nmm", 34),
        ("Max,\nmm", 35),
        ("Min,\nmm", 35),
    ]
    scale = width / sum(c[1] for c in cols)
    cols = [
        (h, w * scale, "l" if i < 3 else ("c" if i == 3 else "r")) for i, (h, w) in enumerate(cols)
    ]
    zones = res.zones
    shown = pick_tolerances(res, limit)
    rows, emph = [], []
    for i in shown:
        z = zones[i]
        zone, acc, s = z.zone, z.acceptance, z.stats
        desc = zone.describe()
        cut = desc.find(" [")
        if cut > 0:  # the band has its own column
            desc = desc[:cut] + desc[desc.find("]", cut) + 1 :]
        desc = re.sub(r" \(pmi #\d+\)", "", desc)  # the STEP id is in the QIF file
        if not z.fixtured:
            desc += ", free state"
        status = zone_status(res, z)
        nreg = len(acc.regions)
        rows.append(
            [
                zone.key,
                fit_text(desc, cols[1][1] - 4, 6.8),
                f"[{fmt_band(zone.lower)}, {fmt_band(zone.upper)}]",
                status,
                fmt_pct(acc.in_tolerance_fraction),
                f"{nreg} / {fmt_area(acc.largest_region_area)}" if nreg else "0",
                fmt_mm(profile_value(z)),
                fmt_mm(s.rms),
                fmt_mm(s.p999),
                fmt_smm(s.max_pos),
                fmt_smm(s.min_neg),
            ]
        )
        emph.append(z.failed and z.judged)
    note = ""
    rest = [i for i in range(len(zones)) if i not in set(shown)]
    if rest:
        nr = sum(1 for i in rest if not zones[i].judged)
        nf = sum(1 for i in rest if zones[i].failed and zones[i].judged)
        nu = sum(1 for i in rest if zones[i].uncertain and not zones[i].failed and zones[i].judged)
        keys = join_names([zones[i].zone.key for i in rest], 8)
        counts = zip(
            (nf, nu, len(rest) - nf - nu - nr, nr), ("FAIL", "n/e", "PASS", "info"), strict=True
        )
        said = ", ".join(f"{n} {what}" for n, what in counts if n) or "none"
        note = (
            f"+ {len(rest)} more tolerance{'s' if len(rest) != 1 else ''} not listed "
            f"({said}): {keys} "
            "\u2014 every tolerance is in "
            "the QIF file"
        )
    legend = []
    if any(
        zones[i].status == "NOT MEASURED" or not zones[i].acceptance.scored_area > 0 for i in shown
    ):
        legend.append(
            "n/m = not measured: too little of the surface scored, or its datum frame not "
            "established (see the notes)."
        )
    if any(not zones[i].judged for i in shown):
        legend.append(
            "info = qifreport's default band on faces the drawing does not tolerance: "
            "reported, not judged."
        )
    if not res.established:
        legend.append(
            "n/e = criteria met, not established (registration not trusted; see the warning)."
        )
    elif any(zones[i].uncertain for i in shown):
        legend.append(
            "n/e = not established: on the zone limit within the measurement uncertainty."
        )
    note = " ".join([note, *legend]).strip()
    return Table(
        columns=cols,
        rows=rows,
        note=note,
        emphasis=emph,
        title=f"Tolerances ({len(zones)}), each on its own faces; profile = "
        "width of the smallest zone about the band centre holding all "
        "points",
    )


def pick_tolerances(res: InspectionResult, limit: int) -> list[int]:
    """Indices of the tolerances to list, in file order: every one that does not pass
    (failing, not established, not measured; whatever ``limit``), then passing ones, the
    one whose deviation uses most of its band first, up to ``limit`` in all."""
    zones = res.zones
    if len(zones) <= limit:
        return list(range(len(zones)))

    def used(z: ZoneResult) -> float:
        half = 0.5 * (z.zone.upper - z.zone.lower)
        return float(z.stats.max_abs) / half if half > 0 and z.stats.n else 0.0

    must = [i for i, z in enumerate(zones) if zone_status(res, z) not in ("PASS", "info")]
    ok = [i for i in range(len(zones)) if i not in set(must)]
    ok.sort(key=lambda i: -used(zones[i]))
    return sorted(must + ok[: max(limit - len(must), 0)])


def not_passing_tolerances(res: InspectionResult) -> int:
    """How many toleranced surfaces are not PASS (always listed on the page)."""
    return sum(zone_status(res, z) not in ("PASS", "info") for z in res.zones)


def region_table(res: InspectionResult, limit: int, width: float) -> Table:
    """The whole part's out-of-tolerance regions, largest first (the numbers of the maps),
    ``width`` points wide: area, peak, kind, centroid and the region criterion; at most
    ``limit`` rows, the rest summarised in the note."""
    acc = res.acceptance
    cols = [
        ("#", 16),
        ("Area, mm\u00b2", 46),
        ("Peak, mm", 44),
        ("Kind", 34),
        ("Centroid x, y, z, mm", 118),
        ("Criterion", 42),
    ]
    scale = width / sum(c[1] for c in cols)
    cols = [
        (h, w * scale, "r" if i in (0, 1, 2) else ("l" if i in (3, 4) else "c"))
        for i, (h, w) in enumerate(cols)
    ]
    regs = acc.regions
    rows, emph = [], []
    for k, r in enumerate(regs[:limit], start=1):
        c = r.centroid
        over = r.area > acc.max_region_area
        rows.append(
            [
                str(k),
                fmt_area(r.area),
                fmt_smm(r.peak),
                "proud" if r.sign > 0 else "sunk",
                ", ".join(_fmt_coord(v) for v in c[:3]),
                "> limit" if over else "ok",
            ]
        )
        emph.append(over)
    note = ""
    if len(regs) > limit:
        rest = regs[limit:]
        nover = sum(1 for r in rest if r.area > acc.max_region_area)
        note = (
            f"+ {len(rest)} more regions ({fmt_area(sum(r.area for r in rest))} mm\u00b2 "
            f"in all, {nover} above the limit), see QIF"
        )
    if not regs:
        rows = [["", "none", "", "", "no vertex outside its band", ""]]
        emph = [False]
    title = (
        f"Out-of-tolerance regions, whole part ({len(regs)}; limit "
        f"{acc.max_region_area:g} mm\u00b2)"
    )
    return Table(columns=cols, rows=rows, note=note, emphasis=emph, title=title)


#: the order characteristics are listed in when they do not all fit: what decides first
_CHAR_ORDER = {"FAIL": 0, "INDETERMINATE": 1, "NOT_MEASURED": 2, "PASS": 3, "BASIC": 4}
_CHAR_RESULT = {
    "PASS": "PASS",
    "FAIL": "FAIL",
    "INDETERMINATE": "n/e",
    "NOT_MEASURED": "n/m",
    "BASIC": "basic",
}


def used_share(c) -> float:
    """How much of its tolerance a characteristic's value uses (1: on its limit; a
    dimension: its distance from the middle of its limits over half their width); 0 when
    unknown."""
    s = c.spec
    if c.value is None:
        return 0.0
    tol = (s.tolerance or 0.0) + (c.bonus or 0.0)
    if s.kind != "dimension" and tol > 0:
        return float(c.value) / tol
    lo, hi = s.lower_limit, s.upper_limit
    if lo is not None and hi is not None and hi > lo:
        return abs(float(c.value) - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
    return 0.0


def pick_characteristics(res: InspectionResult, limit: int) -> list[int]:
    """Indices of the feature characteristics to list, in the order listed: failing, not
    established, not measured (all of them, whatever ``limit``), then passing ones, the one
    using most of its tolerance first, up to ``limit`` in all."""
    chars = res.characteristics
    order = sorted(
        range(len(chars)),
        key=lambda i: (_CHAR_ORDER[chars[i].status], -used_share(chars[i]), i),
    )
    must = [i for i in order if chars[i].status not in ("PASS", "BASIC")]
    rest = [i for i in order if chars[i].status in ("PASS", "BASIC")]
    return must + rest[: max(limit - len(must), 0)]


def not_passing_characteristics(res: InspectionResult) -> int:
    """How many feature characteristics are not PASS (always listed on the page)."""
    return sum(c.status not in ("PASS", "BASIC") for c in res.characteristics)


def wrapped_row(cells: list[str], widths: dict[int, float], size: float) -> list[list[str]]:
    """A table row whose cells ``widths`` names (column -> points) wrap onto a continuation
    row instead of being cut (two lines a cell at most, the second cut if need be)."""
    split = {k: wrap_text(cells[k], w, size) for k, w in widths.items()}
    for k, lines in split.items():
        if len(lines) > 2:
            rest = " ".join(lines[1:])
            split[k] = [lines[0], fit_text(rest, widths[k], size)]
    n = max(len(v) for v in split.values())
    rows = []
    for j in range(n):
        row = [cells[k] if j == 0 else "" for k in range(len(cells))]
        for k, lines in split.items():
            row[k] = lines[j] if j < len(lines) else ""
        rows.append(row)
    return rows


def characteristic_table(res: InspectionResult, width: float, limit: int) -> Table | None:
    """One row per feature characteristic of the drawing (form, orientation, location,
    runout, dimensions), ``width`` points wide: what, measured value, limit, expanded
    uncertainty, result and how it was read; at most ``limit`` rows, the rest counted by
    result in the note. None when the drawing has none."""
    chars = res.characteristics
    if not chars:
        return None
    cols = [
        ("Key", 24),
        ("Characteristic", 128),
        ("Value", 44),
        ("Limit", 66),
        ("U (k=2)", 36),
        ("Result", 30),
        ("Reading / reason", 226),
    ]
    scale = width / sum(c[1] for c in cols)
    align = "llrrrcl"
    cols = [(h, w * scale, align[i]) for i, (h, w) in enumerate(cols)]
    shown = pick_characteristics(res, limit)
    rows, emph = [], []
    wide = {1: cols[1][1] - 4, 3: cols[3][1] - 4, 6: cols[6][1] - 4}
    for i in shown:
        c = chars[i]
        s = c.spec
        what = kind_label(s.kind) if s.kind != "dimension" else s.dim_type or "dimension"
        if s.datums:
            what += " |" + "|".join(s.datums) + "|"
        what += f" {s.name}"
        unit = "\u00b0" if s.unit == "deg" else ""
        value = "-" if c.value is None else f"{c.value:.4f}{unit}"
        limit_text = s.limits_text()
        if c.bonus > 0:
            limit_text += f" +{c.bonus:.3f}"
        how = c.reason if c.status in ("NOT_MEASURED", "FAIL") else c.reading
        cells = [
            s.key,
            what,
            value,
            limit_text,
            fmt_mm(c.uncertainty) if c.uncertainty is not None else "-",
            _CHAR_RESULT[c.status],
            how,
        ]
        lines = wrapped_row(cells, wide, 6.8)
        rows += lines
        emph += [c.status == "FAIL"] * len(lines)
    note = ""
    rest = [chars[i] for i in range(len(chars)) if i not in set(shown)]
    if rest:
        counts = {}
        for c in rest:
            counts[_CHAR_RESULT[c.status]] = counts.get(_CHAR_RESULT[c.status], 0) + 1
        listing = ", ".join(f"{n} {k}" for k, n in counts.items())
        most = max((used_share(c) for c in rest), default=0.0)
        note = (
            f"+ {len(rest)} more ({listing}), each using at most {100 * most:.0f} % of its "
            "tolerance (values in the QIF file)"
        )
    legend = []
    statuses = {chars[i].status for i in shown}
    if "INDETERMINATE" in statuses:
        legend.append("n/e = within the uncertainty of its limit")
    if "NOT_MEASURED" in statuses:
        legend.append("n/m = not measured (reason given)")
    if any(c.budget is not None for c in chars):
        legend.append("U: the uncertainty budget, with the instrument the header names")
    if legend:
        note = (note + " " + "; ".join(legend) + ".").strip()
    title = (
        f"Feature characteristics ({len(chars)}): form by the minimum zone, "
        "datum-referenced ones in their datum frame"
    )
    if len(shown) < len(chars):  # short of room: the count in the heading, no title line
        cols[1] = (f"Feature characteristic ({len(chars)})", cols[1][1], cols[1][2])
        title = ""
    return Table(columns=cols, rows=rows, note=note, emphasis=emph, title=title)
