"""Feature characteristics of a drawing measured on the part's surface: form, orientation,
location and runout tolerances and the dimensions (ASME Y14.5-2018; ISO 1101), each as a
value against its limit with the value's expanded uncertainty.

The surface is the compliance-removed (or restrained) one in the nominal frame
(:class:`~qifreport.metrology.gdt.measured_surface.MeasuredSurface`); a tolerance that names
datums is read in their frame (:mod:`.frames`), one without in the registration's.

=====================  =====================================================================
form                   flatness (plane: minimum zone), cylindricity (minimum radial zone),
                       roundness (the worst cross-section's minimum radial zone), straightness
                       (plane or cylinder line elements; a cylinder's derived median line when
                       the zone is cylindrical)
orientation            perpendicularity, parallelism, angularity: a plane's points across the
                       zone's nominal normal in the frame (minimised over a rotation the frame
                       leaves free); an axis: its lateral run over its length (diametral zone)
location               position: a plane's points from true position (2 x farthest); an axis
                       (actual mating envelope's: largest inscribed of a hole, smallest
                       circumscribed of a pin) from its true position at both ends (diametral);
                       with MMC the bonus from the actual mating size and the size's limits;
                       coaxiality and concentricity the same about the nominal axis
runout                 circular (worst cross-section) and total, about the frame's datum axis:
                       radial for a cylinder, axial for a face across the axis
size and distance      dimensions: the geometric quantity of the faces (cylinder diameter or
                       radius, distance between opposed planes or between features, angle)
                       that the nominal mesh gives as the drawing's nominal, then measured the
                       same way: ``actual = nominal + (measured - nominal mesh)``; a quantity
                       whose nominal disagrees with the drawing is not measured (never guessed)
=====================  =====================================================================

Each tolerance kind is measured by the function its :class:`qifreport.kinds.CharacteristicKind`
names (:mod:`.geometric`, :mod:`.location`); dimensions by :mod:`.dimensions`; the plan from
the PMI is :mod:`.pmi_plan`'s, the spec and result :mod:`.characteristic_types`'. This module
dispatches to them.

Statuses: ``PASS``/``FAIL``/``INDETERMINATE`` by the decision rule
(:func:`qifreport.metrology.acceptance.decision.decide`, the value's ``U`` against its limits),
``NOT_MEASURED`` with the reason, ``BASIC`` (a basic or reference dimension: reported, no
limits). Lengths mm, angles degrees.
"""

from __future__ import annotations

import numpy as np

from qifreport.kinds import (
    CharacteristicKind,
    kind_label,
    lookup_kind,
    resolve,
    unapplied_material,
    unapplied_modifiers,
)
from qifreport.metrology.acceptance.scanner import DEFAULT_SCANNER, ScannerProfile
from qifreport.metrology.gdt.budgets import apply_budget, sampling_budget
from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    Unmeasurable,
    faces_text,
    judge,
    not_measured,
    reading_text,
)
from qifreport.metrology.gdt.dimensions import measure_dimension
from qifreport.metrology.gdt.frames import DatumFrameResult, DatumSpec, TargetSpec, establish_frame
from qifreport.metrology.gdt.measured_surface import MeasuredSurface

__all__ = [
    "frame_of",
    "measure_characteristics",
]


def frame_of(
    labels: list[str],
    datums: dict[str, DatumSpec],
    surface: MeasuredSurface,
    frames: dict[tuple[tuple[str, ...], int], DatumFrameResult],
) -> DatumFrameResult | None:
    """The frame of ``labels`` on ``surface``, established once per surface (``frames``
    keeps them); None when a label is not a datum of the part."""
    if not labels or not all(d in datums for d in labels):
        return None
    key = (tuple(labels), id(surface))
    if key not in frames:
        frames[key] = establish_frame([datums[d] for d in labels], surface)
    return frames[key]


def measure_characteristics(
    specs: list[CharacteristicSpec],
    datums: dict[str, DatumSpec],
    surface: MeasuredSurface,
    rule: str,
    free_surface: MeasuredSurface | None = None,
    frames: dict | None = None,
    scanner: ScannerProfile = DEFAULT_SCANNER,
) -> tuple[list[CharacteristicResult], list[DatumFrameResult]]:
    """Measure ``specs`` on ``surface`` (``free_surface`` for those with the free-state
    modifier, when the part was held otherwise) and judge them by ``rule``, each value's
    uncertainty its budget with the instrument ``scanner``'s figures
    (:func:`~qifreport.metrology.gdt.budgets.apply_budget`).

    ``frames``: the frames established so far (:func:`frame_of`), shared with the
    datum-located profiles. Returns the results (one per spec, same order) and every
    frame established (first-cited order).
    """
    frames = {} if frames is None else frames
    sizes = [s for s in specs if s.kind == "dimension" and s.dim_type in ("diameter", "radius")]
    areas = [(d.label, t) for d in datums.values() for t in d.targets if t.is_area]
    results = []
    for spec in specs:
        surf = free_surface if spec.free_state and free_surface is not None else surface
        frame = frame_of(spec.datums, datums, surf, frames)
        res = apply_budget(_measure(spec, surf, frame, rule, sizes, areas), scanner, surf, rule)
        res = _without_material_bonus(spec, res)
        soft = [p for p in spec.problems if "simulated regardless" in p]
        if soft and res.status != "NOT_MEASURED":  # a datum at MMC/LMC: said in the reading
            res.reading = "; ".join([res.reading, *soft]) if res.reading else "; ".join(soft)
        results.append(res)
    return results, list(frames.values())


