"""Datums and datum reference frames of the semantic PMI, read from the Part 21 text.

:class:`DatumReader` reads every DATUM with the faces of its features, its targets (kind,
placement, size and faces, :class:`~qifreport.step.pmi.DatumTarget`) and the datum reference
frame of a tolerance (DATUM_SYSTEM / DATUM_REFERENCE_COMPARTMENT / COMMON_DATUM_LIST /
DATUM_REFERENCE_ELEMENT, or the older DATUM_REFERENCE / REFERENCED_MODIFIED_DATUM).
Lengths in mm.
"""

from __future__ import annotations

import math

from .aspect_faces import AspectFaceLinker, sorted_unique
from .face_links import TARGET_TYPES
from .instance_graph import enum_names, refs_of, text_of
from .p21 import Enum, Ref
from .pmi import Datum, DatumRef, DatumTarget
from .units import number_text

__all__ = ["DatumReader"]


class DatumReader(AspectFaceLinker):
    """Datums, their targets and the datum reference frames of tolerances."""

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
                    feature_step_ids=sorted_unique(features),
                    face_notes=face_notes,
                )
            )
        return out


def _natural(label: str) -> tuple:
    """Sort key: 'A2' before 'A10'."""
    head = label.rstrip("0123456789")
    tail = label[len(head) :]
    return head, int(tail) if tail else -1
