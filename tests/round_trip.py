"""A characteristic result as written against the one read back, field by field.

The writer (:mod:`qifreport.qif.writer`, :mod:`qifreport.qif.feature_characteristics`)
writes a :class:`~qifreport.metrology.gdt.characteristic_types.CharacteristicResult`; the
reader (:func:`qifreport.qif.reader.read_results`) gives one back. What QIF carries comes back
equal: a decimal as the writer rounds it (:func:`qifreport.qif.xmlkit.dec`), a double
attribute exactly, a text as an ``xs:token`` (whitespace collapsed).
"""

from __future__ import annotations

import dataclasses
import math

from qifreport.kinds import lookup_kind
from qifreport.metrology.gdt.characteristic_types import CharacteristicResult
from qifreport.metrology.gdt.geometric import per_unit
from qifreport.qif.feature_characteristics import qif_status
from qifreport.qif.xmlkit import dec, token

#: spec fields a document does not carry: the mesh's faces, how the PMI drew it
NOT_CARRIED = {
    "faces",
    "origin_faces",
    "target_faces",
    "problems",
    "zone_form",
    "datum_materials",
    "composite",
    "thread",
    "drawn",
    "dim_type",
    "unit_basis",
}


def _decimal(x: float | None) -> float | None:
    """``x`` as the document holds a decimal (None for no or a non-finite value)."""
    return None if x is None or not math.isfinite(x) else float(dec(x))


def _double(x: float | None) -> float | None:
    """``x`` as the document holds a double attribute (None for no or a non-finite one)."""
    return None if x is None or not math.isfinite(x) else x


def _same_number(a: float | None, b: float | None) -> bool:
    both_nan = a is not None and b is not None and math.isnan(a) and math.isnan(b)
    return a == b or both_nan


def _reason(w: CharacteristicResult) -> str:
    """The reason a document carries: a failure's non-conformance (``"not conforming"``
    without one), a reason not to measure; no other."""
    if w.status == "FAIL":
        return token(w.reason or "not conforming")
    return w.reason if w.status == "NOT_MEASURED" else ""


def assert_same_spec(w: CharacteristicResult, r: CharacteristicResult) -> None:
    """The spec read back ``r.spec`` is the written ``w.spec`` as QIF carries it."""
    ws, rs = w.spec, r.spec
    what = ws.key
    assert rs.key == ws.key and rs.kind == ws.kind, (what, rs.key, rs.kind)
    assert rs.name == token(ws.name), what
    assert rs.datums == ws.datums and rs.modifiers == ws.modifiers, what
    assert rs.tolerance == _decimal(ws.tolerance), (what, rs.tolerance, ws.tolerance)
    assert rs.unit == ws.unit and rs.basic == ws.basic, what
    if ws.kind == "dimension":
        assert rs.nominal == _decimal(ws.nominal), what
        for got, want in ((rs.lower_limit, ws.lower_limit), (rs.upper_limit, ws.upper_limit)):
            assert (got is None) == (want is None), what
            assert want is None or abs(got - want) <= 1e-7, (what, got, want)
    else:
        assert rs.dim_type == ws.dim_type, what
    assert per_unit(rs.unit_basis) == per_unit(ws.unit_basis), (what, rs.unit_basis)
    carried = {f.name for f in dataclasses.fields(ws)} - NOT_CARRIED
    checked = {"key", "kind", "name", "datums", "modifiers", "tolerance", "unit", "basic"}
    checked |= {"nominal", "lower_limit", "upper_limit", "step_id", "max_value", "composite_of"}
    assert carried <= checked, carried - checked  # a new field: say how it is carried
    assert rs.step_id == ws.step_id, what
    assert rs.composite_of == ws.composite_of, what  # a lower segment's frame
    kind = lookup_kind(ws.kind)
    if kind is not None and kind.qif.max_tolerance:  # MaximumToleranceValue
        assert (rs.max_value is None) == (ws.max_value is None), what
        assert ws.max_value is None or abs(rs.max_value - ws.max_value) <= 1e-7, what


