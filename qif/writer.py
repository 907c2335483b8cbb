"""QIF 3.0 results document of one inspection.

One ``QIFDocument`` (``versionQIF="3.0.0"``, default namespace ``http://qifstandards.org/xsd/qif3``)
per inspection, written with lxml. What goes where:

=========================================  ==================================================
``Header``, ``SoftwareDefinitions``         qifreport and its version, author/organization
``ExternalQIFReferences``                   a STEP nominal's QIF plan (:mod:`.plan`), by its
                                            QPId and file name ``<stem>_plan.qif``; the
                                            document carries that plan in full, each of its
                                            elements with the plan document's id and UUID
                                            (:func:`~.plan.plan_sections` runs first), and
                                            measures its items
``AlgorithmDefinitions``                    rigid alignment and the virtual fixture (GB-CICP
                                            or the ``--method`` baseline), with their
                                            parameters (JSON)
``FileUnits``                               mm, degree, mm^2
``DatumDefinitions``, ``DatumReferenceFrames``  the datums of the PMI, one frame per datum
                                            sequence a profile tolerance cites
``MeasurementResources``                    the scanner whose acceptance figures the
                                            uncertainty budgets used (a ``MeasurementDevice``,
                                            :mod:`.uncertainty`), named by each characteristic
                                            measurement that has a budget
``Product``                                 the part (name, UUID), its component and assembly
                                            path; the toleranced surfaces are referenced from it
``Features``                                one ``OtherSurfaceFeature`` per toleranced surface
                                            (its B-rep faces as STEP entity ids, an Attribute)
``Characteristics``                         one ``SurfaceProfileCharacteristic`` per profile
                                            tolerance of the PMI (the plan's items), plus the
                                            general tolerance (the command line's, or the
                                            default: "not from the drawing") on the faces no
                                            profile covers; beside each, its acceptance
                                            rule's decision (a ``UserDefinedAttribute``
                                            characteristic ``<key>_ACCEPTANCE``); then the
                                            drawing's feature tolerances and dimensions as
                                            their own types (:mod:`.feature_characteristics`)
``Results/MeasurementResultsSet``           one ``MeasurementResults``: traceability (input
                                            files and SHA-256, software, time), one feature
                                            measurement per surface, one characteristic
                                            measurement per tolerance, the inspection status
``Results/ActualComponentSets``             the inspected part, its status, its serial number
=========================================  ==================================================

Values
------
The characteristic measurement's ``Value`` is the **profile value** of QIF / ASME Y14.5: the
width of the smallest zone, disposed as the tolerance zone (same centre ``c``), that contains
every scored point of the surface and the peaks of its out-of-tolerance regions,
``2 max |d - c|``. ``WorstPositiveDeviation`` and ``WorstNegativeDeviation`` are the signed
extremes of the deviation ``d``. Its **status** is the profile read as the drawing states it
(:func:`~qifreport.qif.profile_characteristics.strict_profile_status`): ``FAIL`` whenever the
value exceeds the tolerance, so a ``Value`` beyond its ``ToleranceValue`` is never ``PASS``.

qifreport's decision for a compliant part (paper Section 10: the area criterion, at least
``min_fraction`` of the scored area in the band, and the region criterion, no connected
out-of-tolerance region larger than ``max_region_area``) is another rule than value <=
tolerance. QIF states a characteristic judged by a rule of its own as a
``UserDefinedAttributeCharacteristic`` (``WhatToMeasure``: the rule; ``PassValues``
``CONFORMS``, ``FailValues`` ``DOES_NOT_CONFORM``): one per surface, ``<key>_ACCEPTANCE``,
whose status is that decision (the one the inspection status follows). A surface with a few
isolated points out of its band therefore reads FAIL on its profile and PASS on its
acceptance: each status agrees with its own value.

Statistics QIF has no element for (RMS, mean, P95/P99/P99.9, tail fractions, in-tolerance area
fraction, coverage, out-of-tolerance regions) are typed ``Attributes`` (``AttributeD1``,
``AttributeI1``, ``AttributeD3``, ``AttributeBool``, ``AttributeStr``); their names end in the
unit (``_mm``, ``_mm2``; fractions are 0..1). Whole-part results are Attributes of the
``MeasurementResults``; per-tolerance results are Attributes of each characteristic
measurement. Out-of-tolerance regions are ``region_<k>_*`` attributes (area, peak, sign,
centroid and peak location in the nominal frame), largest first. The virtual fixture's method
is ``fit_method`` (``gbcicp``, ``nicp``, ``cpd``, ``rbffem``) beside the other ``fit_*``
attributes. With ``--seeds`` the regions are the persistent ones only and the resampling
study is in ``repeatability_*`` attributes (counts, RMS/max per run and their spread as a
half-range, the dropped regions).

Lengths are ``xs:decimal`` in QIF (no exponent): they are written with
:data:`DECIMAL_PLACES` places (0.1 um); doubles (Attributes) are written exactly (``repr``).

Modules
-------
A surface's two characteristics are written from their
:class:`~qifreport.metrology.gdt.characteristic_types.CharacteristicResult`
(:mod:`qifreport.qif.profile_characteristics`, which also has the profile value and
statuses), the drawing's feature characteristics from theirs
(:mod:`qifreport.qif.feature_characteristics`). The generic XML building blocks (element
maker, ids, literals, ``Attributes``) are in :mod:`qifreport.qif.xmlkit`, shared with the
statistics documents; the results' typed ``Attributes`` in
:mod:`qifreport.qif.result_attributes`. :func:`build_qif` puts the sections together in
document order, each made by its own builder below.
"""

