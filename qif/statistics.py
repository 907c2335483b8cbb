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
Every characteristic of a supported kind (:func:`~.batch_summary.is_supported`) with a
numeric tolerance or limits is carried:

* the surface profiles (``SurfaceProfile``), as the results documents carry them;
* the geometric tolerances of the drawing (the registered kinds' QIF types,
  :data:`qifreport.kinds.KINDS`, by their statistics rule: ``Flatness``,
  ``Position``, ``Perpendicularity``, ``CircularRunout`` ...): a zone width judged against
  its ``ToleranceValue`` (or the ``ToleranceValuePerUnit`` of a per-unit-length or
  per-unit-area tolerance), one-sided like a profile;
* the dimensions (:data:`~.batch_summary.LINEAR_DIMENSION_KINDS`: ``Diameter``,
  ``DistanceBetween``, ``Width`` ..., mm; :data:`~.batch_summary.ANGULAR_DIMENSION_KINDS`:
  ``Angle``, ``AngleBetween``, degrees):
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
A profile or geometric tolerance is one-sided (upper ``Cpk`` only), a dimension two-sided
(``Cp`` and ``Cpk``): :mod:`qifreport.qif.batch_summary`.

Numbers
-------
Statistics (``xs:decimal``) are written as the shortest decimal that reads back as the same
double (no exponent): a reader gets exactly the value computed here. Copied measurement
values are written the same way, so they equal the values read from the source documents.
"""

from __future__ import annotations

import logging
import math
from datetime import datetime
from pathlib import Path

import numpy as np
from lxml import etree

from qifreport import __version__

from .batch_summary import (
    ANGULAR_DIMENSION_KINDS,
    CharacteristicSummary,
    Observation,
    from_results,
    group_batch,
    qif_type_of,
    summarize,
    summary_of,
)
from .reader import QIFResults
from .statistics_copies import (
    CHARACTERISTIC_STATUSES,
    INSPECTION_STATUSES,
    Definitions,
    Runs,
    decimal_text,
    parse_time,
    source_uri,
    worst_deviations,
)
from .writer import write_qif
from .xmlkit import SCHEMA_LOCATION, XSI, Attrs, E, Ids, id_array, qpid, token, xml_time

__all__ = [
    "CHARACTERISTIC_STATUSES",
    "INSPECTION_STATUSES",
    "NO_VALUE_REASON",
    "CharacteristicSummary",
    "build_statistics",
    "summarize",
    "write_statistics",
]

log = logging.getLogger("qifreport.statistics")

#: exclusion reason of a measurement without a value
NO_VALUE_REASON = "no measured value"


def _stat(tag: str, x: float, ref: str | None = None) -> etree._Element:
    """A ``StatsMeasuredDecimalType`` value (``...WithReferenceType`` with ``ref``)."""
    children = [E.Value(decimal_text(x))]
    if ref is not None:
        children.append(E.Id(ref))
    return E(tag, *children)


def _count(tag: str, n: int, refs: list[str] | None = None) -> etree._Element:
    """A ``StatsNonNegativeIntegerType`` value (``...WithReferencesType`` with ``refs``)."""
    children = [E.Value(str(int(n)))]
    if refs:
        children.append(id_array("Ids", refs))
    return E(tag, *children)


def _informational() -> etree._Element:
    return E.Status(E.StatsEvalStatusEnum("INFORMATIONAL"))


def _check_batch(
    results: list[QIFResults],
    groups: dict[str, list[Observation]],
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
        if from_results(qif_type_of(obs[0].char)) and obs[0].char.spec.tolerance is None
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
    key: str, obs: list[Observation], s: CharacteristicSummary, meas_ids: list[str]
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
        if worst_deviations(s.kind)
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
    groups = group_batch(results)
    _check_batch(results, groups, sources, nominal_sha256)
    ids = Ids()
    definitions, std_id, sw_id = _definitions(
        results, groups, sources, standard, software_version, ids
    )
    part_id, comp_id, path_id = ids(), ids(), ids()
    defs, runs = _copies(results, groups, sources, path_id, ids)
    statistics = _study(results, groups, runs, part_name, created, nominal_sha256, sw_id, ids)
    root = _document(
        part_name,
        created,
        results,
        groups,
        definitions,
        defs,
        runs,
        statistics,
        (std_id, part_id, comp_id, path_id),
        ids,
    )
    log.debug(
        "statistics of %s: %d inspections, %d characteristics, idMax %d",
        part_name,
        len(results),
        len(groups),
        ids.max,
    )
    return etree.ElementTree(root)


def _definitions(
    results: list[QIFResults],
    groups: dict[str, list[Observation]],
    sources: list[str] | None,
    standard: tuple[str, str, str],
    software_version: str | None,
    ids: Ids,
) -> tuple[list[etree._Element | None], str, str]:
    """:func:`_document`'s ``definitions`` (``ExternalQIFReferences``, None without
    ``sources``; ``StandardsDefinitions``, ``SoftwareDefinitions``, ``FileUnits``), the
    standard's and the software's ids (the document's first two)."""
    std_id, sw_id = ids(), ids()
    standards = _standards(standard, std_id)
    software = _software(software_version or __version__, sw_id)
    units = _file_units(groups)
    external = _external_references(results, sources, ids)
    return [external, standards, software, units], std_id, sw_id


def _copies(
    results: list[QIFResults],
    groups: dict[str, list[Observation]],
    sources: list[str] | None,
    path_id: str,
    ids: Ids,
) -> tuple[Definitions, Runs]:
    """The characteristics' definitions copied from the results documents (one per group)
    and each inspection's copied measurements, given their ids from ``ids`` in that order;
    ``path_id``: the id of the part's ``AsmPath``, which the measurements refer to."""
    defs = Definitions()
    for key, obs in groups.items():
        defs.add(key, obs, ids)
    runs = Runs({(o.scan, o.char.document.id) for obs in groups.values() for o in obs})
    for k, res in enumerate(results):
        runs.add(k, res, defs.item_ids, sources, path_id, ids)
    return defs, runs


def _standards(standard: tuple[str, str, str], std_id: str) -> etree._Element:
    """``StandardsDefinitions``: the tolerancing standard (organization, designator, year)."""
    std_org, std_des, std_year = standard
    return E.StandardsDefinitions(
        E.Standard(
            E.Organization(E.StandardsOrganizationEnum(std_org)),
            E.Designator(std_des),
            E.Year(std_year),
            id=std_id,
        ),
        n="1",
    )


def _software(version: str, sw_id: str) -> etree._Element:
    """``SoftwareDefinitions``: qifreport, at ``version``."""
    return E.SoftwareDefinitions(
        E.Software(
            E.VendorName("qifreport"),
            E.ApplicationName("qifreport"),
            E.Version(version),
            E.Description("Dimensional inspection of flexible parts by virtual fixturing"),
            id=sw_id,
        ),
        n="1",
    )


def _file_units(groups: dict[str, list[Observation]]) -> etree._Element:
    """``FileUnits``: mm, and degrees when an angle is carried."""
    angular = []
    if any(qif_type_of(obs[0].char) in ANGULAR_DIMENSION_KINDS for obs in groups.values()):
        angular.append(
            E.AngularUnit(
                E.SIUnitName("radian"),
                E.UnitName("degree"),
                E.UnitConversion(E.Factor("0.0174532925199433")),
            )
        )
    return E.FileUnits(
        E.PrimaryUnits(
            *angular,
            E.LinearUnit(
                E.SIUnitName("meter"), E.UnitName("mm"), E.UnitConversion(E.Factor("0.001"))
            ),
        )
    )


def _external_references(
    results: list[QIFResults], sources: list[str] | None, ids: Ids
) -> etree._Element | None:
    """``ExternalQIFReferences``: one ``ExternalQIFDocument`` per results document (None
    without ``sources``)."""
    if sources is None:
        return None
    docs = []
    for k, (res, src) in enumerate(zip(results, sources, strict=True), start=1):
        serial = f", serial number {res.serial_number}" if res.serial_number else ""
        docs.append(
            E.ExternalQIFDocument(
                E.QPId(res.qpid),
                E.URI(source_uri(src)),
                E.Description(f"QIF results document of inspection {k}{serial}"),
                id=ids(),
            )
        )
    return E.ExternalQIFReferences(*docs, n=str(len(docs)))


def _study(
    results: list[QIFResults],
    groups: dict[str, list[Observation]],
    runs: Runs,
    part_name: str,
    created: datetime,
    nominal_sha256: str | None,
    sw_id: str,
    ids: Ids,
) -> etree._Element:
    """``Statistics``: the capability study, one ``<Kind>CharacteristicStats`` per
    designator."""
    summaries = {key: summary_of(key, obs) for key, obs in groups.items()}
    stats = [
        _characteristic_stats(
            key, obs, summaries[key], [runs.meas_id[(o.scan, o.char.document.id)] for o in obs]
        )
        for key, obs in groups.items()
    ]
    starts = [t for t in (parse_time(r.inspection_start) for r in results) if t is not None]
    ends = [t for t in (parse_time(r.inspection_end) for r in results) if t is not None]
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
        id_array("ResultsIds", runs.mr_ids),
        E.CharacteristicsStats(*stats, n=str(len(stats))),
        E.NumberOfSamples(str(len(results))),
    ]
    return E.Statistics(
        E.StatisticalStudiesResults(
            E.CapabilityStudyResults(*[x for x in study if x is not None], id=ids()), n="1"
        )
    )


