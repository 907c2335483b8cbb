"""Plausibility of the tolerance values read from a STEP file, against the part's size.

A file that states its tolerances in the wrong unit (metres declared, millimetres meant) reads
without error, and the inspection would then score the part against zones a thousand times too
wide: everything passes. :func:`implausible_tolerances` names every value no drawing would
give; the caller refuses the part unless the user accepts the values as read.

The rule
--------
With ``D`` the diagonal of the part's bounding box and ``t`` the wall thickness of a thin-walled
part (optional), a value is implausible when

* a geometric tolerance zone (:attr:`GeometricTolerance.value`, and its
  :attr:`GeometricTolerance.max_value`), of any characteristic, is wider than
  ``fraction * D`` (``fraction`` = 0.10 by default);
* the tolerance band of a length dimension (``upper - lower``, or ``upper_limit -
  lower_limit``) is wider than ``fraction * D``;
* a profile zone (``surface_profile``, ``line_profile``) is wider than ``t``, when ``t`` is
  given: a zone wider than the wall itself bounds nothing on a thin wall. Automotive skins can
  have a profile zone above the sheet thickness; that is what accepting the values as read is
  for;
* any of these values is negative or not finite;
* the geometric tolerances are all stated in millimetres while every length dimension of the
  same file is in inches, and no tolerance reaches 0.254 mm (:data:`INCH_NUMBERS_BELOW`, 0.01
  inch): an exporter that wrote the drawing's inch numbers under a millimetre unit (a NIST
  CTC 03 edition: 0.005-0.08 "mm" beside inch dimensions), whose zones would read 25.4 times
  too tight. Read as stated only when the user accepts the values as read.

Zero is not flagged (a zero position tolerance at maximum material is a real callout), nor are
angles, nominal values, or values the reader could not establish (``None``, which carry their
own problem). Values are in millimetres, as :mod:`qifreport.step.semantic` returns them.
"""

from __future__ import annotations

import math

from qifreport.kinds import lookup_kind

from .pmi import PMI

__all__ = [
    "DIAGONAL_FRACTION",
    "INCH_NUMBERS_BELOW",
    "file_warnings",
    "implausible_tolerances",
    "inch_numbers_under_mm",
]

#: default largest plausible tolerance width, as a fraction of the part's diagonal
DIAGONAL_FRACTION = 0.10

#: mm: millimetre tolerances all below this beside inch dimensions look like inch numbers
INCH_NUMBERS_BELOW = 0.254