from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass, field, is_dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
from lxml import etree

from qifreport.jsonio import json_default
from qifreport.metrology.gdt.pmi_plan import CharacteristicPlan
from qifreport.metrology.inspection import (
    FREE_STATE_CONFORMS,
    FREE_STATE_LOCAL_DEFECTS,
    FREE_STATE_UNCERTAIN,
    InspectionResult,
    ZoneResult,
)
from qifreport.registration.deformable.methods import method_spec

from .composite import fold_measurement
from .definitions import (
    CONFORMS,
    DOES_NOT_CONFORM,
    Sections,
    acceptance_definition,
    datum_definitions,
    datum_reference_frames,
    drf_key,
    face_attrs,
    feature_definition,
    feature_measurement,
    file_units,
    product,
    profile_definition,
    profile_feature_name,
    software_definitions,
    standards_definitions,
)
from .feature_characteristics import (
    characteristic_definition,
    characteristic_measurement,
    qif_status,
    qif_type,
)
from .plan import (
    PlanItem,
    PlanSections,
    PlanSource,
    more_frames,
    plan_qpid,
    plan_reference,
    plan_sections,
)
from .profile_characteristics import (
    acceptance_characteristic,
    profile_characteristic,
    profile_value,
)
from .result_attributes import (
    MAX_REGIONS_LISTED,
    acceptance_attrs,
    coverage_attrs,
    detectable_attrs,
    measurement_results_attrs,
    stats_attrs,
)
from .uncertainty import measurement_resources
from .xmlkit import (
    DECIMAL_PLACES,
    NS,
    SCHEMA_LOCATION,
    XSI,
    Attrs,
    E,
    Ids,
    dec,
    id_array,
    qpid,
    token,
    xml_time,
)

__all__ = [
    "DECIMAL_PLACES",
    "MAX_REGIONS_LISTED",
    "NS",
    "SCHEMA_LOCATION",
    "XML_DECLARATION",
    "XSI",
    "E",
    "Provenance",
    "acceptance_rule",
    "build_qif",
    "dec",
    "write_qif",
]


