"""The definition sections a QIF plan and a QIF results document share: the standard and the
software, the file's units, datums and datum reference frames, and each surface profile's
feature and characteristic (definition, nominal, item) with its acceptance characteristic.

The results document (:mod:`qifreport.qif.writer`) adds the measurements beside them; the plan
(:mod:`qifreport.qif.plan`) adds none. A surface feature names its B-rep faces twice: by their
index in the part's face list (``b_rep_faces``, the ids the deviation outputs use) and by the
STEP file's ``ADVANCED_FACE`` entity (``step_faces``, ``#n`` without the hash) when the nominal
is a STEP file.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from lxml import etree

from qifreport import __version__
from qifreport.kinds import SEPARATE
from qifreport.metrology.acceptance.bands import ToleranceZone

from .modifiers import extent, modifier_flags
from .xmlkit import Attrs, E, Ids, dec, id_array, token

__all__ = [
    "CONFORMS",
    "DOES_NOT_CONFORM",
    "PartIds",
    "Sections",
    "acceptance_definition",
    "datum_definitions",
    "datum_ids",
    "datum_reference_frames",
    "DrfKey",
    "drf_key",
    "drf_name",
    "face_attrs",
    "feature_definition",
    "feature_measurement",
    "file_units",
    "product",
    "profile_definition",
    "profile_feature_name",
    "software_definitions",
    "standards_definitions",
]

#: what a profile zone that is not the drawing's is, by its source
NOT_FROM_DRAWING = {
    "general": "Not from the drawing: the general band the operator stated (--tolerance).",
    "default": (
        "Not from the drawing: qifreport's default band on the faces no tolerance covers; "
        "beside a drawing it is reported, not judged (status UNDEFINED)."
    ),
}

#: the values of a profile's acceptance characteristic (a UserDefinedAttribute)
CONFORMS, DOES_NOT_CONFORM = "CONFORMS", "DOES_NOT_CONFORM"


@dataclass
class Sections:
    """The features' and characteristics' elements, per section, in document order; the
    ``*_ids`` lists are what the ``Product``'s part references."""

    fdefs: list[etree._Element] = field(default_factory=list)
    fnoms: list[etree._Element] = field(default_factory=list)
    fitems: list[etree._Element] = field(default_factory=list)
    fmeas: list[etree._Element] = field(default_factory=list)
    cdefs: list[etree._Element] = field(default_factory=list)
    cnoms: list[etree._Element] = field(default_factory=list)
    citems: list[etree._Element] = field(default_factory=list)
    cmeas: list[etree._Element] = field(default_factory=list)
    fnom_ids: list[str] = field(default_factory=list)
    cnom_ids: list[str] = field(default_factory=list)
    #: the characteristic nominals that are separate requirements (SEP REQT), by frame
    separate: dict[DrfKey, list[str]] = field(default_factory=dict)

    def features(self) -> etree._Element:
        """``Features``: definitions, nominals, items."""
        return E.Features(
            E.FeatureDefinitions(*self.fdefs, n=str(len(self.fdefs))),
            E.FeatureNominals(*self.fnoms, n=str(len(self.fnoms))),
            E.FeatureItems(*self.fitems, n=str(len(self.fitems))),
        )

    def characteristics(self, std_id: str) -> etree._Element:
        """``Characteristics``: the standard, definitions, nominals, items, and the separate
        requirements (SEP REQT) per frame as ``SimultaneousRequirementGroups`` (``SEP_REQ``)."""
        groups = [
            E.SimultaneousRequirementGroup(
                id_array("CharacteristicNominalIds", cns), E.Requirement("SEP_REQ")
            )
            for cns in self.separate.values()
            if cns
        ]
        out = E.Characteristics(
            E.FormalStandardId(std_id),
            E.CharacteristicDefinitions(*self.cdefs, n=str(len(self.cdefs))),
            E.CharacteristicNominals(*self.cnoms, n=str(len(self.cnoms))),
            E.CharacteristicItems(*self.citems, n=str(len(self.citems))),
        )
        if groups:
            out.append(E.SimultaneousRequirementGroups(*groups, n=str(len(groups))))
        return out

    def mark_separate(self, modifiers: list[str], key: DrfKey, cn: str) -> None:
        """Count characteristic nominal ``cn`` (frame ``key``) among the separate
        requirements when its ``modifiers`` say SEP REQT."""
        if SEPARATE in modifiers:
            self.separate.setdefault(key, []).append(cn)


@dataclass
class PartIds:
    """Ids of the part, its component and its assembly path."""

    part: str
    component: str
    asm_path: str


