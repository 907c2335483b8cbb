"""The faces of a shape aspect beyond :class:`~qifreport.step.face_links.FaceLinker`'s walk.

:class:`AspectFaceLinker` adds the AP214 link of older exports, a shape aspect's
``PROPERTY_DEFINITION`` whose ``SHAPE_DEFINITION_REPRESENTATION`` lists the faces, and
:meth:`AspectFaceLinker.part_faces`, every face of the product shape (the faces of a
whole-part tolerance). The datum, tolerance and dimension readers
(:mod:`.datums`, :mod:`.tolerances`, :mod:`.dimensions`) stand on it.
"""

from __future__ import annotations

from collections.abc import Iterable

from .face_links import TARGET_TYPES, FaceLinker
from .instance_graph import refs_of
from .p21 import Entity, Ref

__all__ = ["PLACEMENT_TYPES", "AspectFaceLinker", "sorted_unique"]

#: representation relationships followed from a product shape to its B-rep representations
#: (not CONSTRUCTIVE_GEOMETRY_REPRESENTATION_RELATIONSHIP: supplemental geometry)
_SHAPE_REP_RELATIONSHIPS = ("SHAPE_REPRESENTATION_RELATIONSHIP", "REPRESENTATION_RELATIONSHIP")
#: representation items of a PROPERTY_DEFINITION -> SHAPE_DEFINITION_REPRESENTATION face link
#: that only place the aspect (not geometry it consists of)
PLACEMENT_TYPES = frozenset({"AXIS2_PLACEMENT_3D", "AXIS2_PLACEMENT_2D", "AXIS1_PLACEMENT"})


def sorted_unique(ids: Iterable[int]) -> list[int]:
    """The distinct ``ids``, ascending."""
    return sorted(set(ids))


class AspectFaceLinker(FaceLinker):
    """Faces of shape aspects, also through a property's shape representation, and the faces
    of the whole product shape (on :class:`~qifreport.step.face_links.FaceLinker`)."""

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
            kept = [r for r in items if not PLACEMENT_TYPES.intersection(self.types(r))]
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
