"""A characteristic's uncertainty budget (:class:`~qifreport.metrology.acceptance.budget.
UncertaintyBudget`): the measurement's own terms (the points' statistics, the datum frame,
the mesh), the instrument's from the scanner profile and the temperature's, combined; the
value is then judged (ISO 14253-1) with ``U = 2 u_c``.

The instrument term by what the value is (each figure a maximum permissible error, its
standard uncertainty ``MPE / sqrt(3)``):

=======================  ================================================================
a diameter (radius)      PS (PS / 2): a sphere's size error
a distance               E(L), ``L`` the distance
an angle                 PF across the features' extent ``L``: ``sqrt(2) PF / L`` rad
form, orientation,       PF (F for a plane when the profile gives it): the range a perfect
runout, a profile        feature's points take about it
without datums
location, a profile      2 E(L): the value is twice the feature's displacement, ``L`` the
with datums              feature's distance from the model's origin (where the datums'
                         frame is put) at least its own extent
=======================  ================================================================

A length's temperature term (``alpha |T - 20| L``) is added when the profile gives the
part's temperature and CTE. With ``--seeds N`` (N >= 2) a **registration** term is added
too (:func:`registration_term`): the value's spread over the resampled registrations.
Without it the budget has no registration term and says so by its absence. Lengths mm,
angles degrees.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from qifreport.kinds import lookup_kind
from qifreport.metrology.acceptance.budget import (
    UncertaintyBudget,
    rectangular,
    temperature_term,
)
from qifreport.metrology.acceptance.scanner import ScannerProfile
from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    implausible,
    judge,
    not_measured,
)
from qifreport.metrology.gdt.measured_surface import MeasuredSurface

__all__ = ["JUDGED", "apply_budget", "registration_term", "sampling_budget"]

#: the statuses the decision rule gives (re-judged with the budget's ``U``)
JUDGED = ("PASS", "FAIL", "INDETERMINATE")


def sampling_budget(U_sampling: float, frame_U: float = 0.0, mesh_U: float = 0.0):
    """The measurement's own terms from their expanded uncertainties (k = 2), mm: the
    points' statistics, the datum frame's fit, the mesh's difference from the scan
    points."""
    budget = UncertaintyBudget()
    budget.add("sampling", 0.5 * U_sampling, "the points' scatter about the fitted feature")
    budget.add("datum frame", 0.5 * frame_U, "the datum frame's fit to its datums' points")
    budget.add("mesh", 0.5 * mesh_U, "the reading on the mesh's vertices vs the scan points")
    return budget


def apply_budget(
    res: CharacteristicResult,
    scanner: ScannerProfile,
    surf: MeasuredSurface,
    rule: str,
) -> CharacteristicResult:
    """``res`` with its budget (module docstring): the measurement's terms
    (``res.budget``, or its ``uncertainty`` as the one sampling term), the instrument's and
    the temperature's; ``res.uncertainty`` becomes the budget's ``U`` and a judged value is
    judged again with it by ``rule``. A value that is not measured, or has no uncertainty,
    is returned as it is."""
    U0 = res.uncertainty
    if res.value is None or U0 is None or not math.isfinite(U0):
        return res
    if res.status not in (*JUDGED, "BASIC"):
        return res
    budget = res.budget if res.budget is not None else sampling_budget(U0)
    budget.scanner = scanner.label
    length = _instrument(budget, res, scanner, surf)
    if length is not None:
        temp = temperature_term(scanner, length)
        if temp is not None:
            budget.add("temperature", *temp)
    res.budget = budget
    return _judged_again(res, rule, surf.diagonal)


def registration_term(
    res: CharacteristicResult, values: Sequence[float | None], rule: str, diagonal: float
) -> CharacteristicResult:
    """``res`` with its budget's **registration** term: the repeatability of the whole
    measurement chain (pose, fixture, deviation, fit) over resampled registrations of the
    scan (``--seeds``), the standard deviation of ``res.value`` and the resampled runs'
    ``values`` (GUM 4.2, a Type A evaluation), and judged again by ``rule`` with the new
    ``U`` (``diagonal``: the part's size, mm). A characteristic without a budget or a value,
    or with fewer than two readings of it, is returned as it is.

    Parameters
    ----------
    res : the reported run's result (its budget is added to in place).
    values : the same characteristic's value in each resampled run, mm or deg (None: not
        measured there).
    """
    if res.budget is None or res.value is None or res.status not in (*JUDGED, "BASIC"):
        return res
    got = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not got:
        return res
    u = float(np.std([float(res.value), *got], ddof=1))
    res.budget.add(
        "registration",
        u,
        f"standard deviation over the reported and {len(got)} resampled registrations (--seeds)",
    )
    return _judged_again(res, rule, diagonal)


def _judged_again(res: CharacteristicResult, rule: str, diagonal: float) -> CharacteristicResult:
    """``res`` with ``uncertainty`` its budget's ``U``, judged again by ``rule``."""
    res.uncertainty = res.budget.expanded
    if res.status == "BASIC":
        why = implausible(res, diagonal)
        return res if why is None else not_measured(res.spec, why)
    s = res.spec
    lo, hi = (s.lower_limit, s.upper_limit) if s.kind == "dimension" else (None, res.limit)
    res.reason = ""
    judge(res, rule, lo, hi, diagonal)
    if res.status == "INDETERMINATE" and res.budget.terms:
        top = max(res.budget.terms, key=lambda t: t.u)
        res.reason += (
            f"; its largest term: {top.name}, u {top.u:.2g} {res.spec.unit} ({top.source})"
        )
    return res