def product(
    part_name: str,
    part: PartIds,
    zs: Sections,
    dids: dict[str, str],
    drf_ids: dict[DrfKey, str],
    ids: Ids,
    *,
    number: str | None = None,
    version: str | None = None,
) -> etree._Element:
    """``Product``: the part (its feature and characteristic nominals, datums, frames), its
    component and assembly path; the part's and component's UUIDs from ``ids``; the part's
    ``number`` (``ModelNumber``) and drawing ``version`` when known."""
    lists = [
        ("FeatureNominalIds", zs.fnom_ids),
        ("CharacteristicNominalIds", zs.cnom_ids),
        ("DatumDefinitionIds", list(dids.values())),
        ("DatumReferenceFrameIds", list(drf_ids.values())),
    ]
    part_el = E.Part(
        E.Header(E.Name(part_name)),
        E.UUID(ids.uuid(part.part, "part")),
        *([E.ModelNumber(number)] if number else []),
        *([E.Version(version)] if version else []),
        *[id_array(name, values) for name, values in lists if values],
        id=part.part,
    )
    component = E.Component(
        E.UUID(ids.uuid(part.component, "component")), E.Part(E.Id(part.part)), id=part.component
    )
    return E.Product(
        E.PartSet(part_el, n="1"),
        E.ComponentSet(component, n="1"),
        E.RootPart(E.Id(part.part)),
        E.AsmPaths(E.AsmPath(id_array("ComponentIds", [part.component]), id=part.asm_path), n="1"),
    )


def standards_definitions(standard: tuple[str, str, str], std_id: str) -> etree._Element:
    """``StandardsDefinitions``: the tolerancing standard (organization, designator, year)."""
    std_org, std_des, std_year = standard
    return E.StandardsDefinitions(
        E.Standard(
            E.Organization(E.StandardsOrganizationEnum(std_org)),
            E.Designator(std_des),
            E.Year(std_year),
            id=std_id,
        ),
        n="1",
    )


def software_definitions(sw_id: str) -> etree._Element:
    """``SoftwareDefinitions``: qifreport and its version."""
    return E.SoftwareDefinitions(
        E.Software(
            E.VendorName("qifreport"),
            E.ApplicationName("qifreport"),
            E.Version(__version__),
            E.Description("Dimensional inspection of flexible parts by virtual fixturing"),
            id=sw_id,
        ),
        n="1",
    )


def file_units() -> etree._Element:
    """``FileUnits``: mm^2, degree, mm."""
    return E.FileUnits(
        E.PrimaryUnits(
            E.AreaUnit(
                E.SIUnitName("square meter"),
                E.UnitName("mm^2"),
                E.UnitConversion(E.Factor("0.000001")),
            ),
            E.AngularUnit(
                E.SIUnitName("radian"),
                E.UnitName("degree"),
                E.UnitConversion(E.Factor("0.0174532925199433")),
            ),
            E.LinearUnit(
                E.SIUnitName("meter"), E.UnitName("mm"), E.UnitConversion(E.Factor("0.001"))
            ),
        )
    )


#: one datum reference of a frame: its label and material boundary (MAXIMUM, LEAST, NONE)
DrfKey = tuple[tuple[str, str], ...]


def drf_key(labels: Sequence[str], materials: Sequence[str] | None = None) -> DrfKey:
    """The key of a datum reference frame: its datums in precedence with their material
    boundary (``NONE`` when not given)."""
    mats = list(materials or [])
    return tuple((lab, mats[k] if k < len(mats) else "NONE") for k, lab in enumerate(labels))


def drf_name(key: DrfKey) -> str:
    """A frame's name as a feature control frame writes it, e.g. ``|A|B(M)|``."""
    mark = {"MAXIMUM": "(M)", "LEAST": "(L)"}
    return "|" + "|".join(lab + mark.get(m, "") for lab, m in key) + "|"


def datum_ids(
    datums: Sequence[str], cited: Iterable[DrfKey], ids: Ids
) -> tuple[dict[str, str], dict[DrfKey, str]]:
    """Ids of the datums (the PMI's, then those ``cited`` by a tolerance) and of one datum
    reference frame per frame cited (:func:`drf_key`, first-cited order)."""
    cited = [tuple(seq) for seq in cited]
    labels = list(dict.fromkeys(list(datums) + [lab for seq in cited for lab, _ in seq]))
    dids = {lab: ids() for lab in labels}
    drf_ids: dict[DrfKey, str] = {}
    for seq in cited:
        if seq:
            drf_ids.setdefault(seq, "")
    for key in drf_ids:
        drf_ids[key] = ids()
    return dids, drf_ids


