"""QIF 3.0 Statistics document of a batch of inspections.

qifreport inspects many scans of one part (a batch); each scan has its QIF results document
(:mod:`qifreport.qif.writer`), read back with :func:`qifreport.qif.reader.read_results`.
:func:`summarize` reduces the batch to one :class:`CharacteristicSummary` per characteristic
(per designator: a toleranced surface's zone key, ``"T1"``, ``"general"``; a feature
characteristic's key, ``"G1"``, ``"D3"``) and :func:`build_statistics` writes it as a QIF
3.0 document whose ``Statistics`` section (``QIFApplications/QIFStatistics.xsd``,
``QIFLibrary/Statistics.xsd``) holds one capability study with one typed statistics element
per characteristic.

Characteristics
---------------
Every characteristic of a kind in :data:`SUPPORTED_KINDS` with a numeric tolerance or limits
is carried:

* the surface profiles (``SurfaceProfile``), as the results documents carry them;
* the geometric tolerances of the drawing (:data:`GEOMETRIC_KINDS`: ``Flatness``,
  ``Position``, ``Perpendicularity``, ``CircularRunout`` ...): a zone width judged against
  its ``ToleranceValue`` (or the ``ToleranceValuePerUnit`` of a per-unit-length or
  per-unit-area tolerance), one-sided like a profile;
* the dimensions (:data:`LINEAR_DIMENSION_KINDS`: ``Diameter``, ``DistanceBetween``,
  ``Width`` ..., mm; :data:`ANGULAR_DIMENSION_KINDS`: ``Angle``, ``AngleBetween``, degrees):
  a size between the limits of the definition's ``Tolerance`` (``MaxValue``/``MinValue``
  about the nominal's ``TargetValue``, or the limits themselves with ``DefinedAsLimit``),
  two-sided.

A feature characteristic's definition and nominal are read from its results document (the
file of :attr:`QIFResults.path <qifreport.qif.reader.QIFResults.path>`: the results as read
back carry neither a dimension's limits nor the elements a definition of its type needs).
Left out, each with a logged reason (never an error): a characteristic without a numeric
tolerance or limits (a basic or reference dimension, ``NonTolerance``; a limits-and-fits
code), one whose results document cannot be read, and every other type (the
``UserDefinedAttribute`` acceptance characteristics ``<key>_ACCEPTANCE`` beside each
profile, the PMI items QIF has no type for).

Layout
------
The document is self-contained: the statistics reference characteristic measurements by QIF
id, so the measurements they summarise are in the same document, with the characteristics
they measure (the structure of qifreport's results documents, one per designator):

==========================================  ==================================================
``Header``, ``SoftwareDefinitions``          qifreport (and its version) as the application
``ExternalQIFReferences``                    with ``sources``: one ``ExternalQIFDocument`` per
                                             inspection (the per-scan results document's
                                             ``QPId`` and its URI relative to this file)
``FileUnits``                                mm (and degree when an angle is carried)
``Product``, ``Features``                    the part, one ``OtherSurfaceFeature`` definition,
                                             nominal and item per characteristic
                                             (``SURFACE_<key>`` for a profile,
                                             ``FEATURE_<key>`` for a feature characteristic)
``Characteristics``                          per designator, its type's ``Definition``,
                                             ``Nominal`` and ``Item``
                                             (``CharacteristicDesignator``). A profile's
                                             definition is written from the results read back
                                             (``Name``, ``Description``, ``ToleranceValue``,
                                             ``UnequallyDisposedZone``); a feature
                                             characteristic's definition and nominal are
                                             copies of those of its first results document
                                             (tolerance or limits, material condition, zone
                                             shape, ``TargetValue``, ``AnalysisMode`` ...)
                                             without the ``DatumReferenceFrameId`` (this
                                             document has no datums: the frame is named in
                                             the description) and with the description's
                                             first clause only (the rest says how that one
                                             scan was read)
``Results/MeasurementResultsSet``            one ``MeasurementResults`` per inspection, in the
                                             order given: inspection times, (with ``sources``)
                                             an ``ExternalFileReference`` to its QIF file, one
                                             ``<Kind>CharacteristicMeasurement`` per carried
                                             characteristic (``Status`` and ``Value``, for a
                                             profile also ``WorstPositiveDeviation`` and
                                             ``WorstNegativeDeviation``, copied; its id in the
                                             source is the ``source_id`` attribute), the
                                             inspection status
``Results/ActualComponentSets``              one ``ActualComponent`` per inspection (serial
                                             number, status)
``Statistics/StatisticalStudiesResults``     one ``CapabilityStudyResults``
                                             (``CapabilityStudyResultsType``): status
                                             ``INFORMATIONAL``, the software, the batch's first
                                             start and last end, ``ResultsIds`` (the
                                             ``MeasurementResults`` above),
                                             ``CharacteristicsStats``, ``NumberOfSamples``
                                             (the number of inspections)
==========================================  ==================================================

Each characteristic's statistics are a ``<Kind>CharacteristicStats`` element: for a profile
``SurfaceProfileCharacteristicStats`` (``SurfaceProfileCharacteristicStatsEvalType``, from
``ProfileCharacteristicStatsEvalBaseType`` and ``GeometricCharacteristicStatsEvalType``), for a
geometric tolerance e.g. ``FlatnessCharacteristicStats`` or ``PositionCharacteristicStats``
(from ``GeometricCharacteristicStatsEvalType`` too), for a dimension e.g.
``DiameterCharacteristicStats`` (``LinearCharacteristicStatsEvalType``) or
``AngleBetweenCharacteristicStats`` (``AngularCharacteristicStatsEvalType``):

* ``Attributes``: ``designator`` (``AttributeStr``); ``n_pass``, ``n_fail``, ``n_other``
  (``AttributeI1``): how many of its measurements have the characteristic status ``PASS``,
  ``FAIL`` or another one (``INDETERMINATE``, ``NOT_ANALYZED``...). QIF has no statistics
  element for counts of a characteristic's status: ``NumberOutOfTolerance`` counts values
  beyond the tolerance, and qifreport's status is its acceptance rule, not that comparison
  (a part can PASS with a profile value above the tolerance, see :mod:`qifreport.qif.writer`;
  a position at MMC with a bonus).
* ``MeasuredIds`` (``StatsArrayIdType``): the ids of its measurements in ``Results``, all of
  them; those without a measured value are ``Exclusions`` (reason ``OtherExclusionReason``).
* ``Status``: ``INFORMATIONAL`` (no capability requirement was given to judge against).
* ``ValueStats`` (``StatsWithTolLinearType``; ``StatsWithTolAngularType`` for an angle, in
  degrees), over the measurements' ``Value`` (a profile value or a geometric tolerance's
  zone width, mm; a dimension's size, mm or degrees): ``TotalNumber`` (measurements),
  ``EffectiveNumber`` (those with a value, ``count``), ``Average``, ``StandardDeviation`` (the
  sample standard deviation, ``n - 1`` in the denominator, as the schema defines ``STDDEV``;
  written when ``count >= 2``), ``Minimum`` and ``Maximum`` (each with the ``Id`` of its
  measurement), ``Range``, ``NumberOutOfTolerance`` (values above the tolerance; for a
  dimension beyond either limit; with their ``Ids``), for a dimension also
  ``NumberOverUpperTolerance`` and ``NumberUnderLowerTolerance`` (for each limit it has),
  ``Cp`` (a dimension with both limits) and ``Cpk``.
* ``CapabilityCalculationMethod`` (a profile or a geometric tolerance): ``THREE_SIGMA`` when
  ``Cpk`` is written. The dimensions' statistics types have no such element.
* A profile's ``WorstPositiveDeviationStats``, ``WorstNegativeDeviationStats``
  (``StatsLinearType``): ``Average``, ``Minimum``, ``Maximum`` of the measurements' worst
  deviations (mm).

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

Numbers
-------
Statistics (``xs:decimal``) are written as the shortest decimal that reads back as the same
double (no exponent): a reader gets exactly the value computed here. Copied measurement
values are written the same way, so they equal the values read from the source documents.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass, field
from datetime import datetime
from decimal import Decimal
from pathlib import Path
from urllib.parse import quote

import numpy as np
from lxml import etree

from qifreport import __version__
from qifreport.metrology.spc import capability, upper_cpk

from .reader import CharacteristicResult, QIFResults, child_text
from .writer import write_qif
from .xmlkit import NS, SCHEMA_LOCATION, XSI, Attrs, E, Ids, id_array, qpid, token, xml_time
from .xsd import DocumentRefused, parse_document

__all__ = [
    "ANGULAR_DIMENSION_KINDS",
    "CHARACTERISTIC_STATUSES",
    "DIMENSION_KINDS",
    "GEOMETRIC_KINDS",
    "INSPECTION_STATUSES",
    "LINEAR_DIMENSION_KINDS",
    "NO_VALUE_REASON",
    "SUPPORTED_KINDS",
    "CharacteristicSummary",
    "build_statistics",
    "summarize",
    "write_statistics",
]

log = logging.getLogger("qifreport.statistics")

#: ``CharacteristicStatusEnumType`` values (anything else is an ``OtherCharacteristicStatus``)
CHARACTERISTIC_STATUSES = frozenset(
    {
        "PASS",
        "FAIL",
        "REWORK",
        "SYSERROR",
        "INDETERMINATE",
        "NOT_ANALYZED",
        "BASIC_OR_TED",
        "UNDEFINED",
    }
)
#: ``InspectionStatusEnumType`` values (anything else is an ``OtherInspectionStatus``)
INSPECTION_STATUSES = frozenset(
    {"PASS", "FAIL", "REWORK", "SYSERROR", "UNKNOWN", "NOT_CALCULATED", "NOT_MEASURED", "UNDEFINED"}
)
#: geometric characteristic kinds: a zone width (mm) at most the ``ToleranceValue`` (one-sided)
GEOMETRIC_KINDS = frozenset(
    {
        "SurfaceProfile",
        "LineProfile",
        "Flatness",
        "Straightness",
        "Circularity",
        "Cylindricity",
        "Perpendicularity",
        "Parallelism",
        "Angularity",
        "Position",
        "Coaxiality",
        "Concentricity",
        "Symmetry",
        "CircularRunout",
        "TotalRunout",
    }
)
#: dimensions in mm between limits (two-sided; ``LinearCharacteristicStatsEvalType``)
LINEAR_DIMENSION_KINDS = frozenset(
    {
        "Diameter",
        "Radius",
        "SphericalDiameter",
        "SphericalRadius",
        "Thickness",
        "DistanceBetween",
        "DistanceFrom",
        "Width",
        "Length",
        "Height",
        "Depth",
        "Chord",
        "CurveLength",
        "LinearCoordinate",
    }
)
#: dimensions in degrees between limits (``AngularCharacteristicStatsEvalType``)
ANGULAR_DIMENSION_KINDS = frozenset({"Angle", "AngleBetween", "AngleFrom", "AngularCoordinate"})
#: every dimension kind
DIMENSION_KINDS = LINEAR_DIMENSION_KINDS | ANGULAR_DIMENSION_KINDS
#: characteristic kinds :func:`build_statistics` can write (``<kind>CharacteristicStats``)
SUPPORTED_KINDS = GEOMETRIC_KINDS | DIMENSION_KINDS
#: exclusion reason of a measurement without a value
NO_VALUE_REASON = "no measured value"
#: the profile kinds (worst deviations copied and summarised)
_PROFILE_KINDS = ("SurfaceProfile", "LineProfile")


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


@dataclass(frozen=True)
class _Spec:
    """What a characteristic's value is judged against: ``lower`` (None for a geometric
    tolerance, whose value is at least 0) and ``upper`` limits, a dimension's ``nominal``."""

    lower: float | None
    upper: float | None
    nominal: float | None = None


