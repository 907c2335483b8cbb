"""A composite feature control frame as QIF states it: one characteristic, its upper
(pattern-locating) segment the characteristic's own definition and measurement, each lower
segment a ``SecondCompositeSegment...`` (``Third...``, ``Fourth...``) element inside them
(``CompositeSegmentPositionDefinitionType``, ``CompositeSegmentProfileDefinitionType`` and
their measurements), as the NIST models' QIF translations write them.

The writer builds a lower segment's definition and measurement as it would build a
characteristic's, then folds them into the upper's (:func:`fold_definition`,
:func:`fold_measurement`): the segment keeps its datum reference frame, tolerance,
designator, material condition and zone shape, its value and status; what QIF has no
element for (qifreport's attributes: the reading, uncertainty, statistics ...) goes to the
upper's ``Attributes`` under the prefix ``segment_<n>_``, where the reader finds them
(:func:`segment_attributes`).

The characteristic's ``Status`` is the frame's: the worst of its segments
(:func:`frame_status`); the upper segment's own is the attribute ``segment_1_status``.
"""

from __future__ import annotations

from lxml import etree

from .definitions import Sections
from .xmlkit import NS, E

__all__ = [
    "ORDINALS",
    "SEGMENT_TYPES",
    "fold_definition",
    "fold_measurement",
    "frame_status",
    "segment_attributes",
    "segment_elements",
]

#: QIF characteristic type -> its composite segments' type name
SEGMENT_TYPES = {"Position": "Position", "SurfaceProfile": "Profile", "LineProfile": "Profile"}
#: segment number -> QIF's ordinal (the upper segment is the first)
ORDINALS = {2: "Second", 3: "Third", 4: "Fourth"}
#: QIF statuses, the frame's status being its worst segment's
_SEVERITY = ("PASS", "BASIC_OR_TED", "UNDEFINED", "NOT_ANALYZED", "INDETERMINATE", "FAIL")
_Q = f"{{{NS}}}"
#: a segment definition's elements, schema order (``ProjectedToleranceZone``: the segment's
#: name of the characteristic's ``ProjectedToleranceZoneValue``)
_DEFINITION_ORDER = {
    "Position": (
        "DatumReferenceFrameId",
        "ToleranceValue",
        "CharacteristicDesignator",
        "MaterialCondition",
        "ZoneShape",
        "MaximumToleranceValue",
        "ProjectedToleranceZoneValue",
    ),
    "Profile": ("DatumReferenceFrameId", "ToleranceValue", "CharacteristicDesignator"),
}
#: the characteristic definition's elements a segment comes before, per segment type
_BEFORE = {
    "Position": ("ToPointToleranceValue", "OrientationOnly"),
    "Profile": ("DatumReferenceFrameId", "OrientationOnly", "Extent"),
}
_MEASUREMENT_ORDER = ("Value", "MaxValue", "MinValue", "Status")
#: a characteristic measurement's numbers a segment's has no element for (attributes)
_MORE_NUMBERS = ("Bonus", "WorstPositiveDeviation", "WorstNegativeDeviation")


def _local(el: etree._Element) -> str:
    return etree.QName(el).localname if isinstance(el.tag, str) else ""


def _segment_tag(qif_type: str, n: int, what: str) -> str:
    return f"{ORDINALS[n]}CompositeSegment{SEGMENT_TYPES[qif_type]}{what}"


def segment_elements(parent: etree._Element, what: str) -> list[tuple[int, etree._Element]]:
    """The composite segments (number, element) of a characteristic definition or
    measurement ``parent`` (``what``: ``"Definition"`` or ``"Measurement"``), in order."""
    out = []
    for el in parent:
        name = _local(el)
        for n, ordinal in ORDINALS.items():
            if name.startswith(f"{ordinal}CompositeSegment") and name.endswith(what):
                out.append((n, el))
    return out


def _attributes(el: etree._Element, prefix: str) -> list[etree._Element]:
    """``el``'s ``Attributes`` children, renamed ``<prefix><name>``."""
    out = []
    for a in el.findall(f"{_Q}Attributes/*"):
        a.set("name", prefix + a.get("name", ""))
        out.append(a)
    return out


def _add_attributes(target: etree._Element, items: list[etree._Element], first: int) -> None:
    """Append ``items`` to ``target``'s ``Attributes`` (made as its child ``first`` when it
    has none)."""
    if not items:
        return
    attrs = target.find(f"{_Q}Attributes")
    if attrs is None:
        attrs = E.Attributes(n="0")
        target.insert(first, attrs)
    for a in items:
        attrs.append(a)
    attrs.set("n", str(len(attrs)))