def assert_same_result(w: CharacteristicResult, r: CharacteristicResult) -> None:
    """The characteristic read back ``r`` is the written ``w``: its spec, status, value,
    reading and numbers as QIF carries them, a toleranced surface's worst deviations,
    statistics and acceptance; the document record holds the QIF status written."""
    assert_same_spec(w, r)
    what = w.spec.key
    assert r.status == w.status and r.document.status == qif_status(w), (what, r.status)
    assert r.reason == _reason(w), (what, r.reason, w.reason)
    assert r.value == _decimal(w.value), (what, r.value, w.value)
    assert r.reading == w.reading and r.n_points == w.n_points, what
    assert r.least_squares == _double(w.least_squares), what
    assert r.uncertainty == _double(w.uncertainty), what
    assert _same_number(r.coverage, w.coverage), (what, r.coverage, w.coverage)
    assert r.bonus == (_decimal(w.bonus) or 0.0), what
    assert (r.direction is None) == (w.direction is None), what
    assert r.worst_positive == _decimal(w.worst_positive), what
    assert r.worst_negative == _decimal(w.worst_negative), what
    assert (r.stats is None) == (w.stats is None), what
    if w.stats is not None:
        for f, x in dataclasses.asdict(w.stats).items():
            assert _same_number(getattr(r.stats, f), x), (what, f)
    assert_same_budget(w, r)
    assert (r.acceptance is None) == (w.acceptance is None), what
    if w.acceptance is not None:
        a, b = r.acceptance, w.acceptance
        assert (a.passed, a.reasons, len(a.regions)) == (b.passed, b.reasons, len(b.regions))
        assert a.in_tolerance_fraction == b.in_tolerance_fraction, what
        assert [(g.area, g.peak, g.sign) for g in a.regions] == [
            (g.area, g.peak, g.sign) for g in b.regions
        ]


def assert_same_budget(w: CharacteristicResult, r: CharacteristicResult) -> None:
    """The uncertainty budget read back is the one written: its scanner, and each term's
    name, standard uncertainty (a double attribute: exactly) and source."""
    what = w.spec.key
    assert (r.budget is None) == (w.budget is None), what
    if w.budget is None:
        return
    assert r.budget.scanner == w.budget.scanner, what
    got = [(t.name, t.u, t.source) for t in r.budget.terms]
    assert got == [(t.name, t.u, t.source) for t in w.budget.terms], (what, got)


def one_characteristic_document(c: CharacteristicResult) -> bytes:
    """A bare QIF results document holding the one characteristic ``c`` (its feature, its
    definition, nominal, item and measurement), written by the product's builders; it
    defines no actual component (its keyrefs are the only schema findings)."""
    from lxml import etree

    from qifreport.qif.definitions import Sections
    from qifreport.qif.feature_characteristics import (
        characteristic_definition,
        characteristic_measurement,
    )
    from qifreport.qif.xmlkit import E, Ids, id_array, qpid

    ids, zs = Ids(), Sections()
    actual_id, mr_id = ids(), ids()
    _, ci, fm = characteristic_definition(zs, c.spec, ids, {}, result=c, actual_id=actual_id)
    meas = characteristic_measurement(c, ids, ci, fm, actual_id)
    root = E.QIFDocument(
        E.QPId(qpid()),
        zs.features(),
        zs.characteristics(ids()),
        E.Results(
            E.MeasurementResultsSet(
                E.MeasurementResults(
                    E.MeasuredCharacteristics(E.CharacteristicMeasurements(meas, n="1")),
                    E.InspectionStatus(E.InspectionStatusEnum(c.status)),
                    id_array("ActualComponentIds", [actual_id]),
                    id=mr_id,
                ),
                n="1",
            )
        ),
        versionQIF="3.0.0",
        idMax=str(ids.max),
    )
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8")