@dataclass
class _Source:
    """A feature characteristic in its results document: its definition and nominal
    elements and its limits, or why it is not carried."""

    spec: _Spec | None
    definition: etree._Element | None = None
    nominal: etree._Element | None = None
    reason: str = ""


@dataclass
class _Observation:
    """One characteristic measurement of the batch: the inspection it is from, and it."""

    scan: int
    char: CharacteristicResult
    source: _Source = field(default_factory=lambda: _Source(None))

    @property
    def value(self) -> float | None:
        v = self.char.value
        return v if v is not None and math.isfinite(v) else None

    @property
    def spec(self) -> _Spec:
        if self.char.kind == "SurfaceProfile":
            return _Spec(None, self.char.tolerance)
        assert self.source.spec is not None
        return self.source.spec


def _description(c: CharacteristicResult) -> str | None:
    """A characteristic's description: a feature characteristic's first clause (what it is;
    the rest, after ``"; "``, says how one scan was read, :mod:`.feature_characteristics`)."""
    if c.description is None or c.kind == "SurfaceProfile":
        return c.description
    return c.description.split("; ")[0]


def _key(c: CharacteristicResult) -> str:
    key = c.designator if c.designator is not None else c.name
    if key is None:
        raise ValueError(
            f"characteristic measurement {c.id} ({c.kind}) has neither a "
            "designator nor a name: it cannot be matched across the batch"
        )
    return key


