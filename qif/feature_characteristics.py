"""QIF 3.0 characteristics of the drawing's feature tolerances and dimensions
(:mod:`qifreport.metrology.gdt.characteristics`): each PMI item as its own characteristic type
(``FlatnessCharacteristic``, ``PositionCharacteristic``, ``DiameterCharacteristic`` ...)
with its definition (tolerance, datum reference frame, material condition, zone shape),
nominal, item (designator) and measurement (status, value, bonus), on an
``OtherSurfaceFeature`` that names its B-rep faces.

Status: ``PASS``/``FAIL``/``INDETERMINATE`` as measured (the value against the tolerance
or the limits, under the decision rule with the value's expanded uncertainty), so a
``Value`` beyond its ``ToleranceValue`` is never ``PASS``; ``NOT_ANALYZED`` (QIF's status
for an item not measured) with the reason in ``NonConformanceDesignator``-free attributes
(``not_measured_reason``) and the ``Description``; ``BASIC_OR_TED`` for a basic or
reference dimension (its value is reported).

Statuses are mapped here, at the boundary, both ways: :func:`qif_status` writes a
:class:`~qifreport.metrology.gdt.characteristic_types.CharacteristicResult`'s status (one of
its :data:`~qifreport.metrology.gdt.characteristic_types.STATUSES`) as QIF's
``CharacteristicStatusEnum`` and :func:`status_from_qif` reads one back:

================  ==============================================================
ours              QIF ``CharacteristicStatusEnum``
================  ==============================================================
``PASS``          ``PASS``
``FAIL``          ``FAIL``
``INDETERMINATE`` ``INDETERMINATE``
``NOT_MEASURED``  ``NOT_ANALYZED``
``BASIC``         ``BASIC_OR_TED``
``OTHER``         read only: ``REWORK``, ``SYSERROR``, ``UNDEFINED``, an
                  ``OtherCharacteristicStatus`` or none (written back as read)
================  ==============================================================

So are the characteristic types: :func:`qif_type` names a spec's QIF type and
:func:`kind_of_qif_type` reads one back (a registered kind's, found by the registry, a
dimension's, or :data:`~qifreport.metrology.gdt.characteristic_types.OTHER_KIND`).
"""

from __future__ import annotations

import math

import numpy as np
from lxml import etree

from qifreport.kinds import QifRules, kind_for_qif_type, kind_label, lookup_kind
from qifreport.metrology.acceptance.bands import material_boundary
from qifreport.metrology.gdt.characteristic_types import (
    OTHER_KIND,
    CharacteristicResult,
    CharacteristicSpec,
)
from qifreport.metrology.gdt.geometric import per_unit

from .definitions import DrfKey, Sections, drf_key, face_attrs, feature_definition
from .modifiers import extent, modifier_flags, projected_value
from .uncertainty import budget_attributes, uncertainty_attributes
from .xmlkit import Attrs, E, Ids, dec, id_array, token

__all__ = [
    "ANGULAR_DIMENSION_KINDS",
    "DIMENSION_KINDS",
    "LINEAR_DIMENSION_KINDS",
    "characteristic_definition",
    "spec_feature_name",
    "characteristic_measurement",
    "kind_of_qif_type",
    "material_condition",
    "qif_status",
    "qif_type",
    "status_from_qif",
]

#: dimensions in mm between limits (two-sided; ``LinearCharacteristicStatsEvalType``)
LINEAR_DIMENSION_KINDS = frozenset(
    {
        "Diameter",
        "Radius",
        "SphericalDiameter",
        "SphericalRadius",
        "Thickness",
        "DistanceBetween",
        "DistanceFrom",
        "Width",
        "Length",
        "Height",
        "Depth",
        "Chord",
        "CurveLength",
        "LinearCoordinate",
    }
)
#: dimensions in degrees between limits (``AngularCharacteristicStatsEvalType``)
ANGULAR_DIMENSION_KINDS = frozenset({"Angle", "AngleBetween", "AngleFrom", "AngularCoordinate"})
#: every dimension kind
DIMENSION_KINDS = LINEAR_DIMENSION_KINDS | ANGULAR_DIMENSION_KINDS

_STATUS = {
    "PASS": "PASS",
    "FAIL": "FAIL",
    "INDETERMINATE": "INDETERMINATE",
    "NOT_MEASURED": "NOT_ANALYZED",
    "BASIC": "BASIC_OR_TED",
}