@dataclass
class Provenance:
    """What the results document says about where the inspection came from.

    Attributes
    ----------
    part_name : the part's name (the nominal file's stem by default).
    nominal_path, scan_path : the input files as given.
    nominal_sha256, scan_sha256 : hex SHA-256 digests of the input files.
    started, finished : time of inspection (timezone-aware).
    datums : datum labels defined by the PMI (file order), ``[]`` without PMI.
    face_step_ids : (n_faces,) the STEP entity id of each B-rep face (-1 unknown), None for
        a mesh nominal.
    nominal_info : description of the nominal (format, tessellation, PMI counts).
    author, organization, operator, serial_number : options of the command line.
    standard : (organization, designator, year) of the tolerancing standard.
    trace : the inspection's traceability (:func:`qifreport.pipeline.traceability`: part
        number, revision, instrument, temperature ...); ``{}`` when not known.
    plan : the part's plan (a STEP nominal's drawing, :mod:`.plan`): the results carry it
        with the plan document's ids and UUIDs and measure its items; None: no drawing to
        refer to.
    """

    part_name: str
    nominal_path: str
    scan_path: str
    nominal_sha256: str
    scan_sha256: str
    started: datetime
    finished: datetime
    datums: list[str] = field(default_factory=list)
    nominal_info: dict = field(default_factory=dict)
    face_step_ids: np.ndarray | None = None
    author: str | None = None
    organization: str | None = None
    operator: str | None = None
    serial_number: str | None = None
    standard: tuple[str, str, str] = ("ASME", "Y14.5", "2018")
    plan: PlanSource | None = None
    trace: dict = field(default_factory=dict)


def acceptance_rule(min_fraction: float, max_region_area: float) -> str:
    """The conformance rule stated in every characteristic definition."""
    return (
        f"qifreport virtual-fixture acceptance: at least {100 * min_fraction:g} % of the "
        f"scored area within the zone (area criterion) and no connected out-of-tolerance "
        f"region larger than {max_region_area:g} mm^2 (region criterion)"
    )


def build_qif(res: InspectionResult, prov: Provenance) -> etree._ElementTree:
    """The QIF 3.0 results document of one inspection (an lxml tree, not yet written).

    Parameters
    ----------
    res : InspectionResult
        The inspection.
    prov : Provenance
        Where it came from (inputs, times, people, the standard).

    Returns
    -------
    lxml.etree._ElementTree
        Write it with :func:`write_qif`.
    """
    # -- the plan first, with the same ids and UUIDs as the plan document
    src = prov.plan if prov.plan is not None else _without_drawing(prov)
    ids = Ids(namespace=plan_qpid(src.nominal_sha256) if prov.plan is not None else None)
    ps = plan_sections(src, ids)
    cited = [drf_key(z.zone.datums, z.zone.datum_materials) for z in res.zones]
    cited += [drf_key(c.spec.datums, c.spec.datum_materials) for c in res.characteristics]
    more_frames(ps, cited, ids)

    # -- definitions only the results have: algorithms, the instrument, the inspected part
    rigid_alg_id, fit_alg_id = ids(), ids()
    algorithms = _algorithm_definitions(res, ps.sw_id, rigid_alg_id, fit_alg_id)
    device_id = ids()
    resources = measurement_resources(res.params.scanner, device_id)
    actual_id = ids()

    # -- the measurements, on the plan's items (the rest: items of the results' own)
    rule = acceptance_rule(res.params.min_fraction, res.params.max_region_area)
    zs = ps.zs
    _measurements(res, ps, prov.face_step_ids, ids, rule, actual_id, device_id)
    results = _results(res, prov, ps.sw_id, zs, ps.part.asm_path, actual_id, ids)
    # a STEP nominal's plan (qifreport plan), by its QPId
    plan_ref = None
    if prov.plan is not None:
        plan_ref = plan_reference(Path(prov.nominal_path).stem, prov.nominal_sha256, ids())

    children = [
        E.QPId(qpid()),
        E.Version(E.TimeCreated(xml_time(prov.finished))),
        _header(prov),
        plan_ref,
        standards_definitions(prov.standard, ps.std_id),
        software_definitions(ps.sw_id),
        algorithms,
        file_units(),
        datum_definitions(ps.dids, ps.datum_features),
        datum_reference_frames(ps.drf_ids, ps.dids),
        resources,
        product(
            prov.part_name,
            ps.part,
            zs,
            ps.dids,
            ps.drf_ids,
            ids,
            number=(prov.trace or {}).get("part_number"),
            version=(prov.trace or {}).get("revision"),
        ),
        zs.features(),
        zs.characteristics(ps.std_id),
        results,
    ]
    root = E.QIFDocument(
        *[c for c in children if c is not None], versionQIF="3.0.0", idMax=str(ids.max)
    )
    root.set(f"{{{XSI}}}schemaLocation", SCHEMA_LOCATION)
    return etree.ElementTree(root)