# ------------------------------------------------------------------- feature definitions

_Q = f"{{{NS}}}"


def _float(text: str | None) -> float | None:
    if text is None:
        return None
    try:
        x = float(text)
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def _limits(kind: str, definition: etree._Element, nominal: etree._Element) -> _Spec | str:
    """The limits a feature characteristic's definition states, or why it has none."""
    if kind in GEOMETRIC_KINDS:
        tol = _float(child_text(definition, "q:ToleranceValue"))
        for per_unit in ("q:ToleranceZonePerUnitArea", "q:ToleranceZonePerUnitLength"):
            if tol is None:
                tol = _float(child_text(definition, f"{per_unit}/q:ToleranceValuePerUnit"))
        if tol is None:
            return "no numeric tolerance value"
        return _Spec(None, tol)
    if definition.find(f"{_Q}NonTolerance") is not None:
        return "no limits (a basic or reference dimension)"
    if definition.find(f"{_Q}LimitsAndFitsSpecification") is not None:
        return "limits given as a limits-and-fits code, not evaluated here"
    tol = definition.find(f"{_Q}Tolerance")
    if tol is None or tol.find(f"{_Q}DefinitionId") is not None:
        return "no limits in its definition"
    hi, lo = child_text(tol, "q:MaxValue"), child_text(tol, "q:MinValue")
    target = child_text(nominal, "q:TargetValue")
    if _float(hi) is None and _float(lo) is None:
        return "no limits in its definition"
    if child_text(tol, "q:DefinedAsLimit") in ("true", "1"):
        return _Spec(_float(lo), _float(hi), _float(target))
    if _float(target) is None:
        return "limits relative to a nominal it does not state"

    def limit(offset: str | None) -> float | None:
        # nominal + offset as decimals, then the nearest double (10 + 0.1 is 10.1 exactly)
        return None if _float(offset) is None else float(Decimal(target) + Decimal(offset))

    return _Spec(limit(lo), limit(hi), _float(target))


