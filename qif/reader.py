"""Read a QIF 3.0 results document back: ours in full, anyone's in outline.

:func:`read_results` returns, for every characteristic measurement of the first
``MeasurementResults``, the product's own
:class:`~qifreport.metrology.gdt.characteristic_types.CharacteristicResult`, the type the
writer writes: its spec built from the QIF definition, nominal and item (the kind found by
the QIF type, :func:`qifreport.qif.feature_characteristics.kind_of_qif_type`; designator as
key, name, tolerance, a dimension's nominal and limits, datum labels), its status mapped
to the product's (:func:`~qifreport.qif.feature_characteristics.status_from_qif`), its
value and a profile's worst deviations; the QIF type, id, status as written, description and
attributes in its :class:`~qifreport.metrology.gdt.characteristic_types.DocumentRecord`. A
characteristic type no kind has is read too, of kind
:data:`~qifreport.metrology.gdt.characteristic_types.OTHER_KIND`.

For documents qifreport wrote, the rest is rebuilt from the typed ``Attributes``: the
reading, least-squares value, uncertainty, coverage and points of a feature characteristic,
a tolerance's step entity and modifiers, and the result objects of a toleranced surface
(:class:`qifreport.metrology.acceptance.statistics.DeviationStats`,
:class:`qifreport.metrology.acceptance.criteria.Acceptance` with its
:class:`~qifreport.metrology.acceptance.criteria.Region` list), so a round trip can be checked
number by number (see :mod:`qifreport.qif.writer` for the layout). Regions come back without
their vertex lists (``vertices`` empty, ``peak_vertex`` -1): QIF carries the area, peak, sign,
centroid and peak location. A feature's faces are not read (``faces`` empty).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from decimal import Decimal
from pathlib import Path

import numpy as np
from lxml import etree

from qifreport.metrology.acceptance.criteria import Acceptance, Region
from qifreport.metrology.acceptance.statistics import DeviationStats
from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    DocumentRecord,
)

from .composite import segment_attributes, segment_elements
from .feature_characteristics import kind_of_qif_type, status_from_qif
from .uncertainty import budget_from_attributes
from .writer import NS

__all__ = [
    "Limits",
    "QIFResults",
    "acceptance_from_attributes",
    "child_text",
    "definition_limits",
    "read_attributes",
    "read_results",
    "stats_from_attributes",
]

_Q = f"{{{NS}}}"
_STATS_KEYS = ("rms", "mean", "max_abs", "max_pos", "min_neg", "p95", "p99", "p999")


@dataclass
class QIFResults:
    """A results document in the product's terms.

    Attributes
    ----------
    path : the file.  version : ``versionQIF``.  qpid : the document's QPId.
    application : ``Header/Application/Name``.  software_version : of qifreport (or None).
    status : overall ``InspectionStatusEnum`` of the first results.
    characteristics : one per characteristic measurement, in document order.
    attributes : typed Attributes of the MeasurementResults (qifreport: whole part).
    inputs : ``(URI, description)`` of the external file references.
    inspection_start, inspection_end : ISO times, or None.
    serial_number : of the actual component, or None.
    stats, point_stats, acceptance : whole-part results rebuilt (qifreport documents).
    """

    path: Path
    version: str
    qpid: str | None
    application: str | None
    software_version: str | None
    status: str | None
    characteristics: list[CharacteristicResult]
    attributes: dict
    inputs: list[tuple[str, str]]
    inspection_start: str | None = None
    inspection_end: str | None = None
    serial_number: str | None = None
    stats: DeviationStats | None = None
    point_stats: DeviationStats | None = None
    acceptance: Acceptance | None = None

    @property
    def written_by_qifreport(self) -> bool:
        return self.application == "qifreport"

    def characteristic(self, designator: str) -> CharacteristicResult:
        """The characteristic with this designator (qifreport: the zone key)."""
        for c in self.characteristics:
            if c.spec.key == designator:
                return c
        raise KeyError(designator)


def child_text(el, path: str) -> str | None:
    """The stripped text of ``el``'s first descendant at ``path`` (``q:`` prefixes for the
    QIF namespace); None without ``el``, such an element or its text."""
    x = el.find(path.replace("q:", _Q)) if el is not None else None
    return None if x is None or x.text is None else x.text.strip()


def _num(s: str | None) -> float | None:
    """A decimal's value; None without one (or for a word: an attribute characteristic's
    value, e.g. ``CONFORMS``)."""
    if s is None:
        return None
    try:
        return float(s)
    except ValueError:
        return None


def read_attributes(parent) -> dict:
    """Typed QIF ``Attributes`` of an element as ``{name: value}`` (D1/I1/Bool/Str/D3/Time)."""
    out: dict = {}
    attrs = parent.find(f"{_Q}Attributes") if parent is not None else None
    if attrs is None:
        return out
    for a in attrs:
        tag = etree.QName(a).localname
        name, v = a.get("name"), a.get("value")
        if tag == "AttributeD1":
            out[name] = float(v)
        elif tag == "AttributeI1":
            out[name] = int(v)
        elif tag == "AttributeBool":
            out[name] = v in ("true", "1")
        elif tag in ("AttributeD2", "AttributeD3", "AttributeI2", "AttributeI3"):
            cast = float if tag.startswith("AttributeD") else int
            out[name] = np.array([cast(x) for x in v.split()])
        elif v is not None:
            out[name] = v
        else:
            out[name] = etree.tostring(a, encoding="unicode")
    return out


def stats_from_attributes(a: dict, prefix: str = "") -> DeviationStats | None:
    """Rebuild :class:`DeviationStats` from qifreport's attributes (None if absent)."""
    if f"{prefix}n_samples" not in a:
        return None
    g = {k: a.get(f"{prefix}{k}_mm", math.nan) for k in _STATS_KEYS}
    thr = a.get(f"{prefix}threshold_mm")
    fr = {k: a.get(f"{prefix}{k}", math.nan) for k in ("frac_above", "frac_below", "frac_beyond")}
    return DeviationStats(
        n=int(a[f"{prefix}n_samples"]),
        threshold=thr,
        weighted=bool(a.get(f"{prefix}area_weighted", False)),
        **g,
        **fr,
    )