def _positive(name: str, value: object) -> float:
    """``value`` as a positive finite float, else ``ValueError`` naming ``name``."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def _verdict(width: float, limit: float, fraction: float, thickness: float | None) -> list[str]:
    """Why ``width`` (mm) is implausible; ``[]`` when it is not. ``thickness`` only for a
    profile zone."""
    if not math.isfinite(width) or width < 0:
        return ["not a tolerance width (negative or not finite)"]
    why = []
    if width > limit:
        why.append(f"wider than {fraction:.0%} of the part's diagonal (limit {limit:.4g} mm)")
    if thickness is not None and width > thickness:
        why.append(
            f"than the wall ({thickness:g} mm thick)"
            if why
            else f"wider than the wall ({thickness:g} mm thick)"
        )
    return why


def implausible_tolerances(
    pmi: PMI | None,
    diagonal_mm: float,
    thickness_mm: float | None = None,
    *,
    fraction: float = DIAGONAL_FRACTION,
) -> list[str]:
    """Name every tolerance value implausible for a part of this size (the module's rule).

    Parameters
    ----------
    pmi : PMI or None
        The semantic PMI (:func:`qifreport.step.semantic.read_pmi_text`), values in mm;
        ``None`` gives ``[]``.
    diagonal_mm : float
        Diagonal of the part's bounding box, mm (> 0).
    thickness_mm : float, optional
        Wall thickness of a thin-walled part, mm (> 0); ``None`` (default) applies no wall
        rule.
    fraction : float, optional
        Largest plausible width as a fraction of ``diagonal_mm`` (default 0.10).

    Returns
    -------
    list of str
        One reason per implausible value, in file order (tolerances, then dimensions), e.g.
        ``"#52 surface_profile 'skin': 1000 mm (file: '1. METRE') is wider than 10% of the
        part's diagonal (limit 30 mm)"``; ``[]`` when every value is plausible.

    Raises
    ------
    ValueError
        When ``diagonal_mm``, ``thickness_mm`` or ``fraction`` is not a positive finite number.
    """
    diagonal = _positive("diagonal_mm", diagonal_mm)
    thickness = None if thickness_mm is None else _positive("thickness_mm", thickness_mm)
    frac = _positive("fraction", fraction)
    if pmi is None:
        return []
    limit = frac * diagonal
    out: list[str] = []
    for tol in pmi.tolerances:
        label = f"#{tol.step_id} {tol.type}" + (f" {tol.name!r}" if tol.name else "")
        # a profile's zone is a band about the surface: checked against a thin wall
        kind = lookup_kind(tol.type)
        wall = thickness if kind is not None and kind.family == "profile" else None
        for what, value in (("", tol.value), (" maximum", tol.max_value)):
            if value is None:
                continue
            why = _verdict(float(value), limit, frac, wall)
            if why:
                src = f" (file: {tol.value_text!r})" if tol.value_text and not what else ""
                out.append(f"{label}{what}: {float(value):g} mm{src} is " + " and ".join(why))
    for dim in pmi.dimensions:
        if dim.unit != "mm":
            continue
        label = f"#{dim.step_id} {dim.type} dimension"
        for what, lo, hi in (
            ("tolerance band", dim.lower, dim.upper),
            ("limits", dim.lower_limit, dim.upper_limit),
        ):
            if lo is None or hi is None:
                continue
            width = float(hi) - float(lo)
            why = _verdict(width, limit, frac, None)
            if why:
                src = f" (file: {dim.value_text!r})" if dim.value_text else ""
                band = f"{what} {float(lo):g}..{float(hi):g}"
                out.append(f"{label} {band}: {width:g} mm{src} is " + " and ".join(why))
    mixed = inch_numbers_under_mm(pmi)
    if mixed:
        out.append(mixed)
    return out


def _unit_of(value_text: str) -> str:
    """``'mm'``, ``'inch'`` or ``''`` for the unit a value's file text names
    (``'0.005 MILLI METRE'``, ``'0.25 INCH'``; limits after a ``;`` are the same unit)."""
    parts = value_text.split(";", 1)[0].split(None, 1)
    unit = parts[1].strip().lower() if len(parts) == 2 else ""
    if "inch" in unit:
        return "inch"
    if unit in ("mm", "milli metre", "millimetre", "millimeter", "milli meter"):
        return "mm"
    return ""


def inch_numbers_under_mm(pmi: PMI) -> str:
    """Why the file's millimetre tolerances look like inch numbers (the module's last rule),
    or ``""``: every geometric tolerance in mm, every length dimension in inch, none of
    the tolerances reaching :data:`INCH_NUMBERS_BELOW`."""
    tols = [(t, _unit_of(t.value_text or "")) for t in pmi.tolerances if t.value is not None]
    dims = [_unit_of(d.value_text or "") for d in pmi.dimensions if d.unit == "mm" and d.value_text]
    if not tols or not dims or any(u != "mm" for _, u in tols) or any(u != "inch" for u in dims):
        return ""
    values = [float(t.value) for t, _ in tols]
    if max(values) >= INCH_NUMBERS_BELOW:
        return ""
    lo, hi = min(values), max(values)
    return (
        f"the {len(values)} geometric tolerances are stated in mm ({lo:g}-{hi:g} mm) while "
        f"all {len(dims)} length dimensions are in inch: inch numbers under a millimetre "
        f"unit would read 25.4 times too tight ({25.4 * lo:g}-{25.4 * hi:g} mm in inch)"
    )


def file_warnings(pmi: PMI) -> list[str]:
    """What ``pmi`` and ``plan`` warn of, one line each: the exporter quirks the reader put
    right (:meth:`~qifreport.step.pmi.PMI.reader_warnings`) and the inch numbers a mm unit
    may carry (:func:`inch_numbers_under_mm`; the inspection refuses those)."""
    suspect = inch_numbers_under_mm(pmi)
    return [*pmi.reader_warnings(), *([suspect] if suspect else [])]