#: a composite feature control frame's segments, as the definition's attribute says them
_COMPOSITE = {
    "upper": "upper (pattern-locating: located in its datum reference frame)",
    "lower": "lower (feature-relating: its datums orient only; the pattern placed as a whole)",
}


def qif_status(c: CharacteristicResult) -> str:
    """The ``CharacteristicStatusEnum`` of a characteristic result (an ``OTHER`` one: its
    status as read, or ``UNDEFINED``)."""
    if c.status in _STATUS:
        return _STATUS[c.status]
    return (c.document.status if c.document is not None else None) or "UNDEFINED"


#: QIF's statuses the product gives, as its own
_FROM_QIF = {v: k for k, v in _STATUS.items()}


def status_from_qif(text: str | None) -> str:
    """A characteristic result's status of a QIF status text (``CharacteristicStatusEnum`` or
    the other-status text): ``OTHER`` for one the product does not give, or none."""
    return _FROM_QIF.get(text, "OTHER") if text is not None else "OTHER"


def kind_of_qif_type(qif_type: str) -> tuple[str, str, str]:
    """The ``(kind, dim_type, unit)`` of a spec of a QIF characteristic type: a registered
    kind's (:func:`qifreport.kinds.kind_for_qif_type`), a dimension (its type in words,
    ``"DistanceBetween"`` -> ``"distance between"``; the unit ``"deg"`` for an angle), or
    :data:`~qifreport.metrology.gdt.characteristic_types.OTHER_KIND`."""
    kind = kind_for_qif_type(qif_type)
    if kind is not None:
        return kind.name, "", "mm"
    if qif_type in DIMENSION_KINDS:
        words = "".join(f" {ch.lower()}" if ch.isupper() else ch for ch in qif_type).strip()
        return "dimension", words, "deg" if qif_type in ANGULAR_DIMENSION_KINDS else "mm"
    return OTHER_KIND, "", "mm"


def _dimension_type(s: CharacteristicSpec) -> str:
    if s.unit == "deg":
        # an angle between two features (a location) or the angular size of one (a cone's,
        # a chamfer's)
        both = s.origin_faces is not None and s.target_faces is not None
        return "AngleBetween" if both else "Angle"
    if s.dim_type == "diameter":
        return "Diameter"
    if s.dim_type == "radius":
        return "Radius"
    if s.dim_type == "spherical diameter":
        return "SphericalDiameter"
    if s.dim_type == "spherical radius":
        return "SphericalRadius"
    if s.dim_type == "thickness":
        return "Thickness"
    if s.origin_faces is not None and s.target_faces is not None:
        return "DistanceBetween"
    return "Width"


def qif_type(s: CharacteristicSpec, direction: np.ndarray | None = None) -> str:
    """The QIF characteristic type name (without the Definition/Nominal/... suffix): a
    tolerance kind QIF has no type for, or a line profile whose section direction is not
    known (its nominal needs a ``Vector``), is a ``UserDefinedAttribute`` (not measured)."""
    if s.kind == "dimension":
        return _dimension_type(s)
    kind = lookup_kind(s.kind)
    if kind is None or kind.band or kind.qif_type is None:
        return "UserDefinedAttribute"
    if kind.qif.section_vector and direction is None:
        return "UserDefinedAttribute"
    return kind.qif_type


def material_condition(mods: list[str]) -> str:
    """QIF ``MaterialCondition`` of a tolerance's modifiers: MAXIMUM, LEAST or NONE."""
    return material_boundary(mods)


def spec_feature_name(spec: CharacteristicSpec) -> str:
    """The name of the surface feature a PMI item is measured on."""
    return token(f"FEATURE_{spec.key}")


