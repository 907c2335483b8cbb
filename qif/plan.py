"""QIF 3.0 plan of a part: what its drawing asks to be measured, from the STEP file alone.

``qifreport plan part.step`` writes one ``QIFDocument`` with the part (``Product``), a
surface feature per toleranced face set and per datum feature (its B-rep faces, by index and
by STEP entity id), the datums and the datum reference frames the tolerances cite
(``ReferencedComponent`` NOMINAL, each datum's material modifier as drawn), and one
characteristic (definition, nominal, item) per PMI item: the surface profiles as
``SurfaceProfileCharacteristic``, the feature tolerances and dimensions as their own types
(:mod:`qifreport.qif.feature_characteristics`). Its ``Plan`` is QIF's "measure and evaluate
everything" (``MeasureEvaluateAll``). No measurement and no results.

The plan's ``QPId`` is derived from the STEP file's SHA-256 and qifreport's version
(:func:`plan_qpid`): the same file read by the same version gives the same plan identity,
and every results document of an inspection of that file names it in its
``ExternalQIFReferences`` (by QPId and by the file name ``<stem>_plan.qif``) whether or not
the plan was written.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from lxml import etree

from qifreport import __version__
from qifreport.metrology.acceptance.bands import ToleranceZone
from qifreport.metrology.gdt.pmi_plan import CharacteristicPlan

from .composite import ORDINALS, SEGMENT_TYPES, fold_definition
from .definitions import (
    DrfKey,
    PartIds,
    Sections,
    acceptance_definition,
    datum_definitions,
    datum_ids,
    datum_reference_frames,
    drf_key,
    face_attrs,
    feature_definition,
    file_units,
    product,
    profile_definition,
    profile_feature_name,
    software_definitions,
    standards_definitions,
)
from .feature_characteristics import characteristic_definition, qif_type, spec_feature_name
from .xmlkit import SCHEMA_LOCATION, XSI, E, Ids, token, xml_time

__all__ = [
    "PlanItem",
    "PlanSections",
    "PlanSource",
    "build_plan",
    "drawing_zones",
    "more_frames",
    "plan_file_name",
    "plan_qpid",
    "plan_reference",
    "plan_sections",
    "read_qpid",
]

#: the namespace of qifreport's derived QPIds (uuid5)
_QPID_NAMESPACE = uuid.UUID("5b0f2a8e-7d1c-4c55-9a55-3f1c2b8e9d10")


def plan_qpid(nominal_sha256: str) -> str:
    """The QPId of the plan of a STEP file (hex SHA-256): the same for the same file and
    qifreport version."""
    return str(uuid.uuid5(_QPID_NAMESPACE, f"plan:{nominal_sha256}:qifreport {__version__}"))


def plan_file_name(nominal_stem: str) -> str:
    """The plan's file name beside the results of a nominal: ``<stem>_plan.qif``."""
    return f"{nominal_stem}_plan.qif"


@dataclass
class PlanSource:
    """What a plan is made from (a STEP nominal's PMI as the inspection reads it).

    Attributes
    ----------
    part_name : the part's name (the STEP file's stem by default).
    nominal_path, nominal_sha256 : the STEP file and its hex SHA-256.
    zones : the profile zones (:func:`qifreport.metrology.acceptance.bands.zones_from_pmi`).
    plan : the feature characteristics and datums
        (:func:`qifreport.metrology.gdt.pmi_plan.specs_from_pmi`).
    datums : the datum labels the PMI defines, file order.
    face_step_ids : (n_faces,) the STEP entity id of each B-rep face (-1 unknown).
    rule : an acceptance rule to state beside each profile (its ``<key>_ACCEPTANCE``
        characteristic, :func:`qifreport.qif.writer.acceptance_rule`); None (the plan of the
        drawing alone, as ``qifreport plan`` and the inspections write it): none.
    standard : (organization, designator, year) of the tolerancing standard.
    """

    part_name: str
    nominal_path: str
    nominal_sha256: str
    zones: list[ToleranceZone]
    plan: CharacteristicPlan
    datums: list[str] = field(default_factory=list)
    face_step_ids: np.ndarray | None = None
    rule: str | None = None
    standard: tuple[str, str, str] = ("ASME", "Y14.5", "2018")