# ---------------------------------------------------------------------------------------------
# section builders, in document order


def _header(prov: Provenance) -> etree._Element:
    """``Header``: the application, the author and organization, what was inspected."""
    header = [E.Application(E.Name("qifreport"), E.Organization("qifreport project"))]
    if prov.author or prov.organization:
        header.append(
            E.Author(
                *([E.Name(prov.author)] if prov.author else []),
                *([E.Organization(prov.organization)] if prov.organization else []),
            )
        )
    header.append(
        E.Description(
            f"Virtual-fixturing inspection of {prov.part_name}: "
            f"{Path(prov.scan_path).name} against "
            f"{Path(prov.nominal_path).name}"
        )
    )
    return E.Header(*header)


def _algorithm_definitions(
    res: InspectionResult, sw_id: str, rigid_alg_id: str, fit_alg_id: str
) -> etree._Element:
    """``AlgorithmDefinitions``: the rigid alignment and the virtual fixture (parameters as
    JSON)."""
    params = res.params
    rigid = res.rigid
    method = res.fit.method if res.fit is not None else params.method
    fit_params = _params_dict(res.fit.params) if res.fit is not None else None
    return E.AlgorithmDefinitions(
        E.Algorithm(
            E.SoftwareId(sw_id),
            E.Parameters(
                json.dumps(
                    {"method": "robust point-to-plane ICP", "iterations": int(rigid.iterations)}
                )
            ),
            E.Name("rigid alignment"),
            E.Description("robust scan-to-model ICP (paper Section 3)"),
            id=rigid_alg_id,
        ),
        E.Algorithm(
            E.SoftwareId(sw_id),
            E.Parameters(
                json.dumps(
                    {
                        "method": method,
                        "energy": res.energy,
                        "rigid_only": params.rigid_only,
                        "condition": res.condition.to_dict(),
                        "fixture_decision": res.fixture_decision,
                        method: fit_params,
                        "restraint": None
                        if res.restraint is None
                        else {k: v for k, v in res.restraint.to_dict().items() if k != "clamps"},
                    },
                    default=json_default,
                )
            ),
            E.Name(_fixture_name(res)),
            E.Description(
                "linear elasticity of the part (quadratic tetrahedra): each clamp driven "
                "back to nominal along its directions, the held scan judged without a fit"
                if res.restraint is not None
                else method_spec(method).qif_algorithm
            ),
            id=fit_alg_id,
        ),
        n="2",
    )


def measured_condition(z: ZoneResult, res: InspectionResult) -> str:
    """The state a characteristic was measured in: ``"restrained"`` (held at its clamps
    by the part's elasticity, ISO 10579), ``"virtual fixture"`` (the free method's fit) or
    ``"free state"`` (the part as it lay: no restraint, or a free-state (F) tolerance)."""
    if not z.fixtured:
        return "free state"
    return "restrained" if res.restraint is not None else "virtual fixture"


def _fixture_name(res) -> str:
    """The virtual fixture's algorithm name: what was applied."""
    if res.restraint is not None:
        return (
            f"restrained at {len(res.restraint.clamps)} clamps by the part's elastic model "
            "(ISO 10579)"
        )
    if res.fit is not None:
        return "virtual fixture"
    if res.fixture_decision == FREE_STATE_CONFORMS:
        return "none (the free state conforms: no restraint needed)"
    if res.fixture_decision == FREE_STATE_UNCERTAIN:
        return "none (the free state is not proven out of tolerance: no restraint simulated)"
    if res.fixture_decision == FREE_STATE_LOCAL_DEFECTS:
        return "none (the free state fails only on defects narrower than the mesh)"
    return "none (rigid only)"


def _without_drawing(prov: Provenance) -> PlanSource:
    """The plan of a part whose inspection has no drawing to refer to (a mesh nominal): no
    item, the datums of the provenance."""
    return PlanSource(
        part_name=prov.part_name,
        nominal_path=prov.nominal_path,
        nominal_sha256=prov.nominal_sha256,
        zones=[],
        plan=CharacteristicPlan(),
        datums=list(prov.datums),
        face_step_ids=prov.face_step_ids,
    )


