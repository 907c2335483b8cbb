"""QIF 3.0 characteristics of the drawing's feature tolerances and dimensions
(:mod:`qifreport.metrology.characteristics`): each PMI item as its own characteristic type
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
"""

from __future__ import annotations

import math

from lxml import etree

from qifreport.metrology.characteristics import CharacteristicResult

from .xmlkit import Attrs, E, Ids, dec, id_array, qpid, token

__all__ = ["QIF_TYPES", "characteristic_elements", "qif_status"]

#: QIF characteristic type of each tolerance kind (the dimensions: :func:`_dimension_type`)
QIF_TYPES = {
    "flatness": "Flatness",
    "straightness": "Straightness",
    "roundness": "Circularity",
    "cylindricity": "Cylindricity",
    "perpendicularity": "Perpendicularity",
    "parallelism": "Parallelism",
    "angularity": "Angularity",
    "position": "Position",
    "coaxiality": "Coaxiality",
    "concentricity": "Concentricity",
    "circular_runout": "CircularRunout",
    "total_runout": "TotalRunout",
    "symmetry": "Symmetry",
    "line_profile": "LineProfile",
}
_STATUS = {
    "PASS": "PASS",
    "FAIL": "FAIL",
    "INDETERMINATE": "INDETERMINATE",
    "NOT_MEASURED": "NOT_ANALYZED",
    "BASIC": "BASIC_OR_TED",
}
#: kinds whose definition needs a material condition / a zone shape (the schema's order)
_MATERIAL = ("perpendicularity", "parallelism", "angularity", "position")
_ZONE_SHAPE = ("straightness", "perpendicularity", "parallelism", "angularity", "position")
_ZONE_SHAPE += ("coaxiality", "concentricity")
_ORIENTATION = ("perpendicularity", "parallelism", "angularity")
_DRF = _MATERIAL + ("coaxiality", "concentricity", "circular_runout", "total_runout", "symmetry")


def qif_status(c: CharacteristicResult) -> str:
    """The ``CharacteristicStatusEnum`` of a measured characteristic."""
    return _STATUS[c.status]


def _dimension_type(c: CharacteristicResult) -> str:
    s = c.spec
    if s.unit == "deg":
        return "AngleBetween"
    if s.dim_type == "diameter":
        return "Diameter"
    if s.dim_type == "radius":
        return "Radius"
    if s.origin_faces is not None and s.target_faces is not None:
        return "DistanceBetween"
    return "Width"


def qif_type(c: CharacteristicResult) -> str:
    """The QIF characteristic type name (without the Definition/Nominal/... suffix): a
    tolerance kind QIF has no type for, or a line profile whose section direction is not
    known (its nominal needs a ``Vector``), is a ``UserDefinedAttribute`` (not measured)."""
    if c.spec.kind == "dimension":
        return _dimension_type(c)
    if c.spec.kind == "line_profile" and c.direction is None:
        return "UserDefinedAttribute"
    return QIF_TYPES.get(c.spec.kind, "UserDefinedAttribute")


def _material(mods: list[str]) -> str:
    text = " ".join(mods)
    if "maximum_material" in text:
        return "MAXIMUM"
    if "least_material" in text:
        return "LEAST"
    return "NONE"