def characteristic_definition(
    zs: Sections,
    spec: CharacteristicSpec,
    ids: Ids,
    drf_ids: dict[DrfKey, str],
    face_step_ids: np.ndarray | None = None,
    *,
    direction: np.ndarray | None = None,
    result: CharacteristicResult | None = None,
    actual_id: str | None = None,
) -> tuple[str, str, str | None]:
    """One PMI item's surface feature (definition, nominal, item) and characteristic
    (definition, nominal, item), appended to ``zs``; with ``actual_id`` (a results document:
    the inspected part) also the feature's measurement, and ``result`` says in the
    definition's description how it was read. ``direction``: a line profile's section direction (its
    nominal's ``Vector``; without it the item is a ``UserDefinedAttribute``).

    Returns the feature item, characteristic item and feature measurement ids."""
    s = spec
    t = qif_type(s, direction)
    fname = spec_feature_name(s)
    fa = face_attrs(s.faces, face_step_ids)
    fn, fi, fm = feature_definition(zs, fname, fa, ids, actual_id)
    cd, cn, ci = ids(), ids(), ids()
    zs.cnom_ids.append(cn)
    zs.mark_separate(s.modifiers, drf_key(s.datums, s.datum_materials), cn)
    da = Attrs().s("key", s.key)
    if s.step_id is not None:
        da.i("step_entity_id", s.step_id)
    if s.modifiers:
        da.s("modifiers", " ".join(s.modifiers))
    if s.composite:
        da.s("composite_segment", _COMPOSITE[s.composite])
    name = token(s.name)
    cdef = [da.element(), E.Description(_describe(s, result)), E.Name(name)]
    cdef += modifier_flags(s.modifiers)
    if t == "UserDefinedAttribute":
        cdef.append(E.WhatToMeasure(f"{kind_label(s.kind)} {s.limits_text()}"))
    elif s.kind == "dimension":
        cdef += _dimension_definition(s)
    else:
        cdef += _tolerance_definition(s, drf_ids)
    zs.cdefs.append(E(f"{t}CharacteristicDefinition", *[x for x in cdef if x is not None], id=cd))
    cnom = [E.CharacteristicDefinitionId(cd), id_array("FeatureNominalIds", [fn]), E.Name(name)]
    if s.kind == "dimension" and s.nominal is not None:
        cnom.append(E.TargetValue(dec(s.nominal)))
    if t in ("DistanceBetween", "AngleBetween"):
        cnom.append(E.AnalysisMode("THREEDIMENSIONAL"))
    if t != "UserDefinedAttribute" and _rules(s).section_vector:
        cnom.append(E.Vector(" ".join(repr(float(x)) for x in direction)))
    zs.cnoms.append(E(f"{t}CharacteristicNominal", *cnom, id=cn))
    zs.citems.append(
        E(
            f"{t}CharacteristicItem",
            E.Name(name),
            E.CharacteristicDesignator(
                E.Designator(s.key), E.UUID(ids.uuid(ci, "characteristic-item"))
            ),
            id_array("FeatureItemIds", [fi]),
            E.CharacteristicNominalId(cn),
            id=ci,
        )
    )
    return fi, ci, fm


def characteristic_measurement(
    c: CharacteristicResult,
    ids: Ids,
    ci: str,
    fm: str,
    actual_id: str,
    device_id: str | None = None,
) -> etree._Element:
    """The characteristic's measurement (status, value, bonus; the reading, least-squares
    value, uncertainty, its budget and points as ``Attributes``) of item ``ci`` on feature
    measurement ``fm``; a value with a budget names the scanner ``device_id``
    (``MeasurementDeviceIds``) and states its combined uncertainty
    (:mod:`qifreport.qif.uncertainty`)."""
    s = c.spec
    t = qif_type(s, c.direction)
    ma = Attrs().s("reading", c.reading or "-")
    if c.least_squares is not None and math.isfinite(c.least_squares):
        ma.d("least_squares_mm", c.least_squares)
    if c.uncertainty is not None and math.isfinite(c.uncertainty):
        ma.d("expanded_uncertainty", c.uncertainty)
    budget_attributes(ma, c.budget)
    if c.coverage is not None:
        ma.d("coverage", c.coverage)
    ma.i("points", c.n_points)
    if c.status == "NOT_MEASURED":
        ma.s("not_measured_reason", c.reason)
    meas = [
        ma.element(),
        E.Status(E.CharacteristicStatusEnum(qif_status(c))),
        E.CharacteristicItemId(ci),
        id_array("FeatureMeasurementIds", [fm]),
        E.ActualComponentId(actual_id),
    ]
    if c.budget is not None and device_id is not None:
        meas.append(id_array("MeasurementDeviceIds", [device_id]))
    if c.status == "FAIL":
        meas.append(E.NonConformanceDesignator(token(c.reason or "not conforming")))
    if c.value is not None and math.isfinite(c.value):
        u = uncertainty_attributes(c.budget) if t != "UserDefinedAttribute" else {}
        meas.append(E.Value(dec(c.value), **u))
        if _rules(s).bonus and c.bonus > 0:
            meas.append(E.Bonus(dec(c.bonus)))
    return E(f"{t}CharacteristicMeasurement", *[x for x in meas if x is not None], id=ids())