def _measurements(
    res: InspectionResult,
    ps: PlanSections,
    face_step_ids: np.ndarray | None,
    ids: Ids,
    rule: str,
    actual_id: str,
    device_id: str,
) -> None:
    """Every zone's and feature characteristic's measurements, appended to ``ps.zs``: on
    the plan's items where the drawing states them; a zone or characteristic the plan has
    not (the command line's or the default band, an item read as another QIF type) gets its
    own definition, nominal and item first. Each zone's acceptance characteristic is the
    results' own."""
    zs = ps.zs
    lowers: list[tuple[PlanItem, etree._Element]] = []  # composite lower segments
    for z in res.zones:
        item = ps.zones.get(z.zone.key)
        if item is None:
            fa = face_attrs(z.zone.faces, face_step_ids)
            fname = profile_feature_name(z.zone)
            fn, fi, fm = feature_definition(zs, fname, fa, ids, actual_id)
            ci = profile_definition(zs, z.zone, rule, ps.drf_ids, ids, fn, fi)
        else:
            fn, fi, ci = item.feature_nominal, item.feature_item, item.characteristic_item
            fm = feature_measurement(zs, fi, item.feature_name, actual_id, ids)
        m = _characteristic_measurement(z, res, ci, fm, actual_id, ids())
        _append_or_hold(zs, lowers, item, m)
        ci = acceptance_definition(zs, z.zone, rule, ids, fn, fi)
        zs.cmeas.append(_acceptance_measurement(z, res, ci, fm, actual_id, ids()))
    for c in res.characteristics:
        item = ps.specs.get(c.spec.key)
        if item is not None and item.qif_type != qif_type(c.spec, c.direction):
            item = None  # read as another type than the plan's: the results' own item
        if item is not None:
            ci = item.characteristic_item
            fm = feature_measurement(zs, item.feature_item, item.feature_name, actual_id, ids)
        else:
            _, ci, fm = characteristic_definition(
                zs,
                c.spec,
                ids,
                ps.drf_ids,
                face_step_ids,
                direction=c.direction,
                result=c,
                actual_id=actual_id,
            )
        m = characteristic_measurement(c, ids, ci, fm, actual_id, device_id)
        _append_or_hold(zs, lowers, item, m)
    _fold_segments(zs, lowers, ids)


def _fold_segments(zs: Sections, lowers: list[tuple[PlanItem, etree._Element]], ids: Ids) -> None:
    """Fold each composite lower segment's measurement into its frame's (the upper
    segment's, :func:`qifreport.qif.composite.fold_measurement`)."""
    item_of = f"{{{NS}}}CharacteristicItemId"
    by_item = {x.findtext(item_of): x for x in zs.cmeas}
    for item, m in lowers:
        upper = by_item.get(m.findtext(item_of))
        if upper is None:  # the upper segment is not measured: the frame is not
            why = "the composite frame's upper segment is not measured"
            upper = _not_measured_frame(m, why, ids())
            zs.cmeas.append(upper)
            by_item[m.findtext(item_of)] = upper
        fold_measurement(upper, m, item.qif_type, item.segment)


def _append_or_hold(zs: Sections, lowers: list, item: PlanItem | None, m: etree._Element) -> None:
    """Append measurement ``m`` to the document's, or hold it to fold into its composite
    frame's upper segment when its plan item is a lower segment."""
    if item is not None and item.segment > 1:
        lowers.append((item, m))
    else:
        zs.cmeas.append(m)


def _not_measured_frame(m: etree._Element, why: str, cm: str) -> etree._Element:
    """A composite frame's measurement (id ``cm``) without its upper segment: ``m``'s item,
    features and part, status ``NOT_ANALYZED`` for reason ``why``."""
    keep = ("CharacteristicItemId", "FeatureMeasurementIds", "ActualComponentId")
    kids = [copy.deepcopy(x) for x in m if etree.QName(x).localname in keep]
    return E(
        m.tag,
        Attrs().s("not_measured_reason", why).element(),
        E.Status(E.CharacteristicStatusEnum("NOT_ANALYZED")),
        *kids,
        id=cm,
    )


