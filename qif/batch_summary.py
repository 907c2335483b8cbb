"""A batch of inspections reduced to per-characteristic statistics (:func:`summarize`): the
QIF results documents read back (:func:`qifreport.qif.reader.read_results`), grouped by
designator (a toleranced surface's zone key, ``"T1"``, ``"general"``; a feature
characteristic's key, ``"G1"``, ``"D3"``), each group's values, limits and capability
indices. :mod:`qifreport.qif.statistics` writes them as a QIF 3.0 statistics document.

A geometric tolerance is carried by its kind's statistics rule
(:class:`qifreport.kinds.StatisticsRule`, found by its QIF type); a dimension by its type
(:data:`LINEAR_DIMENSION_KINDS`, :data:`ANGULAR_DIMENSION_KINDS`).

Capability
----------
A profile or geometric tolerance is one-sided: the value is a zone width, at least 0, and the
characteristic conforms when it is at most ``ToleranceValue``. The lower specification limit
is 0 and the upper ``USL = ToleranceValue``. ``Cp = (USL - LSL) / (6 sigma)`` supposes a
two-sided tolerance with a process centred between the limits; it has no meaning here and
``Cp`` is not written. ``Cpk`` is the upper index only, with the batch's sample standard
deviation ``s``::

    Cpk = (USL - mean) / (3 s)

(the schema's ``CapabilityCalculationMethod`` ``THREE_SIGMA`` for one-sided tolerances),
written when ``count >= 2`` and ``s > 0``. A zone width is bounded below by 0 and skewed, so
the normal-tail reading of a ``Cpk`` (e.g. 1.33 ~ 32 ppm) is an approximation. A position's
tolerance is the stated one (an MMC/LMC bonus, which differs from part to part, is not
added).

A dimension is two-sided, between ``LSL`` and ``USL`` (its limits;
:func:`qifreport.metrology.spc.capability`)::

    Cp  = (USL - LSL) / (6 s)
    Cpk = min(USL - mean, mean - LSL) / (3 s)

each written when ``count >= 2`` and ``s > 0`` (``Cp`` only with both limits; with one
limit ``Cpk`` is that side's index). With the overall sample deviation (no rational
subgroups) the indices are what AIAG SPC calls ``Pp`` and ``Ppk``; they are written as ``Cp``
and ``Cpk``, the names the product uses.

"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from lxml import etree

from qifreport.kinds import StatisticsRule, kind_for_qif_type
from qifreport.metrology.gdt.characteristic_types import CharacteristicResult
from qifreport.metrology.spc import capability, upper_cpk

from .feature_characteristics import (
    ANGULAR_DIMENSION_KINDS,
    DIMENSION_KINDS,
    LINEAR_DIMENSION_KINDS,
)
from .reader import Limits, QIFResults, child_text, definition_limits
from .xsd import DocumentRefused, parse_document

__all__ = [
    "ANGULAR_DIMENSION_KINDS",
    "DIMENSION_KINDS",
    "LINEAR_DIMENSION_KINDS",
    "CharacteristicSummary",
    "Limits",
    "Observation",
    "Source",
    "characteristic_description",
    "designator_of",
    "from_results",
    "group_batch",
    "qif_type_of",
    "is_supported",
    "statistics_rule",
    "summarize",
    "summary_of",
]

log = logging.getLogger("qifreport.statistics")


def statistics_rule(kind: str) -> StatisticsRule | None:
    """How the statistics carry a geometric tolerance of QIF type ``kind`` (``"Flatness"``):
    its registered kind's rule (:data:`qifreport.kinds.KINDS`); None when ``kind`` is not a
    registered tolerance kind's type (a dimension's, another)."""
    k = kind_for_qif_type(kind)
    return None if k is None else k.statistics


def is_supported(kind: str) -> bool:
    """Whether a characteristic of QIF type ``kind`` can be carried (a geometric tolerance
    with a statistics rule, or a dimension): ``<kind>CharacteristicStats`` exists."""
    return statistics_rule(kind) is not None or kind in DIMENSION_KINDS


def from_results(kind: str) -> bool:
    """Whether a characteristic of QIF type ``kind`` is carried from its results as read back
    (a surface profile: tolerance in the results, no definition copied)."""
    rule = statistics_rule(kind)
    return rule is not None and rule.from_results


@dataclass
class CharacteristicSummary:
    """Statistics of one characteristic over a batch of inspections.

    Attributes
    ----------
    designator : str
        The characteristic's designator (qifreport: the zone key, ``"T1"``, ``"general"``,
        or the feature characteristic's key, ``"G1"``, ``"D3"``); its name when it has none.
    kind : str
        QIF characteristic type without suffix, e.g. ``"SurfaceProfile"``, ``"Flatness"``,
        ``"Diameter"``.
    description : str or None
        The definition's description (first one seen).
    tolerance : float or None
        A profile's or geometric tolerance's ``ToleranceValue`` (mm): the upper specification
        limit of the value; None for a dimension.
    count : int
        Measurements with a finite value.
    mean, std : float
        Mean and sample standard deviation (``ddof=1``) of the values, in the value's unit
        (:attr:`unit`); NaN when ``count`` is 0 (mean) or below 2 (std).
    min, max : float
        Smallest and largest value (NaN when ``count`` is 0).
    n_pass, n_fail, n_other : int
        Measurements whose characteristic status is ``PASS``, ``FAIL``, anything else.
    cp : float or None
        Two-sided capability index ``(upper - lower) / (6 std)`` of a dimension with both
        limits; None for a geometric tolerance (one-sided), with ``count < 2`` or
        ``std == 0``.
    cpk : float or None
        Capability index: upper ``(tolerance - mean) / (3 std)`` of a geometric tolerance,
        ``min(upper - mean, mean - lower) / (3 std)`` of a dimension; None without a limit,
        with ``count < 2`` or ``std == 0``.
    n_out_of_tolerance : int
        Values above the tolerance, or beyond either limit of a dimension (0 without a
        tolerance).
    lower, upper : float or None
        The specification limits of the value: for a geometric tolerance ``lower`` is None
        (the value is at least 0) and ``upper`` the tolerance; a dimension's limits (None for
        a side without one).
    nominal : float or None
        A dimension's nominal (``TargetValue``).
    unit : str
        Unit of the values and limits: ``"mm"``, or ``"deg"`` for an angle.
    n_above, n_below : int
        Values above ``upper`` and below ``lower``.
    """

    designator: str
    kind: str
    description: str | None
    tolerance: float | None
    count: int
    mean: float
    std: float
    min: float
    max: float
    n_pass: int
    n_fail: int
    n_other: int
    cp: float | None
    cpk: float | None
    n_out_of_tolerance: int = 0
    lower: float | None = None
    upper: float | None = None
    nominal: float | None = None
    unit: str = "mm"
    n_above: int = 0
    n_below: int = 0

    @property
    def two_sided(self) -> bool:
        """A dimension (limits about a nominal), not a one-sided geometric tolerance."""
        return self.kind in DIMENSION_KINDS


@dataclass
class Source:
    """A feature characteristic in its results document: its definition and nominal
    elements and its limits, or why it is not carried."""

    spec: Limits | None
    definition: etree._Element | None = None
    nominal: etree._Element | None = None
    reason: str = ""


@dataclass
class Observation:
    """One characteristic measurement of the batch: the inspection it is from, and it."""

    scan: int
    char: CharacteristicResult
    source: Source = field(default_factory=lambda: Source(None))

    @property
    def value(self) -> float | None:
        v = self.char.value
        return v if v is not None and math.isfinite(v) else None

    @property
    def spec(self) -> Limits:
        if from_results(qif_type_of(self.char)):
            return Limits(None, self.char.spec.tolerance)
        assert self.source.spec is not None
        return self.source.spec


def qif_type_of(c: CharacteristicResult) -> str:
    """The QIF type of a characteristic read back (:func:`qifreport.qif.reader.read_results`:
    its document record's)."""
    if c.document is None:
        raise ValueError(f"characteristic {c.spec.key} was not read from a results document")
    return c.document.type


def _description(c: CharacteristicResult) -> str | None:
    return c.document.description if c.document is not None else None


def characteristic_description(c: CharacteristicResult) -> str | None:
    """A characteristic's description: a feature characteristic's first clause (what it is;
    the rest, after ``"; "``, says how one scan was read, :mod:`.feature_characteristics`)."""
    text = _description(c)
    if text is None or from_results(qif_type_of(c)):
        return text
    return text.split("; ")[0]


def designator_of(c: CharacteristicResult) -> str:
    """A characteristic's designator (its spec's key), else its name."""
    key = c.spec.key or c.spec.name
    if not key:
        what = f"{c.document.id} ({c.document.type})" if c.document is not None else "?"
        raise ValueError(
            f"characteristic measurement {what} has neither a "
            "designator nor a name: it cannot be matched across the batch"
        )
    return key


# ------------------------------------------------------------------- feature definitions


def _limits(kind: str, definition: etree._Element, nominal: etree._Element) -> Limits | str:
    """The limits a feature characteristic's definition states, or why it has none."""
    return definition_limits(definition, nominal, toleranced=statistics_rule(kind) is not None)


def _sources(res: QIFResults) -> dict[str, Source]:
    """The feature characteristics of one results document (every supported kind but the
    surface profiles) by measurement id: their definition, nominal and limits, read from the
    file, or why they cannot be carried."""
    wanted = [
        c
        for c in res.characteristics
        if is_supported(qif_type_of(c)) and not from_results(qif_type_of(c))
    ]
    if not wanted:
        return {}
    try:
        root = parse_document(res.path).getroot()
    except (OSError, DocumentRefused, etree.XMLSyntaxError) as exc:
        why = f"its results document {res.path.name} could not be read ({exc})"
        return {c.document.id: Source(None, reason=why) for c in wanted}
    by_id = {el.get("id"): el for el in root.iter() if el.get("id") is not None}
    out: dict[str, Source] = {}
    for c in wanted:
        mid = c.document.id
        item = by_id.get(child_text(by_id.get(mid), "q:CharacteristicItemId"))
        nominal = by_id.get(child_text(item, "q:CharacteristicNominalId"))
        definition = by_id.get(child_text(nominal, "q:CharacteristicDefinitionId"))
        if definition is None or nominal is None:
            out[mid] = Source(None, reason=f"no definition in {res.path.name}")
            continue
        spec = _limits(c.document.type, definition, nominal)
        if isinstance(spec, str):
            out[mid] = Source(None, reason=spec)
        else:
            out[mid] = Source(spec, definition, nominal)
    return out


def group_batch(results: list[QIFResults]) -> dict[str, list[Observation]]:
    """The batch's carried measurements by designator, designators in first-seen order.

    A designator of a supported kind without limits (in any inspection) is left out, its
    reason logged; so is every unsupported kind.

    Raises
    ------
    ValueError
        A designator changes type, tolerance or limits within the batch.
    """
    groups: dict[str, list[Observation]] = {}
    left_out: dict[str, str] = {}
    for k, res in enumerate(results):
        sources = _sources(res)
        for c in res.characteristics:
            t = qif_type_of(c)
            if not is_supported(t):
                log.debug("%s (%s) left out: no statistics of this type", designator_of(c), t)
                continue
            key = designator_of(c)
            if c.spec.composite == "lower":
                left_out.setdefault(key, "a composite frame's lower segment: not carried")
                continue
            src = sources.get(c.document.id, Source(None))
            if not from_results(t) and src.spec is None:
                left_out.setdefault(key, f"{t}: {src.reason}")
                continue
            obs = groups.setdefault(key, [])
            o = Observation(k, c, src)
            if obs:
                first = obs[0].char
                if t != qif_type_of(first):
                    raise ValueError(
                        f"{key}: {t} in {res.path.name} but {qif_type_of(first)} "
                        "before: not one part's batch"
                    )
                if from_results(t) and c.spec.tolerance != first.spec.tolerance:
                    raise ValueError(
                        f"{key}: tolerance {c.spec.tolerance} in {res.path.name} "
                        f"but {first.spec.tolerance} before: not one part's batch"
                    )
                if o.spec != obs[0].spec:
                    raise ValueError(
                        f"{key}: limits {o.spec} in {res.path.name} but {obs[0].spec} "
                        "before: not one part's batch"
                    )
            obs.append(o)
    for key, why in left_out.items():
        groups.pop(key, None)
        log.info("characteristic %s left out of the batch statistics: %s", key, why)
    return groups


def summary_of(key: str, obs: list[Observation]) -> CharacteristicSummary:
    kind = qif_type_of(obs[0].char)
    spec = obs[0].spec
    values = np.array([o.value for o in obs if o.value is not None], dtype=float)
    count = len(values)
    mean = float(values.mean()) if count else math.nan
    std = float(values.std(ddof=1)) if count >= 2 else math.nan
    statuses = [o.char.status for o in obs]
    n_pass, n_fail = statuses.count("PASS"), statuses.count("FAIL")
    n_above = int((values > spec.upper).sum()) if spec.upper is not None else 0
    n_below = int((values < spec.lower).sum()) if spec.lower is not None else 0
    if kind in DIMENSION_KINDS:
        tol = None
        cp, cpk = capability(mean, std, count, spec.lower, spec.upper)
    else:
        tol = spec.upper
        cp, cpk = math.nan, (math.nan if tol is None else upper_cpk(mean, std, tol, count))
    return CharacteristicSummary(
        designator=key,
        kind=kind,
        description=next(
            (characteristic_description(o.char) for o in obs if _description(o.char)), None
        ),
        tolerance=tol,
        count=count,
        mean=mean,
        std=std,
        min=float(values.min()) if count else math.nan,
        max=float(values.max()) if count else math.nan,
        n_pass=n_pass,
        n_fail=n_fail,
        n_other=len(obs) - n_pass - n_fail,
        cp=None if math.isnan(cp) else cp,
        cpk=None if math.isnan(cpk) else cpk,
        n_out_of_tolerance=n_above + n_below,
        lower=spec.lower,
        upper=spec.upper,
        nominal=spec.nominal,
        unit="deg" if kind in ANGULAR_DIMENSION_KINDS else "mm",
        n_above=n_above,
        n_below=n_below,
    )


def summarize(results: list[QIFResults]) -> list[CharacteristicSummary]:
    """Per-characteristic statistics of a batch of inspections.

    Parameters
    ----------
    results : list of QIFResults
        The batch's results documents, read back (:func:`qifreport.qif.reader.read_results`);
        a feature characteristic's limits are read from the file itself (:attr:`path`).

    Returns
    -------
    list of CharacteristicSummary
        One per carried designator (see the module docstring), in the order the
        designators first appear.

    Raises
    ------
    ValueError
        A characteristic has no designator and no name, or a designator changes type,
        tolerance or limits within the batch.
    """
    return [summary_of(key, obs) for key, obs in group_batch(results).items()]
