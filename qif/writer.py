"""QIF 3.0 results document of one inspection.

One ``QIFDocument`` (``versionQIF="3.0.0"``, default namespace ``http://qifstandards.org/xsd/qif3``)
per inspection, written with lxml. What goes where:

=========================================  ==================================================
``Header``, ``SoftwareDefinitions``         qifreport and its version, author/organization
``AlgorithmDefinitions``                    rigid alignment and the virtual fixture (GB-CICP
                                            or the ``--method`` baseline), with their
                                            parameters (JSON)
``FileUnits``                               mm, degree, mm^2
``DatumDefinitions``, ``DatumReferenceFrames``  the datums of the PMI, one frame per datum
                                            sequence a profile tolerance cites
``Product``                                 the part (name, UUID), its component and assembly
                                            path; the toleranced surfaces are referenced from it
``Features``                                one ``OtherSurfaceFeature`` per toleranced surface
                                            (its B-rep faces as STEP entity ids, an Attribute)
``Characteristics``                         one ``SurfaceProfileCharacteristic`` per profile
                                            tolerance of the PMI, plus the general tolerance
                                            (the command line's, or the default) on the faces
                                            no profile covers
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
every scored point of the surface, ``2 max |d - c|``. ``WorstPositiveDeviation`` and
``WorstNegativeDeviation`` are the signed extremes of the deviation ``d``. The **status** is
qifreport's decision for a compliant part (paper Section 10): the area criterion (at least
``min_fraction`` of the scored area in the band) and the region criterion (no connected
out-of-tolerance region larger than ``max_region_area``); the rule is stated in the
characteristic definition's ``Description``. A part can therefore PASS with a profile value
above the tolerance (a few isolated points out of the band): the statistics say how much.

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
"""

from __future__ import annotations

import json
import math
import uuid
from dataclasses import asdict, dataclass, field, is_dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from lxml import etree
from lxml.builder import ElementMaker

from qifreport import __version__
from qifreport.metrology.added import AddedMaterial
from qifreport.metrology.bands import ToleranceZone
from qifreport.metrology.inspection import InspectionResult, ZoneResult, method_label
from qifreport.metrology.repeatability import Repeatability
from qifreport.metrology.statistics import DeviationStats

NS = "http://qifstandards.org/xsd/qif3"
XSI = "http://www.w3.org/2001/XMLSchema-instance"
#: ``xsi:schemaLocation`` written in every document: the official root schema, relative to a
#: copy of the QIF XSD folder beside the file (readers that validate map it to their copy).
SCHEMA_LOCATION = f"{NS} ../QIFApplications/QIFDocument.xsd"
#: places after the decimal point of every ``xs:decimal`` length (mm): 0.1 um.
DECIMAL_PLACES = 4
#: at most this many out-of-tolerance regions are listed per surface (largest first); the
#: count of all regions is always given (``region_count``).
MAX_REGIONS_LISTED = 50

E = ElementMaker(namespace=NS, nsmap={None: NS, "xsi": XSI})

#: ``Description`` of the virtual-fixture algorithm, per method (``--method``)
METHOD_DESCRIPTIONS = {
    "gbcicp": "GB-CICP: deformation of the nominal onto the free-state scan under a "
              "bending-energy prior (paper Sections 4-5)",
    "nicp": "NICP: optimal-step non-rigid ICP, deformation of the nominal onto the free-state "
            "scan under a per-vertex affine stiffness prior (paper baseline, Section 6.3)",
    "cpd": "CPD: coherent point drift, a Gaussian-mixture deformation of the nominal onto the "
           "free-state scan with motion coherence (paper baseline, Section 6.2)",
    "rbffem": "RBF-FEM: deformation of the nominal driven by its clamps with multiquadric "
              "radial basis functions (paper baseline, Section 6.1)",
}


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
    nominal_info : description of the nominal (format, tessellation, PMI counts).
    author, organization, operator, serial_number : options of the command line.
    standard : (organization, designator, year) of the tolerancing standard.
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
    author: str | None = None
    organization: str | None = None
    operator: str | None = None
    serial_number: str | None = None
    standard: tuple[str, str, str] = ("ASME", "Y14.5", "2018")


