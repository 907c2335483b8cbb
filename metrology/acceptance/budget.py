"""A measured value's uncertainty budget (GUM, JCGM 100:2008): its contributors' standard
uncertainties, combined by root-sum-square, expanded at k = 2.

Each term (:class:`BudgetTerm`) is one contributor, already a standard uncertainty of the
value (mm, or deg for an angle), with what it comes from:

* **sampling**: the points' statistics (their scatter about the fitted feature over the
  points that measure it, the extremes of a zone), as the measurement computes it;
* **datum frame**: the frame's own fit, for a tolerance read in it (the registration of the
  feature to its datums);
* **mesh**: the difference of a reading on the mesh's vertices from the same reading on
  the scan points (a chord or smoothing effect of the deviation field);
* **instrument**: the scanner's acceptance figures
  (:class:`~qifreport.metrology.acceptance.scanner.ScannerProfile`), each a maximum
  permissible error taken as the half-width of a rectangular distribution
  (``u = MPE / sqrt(3)``, GUM 4.3.7);
* **temperature**: a part scanned away from 20 deg C, ``alpha * |T - 20| * L`` taken the
  same way.

The decision rule (ISO 14253-1) judges the value against its limits with ``U = 2 u_c``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from qifreport.metrology.acceptance.scanner import REFERENCE_TEMPERATURE, ScannerProfile

__all__ = [
    "COVERAGE_FACTOR",
    "BudgetTerm",
    "UncertaintyBudget",
    "rectangular",
    "temperature_term",
]

#: the coverage factor of a stated expanded uncertainty
COVERAGE_FACTOR = 2.0


@dataclass(frozen=True)
class BudgetTerm:
    """One contributor of a budget.

    Attributes
    ----------
    name : ``'sampling'``, ``'datum frame'``, ``'mesh'``, ``'instrument'``,
        ``'temperature'`` ...
    u : its standard uncertainty of the value, mm (deg for an angle).
    source : what it comes from (the figure and the distribution).
    """

    name: str
    u: float
    source: str

    def to_dict(self) -> dict:
        return {"name": self.name, "standard_uncertainty": float(self.u), "source": self.source}


@dataclass
class UncertaintyBudget:
    """A value's budget: its terms, and the scanner whose figures it used.

    Attributes
    ----------
    terms : the contributors (:class:`BudgetTerm`).
    scanner : the instrument's name as outputs state it
        (:attr:`~qifreport.metrology.acceptance.scanner.ScannerProfile.label`; ``''``: no
        instrument term).
    """

    terms: list[BudgetTerm] = field(default_factory=list)
    scanner: str = ""

    @property
    def combined(self) -> float:
        """The combined standard uncertainty ``u_c``: the terms' root-sum-square."""
        return math.sqrt(sum(t.u * t.u for t in self.terms))

    @property
    def expanded(self) -> float:
        """``U = k u_c``, k = :data:`COVERAGE_FACTOR`."""
        return COVERAGE_FACTOR * self.combined

    def add(self, name: str, u: float, source: str) -> None:
        """A term more (none when ``u`` is 0)."""
        if u > 0.0:
            self.terms.append(BudgetTerm(name, float(u), source))

    def to_dict(self) -> dict:
        return {
            "scanner": self.scanner,
            "coverage_factor": COVERAGE_FACTOR,
            "combined_standard_uncertainty": self.combined,
            "expanded_uncertainty": self.expanded,
            "terms": [t.to_dict() for t in self.terms],
        }


def rectangular(mpe: float) -> float:
    """The standard uncertainty of a maximum permissible error ``mpe`` taken as the
    half-width of a rectangular distribution (GUM 4.3.7): ``mpe / sqrt(3)``."""
    return mpe / math.sqrt(3.0)


def temperature_term(scanner: ScannerProfile, length: float) -> tuple[float, str] | None:
    """The standard uncertainty (mm) of a length ``length`` mm scanned at the profile's
    temperature, uncorrected: ``alpha |T - 20| L`` as a rectangular bound, and its source;
    None without a temperature and a CTE."""
    T, alpha = scanner.temperature, scanner.cte
    if T is None or alpha is None or length <= 0.0:
        return None
    dT = abs(T - REFERENCE_TEMPERATURE)
    bound = alpha * dT * length
    return rectangular(bound), (
        f"alpha {alpha:g}/K x |{T:g} - 20| K x L {length:.4g} mm = {bound:.3g} mm, rectangular"
    )