def acceptance_from_attributes(
    a: dict, tolerance: float | None = None, prefix: str = ""
) -> Acceptance | None:
    """Rebuild :class:`Acceptance` (regions without vertex lists) from attributes."""
    if f"{prefix}in_tolerance_area_fraction" not in a and f"{prefix}region_count" not in a:
        return None
    regions = []
    k = 1
    while f"{prefix}region_{k}_area_mm2" in a:
        regions.append(
            Region(
                vertices=np.zeros(0, dtype=np.int64),
                area=a[f"{prefix}region_{k}_area_mm2"],
                peak=a[f"{prefix}region_{k}_peak_mm"],
                peak_vertex=-1,
                centroid=np.asarray(a.get(f"{prefix}region_{k}_centroid_mm", np.full(3, np.nan))),
                sign=int(a[f"{prefix}region_{k}_sign"]),
                peak_location=np.asarray(a[f"{prefix}region_{k}_peak_location_mm"])
                if f"{prefix}region_{k}_peak_location_mm" in a
                else None,
                sampling=a.get(f"{prefix}region_{k}_sampling", "nominal"),
            )
        )
        k += 1
    reasons = []
    k = 1
    while f"{prefix}reason_{k}" in a:
        reasons.append(a[f"{prefix}reason_{k}"])
        k += 1
    uncertain = []
    k = 1
    while f"{prefix}uncertain_reason_{k}" in a:
        uncertain.append(a[f"{prefix}uncertain_reason_{k}"])
        k += 1
    proven_in = a.get(f"{prefix}conformance_proven")
    proven_out = a.get(f"{prefix}nonconformance_proven")
    area_ok = bool(a.get(f"{prefix}area_criterion_ok", False))
    region_ok = bool(a.get(f"{prefix}region_criterion_ok", False))
    scored = a.get(f"{prefix}scored_area_mm2", math.nan)
    return Acceptance(
        tolerance=math.nan if tolerance is None else tolerance,
        min_fraction=a.get(f"{prefix}min_in_tolerance_fraction", math.nan),
        max_region_area=a.get(f"{prefix}max_region_area_mm2", math.nan),
        scored_area=scored,
        nominal_area=a.get(f"{prefix}nominal_area_mm2", math.nan),
        coverage=a.get(f"{prefix}coverage", math.nan),
        in_tolerance_fraction=a.get(f"{prefix}in_tolerance_area_fraction", math.nan),
        area_ok=area_ok,
        regions=regions,
        largest_region_area=a.get(f"{prefix}largest_region_area_mm2", 0.0),
        region_ok=region_ok,
        passed=bool(area_ok and region_ok and scored > 0),
        reasons=reasons,
        decision_rule=a.get(f"{prefix}decision_rule", "simple"),
        proven_in=None if proven_in is None else bool(proven_in),
        proven_out=None if proven_out is None else bool(proven_out),
        uncertainty_mm=(
            a.get(f"{prefix}expanded_uncertainty_median_mm", math.nan),
            a.get(f"{prefix}expanded_uncertainty_max_mm", math.nan),
        ),
        uncertain_reasons=uncertain,
    )