def datum_definitions(
    dids: dict[str, str], features: dict[str, str] | None = None
) -> etree._Element | None:
    """``DatumDefinitions`` (None without datums); ``features``: label -> the feature
    nominal id of its datum feature, when the document has one."""
    if not dids:
        return None
    features = features or {}
    return E.DatumDefinitions(
        *[
            E.DatumDefinition(
                E.DatumLabel(lab),
                *([id_array("FeatureNominalIds", [features[lab]])] if lab in features else []),
                id=did,
            )
            for lab, did in dids.items()
        ],
        n=str(len(dids)),
    )


def datum_reference_frames(
    drf_ids: dict[DrfKey, str], dids: dict[str, str], referenced: str = "ACTUAL"
) -> etree._Element | None:
    """``DatumReferenceFrames``, one per frame (None without), each datum with its material
    modifier. ``referenced``: ``ACTUAL`` (a results document: the datums simulated on the
    part) or ``NOMINAL`` (a plan)."""
    if not drf_ids:
        return None
    prec = ("PRIMARY", "SECONDARY", "TERTIARY")
    frames = []
    for key, fid in drf_ids.items():
        datums = []
        for k, (lab, mat) in enumerate(key):
            p = (
                E.Precedence(E.PrecedenceEnum(prec[k]))
                if k < 3
                else E.Precedence(E.OtherPrecedence(str(k + 1)))
            )
            datums.append(
                E.Datum(
                    E.SimpleDatum(
                        E.DatumDefinitionId(dids[lab]),
                        E.MaterialModifier(mat),
                        E.ReferencedComponent(referenced),
                    ),
                    p,
                )
            )
        frames.append(
            E.DatumReferenceFrame(
                E.Datums(*datums, n=str(len(datums))), E.Name(drf_name(key)), id=fid
            )
        )
    return E.DatumReferenceFrames(*frames, n=str(len(frames)))


def face_attrs(faces: np.ndarray | None, face_step_ids: np.ndarray | None) -> Attrs:
    """A surface feature's faces as ``Attributes``: ``b_rep_faces`` (indices in the part's
    face list) and, for a STEP nominal, ``step_faces`` (their ``ADVANCED_FACE`` entity ids);
    ``faces=None``: every face no other profile tolerance covers."""
    fa = Attrs()
    if faces is None:
        return fa.s("faces", "every face no other profile tolerance covers")
    faces = np.asarray(faces, dtype=np.int64)
    fa.s("b_rep_faces", " ".join(str(int(f)) for f in faces) or "none")
    if face_step_ids is not None and len(faces):
        known = faces[(faces >= 0) & (faces < len(face_step_ids))]
        step = [int(face_step_ids[f]) for f in known if face_step_ids[f] >= 0]
        if step:
            fa.s("step_faces", " ".join(str(s) for s in step))
    return fa


def feature_definition(
    zs: Sections, fname: str, fa: Attrs, ids: Ids, actual_id: str | None = None
) -> tuple[str, str, str | None]:
    """An ``OtherSurfaceFeature`` definition, nominal (its faces, ``fa``) and item, and its
    measurement when ``actual_id`` (a results document) is given. Returns the nominal, item
    and measurement ids."""
    fd, fn, fi = ids(), ids(), ids()
    zs.fnom_ids.append(fn)
    zs.fdefs.append(E.OtherSurfaceFeatureDefinition(id=fd))
    nom = [
        fa.element(),
        E.Name(fname),
        E.UUID(ids.uuid(fn, "feature-nominal")),
        E.FeatureDefinitionId(fd),
    ]
    zs.fnoms.append(E.OtherSurfaceFeatureNominal(*[x for x in nom if x is not None], id=fn))
    zs.fitems.append(
        E.OtherSurfaceFeatureItem(
            E.FeatureNominalId(fn),
            E.FeatureName(fname),
            E.UUID(ids.uuid(fi, "feature-item")),
            E.DeterminationMode(E.Checked(E.CheckDetails(E.Measured()))),
            id=fi,
        )
    )
    fm = None if actual_id is None else feature_measurement(zs, fi, fname, actual_id, ids)
    return fn, fi, fm


def feature_measurement(zs: Sections, fi: str, fname: str, actual_id: str, ids: Ids) -> str:
    """The measurement of the surface feature item ``fi`` on the inspected part
    ``actual_id``, appended to ``zs``; returns its id."""
    fm = ids()
    zs.fmeas.append(
        E.OtherSurfaceFeatureMeasurement(
            E.FeatureItemId(fi), E.FeatureName(fname), E.ActualComponentId(actual_id), id=fm
        )
    )
    return fm