@dataclass
class PlanItem:
    """One drawing item's elements in a plan: its surface feature (name, nominal and item
    ids) and its characteristic item id and QIF type; a composite frame's lower segment is
    segment ``segment`` (2, 3, 4) of its upper segment's characteristic item
    (:mod:`qifreport.qif.composite`)."""

    feature_name: str
    feature_nominal: str
    feature_item: str
    characteristic_item: str
    qif_type: str
    segment: int = 1


@dataclass
class PlanSections:
    """The sections of a part's plan and the ids they hold: every document that carries the
    plan (the plan itself, the results of each inspection of the part) builds them first,
    with :class:`~qifreport.qif.xmlkit.Ids` namespaced by the plan's QPId, so each element
    of the plan has the same id and UUID in all of them.

    Attributes
    ----------
    std_id, sw_id : the tolerancing standard's and qifreport's ids.
    dids, drf_ids : the datums' and datum reference frames' ids.
    datum_features : datum label -> the feature nominal id of its datum feature.
    part : the part's, component's and assembly path's ids.
    zs : the features and characteristics (a results document appends its own).
    zones, specs : profile zone key / feature characteristic key -> its :class:`PlanItem`.
    """

    std_id: str
    sw_id: str
    dids: dict[str, str]
    drf_ids: dict[DrfKey, str]
    datum_features: dict[str, str]
    part: PartIds
    zs: Sections
    zones: dict[str, PlanItem] = field(default_factory=dict)
    specs: dict[str, PlanItem] = field(default_factory=dict)


def drawing_zones(zones: list[ToleranceZone]) -> list[ToleranceZone]:
    """The profile zones the drawing states (the general zone only when a whole-part
    profile of the PMI sets it, not the command line's or the default band)."""
    return [z for z in zones if z.faces is not None or z.step_id is not None]


def plan_sections(src: PlanSource, ids: Ids) -> PlanSections:
    """The plan's sections (:class:`PlanSections`), ids handed out by ``ids`` in a fixed
    order: standard, software, datums and frames, part, datum features, profiles, feature
    characteristics."""
    std_id, sw_id = ids(), ids()
    specs = src.plan.specs
    zones = drawing_zones(src.zones)
    cited = [drf_key(z.datums, z.datum_materials) for z in zones]
    cited += [drf_key(s.datums, s.datum_materials) for s in specs]
    dids, drf_ids = datum_ids(src.datums, cited, ids)
    part = PartIds(part=ids(), component=ids(), asm_path=ids())
    ps = PlanSections(std_id, sw_id, dids, drf_ids, {}, part, Sections())
    for label, d in src.plan.datums.items():
        if label not in dids or not len(d.faces):
            continue
        fa = face_attrs(d.faces, src.face_step_ids)
        fn, _, _ = feature_definition(ps.zs, token(f"DATUM_FEATURE_{label}"), fa, ids)
        ps.datum_features[label] = fn
    uppers = _segment_uppers(zones, lambda z: "SurfaceProfile")
    for z in sorted(zones, key=lambda z: z.key in uppers):  # upper segments first
        fa = face_attrs(z.faces, src.face_step_ids)
        fname = profile_feature_name(z)
        fn, fi, _ = feature_definition(ps.zs, fname, fa, ids)
        ci = profile_definition(ps.zs, z, src.rule or "", drf_ids, ids, fn, fi)
        item = PlanItem(fname, fn, fi, ci, "SurfaceProfile")
        ps.zones[z.key] = _item_or_segment(ps.zs, ps.zones, uppers.get(z.key), item)
        if src.rule:
            acceptance_definition(ps.zs, z, src.rule, ids, fn, fi)
    uppers = _segment_uppers(specs, qif_type)
    for s in sorted(specs, key=lambda s: s.key in uppers):
        fi, ci, _ = characteristic_definition(ps.zs, s, ids, drf_ids, src.face_step_ids)
        fn = ps.zs.fnom_ids[-1]  # the feature nominal it has just defined
        item = PlanItem(spec_feature_name(s), fn, fi, ci, qif_type(s))
        ps.specs[s.key] = _item_or_segment(ps.zs, ps.specs, uppers.get(s.key), item)
    return ps


def _segment_uppers(items: list, type_of) -> dict[str, str]:
    """Each composite lower segment among ``items`` (zones or specs) whose upper segment is
    among them, of a QIF type with composite segments (``type_of(item)``): lower key ->
    upper key."""
    by_step = {x.step_id: x for x in items if x.composite == "upper" and x.step_id is not None}
    out = {}
    for x in items:
        up = by_step.get(x.composite_of) if x.composite == "lower" else None
        if up is not None and type_of(x) == type_of(up) and type_of(x) in SEGMENT_TYPES:
            out[x.key] = up.key
    return out