def _document(
    part_name: str,
    created: datetime,
    results: list[QIFResults],
    groups: dict[str, list[Observation]],
    definitions: list[etree._Element | None],
    defs: Definitions,
    runs: Runs,
    statistics: etree._Element,
    part_ids: tuple[str, str, str, str],
    ids: Ids,
) -> etree._Element:
    """The ``QIFDocument``: header, ``definitions`` (external references, standards,
    software, units; None left out), product, features, characteristics, results and the
    statistics; ``part_ids``: the standard's, part's, component's and assembly path's ids."""
    std_id, part_id, comp_id, path_id = part_ids
    zs = defs.sections
    part = E.Part(
        E.Header(E.Name(part_name)),
        E.UUID(qpid()),
        id_array("FeatureNominalIds", zs.fnom_ids),
        id_array("CharacteristicNominalIds", [c.get("id") for c in zs.cnoms]),
        id=part_id,
    )
    product = E.Product(
        E.PartSet(part, n="1"),
        E.ComponentSet(E.Component(E.UUID(qpid()), E.Part(E.Id(part_id)), id=comp_id), n="1"),
        E.RootPart(E.Id(part_id)),
        E.AsmPaths(E.AsmPath(id_array("ComponentIds", [comp_id]), id=path_id), n="1"),
    )
    features, characteristics = zs.features(), zs.characteristics(std_id)
    result_set = E.Results(
        E.MeasurementResultsSet(*runs.mrs, n=str(len(runs.mrs))),
        E.ActualComponentSets(E.ActualComponentSet(*runs.actuals, n=str(len(runs.actuals))), n="1"),
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
        *definitions,
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
    return root


def _study_description(n: int, part_name: str, groups: dict[str, list[Observation]]) -> str:
    """The study's description: what its statistics are over and how Cpk is computed."""
    if all(from_results(qif_type_of(obs[0].char)) for obs in groups.values()):
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
