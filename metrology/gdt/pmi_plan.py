"""What a part's drawing asks to measure beyond its surface profiles
(:class:`CharacteristicPlan`): one :class:`~.characteristic_types.CharacteristicSpec` per
geometric tolerance and dimension of its PMI, and the datums they (and the profiles) refer
to, in mesh face ids.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from qifreport.kinds import lookup_kind
from qifreport.metrology.acceptance.bands import (
    composite_segment,
    composite_upper,
    material_boundary,
)
from qifreport.metrology.gdt.characteristic_types import CharacteristicSpec
from qifreport.metrology.gdt.frames import DatumSpec, TargetSpec
from qifreport.registration.arrays import unique_sorted

__all__ = ["POINT_TARGETS", "CharacteristicPlan", "specs_from_pmi"]

#: datum targets read as a contact at their placement on the surface (a line target at its
#: placement's point); the others (circles, areas) simulate their datum's feature
POINT_TARGETS = ("point", "line", "")
#: supplemental geometry standing for a thread, in a face note (:mod:`qifreport.step.pmi`)
_THREAD = re.compile(r"('[^']*thread[^']*')", re.IGNORECASE)

#: STEP face entity ids -> sorted unique mesh face ids (the ids the mesh has)
FacesOf = Callable[[list[int]], np.ndarray]


@dataclass
class CharacteristicPlan:
    """What a part's drawing asks to measure beyond its surface profiles: the feature
    characteristics and the datums they (and the profiles) refer to."""

    specs: list[CharacteristicSpec] = field(default_factory=list)
    datums: dict[str, DatumSpec] = field(default_factory=dict)


def specs_from_pmi(pmi, face_index: dict[int, int]) -> CharacteristicPlan:
    """The feature characteristics and datums of a part's PMI (surface profiles excepted:
    they are zones, :func:`qifreport.metrology.acceptance.bands.zones_from_pmi`).

    Parameters
    ----------
    pmi : :class:`qifreport.step.pmi.PMI` (mm, degrees) or None.
    face_index : STEP face entity id -> mesh face id.

    Returns
    -------
    CharacteristicPlan: one spec per geometric tolerance of another type than a profile,
    then one per dimension, in file order; the datums by label, with their faces and
    targets (a common datum ``A-B`` is not listed: its characteristics say so).
    """
    if pmi is None:
        return CharacteristicPlan()
    faces_of = partial(_faces_of, face_index)
    datums: dict[str, DatumSpec] = {}
    for d in pmi.datums:
        datums.setdefault(
            d.label, DatumSpec(d.label, faces_of(d.face_step_ids), _targets(d, faces_of))
        )
    _add_common_datums(pmi, datums)
    specs = [
        _tolerance_spec(f"G{k}", tol, pmi, datums, faces_of)
        for k, tol in enumerate(_feature_tolerances(pmi), start=1)
    ]
    specs += [
        _dimension_spec(f"D{k}", dim, faces_of) for k, dim in enumerate(pmi.dimensions, start=1)
    ]
    return CharacteristicPlan(specs, datums)


def _faces_of(face_index: dict[int, int], ids) -> np.ndarray:
    return np.array(sorted({face_index[s] for s in ids if s in face_index}), dtype=np.int64)


def _targets(d, faces_of: FacesOf) -> list[TargetSpec]:
    """A datum's targets as simulated: its points on the surface and its sized areas (a
    circle a pin meets, a rectangle); none when one of them is neither, or has no place or
    face (the datum is then simulated on its feature's faces)."""
    targets = [
        TargetSpec(t.name, np.asarray(t.position, dtype=np.float64), faces_of(t.face_step_ids))
        for t in d.target_details
        if t.position is not None and t.face_step_ids and t.kind in POINT_TARGETS
    ] + [
        TargetSpec(
            t.name,
            np.asarray(t.position, dtype=np.float64),
            faces_of(t.face_step_ids) if t.face_step_ids else np.empty(0, dtype=np.int64),
            normal=np.asarray(t.direction, dtype=np.float64),
            x_direction=None if t.x_direction is None else np.asarray(t.x_direction, float),
            length=t.length,
            width=t.width,
            diameter=t.diameter,
        )
        for t in d.target_details
        if t.position is not None
        and t.direction is not None
        and (
            (t.kind == "circle" and t.diameter)
            or (t.kind == "rectangle" and t.length and t.width and t.x_direction)
        )
    ]
    return targets if len(targets) >= len(d.target_details) else []


def _add_common_datums(pmi, datums: dict[str, DatumSpec]) -> None:
    """A common datum (A-B) the tolerances cite: one simulator on the features of all its
    datums together, added to ``datums``."""
    for tol in pmi.tolerances:
        for ref in tol.datums:
            parts = [p.strip() for p in ref.label.split("-")]
            if len(parts) > 1 and ref.label not in datums and all(p in datums for p in parts):
                faces = unique_sorted(np.concatenate([datums[p].faces for p in parts]))
                datums[ref.label] = DatumSpec(ref.label, faces)


def _feature_tolerances(pmi) -> list:
    """The PMI's geometric tolerances that are feature characteristics (not bands)."""
    out = []
    for tol in pmi.tolerances:
        kind = lookup_kind(tol.type)
        if kind is not None and kind.band:
            continue
        out.append(tol)
    return out


def _tolerance_spec(
    key: str, tol, pmi, datums: dict[str, DatumSpec], faces_of: FacesOf
) -> CharacteristicSpec:
    """The spec of geometric tolerance ``tol``, with the problems found reading it."""
    refs = sorted(tol.datums, key=lambda d: d.precedence)
    spec = CharacteristicSpec(
        key=key,
        kind=tol.type,
        name=tol.name or f"#{tol.step_id}",
        step_id=tol.step_id,
        faces=faces_of(tol.face_step_ids),
        tolerance=tol.value,
        datums=[d.label for d in refs],
        datum_materials=[material_boundary(d.modifiers) for d in refs],
        modifiers=list(tol.modifiers),
        zone_form=tol.zone_form,
        unit_basis=tol.unit_basis,
        composite=composite_segment(tol, pmi.tolerances),
        composite_of=composite_upper(tol, pmi.tolerances),
        max_value=tol.max_value,
    )
    if tol.value is None:
        spec.problems.append("tolerance value could not be established")
    kind = lookup_kind(tol.type)
    measured = () if kind is None else kind.measured_per_unit
    if tol.unit_basis and not any(u in tol.unit_basis for u in measured):
        spec.problems.append(f"per-unit tolerance ({tol.unit_basis}) not evaluated")
    for ref in tol.datums:
        if ref.label not in datums:
            spec.problems.append(f"datum {ref.label} is not defined on the part")
        elif any("maximum_material" in m or "least_material" in m for m in ref.modifiers):
            spec.problems.append(
                f"datum {ref.label} at a material condition: simulated regardless of "
                "material boundary"
            )
    return spec


def _dimension_spec(key: str, dim, faces_of: FacesOf) -> CharacteristicSpec:
    """The spec of dimension ``dim``: its limits from its nominal and tolerance."""
    nominal = dim.nominal
    lo = dim.lower_limit
    hi = dim.upper_limit
    if nominal is not None and lo is None and dim.lower is not None:
        lo = nominal + dim.lower
    if nominal is not None and hi is None and dim.upper is not None:
        hi = nominal + dim.upper
    spec = CharacteristicSpec(
        key=key,
        kind="dimension",
        name=dim.name or f"#{dim.step_id}",
        step_id=dim.step_id,
        faces=faces_of(dim.face_step_ids),
        dim_type=dim.type,
        nominal=nominal,
        lower_limit=lo,
        upper_limit=hi,
        unit=dim.unit,
        basic=any(q in ("basic", "reference") for q in dim.qualifiers),
        # a statistical tolerance (ST), as a geometric tolerance states it: not applied
        modifiers=["statistical_tolerance"] if "statistical" in dim.qualifiers else [],
        origin_faces=faces_of(dim.origin_face_step_ids) if dim.origin_face_step_ids else None,
        target_faces=faces_of(dim.target_face_step_ids) if dim.target_face_step_ids else None,
        thread=next((m.group(1) for n in dim.face_notes if (m := _THREAD.search(n))), ""),
        drawn=bool(dim.face_notes)
        and all("carrying the geometry" in n and "CURVE" in n for n in dim.face_notes),
    )
    if nominal is None and (lo is None) != (hi is None):
        # one limit without a nominal (none at all: a size reported, :mod:`.dimensions`)
        spec.problems.append("the dimension's nominal could not be established")
    return spec