def _sources(res: QIFResults) -> dict[str, _Source]:
    """The feature characteristics of one results document (every supported kind but the
    surface profiles) by measurement id: their definition, nominal and limits, read from the
    file, or why they cannot be carried."""
    wanted = [
        c for c in res.characteristics if c.kind in SUPPORTED_KINDS and c.kind != "SurfaceProfile"
    ]
    if not wanted:
        return {}
    try:
        root = parse_document(res.path).getroot()
    except (OSError, DocumentRefused, etree.XMLSyntaxError) as exc:
        why = f"its results document {res.path.name} could not be read ({exc})"
        return {c.id: _Source(None, reason=why) for c in wanted}
    by_id = {el.get("id"): el for el in root.iter() if el.get("id") is not None}
    out: dict[str, _Source] = {}
    for c in wanted:
        item = by_id.get(child_text(by_id.get(c.id), "q:CharacteristicItemId"))
        nominal = by_id.get(child_text(item, "q:CharacteristicNominalId"))
        definition = by_id.get(child_text(nominal, "q:CharacteristicDefinitionId"))
        if definition is None or nominal is None:
            out[c.id] = _Source(None, reason=f"no definition in {res.path.name}")
            continue
        spec = _limits(c.kind, definition, nominal)
        if isinstance(spec, str):
            out[c.id] = _Source(None, reason=spec)
        else:
            out[c.id] = _Source(spec, definition, nominal)
    return out


def _group(results: list[QIFResults]) -> dict[str, list[_Observation]]:
    """The batch's carried measurements by designator, designators in first-seen order.

    A designator of a supported kind without limits (in any inspection) is left out, its
    reason logged; so is every unsupported kind.

    Raises
    ------
    ValueError
        A designator changes type, tolerance or limits within the batch.
    """
    groups: dict[str, list[_Observation]] = {}
    left_out: dict[str, str] = {}
    for k, res in enumerate(results):
        sources = _sources(res)
        for c in res.characteristics:
            if c.kind not in SUPPORTED_KINDS:
                log.debug("%s (%s) left out: no statistics of this type", _key(c), c.kind)
                continue
            key = _key(c)
            src = sources.get(c.id, _Source(None))
            if c.kind != "SurfaceProfile" and src.spec is None:
                left_out.setdefault(key, f"{c.kind}: {src.reason}")
                continue
            obs = groups.setdefault(key, [])
            o = _Observation(k, c, src)
            if obs:
                first = obs[0]
                if c.kind != first.char.kind:
                    raise ValueError(
                        f"{key}: {c.kind} in {res.path.name} but {first.char.kind} "
                        "before: not one part's batch"
                    )
                if c.kind == "SurfaceProfile" and c.tolerance != first.char.tolerance:
                    raise ValueError(
                        f"{key}: tolerance {c.tolerance} in {res.path.name} "
                        f"but {first.char.tolerance} before: not one part's batch"
                    )
                if o.spec != first.spec:
                    raise ValueError(
                        f"{key}: limits {o.spec} in {res.path.name} but {first.spec} "
                        "before: not one part's batch"
                    )
            obs.append(o)
    for key, why in left_out.items():
        groups.pop(key, None)
        log.info("characteristic %s left out of the batch statistics: %s", key, why)
    return groups


