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

from .definitions import (
    Sections,
    acceptance_definition,
    datum_definitions,
    datum_ids,
    datum_reference_frames,
    drf_key,
    face_attrs,
    feature_definition,
    file_units,
    profile_definition,
    profile_feature_name,
    software_definitions,
    standards_definitions,
)
from .feature_characteristics import characteristic_definition
from .xmlkit import SCHEMA_LOCATION, XSI, E, Ids, id_array, qpid, token, xml_time

__all__ = [
    "PlanSource",
    "build_plan",
    "plan_file_name",
    "plan_qpid",
    "plan_reference",
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


def build_plan(src: PlanSource, created: datetime | None = None) -> etree._ElementTree:
    """The QIF 3.0 plan document of a part (an lxml tree; write it with
    :func:`qifreport.qif.writer.write_qif`)."""
    created = created or datetime.now(timezone.utc)
    ids = Ids()
    std_id, sw_id = ids(), ids()
    specs = src.plan.specs
    # the general zone is the drawing's only when a whole-part profile of the PMI sets it
    zones = [z for z in src.zones if z.faces is not None or z.step_id is not None]
    cited = [drf_key(z.datums, z.datum_materials) for z in zones]
    cited += [drf_key(s.datums, s.datum_materials) for s in specs]
    dids, drf_ids = datum_ids(src.datums, cited, ids)

    zs = Sections()
    part_id, component_id, asm_id = ids(), ids(), ids()
    datum_features = {}
    for label, d in src.plan.datums.items():
        if label not in dids or not len(d.faces):
            continue
        fa = face_attrs(d.faces, src.face_step_ids)
        fn, _, _ = feature_definition(zs, token(f"DATUM_FEATURE_{label}"), fa, ids)
        datum_features[label] = fn
    for z in zones:
        fa = face_attrs(z.faces, src.face_step_ids)
        fn, fi, _ = feature_definition(zs, profile_feature_name(z), fa, ids)
        profile_definition(zs, z, src.rule or "", drf_ids, ids, fn, fi)
        if src.rule:
            acceptance_definition(zs, z, src.rule, ids, fn, fi)
    for s in specs:
        characteristic_definition(zs, s, ids, drf_ids, src.face_step_ids)

    part_el = E.Part(
        E.Header(E.Name(src.part_name)),
        E.UUID(qpid()),
        *([id_array("FeatureNominalIds", zs.fnom_ids)] if zs.fnom_ids else []),
        *([id_array("CharacteristicNominalIds", zs.cnom_ids)] if zs.cnom_ids else []),
        *([id_array("DatumDefinitionIds", dids.values())] if dids else []),
        *([id_array("DatumReferenceFrameIds", drf_ids.values())] if drf_ids else []),
        id=part_id,
    )
    product = E.Product(
        E.PartSet(part_el, n="1"),
        E.ComponentSet(E.Component(E.UUID(qpid()), E.Part(E.Id(part_id)), id=component_id), n="1"),
        E.RootPart(E.Id(part_id)),
        E.AsmPaths(E.AsmPath(id_array("ComponentIds", [component_id]), id=asm_id), n="1"),
    )
    header = E.Header(
        E.Application(E.Name("qifreport"), E.Organization("qifreport project")),
        E.Description(
            f"Measurement plan of {src.part_name} from {Path(src.nominal_path).name} "
            f"(SHA-256 {src.nominal_sha256}): every PMI item of the drawing"
        ),
    )
    children = [
        E.QPId(plan_qpid(src.nominal_sha256)),
        E.Version(E.TimeCreated(xml_time(created))),
        header,
        standards_definitions(src.standard, std_id),
        software_definitions(sw_id),
        file_units(),
        datum_definitions(dids, datum_features),
        datum_reference_frames(drf_ids, dids, referenced="NOMINAL"),
        product,
        zs.features() if zs.fdefs else None,
        zs.characteristics(std_id) if zs.cdefs else None,
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
