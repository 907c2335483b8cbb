"""Checks a QMS importer makes that the schema cannot: a characteristic measurement whose
``Status`` says ``PASS`` while its ``Value`` lies beyond its definition's tolerance
(``ToleranceValue`` + ``Bonus`` for a zone, ``Tolerance`` limits about the nominal's
``TargetValue`` for a dimension) contradicts itself.

:func:`status_contradictions` lists every such measurement of a results document, one
line each (empty when there is none).
"""

from __future__ import annotations

from lxml import etree

from .composite import segment_elements
from .xsd import QIF_NS

__all__ = ["status_contradictions"]

_Q = f"{{{QIF_NS}}}"
#: a value this much beyond its limit is beyond it (the decimals written: 0.1 um)
_SLACK = 1e-7


def _num(el: etree._Element | None) -> float | None:
    if el is None or el.text is None:
        return None
    try:
        return float(el.text)
    except ValueError:
        return None  # a UserDefinedAttribute's value is a word


def status_contradictions(root: etree._Element) -> list[str]:
    """Every characteristic measurement of ``root`` (a ``QIFDocument``) with status
    ``PASS`` and a numeric ``Value`` outside its limits (or a composite segment's),
    as ``'<tag> <id>: ...'`` lines."""
    by_id = {el.get("id"): el for el in root.iter() if el.get("id") is not None}
    out = []
    for m in root.iter():
        tag = etree.QName(m).localname if isinstance(m.tag, str) else ""
        if not tag.endswith("CharacteristicMeasurement"):
            continue
        if m.findtext(f"{_Q}Status/{_Q}CharacteristicStatusEnum") != "PASS":
            continue
        value = _num(m.find(f"{_Q}Value"))
        if value is None:
            continue
        item = by_id.get(m.findtext(f"{_Q}CharacteristicItemId"))
        nominal = (
            by_id.get(item.findtext(f"{_Q}CharacteristicNominalId")) if item is not None else None
        )
        definition = (
            by_id.get(nominal.findtext(f"{_Q}CharacteristicDefinitionId"))
            if nominal is not None
            else None
        )
        if definition is None:
            continue
        out += _segment_contradictions(tag, m, definition)
        tol = _num(definition.find(f"{_Q}ToleranceValue"))
        if tol is not None:
            limit = tol + (_num(m.find(f"{_Q}Bonus")) or 0.0)
            if value > limit + _SLACK:
                out.append(f"{tag} {m.get('id')}: PASS with value {value} > tolerance {limit}")
            continue
        target = _num(nominal.find(f"{_Q}TargetValue"))
        hi = _num(definition.find(f"{_Q}Tolerance/{_Q}MaxValue"))
        lo = _num(definition.find(f"{_Q}Tolerance/{_Q}MinValue"))
        if target is None:
            continue
        if hi is not None and value > target + hi + _SLACK:
            out.append(f"{tag} {m.get('id')}: PASS with value {value} > {target + hi}")
        if lo is not None and value < target + lo - _SLACK:
            out.append(f"{tag} {m.get('id')}: PASS with value {value} < {target + lo}")
    return out


def _segment_contradictions(tag: str, m: etree._Element, definition: etree._Element) -> list[str]:
    """A composite frame's segments (:mod:`qifreport.qif.composite`) whose ``PASS`` has a
    value beyond the segment's tolerance."""
    limits = {
        n: _num(d.find(f"{_Q}ToleranceValue"))
        for n, d in segment_elements(definition, "Definition")
    }
    out = []
    for n, seg in segment_elements(m, "Measurement"):
        if seg.findtext(f"{_Q}Status/{_Q}CharacteristicStatusEnum") != "PASS":
            continue
        value, limit = _num(seg.find(f"{_Q}Value")), limits.get(n)
        if value is not None and limit is not None and value > limit + _SLACK:
            name = etree.QName(seg).localname
            out.append(f"{tag} {m.get('id')} {name}: PASS with value {value} > tolerance {limit}")
    return out
