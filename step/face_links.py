"""Association of PMI items with B-rep faces, through the shape aspects of the file.

A shape aspect is mapped to faces through GEOMETRIC_ITEM_SPECIFIC_USAGE and
ITEM_IDENTIFIED_REPRESENTATION_USAGE, recursing through SHAPE_ASPECT_RELATIONSHIP and
SHAPE_ASPECT_DERIVING_RELATIONSHIP (composite, composite group, all-around, derived aspects ->
their components); a dimension is mapped to the faces of its feature(s), and a DATUM to those of
its datum features and, through FEATURE_FOR_DATUM_TARGET_RELATIONSHIP, of its target features.
Shells and solids stand for all their faces. When the file associates a feature with non-face
geometry only (datum target points and lines, thread cylinders, axes, edges),
:class:`~qifreport.step.brep_geometry.FaceLocator` finds the faces carrying that geometry or
coaxial with it, and the face notes say so. :class:`FaceLinker` does this for one model, with
caching.
"""

from __future__ import annotations

from .brep_geometry import FACE_TYPES, FaceLocator
from .instance_graph import refs_of, text_of
from .p21 import P21Model, Ref
from .units import MeasureReader

__all__ = ["LOCATION_TYPES", "SIZE_TYPES", "TARGET_TYPES", "FaceLinker"]

#: dimension entity types; a dimension applies to the faces of its feature(s)
SIZE_TYPES = (
    "DIMENSIONAL_SIZE",
    "ANGULAR_SIZE",
    "DIMENSIONAL_SIZE_WITH_PATH",
    "DIMENSIONAL_SIZE_WITH_DATUM_FEATURE",
)
LOCATION_TYPES = (
    "DIMENSIONAL_LOCATION",
    "ANGULAR_LOCATION",
    "DIMENSIONAL_LOCATION_WITH_PATH",
    "DIRECTED_DIMENSIONAL_LOCATION",
    "DIMENSIONAL_LOCATION_WITH_DATUM_FEATURE",
)
#: shells and solids whose faces are all meant
_SHELL_TYPES = frozenset(
    {
        "CLOSED_SHELL",
        "OPEN_SHELL",
        "ORIENTED_CLOSED_SHELL",
        "TESSELLATED_SHELL",
        "TESSELLATED_SOLID",
    }
)
_SOLID_TYPES = frozenset({"MANIFOLD_SOLID_BREP", "BREP_WITH_VOIDS"})
#: usages linking a shape aspect to representation items; DRAUGHTING_MODEL_ITEM_ASSOCIATION is
#: also an ITEM_IDENTIFIED_REPRESENTATION_USAGE but points at presentation, so it is excluded
_USAGE_TYPES = frozenset({"GEOMETRIC_ITEM_SPECIFIC_USAGE", "ITEM_IDENTIFIED_REPRESENTATION_USAGE"})
#: shape aspect relationships followed from the relating (whole) to the related (part)
_PART_OF_TYPES = frozenset({"SHAPE_ASPECT_RELATIONSHIP", "SHAPE_ASPECT_DERIVING_RELATIONSHIP"})
#: datums and datum targets: a datum's faces are its features', a target's its target features'
_DATUM_TYPES = frozenset({"DATUM"})
TARGET_TYPES = frozenset({"DATUM_TARGET", "PLACED_DATUM_TARGET_FEATURE"})


