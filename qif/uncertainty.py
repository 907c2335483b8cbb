"""The instrument and the uncertainty budgets in QIF: the scanner as a ``MeasurementDevice``
of ``MeasurementResources`` (its acceptance figures typed ``Attributes``), each
characteristic measurement naming it (``MeasurementDeviceIds``), its ``Value``'s
``combinedUncertainty`` (the budget's ``u_c``, with ``meanError`` 0: the value is taken as
unbiased), and the budget's terms as ``Attributes`` of the measurement
(``budget_<term>_u``, mm or deg, and ``budget_<term>_source``; ``budget_scanner``), read
back by :func:`budget_from_attributes`.
"""

from __future__ import annotations

from lxml import etree

from qifreport.metrology.acceptance.budget import BudgetTerm, UncertaintyBudget
from qifreport.metrology.acceptance.scanner import ScannerProfile

from .xmlkit import Attrs, E, dec, token

__all__ = [
    "budget_attributes",
    "budget_from_attributes",
    "measurement_resources",
    "uncertainty_attributes",
]

_PREFIX = "budget_"


def measurement_resources(scanner: ScannerProfile, device_id: str) -> etree._Element:
    """``MeasurementResources`` holding the scanner, ``MeasurementDevice`` ``device_id``."""
    fig = Attrs().b("default_scanner_class", scanner.default)
    fig.d("probing_form_PF_mm", scanner.probing_form).d("probing_size_PS_mm", scanner.probing_size)
    fig.d("length_error_A_mm", scanner.length_a).d("length_error_K", scanner.length_k)
    fig.d("flatness_F_mm", scanner.flatness).d("temperature_C", scanner.temperature)
    fig.d("cte_per_K", scanner.cte)
    description = (
        f"{scanner.label}: ISO 10360-8 / VDI/VDE 2634-2 acceptance figures, the instrument "
        f"terms of each characteristic's uncertainty budget; {scanner.source}"
    )
    device = [E.Name(token(scanner.name)), E.Description(description)]
    if scanner.model:
        device.append(E.ModelNumber(scanner.model))
    device.append(fig.element())
    devices = E.MeasurementDevices(E.MeasurementDevice(*device, id=device_id), n="1")
    return E.MeasurementResources(devices)


def budget_attributes(attrs: Attrs, budget: UncertaintyBudget | None) -> None:
    """The budget's scanner and terms added to a measurement's ``attrs``."""
    if budget is None:
        return
    if budget.scanner:
        attrs.s(f"{_PREFIX}scanner", budget.scanner)
    for t in budget.terms:
        key = "_".join(t.name.split())
        attrs.d(f"{_PREFIX}{key}_u", t.u).s(f"{_PREFIX}{key}_source", t.source)


def uncertainty_attributes(budget: UncertaintyBudget | None) -> dict[str, str]:
    """A ``Value``'s QIF uncertainty attributes: ``combinedUncertainty`` (the budget's
    ``u_c``) and ``meanError`` (0); none without a budget."""
    if budget is None:
        return {}
    return {"combinedUncertainty": dec(budget.combined), "meanError": dec(0.0)}


def budget_from_attributes(attrs: dict) -> UncertaintyBudget | None:
    """The budget written by :func:`budget_attributes` (None when there is none)."""
    terms = []
    for name, value in attrs.items():
        if not (name.startswith(_PREFIX) and name.endswith("_u")):
            continue
        key = name[len(_PREFIX) : -2]
        if isinstance(value, int | float) and not isinstance(value, bool):
            source = str(attrs.get(f"{_PREFIX}{key}_source", ""))
            terms.append(BudgetTerm(key.replace("_", " "), float(value), source))
    if not terms:
        return None
    return UncertaintyBudget(terms, str(attrs.get(f"{_PREFIX}scanner", "")))