class _Ids:
    """Sequential QIF ids (1, 2, ...); ``max`` is the document's ``idMax``."""

    def __init__(self) -> None:
        self.max = 0

    def __call__(self) -> str:
        self.max += 1
        return str(self.max)


def _qpid() -> str:
    return str(uuid.uuid4())


def dec(x: float, places: int = DECIMAL_PLACES) -> str:
    """An ``xs:decimal`` literal (fixed point, no exponent, no ``-0``)."""
    s = f"{float(x):.{places}f}"
    if float(s) == 0.0:
        s = s.lstrip("-")
    return s


def _dbl(x: float) -> str:
    """An ``xs:double`` literal that round-trips exactly (``INF``/``NaN`` as XSD spells them)."""
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "INF" if x > 0 else "-INF"
    return repr(x)


def _time(t: datetime) -> str:
    return t.astimezone(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def _array(tag: str, ids: list[str]) -> etree._Element:
    return E(tag, *[E.Id(i) for i in ids], n=str(len(ids)))


class _Attrs:
    """Builder of a QIF ``Attributes`` element (typed name/value pairs)."""

    def __init__(self) -> None:
        self.items: list[etree._Element] = []

    def d(self, name: str, value: float | None) -> _Attrs:
        if value is not None and math.isfinite(float(value)):
            self.items.append(E.AttributeD1(name=name, value=_dbl(value)))
        return self

    def i(self, name: str, value: int) -> _Attrs:
        self.items.append(E.AttributeI1(name=name, value=str(int(value))))
        return self

    def b(self, name: str, value: bool) -> _Attrs:
        self.items.append(E.AttributeBool(name=name, value="true" if value else "false"))
        return self

    def s(self, name: str, value: str) -> _Attrs:
        self.items.append(E.AttributeStr(name=name, value=str(value)))
        return self

    def d3(self, name: str, xyz) -> _Attrs:
        xyz = np.asarray(xyz, dtype=float).ravel()
        if xyz.shape == (3,) and np.all(np.isfinite(xyz)):
            self.items.append(E.AttributeD3(name=name, value=" ".join(_dbl(v) for v in xyz)))
        return self

    def stats(self, s: DeviationStats, prefix: str = "") -> _Attrs:
        self.i(f"{prefix}n_samples", s.n)
        for key in ("rms", "mean", "max_abs", "max_pos", "min_neg", "p95", "p99", "p999"):
            self.d(f"{prefix}{key}_mm", getattr(s, key))
        if s.threshold is not None:
            self.d(f"{prefix}threshold_mm", s.threshold)
            for key in ("frac_above", "frac_below", "frac_beyond"):
                self.d(f"{prefix}{key}", getattr(s, key))
        self.b(f"{prefix}area_weighted", s.weighted)
        return self

    def element(self) -> etree._Element | None:
        if not self.items:
            return None
        return E.Attributes(*self.items, n=str(len(self.items)))


def _acceptance_attrs(a: _Attrs, acc, V: np.ndarray, prefix: str = "") -> None:
    a.d(f"{prefix}in_tolerance_area_fraction", acc.in_tolerance_fraction)
    a.d(f"{prefix}min_in_tolerance_fraction", acc.min_fraction)
    a.b(f"{prefix}area_criterion_ok", acc.area_ok)
    a.d(f"{prefix}scored_area_mm2", acc.scored_area)
    a.d(f"{prefix}nominal_area_mm2", acc.nominal_area)
    a.d(f"{prefix}coverage", acc.coverage)
    a.i(f"{prefix}region_count", len(acc.regions))
    a.d(f"{prefix}largest_region_area_mm2", acc.largest_region_area)
    a.d(f"{prefix}max_region_area_mm2", acc.max_region_area)
    a.b(f"{prefix}region_criterion_ok", acc.region_ok)
    for k, r in enumerate(acc.regions[:MAX_REGIONS_LISTED], start=1):
        a.d(f"{prefix}region_{k}_area_mm2", r.area)
        a.d(f"{prefix}region_{k}_peak_mm", r.peak)
        a.i(f"{prefix}region_{k}_sign", r.sign)
        a.d3(f"{prefix}region_{k}_centroid_mm", r.centroid)
        a.d3(f"{prefix}region_{k}_peak_location_mm", V[r.peak_vertex])
    for k, reason in enumerate(acc.reasons, start=1):
        a.s(f"{prefix}reason_{k}", reason)


def profile_value(z: ZoneResult) -> float:
    """QIF profile value of a surface: ``2 max |d - c|`` over its scored points (mm), NaN if
    nothing was scored."""
    s, c = z.stats, z.zone.center
    if s.n == 0 or not math.isfinite(s.max_pos):
        return math.nan
    return 2.0 * max(s.max_pos - c, c - s.min_neg)


def acceptance_rule(min_fraction: float, max_region_area: float) -> str:
    """The conformance rule stated in every characteristic definition."""
    return (f"qifreport virtual-fixture acceptance: at least {100 * min_fraction:g} % of the "
            f"scored area within the zone (area criterion) and no connected out-of-tolerance "
            f"region larger than {max_region_area:g} mm^2 (region criterion)")


def build_qif(res: InspectionResult, prov: Provenance) -> etree._ElementTree:
    """The QIF 3.0 results document of one inspection (an lxml tree, not yet written)."""
    ids = _Ids()
    params = res.params
    zones = res.zones

    # -- definitions that others reference: standard, software, algorithms, units
    std_id, sw_id = ids(), ids()
    std_org, std_des, std_year = prov.standard
    standards = E.StandardsDefinitions(
        E.Standard(E.Organization(E.StandardsOrganizationEnum(std_org)), E.Designator(std_des),
                   E.Year(std_year), id=std_id), n="1")
    software = E.SoftwareDefinitions(
        E.Software(E.VendorName("qifreport"), E.ApplicationName("qifreport"),
                   E.Version(__version__),
                   E.Description("Dimensional inspection of flexible parts by virtual "
                                 "fixturing"), id=sw_id), n="1")
    rigid_alg_id, fit_alg_id = ids(), ids()
    rigid = res.rigid
    method = res.fit.method if res.fit is not None else params.method
    fit_params = _params_dict(res.fit.params) if res.fit is not None else None
    algorithms = E.AlgorithmDefinitions(
        E.Algorithm(E.SoftwareId(sw_id),
                    E.Parameters(json.dumps({"method": "robust point-to-plane ICP",
                                             "iterations": int(rigid.iterations)})),
                    E.Name("rigid alignment"),
                    E.Description("robust scan-to-model ICP (paper Section 3)"), id=rigid_alg_id),
        E.Algorithm(E.SoftwareId(sw_id),
                    E.Parameters(json.dumps({"method": method, "energy": res.energy,
                                             "rigid_only": params.rigid_only,
                                             method: fit_params}, default=_json_default)),
                    E.Name("virtual fixture" if not params.rigid_only else "none (rigid only)"),
                    E.Description(METHOD_DESCRIPTIONS.get(method, method)),
                    id=fit_alg_id),
        n="2")
    units = E.FileUnits(E.PrimaryUnits(
        E.AreaUnit(E.SIUnitName("square meter"), E.UnitName("mm^2"),
                   E.UnitConversion(E.Factor("0.000001"))),
        E.AngularUnit(E.SIUnitName("radian"), E.UnitName("degree"),
                      E.UnitConversion(E.Factor("0.0174532925199433"))),
        E.LinearUnit(E.SIUnitName("meter"), E.UnitName("mm"),
                     E.UnitConversion(E.Factor("0.001"))),
    ))

    # -- datums and datum reference frames
    labels = list(dict.fromkeys(list(prov.datums) + [d for z in zones for d in z.zone.datums]))
    datum_ids = {lab: ids() for lab in labels}
    drf_ids: dict[tuple[str, ...], str] = {}
    for z in zones:
        if z.zone.datums:
            drf_ids.setdefault(tuple(z.zone.datums), "")
    for key in drf_ids:
        drf_ids[key] = ids()
    datum_defs = None
    if labels:
        datum_defs = E.DatumDefinitions(
            *[E.DatumDefinition(E.DatumLabel(lab), id=datum_ids[lab]) for lab in labels],
            n=str(len(labels)))
    drfs = None
    if drf_ids:
        prec = ("PRIMARY", "SECONDARY", "TERTIARY")
        frames = []
        for seq, fid in drf_ids.items():
            datums = []
            for k, lab in enumerate(seq):
                p = (E.Precedence(E.PrecedenceEnum(prec[k])) if k < 3
                     else E.Precedence(E.OtherPrecedence(str(k + 1))))
                datums.append(E.Datum(
                    E.SimpleDatum(E.DatumDefinitionId(datum_ids[lab]),
                                  E.MaterialModifier("NONE"), E.ReferencedComponent("ACTUAL")),
                    p))
            frames.append(E.DatumReferenceFrame(E.Datums(*datums, n=str(len(datums))),
                                                E.Name("|" + "|".join(seq) + "|"), id=fid))
        drfs = E.DatumReferenceFrames(*frames, n=str(len(frames)))

    # -- one surface feature and one characteristic per zone
    rule = acceptance_rule(params.min_fraction, params.max_region_area)
    part_id, comp_id, path_id, actual_id = ids(), ids(), ids(), ids()
    fdefs, fnoms, fitems, cdefs, cnoms, citems, fmeas, cmeas = ([] for _ in range(8))
    fnom_ids, cnom_ids = [], []
    for z in zones:
        zone = z.zone
        fd, fn, fi, fm = ids(), ids(), ids(), ids()
        cd, cn, ci, cm = ids(), ids(), ids(), ids()
        fnom_ids.append(fn)
        cnom_ids.append(cn)
        fname = _feature_name(zone)
        fdefs.append(E.OtherSurfaceFeatureDefinition(id=fd))
        fa = _Attrs()
        if zone.faces is None:
            fa.s("faces", "every face no other profile tolerance covers")
        else:
            fa.s("b_rep_faces", " ".join(str(int(f)) for f in zone.faces))
        nom = [fa.element(), E.Name(fname), E.UUID(_qpid()), E.FeatureDefinitionId(fd)]
        fnoms.append(E.OtherSurfaceFeatureNominal(*[x for x in nom if x is not None], id=fn))
        fitems.append(E.OtherSurfaceFeatureItem(
            E.FeatureNominalId(fn), E.FeatureName(fname), E.UUID(_qpid()),
            E.DeterminationMode(E.Checked(E.CheckDetails(E.Measured()))), id=fi))
        fmeas.append(E.OtherSurfaceFeatureMeasurement(
            E.FeatureItemId(fi), E.FeatureName(fname), E.ActualComponentId(actual_id), id=fm))

        da = _Attrs().s("key", zone.key).s("source", zone.source)
        da.d("lower_mm", zone.lower).d("upper_mm", zone.upper)
        if zone.step_id is not None:
            da.i("step_entity_id", zone.step_id)
        if zone.modifiers:
            da.s("modifiers", " ".join(zone.modifiers))
        cdef = [da.element(), E.Description(f"{zone.describe()}. {rule}."),
                E.Name(_token(zone.name))]
        if zone.free_state:
            cdef.append(E.FreeState("true"))
        cdef.append(E.ToleranceValue(dec(zone.width)))
        if not math.isclose(zone.center, 0.0, abs_tol=1e-12):
            # ASME UZ: the part of the zone outside the material (toward +normal) = upper
            cdef.append(E.UnequallyDisposedZone(dec(zone.upper)))
        if zone.datums:
            cdef.append(E.DatumReferenceFrameId(drf_ids[tuple(zone.datums)]))
        cdefs.append(E.SurfaceProfileCharacteristicDefinition(*[x for x in cdef if x is not None],
                                                              id=cd))
        cnoms.append(E.SurfaceProfileCharacteristicNominal(
            E.CharacteristicDefinitionId(cd), _array("FeatureNominalIds", [fn]),
            E.Name(_token(zone.name)), id=cn))
        citems.append(E.SurfaceProfileCharacteristicItem(
            E.Name(_token(zone.name)),
            E.CharacteristicDesignator(E.Designator(zone.key), E.UUID(_qpid())),
            _array("FeatureItemIds", [fi]), E.CharacteristicNominalId(cn), id=ci))

        ma = _Attrs().b("fixtured", z.fixtured).d("profile_value_mm", profile_value(z))
        ma.stats(z.stats)
        _acceptance_attrs(ma, z.acceptance, res.V)
        if res.repeatability is not None:
            sp = next((x for x in res.repeatability.surfaces[1:] if x.key == zone.key), None)
            if sp is not None:
                ma.i("repeatability_regions", sp.n_regions)
                ma.i("repeatability_persistent_regions", sp.n_persistent)
        status = _status(z, established=res.established)
        meas = [ma.element(), E.Status(E.CharacteristicStatusEnum(status)),
                E.CharacteristicItemId(ci), _array("FeatureMeasurementIds", [fm]),
                E.ActualComponentId(actual_id)]
        if not z.acceptance.passed:
            meas.append(E.NonConformanceDesignator(_token("; ".join(z.acceptance.reasons)
                                                          or "not conforming")))
        pv = profile_value(z)
        if math.isfinite(pv):
            meas.append(E.Value(dec(pv)))
            meas.append(E.WorstPositiveDeviation(dec(z.stats.max_pos)))
            meas.append(E.WorstNegativeDeviation(dec(z.stats.min_neg)))
        cmeas.append(E.SurfaceProfileCharacteristicMeasurement(
            *[x for x in meas if x is not None], id=cm))

    # -- product
    part = E.Part(
        E.Header(E.Name(prov.part_name)),
        E.UUID(_qpid()),
        _array("FeatureNominalIds", fnom_ids),
        _array("CharacteristicNominalIds", cnom_ids),
        *([_array("DatumDefinitionIds", list(datum_ids.values()))] if datum_ids else []),
        *([_array("DatumReferenceFrameIds", list(drf_ids.values()))] if drf_ids else []),
        id=part_id)
    product = E.Product(
        E.PartSet(part, n="1"),
        E.ComponentSet(E.Component(E.UUID(_qpid()), E.Part(E.Id(part_id)), id=comp_id), n="1"),
        E.RootPart(E.Id(part_id)),
        E.AsmPaths(E.AsmPath(_array("ComponentIds", [comp_id]), id=path_id), n="1"),
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

    # -- results
    # NOT ESTABLISHED (would pass, registration not trusted): QIF's UNKNOWN; the reasons are
    # the decided_by_* and warning_* attributes
    verdict = {"PASS": "PASS", "FAIL": "FAIL"}.get(res.verdict, "UNKNOWN")
    ra = _Attrs().s("verdict", res.verdict)
    for k, line in enumerate(res.trust_warnings(), start=1):
        ra.s(f"warning_{k}", line)
    for k, line in enumerate(res.decided_by(), start=1):
        ra.s(f"decided_by_{k}", line)
    ra.stats(res.vertex_stats)
    _acceptance_attrs(ra, res.acceptance, res.V)
    ra.stats(res.point_stats, prefix="scan_points_")
    if res.added is not None:
        _added_attrs(ra, res.added)
    h = res.hygiene
    if h is not None:
        ra.i("nominal_boundary_edges", h.boundary_edges)
        ra.i("nominal_non_manifold_edges", h.non_manifold_edges)
        ra.i("nominal_degenerate_faces", h.degenerate_faces)
        ra.i("nominal_duplicate_faces", h.duplicate_faces).i("nominal_components", h.components)
        ra.d("boundary_band_mm", h.boundary_band)
        ra.d("boundary_excluded_area_mm2", h.boundary_excluded_area)
    ra.d("scan_area_mm2", res.scan_area).b("coverage_ceiling_ok", res.coverage_ceiling_ok)
    ra.d("edge_excluded_area_mm2", res.edge_excluded_area).s("bending_energy", res.energy)
    a = res.prealign
    if a is not None:
        ra.s("pose_method", a.method)
        if a.method != "identity":
            ra.d("pose_inlier_fraction", a.inlier_fraction).d("pose_gate_mm", a.gate)
            ra.i("pose_restart_agreement", a.restart_agreement).i("pose_starts", a.n_starts)
            ra.i("pose_descriptor_matches", a.matches).i("pose_ransac_inliers", a.ransac_inliers)
            ra.b("pose_ambiguous", a.ambiguous).d("pose_conditioning", a.conditioning)
    ra.d("rigid_rms_mm", rigid.rms).d("rigid_inlier_fraction", rigid.inlier_fraction)
    ra.i("rigid_iterations", rigid.iterations)
    ra.s("rigid_rotation", " ".join(_dbl(v) for v in np.asarray(rigid.R).ravel()))
    ra.d3("rigid_translation_mm", rigid.t)
    if res.fit is not None:
        fit = res.fit
        ra.s("fit_method", fit.method).s("fit_method_name", method_label(fit.method))
        ra.i("fit_iterations", fit.iterations).i("fit_passes", fit.passes)
        ra.b("fit_fallback", fit.fallback).d("fit_flagged_fraction", fit.flagged_fraction)
        ra.d("fit_residual_scale_mm", fit.scale)
        ra.d("fit_max_displacement_mm", float(np.linalg.norm(fit.e, axis=1).max()))
    if res.repeatability is not None:
        _repeatability_attrs(ra, res.repeatability)
    for k, ne in enumerate(res.not_evaluated, start=1):
        ref = f" #{ne.step_id}" if ne.step_id is not None else ""
        ra.s(f"not_evaluated_{k}", f"{ne.kind} {ne.name}{ref}: {ne.reason}")
    ra.i("nominal_vertices", len(res.V)).i("nominal_triangles", len(res.F))
    ra.i("scan_points", len(res.P))
    for stage, sec in res.timings.items():
        ra.d(f"time_{stage}_s", sec)
    ra.s("nominal_sha256", prov.nominal_sha256).s("scan_sha256", prov.scan_sha256)

    trace = [E.InspectionStart(_time(prov.started)), E.InspectionEnd(_time(prov.finished)),
             E.InspectionSoftwareItems(_array("AnalysisSoftware", [sw_id]))]
    if prov.organization:
        trace.insert(0, E.InspectingOrganization(E.Name(_token(prov.organization))))
    if prov.operator:
        trace.append(E.InspectionOperator(E.Name(_token(prov.operator))))
    trace += [E.ReportPreparationDate(_time(prov.finished))]
    refs = [
        E.ExternalFileReference(E.URI(_uri(prov.nominal_path)),
                                E.FileSpec(E.OtherFileSpec(_file_spec(prov.nominal_path))),
                                E.Description(f"nominal; SHA-256 {prov.nominal_sha256}")),
        E.ExternalFileReference(E.URI(_uri(prov.scan_path)),
                                E.FileSpec(E.OtherFileSpec(_file_spec(prov.scan_path))),
                                E.Description(f"scan; SHA-256 {prov.scan_sha256}")),
    ]
    mr = E.MeasurementResults(
        ra.element(),
        E.InspectionTraceability(*trace),
        E.ThisResultsInstanceQPId(_qpid()),
        E.ExternalFileReferences(*refs, n=str(len(refs))),
        E.MeasuredFeatures(*fmeas, n=str(len(fmeas))),
        E.MeasuredCharacteristics(E.CharacteristicMeasurements(*cmeas, n=str(len(cmeas)))),
        E.InspectionStatus(E.InspectionStatusEnum(verdict)),
        _array("ActualComponentIds", [actual_id]),
        id=ids(),
    )
    actual = [E.SerialNumber(prov.serial_number)] if prov.serial_number else []
    results = E.Results(
        E.MeasurementResultsSet(mr, n="1"),
        E.ActualComponentSets(E.ActualComponentSet(E.ActualComponent(
            *actual, E.Status(E.InspectionStatusEnum(verdict)), E.AsmPathId(path_id),
            id=actual_id), n="1"), n="1"),
    )

    header = [E.Application(E.Name("qifreport"), E.Organization("qifreport project"))]
    if prov.author or prov.organization:
        header.append(E.Author(*([E.Name(prov.author)] if prov.author else []),
                               *([E.Organization(prov.organization)] if prov.organization
                                 else [])))
    header.append(E.Description(f"Virtual-fixturing inspection of {prov.part_name}: "
                                f"{Path(prov.scan_path).name} against "
                                f"{Path(prov.nominal_path).name}"))
    children = [
        E.QPId(_qpid()),
        E.Version(E.TimeCreated(_time(prov.finished))),
        E.Header(*header),
        standards, software, algorithms, units,
        datum_defs, drfs, product, features, characteristics, results,
    ]
    root = E.QIFDocument(*[c for c in children if c is not None], versionQIF="3.0.0",
                         idMax=str(ids.max))
    root.set(f"{{{XSI}}}schemaLocation", SCHEMA_LOCATION)
    return etree.ElementTree(root)


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


def _status(z: ZoneResult, established: bool = True) -> str:
    if z.acceptance.scored_area <= 0 or z.stats.n == 0:
        return "NOT_ANALYZED"
    if not z.acceptance.passed:
        return "FAIL"
    return "PASS" if established else "INDETERMINATE"


def _added_attrs(ra: _Attrs, a: AddedMaterial) -> None:
    """The data-referenced pass (added material) as ``added_*`` attributes."""
    ra.d("added_threshold_mm", a.threshold).d("added_mean_signed_mm", a.mean_signed)
    ra.d("added_p99_signed_mm", a.p99_signed).d("added_p999_signed_mm", a.p999_signed)
    ra.d("added_max_signed_mm", a.max_signed).d("added_min_signed_mm", a.min_signed)
    ra.d("added_frac_above", a.frac_above).d("added_frac_below", a.frac_below)
    ra.i("added_region_count", len(a.regions)).d("added_largest_region_mm2", a.largest_area)
    ra.b("added_fail_on", a.fail_on).b("added_passed", a.passed)
    for k, r in enumerate(a.regions[:50], start=1):
        ra.d(f"added_region_{k}_area_mm2", r.area).d(f"added_region_{k}_peak_mm", r.peak)
        ra.d3(f"added_region_{k}_centroid_mm", r.centroid)


def _repeatability_attrs(ra: _Attrs, rep: Repeatability) -> None:
    """The resampling study (``--seeds``) as ``repeatability_*`` attributes."""
    ra.i("repeatability_seeds", rep.seeds).d("repeatability_keep_fraction", rep.keep_fraction)
    ra.s("repeatability_reported_run", "full scan")
    ra.i("repeatability_regions", rep.n_regions)
    ra.i("repeatability_persistent_regions", rep.n_persistent)
    ra.d("repeatability_rms_spread_mm", rep.rms_spread)
    ra.d("repeatability_max_spread_mm", rep.max_spread)
    for k, (rms, mx) in enumerate(zip(rep.rms, rep.max_abs, strict=True)):
        run = "full" if k == 0 else f"seed_{k - 1}"
        ra.d(f"repeatability_{run}_rms_mm", rms).d(f"repeatability_{run}_max_abs_mm", mx)
    dropped = [(s.key, d) for s in rep.surfaces for d in s.dropped]
    ra.i("repeatability_dropped_count", len(dropped))
    for k, (key, d) in enumerate(dropped[:MAX_REGIONS_LISTED], start=1):
        ra.s(f"repeatability_dropped_{k}_surface", key)
        ra.d(f"repeatability_dropped_{k}_area_mm2", d.area)
        ra.d(f"repeatability_dropped_{k}_peak_mm", d.peak)
        ra.d3(f"repeatability_dropped_{k}_centroid_mm", d.centroid)
        ra.i(f"repeatability_dropped_{k}_runs_found", d.runs_found)


def _params_dict(params) -> dict | None:
    """A method's parameter dataclass as a dict (None when it is not one)."""
    if is_dataclass(params) and not isinstance(params, type):
        return asdict(params)
    return dict(params) if isinstance(params, dict) else None


def _feature_name(zone: ToleranceZone) -> str:
    if zone.faces is None:
        return "SURFACE_GENERAL"
    return _token(f"SURFACE_{zone.key}")


def _token(s: str) -> str:
    """Collapse whitespace (``xs:token``); never empty."""
    return " ".join(str(s).split()) or "-"


def _uri(path: str) -> str:
    p = Path(path)
    try:
        return p.resolve().as_uri()
    except ValueError:
        return str(p)


def _file_spec(path: str) -> str:
    suffix = Path(path).suffix.lower().lstrip(".")
    return {"stp": "STEP", "step": "STEP", "p21": "STEP"}.get(suffix, suffix.upper() or "DATA")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)
