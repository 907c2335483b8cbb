"""A results document refers to its plan: every reference resolves, and every element of
the plan is carried with the plan document's id, tag, UUID and designator."""

from __future__ import annotations

from pathlib import Path

from lxml import etree

Q = "{http://qifstandards.org/xsd/qif3}"


def _local(el: etree._Element) -> str:
    return etree.QName(el).localname


def references(root: etree._Element) -> list[etree._Element]:
    """Every QIF id reference of a document (a ``QIFReferenceType``: an ``...Id`` element or
    an ``Id`` of an ``...Ids`` list, whose text is an id), external ones (``xId``) left out."""
    out = []
    for el in root.iter(f"{Q}*"):
        name = _local(el)
        if not (name == "Id" or name.endswith("Id")) or "QPId" in name:
            continue
        if el.get("xId") is None and (el.text or "").strip().isdigit():
            out.append(el)
    return out


def by_id(root: etree._Element) -> dict[str, etree._Element]:
    return {el.get("id"): el for el in root.iter(f"{Q}*") if el.get("id") is not None}


def assert_refers_to_plan(results: Path, plan: Path) -> dict[str, int]:
    """Assert that ``results`` carries ``plan`` and measures its items; returns counts."""
    r = etree.parse(str(results)).getroot()
    p = etree.parse(str(plan)).getroot()
    rid, pid = by_id(r), by_id(p)
    assert len(rid) == len(set(rid)), "duplicate ids"
    refs = references(r)
    dangling = [f"{_local(e)}={e.text}" for e in refs if e.text.strip() not in rid]
    assert not dangling, f"unresolved references: {dangling[:5]}"
    ext = r.find(f"{Q}ExternalQIFReferences/{Q}ExternalQIFDocument")
    assert ext is not None and ext.findtext(f"{Q}QPId") == p.findtext(f"{Q}QPId")
    for i, pel in pid.items():
        rel = rid.get(i)
        assert rel is not None and rel.tag == pel.tag, f"plan id {i} {_local(pel)} not carried"
        for path in (f"{Q}UUID", f"{Q}CharacteristicDesignator/{Q}UUID"):
            assert rel.findtext(path) == pel.findtext(path), f"plan id {i}: {path} differs"
        assert rel.findtext(f"{Q}Name") == pel.findtext(f"{Q}Name")
    items = {i for i, el in pid.items() if _local(el).endswith("CharacteristicItem")}
    measured = {
        m.findtext(f"{Q}CharacteristicItemId").strip()
        for m in r.iter(f"{Q}*")
        if _local(m).endswith("CharacteristicMeasurement")
    }
    assert items <= measured, f"plan items with no measurement: {sorted(items - measured)}"
    segments = _assert_segments_measured(r, p, rid)
    return {
        "plan_elements": len(pid),
        "references": len(refs),
        "plan_items": len(items),
        "segments": segments,
    }


def _segments(el: etree._Element, what: str) -> list[etree._Element]:
    return [x for x in el if "CompositeSegment" in _local(x) and _local(x).endswith(what)]


def _assert_segments_measured(r: etree._Element, p: etree._Element, rid: dict) -> int:
    """Each composite segment of the plan is carried with its designator and UUID, and the
    measurement of its characteristic has a segment measurement for it; returns how many."""
    item_of = {}  # definition id -> the results' measurement of its item
    for m in r.iter(f"{Q}*"):
        if _local(m).endswith("CharacteristicMeasurement"):
            item = rid[m.findtext(f"{Q}CharacteristicItemId").strip()]
            nominal = rid[item.findtext(f"{Q}CharacteristicNominalId").strip()]
            item_of[nominal.findtext(f"{Q}CharacteristicDefinitionId").strip()] = m
    n = 0
    for d in p.iter(f"{Q}*"):
        segs = _segments(d, "Definition") if _local(d).endswith("CharacteristicDefinition") else []
        if not segs:
            continue
        carried = _segments(rid[d.get("id")], "Definition")
        path = f"{Q}CharacteristicDesignator/{Q}UUID"
        assert [x.findtext(path) for x in carried] == [x.findtext(path) for x in segs]
        m = item_of[d.get("id")]
        assert len(_segments(m, "Measurement")) == len(segs), f"definition {d.get('id')}"
        n += len(segs)
    return n