def _definition_of(zs: Sections, ci: str) -> etree._Element:
    """The characteristic definition element of item ``ci`` among ``zs``."""
    item = next(x for x in zs.citems if x.get("id") == ci)
    cn = item.findtext(f"{_Q}CharacteristicNominalId")
    nominal = next(x for x in zs.cnoms if x.get("id") == cn)
    cd = nominal.findtext(f"{_Q}CharacteristicDefinitionId")
    return next(x for x in zs.cdefs if x.get("id") == cd)


def fold_definition(zs: Sections, upper_ci: str, qif_type: str, n: int) -> None:
    """Move the characteristic ``zs`` defined last (a lower segment's definition, nominal
    and item) into the definition of item ``upper_ci`` as its segment ``n`` (2: second):
    its frame, tolerance, designator and, for a position, material condition, zone shape,
    MAX tolerance and projected height; its attributes prefixed ``segment_<n>_``."""
    lower, item = zs.cdefs.pop(), zs.citems.pop()
    zs.cnoms.pop()
    cn = zs.cnom_ids.pop()
    for cns in zs.separate.values():  # the frame's upper segment states it
        if cn in cns:
            cns.remove(cn)
    upper = _definition_of(zs, upper_ci)
    kind = SEGMENT_TYPES[qif_type]
    found = {_local(el): el for el in lower}
    found["CharacteristicDesignator"] = item.find(f"{_Q}CharacteristicDesignator")
    kids = []
    for tag in _DEFINITION_ORDER[kind]:
        el = found.get(tag)
        if el is not None:
            if tag == "ProjectedToleranceZoneValue":
                el = E.ProjectedToleranceZone(el.text)
            kids.append(el)
    uz = found.get("UnequallyDisposedZone")
    if kind == "Profile" and uz is not None:
        kids.append(E.OuterDisposition(uz.text))
    segment = E(_segment_tag(qif_type, n, "Definition"), *kids)
    at = next((k for k, el in enumerate(upper) if _local(el) in _BEFORE[kind]), len(upper))
    upper.insert(at, segment)
    prefix = f"segment_{n}_"
    items = _attributes(lower, prefix)
    description = found.get("Description")
    if description is not None:
        items.append(E.AttributeStr(name=f"{prefix}description", value=description.text or ""))
    _add_attributes(upper, items, 0)


def frame_status(statuses: list[str]) -> str:
    """A composite characteristic's QIF status: its worst segment's."""
    known = [s for s in statuses if s in _SEVERITY]
    return max(known, key=_SEVERITY.index) if known else "UNDEFINED"


def fold_measurement(upper: etree._Element, lower: etree._Element, qif_type: str, n: int) -> None:
    """Fold a lower segment's characteristic measurement ``lower`` into the upper's
    ``upper`` as its segment ``n``: its value and status in the
    ``...CompositeSegment...Measurement``, its attributes (and a failure's designator)
    prefixed ``segment_<n>_``; the characteristic's status becomes the frame's."""
    found = {_local(el): el for el in lower}
    kids = [found[t] for t in _MEASUREMENT_ORDER if t in found]
    upper.append(E(_segment_tag(qif_type, n, "Measurement"), *kids))
    prefix = f"segment_{n}_"
    items = _attributes(lower, prefix)
    for tag in _MORE_NUMBERS:
        if tag in found:
            items.append(E.AttributeD1(name=f"{prefix}{tag}", value=found[tag].text or ""))
    why = found.get("NonConformanceDesignator")
    if why is not None:
        items.append(E.AttributeStr(name=f"{prefix}non_conformance", value=why.text or ""))
    status = upper.find(f"{_Q}Status/{_Q}CharacteristicStatusEnum")
    attrs = upper.find(f"{_Q}Attributes")
    own = None
    if attrs is not None:
        own = next((a for a in attrs if a.get("name") == "segment_1_status"), None)
    if own is None and status is not None:
        items.insert(0, E.AttributeStr(name="segment_1_status", value=status.text or ""))
    _add_attributes(upper, items, 0)
    if status is None:
        return
    segments = [
        el.findtext(f"{_Q}Status/{_Q}CharacteristicStatusEnum")
        for _, el in segment_elements(upper, "Measurement")
    ]
    status.text = frame_status([status.text or "", *[s or "" for s in segments]])
    if status.text == "FAIL" and upper.find(f"{_Q}NonConformanceDesignator") is None:
        at = next(k for k, el in enumerate(upper) if _after_designator(el))
        upper.insert(at, E.NonConformanceDesignator(f"composite segment {n} does not conform"))


def _after_designator(el: etree._Element) -> bool:
    """Whether a measurement's child ``el`` comes after its ``NonConformanceDesignator``
    (its value or a composite segment)."""
    name = _local(el)
    return name == "Value" or "CompositeSegment" in name


def segment_attributes(attrs: dict, n: int) -> dict:
    """The attributes of segment ``n`` among a composite characteristic's (prefix
    removed)."""
    prefix = f"segment_{n}_"
    return {k[len(prefix) :]: v for k, v in attrs.items() if k.startswith(prefix)}
