"""Semantic PMI of STEP AP242 files, read from the Part 21 text (no OpenCASCADE).

OCCT's XDE reader loses or corrupts part of the semantic PMI of real files: magnitudes stored
as complex instances ``(LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM()
MEASURE_WITH_UNIT(...))`` come back as 0.0, per-measure units (an inch tolerance in a
millimetre file) are left unconverted, and datum-to-face links that go through
ITEM_IDENTIFIED_REPRESENTATION_USAGE, PLACED_DATUM_TARGET_FEATURE or
COMPOSITE_GROUP_SHAPE_ASPECT are dropped. This module walks the instance graph of
:class:`qifreport.step.p21.P21Model` directly, following the AP242 edition 1 and 2 (and the older
AP214/AP203e2 ``DATUM_REFERENCE``) structures:

* **Units** are resolved per measure, recursively: SI_UNIT with its prefix, CONVERSION_BASED_UNIT
  through its conversion factor (a measure with its own unit), simple or complex instances.
  Every length becomes millimetres and every plane angle degrees. A conversion factor within
  1e-6 (relative) of a well-known one (inch 25.4 mm, foot, degree ...) is snapped to it, so
  that ``0.0174532925`` rad does not turn 90 degrees into 89.99999999.
* **Geometric tolerances** (simple subtypes or complex instances) give their magnitude,
  characteristic, modifiers, zone form, unequal disposition, maximum, unit-basis and datum
  reference frame (DATUM_SYSTEM / DATUM_REFERENCE_COMPARTMENT / COMMON_DATUM_LIST /
  DATUM_REFERENCE_ELEMENT, or DATUM_REFERENCE / REFERENCED_MODIFIED_DATUM).
* **Dimensions** (DIMENSIONAL_SIZE, ANGULAR_SIZE, DIMENSIONAL_LOCATION, ANGULAR_LOCATION and
  their ``_WITH_PATH`` / ``DIRECTED_`` forms) give their nominal or limits from
  DIMENSIONAL_CHARACTERISTIC_REPRESENTATION and their tolerance from PLUS_MINUS_TOLERANCE.
* **Faces**: a shape aspect is mapped to faces through GEOMETRIC_ITEM_SPECIFIC_USAGE and
  ITEM_IDENTIFIED_REPRESENTATION_USAGE, recursing through SHAPE_ASPECT_RELATIONSHIP and
  SHAPE_ASPECT_DERIVING_RELATIONSHIP (composite, composite group, all-around, derived aspects ->
  their components), a dimension to the faces of its feature(s), and a DATUM to those of its
  datum features and, through FEATURE_FOR_DATUM_TARGET_RELATIONSHIP, of its target features.
  When the file associates a feature with non-face geometry only (datum target points and
  lines, thread cylinders, axes, edges), :class:`_Geometry` finds the faces carrying that
  geometry or coaxial with it, and ``face_notes`` says so.

Nothing is guessed: a value that cannot be established is ``None`` and a problem string says
why. Entry points: :func:`read_pmi_text` (a path) and :func:`pmi_from_model` (a parsed model).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .p21 import Entity, Enum, P21Error, P21Model, Ref, Typed
from .pmi import PMI, Datum, DatumRef, Dimension, GeometricTolerance

log = logging.getLogger(__name__)

__all__ = ["Measure", "Unit", "pmi_from_model", "read_pmi_text"]

# --------------------------------------------------------------------------------------------
# vocabulary
# --------------------------------------------------------------------------------------------

#: geometric tolerance entity types -> characteristic
GT_TYPES: dict[str, str] = {
    "SURFACE_PROFILE_TOLERANCE": "surface_profile",
    "LINE_PROFILE_TOLERANCE": "line_profile",
    "FLATNESS_TOLERANCE": "flatness",
    "STRAIGHTNESS_TOLERANCE": "straightness",
    "ROUNDNESS_TOLERANCE": "roundness",
    "CYLINDRICITY_TOLERANCE": "cylindricity",
    "POSITION_TOLERANCE": "position",
    "PERPENDICULARITY_TOLERANCE": "perpendicularity",
    "PARALLELISM_TOLERANCE": "parallelism",
    "ANGULARITY_TOLERANCE": "angularity",
    "CIRCULAR_RUNOUT_TOLERANCE": "circular_runout",
    "TOTAL_RUNOUT_TOLERANCE": "total_runout",
    "COAXIALITY_TOLERANCE": "coaxiality",
    "CONCENTRICITY_TOLERANCE": "concentricity",
    "SYMMETRY_TOLERANCE": "symmetry",
}
#: instances of any of these are geometric tolerances (the characteristic may be missing)
_GT_ANY = (
    *GT_TYPES,
    "GEOMETRIC_TOLERANCE",
    "MODIFIED_GEOMETRIC_TOLERANCE",
    "GEOMETRIC_TOLERANCE_WITH_DATUM_REFERENCE",
    "GEOMETRIC_TOLERANCE_WITH_MODIFIERS",
    "GEOMETRIC_TOLERANCE_WITH_DEFINED_UNIT",
    "UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE",
)

SIZE_TYPES = (
    "DIMENSIONAL_SIZE",
    "ANGULAR_SIZE",
    "DIMENSIONAL_SIZE_WITH_PATH",
    "DIMENSIONAL_SIZE_WITH_DATUM_FEATURE",
)
LOCATION_TYPES = (
    "DIMENSIONAL_LOCATION",
    "ANGULAR_LOCATION",
    "DIMENSIONAL_LOCATION_WITH_PATH",
    "DIRECTED_DIMENSIONAL_LOCATION",
    "DIMENSIONAL_LOCATION_WITH_DATUM_FEATURE",
)
#: topological faces accepted as targets of a face association
FACE_TYPES = frozenset(
    {"ADVANCED_FACE", "FACE_SURFACE", "FACE", "ORIENTED_FACE", "SUBFACE", "CONNECTED_FACE_SUB_SET"}
)
#: shells and solids whose faces are all meant
_SHELL_TYPES = frozenset({"CLOSED_SHELL", "OPEN_SHELL", "ORIENTED_CLOSED_SHELL"})
_SOLID_TYPES = frozenset({"MANIFOLD_SOLID_BREP", "BREP_WITH_VOIDS"})
#: usages linking a shape aspect to representation items; DRAUGHTING_MODEL_ITEM_ASSOCIATION is
#: also an ITEM_IDENTIFIED_REPRESENTATION_USAGE but points at presentation, so it is excluded
_USAGE_TYPES = frozenset({"GEOMETRIC_ITEM_SPECIFIC_USAGE", "ITEM_IDENTIFIED_REPRESENTATION_USAGE"})
#: shape aspect relationships followed from the relating (whole) to the related (part)
_PART_OF_TYPES = frozenset({"SHAPE_ASPECT_RELATIONSHIP", "SHAPE_ASPECT_DERIVING_RELATIONSHIP"})
_DATUM_TYPES = frozenset({"DATUM"})
_TARGET_TYPES = frozenset({"DATUM_TARGET", "PLACED_DATUM_TARGET_FEATURE"})

_SI_PREFIX = {
    "EXA": 1e18, "PETA": 1e15, "TERA": 1e12, "GIGA": 1e9, "MEGA": 1e6, "KILO": 1e3,
    "HECTO": 1e2, "DECA": 1e1, "DECI": 1e-1, "CENTI": 1e-2, "MILLI": 1e-3, "MICRO": 1e-6,
    "NANO": 1e-9, "PICO": 1e-12, "FEMTO": 1e-15, "ATTO": 1e-18,
}  # fmt: skip
#: well-known conversion-based units: (kind, exact factor in mm or degrees)
_KNOWN_UNITS = {
    "INCH": ("length", 25.4),
    "FOOT": ("length", 304.8),
    "MIL": ("length", 0.0254),
    "THOU": ("length", 0.0254),
    "MILLIMETRE": ("length", 1.0),
    "MILLIMETER": ("length", 1.0),
    "DEGREE": ("angle", 1.0),
    "DEG": ("angle", 1.0),
    "MINUTE": ("angle", 1.0 / 60.0),
    "SECOND": ("angle", 1.0 / 3600.0),
}
_SNAP_RTOL = 1e-6
#: short names of length scales (mm per unit) for PMI.length_unit
_LENGTH_NAMES = {1.0: "mm", 25.4: "inch", 1000.0: "m", 10.0: "cm", 304.8: "ft", 0.001: "um"}
#: dimensional notes (DESCRIPTIVE_REPRESENTATION_ITEM('dimensional note', ...)) -> qualifier
_NOTES = {"theoretical": "basic", "auxiliary": "reference"}


# --------------------------------------------------------------------------------------------
# units and measures
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Unit:
    """A resolved unit.

    Attributes
    ----------
    kind : str
        ``'length'``, ``'angle'``, ``'solid_angle'``, ``'area'``, ``'other'`` or
        ``'unknown'``.
    scale : float or None
        Millimetres (length), degrees (angle) or mm^2 (area) per unit; ``None`` if unknown.
    text : str
        How the file names it: ``'MILLI METRE'``, ``'INCH'``, ``'DEGREE'``, ``'RADIAN'`` ...
    problem : str or None
        Why the unit could not be fully resolved.
    """

    kind: str
    scale: float | None
    text: str
    problem: str | None = None


@dataclass
class Measure:
    """A measure with unit, converted to mm / degrees.

    Attributes
    ----------
    value : float or None
        Converted value (mm for lengths, degrees for angles); ``None`` if not established.
    raw : float or None
        The number as written in the file.
    kind : str
        Unit kind, see :class:`Unit`.
    text : str
        ``'<raw> <unit text>'``, e.g. ``'0.03 INCH'``.
    measure_type : str
        The typed value's type, e.g. ``'LENGTH_MEASURE'``.
    problems : list of str
    """

    value: float | None
    raw: float | None
    kind: str
    text: str
    measure_type: str = ""
    problems: list[str] = field(default_factory=list)


def _clean(x: float) -> float:
    """Round to 12 significant digits: ``0.015 * 25.4`` is 0.381, not 0.38099999999999995.

    The files carry at most 15 significant digits and unit conversions add binary noise in the
    last ones; 12 digits keep far more than any tolerance needs.
    """
    return float(f"{x:.12g}")


def _fmt(x: float) -> str:
    """Shortest faithful text of a number (``0.75``, ``25.4``, ``1``)."""
    return f"{x:.15g}"


def _unwrap(value: object) -> tuple[object, str]:
    """Strip nested typed parameters: ``POSITIVE_LENGTH_MEASURE(LENGTH_MEASURE(1.))``."""
    name = ""
    while isinstance(value, Typed):
        name = name or value.type
        value = value.value
    return value, name


def _refs(value: object) -> list[Ref]:
    """References in a parameter that is a reference or an aggregate of them (flattened)."""
    if isinstance(value, Ref):
        return [value]
    if isinstance(value, Typed):
        return _refs(value.params)
    if isinstance(value, tuple):
        out: list[Ref] = []
        for v in value:
            out.extend(_refs(v))
        return out
    return []


def _enum_names(value: object) -> list[str]:
    """Lower-case names of the enumerations in a parameter (flattened)."""
    if isinstance(value, Enum):
        return [value.name.lower()]
    if isinstance(value, Typed):
        return _enum_names(value.params)
    if isinstance(value, tuple):
        out: list[str] = []
        for v in value:
            out.extend(_enum_names(v))
        return out
    return []


def _text(value: object) -> str:
    """A string attribute, ``''`` for ``$`` or anything else."""
    return value if isinstance(value, str) else ""


def _sorted_unique(ids: Iterable[int]) -> list[int]:
    return sorted(set(ids))


# --------------------------------------------------------------------------------------------
# the reader
# --------------------------------------------------------------------------------------------


class _Reader:
    """Resolution state for one model (caches units, measures and face sets)."""

    def __init__(self, model: P21Model) -> None:
        self.m = model
        self._units: dict[int, Unit] = {}
        self._faces: dict[int, tuple[frozenset[int], tuple[str, ...], tuple[str, ...]]] = {}
        self._geometry: _Geometry | None = None
        self.problems: list[str] = []
        self.context_length = Unit("length", 1.0, "MILLI METRE (assumed)")
        self.context_angle = Unit("angle", 180.0 / math.pi, "RADIAN (assumed)")

    # ---- helpers ------------------------------------------------------------------------
    def get(self, ref: object) -> Entity | None:
        """The entity of a reference, ``None`` for ``$``/dangling/unreadable."""
        if not isinstance(ref, Ref):
            return None
        try:
            return self.m.get(ref)
        except P21Error as exc:
            self.problems.append(f"#{ref.id}: unreadable record ({exc})")
            return None

    def types(self, ref: Ref | int) -> tuple[str, ...]:
        key = ref.id if isinstance(ref, Ref) else ref
        if key not in self.m.raw:
            return ()
        try:
            return self.m.type_names(key)
        except P21Error:
            return ()

    def referrers_with(self, eid: int, names: Iterable[str]) -> list[Entity]:
        """Referring entities having one of ``names`` as type or part."""
        wanted = set(names)
        out = []
        for src in self.m.referrers(eid):
            if wanted.intersection(self.types(src)):
                ent = self.get(Ref(src))
                if ent is not None:
                    out.append(ent)
        return out

    @staticmethod
    def params_of(ent: Entity, names: Iterable[str]) -> tuple | None:
        """Parameters of the first of ``names`` that ``ent`` has (type or part)."""
        for n in names:
            p = ent.part(n)
            if p is not None:
                return p
        return None

    # ---- units --------------------------------------------------------------------------
    def unit(self, ref: object, _depth: int = 0) -> Unit:
        """Resolve a unit reference (SI, conversion based, derived; simple or complex)."""
        if not isinstance(ref, Ref):
            return Unit("unknown", None, "?", "no unit given")
        cached = self._units.get(ref.id)
        if cached is not None:
            return cached
        if _depth > 10:
            return Unit("unknown", None, "?", f"#{ref.id}: unit definition loops")
        ent = self.get(ref)
        u = self._unit(ent, ref.id, _depth) if ent else Unit("unknown", None, "?", f"#{ref.id}?")
        self._units[ref.id] = u
        return u

    def _unit(self, ent: Entity, eid: int, depth: int) -> Unit:
        hinted = (
            "length"
            if ent.has("LENGTH_UNIT")
            else "angle"
            if ent.has("PLANE_ANGLE_UNIT")
            else "solid_angle"
            if ent.has("SOLID_ANGLE_UNIT")
            else None
        )
        si = ent.part("SI_UNIT")
        if si is not None:
            prefix, name = (si[-2], si[-1]) if len(si) >= 2 else (None, si[-1] if si else None)
            pname = prefix.name if isinstance(prefix, Enum) else None
            uname = name.name if isinstance(name, Enum) else "?"
            factor = _SI_PREFIX.get(pname, 1.0) if pname else 1.0
            text = f"{pname} {uname}" if pname else uname
            if uname == "METRE":
                return Unit("length", factor * 1000.0, text)
            if uname == "RADIAN":
                return Unit("angle", factor * 180.0 / math.pi, text)
            if uname == "STERADIAN":
                return Unit("solid_angle", factor, text)
            return Unit(hinted or "other", None, text)
        cbu = ent.part("CONVERSION_BASED_UNIT")
        if cbu is not None and len(cbu) >= 2:
            name = _text(cbu[-2]) or "?"
            factor_ent = self.get(cbu[-1])
            if factor_ent is None:
                return Unit(hinted or "unknown", None, name, f"#{eid}: no conversion factor")
            value, _, unit_ref = self._value_and_unit(factor_ent)
            base = self.unit(unit_ref, depth + 1) if unit_ref is not None else None
            if not isinstance(value, (int, float)) or base is None or base.scale is None:
                why = base.problem if base is not None and base.problem else "unresolved"
                return Unit(hinted or "unknown", None, name, f"#{eid} {name}: {why}")
            kind = base.kind if base.kind != "unknown" else (hinted or "unknown")
            scale = float(value) * base.scale
            known = _KNOWN_UNITS.get(name.upper())
            if known and known[0] == kind and math.isclose(scale, known[1], rel_tol=_SNAP_RTOL):
                scale = known[1]
            problem = None
            if hinted and kind != hinted:
                problem = f"#{eid} {name}: declared {hinted} unit converts to a {kind} unit"
            return Unit(kind, scale, name, problem)
        if ent.has("DERIVED_UNIT"):
            elements = _refs(ent.part("DERIVED_UNIT"))
            powers = []
            for el in elements:
                el_ent = self.get(el)
                p = el_ent.part("DERIVED_UNIT_ELEMENT") if el_ent else None
                if p and len(p) >= 2 and isinstance(p[1], (int, float)):
                    powers.append((self.unit(p[0], depth + 1), float(p[1])))
            if len(powers) == 1 and powers[0][0].kind == "length" and powers[0][1] == 2.0:
                base = powers[0][0]
                scale = base.scale**2 if base.scale is not None else None
                return Unit("area", scale, f"{base.text}^2")
            return Unit("other", None, "derived unit")
        if ent.has("CONTEXT_DEPENDENT_UNIT"):
            p = ent.part("CONTEXT_DEPENDENT_UNIT")
            name = _text(p[-1]) if p else "?"
            return Unit(hinted or "other", None, name, f"#{eid}: context dependent unit {name!r}")
        return Unit(hinted or "unknown", None, "?", f"#{eid}: unit {ent.types} not understood")

    # ---- measures -----------------------------------------------------------------------
    def _value_and_unit(self, ent: Entity) -> tuple[object, str, Ref | None]:
        """Find ``(value_component, measure type, unit_component)`` in any part of ``ent``.

        Works for MEASURE_WITH_UNIT and its subtypes (``(value, unit)``), a simple
        MEASURE_REPRESENTATION_ITEM (``(name, value, unit)``) and complex instances where the
        pair sits in the MEASURE_WITH_UNIT part.
        """
        parts = (ent.params,) if ent.parts is None else tuple(ent.parts.values())
        for params in parts:
            for i, v in enumerate(params):
                if isinstance(v, Typed):
                    value, mtype = _unwrap(v)
                    unit_ref = params[i + 1] if i + 1 < len(params) else None
                    return value, mtype, unit_ref if isinstance(unit_ref, Ref) else None
        return None, "", None

    def measure(self, ref: object, expect: str | None = None) -> Measure:
        """Resolve a measure-with-unit reference into mm / degrees.

        Parameters
        ----------
        ref : Ref
            A (LENGTH_/PLANE_ANGLE_)MEASURE_WITH_UNIT, MEASURE_REPRESENTATION_ITEM or complex
            instance with these parts.
        expect : str, optional
            ``'length'`` or ``'angle'``: noted as a problem when the unit is of another kind.
        """
        ent = self.get(ref)
        if ent is None:
            rid = f"#{ref.id}" if isinstance(ref, Ref) else repr(ref)
            return Measure(None, None, "unknown", "", problems=[f"measure {rid} not found"])
        value, mtype, unit_ref = self._value_and_unit(ent)
        problems: list[str] = []
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return Measure(
                None, None, "unknown", f"{value!r}", mtype,
                [f"#{ent.id}: no numeric value_component ({value!r})"],
            )  # fmt: skip
        raw = float(value)
        unit = self.unit(unit_ref)
        if unit.scale is None:
            # fall back on the kind of the measure type and the context unit, with a note
            fallback = None
            if "LENGTH" in mtype:
                fallback = self.context_length
            elif "PLANE_ANGLE" in mtype:
                fallback = self.context_angle
            if fallback is not None and fallback.scale is not None:
                problems.append(
                    f"#{ent.id}: unit not resolved ({unit.problem or unit.text}); "
                    f"context unit {fallback.text} used"
                )
                unit = fallback
            else:
                problems.append(f"#{ent.id}: unit not resolved ({unit.problem or unit.text})")
                return Measure(None, raw, unit.kind, f"{_fmt(raw)} {unit.text}", mtype, problems)
        elif unit.problem:
            problems.append(unit.problem)
        if expect and unit.kind != expect:
            problems.append(f"#{ent.id}: expected a {expect} measure, unit is {unit.text}")
        value = _clean(raw * unit.scale)
        return Measure(value, raw, unit.kind, f"{_fmt(raw)} {unit.text}", mtype, problems)

    def item_name(self, ent: Entity) -> str:
        """Name of a representation item (simple MEASURE_REPRESENTATION_ITEM or complex)."""
        p = ent.part("REPRESENTATION_ITEM")
        if p:
            return _text(p[0])
        if ent.parts is None and ent.params and isinstance(ent.params[0], str):
            return ent.params[0]
        return ""

    # ---- faces --------------------------------------------------------------------------
    @property
    def geometry(self) -> _Geometry:
        """The geometric locator (built on first use)."""
        if self._geometry is None:
            self._geometry = _Geometry(self)
        return self._geometry

    def faces(self, ref: object) -> tuple[list[int], list[str], list[str]]:
        """Faces of a shape aspect, dimension or datum.

        Returns
        -------
        faces : list of int
            Sorted face ids.
        problems : list of str
            Why no face (or not every item) could be found.
        notes : list of str
            How faces were derived from non-face items (edges, curves, points).
        """
        if not isinstance(ref, Ref) or ref.id not in self.m.raw:
            return [], [f"no shape aspect ({ref!r})"], []
        cached = self._faces.get(ref.id)
        if cached is None:
            found: set[int] = set()
            others: list[Ref] = []
            self._collect(ref.id, set(), found, others)
            problems: list[str] = []
            notes: list[str] = []
            unplaced: dict[str, int] = {}
            derived: dict[str, dict[str, int]] = {}
            for item in dict.fromkeys(others):
                faces, how = self.geometry.locate(item)
                kind = self._type_label(item)
                if faces:
                    found |= faces
                    derived.setdefault(how, {}).setdefault(kind, 0)
                    derived[how][kind] += 1
                else:
                    unplaced[kind] = unplaced.get(kind, 0) + 1
            for how, kinds in derived.items():
                notes.append(f"faces {how}: {_count_text(kinds)}")
            if unplaced:
                what = _count_text(unplaced)
                if found:
                    notes.append(f"items not placed on faces: {what}")
                else:
                    problems.append(f"associated geometry has no faces, only: {what}")
            elif not found:
                problems.append(f"#{ref.id}: no associated geometry found")
            cached = (frozenset(found), tuple(problems), tuple(notes))
            self._faces[ref.id] = cached
        return sorted(cached[0]), list(cached[1]), list(cached[2])

    def _type_label(self, ref: Ref) -> str:
        types = self.types(ref)
        return types[0] if len(types) == 1 else "+".join(types) or f"#{ref.id}?"

    def _collect(self, eid: int, seen: set[int], found: set[int], others: list[Ref]) -> None:
        if eid in seen:
            return
        seen.add(eid)
        ent = self.get(Ref(eid))
        if ent is None:
            return
        types = set(ent.types)
        # a dimension: the faces of what it applies to
        size = self.params_of(ent, SIZE_TYPES)
        if size is not None and size:
            for r in _refs(size[0]):
                self._collect(r.id, seen, found, others)
            return
        loc = self.params_of(ent, LOCATION_TYPES)
        if loc is not None and len(loc) >= 4:
            for r in _refs(loc[2:4]):
                self._collect(r.id, seen, found, others)
            return
        is_datum = bool(types & _DATUM_TYPES)
        is_target = bool(types & _TARGET_TYPES)
        for src in self.m.referrers(eid):
            stypes = self.types(src)
            if len(stypes) != 1:
                continue
            stype = stypes[0]
            if stype in _USAGE_TYPES:
                p = self.get(Ref(src)).params
                if len(p) >= 5 and p[2] == Ref(eid):
                    self._items(p[4], found, others)
            elif stype in _PART_OF_TYPES:
                p = self.get(Ref(src)).params
                if len(p) < 4:
                    continue
                if p[2] == Ref(eid) and isinstance(p[3], Ref):
                    # whole -> part; never from a feature into the datum it establishes
                    if not set(self.types(p[3])) & _DATUM_TYPES:
                        self._collect(p[3].id, seen, found, others)
                elif is_datum and p[3] == Ref(eid) and isinstance(p[2], Ref):
                    # datum <- datum feature / datum target
                    self._collect(p[2].id, seen, found, others)
            elif stype == "FEATURE_FOR_DATUM_TARGET_RELATIONSHIP" and is_target:
                p = self.get(Ref(src)).params
                if len(p) >= 4 and p[3] == Ref(eid) and isinstance(p[2], Ref):
                    self._collect(p[2].id, seen, found, others)
        if is_target and not found and not others:
            # a target without feature geometry: its placement (SHAPE_DEFINITION_REPRESENTATION
            # of the target, item 'orientation') lies on the target face
            others.extend(self._target_placements(eid))

    def _target_placements(self, eid: int) -> list[Ref]:
        out = []
        for pd in self.referrers_with(eid, ("PROPERTY_DEFINITION",)):
            for sdr in self.referrers_with(pd.id, ("SHAPE_DEFINITION_REPRESENTATION",)):
                rep = self.get(sdr.params[1]) if len(sdr.params) >= 2 else None
                if rep is None or rep.parts is not None or len(rep.params) < 2:
                    continue
                for item in _refs(rep.params[1]):
                    if "AXIS2_PLACEMENT_3D" in self.types(item):
                        out.append(item)
        return out

    def _items(self, value: object, found: set[int], others: list[Ref]) -> None:
        """Add the faces among identified items (one item or a list); keep the rest."""
        for r in _refs(value):
            types = self.types(r)
            if FACE_TYPES.intersection(types):
                found.add(r.id)
            elif _SHELL_TYPES.intersection(types) or _SOLID_TYPES.intersection(types):
                self._shell_faces(r, found)
            else:
                others.append(r)

    def _shell_faces(self, ref: Ref, found: set[int]) -> None:
        ent = self.get(ref)
        if ent is None:
            return
        if _SOLID_TYPES.intersection(ent.types):
            p = self.params_of(ent, _SOLID_TYPES)
            for r in _refs(p[1:2] if p else ()):
                self._shell_faces(r, found)
            return
        p = self.params_of(ent, _SHELL_TYPES)
        for r in _refs(p[1:] if p else ()):
            if FACE_TYPES.intersection(self.types(r)):
                found.add(r.id)

    # ---- datums -------------------------------------------------------------------------
    def datum_label(self, ref: object) -> tuple[str, list[int], list[str]]:
        """Label, datum ids and per-element modifiers of a datum or a common datum."""
        ent = self.get(ref)
        if ent is None:
            return "?", [], []
        if ent.has("DATUM"):
            p = ent.part("DATUM")
            return (_text(p[4]) if len(p) >= 5 else "?") or "?", [ent.id], []
        if ent.has("DATUM_REFERENCE_ELEMENT"):
            p = ent.part("DATUM_REFERENCE_ELEMENT")
            label, ids, mods = self._base_label(p[4] if len(p) >= 5 else None)
            return label, ids, mods + self._modifiers(p[5] if len(p) >= 6 else None)
        return "?", [], []

    def _base_label(self, base: object) -> tuple[str, list[int], list[str]]:
        """``datum_or_common_datum``: a DATUM, or a COMMON_DATUM_LIST of elements."""
        if isinstance(base, Ref):
            return self.datum_label(base)
        labels, ids, mods = [], [], []
        for r in _refs(base):
            lab, i, m = self.datum_label(r)
            labels.append(lab)
            ids.extend(i)
            mods.extend(m)
        return ("-".join(labels) or "?"), ids, mods

    def _modifiers(self, value: object) -> list[str]:
        """Datum reference modifiers: simple enumerations or DATUM_REFERENCE_MODIFIER_WITH_VALUE."""
        out = _enum_names(value)
        for r in _refs(value):
            ent = self.get(r)
            p = ent.part("DATUM_REFERENCE_MODIFIER_WITH_VALUE") if ent else None
            if p and len(p) >= 2:
                name = p[0].name.lower() if isinstance(p[0], Enum) else "modifier"
                meas = self.measure(p[1])
                unit = "mm" if meas.kind == "length" else "deg" if meas.kind == "angle" else ""
                val = _fmt(meas.value) if meas.value is not None else meas.text
                out.append(f"{name} {val} {unit}".strip())
        return out

    def datum_system(self, refs: object, problems: list[str]) -> list[DatumRef]:
        """Datum reference frame of a tolerance from its datum_system attribute."""
        out: list[DatumRef] = []
        for ref in _refs(refs):
            ent = self.get(ref)
            if ent is None:
                problems.append(f"datum system #{ref.id} not found")
                continue
            if ent.has("DATUM_SYSTEM"):
                p = ent.part("DATUM_SYSTEM")
                for prec, comp in enumerate(_refs(p[4] if len(p) >= 5 else ()), start=1):
                    cent = self.get(comp)
                    cp = self.params_of(cent, ("DATUM_REFERENCE_COMPARTMENT",)) if cent else None
                    if not cp or len(cp) < 5:
                        problems.append(f"#{comp.id}: not a DATUM_REFERENCE_COMPARTMENT")
                        continue
                    label, ids, mods = self._base_label(cp[4])
                    mods = mods + self._modifiers(cp[5] if len(cp) >= 6 else None)
                    out.append(DatumRef(label, prec, list(dict.fromkeys(mods)), ids))
            elif ent.has("DATUM_REFERENCE") or ent.has("REFERENCED_MODIFIED_DATUM"):
                p = self.params_of(ent, ("REFERENCED_MODIFIED_DATUM", "DATUM_REFERENCE"))
                prec = p[0] if p and isinstance(p[0], int) else 0
                label, ids, _ = self.datum_label(p[1] if p and len(p) >= 2 else None)
                mods = _enum_names(p[2]) if p and len(p) >= 3 else []
                out.append(DatumRef(label, prec, mods, ids))
            elif ent.has("DATUM_REFERENCE_COMPARTMENT"):  # a compartment given directly
                cp = ent.part("DATUM_REFERENCE_COMPARTMENT")
                label, ids, mods = self._base_label(cp[4] if len(cp) >= 5 else None)
                mods = mods + self._modifiers(cp[5] if len(cp) >= 6 else None)
                out.append(DatumRef(label, len(out) + 1, mods, ids))
            else:
                problems.append(f"#{ref.id}: datum reference {ent.types} not understood")
        out.sort(key=lambda d: d.precedence)
        return out

    def datums(self) -> list[Datum]:
        """Every DATUM with the faces of its features and its target names."""
        out = []
        for ent in self.m.by_type("DATUM"):
            p = ent.part("DATUM") or ()
            label = _text(p[4]) if len(p) >= 5 else ""
            problems: list[str] = []
            if not label:
                problems.append(f"#{ent.id}: datum without identification")
            targets, features = [], []
            for rel in self.referrers_with(ent.id, ("SHAPE_ASPECT_RELATIONSHIP",)):
                rp = rel.params
                if len(rp) >= 4 and rp[3] == Ref(ent.id) and isinstance(rp[2], Ref):
                    features.append(rp[2].id)
                    src = self.get(rp[2])
                    tp = self.params_of(src, _TARGET_TYPES) if src else None
                    if tp is not None:
                        tid = _text(tp[4]) if len(tp) >= 5 else ""
                        targets.append(f"{label}{tid}")
            faces, notes, face_notes = self.faces(Ref(ent.id))
            problems.extend(notes)
            out.append(
                Datum(
                    step_id=ent.id,
                    label=label,
                    face_step_ids=faces,
                    targets=sorted(set(targets), key=_natural),
                    problems=problems,
                    feature_step_ids=_sorted_unique(features),
                    face_notes=face_notes,
                )
            )
        return out

    # ---- geometric tolerances -----------------------------------------------------------
    def tolerances(self) -> list[GeometricTolerance]:
        ids: set[int] = set()
        for t in _GT_ANY:
            ids.update(e.id for e in self.m.by_type(t))
        composite: dict[int, list[int]] = {}
        for rel in self.m.by_type("GEOMETRIC_TOLERANCE_RELATIONSHIP"):
            p = rel.params
            if (
                len(p) >= 4
                and _text(p[0]).strip().lower() == "composite"
                and isinstance(p[2], Ref)
                and isinstance(p[3], Ref)
            ):
                composite.setdefault(p[2].id, []).append(p[3].id)
                composite.setdefault(p[3].id, []).append(p[2].id)
        out = []
        for eid in sorted(ids):
            ent = self.get(Ref(eid))
            if ent is None:
                continue
            gt = self._tolerance(ent)
            gt.composite_with = composite.get(eid, [])
            out.append(gt)
        return out

    def _tolerance(self, ent: Entity) -> GeometricTolerance:
        problems: list[str] = []
        kinds = [GT_TYPES[t] for t in ent.types if t in GT_TYPES]
        gtype = kinds[0] if kinds else "unknown"
        if not kinds:
            problems.append(f"#{ent.id}: no tolerance characteristic ({', '.join(ent.types)})")
        elif len(set(kinds)) > 1:
            problems.append(f"#{ent.id}: several characteristics {kinds}")
        if ent.parts is None:  # simple instance: GEOMETRIC_TOLERANCE attributes come first
            base = ent.params
            extra = ent.params[4:]
        else:
            base = ent.part("GEOMETRIC_TOLERANCE") or ()
            extra = ()
        name = _text(base[0]) if base else ""
        value, value_text = None, ""
        if len(base) >= 3:
            meas = self.measure(base[2], expect="length")
            value, value_text = meas.value, meas.text
            problems.extend(meas.problems)
            if meas.kind != "length" and value is not None:
                value = None
                problems.append(f"#{ent.id}: magnitude is not a length ({meas.text})")
        else:
            problems.append(f"#{ent.id}: no magnitude attribute")
        tsa = base[3] if len(base) >= 4 else None

        # datum reference frame
        drf = ent.part("GEOMETRIC_TOLERANCE_WITH_DATUM_REFERENCE")
        if drf is None and extra and _refs(extra[0]):
            drf = (extra[0],)
        datums = self.datum_system(drf[0], problems) if drf else []

        # modifiers
        modifiers: list[str] = []
        p = ent.part("GEOMETRIC_TOLERANCE_WITH_MODIFIERS")
        if p is not None:
            modifiers += _enum_names(p[-1] if ent.parts is None else p[0] if p else ())
        p = ent.part("MODIFIED_GEOMETRIC_TOLERANCE")
        if p:
            modifiers += _enum_names(p[-1])
        tsa_ent = self.get(tsa)
        if tsa_ent is not None:
            if tsa_ent.has("ALL_AROUND_SHAPE_ASPECT"):
                modifiers.append("all_around")
            if tsa_ent.has("BETWEEN_SHAPE_ASPECT"):
                modifiers.append("between")
            if tsa_ent.has("ALL_OVER_SHAPE_ASPECT") or tsa_ent.has("CONTINUOUS_SHAPE_ASPECT"):
                modifiers.append(
                    "all_over" if tsa_ent.has("ALL_OVER_SHAPE_ASPECT") else "continuous_feature"
                )

        unequal = self._optional_length(ent, "UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE", problems)
        max_value = self._optional_length(
            ent, "GEOMETRIC_TOLERANCE_WITH_MAXIMUM_TOLERANCE", problems
        )
        unit_basis = self._unit_basis(ent, problems)

        # tolerance zone
        zone_form = None
        for zone in self.referrers_with(ent.id, ("TOLERANCE_ZONE",)):
            zp = zone.part("TOLERANCE_ZONE")
            if zp and len(zp) >= 6:
                form = self.get(zp[5])
                fp = form.part("TOLERANCE_ZONE_FORM") if form else None
                if fp:
                    zone_form = _text(fp[0]) or None
            for zdef in self.referrers_with(zone.id, ("PROJECTED_ZONE_DEFINITION",)):
                zdp = zdef.part("PROJECTED_ZONE_DEFINITION")
                length = self.measure(zdp[-1]).value if zdp else None
                modifiers.append(
                    f"projected {_fmt(length)} mm" if length is not None else "projected"
                )

        faces: list[int] = []
        face_notes: list[str] = []
        if tsa_ent is None:
            problems.append(f"#{ent.id}: no toleranced shape aspect")
        else:
            faces, notes, face_notes = self.faces(tsa)
            problems.extend(notes)
        if value is None and not any("magnitude" in s or "unit" in s for s in problems):
            problems.append(f"#{ent.id}: magnitude not established")
        return GeometricTolerance(
            step_id=ent.id,
            name=name,
            type=gtype,
            value=value,
            value_text=value_text,
            zone_form=zone_form,
            modifiers=list(dict.fromkeys(modifiers)),
            unequal_displacement=unequal,
            max_value=max_value,
            unit_basis=unit_basis,
            datums=datums,
            face_step_ids=faces,
            problems=problems,
            shape_aspect_step_id=tsa.id if isinstance(tsa, Ref) else None,
            face_notes=face_notes,
        )

    def _optional_length(self, ent: Entity, part: str, problems: list[str]) -> float | None:
        p = ent.part(part)
        if not p:
            return None
        meas = self.measure(p[0], expect="length")
        problems.extend(meas.problems)
        return meas.value

    def _unit_basis(self, ent: Entity, problems: list[str]) -> str | None:
        unit_p = ent.part("GEOMETRIC_TOLERANCE_WITH_DEFINED_UNIT")
        if not unit_p:
            return None
        size = self.measure(unit_p[0], expect="length")
        problems.extend(size.problems)
        first = f"{_fmt(size.value)} mm" if size.value is not None else size.text
        area_p = ent.part("GEOMETRIC_TOLERANCE_WITH_DEFINED_AREA_UNIT")
        if not area_p:
            return f"per unit length {first}"
        area = area_p[0].name.lower() if area_p and isinstance(area_p[0], Enum) else "area"
        second = None
        if len(area_p) >= 2 and isinstance(area_p[1], Ref):
            sm = self.measure(area_p[1], expect="length")
            problems.extend(sm.problems)
            second = f"{_fmt(sm.value)} mm" if sm.value is not None else sm.text
        text = f"per {area} area {first}"
        return f"{text} x {second}" if second else text

    # ---- dimensions ---------------------------------------------------------------------
    def dimensions(self) -> list[Dimension]:
        ids: set[int] = set()
        for t in (*SIZE_TYPES, *LOCATION_TYPES):
            ids.update(e.id for e in self.m.by_type(t))
        out = []
        for eid in sorted(ids):
            ent = self.get(Ref(eid))
            if ent is not None:
                out.append(self._dimension(ent))
        return out

    def _dimension(self, ent: Entity) -> Dimension:
        problems: list[str] = []
        size = self.params_of(ent, SIZE_TYPES)
        angular = ent.has("ANGULAR_SIZE") or ent.has("ANGULAR_LOCATION")
        origin: list[int] = []
        target: list[int] = []
        if size is not None:
            kind = "size"
            name = _text(size[1]) if len(size) >= 2 else ""
            faces, notes, face_notes = self.faces(size[0] if size else None)
        else:
            kind = "location"
            loc = self.params_of(ent, LOCATION_TYPES) or ()
            name = _text(loc[0]) if loc else ""
            origin, n1, f1 = self.faces(loc[2] if len(loc) >= 3 else None)
            target, n2, f2 = self.faces(loc[3] if len(loc) >= 4 else None)
            faces, notes = _sorted_unique(origin + target), []
            face_notes = [f"origin: {n}" for n in f1] + [f"target: {n}" for n in f2]
            if not origin or not target:
                problems.extend(
                    f"{end} end: {n}"
                    for end, ids_, ns in (("origin", origin, n1), ("target", target, n2))
                    if not ids_
                    for n in ns
                )
        dtype = name.strip().lower() or ("angle" if angular else kind)
        unit = "deg" if angular else "mm"
        expect = "angle" if angular else "length"
        dim = Dimension(
            step_id=ent.id, name=name, kind=kind, type=dtype, unit=unit,
            face_step_ids=faces, problems=problems,
            origin_face_step_ids=origin, target_face_step_ids=target, face_notes=face_notes,
        )  # fmt: skip
        if "diameter" in dtype:
            dim.qualifiers.append("diameter")
        elif "radius" in dtype:
            dim.qualifiers.append("radius")

        # values
        texts = []
        reps = self.referrers_with(ent.id, ("DIMENSIONAL_CHARACTERISTIC_REPRESENTATION",))
        for dcr in reps:
            dp = dcr.params
            if len(dp) < 2 or dp[0] != Ref(ent.id):
                continue
            rep = self.get(dp[1])
            rp = rep.params if rep is not None and rep.parts is None else None
            if not rp or len(rp) < 2:
                problems.append(f"#{dcr.id}: no dimension representation")
                continue
            for item_ref in self._flat_items(rp[1]):
                self._dimension_item(item_ref, dim, expect, texts)
        if not reps:
            problems.append(f"#{ent.id}: no DIMENSIONAL_CHARACTERISTIC_REPRESENTATION")
        dim.value_text = "; ".join(texts)

        # tolerance
        for pmt in self.referrers_with(ent.id, ("PLUS_MINUS_TOLERANCE",)):
            pp = pmt.params
            if len(pp) < 2 or pp[1] != Ref(ent.id):
                continue
            rng = self.get(pp[0])
            if rng is None:
                problems.append(f"#{pmt.id}: tolerance range not found")
            elif rng.has("TOLERANCE_VALUE"):
                tp = rng.part("TOLERANCE_VALUE")
                lo = self.measure(tp[0], expect=expect)
                hi = self.measure(tp[1], expect=expect) if len(tp) >= 2 else None
                problems.extend(lo.problems + (hi.problems if hi else []))
                dim.lower = lo.value
                dim.upper = hi.value if hi else None
                if dim.lower is not None and dim.upper is not None and dim.lower > dim.upper:
                    problems.append(f"#{rng.id}: lower bound above upper bound")
            elif rng.has("LIMITS_AND_FITS"):
                lp = rng.part("LIMITS_AND_FITS")
                dim.fit = "".join(_text(x).strip() for x in lp[:3]) or None
                if dim.fit is None:
                    problems.append(f"#{rng.id}: empty LIMITS_AND_FITS")
            else:
                problems.append(f"#{rng.id}: tolerance range {rng.types} not understood")
        if not faces:
            problems.extend(n for n in notes if n not in problems)
        if dim.nominal is None and dim.lower_limit is None and dim.upper_limit is None:
            problems.append(f"#{ent.id}: no value found")
        dim.qualifiers = list(dict.fromkeys(dim.qualifiers))
        return dim

    def _flat_items(self, items: object) -> list[Ref]:
        """Representation items, expanding COMPOUND_REPRESENTATION_ITEM sets and lists."""
        out: list[Ref] = []
        for r in _refs(items):
            ent = self.get(r)
            if ent is not None and ent.has("COMPOUND_REPRESENTATION_ITEM"):
                p = ent.part("COMPOUND_REPRESENTATION_ITEM")
                out.extend(self._flat_items(p[1:] if p else ()))
            else:
                out.append(r)
        return out

    def _dimension_item(self, ref: Ref, dim: Dimension, expect: str, texts: list[str]) -> None:
        ent = self.get(ref)
        if ent is None:
            return
        if ent.has("DESCRIPTIVE_REPRESENTATION_ITEM"):
            p = ent.part("DESCRIPTIVE_REPRESENTATION_ITEM")
            if p and len(p) >= 2 and _text(p[0]).lower() == "dimensional note":
                note = _text(p[1]).strip().lower()
                dim.qualifiers.append(_NOTES.get(note, note))
            return
        if not (ent.has("MEASURE_REPRESENTATION_ITEM") or ent.has("MEASURE_WITH_UNIT")):
            return
        name = self.item_name(ent).strip().lower()
        meas = self.measure(ref, expect=expect)
        dim.problems.extend(meas.problems)
        for q in _refs(ent.part("QUALIFIED_REPRESENTATION_ITEM") or ()):
            qent = self.get(q)
            if qent is None:
                continue
            qp = qent.params if qent.parts is None else ()
            if qent.has("VALUE_FORMAT_TYPE_QUALIFIER") and qp:
                if name in ("nominal value", "") and dim.value_format is None:
                    dim.value_format = _text(qp[0]) or None
            elif qent.has("TYPE_QUALIFIER") and qp:
                dim.qualifiers.append(_text(qp[0]).strip().lower())
        if name == "nominal value" or (name == "" and dim.nominal is None):
            if name == "":
                dim.problems.append(f"#{ent.id}: unnamed measure taken as the nominal value")
            dim.nominal = meas.value
            texts.append(meas.text)
        elif name == "lower limit":
            dim.lower_limit = meas.value
            texts.append(f"lower limit {meas.text}")
        elif name == "upper limit":
            dim.upper_limit = meas.value
            texts.append(f"upper limit {meas.text}")
        else:
            dim.problems.append(f"#{ent.id}: measure {name!r} not understood ({meas.text})")

    # ---- context ------------------------------------------------------------------------
    def context_units(self) -> None:
        """Length and angle units of the shape's representation context."""
        contexts = self.m.by_type("GLOBAL_UNIT_ASSIGNED_CONTEXT")
        chosen = None
        for t in (
            "ADVANCED_BREP_SHAPE_REPRESENTATION",
            "MANIFOLD_SURFACE_SHAPE_REPRESENTATION",
            "SHAPE_REPRESENTATION",
        ):
            for rep in self.m.by_type(t):
                p = rep.part(t)
                ctx = self.get(p[2]) if p and len(p) >= 3 else None
                if ctx is not None and ctx.has("GLOBAL_UNIT_ASSIGNED_CONTEXT"):
                    chosen = ctx
                    break
            if chosen:
                break
        if chosen is None and contexts:
            chosen = contexts[0]
        if chosen is None:
            self.problems.append("no GLOBAL_UNIT_ASSIGNED_CONTEXT: millimetres assumed")
            return
        for r in _refs(chosen.part("GLOBAL_UNIT_ASSIGNED_CONTEXT")):
            u = self.unit(r)
            if u.kind == "length" and u.scale is not None:
                self.context_length = u
            elif u.kind == "angle" and u.scale is not None:
                self.context_angle = u
        if self.context_length.text.endswith("(assumed)"):
            self.problems.append(f"#{chosen.id}: no length unit in context: millimetres assumed")


