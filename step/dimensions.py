"""Dimensions of the semantic PMI, read from the Part 21 text.

:class:`DimensionReader` reads DIMENSIONAL_SIZE, ANGULAR_SIZE, DIMENSIONAL_LOCATION,
ANGULAR_LOCATION (and their ``_WITH_PATH`` / ``DIRECTED_`` forms): their nominal or limits
from DIMENSIONAL_CHARACTERISTIC_REPRESENTATION (or an AP214 VALUE_RANGE), their tolerance
from PLUS_MINUS_TOLERANCE, their qualifiers and the faces they apply to. Lengths in mm,
angles in degrees.
"""

from __future__ import annotations

from .aspect_faces import PLACEMENT_TYPES, AspectFaceLinker, sorted_unique
from .face_links import LOCATION_TYPES, SIZE_TYPES
from .instance_graph import refs_of, text_of
from .p21 import Entity, Ref
from .pmi import Dimension
from .units import Measure

__all__ = ["DimensionReader"]

#: measure names of a dimension's representation items that are understood
_LIMIT_NAMES = ("lower limit", "upper limit")
#: dimensional notes (DESCRIPTIVE_REPRESENTATION_ITEM('dimensional note', ...)) -> qualifier
_NOTES = {"theoretical": "basic", "auxiliary": "reference"}


class DimensionReader(AspectFaceLinker):
    """Dimensions: sizes and locations, their values and tolerances."""

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
            faces, notes = sorted_unique(origin + target), []
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

        self._plus_minus(ent, dim, expect)
        if not faces:
            problems.extend(n for n in notes if n not in problems)
        if dim.nominal is None and dim.lower_limit is None and dim.upper_limit is None:
            problems.append(f"#{ent.id}: no value found")
        dim.qualifiers = list(dict.fromkeys(dim.qualifiers))
        return dim

    def _plus_minus(self, ent: Entity, dim: Dimension, expect: str) -> None:
        """A dimension's tolerance from its PLUS_MINUS_TOLERANCE: the bounds of a
        TOLERANCE_VALUE (``expect``: ``"length"`` or ``"angle"``) or a LIMITS_AND_FITS
        designation; problems go to ``dim.problems``."""
        for pmt in self.referrers_with(ent.id, ("PLUS_MINUS_TOLERANCE",)):
            pp = pmt.params
            if len(pp) < 2 or pp[1] != Ref(ent.id):
                continue
            rng = self.get(pp[0])
            if rng is None:
                dim.problems.append(f"#{pmt.id}: tolerance range not found")
            elif rng.has("TOLERANCE_VALUE"):
                tp = rng.part("TOLERANCE_VALUE")
                lo = self.measure(tp[0], expect=expect)
                hi = self.measure(tp[1], expect=expect) if len(tp) >= 2 else None
                dim.problems.extend(lo.problems + (hi.problems if hi else []))
                dim.lower = lo.value
                dim.upper = hi.value if hi else None
                if dim.lower is not None and dim.upper is not None and dim.lower > dim.upper:
                    # TOLERANCE_VALUE(+0.005, -0.005): the exporter wrote (upper, lower)
                    dim.warnings.append(
                        f"#{rng.id}: TOLERANCE_VALUE gives its bounds in reverse order "
                        f"({dim.lower:+g}, {dim.upper:+g}): read as {dim.upper:+g} / "
                        f"{dim.lower:+g}"
                    )
                    dim.lower, dim.upper = dim.upper, dim.lower
            elif rng.has("LIMITS_AND_FITS"):
                lp = rng.part("LIMITS_AND_FITS")
                dim.fit = "".join(text_of(x).strip() for x in lp[:3]) or None
                if dim.fit is None:
                    dim.problems.append(f"#{rng.id}: empty LIMITS_AND_FITS")
            else:
                dim.problems.append(f"#{rng.id}: tolerance range {rng.types} not understood")

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
        if lo.value > hi.value:
            dim.warnings.append(
                f"#{ent.id}: VALUE_RANGE names its lower limit {lo.value:g} above its upper "
                f"limit {hi.value:g}: read as {hi.value:g} .. {lo.value:g}"
            )
            lo, hi = hi, lo
        dim.lower_limit, dim.upper_limit = lo.value, hi.value
        texts.append(f"lower limit {lo.text}")
        texts.append(f"upper limit {hi.text}")

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
            if not (ent.has("QUALIFIED_REPRESENTATION_ITEM") or PLACEMENT_TYPES & set(ent.types)):
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
