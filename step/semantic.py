"""Semantic PMI of STEP AP242 files, read from the Part 21 text (no OpenCASCADE).

OCCT's XDE reader loses or corrupts part of the semantic PMI of real files: magnitudes stored
as complex instances ``(LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM()
MEASURE_WITH_UNIT(...))`` come back as 0.0, per-measure units (an inch tolerance in a
millimetre file) are left unconverted, and datum-to-face links that go through
ITEM_IDENTIFIED_REPRESENTATION_USAGE, PLACED_DATUM_TARGET_FEATURE or
COMPOSITE_GROUP_SHAPE_ASPECT are dropped. This module walks the instance graph of
:class:`qifreport.step.p21.P21Model` directly, following the AP242 edition 1 and 2 (and the older
AP214/AP203e2 ``DATUM_REFERENCE``) structures.

* **Geometric tolerances** (simple subtypes or complex instances) give their magnitude,
  characteristic, modifiers, zone form, unequal disposition, maximum, unit-basis and datum
  reference frame (DATUM_SYSTEM / DATUM_REFERENCE_COMPARTMENT / COMMON_DATUM_LIST /
  DATUM_REFERENCE_ELEMENT, or DATUM_REFERENCE / REFERENCED_MODIFIED_DATUM).
* **Dimensions** (DIMENSIONAL_SIZE, ANGULAR_SIZE, DIMENSIONAL_LOCATION, ANGULAR_LOCATION and
  their ``_WITH_PATH`` / ``DIRECTED_`` forms) give their nominal or limits from
  DIMENSIONAL_CHARACTERISTIC_REPRESENTATION and their tolerance from PLUS_MINUS_TOLERANCE.
* **Datums** give their label, datum features and target names.

This module reads those items. It stands on layers that each do one thing: attribute access
and navigation (:mod:`.instance_graph`), units and measures converted to mm and degrees
(:mod:`.units`), the faces each item applies to (:mod:`.face_links`), helped, for non-face
geometry, by a small B-rep geometry kernel (:mod:`.brep_geometry`).

Nothing is guessed: a value that cannot be established is ``None`` and a problem string says
why. Entry points: :func:`read_pmi_text` (a path) and :func:`pmi_from_model` (a parsed model).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable
from pathlib import Path

from qifreport.kinds import KINDS, kind_for_step_entity, lookup_kind

from .face_links import LOCATION_TYPES, SIZE_TYPES, TARGET_TYPES, FaceLinker
from .instance_graph import enum_names, refs_of, text_of
from .p21 import Entity, Enum, P21Model, Ref
from .pmi import PMI, Datum, DatumRef, DatumTarget, Dimension, GeometricTolerance
from .units import Measure, Unit, length_name, number_text

log = logging.getLogger(__name__)

__all__ = ["Measure", "Unit", "pmi_from_model", "read_pmi_text"]

# --------------------------------------------------------------------------------------------
# vocabulary
# --------------------------------------------------------------------------------------------

#: instances of any of these (or of a registered kind's entity,
#: :func:`qifreport.kinds.kind_for_step_entity`) are geometric tolerances (the characteristic
#: may be missing)
_GT_OTHER = (
    "GEOMETRIC_TOLERANCE",
    "MODIFIED_GEOMETRIC_TOLERANCE",
    "GEOMETRIC_TOLERANCE_WITH_DATUM_REFERENCE",
    "GEOMETRIC_TOLERANCE_WITH_MODIFIERS",
    "GEOMETRIC_TOLERANCE_WITH_DEFINED_UNIT",
    "UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE",
)
#: representation relationships followed from a product shape to its B-rep representations
#: (not CONSTRUCTIVE_GEOMETRY_REPRESENTATION_RELATIONSHIP: supplemental geometry)
_SHAPE_REP_RELATIONSHIPS = ("SHAPE_REPRESENTATION_RELATIONSHIP", "REPRESENTATION_RELATIONSHIP")
#: representation items of a PROPERTY_DEFINITION -> SHAPE_DEFINITION_REPRESENTATION face link
#: that only place the aspect (not geometry it consists of)
_PLACEMENT_TYPES = frozenset({"AXIS2_PLACEMENT_3D", "AXIS2_PLACEMENT_2D", "AXIS1_PLACEMENT"})
#: measure names of a dimension's representation items that are understood
_LIMIT_NAMES = ("lower limit", "upper limit")
#: dimensional notes (DESCRIPTIVE_REPRESENTATION_ITEM('dimensional note', ...)) -> qualifier
_NOTES = {"theoretical": "basic", "auxiliary": "reference"}


def _sorted_unique(ids: Iterable[int]) -> list[int]:
    return sorted(set(ids))


# --------------------------------------------------------------------------------------------
# the reader
# --------------------------------------------------------------------------------------------


class _Reader(FaceLinker):
    """Resolution state for one model (caches units, measures and face sets).

    Units and measures come from :class:`~qifreport.step.units.MeasureReader`, faces from
    :class:`~qifreport.step.face_links.FaceLinker`; this layer reads datums, geometric
    tolerances and dimensions.
    """

    # ---- faces: the older PROPERTY_DEFINITION -> SHAPE_DEFINITION_REPRESENTATION link -----
    def _collect(self, eid: int, seen: set[int], found: set[int], others: list[Ref]) -> None:
        """Faces of an aspect, also through PROPERTY_DEFINITION -> SHAPE_DEFINITION_REPRESENTATION.

        Extends :class:`~qifreport.step.face_links.FaceLinker`'s walk (called for the aspect
        and each component it recurses into) with the AP214 link of older exports (an I-DEAS
        AP214 file): ``PROPERTY_DEFINITION(name, description, #aspect)`` and a
        ``SHAPE_DEFINITION_REPRESENTATION(#property, #rep)`` whose representation lists the
        faces (or shells, solids, other geometry). Placements in that representation and datum
        targets (whose representation is their placement) are left to the base walk.
        """
        fresh = eid not in seen
        super()._collect(eid, seen, found, others)
        if not fresh or TARGET_TYPES.intersection(self.types(eid)):
            return
        for items in self._property_shape_items(eid):
            kept = [r for r in items if not _PLACEMENT_TYPES.intersection(self.types(r))]
            self._items(tuple(kept), found, others)

    def _property_shape_items(self, eid: int) -> list[list[Ref]]:
        """Items of the shape representations given to an aspect through a property."""
        out = []
        for pd in self.referrers_with(eid, ("PROPERTY_DEFINITION",)):
            pp = pd.part("PROPERTY_DEFINITION") or ()
            if len(pp) < 3 or pp[2] != Ref(eid):
                continue
            for sdr in self.referrers_with(pd.id, ("SHAPE_DEFINITION_REPRESENTATION",)):
                sp = sdr.params
                rep = self.get(sp[1]) if len(sp) >= 2 and sp[0] == Ref(pd.id) else None
                rp = self.params_of(rep, ("REPRESENTATION", *rep.types)) if rep else None
                if rp and len(rp) >= 2:
                    out.append(refs_of(rp[1]))
        return out

    # ---- datums -------------------------------------------------------------------------
    def datum_target(self, name: str, tid: int, tp) -> DatumTarget:
        """A target's kind, placement (mm: its representation's AXIS2_PLACEMENT_3D, named
        'orientation' by AP242) and faces (its FEATURE_FOR_DATUM_TARGET_RELATIONSHIP's
        shape aspect's)."""
        kind = (text_of(tp[1]) if len(tp) >= 2 else "") or ""
        position = direction = x_direction = None
        sizes: dict[str, float] = {}
        scale = self.context_length.scale or 1.0

        def unit(ref: object) -> list[float] | None:
            ent = self.get(ref) if isinstance(ref, Ref) else None
            if ent is None or not ent.has("DIRECTION"):
                return None
            d = [float(x) for x in ent.part("DIRECTION")[1]] + [0.0] * 3
            n = math.sqrt(sum(x * x for x in d[:3]))
            return [x / n for x in d[:3]] if n > 0 else None

        for items in self._property_shape_items(tid):
            for r in items:
                pl = self.get(r)
                if pl is not None and pl.has("MEASURE_REPRESENTATION_ITEM"):
                    # the target's size: 'target length', 'target width', 'target diameter'
                    item = self.item_name(pl).strip().lower()
                    meas = self.measure(r, expect="length")
                    if item.startswith("target ") and meas.value is not None:
                        sizes[item[len("target ") :]] = meas.value
                    continue
                pp = pl.part("AXIS2_PLACEMENT_3D") if pl is not None else None
                if not pp or len(pp) < 3 or position is not None:
                    continue
                loc = self.get(pp[1])
                if loc is not None and loc.has("CARTESIAN_POINT"):
                    c = [float(x) for x in loc.part("CARTESIAN_POINT")[1]] + [0.0] * 3
                    position = [scale * x for x in c[:3]]
                direction = unit(pp[2])
                x_direction = unit(pp[3]) if len(pp) >= 4 else None
            if position is not None:
                break
        faces: set[int] = set()
        for rel in self.referrers_with(tid, ("FEATURE_FOR_DATUM_TARGET_RELATIONSHIP",)):
            rp = rel.params
            if len(rp) >= 4 and rp[3] == Ref(tid) and isinstance(rp[2], Ref):
                faces.update(self.faces(rp[2])[0])
        return DatumTarget(
            name=name,
            step_id=tid,
            kind=kind,
            position=position,
            direction=direction,
            face_step_ids=sorted(faces),
            x_direction=x_direction,
            length=sizes.get("length"),
            width=sizes.get("width"),
            diameter=sizes.get("diameter"),
        )

    def datum_label(self, ref: object) -> tuple[str, list[int], list[str]]:
        """Label, datum ids and per-element modifiers of a datum or a common datum."""
        ent = self.get(ref)
        if ent is None:
            return "?", [], []
        if ent.has("DATUM"):
            p = ent.part("DATUM")
            return (text_of(p[4]) if len(p) >= 5 else "?") or "?", [ent.id], []
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
        for r in refs_of(base):
            lab, i, m = self.datum_label(r)
            labels.append(lab)
            ids.extend(i)
            mods.extend(m)
        return ("-".join(labels) or "?"), ids, mods

    def _modifiers(self, value: object) -> list[str]:
        """Datum reference modifiers: simple enumerations or DATUM_REFERENCE_MODIFIER_WITH_VALUE."""
        out = enum_names(value)
        for r in refs_of(value):
            ent = self.get(r)
            p = ent.part("DATUM_REFERENCE_MODIFIER_WITH_VALUE") if ent else None
            if p and len(p) >= 2:
                name = p[0].name.lower() if isinstance(p[0], Enum) else "modifier"
                meas = self.measure(p[1])
                unit = "mm" if meas.kind == "length" else "deg" if meas.kind == "angle" else ""
                val = number_text(meas.value) if meas.value is not None else meas.text
                out.append(f"{name} {val} {unit}".strip())
        return out

    def datum_system(self, refs: object, problems: list[str]) -> list[DatumRef]:
        """Datum reference frame of a tolerance from its datum_system attribute."""
        out: list[DatumRef] = []
        for ref in refs_of(refs):
            ent = self.get(ref)
            if ent is None:
                problems.append(f"datum system #{ref.id} not found")
                continue
            if ent.has("DATUM_SYSTEM"):
                p = ent.part("DATUM_SYSTEM")
                for prec, comp in enumerate(refs_of(p[4] if len(p) >= 5 else ()), start=1):
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
                mods = enum_names(p[2]) if p and len(p) >= 3 else []
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
            label = text_of(p[4]) if len(p) >= 5 else ""
            problems: list[str] = []
            if not label:
                problems.append(f"#{ent.id}: datum without identification")
            targets, features, details = [], [], {}
            for rel in self.referrers_with(ent.id, ("SHAPE_ASPECT_RELATIONSHIP",)):
                rp = rel.params
                if len(rp) >= 4 and rp[3] == Ref(ent.id) and isinstance(rp[2], Ref):
                    features.append(rp[2].id)
                    src = self.get(rp[2])
                    tp = self.params_of(src, TARGET_TYPES) if src else None
                    if tp is not None:
                        tid = text_of(tp[4]) if len(tp) >= 5 else ""
                        targets.append(f"{label}{tid}")
                        details.setdefault(
                            f"{label}{tid}", self.datum_target(f"{label}{tid}", src.id, tp)
                        )
            faces, notes, face_notes = self.faces(Ref(ent.id))
            problems.extend(notes)
            out.append(
                Datum(
                    step_id=ent.id,
                    label=label,
                    face_step_ids=faces,
                    targets=sorted(set(targets), key=_natural),
                    target_details=[details[t] for t in sorted(details, key=_natural)],
                    problems=problems,
                    feature_step_ids=_sorted_unique(features),
                    face_notes=face_notes,
                )
            )
        return out

    # ---- geometric tolerances -----------------------------------------------------------
    def tolerances(self) -> list[GeometricTolerance]:
        ids: set[int] = set()
        for t in (*(e for k in KINDS.values() for e in k.step_entities), *_GT_OTHER):
            ids.update(e.id for e in self.m.by_type(t))
        composite: dict[int, list[int]] = {}
        for rel in self.m.by_type("GEOMETRIC_TOLERANCE_RELATIONSHIP"):
            p = rel.params
            if (
                len(p) >= 4
                and text_of(p[0]).strip().lower() == "composite"
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
        kinds = [k.name for t in ent.types if (k := kind_for_step_entity(t)) is not None]
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
        name = text_of(base[0]) if base else ""
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
        if drf is None and extra and refs_of(extra[0]):
            drf = (extra[0],)
        datums = self.datum_system(drf[0], problems) if drf else []

        # modifiers
        modifiers: list[str] = []
        p = ent.part("GEOMETRIC_TOLERANCE_WITH_MODIFIERS")
        if p is not None:
            modifiers += enum_names(p[-1] if ent.parts is None else p[0] if p else ())
        p = ent.part("MODIFIED_GEOMETRIC_TOLERANCE")
        if p:
            modifiers += enum_names(p[-1])
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
                    zone_form = text_of(fp[0]) or None
            for zdef in self.referrers_with(zone.id, ("PROJECTED_ZONE_DEFINITION",)):
                zdp = zdef.part("PROJECTED_ZONE_DEFINITION")
                length = self.measure(zdp[-1]).value if zdp else None
                modifiers.append(
                    f"projected {number_text(length)} mm" if length is not None else "projected"
                )

        faces: list[int] = []
        face_notes: list[str] = []
        whole = False
        if tsa_ent is None:
            problems.append(f"#{ent.id}: no toleranced shape aspect")
        else:
            faces, notes, face_notes = self.faces(tsa)
            why = self._whole_part_reason(tsa_ent, gtype, faces, notes, modifiers)
            if why:
                whole = True
                faces, how = self.part_faces(tsa_ent)
                face_notes = [f"whole part ({why}): {how}"]
                if not faces:
                    problems.append(f"#{ent.id}: whole-part tolerance, but {how}")
            else:
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
            whole_part=whole,
        )

    def _whole_part_reason(
        self, tsa: Entity, gtype: str, faces: list[int], notes: list[str], modifiers: list[str]
    ) -> str:
        """Why a tolerance applies to the whole part ('' when it does not).

        The toleranced shape aspect is the PRODUCT_DEFINITION_SHAPE itself (NIST FTC 07 #16292,
        FTC 10 #18552), or, for a profile, a shape aspect linked to no geometry at all (all-over,
        all-around or plain): both mean every surface of the part. A shape aspect linked to
        geometry that carries no face is not a whole-part tolerance (its problems say so).
        """
        if tsa.has("PRODUCT_DEFINITION_SHAPE"):
            return f"toleranced shape aspect #{tsa.id} is the PRODUCT_DEFINITION_SHAPE"
        # a profile whose shape aspect has no face link at all is a whole-part profile
        kind = lookup_kind(gtype)
        if kind is None or kind.family != "profile" or faces:
            return ""
        if not all("no associated geometry found" in n for n in notes):
            return ""
        mods = [m for m in modifiers if m in ("all_over", "all_around")]
        what = f"{mods[0].replace('_', '-')} " if mods else ""
        return f"{what}shape aspect #{tsa.id} has no face link"

    def part_faces(self, aspect: Entity) -> tuple[list[int], str]:
        """Every face of the product shape a shape aspect (or the shape itself) belongs to.

        Follows SHAPE_DEFINITION_REPRESENTATION from the PRODUCT_DEFINITION_SHAPE to its
        representations, then (SHAPE_)REPRESENTATION_RELATIONSHIPs to the B-rep
        representations, whose solids and shells give the faces.

        Returns
        -------
        faces : list of int
            Sorted face ids (empty when none is found).
        how : str
            Human-readable derivation, e.g. ``'all 15 faces of PRODUCT_DEFINITION_SHAPE #4'``.
        """
        pds = aspect
        if not aspect.has("PRODUCT_DEFINITION_SHAPE"):
            # SHAPE_ASPECT or a simple subtype instance (ALL_AROUND_SHAPE_ASPECT(...)): the
            # shape aspect attributes come first
            p = aspect.part("SHAPE_ASPECT") or (aspect.params if aspect.parts is None else ())
            pds = self.get(p[2]) if len(p) >= 3 else None
        if pds is None:
            return [], f"shape aspect #{aspect.id} names no product shape"
        reps: list[int] = []
        for sdr in self.referrers_with(pds.id, ("SHAPE_DEFINITION_REPRESENTATION",)):
            if len(sdr.params) >= 2 and sdr.params[0] == Ref(pds.id):
                reps.extend(r.id for r in refs_of(sdr.params[1]))
        seen: set[int] = set()
        found: set[int] = set()
        others: list[Ref] = []
        while reps:
            rid = reps.pop()
            if rid in seen:
                continue
            seen.add(rid)
            rep = self.get(Ref(rid))
            rp = self.params_of(rep, ("REPRESENTATION", *rep.types)) if rep else None
            if rp and len(rp) >= 2:
                self._items(rp[1], found, others)
            for rel in self.referrers_with(rid, _SHAPE_REP_RELATIONSHIPS):
                relp = self.params_of(rel, _SHAPE_REP_RELATIONSHIPS) or ()
                reps.extend(r.id for r in refs_of(relp[2:4]) if r.id not in seen)
        if not found:
            return [], f"no face found under PRODUCT_DEFINITION_SHAPE #{pds.id}"
        return sorted(found), f"all {len(found)} faces of PRODUCT_DEFINITION_SHAPE #{pds.id}"

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
        first = f"{number_text(size.value)} mm" if size.value is not None else size.text
        area_p = ent.part("GEOMETRIC_TOLERANCE_WITH_DEFINED_AREA_UNIT")
        if not area_p:
            return f"per unit length {first}"
        area = area_p[0].name.lower() if area_p and isinstance(area_p[0], Enum) else "area"
        second = None
        if len(area_p) >= 2 and isinstance(area_p[1], Ref):
            sm = self.measure(area_p[1], expect="length")
            problems.extend(sm.problems)
            second = f"{number_text(sm.value)} mm" if sm.value is not None else sm.text
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
            name = text_of(size[1]) if len(size) >= 2 else ""
            faces, notes, face_notes = self.faces(size[0] if size else None)
        else:
            kind = "location"
            loc = self.params_of(ent, LOCATION_TYPES) or ()
            if len(loc) < 4 and ent.parts is not None:
                # a complex instance (AP214 exports): the attributes sit in its supertype part
                loc = ent.part("SHAPE_ASPECT_RELATIONSHIP") or loc
                if len(loc) < 4:
                    problems.append(f"#{ent.id}: location without relating/related aspects")
            name = text_of(loc[0]) if loc else ""
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
        texts: list[str] = []
        others: list[tuple[Entity, Measure, str]] = []
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
                item = self.get(item_ref)
                if item is not None and item.has("VALUE_RANGE"):
                    self._value_range(item, dim, expect, texts)
                else:
                    self._dimension_item(item_ref, dim, expect, texts, others)
        if not reps:
            problems.append(f"#{ent.id}: no DIMENSIONAL_CHARACTERISTIC_REPRESENTATION")
        self._other_measures(others, dim, texts)
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
                dim.fit = "".join(text_of(x).strip() for x in lp[:3]) or None
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
        for r in refs_of(items):
            ent = self.get(r)
            if ent is not None and ent.has("COMPOUND_REPRESENTATION_ITEM"):
                p = ent.part("COMPOUND_REPRESENTATION_ITEM")
                out.extend(self._flat_items(p[1:] if p else ()))
            else:
                out.append(r)
        return out

    def _value_range(self, ent: Entity, dim: Dimension, expect: str, texts: list[str]) -> None:
        """VALUE_RANGE(name, (lower, upper)): the limits of a dimension (AP214 exports).

        Members named 'lower limit' / 'upper limit' are taken by name, unnamed ones by value
        (the smaller is the lower limit).
        """
        p = ent.part("VALUE_RANGE") or ()
        members = self._flat_items(p[1:] if p else ())
        measured = []
        for r in members:
            m_ent = self.get(r)
            if m_ent is None:
                continue
            meas = self.measure(r, expect=expect)
            dim.problems.extend(meas.problems)
            measured.append((self.item_name(m_ent).strip().lower(), meas))
        values = [m for _, m in measured if m.value is not None]
        named = {n: m for n, m in measured if n in _LIMIT_NAMES and m.value is not None}
        if len(named) == 2:
            lo, hi = named["lower limit"], named["upper limit"]
        elif len(values) == 2:
            lo, hi = sorted(values, key=lambda m: m.value)
        else:
            dim.problems.append(
                f"#{ent.id}: VALUE_RANGE with {len(values)} readable limit(s) of {len(members)}"
            )
            return
        dim.lower_limit, dim.upper_limit = lo.value, hi.value
        texts.append(f"lower limit {lo.text}")
        texts.append(f"upper limit {hi.text}")
        if lo.value > hi.value:
            dim.problems.append(f"#{ent.id}: lower limit above upper limit")

    def _other_measures(
        self, others: list[tuple[Entity, Measure, str]], dim: Dimension, texts: list[str]
    ) -> None:
        """Measures with a name other than the AP242 ones (older exports: a plain
        MEASURE_REPRESENTATION_ITEM('distance', LENGTH_MEASURE(40.), #4)).

        The only one of a dimension that has no nominal and no limits is its nominal value
        (noted); otherwise each is listed as not understood.
        """
        if not others:
            return
        if len(others) == 1 and dim.nominal is None and dim.lower_limit is None:
            ent, meas, name = others[0]
            if meas.value is not None:
                dim.nominal = meas.value
                texts.append(meas.text)
                dim.problems.append(f"#{ent.id}: measure {name!r} taken as the nominal value")
                return
        for ent, meas, name in others:
            dim.problems.append(f"#{ent.id}: measure {name!r} not understood ({meas.text})")

    def _dimension_item(
        self,
        ref: Ref,
        dim: Dimension,
        expect: str,
        texts: list[str],
        others: list[tuple[Entity, Measure, str]],
    ) -> None:
        ent = self.get(ref)
        if ent is None:
            dim.problems.append(f"#{ref.id}: dimension value item not found")
            return
        if ent.has("DESCRIPTIVE_REPRESENTATION_ITEM"):
            p = ent.part("DESCRIPTIVE_REPRESENTATION_ITEM")
            if p and len(p) >= 2 and text_of(p[0]).lower() == "dimensional note":
                note = text_of(p[1]).strip().lower()
                dim.qualifiers.append(_NOTES.get(note, note))
            else:
                name, text = (text_of(p[0]), text_of(p[1])) if p and len(p) >= 2 else ("", "")
                dim.problems.append(
                    f"#{ent.id}: descriptive item {name!r} not understood ({text!r})"
                )
            return
        if not (ent.has("MEASURE_REPRESENTATION_ITEM") or ent.has("MEASURE_WITH_UNIT")):
            if not (ent.has("QUALIFIED_REPRESENTATION_ITEM") or _PLACEMENT_TYPES & set(ent.types)):
                dim.problems.append(f"#{ent.id}: value item {'+'.join(ent.types)} not understood")
            return
        name = self.item_name(ent).strip().lower()
        meas = self.measure(ref, expect=expect)
        dim.problems.extend(meas.problems)
        for q in refs_of(ent.part("QUALIFIED_REPRESENTATION_ITEM") or ()):
            qent = self.get(q)
            if qent is None:
                continue
            qp = qent.params if qent.parts is None else ()
            if qent.has("VALUE_FORMAT_TYPE_QUALIFIER") and qp:
                if name in ("nominal value", "") and dim.value_format is None:
                    dim.value_format = text_of(qp[0]) or None
            elif qent.has("TYPE_QUALIFIER") and qp:
                dim.qualifiers.append(text_of(qp[0]).strip().lower())
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
            others.append((ent, meas, name))

    # ---- items that refer to nothing read ----------------------------------------------
    def unread_references(
        self, tolerances: list[GeometricTolerance], dimensions: list[Dimension]
    ) -> list[str]:
        """Values and tolerances of dimensions, and tolerance relationships, whose target
        was not read as a dimension or tolerance: listed with the entity id and why."""
        dims = {d.step_id for d in dimensions}
        tols = {t.step_id for t in tolerances}
        out = []
        for etype, index, known, what in (
            ("DIMENSIONAL_CHARACTERISTIC_REPRESENTATION", 0, dims, "dimension"),
            ("PLUS_MINUS_TOLERANCE", 1, dims, "dimension"),
            ("GEOMETRIC_TOLERANCE_RELATIONSHIP", 2, tols, "geometric tolerance"),
            ("GEOMETRIC_TOLERANCE_RELATIONSHIP", 3, tols, "geometric tolerance"),
        ):
            for ent in self.m.by_type(etype):
                p = ent.part(etype) or ()
                target = p[index] if len(p) > index else None
                if not isinstance(target, Ref):
                    out.append(f"#{ent.id}: {etype} without a {what}")
                elif target.id not in known:
                    types = "+".join(self.types(target)) or "missing entity"
                    out.append(
                        f"#{ent.id}: {etype} refers to #{target.id} ({types}), "
                        f"not a {what} that could be read"
                    )
        return list(dict.fromkeys(out))


def _natural(label: str) -> tuple:
    """Sort key: 'A2' before 'A10'."""
    head = label.rstrip("0123456789")
    tail = label[len(head) :]
    return head, int(tail) if tail else -1


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
    unread = r.unread_references(tolerances, dimensions)
    t2 = time.perf_counter()
    pmi = PMI(
        schema=model.schema,
        length_unit=length_name(r.context_length),
        length_scale=r.context_length.scale or 1.0,
        tolerances=tolerances,
        dimensions=dimensions,
        datums=datums,
        problems=list(dict.fromkeys(r.problems + unread)),
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
