"""Units and measures of a STEP file, resolved per measure into millimetres and degrees.

Units are resolved recursively: SI_UNIT with its prefix, CONVERSION_BASED_UNIT through its
conversion factor (a measure with its own unit), DERIVED_UNIT (areas), simple or complex
instances. Every length becomes millimetres and every plane angle degrees. A conversion factor
within 1e-6 (relative) of a well-known one (inch 25.4 mm, foot, degree ...) is snapped to it, so
that ``0.0174532925`` rad does not turn 90 degrees into 89.99999999. A measure (MEASURE_WITH_UNIT,
MEASURE_REPRESENTATION_ITEM or a complex instance with these parts) carries its own unit; when
that unit cannot be resolved, the length or angle unit of the shape's representation context is
used and a problem says so. :class:`MeasureReader` does this for one model, with caching.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .instance_graph import GraphWalker, refs_of, text_of, unwrap_typed
from .p21 import Entity, Enum, P21Model, Ref, Typed

__all__ = ["Measure", "MeasureReader", "Unit", "length_name", "number_text"]

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


def number_text(x: float) -> str:
    """Shortest faithful text of a number (``0.75``, ``25.4``, ``1``).

    Parameters
    ----------
    x : float

    Returns
    -------
    str
        ``x`` with up to 15 significant digits and no trailing zeros.
    """
    return f"{x:.15g}"


class MeasureReader(GraphWalker):
    """Units and measures of one model (cached), and the length and angle units of its context.

    Parameters
    ----------
    model : P21Model
        The parsed file.

    Attributes
    ----------
    context_length, context_angle : Unit
        Units of the shape's representation context (set by :meth:`context_units`;
        millimetres and radians until then).
    """

    def __init__(self, model: P21Model) -> None:
        super().__init__(model)
        self._units: dict[int, Unit] = {}
        self.context_length = Unit("length", 1.0, "MILLI METRE (assumed)")
        self.context_angle = Unit("angle", 180.0 / math.pi, "RADIAN (assumed)")

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
            name = text_of(cbu[-2]) or "?"
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
            elements = refs_of(ent.part("DERIVED_UNIT"))
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
            name = text_of(p[-1]) if p else "?"
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
                    value, mtype = unwrap_typed(v)
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
                return Measure(
                    None, raw, unit.kind, f"{number_text(raw)} {unit.text}", mtype, problems
                )
        elif unit.problem:
            problems.append(unit.problem)
        if expect and unit.kind != expect:
            problems.append(f"#{ent.id}: expected a {expect} measure, unit is {unit.text}")
        value = _clean(raw * unit.scale)
        return Measure(value, raw, unit.kind, f"{number_text(raw)} {unit.text}", mtype, problems)

    def item_name(self, ent: Entity) -> str:
        """Name of a representation item (simple MEASURE_REPRESENTATION_ITEM or complex)."""
        p = ent.part("REPRESENTATION_ITEM")
        if p:
            return text_of(p[0])
        if ent.parts is None and ent.params and isinstance(ent.params[0], str):
            return ent.params[0]
        return ""

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
        for r in refs_of(chosen.part("GLOBAL_UNIT_ASSIGNED_CONTEXT")):
            u = self.unit(r)
            if u.kind == "length" and u.scale is not None:
                self.context_length = u
            elif u.kind == "angle" and u.scale is not None:
                self.context_angle = u
        if self.context_length.text.endswith("(assumed)"):
            self.problems.append(f"#{chosen.id}: no length unit in context: millimetres assumed")


def length_name(unit: Unit) -> str:
    """Short name of a length unit (``'mm'``, ``'inch'``, ``'m'`` ...) for ``PMI.length_unit``.

    Parameters
    ----------
    unit : Unit
        A length unit.

    Returns
    -------
    str
        The short name of its scale (within the snapping tolerance), else its text in lower case.
    """
    if unit.scale is not None:
        for scale, name in _LENGTH_NAMES.items():
            if math.isclose(unit.scale, scale, rel_tol=_SNAP_RTOL):
                return name
    return unit.text.lower()
