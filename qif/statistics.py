"""QIF 3.0 Statistics document of a batch of inspections.

qifreport inspects many scans of one part (a batch); each scan has its QIF results document
(:mod:`qifreport.qif.writer`), read back with :func:`qifreport.qif.reader.read_results`.
:func:`summarize` reduces the batch to one :class:`CharacteristicSummary` per characteristic
(per designator, e.g. ``"T1"``, ``"general"``) and :func:`build_statistics` writes it as a
QIF 3.0 document whose ``Statistics`` section (``QIFApplications/QIFStatistics.xsd``,
``QIFLibrary/Statistics.xsd``) holds one capability study with one typed statistics element
per characteristic.

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
``FileUnits``                                mm
``Product``, ``Features``                    the part, one ``OtherSurfaceFeature`` definition,
                                             nominal and item per characteristic
``Characteristics``                          per designator: ``SurfaceProfileCharacteristic``
                                             ``Definition`` (``Name``, ``Description``,
                                             ``ToleranceValue``, ``UnequallyDisposedZone``),
                                             ``Nominal`` and ``Item`` (``CharacteristicDesignator``)
``Results/MeasurementResultsSet``            one ``MeasurementResults`` per inspection, in the
                                             order given: inspection times, (with ``sources``)
                                             an ``ExternalFileReference`` to its QIF file, one
                                             ``SurfaceProfileCharacteristicMeasurement`` per
                                             characteristic (``Status``, ``Value``,
                                             ``WorstPositiveDeviation``,
                                             ``WorstNegativeDeviation`` copied; its id in the
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

Each characteristic's statistics are a ``SurfaceProfileCharacteristicStats`` element
(``SurfaceProfileCharacteristicStatsEvalType``, from ``ProfileCharacteristicStatsEvalBaseType``
and ``GeometricCharacteristicStatsEvalType``):

* ``Attributes``: ``designator`` (``AttributeStr``); ``n_pass``, ``n_fail``, ``n_other``
  (``AttributeI1``): how many of its measurements have the characteristic status ``PASS``,
  ``FAIL`` or another one (``INDETERMINATE``, ``NOT_ANALYZED``...). QIF has no statistics
  element for counts of a characteristic's status: ``NumberOutOfTolerance`` counts values
  beyond the tolerance, and qifreport's status is its acceptance rule, not that comparison
  (a part can PASS with a profile value above the tolerance, see :mod:`qifreport.qif.writer`).
* ``MeasuredIds`` (``StatsArrayIdType``): the ids of its measurements in ``Results``, all of
  them; those without a measured value are ``Exclusions`` (reason ``OtherExclusionReason``).
* ``Status``: ``INFORMATIONAL`` (no capability requirement was given to judge against).
* ``ValueStats`` (``StatsWithTolLinearType``), over the profile values (the measurements'
  ``Value``, mm; see :mod:`qifreport.qif.writer`): ``TotalNumber`` (measurements),
  ``EffectiveNumber`` (those with a value, ``count``), ``Average``, ``StandardDeviation`` (the
  sample standard deviation, ``n - 1`` in the denominator, as the schema defines ``STDDEV``;
  written when ``count >= 2``), ``Minimum`` and ``Maximum`` (each with the ``Id`` of its
  measurement),
  ``Range``, ``NumberOutOfTolerance`` (values above the tolerance, with their ``Ids``),
  ``Cpk``.
* ``CapabilityCalculationMethod``: ``THREE_SIGMA`` when ``Cpk`` is written.
* ``WorstPositiveDeviationStats``, ``WorstNegativeDeviationStats`` (``StatsLinearType``):
  ``Average``, ``Minimum``, ``Maximum`` of the measurements' worst deviations (mm).

Capability
----------
A profile tolerance is one-sided: the profile value is a zone width, at least 0, and the
characteristic conforms when it is at most ``ToleranceValue``. The lower specification limit
is 0 and the upper ``USL = ToleranceValue``. ``Cp = (USL - LSL) / (6 sigma)`` supposes a
two-sided tolerance with a process centred between the limits; it has no meaning here and
``Cp`` is not written. ``Cpk`` is the upper index only, with the batch's sample standard
deviation ``s``::

    Cpk = (USL - mean) / (3 s)

(the schema's ``CapabilityCalculationMethod`` ``THREE_SIGMA`` for one-sided tolerances),
written when ``count >= 2`` and ``s > 0``. With the overall sample deviation (no rational
subgroups) the index is what AIAG SPC calls ``Ppk``; it is written as ``Cpk``, the name the
product uses. Profile values are bounded below by 0 and skewed, so the normal-tail reading of
a ``Cpk`` (e.g. 1.33 ~ 32 ppm) is an approximation.

Numbers
-------
Statistics (``xs:decimal``) are written as the shortest decimal that reads back as the same
double (no exponent): a reader gets exactly the value computed here. Copied measurement
values are written the same way, so they equal the values read from the source documents.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from urllib.parse import quote

import numpy as np
from lxml import etree

from qifreport import __version__
from qifreport.metrology.spc import upper_cpk

from .reader import CharacteristicResult, QIFResults
from .writer import write_qif
from .xmlkit import SCHEMA_LOCATION, XSI, Attrs, E, Ids, id_array, qpid, token, xml_time

__all__ = [
    "CHARACTERISTIC_STATUSES",
    "INSPECTION_STATUSES",
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
#: characteristic kinds :func:`build_statistics` can write (``<kind>CharacteristicStats``)
SUPPORTED_KINDS = frozenset({"SurfaceProfile"})
#: exclusion reason of a measurement without a value
NO_VALUE_REASON = "no measured value"


@dataclass
class CharacteristicSummary:
    """Statistics of one characteristic over a batch of inspections.

    Attributes
    ----------
    designator : str
        The characteristic's designator (qifreport: the zone key, ``"T1"``, ``"general"``);
        its name when it has none.
    kind : str
        QIF characteristic type without suffix, e.g. ``"SurfaceProfile"``.
    description : str or None
        The definition's description (first one seen).
    tolerance : float or None
        The definition's ``ToleranceValue`` (mm): the upper specification limit of the value.
    count : int
        Measurements with a finite value.
    mean, std : float
        Mean and sample standard deviation (``ddof=1``) of the values, mm; NaN when
        ``count`` is 0 (mean) or below 2 (std).
    min, max : float
        Smallest and largest value, mm (NaN when ``count`` is 0).
    n_pass, n_fail, n_other : int
        Measurements whose characteristic status is ``PASS``, ``FAIL``, anything else.
    cp : float or None
        Two-sided capability index: None, a geometric tolerance is one-sided.
    cpk : float or None
        Upper capability index ``(tolerance - mean) / (3 std)``; None without a tolerance,
        with ``count < 2`` or ``std == 0``.
    n_out_of_tolerance : int
        Values above the tolerance (0 without a tolerance).
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


