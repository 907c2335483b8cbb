"""The tables of the inspection page that list the part: tolerances and regions.

* **Tolerances** -- one row per toleranced surface: band, verdict, in-band area, regions,
  profile value (as in the QIF ``Value``), RMS, P99.9 and the signed extremes; failing ones
  are listed first when they do not all fit.
* **Regions** -- the whole part's out-of-tolerance regions, largest first, numbered as on the
  maps.
"""

from __future__ import annotations

from qifreport.kinds import kind_label
from qifreport.metrology.inspection import InspectionResult, ZoneResult
from qifreport.qif.profile_characteristics import profile_value

from .kit import Table, fit_text, fmt_area, fmt_band, fmt_mm, fmt_pct, fmt_smm, join_names

__all__ = [
    "characteristic_table",
    "pick_characteristics",
    "pick_tolerances",
    "region_table",
    "tolerance_table",
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
    if not res.established:
        note = (
            "n/e = criteria met, not established (registration not trusted; see the "
            "warning). " + note
        ).strip()
    elif any(zones[i].uncertain for i in shown):
        note = (
            "n/e = not established: on the zone limit within the measurement uncertainty. " + note
        ).strip()
    if any(not zones[i].judged for i in shown):
        note = (
            "info = qifreport's default band on faces the drawing does not tolerance: "
            "reported, not judged. " + note
        ).strip()
    if any(
        zones[i].status == "NOT MEASURED" or not zones[i].acceptance.scored_area > 0 for i in shown
    ):
        note = (
            "n/m = not measured: too little of the surface scored, or its datum frame not "
            "established (see the notes). " + note
        ).strip()
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
    """Indices of the tolerances to list: failing ones first, then in file order."""
    zones = res.zones
    if len(zones) <= limit:
        return list(range(len(zones)))
    fail = [i for i, z in enumerate(zones) if z.failed]
    ok = [i for i, z in enumerate(zones) if not z.failed]
    return sorted((fail + ok)[: max(limit, 0)])


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


def pick_characteristics(res: InspectionResult, limit: int) -> list[int]:
    """Indices of the feature characteristics to list: failing, then not established, then
    not measured, then passing ones, each in file order; at most ``limit``."""
    chars = res.characteristics
    order = sorted(range(len(chars)), key=lambda i: (_CHAR_ORDER[chars[i].status], i))
    return sorted(order[: max(limit, 0)])


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
        ("Characteristic", 150),
        ("Value", 44),
        ("Limit", 70),
        ("U (k=2)", 36),
        ("Result", 30),
        ("Reading / reason", 200),
    ]
    scale = width / sum(c[1] for c in cols)
    align = "llrrrcl"
    cols = [(h, w * scale, align[i]) for i, (h, w) in enumerate(cols)]
    shown = pick_characteristics(res, limit)
    rows, emph = [], []
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
        rows.append(
            [
                s.key,
                fit_text(what, cols[1][1] - 4, 6.8),
                value,
                fit_text(limit_text, cols[3][1] - 4, 6.8),
                fmt_mm(c.uncertainty) if c.uncertainty is not None else "-",
                _CHAR_RESULT[c.status],
                fit_text(how, cols[6][1] - 4, 6.8),
            ]
        )
        emph.append(c.status == "FAIL")
    note = ""
    rest = [chars[i] for i in range(len(chars)) if i not in set(shown)]
    if rest:
        counts = {}
        for c in rest:
            counts[_CHAR_RESULT[c.status]] = counts.get(_CHAR_RESULT[c.status], 0) + 1
        listing = ", ".join(f"{n} {k}" for k, n in counts.items())
        note = f"+ {len(rest)} more in the QIF file ({listing})"
    legend = []
    statuses = {chars[i].status for i in shown}
    if "INDETERMINATE" in statuses:
        legend.append("n/e = within the uncertainty of its limit")
    if "NOT_MEASURED" in statuses:
        legend.append("n/m = not measured (reason given)")
    if any(c.budget is not None for c in chars):
        legend.append(f"U: uncertainty budget, instrument {res.params.scanner.label}")
    if legend:
        note = ("; ".join(legend) + ". " + note).strip()
    title = (
        f"Feature characteristics ({len(chars)}): form by the minimum zone, "
        "datum-referenced ones in their datum frame"
    )
    if len(shown) < len(chars):  # short of room: the count in the heading, no title line
        cols[1] = (f"Feature characteristic ({len(chars)})", cols[1][1], cols[1][2])
        title = ""
    return Table(columns=cols, rows=rows, note=note, emphasis=emph, title=title)