def _acceptance_measurement(
    z: ZoneResult, res: InspectionResult, ci: str, fm: str, actual_id: str, cm: str
) -> etree._Element:
    """The acceptance characteristic's measurement (:func:`acceptance_characteristic`): the
    inspection's decision for the surface (area and region criteria under the decision
    rule), ``CONFORMS`` or ``DOES_NOT_CONFORM``; the profile characteristic beside it keeps
    the strict reading, so neither contradicts its own value."""
    c = acceptance_characteristic(z, res.established)
    meas = [
        E.Status(E.CharacteristicStatusEnum(_status(z, c))),
        E.CharacteristicItemId(ci),
        id_array("FeatureMeasurementIds", [fm]),
        E.ActualComponentId(actual_id),
    ]
    if c.reason:
        meas.append(E.NonConformanceDesignator(token(c.reason)))
    if c.status in ("PASS", "FAIL"):
        meas.append(E.Value(CONFORMS if c.status == "PASS" else DOES_NOT_CONFORM))
    return E.UserDefinedAttributeCharacteristicMeasurement(*meas, id=cm)


def _status(z: ZoneResult, c) -> str:
    """A zone's characteristic status: as measured, or ``UNDEFINED`` for a zone the verdict
    does not judge (qifreport's default band beside a drawing: no requirement, reported)."""
    return qif_status(c) if z.judged else "UNDEFINED"


def _characteristic_measurement(
    z: ZoneResult, res: InspectionResult, ci: str, fm: str, actual_id: str, cm: str
) -> etree._Element:
    """A ``SurfaceProfileCharacteristicMeasurement`` (:func:`profile_characteristic`): the
    zone's statistics and acceptance (Attributes), status, profile value and worst
    deviations."""
    c = profile_characteristic(z, res.established)
    ma = Attrs().b("fixtured", z.fixtured).s("measured_condition", measured_condition(z, res))
    ma.d("profile_value_mm", profile_value(z))
    stats_attrs(ma, z.stats)
    acceptance_attrs(ma, z.acceptance, res.V)
    coverage_attrs(ma, z.coverage)
    detectable_attrs(ma, z.detectable)
    if res.repeatability is not None:
        sp = next((x for x in res.repeatability.surfaces[1:] if x.key == z.zone.key), None)
        if sp is not None:
            ma.i("repeatability_regions", sp.n_regions)
            ma.i("repeatability_persistent_regions", sp.n_persistent)
    ma.s("reading", c.reading)
    ma.b("judged", z.judged)
    meas = [
        ma.element(),
        E.Status(E.CharacteristicStatusEnum(_status(z, c))),
        E.CharacteristicItemId(ci),
        id_array("FeatureMeasurementIds", [fm]),
        E.ActualComponentId(actual_id),
    ]
    if c.reason:
        meas.append(E.NonConformanceDesignator(token(c.reason)))
    if c.value is not None:
        meas.append(E.Value(dec(c.value)))
        meas.append(E.WorstPositiveDeviation(dec(c.worst_positive)))
        meas.append(E.WorstNegativeDeviation(dec(c.worst_negative)))
    return E.SurfaceProfileCharacteristicMeasurement(*[x for x in meas if x is not None], id=cm)