# --------------------------------------------------------------------------------------------
# geometry: faces of non-topological associated geometry
# --------------------------------------------------------------------------------------------

_ROTATIONAL = ("cylinder", "cone", "sphere", "torus")
_ANGLE_STEP = math.radians(10.0)  # arc sampling step
_SPLINE_SAMPLES = 24
_LINE_SAMPLES = 9  # so that a line target whose ends touch face boundaries has inner samples


@dataclass
class _Piece:
    """Sample points of one geometric item, with its axis when it is a circle or a line."""

    points: np.ndarray  # (k, 3)
    circle: tuple[np.ndarray, np.ndarray, float] | None = None  # centre, normal, radius
    line: tuple[np.ndarray, np.ndarray] | None = None  # point, unit direction


@dataclass
class _Surface:
    """An analytic face surface in the shape's length unit."""

    face: int
    kind: str  # 'plane', 'cylinder', 'cone', 'sphere', 'torus' or 'other'
    origin: np.ndarray
    z: np.ndarray
    x: np.ndarray
    radius: float = 0.0
    minor: float = 0.0
    semi_angle: float = 0.0
    same_sense: bool = True

    @property
    def y(self) -> np.ndarray:
        return np.cross(self.z, self.x)

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance of points ``p`` (k, 3) to the (untrimmed) surface."""
        d = p - self.origin
        h = d @ self.z
        if self.kind == "plane":
            return np.abs(h)
        rho = np.linalg.norm(d - np.outer(h, self.z), axis=1)
        if self.kind == "cylinder":
            return np.abs(rho - self.radius)
        if self.kind == "cone":
            t = math.tan(self.semi_angle)
            return np.abs(rho - self.radius - h * t) * math.cos(self.semi_angle)
        if self.kind == "sphere":
            return np.abs(np.linalg.norm(d, axis=1) - self.radius)
        if self.kind == "torus":
            return np.abs(np.hypot(rho - self.radius, h) - self.minor)
        return np.full(len(p), np.inf)

    def uv(self, p: np.ndarray) -> np.ndarray:
        """Surface coordinates (u periodic in radians for rotational surfaces)."""
        d = p - self.origin
        a, b, h = d @ self.x, d @ self.y, d @ self.z
        if self.kind == "plane":
            return np.column_stack([a, b])
        u = np.arctan2(b, a)
        if self.kind == "sphere":
            r = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
            return np.column_stack([u, np.arcsin(np.clip(h / r, -1.0, 1.0))])
        return np.column_stack([u, h])

    def radius_at(self, h: float) -> float:
        if self.kind == "cone":
            return self.radius + h * math.tan(self.semi_angle)
        return self.radius


def _crossings(uv: np.ndarray, segments: list[np.ndarray], periodic: bool) -> np.ndarray:
    """Even-odd count of boundary crossings of the rays from ``uv`` towards +v."""
    count = np.zeros(len(uv), dtype=int)
    for seg in segments:
        if len(seg) < 2:
            continue
        u1, v1 = seg[:-1, 0], seg[:-1, 1]
        u2, v2 = seg[1:, 0], seg[1:, 1]
        du = u2 - u1
        if periodic:
            du = (du + math.pi) % (2.0 * math.pi) - math.pi
        lo_u = np.where(du >= 0, u1, u1 + du)  # start of the span in increasing u
        span = np.abs(du)
        keep = span > 1e-15
        lo_u, span = lo_u[keep], span[keep]
        lo_v = np.where(du >= 0, v1, v2)[keep]
        hi_v = np.where(du >= 0, v2, v1)[keep]
        for i, (pu, pv) in enumerate(uv):
            a = pu - lo_u
            if periodic:
                a = a % (2.0 * math.pi)
            inside = (a >= 0) & (a < span)
            if not inside.any():
                continue
            t = a[inside] / span[inside]
            v = lo_v[inside] + t * (hi_v[inside] - lo_v[inside])
            count[i] += int(np.count_nonzero(v > pv))
    return count % 2 == 1


def _segment_distance(p: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` (k, 3) to a 3D polyline (m, 3)."""
    if len(polyline) == 1:
        return np.linalg.norm(p - polyline[0], axis=1)
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.clip(np.einsum("kij,ij->ki", p[:, None, :] - a[None], ab) / L2, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


class _Geometry:
    """Locates the faces carrying (or coaxial with) points and curves of supplemental geometry.

    AP242 files often associate datum targets, axes, thread cylinders or dimension origins
    with geometry that is not a face: isolated CARTESIAN_POINTs, TRIMMED_CURVEs,
    COMPOSITE_CURVEs, GEOMETRIC_CURVE_SETs, EDGE_CURVEs. This class maps them to faces:

    * an EDGE_CURVE to the faces it bounds (for a circular edge only the coaxial rotational
      faces, i.e. the hole or boss rather than the surrounding plane);
    * any other item is sampled; a face *carries* a sample when the sample lies on its
      surface within ``tol`` and inside its boundary (even-odd ray test in surface
      coordinates, or within ``tol`` of the boundary);
    * a circle or line that no face carries is matched to the rotational faces (cylinder,
      cone, sphere, torus) whose axis it shares: a circle centred on the axis, a line on it.

    Coordinates are those of the shape representation (file length unit); supplemental
    geometry is assumed to share the coordinate system of the B-rep (true for single parts).
    """

    def __init__(self, reader: _Reader) -> None:
        self.r = reader
        self.m = reader.m
        self.angle_rad = math.radians(reader.context_angle.scale or 180.0 / math.pi)
        self._surfaces: dict[int, _Surface | None] = {}
        self._boundary: dict[int, list[np.ndarray]] = {}
        self._edge_samples: dict[int, np.ndarray] = {}
        self._all_faces: list[int] | None = None
        pts = [self.point(v.params[1]) for v in self.m.by_type("VERTEX_POINT")]
        pts = [p for p in pts if p is not None]
        diag = float(np.ptp(np.array(pts), axis=0).max()) * math.sqrt(3) if pts else 1.0
        #: on-surface / on-axis tolerance, in the file's length unit
        self.tol = max(diag * 1e-5, 1e-9)
        self.diag = diag

    # ---- primitives ---------------------------------------------------------------------
    def point(self, ref: object) -> np.ndarray | None:
        ent = self.r.get(ref)
        if ent is None:
            return None
        if ent.has("CARTESIAN_POINT"):
            coords = ent.part("CARTESIAN_POINT")[1]
            vals = [float(c) for c in coords] + [0.0] * (3 - len(coords))
            return np.array(vals[:3])
        if ent.has("VERTEX_POINT"):
            return self.point(ent.part("VERTEX_POINT")[1])
        return None

    def direction(self, ref: object, default: tuple = (0.0, 0.0, 1.0)) -> np.ndarray:
        ent = self.r.get(ref)
        if ent is not None and ent.has("VECTOR"):
            return self.direction(ent.part("VECTOR")[1], default)
        if ent is not None and ent.has("DIRECTION"):
            vals = [float(c) for c in ent.part("DIRECTION")[1]] + [0.0] * 3
            v = np.array(vals[:3])
        else:
            v = np.array(default, dtype=float)
        n = np.linalg.norm(v)
        return v / n if n > 0 else np.array(default, dtype=float)

    def placement(self, ref: object) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Origin, z and x axes of an AXIS2_PLACEMENT_3D (x made orthogonal to z)."""
        ent = self.r.get(ref)
        if ent is None or not (ent.has("AXIS2_PLACEMENT_3D") or ent.has("AXIS2_PLACEMENT_2D")):
            return None
        p = ent.params
        origin = self.point(p[1])
        if origin is None:
            return None
        z = self.direction(p[2]) if len(p) >= 4 else np.array([0.0, 0.0, 1.0])
        x = self.direction(p[-1], (1.0, 0.0, 0.0)) if len(p) >= 3 else np.array([1.0, 0, 0])
        x = x - (x @ z) * z
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        return origin, z, x / np.linalg.norm(x)

    # ---- curves -------------------------------------------------------------------------
    def _conic(self, ent: Entity) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        p = ent.params
        pl = self.placement(p[1])
        if pl is None:
            raise ValueError(f"#{ent.id}: no placement")
        a = float(p[2])
        b = float(p[3]) if ent.has("ELLIPSE") and len(p) >= 4 else a
        return pl[0], pl[1], pl[2], a, b

    def _conic_points(self, conic: tuple, t0: float, t1: float) -> np.ndarray:
        c, z, x, a, b = conic
        y = np.cross(z, x)
        n = max(2, int(math.ceil(abs(t1 - t0) / _ANGLE_STEP)) + 1)
        t = np.linspace(t0, t1, n)
        return c + np.outer(a * np.cos(t), x) + np.outer(b * np.sin(t), y)

    def _conic_param(self, conic: tuple, q: np.ndarray) -> float:
        c, z, x, a, b = conic
        d = q - c
        return math.atan2((d @ np.cross(z, x)) / b, (d @ x) / a)

    def _spline(self, ent: Entity, n: int = _SPLINE_SAMPLES) -> np.ndarray:
        """Sample a (rational) B_SPLINE_CURVE_WITH_KNOTS over its whole parameter range."""
        base = ent.part("B_SPLINE_CURVE") or ent.part("B_SPLINE_CURVE_WITH_KNOTS")
        if ent.parts is None:  # simple: name, degree, points, form, closed, si, mults, knots
            degree, pts = int(base[1]), base[2]
            mults, knots = base[6], base[7]
            weights = None
        else:
            degree, pts = int(base[1]), base[2]
            kp = ent.part("B_SPLINE_CURVE_WITH_KNOTS")
            mults, knots = kp[0], kp[1]
            wp = ent.part("RATIONAL_B_SPLINE_CURVE")
            weights = np.array([float(w) for w in wp[0]]) if wp else None
        ctrl = np.array([self.point(r) for r in _refs(pts)], dtype=float)
        kv = np.repeat(np.array([float(k) for k in knots]), [int(m) for m in mults])
        if weights is not None and len(weights) == len(ctrl):
            ctrl = np.column_stack([ctrl * weights[:, None], weights])
        t = np.linspace(kv[degree], kv[len(kv) - degree - 1], n)
        out = np.array([_de_boor(degree, kv, ctrl, ti) for ti in t])
        if out.shape[1] == 4:
            out = out[:, :3] / out[:, 3:4]
        return out

    def curve(self, ref: object, trims: tuple[object, object] | None = None, sense: bool = True,
              ends: tuple[np.ndarray, np.ndarray] | None = None) -> _Piece | None:  # fmt: skip
        """Sample a curve, optionally trimmed by parameters or points (TRIMMED_CURVE)."""
        ent = self.r.get(ref)
        if ent is None:
            return None
        if ent.has("LINE"):
            p = ent.params
            q = self.point(p[1])
            vec = self.r.get(p[2])
            d = self.direction(p[2])
            mag = float(vec.params[2]) if vec is not None and vec.has("VECTOR") else 1.0
            if ends is not None:
                a, b = ends
            elif trims is not None:
                t0, t1 = (self._trim_param(tr, lambda x: float((x - q) @ d) / mag) for tr in trims)
                a, b = q + t0 * mag * d, q + t1 * mag * d
            else:
                a, b = q, q + mag * d
            pts = a + np.outer(np.linspace(0.0, 1.0, _LINE_SAMPLES), b - a)
            return _Piece(pts, line=(q, d))
        if ent.has("CIRCLE") or ent.has("ELLIPSE"):
            conic = self._conic(ent)
            if ends is not None:
                t0, t1 = (self._conic_param(conic, e) for e in ends)
                same = np.linalg.norm(ends[0] - ends[1]) < self.tol
            elif trims is not None:
                t0, t1 = (
                    self._trim_param(tr, lambda x: self._conic_param(conic, x), angle=True)
                    for tr in trims
                )
                same = False
            else:
                t0, t1, same = 0.0, 2.0 * math.pi, False
            if not sense:
                t0, t1 = t1, t0
            if same:
                t1 = t0 + 2.0 * math.pi
            else:
                while t1 <= t0 + 1e-12:
                    t1 += 2.0 * math.pi
                while t1 - t0 > 2.0 * math.pi + 1e-9:
                    t1 -= 2.0 * math.pi
            circle = (conic[0], conic[1], conic[3]) if conic[3] == conic[4] else None
            return _Piece(self._conic_points(conic, t0, t1), circle=circle)
        if ent.has("TRIMMED_CURVE"):
            p = ent.params
            return self.curve(
                p[1], (p[2], p[3]), bool(p[4].value) if isinstance(p[4], Enum) else True
            )
        if ent.has("B_SPLINE_CURVE_WITH_KNOTS"):
            pts = self._spline(ent)
            if ends is not None:
                i0 = int(np.argmin(np.linalg.norm(pts - ends[0], axis=1)))
                i1 = int(np.argmin(np.linalg.norm(pts - ends[1], axis=1)))
                if i0 != i1:
                    lo, hi = sorted((i0, i1))
                    pts = pts[lo : hi + 1]
            return _Piece(pts)
        if ent.has("SURFACE_CURVE") or ent.has("SEAM_CURVE") or ent.has("INTERSECTION_CURVE"):
            return self.curve(ent.params[1], trims, sense, ends)
        if ent.has("POLYLINE"):
            pts = [self.point(r) for r in _refs(ent.params[1])]
            return _Piece(np.array([q for q in pts if q is not None]))
        return None

    def _trim_param(self, trim: object, project, angle: bool = False) -> float:
        """A trimming select: PARAMETER_VALUE (preferred) or a CARTESIAN_POINT."""
        items = trim if isinstance(trim, tuple) and not isinstance(trim, Typed) else (trim,)
        for it in items:
            if isinstance(it, Typed) and it.type == "PARAMETER_VALUE":
                v = float(_unwrap(it)[0])
                return v * self.angle_rad if angle else v
        for it in items:
            q = self.point(it)
            if q is not None:
                return project(q)
        raise ValueError("no trimming value")

    def pieces(self, ref: Ref) -> list[_Piece]:
        """Sample an identified item (point, curve, curve set, placement)."""
        ent = self.r.get(ref)
        if ent is None:
            return []
        if ent.has("CARTESIAN_POINT") or ent.has("VERTEX_POINT"):
            q = self.point(ref)
            return [_Piece(q[None, :])] if q is not None else []
        if ent.has("AXIS2_PLACEMENT_3D"):
            pl = self.placement(ref)
            return [_Piece(pl[0][None, :])] if pl else []
        if ent.has("GEOMETRIC_CURVE_SET") or ent.has("GEOMETRIC_SET"):
            out = []
            for r in _refs(ent.params[1]):
                out.extend(self.pieces(r))
            return out
        if ent.has("COMPOSITE_CURVE"):
            out = []
            for seg in _refs(ent.params[1]):
                s = self.r.get(seg)
                if s is not None and len(s.params) >= 3:
                    out.extend(self.pieces(s.params[2]))
            return _merge_circles(out)
        if ent.has("EDGE_CURVE"):
            p = ent.params
            a, b = self.point(p[1]), self.point(p[2])
            ends = (a, b) if a is not None and b is not None else None
            piece = self.curve(p[3], sense=bool(p[4].value), ends=ends)
            return [piece] if piece is not None else []
        try:
            piece = self.curve(ref)
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("geometry #%d not sampled: %s", ref.id, exc)
            return []
        return [piece] if piece is not None else []

    # ---- faces --------------------------------------------------------------------------
    def surface(self, face: int) -> _Surface | None:
        if face in self._surfaces:
            return self._surfaces[face]
        s = None
        ent = self.r.get(Ref(face))
        try:
            if ent is not None and ent.has("ADVANCED_FACE"):
                p = ent.params
                s = self._make_surface(
                    face, p[2], bool(p[3].value) if isinstance(p[3], Enum) else True
                )
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("face #%d surface not understood: %s", face, exc)
        self._surfaces[face] = s
        return s

    def _make_surface(self, face: int, ref: object, same_sense: bool) -> _Surface | None:
        ent = self.r.get(ref)
        if ent is None:
            return None
        kinds = {
            "PLANE": "plane", "CYLINDRICAL_SURFACE": "cylinder", "CONICAL_SURFACE": "cone",
            "SPHERICAL_SURFACE": "sphere", "TOROIDAL_SURFACE": "torus",
        }  # fmt: skip
        kind = next((k for t, k in kinds.items() if ent.has(t)), None)
        if kind is None:
            return None
        p = ent.params
        pl = self.placement(p[1])
        if pl is None:
            return None
        s = _Surface(face, kind, pl[0], pl[1], pl[2], same_sense=same_sense)
        if kind in ("cylinder", "cone", "sphere", "torus"):
            s.radius = float(p[2])
        if kind == "cone":
            s.semi_angle = float(p[3]) * self.angle_rad
        if kind == "torus":
            s.minor = float(p[3])
        return s

    def boundary(self, face: int) -> list[np.ndarray]:
        """Sampled 3D boundary polylines of a face (one per edge or vertex loop)."""
        if face in self._boundary:
            return self._boundary[face]
        out: list[np.ndarray] = []
        ent = self.r.get(Ref(face))
        for bound in _refs(ent.params[1] if ent is not None else ()):
            b = self.r.get(bound)
            loop = self.r.get(b.params[1]) if b is not None and len(b.params) >= 2 else None
            if loop is None:
                continue
            if loop.has("VERTEX_LOOP"):
                q = self.point(loop.params[1])
                if q is not None:
                    out.append(q[None, :])
                continue
            for oe in _refs(loop.params[1] if loop.has("EDGE_LOOP") else ()):
                o = self.r.get(oe)
                if o is None or len(o.params) < 4:
                    continue
                edge = o.params[3]
                if edge.id not in self._edge_samples:
                    pieces = self.pieces(edge)
                    self._edge_samples[edge.id] = pieces[0].points if pieces else np.empty((0, 3))
                pts = self._edge_samples[edge.id]
                if len(pts):
                    out.append(pts)
        self._boundary[face] = out
        return out

    def all_faces(self) -> list[int]:
        if self._all_faces is None:
            self._all_faces = [e.id for e in self.m.by_type("ADVANCED_FACE")]
        return self._all_faces

    def carried_by(self, pts: np.ndarray) -> tuple[set[int], set[int]]:
        """Faces carrying the points: ``(strictly inside, on the boundary)``."""
        inside: set[int] = set()
        edge: set[int] = set()
        for face in self.all_faces():
            s = self.surface(face)
            if s is None:
                continue
            on = s.distance(pts) <= self.tol
            if not on.any():
                continue
            q = pts[on]
            bnd = self.boundary(face)
            if not bnd:
                continue
            near = np.zeros(len(q), dtype=bool)
            for poly in bnd:
                near |= _segment_distance(q, poly) <= self.tol
            if near.any():
                edge.add(face)
            rest = q[~near]
            if len(rest) and s.kind != "torus":
                segs = [s.uv(poly) for poly in bnd]
                if _crossings(s.uv(rest), segs, periodic=s.kind != "plane").any():
                    inside.add(face)
            elif len(rest):  # torus: no ray test; accept when inside the boundary's box
                lo = np.min([poly.min(axis=0) for poly in bnd], axis=0) - self.tol
                hi = np.max([poly.max(axis=0) for poly in bnd], axis=0) + self.tol
                if ((rest >= lo) & (rest <= hi)).all(axis=1).any():
                    inside.add(face)
        return inside, edge

    def coaxial(self, piece: _Piece) -> set[int]:
        """Rotational faces sharing the axis of a circle (or lying around an axis line)."""
        if piece.circle is not None:
            c, n, rc = piece.circle
            axis_pt, axis_dir, samples = c, n, c[None, :]
        elif piece.line is not None:
            axis_pt, axis_dir = piece.line
            samples, rc = piece.points, None
        else:
            return set()
        best: dict[int, float] = {}
        for face in self.all_faces():
            s = self.surface(face)
            if s is None or s.kind not in _ROTATIONAL:
                continue
            if np.linalg.norm(np.cross(s.z, axis_dir)) > 1e-4:
                continue
            off = axis_pt - s.origin
            if np.linalg.norm(off - (off @ s.z) * s.z) > max(self.tol, 1e-6 * self.diag) * 10:
                continue
            bnd = self.boundary(face)
            if not bnd:
                continue
            h = np.concatenate([(poly - s.origin) @ s.z for poly in bnd])
            hs = (samples - s.origin) @ s.z
            lo, hi = h.min() - 10 * self.tol, h.max() + 10 * self.tol
            if rc is not None:  # a circle: its plane must cut the face
                if not (lo <= hs[0] <= hi):
                    continue
                best[face] = abs(s.radius_at(float(hs[0])) - rc)
            else:  # an axis line: must overlap the face's axial extent substantially
                overlap = min(hi, hs.max()) - max(lo, hs.min())
                if overlap <= 0.5 * min(hi - lo, hs.max() - hs.min()):
                    continue
                best[face] = s.radius if s.kind != "sphere" else 0.0
        if not best:
            return set()
        closest = min(best.values())
        return {f for f, d in best.items() if d <= closest + 10 * self.tol}

    def edge_faces(self, edge: int) -> set[int]:
        """Faces bounded by an edge; for a circular edge only its coaxial rotational faces."""
        faces: set[int] = set()
        for oe in self.r.referrers_with(edge, ("ORIENTED_EDGE",)):
            for loop in self.r.referrers_with(oe.id, ("EDGE_LOOP",)):
                for bound in self.r.referrers_with(loop.id, ("FACE_BOUND", "FACE_OUTER_BOUND")):
                    for face in self.m.referrers(bound.id):
                        if FACE_TYPES.intersection(self.r.types(face)):
                            faces.add(face)
        pieces = self.pieces(Ref(edge))
        if faces and pieces and pieces[0].circle is not None:
            c, n, _ = pieces[0].circle
            rot = set()
            for f in faces:
                s = self.surface(f)
                if s is not None and s.kind in _ROTATIONAL:
                    off = c - s.origin
                    if (
                        np.linalg.norm(np.cross(s.z, n)) < 1e-4
                        and np.linalg.norm(off - (off @ s.z) * s.z) <= 10 * self.tol
                    ):
                        rot.add(f)
            if rot:
                return rot
        return faces

    def locate(self, ref: Ref) -> tuple[set[int], str]:
        """Faces for a non-face item and how they were found (``''`` when none)."""
        types = self.r.types(ref)
        if "EDGE_CURVE" in types:
            faces = self.edge_faces(ref.id)
            return faces, "bounded by the edge" if faces else ""
        try:
            pieces = self.pieces(ref)
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("geometry #%d not sampled: %s", ref.id, exc)
            return set(), ""
        pieces = [pc for pc in pieces if len(pc.points)]
        carried = []
        for piece in pieces:
            inside, edge = self.carried_by(piece.points)
            carried.append(inside or edge)
        if pieces and all(carried):
            return set().union(*carried), "carrying the geometry"
        # some piece floats (an axis, a thread or a centre line): the item describes a
        # feature by its axis, so the coaxial rotational faces are meant
        coaxial: set[int] = set()
        for piece in pieces:
            coaxial |= self.coaxial(piece)
        if coaxial:
            return coaxial, "coaxial with the geometry"
        found = set().union(*carried) if carried else set()
        return found, "carrying part of the geometry" if found else ""


def _merge_circles(pieces: list[_Piece]) -> list[_Piece]:
    """Arcs of one circle (a COMPOSITE_CURVE of half circles) become one piece."""
    if len(pieces) < 2 or any(p.circle is None for p in pieces):
        return pieces
    c0, n0, r0 = pieces[0].circle
    for p in pieces[1:]:
        c, n, r = p.circle
        if np.linalg.norm(c - c0) > 1e-9 * max(1.0, r0) or abs(abs(n @ n0) - 1) > 1e-9 or r != r0:
            return pieces
    return [_Piece(np.concatenate([p.points for p in pieces]), circle=pieces[0].circle)]


def _de_boor(degree: int, knots: np.ndarray, ctrl: np.ndarray, t: float) -> np.ndarray:
    """Point of a B-spline at ``t`` (de Boor); ``ctrl`` may be homogeneous."""
    n = len(ctrl)
    k = int(np.searchsorted(knots, t, side="right") - 1)
    k = min(max(k, degree), n - 1)
    d = [ctrl[j + k - degree].copy() for j in range(degree + 1)]
    for r in range(1, degree + 1):
        for j in range(degree, r - 1, -1):
            i = j + k - degree
            denom = knots[i + degree + 1 - r] - knots[i]
            alpha = 0.0 if denom == 0 else (t - knots[i]) / denom
            d[j] = (1.0 - alpha) * d[j - 1] + alpha * d[j]
    return d[degree]


def _natural(label: str) -> tuple:
    """Sort key: 'A2' before 'A10'."""
    head = label.rstrip("0123456789")
    tail = label[len(head) :]
    return head, int(tail) if tail else -1


def _count_text(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {t}" for t, n in sorted(counts.items()))


def _length_name(unit: Unit) -> str:
    if unit.scale is not None:
        for scale, name in _LENGTH_NAMES.items():
            if math.isclose(unit.scale, scale, rel_tol=_SNAP_RTOL):
                return name
    return unit.text.lower()


def pmi_from_model(model: P21Model) -> PMI:
    """Semantic PMI of a parsed Part 21 model.

    Parameters
    ----------
    model : P21Model
        The file, as returned by :meth:`P21Model.read`.

    Returns
    -------
    PMI
        Tolerances, dimensions and datums in file-id order, lengths in mm, angles in degrees.
    """
    t0 = time.perf_counter()
    r = _Reader(model)
    r.context_units()
    tolerances = r.tolerances()
    t1 = time.perf_counter()
    dimensions = r.dimensions()
    datums = r.datums()
    t2 = time.perf_counter()
    pmi = PMI(
        schema=model.schema,
        length_unit=_length_name(r.context_length),
        length_scale=r.context_length.scale or 1.0,
        tolerances=tolerances,
        dimensions=dimensions,
        datums=datums,
        problems=list(dict.fromkeys(r.problems)),
    )
    log.debug(
        "semantic PMI: %d tolerances (%.3f s), %d dimensions and %d datums (%.3f s)",
        len(tolerances), t1 - t0, len(dimensions), len(datums), t2 - t1,
    )  # fmt: skip
    return pmi


def read_pmi_text(path: str | Path) -> PMI:
    """Read the semantic PMI of a STEP AP242 file from its Part 21 text.

    Parameters
    ----------
    path : str or Path
        The ``.stp`` / ``.step`` file.

    Returns
    -------
    PMI
        See :class:`qifreport.step.pmi.PMI`.

    Raises
    ------
    OSError
        When the file cannot be read.
    step.p21.P21Error
        When it is not a Part 21 file.
    """
    t0 = time.perf_counter()
    model = P21Model.read(path)
    t1 = time.perf_counter()
    pmi = pmi_from_model(model)
    log.debug(
        "read_pmi_text %s: split %.3f s, PMI %.3f s, total %.3f s",
        Path(path).name, t1 - t0, time.perf_counter() - t1, time.perf_counter() - t0,
    )  # fmt: skip
    return pmi