def _datum_labels(root: etree._Element, by_id: dict) -> dict[str, list[str]]:
    """The datum labels of each datum reference frame of the document ``root``, by its id
    (``by_id``: the document's elements by id)."""
    drf_labels: dict[str, list[str]] = {}
    for drf in root.iterfind(f"{_Q}DatumReferenceFrames/{_Q}DatumReferenceFrame"):
        labels = []
        for d in drf.iterfind(f"{_Q}Datums/{_Q}Datum"):
            did = child_text(d, "q:SimpleDatum/q:DatumDefinitionId")
            lab = child_text(by_id.get(did), "q:DatumLabel") if did else None
            if lab:
                labels.append(lab)
        drf_labels[drf.get("id")] = labels
    return drf_labels


@dataclass(frozen=True)
class Limits:
    """What a characteristic's value is judged against: ``lower`` (None for a geometric
    tolerance, whose value is at least 0) and ``upper`` limits, a dimension's ``nominal``."""

    lower: float | None
    upper: float | None
    nominal: float | None = None


def _float(text: str | None) -> float | None:
    """A finite decimal's value; None without one."""
    if text is None:
        return None
    try:
        x = float(text)
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def definition_limits(
    definition: etree._Element, nominal: etree._Element, toleranced: bool
) -> Limits | str:
    """The limits a characteristic's ``definition`` (and ``nominal``: its target value)
    states, or why it has none: a geometric tolerance's (``toleranced``) its tolerance value
    (or per-unit value) as the upper limit, a dimension's its limits about its nominal."""
    if toleranced:
        tol = _float(child_text(definition, "q:ToleranceValue"))
        for per_unit in ("q:ToleranceZonePerUnitArea", "q:ToleranceZonePerUnitLength"):
            if tol is None:
                tol = _float(child_text(definition, f"{per_unit}/q:ToleranceValuePerUnit"))
        if tol is None:
            return "no numeric tolerance value"
        return Limits(None, tol)
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
        return Limits(_float(lo), _float(hi), _float(target))
    if _float(target) is None:
        return "limits relative to a nominal it does not state"

    def limit(offset: str | None) -> float | None:
        # nominal + offset as decimals, then the nearest double (10 + 0.1 is 10.1 exactly)
        return None if _float(offset) is None else float(Decimal(target) + Decimal(offset))

    return Limits(limit(lo), limit(hi), _float(target))


@dataclass
class _Elements:
    """A characteristic measurement's item, nominal and definition elements (None: not in
    the document) and the definition's attributes when the document is ours."""

    item: etree._Element | None
    nominal: etree._Element | None
    definition: etree._Element | None
    definition_attrs: dict

    @classmethod
    def of(cls, m: etree._Element, by_id: dict, ours: bool) -> _Elements:
        item = by_id.get(child_text(m, "q:CharacteristicItemId"))
        nominal = by_id.get(child_text(item, "q:CharacteristicNominalId"))
        definition = by_id.get(child_text(nominal, "q:CharacteristicDefinitionId"))
        return cls(item, nominal, definition, read_attributes(definition) if ours else {})