def profile_feature_name(zone: ToleranceZone) -> str:
    """The surface feature's name of a profile zone."""
    if zone.faces is None:
        return "SURFACE_GENERAL"
    return token(f"SURFACE_{zone.key}")


def profile_definition(
    zs: Sections,
    zone: ToleranceZone,
    rule: str,
    drf_ids: dict[DrfKey, str],
    ids: Ids,
    fn: str,
    fi: str,
) -> str:
    """A ``SurfaceProfileCharacteristic`` definition (the zone and the acceptance rule),
    nominal and item (its designator) on the feature ``fn``/``fi``; returns the item id."""
    cd, cn, ci = ids(), ids(), ids()
    zs.cnom_ids.append(cn)
    zs.mark_separate(zone.modifiers, drf_key(zone.datums, zone.datum_materials), cn)
    da = Attrs().s("key", zone.key).s("source", zone.source)
    da.d("lower_mm", zone.lower).d("upper_mm", zone.upper)
    if zone.step_id is not None:
        da.i("step_entity_id", zone.step_id)
    if zone.modifiers:
        da.s("modifiers", " ".join(zone.modifiers))
    if zone.composite:
        da.s("composite_segment", zone.composite)
    text = f"{zone.describe()}. {rule}." if rule else f"{zone.describe()}."
    if zone.source != "pmi":
        text += f" {NOT_FROM_DRAWING[zone.source]}"
    cdef = [da.element(), E.Description(text), E.Name(token(zone.name))]
    cdef += modifier_flags(zone.modifiers + (["free_state"] if zone.free_state else []))
    cdef.append(E.ToleranceValue(dec(zone.width)))
    if not math.isclose(zone.center, 0.0, abs_tol=1e-12):
        # ASME UZ: the part of the zone outside the material (toward +normal) = upper
        cdef.append(E.UnequallyDisposedZone(dec(zone.upper)))
    if zone.datums:
        cdef.append(E.DatumReferenceFrameId(drf_ids[drf_key(zone.datums, zone.datum_materials)]))
    cdef.append(extent(zone.modifiers))
    zs.cdefs.append(
        E.SurfaceProfileCharacteristicDefinition(*[x for x in cdef if x is not None], id=cd)
    )
    zs.cnoms.append(
        E.SurfaceProfileCharacteristicNominal(
            E.CharacteristicDefinitionId(cd),
            id_array("FeatureNominalIds", [fn]),
            E.Name(token(zone.name)),
            id=cn,
        )
    )
    zs.citems.append(
        E.SurfaceProfileCharacteristicItem(
            E.Name(token(zone.name)),
            E.CharacteristicDesignator(
                E.Designator(zone.key), E.UUID(ids.uuid(ci, "characteristic-item"))
            ),
            id_array("FeatureItemIds", [fi]),
            E.CharacteristicNominalId(cn),
            id=ci,
        )
    )
    return ci


def acceptance_definition(
    zs: Sections, zone: ToleranceZone, rule: str, ids: Ids, fn: str, fi: str
) -> str:
    """The profile's acceptance under qifreport's rule as its own
    ``UserDefinedAttributeCharacteristic`` (``<key>_ACCEPTANCE``, values ``CONFORMS`` /
    ``DOES_NOT_CONFORM``): definition, nominal, item. Returns the item id."""
    cd, cn, ci = ids(), ids(), ids()
    zs.cnom_ids.append(cn)
    name = token(f"{zone.key}_ACCEPTANCE")
    zs.cdefs.append(
        E.UserDefinedAttributeCharacteristicDefinition(
            E.Description(f"{zone.describe()}: {rule}"),
            E.Name(name),
            E.WhatToMeasure(f"{rule}, on the faces of {zone.key}"),
            id=cd,
        )
    )
    zs.cnoms.append(
        E.UserDefinedAttributeCharacteristicNominal(
            E.CharacteristicDefinitionId(cd),
            id_array("FeatureNominalIds", [fn]),
            E.Name(name),
            E.PassValues(E.StringValue(CONFORMS), n="1"),
            E.FailValues(E.StringValue(DOES_NOT_CONFORM), n="1"),
            id=cn,
        )
    )
    zs.citems.append(
        E.UserDefinedAttributeCharacteristicItem(
            E.Name(name),
            E.CharacteristicDesignator(
                E.Designator(f"{zone.key}_ACCEPTANCE"),
                E.UUID(ids.uuid(ci, "characteristic-item")),
            ),
            id_array("FeatureItemIds", [fi]),
            E.CharacteristicNominalId(cn),
            id=ci,
        )
    )
    return ci