def _summary(key: str, obs: list[_Observation]) -> CharacteristicSummary:
    first = obs[0].char
    spec = obs[0].spec
    values = np.array([o.value for o in obs if o.value is not None], dtype=float)
    count = len(values)
    mean = float(values.mean()) if count else math.nan
    std = float(values.std(ddof=1)) if count >= 2 else math.nan
    statuses = [o.char.status for o in obs]
    n_pass, n_fail = statuses.count("PASS"), statuses.count("FAIL")
    n_above = int((values > spec.upper).sum()) if spec.upper is not None else 0
    n_below = int((values < spec.lower).sum()) if spec.lower is not None else 0
    if first.kind in DIMENSION_KINDS:
        tol = None
        cp, cpk = capability(mean, std, count, spec.lower, spec.upper)
    else:
        tol = spec.upper
        cp, cpk = math.nan, (math.nan if tol is None else upper_cpk(mean, std, tol, count))
    return CharacteristicSummary(
        designator=key,
        kind=first.kind,
        description=next((_description(o.char) for o in obs if o.char.description), None),
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
        unit="deg" if first.kind in ANGULAR_DIMENSION_KINDS else "mm",
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
    return [_summary(key, obs) for key, obs in _group(results).items()]


# ---------------------------------------------------------------------------------- writing


def _num(x: float) -> str:
    """The shortest ``xs:decimal`` literal that reads back as the double ``x``."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"not a finite number: {x}")
    if x == 0.0:
        return "0"
    return np.format_float_positional(x, unique=True, trim="-")


def _stat(tag: str, x: float, ref: str | None = None) -> etree._Element:
    """A ``StatsMeasuredDecimalType`` value (``...WithReferenceType`` with ``ref``)."""
    children = [E.Value(_num(x))]
    if ref is not None:
        children.append(E.Id(ref))
    return E(tag, *children)


def _count(tag: str, n: int, refs: list[str] | None = None) -> etree._Element:
    """A ``StatsNonNegativeIntegerType`` value (``...WithReferencesType`` with ``refs``)."""
    children = [E.Value(str(int(n)))]
    if refs:
        children.append(id_array("Ids", refs))
    return E(tag, *children)


def _characteristic_status(text: str | None) -> etree._Element:
    """``Status`` of a characteristic measurement (``UNDEFINED`` when unknown)."""
    text = text or "UNDEFINED"
    if text in CHARACTERISTIC_STATUSES:
        return E.Status(E.CharacteristicStatusEnum(text))
    return E.Status(E.OtherCharacteristicStatus(text))


def _inspection_status(tag: str, text: str | None) -> etree._Element:
    """An ``InspectionStatusType`` element (``UNKNOWN`` when unknown)."""
    text = text or "UNKNOWN"
    if text in INSPECTION_STATUSES:
        return E(tag, E.InspectionStatusEnum(text))
    return E(tag, E.OtherInspectionStatus(text))


def _informational() -> etree._Element:
    return E.Status(E.StatsEvalStatusEnum("INFORMATIONAL"))


def _parse_time(text: str | None) -> datetime | None:
    """A timezone-aware time from an ``xs:dateTime`` text; None if absent, unreadable or
    without a timezone (it could not be ordered against the others)."""
    if not text:
        return None
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError:
        log.warning("inspection time %r is not an ISO date-time: left out", text)
        return None
    return t if t.tzinfo is not None else None


def _source_uri(source: str) -> str:
    """A relative URI reference for a file name or relative path (``/`` separators)."""
    return quote(source.replace("\\", "/"), safe="/")


def _check_batch(
    results: list[QIFResults],
    groups: dict[str, list[_Observation]],
    sources: list[str] | None,
    nominal_sha256: str | None,
) -> None:
    """Raise ValueError unless the batch can be written as one statistics document."""
    if not results:
        raise ValueError("no inspection results: nothing to summarise")
    if sources is not None:
        if len(sources) != len(results):
            raise ValueError(f"{len(sources)} sources for {len(results)} results")
        missing = [r.path.name for r in results if not r.qpid]
        if missing:
            raise ValueError(f"results without a QPId cannot be referenced: {missing}")
    untoleranced = [
        key
        for key, obs in groups.items()
        if obs[0].char.kind == "SurfaceProfile" and obs[0].char.tolerance is None
    ]
    if untoleranced:
        raise ValueError(f"characteristics without a ToleranceValue: {untoleranced}")
    if nominal_sha256 is not None:
        for r in results:
            theirs = r.attributes.get("nominal_sha256")
            if theirs is not None and theirs != nominal_sha256:
                raise ValueError(
                    f"{r.path.name} was inspected against another nominal "
                    f"(SHA-256 {theirs}, not {nominal_sha256})"
                )


def _characteristic_stats(
    key: str, obs: list[_Observation], s: CharacteristicSummary, meas_ids: list[str]
) -> etree._Element:
    """The ``<Kind>CharacteristicStats`` of one characteristic.

    ``meas_ids[i]`` is the local id of the measurement ``obs[i]``.
    """
    attrs = Attrs().s("designator", key)
    attrs.i("n_pass", s.n_pass).i("n_fail", s.n_fail).i("n_other", s.n_other)
    excluded = [m for o, m in zip(obs, meas_ids, strict=True) if o.value is None]
    measured = [id_array("Ids", meas_ids)]
    if excluded:
        measured.append(
            E.Exclusions(
                *[
                    E.Exclusion(E.Id(m), E.Reason(E.OtherExclusionReason(NO_VALUE_REASON)))
                    for m in excluded
                ],
                n=str(len(excluded)),
            )
        )

    values = [(o.value, m) for o, m in zip(obs, meas_ids, strict=True) if o.value is not None]
    vs = [_count("TotalNumber", len(obs)), _count("EffectiveNumber", s.count)]
    if values:
        lo = min(values, key=lambda vm: vm[0])
        hi = max(values, key=lambda vm: vm[0])
        vs.append(_stat("Average", s.mean))
        if s.count >= 2:
            vs.append(_stat("StandardDeviation", s.std))
        vs += [
            _stat("Minimum", lo[0], lo[1]),
            _stat("Maximum", hi[0], hi[1]),
            _stat("Range", hi[0] - lo[0]),
        ]
    above = [m for v, m in values if s.upper is not None and v > s.upper]
    below = [m for v, m in values if s.lower is not None and v < s.lower]
    if s.two_sided:
        out = set(above) | set(below)
        beyond = [m for _, m in values if m in out]
        vs.append(_count("NumberOutOfTolerance", len(beyond), beyond))
        if s.upper is not None:
            vs.append(_count("NumberOverUpperTolerance", len(above), above))
        if s.lower is not None:
            vs.append(_count("NumberUnderLowerTolerance", len(below), below))
        if s.cp is not None:
            vs.append(_stat("Cp", s.cp))
    else:
        vs.append(_count("NumberOutOfTolerance", len(above), above))
    if s.cpk is not None:
        vs.append(_stat("Cpk", s.cpk))

    children = [attrs.element(), E.MeasuredIds(*measured), _informational(), E.ValueStats(*vs)]
    if s.cpk is not None and not s.two_sided:
        children.append(E.CapabilityCalculationMethod("THREE_SIGMA"))
    deviations = (
        (
            ("WorstPositiveDeviationStats", "worst_positive"),
            ("WorstNegativeDeviationStats", "worst_negative"),
        )
        if s.kind in _PROFILE_KINDS
        else ()
    )
    for tag, name in deviations:
        w = [(getattr(o.char, name), m) for o, m in zip(obs, meas_ids, strict=True)]
        w = [(x, m) for x, m in w if x is not None and math.isfinite(x)]
        if w:
            lo = min(w, key=lambda xm: xm[0])
            hi = max(w, key=lambda xm: xm[0])
            children.append(
                E(
                    tag,
                    _stat("Average", float(np.mean([x for x, _ in w]))),
                    _stat("Minimum", lo[0], lo[1]),
                    _stat("Maximum", hi[0], hi[1]),
                )
            )
    return E(f"{s.kind}CharacteristicStats", *children)


def _feature_copies(
    key: str, obs: list[_Observation], cd: str, cn: str, fn: str
) -> tuple[etree._Element, etree._Element]:
    """Copies of a feature characteristic's definition and nominal from its first results
    document, with the ids ``cd`` and ``cn``: the nominal refers to the definition ``cd`` and
    the feature nominal ``fn``; the definition without its ``DatumReferenceFrameId`` (this
    document has no datums) and with the first clause of its description (the rest says how
    that one scan was read)."""
    src = obs[0].source
    assert src.definition is not None and src.nominal is not None
    cdef, cnom = copy.deepcopy(src.definition), copy.deepcopy(src.nominal)
    cdef.set("id", cd)
    for drf in cdef.findall(f"{_Q}DatumReferenceFrameId"):
        cdef.remove(drf)
    desc = cdef.find(f"{_Q}Description")
    if desc is not None and desc.text:
        desc.text = _description(obs[0].char) or desc.text
    cnom.set("id", cn)
    ref = cnom.find(f"{_Q}CharacteristicDefinitionId")
    ref.text = cd
    for old in cnom.findall(f"{_Q}FeatureNominalIds"):
        old.addnext(id_array("FeatureNominalIds", [fn]))
        cnom.remove(old)
    log.debug("%s: definition and nominal copied from %s", key, obs[0].char.id)
    return cdef, cnom


def build_statistics(
    results: list[QIFResults],
    *,
    part_name: str,
    created: datetime,
    nominal_sha256: str | None = None,
    sources: list[str] | None = None,
    software_version: str | None = None,
    standard: tuple[str, str, str] = ("ASME", "Y14.5", "2018"),
) -> etree._ElementTree:
    """The QIF 3.0 statistics document of a batch of inspections (an lxml tree).

    Parameters
    ----------
    results : list of QIFResults
        The batch's results documents, read back; one ``MeasurementResults`` each, in this
        order. Their surface profiles (each must have a ``ToleranceValue``) and feature
        characteristics with a tolerance or limits are carried (see the module docstring:
        the feature characteristics' definitions are read from the files, :attr:`path`);
        the others are left out, logged.
    part_name : str
        Name of the part (``Product``).
    created : datetime
        Time the document is created (``Version/TimeCreated``, ``ReportPreparationDate``).
    nominal_sha256 : str, optional
        SHA-256 of the nominal the batch was inspected against: written as the study's
        ``nominal_sha256`` attribute and checked against each result's own.
    sources : list of str, optional
        The results documents' file names (or paths) relative to the statistics file, one
        per result: declared as ``ExternalQIFReferences`` (with their QPIds) and referenced
        by each copied ``MeasurementResults``. The files must be there for the DMSC checks.
    software_version : str, optional
        Version of qifreport to state (default: this one).
    standard : (str, str, str)
        (organization, designator, year) of the tolerancing standard of the characteristics
        (``Characteristics/FormalStandardId`` is required; the results documents as read back
        do not carry theirs): qifreport's default, ASME Y14.5-2018.

    Returns
    -------
    lxml.etree._ElementTree
        Write it with :func:`write_statistics`.

    Raises
    ------
    ValueError
        No results, ``sources`` of another length, a source without QPId, a surface profile
        without tolerance, a characteristic changing type, tolerance or limits within the
        batch, or a result inspected against another nominal.
    """
    groups = _group(results)
    _check_batch(results, groups, sources, nominal_sha256)
    ids = Ids()

    std_id, sw_id = ids(), ids()
    std_org, std_des, std_year = standard
    standards = E.StandardsDefinitions(
        E.Standard(
            E.Organization(E.StandardsOrganizationEnum(std_org)),
            E.Designator(std_des),
            E.Year(std_year),
            id=std_id,
        ),
        n="1",
    )
    software = E.SoftwareDefinitions(
        E.Software(
            E.VendorName("qifreport"),
            E.ApplicationName("qifreport"),
            E.Version(software_version or __version__),
            E.Description("Dimensional inspection of flexible parts by virtual fixturing"),
            id=sw_id,
        ),
        n="1",
    )
    angular = []
    if any(obs[0].char.kind in ANGULAR_DIMENSION_KINDS for obs in groups.values()):
        angular.append(
            E.AngularUnit(
                E.SIUnitName("radian"),
                E.UnitName("degree"),
                E.UnitConversion(E.Factor("0.0174532925199433")),
            )
        )
    units = E.FileUnits(
        E.PrimaryUnits(
            *angular,
            E.LinearUnit(
                E.SIUnitName("meter"), E.UnitName("mm"), E.UnitConversion(E.Factor("0.001"))
            ),
        )
    )

    external = None
    if sources is not None:
        docs = []
        for k, (res, src) in enumerate(zip(results, sources, strict=True), start=1):
            serial = f", serial number {res.serial_number}" if res.serial_number else ""
            docs.append(
                E.ExternalQIFDocument(
                    E.QPId(res.qpid),
                    E.URI(_source_uri(src)),
                    E.Description(f"QIF results document of inspection {k}{serial}"),
                    id=ids(),
                )
            )
        external = E.ExternalQIFReferences(*docs, n=str(len(docs)))

    # -- one feature and one characteristic (definition, nominal, item) per designator
    part_id, comp_id, path_id = ids(), ids(), ids()
    fdefs, fnoms, fitems, cdefs, cnoms, citems = ([] for _ in range(6))
    item_ids: dict[str, str] = {}
    for key, obs in groups.items():
        c = obs[0].char
        profile = c.kind == "SurfaceProfile"
        fd, fn, fi, cd, cn, ci = (ids() for _ in range(6))
        item_ids[key] = ci
        fname = token(f"SURFACE_{key}".upper() if profile else f"FEATURE_{key}")
        name = token(c.name or key)
        fdefs.append(E.OtherSurfaceFeatureDefinition(id=fd))
        fnoms.append(
            E.OtherSurfaceFeatureNominal(
                E.Name(fname), E.UUID(qpid()), E.FeatureDefinitionId(fd), id=fn
            )
        )
        fitems.append(
            E.OtherSurfaceFeatureItem(
                E.FeatureNominalId(fn),
                E.FeatureName(fname),
                E.UUID(qpid()),
                E.DeterminationMode(E.Checked(E.CheckDetails(E.Measured()))),
                id=fi,
            )
        )
        if profile:
            description = next((o.char.description for o in obs if o.char.description), None)
            cdef = [E.Description(description)] if description else []
            cdef += [E.Name(name), E.ToleranceValue(_num(c.tolerance))]
            if c.unequally_disposed is not None:
                cdef.append(E.UnequallyDisposedZone(_num(c.unequally_disposed)))
            cdefs.append(E.SurfaceProfileCharacteristicDefinition(*cdef, id=cd))
            cnoms.append(
                E.SurfaceProfileCharacteristicNominal(
                    E.CharacteristicDefinitionId(cd),
                    id_array("FeatureNominalIds", [fn]),
                    E.Name(name),
                    id=cn,
                )
            )
        else:
            cdef_el, cnom_el = _feature_copies(key, obs, cd, cn, fn)
            cdefs.append(cdef_el)
            cnoms.append(cnom_el)
        citems.append(
            E(
                f"{c.kind}CharacteristicItem",
                E.Name(name),
                E.CharacteristicDesignator(E.Designator(token(key))),
                id_array("FeatureItemIds", [fi]),
                E.CharacteristicNominalId(cn),
                id=ci,
            )
        )

    # -- the batch's measurements, copied: one MeasurementResults per inspection
    carried = {(o.scan, o.char.id) for obs in groups.values() for o in obs}
    meas_id: dict[tuple[int, str], str] = {}  # (inspection, source measurement id) -> id
    mr_ids, mrs, actuals = [], [], []
    for k, res in enumerate(results):
        actual_id, mr_id = ids(), ids()
        mr_ids.append(mr_id)
        meas = []
        for c in res.characteristics:
            if (k, c.id) not in carried:
                continue
            m = meas_id[(k, c.id)] = ids()
            el = [
                Attrs().s("source_id", c.id).element(),
                _characteristic_status(c.status),
                E.CharacteristicItemId(item_ids[_key(c)]),
                E.ActualComponentId(actual_id),
            ]
            copied = [("Value", c.value)]
            if c.kind in _PROFILE_KINDS:
                copied += [
                    ("WorstPositiveDeviation", c.worst_positive),
                    ("WorstNegativeDeviation", c.worst_negative),
                ]
            for tag, x in copied:
                if x is not None and math.isfinite(x):
                    el.append(E(tag, _num(x)))
            meas.append(E(f"{c.kind}CharacteristicMeasurement", *el, id=m))
        times = [
            (tag, _parse_time(t))
            for tag, t in (
                ("InspectionStart", res.inspection_start),
                ("InspectionEnd", res.inspection_end),
            )
        ]
        trace = [E(tag, xml_time(t)) for tag, t in times if t is not None]
        mr = [E.InspectionTraceability(*trace)] if trace else []
        if sources is not None:
            mr.append(
                E.ExternalFileReferences(
                    E.ExternalFileReference(
                        E.URI(_source_uri(sources[k])),
                        E.FileSpec(E.OtherFileSpec("QIF")),
                        E.Description(
                            f"the QIF results document (QPId {res.qpid}) these results "
                            "are copied from"
                        ),
                    ),
                    n="1",
                )
            )
        if meas:
            mr.append(
                E.MeasuredCharacteristics(E.CharacteristicMeasurements(*meas, n=str(len(meas))))
            )
        mr += [
            _inspection_status("InspectionStatus", res.status),
            id_array("ActualComponentIds", [actual_id]),
        ]
        mrs.append(E.MeasurementResults(*mr, id=mr_id))
        serial = [E.SerialNumber(res.serial_number)] if res.serial_number else []
        actuals.append(
            E.ActualComponent(
                *serial,
                _inspection_status("Status", res.status),
                E.AsmPathId(path_id),
                id=actual_id,
            )
        )

    # -- the study
    summaries = {key: _summary(key, obs) for key, obs in groups.items()}
    stats = [
        _characteristic_stats(key, obs, summaries[key], [meas_id[(o.scan, o.char.id)] for o in obs])
        for key, obs in groups.items()
    ]
    starts = [t for t in (_parse_time(r.inspection_start) for r in results) if t is not None]
    ends = [t for t in (_parse_time(r.inspection_end) for r in results) if t is not None]
    trace = (
        ([E.InspectionStart(xml_time(min(starts)))] if starts else [])
        + ([E.InspectionEnd(xml_time(max(ends)))] if ends else [])
        + [E.ReportPreparationDate(xml_time(created))]
    )
    study_attrs = Attrs()
    if nominal_sha256 is not None:
        study_attrs.s("nominal_sha256", nominal_sha256)
    study = [
        E.ThisStatisticalStudyResultsInstanceQPId(qpid()),
        study_attrs.element(),
        _informational(),
        E.SoftwareId(sw_id),
        E.InspectionTraceability(*trace),
        E.Name(token(f"{part_name} batch")),
        E.Description(_study_description(len(results), part_name, groups)),
        id_array("ResultsIds", mr_ids),
        E.CharacteristicsStats(*stats, n=str(len(stats))),
        E.NumberOfSamples(str(len(results))),
    ]
    statistics = E.Statistics(
        E.StatisticalStudiesResults(
            E.CapabilityStudyResults(*[x for x in study if x is not None], id=ids()), n="1"
        )
    )

    part = E.Part(
        E.Header(E.Name(part_name)),
        E.UUID(qpid()),
        id_array("FeatureNominalIds", [f.get("id") for f in fnoms]),
        id_array("CharacteristicNominalIds", [c.get("id") for c in cnoms]),
        id=part_id,
    )
    product = E.Product(
        E.PartSet(part, n="1"),
        E.ComponentSet(E.Component(E.UUID(qpid()), E.Part(E.Id(part_id)), id=comp_id), n="1"),
        E.RootPart(E.Id(part_id)),
        E.AsmPaths(E.AsmPath(id_array("ComponentIds", [comp_id]), id=path_id), n="1"),
    )
    features = E.Features(
        E.FeatureDefinitions(*fdefs, n=str(len(fdefs))),
        E.FeatureNominals(*fnoms, n=str(len(fnoms))),
        E.FeatureItems(*fitems, n=str(len(fitems))),
    )
    characteristics = E.Characteristics(
        E.FormalStandardId(std_id),
        E.CharacteristicDefinitions(*cdefs, n=str(len(cdefs))),
        E.CharacteristicNominals(*cnoms, n=str(len(cnoms))),
        E.CharacteristicItems(*citems, n=str(len(citems))),
    )
    result_set = E.Results(
        E.MeasurementResultsSet(*mrs, n=str(len(mrs))),
        E.ActualComponentSets(E.ActualComponentSet(*actuals, n=str(len(actuals))), n="1"),
    )

    header = E.Header(
        E.Application(E.Name("qifreport"), E.Organization("qifreport project")),
        E.Description(
            f"Batch statistics of {part_name}: {len(results)} inspections, "
            f"{len(groups)} characteristics"
        ),
    )
    children = [
        E.QPId(qpid()),
        E.Version(E.TimeCreated(xml_time(created))),
        header,
        external,
        standards,
        software,
        units,
        product,
        features,
        characteristics,
        result_set,
        statistics,
    ]
    root = E.QIFDocument(
        *[c for c in children if c is not None], versionQIF="3.0.0", idMax=str(ids.max)
    )
    root.set(f"{{{XSI}}}schemaLocation", SCHEMA_LOCATION)
    log.debug(
        "statistics of %s: %d inspections, %d characteristics, idMax %d",
        part_name,
        len(results),
        len(groups),
        ids.max,
    )
    return etree.ElementTree(root)


def _study_description(n: int, part_name: str, groups: dict[str, list[_Observation]]) -> str:
    """The study's description: what its statistics are over and how Cpk is computed."""
    kinds = {obs[0].char.kind for obs in groups.values()}
    if kinds <= {"SurfaceProfile"}:
        return (
            f"Capability of {n} inspections of {part_name}: per "
            "characteristic, statistics of the profile values (mm) of the "
            "measurements in Results; Cpk is the upper one-sided index "
            "(ToleranceValue - mean) / (3 s), s the sample standard deviation; "
            "attributes n_pass, n_fail, n_other count the characteristic statuses"
        )
    return (
        f"Capability of {n} inspections of {part_name}: per characteristic, statistics "
        "of the values of the measurements in Results (profile values and geometric "
        "tolerances' zone widths, mm; dimensions' sizes, mm or degrees); for a profile or "
        "geometric tolerance Cpk is the upper one-sided index (ToleranceValue - mean) / "
        "(3 s), for a dimension Cp = (USL - LSL) / (6 s) and Cpk = min(USL - mean, "
        "mean - LSL) / (3 s), s the sample standard deviation; attributes n_pass, n_fail, "
        "n_other count the characteristic statuses"
    )


def write_statistics(path: Path, tree: etree._ElementTree) -> None:
    """Write a statistics document as :func:`qifreport.qif.writer.write_qif` writes results (UTF-8,
    XML declaration, no BOM, default namespace, indented)."""
    write_qif(Path(path), tree)