def _tolerance(d: etree._Element | None) -> tuple[float | None, str | None]:
    """A definition's tolerance value (mm) and, for a per-unit tolerance, its unit basis as
    the PMI states one (``"per unit length 25 mm"``, ``"per rectangular area 6 mm x 6 mm"``,
    ``"per circular area 10 mm"``)."""
    tol = _num(child_text(d, "q:ToleranceValue"))
    if tol is not None or d is None:
        return tol, None
    length = d.find(f"{_Q}ToleranceZonePerUnitLength")
    if length is not None:
        unit = _float(child_text(length, "q:UnitLength"))
        basis = None if unit is None else f"per unit length {unit:g} mm"
        return _num(child_text(length, "q:ToleranceValuePerUnit")), basis
    area = d.find(f"{_Q}ToleranceZonePerUnitArea")
    if area is None:
        return None, None
    a = _float(child_text(area, "q:RectangularUnitArea/q:RectangularUnitAreaLength"))
    b = _float(child_text(area, "q:RectangularUnitArea/q:RectangularUnitAreaWidth"))
    c = _float(child_text(area, "q:CircularUnitArea/q:CircularUnitAreaDiameter"))
    basis = None
    if a is not None and b is not None:
        basis = f"per rectangular area {a:g} mm x {b:g} mm"
    elif c is not None:
        basis = f"per circular area {c:g} mm"
    return _num(child_text(area, "q:ToleranceValuePerUnit")), basis


def _spec(qif_type: str, e: _Elements, drf_labels: dict[str, list[str]]) -> CharacteristicSpec:
    """The spec of a characteristic of QIF type ``qif_type`` from its elements ``e``."""
    kind, dim_type, unit = kind_of_qif_type(qif_type)
    d, da = e.definition, e.definition_attrs
    limits = None
    if kind == "dimension" and d is not None:
        limits = definition_limits(d, e.nominal, toleranced=False)
    limits = limits if isinstance(limits, Limits) else Limits(None, None)
    step_id = da.get("step_entity_id")
    tolerance, unit_basis = _tolerance(d)
    return CharacteristicSpec(
        key=child_text(e.item, "q:CharacteristicDesignator/q:Designator") or "",
        kind=kind,
        name=child_text(e.item, "q:Name") or child_text(d, "q:Name") or "",
        step_id=step_id if isinstance(step_id, int) else None,
        faces=np.zeros(0, dtype=np.int64),
        tolerance=tolerance,
        dim_type=dim_type,
        nominal=_float(child_text(e.nominal, "q:TargetValue")),
        lower_limit=limits.lower,
        upper_limit=limits.upper,
        unit=unit,
        datums=list(drf_labels.get(child_text(d, "q:DatumReferenceFrameId"), [])),
        modifiers=str(da.get("modifiers", "")).split(),
        basic=d is not None and d.find(f"{_Q}NonTolerance") is not None,
        unit_basis=unit_basis,
        max_value=_num(child_text(d, "q:MaximumToleranceValue")),
    )


def _vector(text: str | None) -> np.ndarray | None:
    """A QIF ``Vector`` (three decimals) as a (3,) array; None without a readable one."""
    try:
        v = np.array([float(x) for x in (text or "").split()])
    except ValueError:
        return None
    return v if v.shape == (3,) else None


