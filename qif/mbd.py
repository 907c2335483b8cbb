"""The characteristics a QIF document defines, read as plain items, and their comparison
item by item with another document's (e.g. qifreport's plan against an independent QIF MBD
translation of the same drawing).

Each characteristic nominal becomes one :class:`MbdItem`: its QIF type, tolerance or
limits in **mm** (or degrees) whatever the document's units (its ``FileUnits`` primary
linear unit and each value's own ``linearUnit``), its datum reference frame as labels with
their material modifiers, its material condition and zone shape. :func:`compare_items`
pairs two lists (geometric tolerances by name, dimensions by type, nominal and limits) and
lists every field that differs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

from .composite import segment_elements
from .modifiers import FLAG_ELEMENTS
from .xmlkit import NS

__all__ = ["FieldDifference", "ItemMatch", "MbdItem", "compare_items", "read_items"]

_Q = {"q": NS}
#: millimetres per length unit, by the unit names QIF documents use
MM_PER_UNIT = {
    "mm": 1.0,
    "millimeter": 1.0,
    "millimetre": 1.0,
    "inch": 25.4,
    "in": 25.4,
    "m": 1000.0,
    "meter": 1000.0,
    "cm": 10.0,
    "um": 1e-3,
    "micrometer": 1e-3,
    "mil": 0.0254,
    "ft": 304.8,
}
#: degrees per angle unit
DEG_PER_UNIT = {"degree": 1.0, "deg": 1.0, "radian": 180.0 / math.pi, "rad": 180.0 / math.pi}
#: QIF characteristic types whose values are angles
ANGULAR_TYPES = ("Angle", "AngleBetween", "AngleFromTo", "AngularCoordinate")
#: dimension types (the rest are geometric tolerances)
DIMENSION_TYPES = (
    "Diameter",
    "Radius",
    "SphericalDiameter",
    "SphericalRadius",
    "Length",
    "Width",
    "Height",
    "Depth",
    "Thickness",
    "Distance",
    "DistanceBetween",
    "DistanceFromTo",
    "ChordCharacteristic",
    "Curvature",
) + ANGULAR_TYPES


@dataclass
class MbdItem:
    """One characteristic of a QIF document.

    Attributes
    ----------
    name : its nominal's ``Name`` (the PMI item's name).
    type : the QIF type without suffix (``Position``, ``Diameter`` ...).
    unit : ``'mm'`` or ``'deg'``.
    tolerance : a geometric tolerance's ``ToleranceValue`` (mm), else None.
    target : a dimension's ``TargetValue`` (mm or deg), else None.
    lower, upper : a dimension's limits (mm or deg, absolute), else None.
    datums : the frame's datums in precedence, ``(label, material modifier)``; a compound
        datum's label is its datums' joined by ``-``.
    material : ``MaterialCondition`` (MAXIMUM, LEAST, NONE ...) or None.
    zone : the ``ZoneShape`` (``DiametricalZone``, ``PlanarZone`` ...) or None.
    designator : its ``CharacteristicDesignator``, if any.
    flags : the modifiers its definition states as elements set true (``FreeState``,
        ``StatisticalCharacteristic``, ``CommonZone``, ``UnitedOrContinuousFeature``,
        ``TangentPlane``) and ``SeparateRequirement`` when a ``SEP_REQ`` simultaneous
        requirement group names it, sorted.
    projected : a projected zone's height (``ProjectedToleranceZoneValue``), mm.
    extent : a profile's ``Extent`` (``ALL_AROUND``, ``ALL_OVER``, another's text);
        ``UNDEFINED`` is read as none.
    segments : a composite frame's further segments (``SecondCompositeSegment...``), in
        order, each as an item of the same type with its tolerance, datums, material
        condition and zone.
    """

    name: str
    type: str
    unit: str = "mm"
    tolerance: float | None = None
    target: float | None = None
    lower: float | None = None
    upper: float | None = None
    datums: tuple[tuple[str, str], ...] = ()
    material: str | None = None
    zone: str | None = None
    designator: str | None = None
    flags: tuple[str, ...] = ()
    projected: float | None = None
    extent: str | None = None
    segments: tuple[MbdItem, ...] = ()

    @property
    def is_dimension(self) -> bool:
        return self.type in DIMENSION_TYPES

    def describe(self) -> str:
        if self.is_dimension:
            lim = f"{_g(self.lower)}..{_g(self.upper)}" if self.lower is not None else "basic"
            return f"{self.type} {_g(self.target)} {self.unit} [{lim}]"
        frame = "|".join(
            lab + {"MAXIMUM": "(M)", "LEAST": "(L)"}.get(m, "") for lab, m in self.datums
        )
        mat = f" {self.material}" if self.material and self.material != "NONE" else ""
        return f"{self.type} {_g(self.tolerance)} mm{mat}" + (f" |{frame}|" if frame else "")


def _g(x: float | None) -> str:
    return "?" if x is None else f"{x:.6g}"


def _units(root: etree._Element) -> tuple[float, float, dict[str, float], dict[str, float]]:
    """(mm per primary linear unit, degrees per primary angular unit, mm per named linear
    unit, degrees per named angular unit) of a document."""
    lin = root.findtext("q:FileUnits/q:PrimaryUnits/q:LinearUnit/q:UnitName", namespaces=_Q)
    ang = root.findtext("q:FileUnits/q:PrimaryUnits/q:AngularUnit/q:UnitName", namespaces=_Q)
    ang = ang or root.findtext(
        "q:FileUnits/q:PrimaryUnits/q:PMIAngularUnit/q:UnitName", namespaces=_Q
    )
    mm = MM_PER_UNIT.get((lin or "mm").strip().lower(), 1.0)
    deg = DEG_PER_UNIT.get((ang or "degree").strip().lower(), 1.0)
    return mm, deg, MM_PER_UNIT, DEG_PER_UNIT


def _value(el: etree._Element | None, angular: bool, mm: float, deg: float) -> float | None:
    if el is None or el.text is None:
        return None
    x = float(el.text)
    if angular:
        unit = el.get("angularUnit")
        return x * (DEG_PER_UNIT.get(unit.lower(), 1.0) if unit else deg)
    unit = el.get("linearUnit")
    return x * (MM_PER_UNIT.get(unit.lower(), 1.0) if unit else mm)


def _frames(root: etree._Element) -> dict[str, tuple[tuple[str, str], ...]]:
    labels = {
        d.get("id"): (d.findtext("q:DatumLabel", namespaces=_Q) or "").strip()
        for d in root.iterfind("q:DatumDefinitions/q:DatumDefinition", _Q)
    }
    frames = {}
    for f in root.iterfind("q:DatumReferenceFrames/q:DatumReferenceFrame", _Q):
        seq = []
        for d in f.iterfind("q:Datums/q:Datum", _Q):
            simple = d.find("q:SimpleDatum", _Q)
            if simple is not None:
                lab = labels.get(simple.findtext("q:DatumDefinitionId", namespaces=_Q), "?")
                mat = simple.findtext("q:MaterialModifier", namespaces=_Q) or "NONE"
                seq.append((lab, mat.strip()))
                continue
            compound = d.find("q:CompoundDatum", _Q)
            if compound is not None:
                parts = [
                    labels.get(x.findtext("q:DatumDefinitionId", namespaces=_Q), "?")
                    for x in compound.iter(f"{{{NS}}}SimpleDatum")
                ]
                mats = {
                    (x.findtext("q:MaterialModifier", namespaces=_Q) or "NONE").strip()
                    for x in compound.iter(f"{{{NS}}}SimpleDatum")
                }
                seq.append(("-".join(parts), "NONE" if mats == {"NONE"} else "/".join(mats)))
        frames[f.get("id")] = tuple(seq)
    return frames


def read_items(path: str | Path, *, skip_user_defined: bool = True) -> list[MbdItem]:
    """Every characteristic a QIF document defines (one per characteristic nominal,
    document order), values in mm and degrees.

    ``skip_user_defined``: leave out ``UserDefinedAttribute`` characteristics (qifreport's
    acceptance-rule characteristics, no PMI item's)."""
    root = etree.parse(str(path)).getroot()
    mm, deg, _, _ = _units(root)
    frames = _frames(root)
    defs = {
        d.get("id"): d for d in root.iterfind("q:Characteristics/q:CharacteristicDefinitions/*", _Q)
    }
    separate = {
        cn
        for g in root.iterfind(
            "q:Characteristics/q:SimultaneousRequirementGroups/q:SimultaneousRequirementGroup", _Q
        )
        if (g.findtext("q:Requirement", namespaces=_Q) or "").strip() == "SEP_REQ"
        for cn in (x.text.strip() for x in g.iterfind("q:CharacteristicNominalIds/q:Id", _Q))
    }
    out = []
    for nom in root.iterfind("q:Characteristics/q:CharacteristicNominals/*", _Q):
        t = etree.QName(nom).localname.removesuffix("CharacteristicNominal")
        if skip_user_defined and t == "UserDefinedAttribute":
            continue
        d = defs.get(nom.findtext("q:CharacteristicDefinitionId", namespaces=_Q))
        angular = t in ANGULAR_TYPES
        item = MbdItem(
            name=(nom.findtext("q:Name", namespaces=_Q) or "").strip(),
            type=t,
            unit="deg" if angular else "mm",
            designator=nom.findtext("q:CharacteristicDesignator/q:Designator", namespaces=_Q),
        )
        item.target = _value(nom.find("q:TargetValue", _Q), angular, mm, deg)
        if d is not None:
            _read_definition(item, d, frames, angular, mm, deg)
            item.segments = tuple(
                _read_definition(MbdItem(item.name, t), seg, frames, False, mm, deg)
                for _, seg in segment_elements(d, "Definition")
            )
        if nom.get("id") in separate:
            item.flags = tuple(sorted((*item.flags, "SeparateRequirement")))
        out.append(item)
    return out


def _read_definition(
    item: MbdItem,
    d: etree._Element,
    frames: dict[str, tuple[tuple[str, str], ...]],
    angular: bool,
    mm: float,
    deg: float,
) -> MbdItem:
    """Complete ``item`` from its characteristic definition (or a composite segment's)
    ``d``: tolerance or limits, frame, material condition, zone, modifiers; returns it."""
    item.tolerance = _value(d.find("q:ToleranceValue", _Q), False, mm, deg)
    tol = d.find("q:Tolerance", _Q)
    if tol is not None:
        hi = _value(tol.find("q:MaxValue", _Q), angular, mm, deg)
        lo = _value(tol.find("q:MinValue", _Q), angular, mm, deg)
        limit = (tol.findtext("q:DefinedAsLimit", namespaces=_Q) or "").strip() == "true"
        base = 0.0 if limit else (item.target or 0.0)
        item.upper = None if hi is None else base + hi
        item.lower = None if lo is None else base + lo
    frame = d.findtext("q:DatumReferenceFrameId", namespaces=_Q)
    if frame is not None:
        item.datums = frames.get(frame.strip(), ())
    mc = d.findtext("q:MaterialCondition", namespaces=_Q)
    item.material = mc.strip() if mc else None
    zone = d.find("q:ZoneShape/*", _Q)
    item.zone = etree.QName(zone).localname if zone is not None else None
    item.flags = tuple(
        sorted(
            f
            for f in FLAG_ELEMENTS
            if (d.findtext(f"q:{f}", namespaces=_Q) or "").strip() == "true"
        )
    )
    projected = d.find("q:ProjectedToleranceZoneValue", _Q)
    if projected is None:
        projected = d.find("q:ProjectedToleranceZone", _Q)
    item.projected = _value(projected, False, mm, deg)
    ext = d.findtext("q:Extent/q:ExtentEnum", namespaces=_Q) or d.findtext(
        "q:Extent/q:OtherExtent", namespaces=_Q
    )
    item.extent = ext.strip() if ext and ext.strip() != "UNDEFINED" else None
    return item


#: how many mm the value of a document that labels inch values as mm is short by
INCH = 25.4


@dataclass
class FieldDifference:
    """One field of a matched pair that differs: its name, both values as text, and what
    the difference is when it is known (``note``: e.g. the other document's value is the
    inch value labelled mm)."""

    field: str
    ours: str
    theirs: str
    note: str = ""


@dataclass
class ItemMatch:
    """One item of either document and its partner (None: the other has no such item)."""

    ours: MbdItem | None
    theirs: MbdItem | None
    differences: list[FieldDifference] = field(default_factory=list)

    @property
    def name(self) -> str:
        return (self.theirs or self.ours).name


def _close(a: float | None, b: float | None, rel: float = 1e-6, abs_: float = 1e-6) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return math.isclose(a, b, rel_tol=rel, abs_tol=abs_)


def _differences(a: MbdItem, b: MbdItem) -> list[FieldDifference]:
    out = []
    if a.type != b.type:
        out.append(FieldDifference("type", a.type, b.type))
    for f in ("tolerance", "target", "lower", "upper"):
        x, y = getattr(a, f), getattr(b, f)
        if not _close(x, y):
            inch = a.unit == "mm" and y is not None and _close(x, y * INCH)
            note = "their value is the inch value, labelled mm" if inch else ""
            out.append(FieldDifference(f, _g(x), _g(y), note))
    if not a.is_dimension or not b.is_dimension:
        if tuple(a.datums) != tuple(b.datums):
            out.append(FieldDifference("datums", _frame(a.datums), _frame(b.datums)))
        if (a.material or "NONE") != (b.material or "NONE"):
            out.append(FieldDifference("material", a.material or "-", b.material or "-"))
        if a.zone != b.zone:
            out.append(FieldDifference("zone", a.zone or "-", b.zone or "-"))
        if not _close(a.projected, b.projected):
            out.append(FieldDifference("projected", _g(a.projected), _g(b.projected)))
        if a.extent != b.extent:
            out.append(FieldDifference("extent", a.extent or "-", b.extent or "-"))
        if len(a.segments) != len(b.segments):
            out.append(FieldDifference("segments", str(len(a.segments)), str(len(b.segments))))
        for k, (x, y) in enumerate(zip(a.segments, b.segments, strict=False)):
            out += [
                FieldDifference(f"segment {k + 2} {d.field}", d.ours, d.theirs, d.note)
                for d in _differences(x, y)
            ]
    if a.flags != b.flags:
        out.append(FieldDifference("modifiers", " ".join(a.flags), " ".join(b.flags)))
    return out


def _frame(seq) -> str:
    return "|" + "|".join(f"{lab}:{m}" for lab, m in seq) + "|" if seq else "-"


def compare_items(ours: list[MbdItem], theirs: list[MbdItem]) -> list[ItemMatch]:
    """Pair two documents' items by content and list each pair's differences.

    Pairs are made in passes, each over every item still unpaired, from the closest match
    to the loosest, so that an exact pair is never taken by a looser one made before it
    (two tolerances of one name, a translator's own names):

    * geometric tolerances: name, type, value and datums; then type, value and datums;
      name, type and value; type and value; and last the name alone (names compared with
      case and spaces ignored);
    * dimensions, which translators name each their own way: type, unit, nominal and
      limits; then unit and nominal.

    Returns their items in their order, each with its partner, then ours that have none."""
    left = list(range(len(ours)))

    def key(s: str) -> str:
        return " ".join(s.lower().split())

    def same_value(x: float | None, y: float | None) -> bool:
        return _close(x, y) or (x is not None and y is not None and _close(x, y * INCH))

    def tol(a: MbdItem, b: MbdItem) -> bool:
        return not a.is_dimension and a.type == b.type and same_value(a.tolerance, b.tolerance)

    def frame(a: MbdItem, b: MbdItem) -> bool:
        return tuple(a.datums) == tuple(b.datums)

    def named(a: MbdItem, b: MbdItem) -> bool:
        return key(a.name) == key(b.name)

    def dim(a: MbdItem, b: MbdItem) -> bool:
        return a.is_dimension and a.unit == b.unit and same_value(a.target, b.target)

    tolerance_passes = [
        lambda a, b: named(a, b) and tol(a, b) and frame(a, b),
        lambda a, b: tol(a, b) and frame(a, b),
        lambda a, b: named(a, b) and tol(a, b),
        tol,
        lambda a, b: not a.is_dimension and named(a, b),
    ]
    dimension_passes = [
        lambda a, b: dim(a, b) and same_value(a.lower, b.lower) and same_value(a.upper, b.upper),
        dim,
    ]
    partner: list[int | None] = [None] * len(theirs)
    for j_kind, passes in ((False, tolerance_passes), (True, dimension_passes)):
        for pred in passes:
            for j, b in enumerate(theirs):
                if b.is_dimension != j_kind or partner[j] is not None:
                    continue
                k = next((k for k in left if pred(ours[k], b)), None)
                if k is not None:
                    left.remove(k)
                    partner[j] = k
    out = list(zip(theirs, partner, strict=True))
    matches = []
    for b, k in out:
        a = ours[k] if k is not None else None
        matches.append(ItemMatch(a, b, _differences(a, b) if a is not None else []))
    matches += [ItemMatch(ours[k], None) for k in left]
    return matches