def _results(
    res: InspectionResult,
    prov: Provenance,
    sw_id: str,
    zs: Sections,
    asm_path: str,
    actual_id: str,
    ids: Ids,
) -> etree._Element:
    """``Results``: one ``MeasurementResults`` (attributes, traceability, the input files,
    the measured features and characteristics, the status) and the actual component."""
    # NOT ESTABLISHED (would pass, registration not trusted): QIF's UNKNOWN; the reasons are
    # the decided_by_* and warning_* attributes
    verdict = {"PASS": "PASS", "FAIL": "FAIL", "NOT MEASURED": "NOT_MEASURED"}.get(
        res.verdict, "UNKNOWN"
    )
    ra = measurement_results_attrs(res, prov.nominal_sha256, prov.scan_sha256)
    trace = prov.trace or {}
    if trace.get("temperature_C") is not None:
        ra.d("part_temperature_C", float(trace["temperature_C"]))
    for key in ("part_number", "revision"):
        if trace.get(key):
            ra.s(key, str(trace[key]))
    refs = _input_file_references(prov)
    mr = E.MeasurementResults(
        ra.element(),
        _traceability(prov, sw_id),
        E.ThisResultsInstanceQPId(qpid()),
        E.ExternalFileReferences(*refs, n=str(len(refs))),
        E.MeasuredFeatures(*zs.fmeas, n=str(len(zs.fmeas))),
        E.MeasuredCharacteristics(E.CharacteristicMeasurements(*zs.cmeas, n=str(len(zs.cmeas)))),
        E.InspectionStatus(E.InspectionStatusEnum(verdict)),
        id_array("ActualComponentIds", [actual_id]),
        id=ids(),
    )
    actual = [E.SerialNumber(prov.serial_number)] if prov.serial_number else []
    return E.Results(
        E.MeasurementResultsSet(mr, n="1"),
        E.ActualComponentSets(
            E.ActualComponentSet(
                E.ActualComponent(
                    *actual,
                    E.Status(E.InspectionStatusEnum(verdict)),
                    E.AsmPathId(asm_path),
                    id=actual_id,
                ),
                n="1",
            ),
            n="1",
        ),
    )


def _traceability(prov: Provenance, sw_id: str) -> etree._Element:
    """``InspectionTraceability``: organization, times, software, operator, report date."""
    trace = [
        E.InspectionStart(xml_time(prov.started)),
        E.InspectionEnd(xml_time(prov.finished)),
        E.InspectionSoftwareItems(id_array("AnalysisSoftware", [sw_id])),
    ]
    if prov.organization:
        trace.insert(0, E.InspectingOrganization(E.Name(token(prov.organization))))
    if prov.operator:
        trace.append(E.InspectionOperator(E.Name(token(prov.operator))))
    trace += [E.ReportPreparationDate(xml_time(prov.finished))]
    return E.InspectionTraceability(*trace)


def _input_file_references(prov: Provenance) -> list[etree._Element]:
    """One ``ExternalFileReference`` per input file (nominal, scan) with its SHA-256."""
    return [
        E.ExternalFileReference(
            E.URI(_uri(prov.nominal_path)),
            E.FileSpec(E.OtherFileSpec(_file_spec(prov.nominal_path))),
            E.Description(f"nominal; SHA-256 {prov.nominal_sha256}"),
        ),
        E.ExternalFileReference(
            E.URI(_uri(prov.scan_path)),
            E.FileSpec(E.OtherFileSpec(_file_spec(prov.scan_path))),
            E.Description(f"scan; SHA-256 {prov.scan_sha256}"),
        ),
    ]


# ---------------------------------------------------------------------------------------------
# writing


#: the XML declaration, double-quoted (lxml's own is single-quoted; strict QIF readers want
#: double quotes throughout: ../shared/README.md)
XML_DECLARATION = b'<?xml version="1.0" encoding="UTF-8" standalone="no"?>\n'


def write_qif(path: Path, tree: etree._ElementTree) -> None:
    """Write the document: UTF-8, a double-quoted XML declaration, no BOM, default
    namespace, indented."""
    etree.indent(tree, space="  ")
    body = etree.tostring(tree, encoding="UTF-8", xml_declaration=False)
    with open(path, "wb") as fh:
        fh.write(XML_DECLARATION)
        fh.write(body)


# ---------------------------------------------------------------------------------------------
# helpers


def _params_dict(params) -> dict | None:
    """A method's parameter dataclass as a dict (None when it is not one)."""
    if is_dataclass(params) and not isinstance(params, type):
        return asdict(params)
    return dict(params) if isinstance(params, dict) else None


def _uri(path: str) -> str:
    p = Path(path)
    try:
        return p.resolve().as_uri()
    except ValueError:
        return str(p)


def _file_spec(path: str) -> str:
    suffix = Path(path).suffix.lower().lstrip(".")
    return {"stp": "STEP", "step": "STEP", "p21": "STEP"}.get(suffix, suffix.upper() or "DATA")