def _item_or_segment(
    zs: Sections, items: dict[str, PlanItem], upper: str | None, item: PlanItem
) -> PlanItem:
    """The plan item of the characteristic just defined (``item``); a lower segment of
    ``upper`` (its key) is folded into the upper's characteristic as its next segment
    (:func:`qifreport.qif.composite.fold_definition`) and refers to the upper's item."""
    if upper is None:
        return item
    up = items[upper]
    ci = up.characteristic_item
    n = 1 + max(it.segment for it in items.values() if it.characteristic_item == ci)
    if n not in ORDINALS:
        return item  # a fifth segment: QIF has none, the segment stays its own
    fold_definition(zs, ci, up.qif_type, n)
    item.characteristic_item, item.segment = ci, n
    return item


def more_frames(ps: PlanSections, cited: list[DrfKey], ids: Ids) -> None:
    """Give the datums and datum reference frames ``cited`` that the plan has not their ids
    (after the plan's: a results document's own frames)."""
    for key in cited:
        for lab, _ in key:
            if lab not in ps.dids:
                ps.dids[lab] = ids()
        if key and key not in ps.drf_ids:
            ps.drf_ids[key] = ids()


def build_plan(src: PlanSource, created: datetime | None = None) -> etree._ElementTree:
    """The QIF 3.0 plan document of a part (an lxml tree; write it with
    :func:`qifreport.qif.writer.write_qif`)."""
    created = created or datetime.now(timezone.utc)
    ids = Ids(namespace=plan_qpid(src.nominal_sha256))
    ps = plan_sections(src, ids)
    header = E.Header(
        E.Application(E.Name("qifreport"), E.Organization("qifreport project")),
        E.Description(
            f"Measurement plan of {src.part_name} from {Path(src.nominal_path).name} "
            f"(SHA-256 {src.nominal_sha256}): every PMI item of the drawing"
        ),
    )
    zs = ps.zs
    children = [
        E.QPId(plan_qpid(src.nominal_sha256)),
        E.Version(E.TimeCreated(xml_time(created))),
        header,
        standards_definitions(src.standard, ps.std_id),
        software_definitions(ps.sw_id),
        file_units(),
        datum_definitions(ps.dids, ps.datum_features),
        datum_reference_frames(ps.drf_ids, ps.dids, referenced="NOMINAL"),
        product(src.part_name, ps.part, zs, ps.dids, ps.drf_ids, ids),
        zs.features() if zs.fdefs else None,
        zs.characteristics(ps.std_id) if zs.cdefs else None,
        E.Plan(E.UnorderedPlanRoot(E.Steps(E.MeasureEvaluateAll(), n="1"))),
    ]
    root = E.QIFDocument(
        *[c for c in children if c is not None], versionQIF="3.0.0", idMax=str(ids.max)
    )
    root.set(f"{{{XSI}}}schemaLocation", SCHEMA_LOCATION)
    return etree.ElementTree(root)


def plan_reference(nominal_stem: str, nominal_sha256: str, ref_id: str) -> etree._Element:
    """``ExternalQIFReferences`` of a results document: the plan of its nominal, by QPId
    (:func:`plan_qpid`) and file name (:func:`plan_file_name`), as the document's id
    ``ref_id``."""
    return E.ExternalQIFReferences(
        E.ExternalQIFDocument(
            E.QPId(plan_qpid(nominal_sha256)),
            E.URI(plan_file_name(nominal_stem)),
            E.Description(
                "the measurement plan of this part: `qifreport plan` on the nominal writes it "
                "(the same QPId for the same STEP file and qifreport version)"
            ),
            id=ref_id,
        ),
        n="1",
    )


def read_qpid(path: Path) -> str | None:
    """The ``QPId`` of a QIF document (its first element after the root), None when the file
    is not a QIF document or has none."""
    try:
        for _, el in etree.iterparse(str(path), events=("end",), huge_tree=False):
            if etree.QName(el).localname == "QPId":
                return (el.text or "").strip() or None
            if etree.QName(el).localname not in ("QPId",) and el.getparent() is not None:
                if el.getparent().getparent() is None:  # a later top-level child
                    return None
    except (etree.XMLSyntaxError, OSError):
        return None
    return None