def _describe(s: CharacteristicSpec, c: CharacteristicResult | None) -> str:
    what = kind_label(s.kind) if s.kind != "dimension" else f"{s.dim_type} dimension"
    frame = f" |{'|'.join(s.datums)}|" if s.datums else ""
    text = f"{what} {s.limits_text()}{frame} (pmi #{s.step_id})"
    if c is None:
        return text
    if c.status == "NOT_MEASURED":
        text += f"; not measured: {c.reason}"
    elif c.reading:
        text += f"; {c.reading}"
    return text


def _rules(s: CharacteristicSpec) -> QifRules:
    """The QIF rules of ``s``'s kind (none for a dimension or an unregistered kind)."""
    kind = lookup_kind(s.kind)
    return QifRules() if kind is None else kind.qif


def _tolerance_definition(
    s: CharacteristicSpec, drf_ids: dict[DrfKey, str]
) -> list[etree._Element]:
    """A geometric tolerance's definition elements after its name: the tolerance value,
    datum reference frame, material condition, zone shape, MAX tolerance and disposition its
    kind's QIF
    rules (:class:`qifreport.kinds.QifRules`) ask for, in the schema's order."""
    rules = _rules(s)
    out = _tolerance_value(s, rules)
    key = drf_key(s.datums, s.datum_materials)
    if rules.datum_frame and s.datums and key in drf_ids:
        out.append(E.DatumReferenceFrameId(drf_ids[key]))
    if rules.material_condition:
        out.append(E.MaterialCondition(material_condition(s.modifiers)))
    if rules.zone_shape is not None:
        form = s.zone_form or ""
        if "cylindrical" in form:
            shape = E.DiametricalZone()
        elif "spherical" in form and rules.spherical_zone:
            shape = E.SphericalZone()
        else:
            shape = E.PlanarZone() if rules.zone_shape == "planar" else E.NonDiametricalZone()
        out.append(E.ZoneShape(shape))
    if rules.tangent_plane and "tangent_plane" in s.modifiers:
        out.append(E.TangentPlane("true"))
    if rules.max_tolerance and s.max_value is not None:
        out.append(E.MaximumToleranceValue(dec(s.max_value)))
    if rules.projected:
        out.append(projected_value(s.modifiers))
    if rules.outer_disposition:
        out.append(E.OuterDisposition(dec(0.5 * (s.tolerance or 0.0))))
    if rules.extent:
        out.append(extent(s.modifiers))
    return [x for x in out if x is not None]


def _tolerance_value(s: CharacteristicSpec, rules: QifRules) -> list[etree._Element]:
    """A geometric tolerance's value: ``ToleranceValue``, or for a per-unit tolerance
    (flatness per unit area, straightness per unit length ...) its
    ``ToleranceZonePerUnitArea`` / ``ToleranceZonePerUnitLength`` where the type has one."""
    value = dec(s.tolerance if s.tolerance is not None else 0.0)
    unit = per_unit(s.unit_basis)
    if unit is not None:
        kind, nums = unit
        if kind == "length" and "length" in rules.per_unit:
            return [
                E.ToleranceZonePerUnitLength(
                    E.ToleranceValuePerUnit(value), E.UnitLength(dec(nums[0]))
                )
            ]
        if kind != "length" and "area" in rules.per_unit:
            area = (
                E.CircularUnitArea(E.CircularUnitAreaDiameter(dec(nums[0])))
                if kind == "circular"
                else E.RectangularUnitArea(
                    E.RectangularUnitAreaLength(dec(nums[0])),
                    E.RectangularUnitAreaWidth(dec(nums[1])),
                )
            )
            return [E.ToleranceZonePerUnitArea(E.ToleranceValuePerUnit(value), area)]
    return [E.ToleranceValue(value)]


def _dimension_definition(s: CharacteristicSpec) -> list[etree._Element]:
    if s.lower_limit is None and s.upper_limit is None:
        return [E.NonTolerance("MEASURED")]  # a basic (or untoleranced) size, reported
    nominal = s.nominal if s.nominal is not None else 0.0
    hi = (s.upper_limit - nominal) if s.upper_limit is not None else None
    lo = (s.lower_limit - nominal) if s.lower_limit is not None else None
    tol = []
    if hi is not None:
        tol.append(E.MaxValue(dec(hi)))
    if lo is not None:
        tol.append(E.MinValue(dec(lo)))
    tol.append(E.DefinedAsLimit("false"))
    return [E.Tolerance(*tol)]
