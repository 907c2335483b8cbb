"""Geometric tolerances of the semantic PMI, read from the Part 21 text.

:class:`ToleranceReader` reads every geometric tolerance (simple subtypes or complex
instances): its magnitude, characteristic, modifiers, zone form, unequal disposition,
maximum, unit-basis, datum reference frame (:class:`~qifreport.step.datums.DatumReader`) and
the faces it applies to, the whole part's when its shape aspect is the product shape.
Lengths in mm.
"""

from __future__ import annotations

from qifreport.kinds import KINDS, kind_for_step_entity, lookup_kind

from .datums import DatumReader
from .instance_graph import enum_names, refs_of, text_of
from .p21 import Entity, Enum, Ref
from .pmi import GeometricTolerance
from .units import number_text

__all__ = ["ToleranceReader"]

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


class ToleranceReader(DatumReader):
    """Geometric tolerances, with their datum reference frames."""

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

        tsa_ent = self.get(tsa)
        modifiers = self._tolerance_modifiers(ent, tsa_ent)

        unequal = self._optional_length(ent, "UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE", problems)
        max_value = self._optional_length(
            ent, "GEOMETRIC_TOLERANCE_WITH_MAXIMUM_TOLERANCE", problems
        )
        unit_basis = self._unit_basis(ent, problems)

        zone_form = self._zone_form(ent, modifiers)
        faces, face_notes, whole = self._toleranced_faces(
            ent, tsa, tsa_ent, gtype, modifiers, problems
        )
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

    def _tolerance_modifiers(self, ent: Entity, tsa_ent: Entity | None) -> list[str]:
        """A tolerance's modifiers: its enumerations (GEOMETRIC_TOLERANCE_WITH_MODIFIERS,
        MODIFIED_GEOMETRIC_TOLERANCE) and those its toleranced shape aspect ``tsa_ent``
        implies (all around, between, all over, continuous feature)."""
        modifiers: list[str] = []
        p = ent.part("GEOMETRIC_TOLERANCE_WITH_MODIFIERS")
        if p is not None:
            modifiers += enum_names(p[-1] if ent.parts is None else p[0] if p else ())
        p = ent.part("MODIFIED_GEOMETRIC_TOLERANCE")
        if p:
            modifiers += enum_names(p[-1])
        if tsa_ent is not None:
            if tsa_ent.has("ALL_AROUND_SHAPE_ASPECT"):
                modifiers.append("all_around")
            if tsa_ent.has("BETWEEN_SHAPE_ASPECT"):
                modifiers.append("between")
            if tsa_ent.has("ALL_OVER_SHAPE_ASPECT") or tsa_ent.has("CONTINUOUS_SHAPE_ASPECT"):
                modifiers.append(
                    "all_over" if tsa_ent.has("ALL_OVER_SHAPE_ASPECT") else "continuous_feature"
                )
        return modifiers

    def _zone_form(self, ent: Entity, modifiers: list[str]) -> str | None:
        """The form of a tolerance's TOLERANCE_ZONE (None: not given); a projected zone's
        length is added to ``modifiers`` (mm)."""
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
        return zone_form

    def _toleranced_faces(
        self,
        ent: Entity,
        tsa: object,
        tsa_ent: Entity | None,
        gtype: str,
        modifiers: list[str],
        problems: list[str],
    ) -> tuple[list[int], list[str], bool]:
        """The faces a tolerance applies to, their notes, and whether it is a whole-part
        tolerance (:meth:`_whole_part_reason`); its problems are added to ``problems``."""
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
        return faces, face_notes, whole

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