def _ours(c: CharacteristicResult, attrs: dict, e: _Elements) -> None:
    """Complete ``c`` read from a qifreport document from its attributes ``attrs`` (and its
    definition's, in ``e``): the reading, least-squares value, uncertainty, coverage and
    points, and a toleranced surface's statistics and acceptance."""
    da = e.definition_attrs
    half = None
    if "lower_mm" in da and "upper_mm" in da:
        half = 0.5 * (da["upper_mm"] - da["lower_mm"])
    c.stats = stats_from_attributes(attrs)
    c.acceptance = acceptance_from_attributes(attrs, half)
    reading = str(attrs.get("reading", ""))
    c.reading = "" if reading == "-" else reading
    c.least_squares = _attr_float(attrs, "least_squares_mm")
    c.uncertainty = _attr_float(attrs, "expanded_uncertainty")
    c.budget = budget_from_attributes(attrs)
    c.coverage = _attr_float(attrs, "coverage")
    points = attrs.get("points")
    if isinstance(points, int):
        c.n_points = points
    elif c.stats is not None:
        c.n_points = c.stats.n
    c.reason = str(attrs.get("not_measured_reason", c.reason))


def _attr_float(attrs: dict, name: str) -> float | None:
    """The number attribute ``name`` (None when absent or not a number)."""
    x = attrs.get(name)
    return float(x) if isinstance(x, int | float) and not isinstance(x, bool) else None


def _characteristic(
    m: etree._Element, e: _Elements, drf_labels: dict[str, list[str]], ours: bool
) -> CharacteristicResult:
    """The characteristic measurement ``m`` with its item, nominal and definition ``e``
    and its datum labels; with the rest of qifreport's results when the document is
    ``ours``."""
    qif_type = etree.QName(m).localname.removesuffix("CharacteristicMeasurement")
    status = child_text(m, "q:Status/q:CharacteristicStatusEnum") or child_text(
        m, "q:Status/q:OtherCharacteristicStatus"
    )
    attrs = read_attributes(m)
    c = CharacteristicResult(
        _spec(qif_type, e, drf_labels),
        value=_num(child_text(m, "q:Value")),
        status=status_from_qif(status),
        reason=child_text(m, "q:NonConformanceDesignator") or "",
        bonus=_num(child_text(m, "q:Bonus")) or 0.0,
        direction=_vector(child_text(e.nominal, "q:Vector")),
        worst_positive=_num(child_text(m, "q:WorstPositiveDeviation")),
        worst_negative=_num(child_text(m, "q:WorstNegativeDeviation")),
        document=DocumentRecord(
            type=qif_type,
            id=m.get("id"),
            status=status,
            description=child_text(e.definition, "q:Description"),
            unequally_disposed=_num(child_text(e.definition, "q:UnequallyDisposedZone")),
            attributes=attrs,
        ),
    )
    if ours:
        _ours(c, attrs, e)
    return c


def _segments(
    m: etree._Element,
    e: _Elements,
    upper: CharacteristicResult,
    drf_labels: dict[str, list[str]],
    ours: bool,
) -> list[CharacteristicResult]:
    """The lower segments of composite frame ``m`` (its item, nominal and definition
    ``e``; :mod:`qifreport.qif.composite`), each as its own characteristic result after
    ``upper`` (the frame's first segment, whose own status this sets back from the
    frame's)."""
    found = segment_elements(m, "Measurement")
    if not found:
        return []
    upper.spec.composite = "upper"
    attrs = upper.document.attributes if upper.document is not None else {}
    if "segment_1_status" in attrs:
        upper.status = status_from_qif(str(attrs["segment_1_status"]))
        if upper.status != "FAIL":
            upper.reason = str(attrs.get("not_measured_reason", ""))
    definitions = {} if e.definition is None else dict(segment_elements(e.definition, "Definition"))
    out = []
    for n, seg in found:
        d = definitions.get(n)
        da = segment_attributes(e.definition_attrs, n)
        sa = segment_attributes(attrs, n)
        step_id = da.get("step_entity_id")
        spec = replace(
            upper.spec,
            key=child_text(d, "q:CharacteristicDesignator/q:Designator") or "",
            step_id=step_id if isinstance(step_id, int) else None,
            tolerance=_num(child_text(d, "q:ToleranceValue")),
            datums=list(drf_labels.get(child_text(d, "q:DatumReferenceFrameId"), [])),
            modifiers=str(da.get("modifiers", "")).split(),
            max_value=_num(child_text(d, "q:MaximumToleranceValue")),
            composite="lower",
            composite_of=upper.spec.step_id,
        )
        status = child_text(seg, "q:Status/q:CharacteristicStatusEnum")
        c = CharacteristicResult(
            spec,
            value=_num(child_text(seg, "q:Value")),
            status=status_from_qif(status),
            reason=str(sa.get("non_conformance", "")),
            bonus=_attr_float(sa, "Bonus") or 0.0,
            direction=upper.direction,
            worst_positive=_attr_float(sa, "WorstPositiveDeviation"),
            worst_negative=_attr_float(sa, "WorstNegativeDeviation"),
            document=DocumentRecord(
                type=upper.document.type if upper.document is not None else "",
                id=f"{m.get('id')}/{n}",  # the frame's measurement, segment n
                status=status,
                description=str(da.get("description", "")) or None,
                attributes=sa,
            ),
        )
        if ours:
            _ours(c, sa, _Elements(e.item, e.nominal, d, da))
        out.append(c)
    return out