def _instrument(
    budget: UncertaintyBudget, res: CharacteristicResult, scanner: ScannerProfile, surf
) -> float | None:
    """Add the instrument term of ``res`` (module docstring) to ``budget``; the length a
    temperature term applies to (mm), None for an angle or a form."""
    s = res.spec
    who = scanner.label
    if s.kind == "dimension":
        if s.unit == "deg":
            extent = _extent(surf, _dimension_faces(s))
            u = math.degrees(math.sqrt(2.0) * rectangular(scanner.probing_form) / extent)
            budget.add("instrument", u, f"PF {scanner.probing_form:g} mm over {extent:.4g} mm")
            return None
        if s.dim_type.endswith(("diameter", "radius")):  # a spherical one too
            share = 1.0 if s.dim_type.endswith("diameter") else 0.5
            u = share * rectangular(scanner.probing_size)
            budget.add("instrument", u, f"PS {scanner.probing_size:g} mm ({who}), rectangular")
            return abs(res.value)
        L = abs(s.nominal if s.nominal is not None else res.value)
        E = scanner.length_error(L)
        budget.add("instrument", rectangular(E), f"E(L={L:.4g} mm) {E:.4g} mm ({who})")
        return L
    kind = lookup_kind(s.kind)
    family = kind.family if kind is not None else "form"
    if family == "location" or (family == "profile" and s.datums):
        L = _location_length(surf, s.faces)
        E = scanner.length_error(L)
        u = rectangular(2.0 * E)
        budget.add("instrument", u, f"2 E(L={L:.4g} mm) {2 * E:.4g} mm ({who}), rectangular")
        return L
    feat = surf.nominal(s.faces) if len(s.faces) else None
    plane = feat is not None and feat.kind == "plane"
    mpe = scanner.form_error(plane)
    what = "F" if plane and scanner.flatness is not None else "PF"
    budget.add("instrument", rectangular(mpe), f"{what} {mpe:g} mm ({who}), rectangular")
    return None


def _dimension_faces(spec) -> np.ndarray:
    """All faces of a dimension (its own, or its origin's and target's)."""
    parts = [spec.faces, spec.origin_faces, spec.target_faces]
    return np.concatenate([np.asarray(p, dtype=np.int64) for p in parts if p is not None])


def _extent(surf: MeasuredSurface, faces) -> float:
    """The diagonal of the box around ``faces``' vertices, mm (the part's when none)."""
    v = surf.own_vertices(faces) if len(faces) else np.empty(0, dtype=np.int64)
    if len(v) < 2:
        return surf.diagonal
    X = surf.V[v]
    return max(float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))), 1e-3)


def _location_length(surf: MeasuredSurface, faces) -> float:
    """A located feature's length for E(L): its centroid's distance from the model's
    origin, at least its own extent, at most the part's diagonal, mm."""
    v = surf.own_vertices(faces) if len(faces) else np.empty(0, dtype=np.int64)
    if not len(v):
        return surf.diagonal
    X = surf.V[v]
    L = max(float(np.linalg.norm(X.mean(axis=0))), _extent(surf, faces))
    return min(L, surf.diagonal)