@dataclass
class _Observation:
    """One characteristic measurement of the batch: the inspection it is from, and it."""

    scan: int
    char: CharacteristicResult

    @property
    def value(self) -> float | None:
        v = self.char.value
        return v if v is not None and math.isfinite(v) else None


def _profiles(res: QIFResults) -> list[CharacteristicResult]:
    """The surface-profile characteristics of one results document: what this
    Statistics document carries (the feature characteristics of issue 22 are listed in
    each results file; their batch statistics are not written yet)."""
    return [c for c in res.characteristics if c.kind == "SurfaceProfile"]


def _key(c: CharacteristicResult) -> str:
    key = c.designator if c.designator is not None else c.name
    if key is None:
        raise ValueError(
            f"characteristic measurement {c.id} ({c.kind}) has neither a "
            "designator nor a name: it cannot be matched across the batch"
        )
    return key


def _group(results: list[QIFResults]) -> dict[str, list[_Observation]]:
    """The batch's measurements by designator, designators in first-seen order.

    Raises
    ------
    ValueError
        A designator changes type or tolerance within the batch.
    """
    groups: dict[str, list[_Observation]] = {}
    for k, res in enumerate(results):
        for c in _profiles(res):
            obs = groups.setdefault(_key(c), [])
            if obs:
                first = obs[0].char
                if c.kind != first.kind:
                    raise ValueError(
                        f"{_key(c)}: {c.kind} in {res.path.name} but {first.kind} "
                        "before: not one part's batch"
                    )
                if c.tolerance != first.tolerance:
                    raise ValueError(
                        f"{_key(c)}: tolerance {c.tolerance} in {res.path.name} "
                        f"but {first.tolerance} before: not one part's batch"
                    )
            obs.append(_Observation(k, c))
    return groups


def _summary(key: str, obs: list[_Observation]) -> CharacteristicSummary:
    first = obs[0].char
    values = np.array([o.value for o in obs if o.value is not None], dtype=float)
    count = len(values)
    mean = float(values.mean()) if count else math.nan
    std = float(values.std(ddof=1)) if count >= 2 else math.nan
    tol = first.tolerance
    cpk = None if tol is None else upper_cpk(mean, std, tol, count)
    cpk = None if cpk is None or math.isnan(cpk) else cpk
    statuses = [o.char.status for o in obs]
    n_pass, n_fail = statuses.count("PASS"), statuses.count("FAIL")
    return CharacteristicSummary(
        designator=key,
        kind=first.kind,
        description=next((o.char.description for o in obs if o.char.description), None),
        tolerance=tol,
        count=count,
        mean=mean,
        std=std,
        min=float(values.min()) if count else math.nan,
        max=float(values.max()) if count else math.nan,
        n_pass=n_pass,
        n_fail=n_fail,
        n_other=len(obs) - n_pass - n_fail,
        cp=None,
        cpk=cpk,
        n_out_of_tolerance=int((values > tol).sum()) if tol is not None else 0,
    )