def _without_material_bonus(
    spec: CharacteristicSpec, res: CharacteristicResult
) -> CharacteristicResult:
    """A characteristic whose material requirement its kind does not apply was read
    against the zone without its bonus, a stricter one: a PASS stands (said in its reading),
    anything else is not measured."""
    missing = unapplied_material(spec.kind, spec.modifiers)
    if not missing or res.status == "NOT_MEASURED":
        return res
    what = ", ".join(m.replace("_", " ") for m in missing)
    if res.status == "PASS":
        note = f"{what}: read regardless of feature size, without its bonus (a stricter zone)"
        res.reading = f"{res.reading}; {note}" if res.reading else note
        return res
    value = "a reading" if res.value is None else f"{res.value:.4g}"
    out = not_measured(
        spec,
        f"{value} read without the {what} bonus, which qifreport does not apply "
        "to this kind: beyond the zone without it, not established with it",
    )
    out.direction = res.direction
    return out


def _measure(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
    areas: list[tuple[str, TargetSpec]],
) -> CharacteristicResult:
    """One spec measured and judged, or why it is not: the checks every kind shares, then
    its kind's measurement (:data:`qifreport.kinds.KINDS`)."""
    hard = [p for p in spec.problems if "simulated regardless" not in p]
    if hard:
        return not_measured(spec, "; ".join(hard))
    unapplied = unapplied_modifiers(spec.kind, spec.modifiers)
    if unapplied:
        return not_measured(
            spec,
            f"modifier {', '.join(m.replace('_', ' ') for m in unapplied)} not applied by "
            "qifreport: a reading without it would be another requirement",
        )
    if spec.kind == "dimension":
        try:
            return measure_dimension(spec, surf, rule, areas)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            return not_measured(spec, str(exc))
    kind = lookup_kind(spec.kind)
    if kind is not None and kind.measure_whole is not None:
        return resolve(kind.measure_whole)(spec, surf, frame, rule)
    if kind is None or kind.measure is None:
        res = not_measured(spec, f"{kind_label(spec.kind)}: not measured by qifreport")
        feat = surf.nominal(spec.faces) if len(spec.faces) else None
        if feat is not None and feat.kind != "sphere":
            res.direction = feat.direction  # a line profile's section normal, for its QIF
        return res
    if not len(spec.faces):
        return not_measured(spec, "no B-rep face of the part is associated")
    if spec.datums and frame is None:
        return not_measured(spec, "its datums are not all defined on the part")
    if frame is not None and not frame.established:
        return not_measured(spec, "datum frame not established: " + "; ".join(frame.problems))
    if kind.datums == "required" and frame is None:
        return not_measured(spec, f"{spec.kind} without datums")
    if not len(surf.triangles_on(spec.faces)):
        return not_measured(spec, "its faces are not on the part inspected")
    members = surf.features(spec.faces)
    if kind.measure_pattern is not None:
        whole = resolve(kind.measure_pattern)(spec, surf, members, frame, rule, sizes)
        if whole is not None:
            return whole
    return _measure_features(spec, kind, surf, members, frame, rule, sizes)


def _measure_features(
    spec: CharacteristicSpec,
    kind: CharacteristicKind,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
) -> CharacteristicResult:
    """Each feature of ``members`` measured by ``kind``'s function; the worst decides (each
    feature of a pattern has its own zone); not measured when one cannot be."""
    measure = kind.measure_function()
    needs_frame = kind.needs_frame
    readings = []
    for faces in members:
        sample = surf.sample(faces)
        feat = sample.nominal
        try:
            if feat is None:
                raise Unmeasurable("a feature that is neither a plane, a cylinder nor a sphere")
            if len(sample.S) < (4 if feat.kind == "plane" else 8):
                raise Unmeasurable(f"{len(sample.S)} measured points on a feature")
            S = sample.S if frame is None or not needs_frame else frame.move(sample.S)
            value, ls, U, how, bonus = measure(spec, S, sample, feat, frame, sizes, surf, faces)
            U_frame = 0.0
            if frame is not None and needs_frame:  # the frame's own uncertainty
                width = 2.0 if kind.diametral else 1.0
                U_frame = width * frame.point_uncertainty(S)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # Unmeasurable, a fit refused (too few points, a partial arc), a programme failed
            why = str(exc) if len(members) == 1 else f"faces {faces_text(faces)}: {exc}"
            return not_measured(spec, why)
        readings.append(
            CharacteristicResult(
                spec,
                value=value,
                least_squares=ls,
                uncertainty=float(np.hypot(U, U_frame)),
                reading=reading_text(how, sample, frame if needs_frame else None),
                n_points=len(S),
                coverage=sample.coverage,
                bonus=bonus,
                budget=sampling_budget(U, U_frame),
            )
        )
    k = int(np.argmax([r.value - (r.limit or 0.0) for r in readings]))
    res = readings[k]
    if len(readings) > 1:
        res.reading = (
            f"worst of {len(readings)} features (faces {faces_text(members[k])}): {res.reading}"
        )
    judge(res, rule, None, res.limit, surf.diagonal)
    return res