def _software_version(root: etree._Element) -> str | None:
    """The version of qifreport among the document's software definitions (the last), if any."""
    sw_version = None
    for sw in root.iterfind(f"{_Q}SoftwareDefinitions/{_Q}Software"):
        if child_text(sw, "q:ApplicationName") == "qifreport":
            sw_version = child_text(sw, "q:Version")
    return sw_version


def read_results(path: Path | str) -> QIFResults:
    """Read a QIF 3.0 results document (ours or another application's).

    Raises
    ------
    ValueError
        The file is not a QIF document or carries no ``MeasurementResults``.
    """
    path = Path(path)
    root = etree.parse(str(path), etree.XMLParser(huge_tree=True, no_network=True)).getroot()
    if root.tag != f"{_Q}QIFDocument":
        raise ValueError(f"{path.name}: not a QIF 3 document (root {root.tag})")
    by_id = {el.get("id"): el for el in root.iter() if el.get("id") is not None}
    mr = root.find(f"{_Q}Results/{_Q}MeasurementResultsSet/{_Q}MeasurementResults")
    if mr is None:
        raise ValueError(f"{path.name}: no MeasurementResults (not a results document)")

    drf_labels = _datum_labels(root, by_id)
    ours = child_text(root, "q:Header/q:Application/q:Name") == "qifreport"
    cms = mr.find(f"{_Q}MeasuredCharacteristics/{_Q}CharacteristicMeasurements")
    chars = []
    for m in cms if cms is not None else []:
        e = _Elements.of(m, by_id, ours)
        c = _characteristic(m, e, drf_labels, ours)
        chars += [c, *_segments(m, e, c, drf_labels, ours)]

    attrs = read_attributes(mr)
    inputs = [
        (child_text(r, "q:URI") or "", child_text(r, "q:Description") or "")
        for r in mr.iterfind(f"{_Q}ExternalFileReferences/{_Q}ExternalFileReference")
    ]
    trace = mr.find(f"{_Q}InspectionTraceability")
    actual = root.find(
        f"{_Q}Results/{_Q}ActualComponentSets/{_Q}ActualComponentSet/{_Q}ActualComponent"
    )
    return QIFResults(
        path=path,
        version=root.get("versionQIF"),
        qpid=child_text(root, "q:QPId"),
        application=child_text(root, "q:Header/q:Application/q:Name"),
        software_version=_software_version(root),
        status=(
            child_text(mr, "q:InspectionStatus/q:InspectionStatusEnum")
            or child_text(mr, "q:InspectionStatus/q:OtherInspectionStatus")
        ),
        characteristics=chars,
        attributes=attrs,
        inputs=inputs,
        inspection_start=child_text(trace, "q:InspectionStart"),
        inspection_end=child_text(trace, "q:InspectionEnd"),
        serial_number=child_text(actual, "q:SerialNumber"),
        stats=stats_from_attributes(attrs) if ours else None,
        point_stats=stats_from_attributes(attrs, "scan_points_") if ours else None,
        acceptance=acceptance_from_attributes(attrs) if ours else None,
    )