def summarize(results: list[QIFResults]) -> list[CharacteristicSummary]:
    """Per-characteristic statistics of a batch of inspections.

    Parameters
    ----------
    results : list of QIFResults
        The batch's results documents, read back (:func:`qifreport.qif.reader.read_results`).

    Returns
    -------
    list of CharacteristicSummary
        One per designator, in the order the designators first appear.

    Raises
    ------
    ValueError
        A characteristic has no designator and no name, or a designator changes type or
        tolerance within the batch.
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
    kinds = sorted({obs[0].char.kind for obs in groups.values()} - SUPPORTED_KINDS)
    if kinds:
        raise ValueError(
            f"characteristic types without statistics support here: {kinds} "
            f"(supported: {sorted(SUPPORTED_KINDS)})"
        )
    untoleranced = [key for key, obs in groups.items() if obs[0].char.tolerance is None]
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
    """The ``SurfaceProfileCharacteristicStats`` of one characteristic.

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
    above = [m for v, m in values if v > s.tolerance]
    vs.append(_count("NumberOutOfTolerance", len(above), above))
    if s.cpk is not None:
        vs.append(_stat("Cpk", s.cpk))

    children = [attrs.element(), E.MeasuredIds(*measured), _informational(), E.ValueStats(*vs)]
    if s.cpk is not None:
        children.append(E.CapabilityCalculationMethod("THREE_SIGMA"))
    for tag, field in (
        ("WorstPositiveDeviationStats", "worst_positive"),
        ("WorstNegativeDeviationStats", "worst_negative"),
    ):
        w = [(getattr(o.char, field), m) for o, m in zip(obs, meas_ids, strict=True)]
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
    return E.SurfaceProfileCharacteristicStats(*children)


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
        order. Every characteristic must be a surface profile with a ``ToleranceValue``.
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
        No results, ``sources`` of another length, a source without QPId, another
        characteristic type, a characteristic without tolerance or changing type or
        tolerance within the batch, or a result inspected against another nominal.
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
    units = E.FileUnits(
        E.PrimaryUnits(
            E.LinearUnit(
                E.SIUnitName("meter"), E.UnitName("mm"), E.UnitConversion(E.Factor("0.001"))
            )
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
        fd, fn, fi, cd, cn, ci = (ids() for _ in range(6))
        item_ids[key] = ci
        fname = token(f"SURFACE_{key}".upper())
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
        citems.append(
            E.SurfaceProfileCharacteristicItem(
                E.Name(name),
                E.CharacteristicDesignator(E.Designator(token(key))),
                id_array("FeatureItemIds", [fi]),
                E.CharacteristicNominalId(cn),
                id=ci,
            )
        )

    # -- the batch's measurements, copied: one MeasurementResults per inspection
    meas_id: dict[tuple[int, str], str] = {}  # (inspection, source measurement id) -> id
    mr_ids, mrs, actuals = [], [], []
    for k, res in enumerate(results):
        actual_id, mr_id = ids(), ids()
        mr_ids.append(mr_id)
        meas = []
        for c in _profiles(res):
            m = meas_id[(k, c.id)] = ids()
            el = [
                Attrs().s("source_id", c.id).element(),
                _characteristic_status(c.status),
                E.CharacteristicItemId(item_ids[_key(c)]),
                E.ActualComponentId(actual_id),
            ]
            for tag, x in (
                ("Value", c.value),
                ("WorstPositiveDeviation", c.worst_positive),
                ("WorstNegativeDeviation", c.worst_negative),
            ):
                if x is not None and math.isfinite(x):
                    el.append(E(tag, _num(x)))
            meas.append(E.SurfaceProfileCharacteristicMeasurement(*el, id=m))
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
        E.Description(
            f"Capability of {len(results)} inspections of {part_name}: per "
            "characteristic, statistics of the profile values (mm) of the "
            "measurements in Results; Cpk is the upper one-sided index "
            "(ToleranceValue - mean) / (3 s), s the sample standard deviation; "
            "attributes n_pass, n_fail, n_other count the characteristic statuses"
        ),
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


def write_statistics(path: Path, tree: etree._ElementTree) -> None:
    """Write a statistics document as :func:`qifreport.qif.writer.write_qif` writes results (UTF-8,
    XML declaration, no BOM, default namespace, indented)."""
    write_qif(Path(path), tree)
