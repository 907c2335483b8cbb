"""Read a QIF 3.0 results document back: ours in full, anyone's in outline.

:func:`read_results` returns, for every characteristic measurement of the first
``MeasurementResults``, its QIF type, designator, status, measured value and tolerance, and,
for documents qifreport wrote, the product's own result objects rebuilt from the typed
``Attributes`` (:class:`qifreport.metrology.acceptance.statistics.DeviationStats`,
:class:`qifreport.metrology.acceptance.criteria.Acceptance` with its
:class:`~qifreport.metrology.acceptance.criteria.Region` list), so a round trip can be checked
number
by number (see :mod:`qifreport.qif.writer` for the layout).
Regions come back without their vertex lists (``vertices`` empty, ``peak_vertex`` -1): QIF
carries the area, peak, sign, centroid and peak location.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

from qifreport.metrology.acceptance.criteria import Acceptance, Region
from qifreport.metrology.acceptance.statistics import DeviationStats

from .writer import NS

__all__ = [
    "acceptance_from_attributes",
    "child_text",
    "CharacteristicResult",
    "QIFResults",
    "read_attributes",
    "read_results",
    "stats_from_attributes",
]

_Q = f"{{{NS}}}"
_STATS_KEYS = ("rms", "mean", "max_abs", "max_pos", "min_neg", "p95", "p99", "p999")


@dataclass
class CharacteristicResult:
    """One characteristic measurement with its definition.

    Attributes
    ----------
    kind : QIF type without suffix, e.g. ``"SurfaceProfile"``, ``"Flatness"``.
    id : the measurement's QIF id.  name : the item's (or definition's) name.
    designator : the item's ``CharacteristicDesignator/Designator`` (qifreport: zone key).
    status : ``CharacteristicStatusEnum`` (or the other-status text).
    value : measured ``Value`` (mm for lengths), None when absent.
    worst_positive, worst_negative : profile measurements' worst deviations, mm.
    tolerance : the definition's ``ToleranceValue``, None when absent.
    unequally_disposed : ``UnequallyDisposedZone``, mm, None when absent.
    description : the definition's description.  datum_labels : of its reference frame.
    attributes : the measurement's typed Attributes, name -> value.
    stats, acceptance : rebuilt for documents written by qifreport, else None.
    """

    kind: str
    id: str
    name: str | None
    designator: str | None
    status: str | None
    value: float | None
    worst_positive: float | None = None
    worst_negative: float | None = None
    tolerance: float | None = None
    unequally_disposed: float | None = None
    description: str | None = None
    datum_labels: list[str] = field(default_factory=list)
    attributes: dict = field(default_factory=dict)
    stats: DeviationStats | None = None
    acceptance: Acceptance | None = None


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
            if c.designator == designator:
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


def _characteristic(
    m: etree._Element, by_id: dict, drf_labels: dict[str, list[str]], ours: bool
) -> CharacteristicResult:
    """The characteristic measurement ``m`` with its item, nominal and definition (found in
    ``by_id``) and its datum labels; with qifreport's statistics and acceptance when the
    document is ``ours``."""
    tag = etree.QName(m).localname
    kind = tag.removesuffix("CharacteristicMeasurement")
    item = by_id.get(child_text(m, "q:CharacteristicItemId"))
    nominal = by_id.get(child_text(item, "q:CharacteristicNominalId")) if item is not None else None
    definition = (
        by_id.get(child_text(nominal, "q:CharacteristicDefinitionId"))
        if nominal is not None
        else None
    )
    status = child_text(m, "q:Status/q:CharacteristicStatusEnum") or child_text(
        m, "q:Status/q:OtherCharacteristicStatus"
    )
    attrs = read_attributes(m)
    tol = _num(child_text(definition, "q:ToleranceValue"))
    c = CharacteristicResult(
        kind=kind,
        id=m.get("id"),
        name=child_text(item, "q:Name") or child_text(definition, "q:Name"),
        designator=child_text(item, "q:CharacteristicDesignator/q:Designator"),
        status=status,
        value=_num(child_text(m, "q:Value")),
        worst_positive=_num(child_text(m, "q:WorstPositiveDeviation")),
        worst_negative=_num(child_text(m, "q:WorstNegativeDeviation")),
        tolerance=tol,
        unequally_disposed=_num(child_text(definition, "q:UnequallyDisposedZone")),
        description=child_text(definition, "q:Description"),
        datum_labels=drf_labels.get(child_text(definition, "q:DatumReferenceFrameId"), []),
        attributes=attrs,
    )
    if ours:
        da = read_attributes(definition)
        half = None
        if "lower_mm" in da and "upper_mm" in da:
            half = 0.5 * (da["upper_mm"] - da["lower_mm"])
        c.stats = stats_from_attributes(attrs)
        c.acceptance = acceptance_from_attributes(attrs, half)
    return c


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
    chars = [_characteristic(m, by_id, drf_labels, ours) for m in (cms if cms is not None else [])]

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