def characteristic_elements(
    c: CharacteristicResult,
    ids: Ids,
    drf_ids: dict[tuple[str, ...], str],
    actual_id: str,
) -> dict[str, etree._Element]:
    """The elements of one characteristic and its surface feature, by section:
    ``fdef``, ``fnom``, ``fitem``, ``fmeas``, ``cdef``, ``cnom``, ``citem``, ``cmeas``
    (ids handed out in that order)."""
    s = c.spec
    t = qif_type(c)
    fd, fn, fi, fm, cd, cn, ci, cm = (ids() for _ in range(8))
    fname = token(f"FEATURE_{s.key}")
    fa = Attrs().s("b_rep_faces", " ".join(str(int(f)) for f in s.faces) or "none")
    out: dict[str, etree._Element] = {
        "fdef": E.OtherSurfaceFeatureDefinition(id=fd),
        "fnom": E.OtherSurfaceFeatureNominal(
            *[x for x in (fa.element(), E.Name(fname), E.UUID(qpid())) if x is not None],
            E.FeatureDefinitionId(fd),
            id=fn,
        ),
        "fitem": E.OtherSurfaceFeatureItem(
            E.FeatureNominalId(fn),
            E.FeatureName(fname),
            E.UUID(qpid()),
            E.DeterminationMode(E.Checked(E.CheckDetails(E.Measured()))),
            id=fi,
        ),
        "fmeas": E.OtherSurfaceFeatureMeasurement(
            E.FeatureItemId(fi), E.FeatureName(fname), E.ActualComponentId(actual_id), id=fm
        ),
    }
    da = Attrs().s("key", s.key)
    if s.step_id is not None:
        da.i("step_entity_id", s.step_id)
    if s.modifiers:
        da.s("modifiers", " ".join(s.modifiers))
    name = token(s.name)
    cdef = [da.element(), E.Description(_describe(c)), E.Name(name)]
    if s.free_state:
        cdef.append(E.FreeState("true"))
    if t == "UserDefinedAttribute":
        cdef.append(E.WhatToMeasure(f"{s.kind.replace('_', ' ')} {s.limits_text()}"))
    elif s.kind == "dimension":
        cdef += _dimension_definition(c)
    else:
        cdef.append(E.ToleranceValue(dec(s.tolerance if s.tolerance is not None else 0.0)))
        if s.kind in _DRF and s.datums and tuple(s.datums) in drf_ids:
            cdef.append(E.DatumReferenceFrameId(drf_ids[tuple(s.datums)]))
        if s.kind in _MATERIAL:
            cdef.append(E.MaterialCondition(_material(s.modifiers)))
        if s.kind in _ZONE_SHAPE:
            diametral = bool(s.zone_form and "cylindrical" in s.zone_form)
            other = E.PlanarZone() if s.kind in _ORIENTATION else E.NonDiametricalZone()
            cdef.append(E.ZoneShape(E.DiametricalZone() if diametral else other))
        if s.kind == "line_profile":
            cdef.append(E.OuterDisposition(dec(0.5 * (s.tolerance or 0.0))))
    out["cdef"] = E(f"{t}CharacteristicDefinition", *[x for x in cdef if x is not None], id=cd)
    cnom = [E.CharacteristicDefinitionId(cd), id_array("FeatureNominalIds", [fn]), E.Name(name)]
    if s.kind == "dimension" and s.nominal is not None:
        cnom.append(E.TargetValue(dec(s.nominal)))
    if t in ("DistanceBetween", "AngleBetween"):
        cnom.append(E.AnalysisMode("THREEDIMENSIONAL"))
    if t == "LineProfile":
        cnom.append(E.Vector(" ".join(repr(float(x)) for x in c.direction)))
    out["cnom"] = E(f"{t}CharacteristicNominal", *cnom, id=cn)
    out["citem"] = E(
        f"{t}CharacteristicItem",
        E.Name(name),
        E.CharacteristicDesignator(E.Designator(s.key), E.UUID(qpid())),
        id_array("FeatureItemIds", [fi]),
        E.CharacteristicNominalId(cn),
        id=ci,
    )
    ma = Attrs().s("reading", c.reading or "-")
    if c.least_squares is not None and math.isfinite(c.least_squares):
        ma.d("least_squares_mm", c.least_squares)
    if c.uncertainty is not None and math.isfinite(c.uncertainty):
        ma.d("expanded_uncertainty", c.uncertainty)
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
    if c.status == "FAIL":
        meas.append(E.NonConformanceDesignator(token(c.reason or "not conforming")))
    if c.value is not None and math.isfinite(c.value):
        meas.append(E.Value(dec(c.value)))
        if s.kind == "position" and c.bonus > 0:
            meas.append(E.Bonus(dec(c.bonus)))
    out["cmeas"] = E(f"{t}CharacteristicMeasurement", *[x for x in meas if x is not None], id=cm)
    return out


def _describe(c: CharacteristicResult) -> str:
    s = c.spec
    what = s.kind.replace("_", " ") if s.kind != "dimension" else f"{s.dim_type} dimension"
    frame = f" |{'|'.join(s.datums)}|" if s.datums else ""
    text = f"{what} {s.limits_text()}{frame} (pmi #{s.step_id})"
    if c.status == "NOT_MEASURED":
        text += f"; not measured: {c.reason}"
    elif c.reading:
        text += f"; {c.reading}"
    return text


def _dimension_definition(c: CharacteristicResult) -> list[etree._Element]:
    s = c.spec
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