class FaceLinker(MeasureReader):
    """Faces of the shape aspects, dimensions and datums of one model (cached).

    Parameters
    ----------
    model : P21Model
        The parsed file.
    """

    def __init__(self, model: P21Model) -> None:
        super().__init__(model)
        self._faces: dict[int, tuple[frozenset[int], tuple[str, ...], tuple[str, ...]]] = {}
        self._geometry: FaceLocator | None = None

    # ---- faces --------------------------------------------------------------------------
    @property
    def geometry(self) -> FaceLocator:
        """The geometric locator (built on first use)."""
        if self._geometry is None:
            self._geometry = FaceLocator(self)
        return self._geometry

    def faces(self, ref: object) -> tuple[list[int], list[str], list[str]]:
        """Faces of a shape aspect, dimension or datum.

        Returns
        -------
        faces : list of int
            Sorted face ids.
        problems : list of str
            Why no face (or not every item) could be found.
        notes : list of str
            How faces were derived from non-face items (edges, curves, points).
        """
        if not isinstance(ref, Ref) or ref.id not in self.m.raw:
            return [], [f"no shape aspect ({ref!r})"], []
        cached = self._faces.get(ref.id)
        if cached is None:
            found: set[int] = set()
            others: list[Ref] = []
            self._collect(ref.id, set(), found, others)
            problems: list[str] = []
            notes: list[str] = []
            unplaced: dict[str, int] = {}
            derived: dict[str, dict[str, int]] = {}
            for item in dict.fromkeys(others):
                faces, how = self.geometry.locate(item)
                kind = self._type_label(item)
                if faces:
                    found |= faces
                    derived.setdefault(how, {}).setdefault(kind, 0)
                    derived[how][kind] += 1
                else:
                    unplaced[kind] = unplaced.get(kind, 0) + 1
            for how, kinds in derived.items():
                notes.append(f"faces {how}: {_count_text(kinds)}")
            if unplaced:
                what = _count_text(unplaced)
                if found:
                    notes.append(f"items not placed on faces: {what}")
                else:
                    problems.append(f"associated geometry has no faces, only: {what}")
            elif not found:
                problems.append(f"#{ref.id}: no associated geometry found")
            cached = (frozenset(found), tuple(problems), tuple(notes))
            self._faces[ref.id] = cached
        return sorted(cached[0]), list(cached[1]), list(cached[2])

    def _type_label(self, ref: Ref) -> str:
        """The item's entity type, and its name for a named set of supplemental geometry
        (``"GEOMETRIC_CURVE_SET 'Thread Cylinder.1'"``: what the geometry stands for)."""
        types = self.types(ref)
        label = types[0] if len(types) == 1 else "+".join(types) or f"#{ref.id}?"
        if label in ("GEOMETRIC_CURVE_SET", "GEOMETRIC_SET"):
            ent = self.get(ref)
            p = ent.part(label) if ent is not None else None
            name = text_of(p[0]) if p else ""
            if name:
                label += f" '{name}'"
        return label

    def _collect(self, eid: int, seen: set[int], found: set[int], others: list[Ref]) -> None:
        if eid in seen:
            return
        seen.add(eid)
        ent = self.get(Ref(eid))
        if ent is None:
            return
        types = set(ent.types)
        # a dimension: the faces of what it applies to
        size = self.params_of(ent, SIZE_TYPES)
        if size is not None and size:
            for r in refs_of(size[0]):
                self._collect(r.id, seen, found, others)
            return
        loc = self.params_of(ent, LOCATION_TYPES)
        if loc is not None and len(loc) >= 4:
            for r in refs_of(loc[2:4]):
                self._collect(r.id, seen, found, others)
            return
        is_datum = bool(types & _DATUM_TYPES)
        is_target = bool(types & TARGET_TYPES)
        for src in self.m.referrers(eid):
            stypes = self.types(src)
            if len(stypes) != 1:
                continue
            stype = stypes[0]
            if stype in _USAGE_TYPES:
                p = self.get(Ref(src)).params
                if len(p) >= 5 and p[2] == Ref(eid):
                    self._items(p[4], found, others)
            elif stype in _PART_OF_TYPES:
                p = self.get(Ref(src)).params
                if len(p) < 4:
                    continue
                if p[2] == Ref(eid) and isinstance(p[3], Ref):
                    # whole -> part; never from a feature into the datum it establishes
                    if not set(self.types(p[3])) & _DATUM_TYPES:
                        self._collect(p[3].id, seen, found, others)
                elif is_datum and p[3] == Ref(eid) and isinstance(p[2], Ref):
                    # datum <- datum feature / datum target
                    self._collect(p[2].id, seen, found, others)
            elif stype == "FEATURE_FOR_DATUM_TARGET_RELATIONSHIP" and is_target:
                p = self.get(Ref(src)).params
                if len(p) >= 4 and p[3] == Ref(eid) and isinstance(p[2], Ref):
                    self._collect(p[2].id, seen, found, others)
        if is_target and not found and not others:
            # a target without feature geometry: its placement (SHAPE_DEFINITION_REPRESENTATION
            # of the target, item 'orientation') lies on the target face
            others.extend(self._target_placements(eid))

    def _target_placements(self, eid: int) -> list[Ref]:
        out = []
        for pd in self.referrers_with(eid, ("PROPERTY_DEFINITION",)):
            for sdr in self.referrers_with(pd.id, ("SHAPE_DEFINITION_REPRESENTATION",)):
                rep = self.get(sdr.params[1]) if len(sdr.params) >= 2 else None
                if rep is None or rep.parts is not None or len(rep.params) < 2:
                    continue
                for item in refs_of(rep.params[1]):
                    if "AXIS2_PLACEMENT_3D" in self.types(item):
                        out.append(item)
        return out

    def _items(self, value: object, found: set[int], others: list[Ref]) -> None:
        """Add the faces among identified items (one item or a list); keep the rest."""
        for r in refs_of(value):
            types = self.types(r)
            if FACE_TYPES.intersection(types):
                found.add(r.id)
            elif _SHELL_TYPES.intersection(types) or _SOLID_TYPES.intersection(types):
                self._shell_faces(r, found)
            else:
                others.append(r)

    def _shell_faces(self, ref: Ref, found: set[int]) -> None:
        ent = self.get(ref)
        if ent is None:
            return
        if _SOLID_TYPES.intersection(ent.types):
            p = self.params_of(ent, _SOLID_TYPES)
            for r in refs_of(p[1:2] if p else ()):
                self._shell_faces(r, found)
            return
        p = self.params_of(ent, _SHELL_TYPES)
        for r in refs_of(p[1:] if p else ()):
            if FACE_TYPES.intersection(self.types(r)):
                found.add(r.id)


def _count_text(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {t}" for t, n in sorted(counts.items()))
