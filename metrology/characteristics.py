"""Feature characteristics of a drawing measured on the part's surface: form, orientation,
location and runout tolerances and the dimensions (ASME Y14.5-2018; ISO 1101), each as a
value against its limit with the value's expanded uncertainty.

The surface is the compliance-removed (or restrained) one in the nominal frame
(:class:`~qifreport.metrology.measured_surface.MeasuredSurface`); a tolerance that names
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

Statuses: ``PASS``/``FAIL``/``INDETERMINATE`` by the decision rule
(:func:`qifreport.metrology.decision.decide`, the value's ``U`` against its limits),
``NOT_MEASURED`` with the reason, ``BASIC`` (a basic or reference dimension: reported, no
limits). Lengths mm, angles degrees.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from qifreport.registration.arrays import unique_sorted

from .bands import composite_segment, material_boundary
from .composite import free_rotations, minimax_offsets, orientation_only
from .datums import MAX_OPEN_DEG, DatumFeature, largest_gap
from .decision import decide
from .form import (
    axis_frame,
    cone_draws,
    cylindricity,
    flatness,
    least_squares_circle,
    least_squares_cone,
    least_squares_cylinder,
    least_squares_sphere,
    roundness,
)
from .form import straightness as line_straightness
from .frames import DatumFrameResult, DatumSpec, TargetSpec, establish_frame
from .measured_surface import MIN_VERTICES, FeatureSample, MeasuredSurface

__all__ = [
    "CharacteristicPlan",
    "CharacteristicResult",
    "CharacteristicSpec",
    "GEOMETRIC_KINDS",
    "frame_of",
    "measure_characteristics",
    "per_unit",
    "specs_from_pmi",
    "zone_uncertainty",
]

#: the geometric tolerance types measured here (surface profiles are zones: :mod:`.bands`)
GEOMETRIC_KINDS = (
    "flatness",
    "straightness",
    "roundness",
    "cylindricity",
    "perpendicularity",
    "parallelism",
    "angularity",
    "position",
    "coaxiality",
    "concentricity",
    "circular_runout",
    "total_runout",
)
#: datum targets read as a contact at their placement on the surface (a line target at its
#: placement's point); the others (circles, areas) simulate their datum's feature
POINT_TARGETS = ("point", "line", "")
#: kinds whose value is a diameter (twice an offset): the frame's uncertainty counts twice
_DIAMETRAL = ("position", "coaxiality", "concentricity")
#: fewest points in a cross-section or a line element
_SECTION_POINTS = 8
#: supplemental geometry standing for a thread, in a face note (:mod:`qifreport.step.pmi`)
_THREAD = re.compile(r"('[^']*thread[^']*')", re.IGNORECASE)
#: a drawing's nominal and the faces' own quantity agree within this share (or 0.02 mm)
_NOMINAL_AGREEMENT = 0.01


@dataclass
class CharacteristicSpec:
    """One PMI item to measure.

    Attributes
    ----------
    key : ``'G<k>'`` (geometric tolerance) or ``'D<k>'`` (dimension), file order.
    kind : the tolerance type (:data:`GEOMETRIC_KINDS` ...) or ``'dimension'``.
    name, step_id : the PMI item's name and STEP entity.
    faces : (k,) mesh face ids of the feature (a location's both ends).
    tolerance : zone width, mm (geometric).
    dim_type : the dimension's type (``'diameter'``, ``'linear distance'`` ...).
    nominal, lower_limit, upper_limit : a dimension's nominal and limits (mm or deg).
    unit : ``'mm'`` or ``'deg'``.
    datums : the frame's labels in precedence (``[]``: none).
    modifiers, zone_form : as read.  basic : a basic or reference dimension.
    origin_faces, target_faces : a location's two features.
    problems : why it cannot be measured (found when reading).
    datum_materials : each datum reference's material boundary as drawn (``'MAXIMUM'``,
        ``'LEAST'``, ``'NONE'``; same order as ``datums``).
    unit_basis : a per-unit tolerance's unit as read (``'per unit length 25 mm'``,
        ``'per rectangular area 6.35 mm x 6.35 mm'``), None for a whole-feature tolerance.
    composite : ``'upper'`` or ``'lower'`` segment of a composite feature control frame
        (:func:`qifreport.metrology.bands.composite_segment`), ``''`` for none.
    thread : the supplemental geometry a dimension of a thread is given on (``"'Thread
        Cylinder.1'"``: a cosmetic thread, its model a tap-drill hole), ``''`` for none.
    drawn : a location dimension between curves drawn on faces (supplemental geometry,
        e.g. construction lines), not between the faces.
    """

    key: str
    kind: str
    name: str
    step_id: int | None
    faces: np.ndarray
    tolerance: float | None = None
    dim_type: str = ""
    nominal: float | None = None
    lower_limit: float | None = None
    upper_limit: float | None = None
    unit: str = "mm"
    datums: list[str] = field(default_factory=list)
    modifiers: list[str] = field(default_factory=list)
    zone_form: str | None = None
    basic: bool = False
    origin_faces: np.ndarray | None = None
    target_faces: np.ndarray | None = None
    problems: list[str] = field(default_factory=list)
    datum_materials: list[str] = field(default_factory=list)
    unit_basis: str | None = None
    composite: str = ""
    thread: str = ""
    drawn: bool = False

    @property
    def free_state(self) -> bool:
        return "free_state" in self.modifiers

    def limits_text(self) -> str:
        if self.kind != "dimension":
            return f"{self.tolerance:g} mm" if self.tolerance is not None else "?"
        lo, hi = self.lower_limit, self.upper_limit
        if lo is None and hi is None:
            return "basic" if self.basic else "no limits"
        return f"{_fmt(lo)} .. {_fmt(hi)} {self.unit}"


@dataclass
class CharacteristicResult:
    """One characteristic measured.

    Attributes
    ----------
    spec : what was measured.
    value : the measured value (mm or deg; a tolerance's zone width, a dimension's size),
        None when not measured.
    least_squares : the least-squares reading beside a minimum zone (form), else None.
    uncertainty : expanded uncertainty of ``value`` (k = 2).
    status : ``'PASS'``, ``'FAIL'``, ``'INDETERMINATE'``, ``'NOT_MEASURED'``, ``'BASIC'``.
    reason : why not measured, or how it failed.
    reading : how it was measured (``'minimum zone, 1,204 vertices, frame |A|B|C|'`` ...).
    n_points : points used.  coverage : share of the feature's vertices measured.
    bonus : MMC/LMC bonus added to the tolerance, mm.
    direction : (3,) the feature's nominal normal or axis where a report needs it (a line
        profile's QIF ``Vector``), else None.
    """

    spec: CharacteristicSpec
    value: float | None = None
    least_squares: float | None = None
    uncertainty: float | None = None
    status: str = "NOT_MEASURED"
    reason: str = ""
    reading: str = ""
    n_points: int = 0
    coverage: float | None = None
    bonus: float = 0.0
    direction: np.ndarray | None = None

    @property
    def limit(self) -> float | None:
        """The upper limit the value is judged against (tolerance + bonus), mm."""
        if self.spec.kind == "dimension":
            return self.spec.upper_limit
        return None if self.spec.tolerance is None else self.spec.tolerance + self.bonus

    def to_dict(self) -> dict:
        s = self.spec
        return {
            "key": s.key,
            "kind": s.kind if s.kind != "dimension" else f"dimension ({s.dim_type})",
            "name": s.name,
            "step_id": s.step_id,
            "faces": [int(f) for f in s.faces],
            "datums": list(s.datums),
            "datum_materials": list(s.datum_materials) or ["NONE"] * len(s.datums),
            "modifiers": list(s.modifiers),
            "composite": s.composite,
            "tolerance_mm": s.tolerance,
            "nominal": s.nominal,
            "lower_limit": s.lower_limit,
            "upper_limit": s.upper_limit,
            "unit": s.unit,
            "value": _num(self.value),
            "least_squares": _num(self.least_squares),
            "uncertainty": _num(self.uncertainty),
            "bonus_mm": self.bonus,
            "status": self.status,
            "reason": self.reason,
            "reading": self.reading,
            "n_points": self.n_points,
            "coverage": _num(self.coverage),
        }


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:g}"


# --------------------------------------------------------------------------- from the PMI


@dataclass
class CharacteristicPlan:
    """What a part's drawing asks to measure beyond its surface profiles: the feature
    characteristics and the datums they (and the profiles) refer to."""

    specs: list[CharacteristicSpec] = field(default_factory=list)
    datums: dict[str, DatumSpec] = field(default_factory=dict)


def specs_from_pmi(pmi, face_index: dict[int, int]) -> CharacteristicPlan:
    """The feature characteristics and datums of a part's PMI (surface profiles excepted:
    they are zones, :func:`qifreport.metrology.bands.zones_from_pmi`).

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

    def faces_of(ids) -> np.ndarray:
        return np.array(sorted({face_index[s] for s in ids if s in face_index}), dtype=np.int64)

    datums: dict[str, DatumSpec] = {}
    for d in pmi.datums:
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
        if len(targets) < len(d.target_details):
            # a target that is not a point on the surface nor a sized area (a circle a pin
            # meets) or has no place or face: the datum is simulated on its feature's faces
            targets = []
        datums.setdefault(d.label, DatumSpec(d.label, faces_of(d.face_step_ids), targets))
    # a common datum (A-B): one simulator on the features of all its datums together
    for tol in pmi.tolerances:
        for ref in tol.datums:
            parts = [p.strip() for p in ref.label.split("-")]
            if len(parts) > 1 and ref.label not in datums and all(p in datums for p in parts):
                faces = unique_sorted(np.concatenate([datums[p].faces for p in parts]))
                datums[ref.label] = DatumSpec(ref.label, faces)
    specs: list[CharacteristicSpec] = []
    k = 0
    for tol in pmi.tolerances:
        if tol.type in ("surface_profile",):
            continue
        k += 1
        spec = CharacteristicSpec(
            key=f"G{k}",
            kind=tol.type,
            name=tol.name or f"#{tol.step_id}",
            step_id=tol.step_id,
            faces=faces_of(tol.face_step_ids),
            tolerance=tol.value,
            datums=[d.label for d in sorted(tol.datums, key=lambda d: d.precedence)],
            datum_materials=[
                material_boundary(d.modifiers)
                for d in sorted(tol.datums, key=lambda d: d.precedence)
            ],
            modifiers=list(tol.modifiers),
            zone_form=tol.zone_form,
            unit_basis=tol.unit_basis,
            composite=composite_segment(tol, pmi.tolerances),
        )
        if tol.value is None:
            spec.problems.append("tolerance value could not be established")
        if tol.unit_basis and not (tol.type == "flatness" and "area" in tol.unit_basis):
            spec.problems.append(f"per-unit tolerance ({tol.unit_basis}) not evaluated")
        for ref in tol.datums:
            if ref.label not in datums:
                spec.problems.append(f"datum {ref.label} is not defined on the part")
            elif any("maximum_material" in m or "least_material" in m for m in ref.modifiers):
                spec.problems.append(
                    f"datum {ref.label} at a material condition: simulated regardless of "
                    "material boundary"
                )
        specs.append(spec)
    k = 0
    for dim in pmi.dimensions:
        k += 1
        nominal = dim.nominal
        lo = dim.lower_limit
        hi = dim.upper_limit
        if nominal is not None and lo is None and dim.lower is not None:
            lo = nominal + dim.lower
        if nominal is not None and hi is None and dim.upper is not None:
            hi = nominal + dim.upper
        spec = CharacteristicSpec(
            key=f"D{k}",
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
            origin_faces=faces_of(dim.origin_face_step_ids) if dim.origin_face_step_ids else None,
            target_faces=faces_of(dim.target_face_step_ids) if dim.target_face_step_ids else None,
            thread=next((m.group(1) for n in dim.face_notes if (m := _THREAD.search(n))), ""),
            drawn=bool(dim.face_notes)
            and all("carrying the geometry" in n and "CURVE" in n for n in dim.face_notes),
        )
        if nominal is None and (lo is None) != (hi is None):
            # one limit without a nominal (none at all: a size reported, :func:`_reported`)
            spec.problems.append("the dimension's nominal could not be established")
        specs.append(spec)
    return CharacteristicPlan(specs, datums)


# --------------------------------------------------------------------------- measuring


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
) -> tuple[list[CharacteristicResult], list[DatumFrameResult]]:
    """Measure ``specs`` on ``surface`` (``free_surface`` for those with the free-state
    modifier, when the part was held otherwise) and judge them by ``rule``.

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
        res = _measure(spec, surf, frame, rule, sizes, areas)
        soft = [p for p in spec.problems if "simulated regardless" in p]
        if soft and res.status != "NOT_MEASURED":  # a datum at MMC/LMC: said in the reading
            res.reading = "; ".join([res.reading, *soft]) if res.reading else "; ".join(soft)
        results.append(res)
    return results, list(frames.values())


def _not_measured(spec: CharacteristicSpec, reason: str) -> CharacteristicResult:
    return CharacteristicResult(spec, status="NOT_MEASURED", reason=reason)


def _measure(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
    areas: list[tuple[str, TargetSpec]],
) -> CharacteristicResult:
    hard = [p for p in spec.problems if "simulated regardless" not in p]
    if hard:
        return _not_measured(spec, "; ".join(hard))
    if spec.kind == "dimension":
        try:
            return _dimension(spec, surf, rule, areas)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            return _not_measured(spec, str(exc))
    if spec.kind == "line_profile":
        return _line_profile(spec, surf, frame, rule)
    if spec.kind not in GEOMETRIC_KINDS:
        res = _not_measured(spec, f"{spec.kind.replace('_', ' ')}: not measured by qifreport")
        feat = surf.nominal(spec.faces) if len(spec.faces) else None
        if feat is not None and feat.kind != "sphere":
            res.direction = feat.direction  # a line profile's section normal, for its QIF
        return res
    if not len(spec.faces):
        return _not_measured(spec, "no B-rep face of the part is associated")
    if spec.datums and frame is None:
        return _not_measured(spec, "its datums are not all defined on the part")
    if frame is not None and not frame.established:
        return _not_measured(spec, "datum frame not established: " + "; ".join(frame.problems))
    needs_frame = spec.kind not in ("flatness", "straightness", "roundness", "cylindricity")
    if needs_frame and frame is None and spec.kind != "position":
        return _not_measured(spec, f"{spec.kind} without datums")
    if not np.isin(surf.face_id, spec.faces).any():
        return _not_measured(spec, "its faces are not on the part inspected")
    members = surf.features(spec.faces)
    if spec.kind == "position" and spec.composite == "lower":
        return _pattern_position(spec, surf, members, frame, rule, sizes)
    if spec.kind == "position" and len(members) == 2:
        width = _center_plane(spec, surf, members, frame, rule)
        if width is not None:
            return width
    readings = []
    for faces in members:
        sample = surf.sample(faces)
        feat = sample.nominal
        try:
            if feat is None:
                raise _Unmeasurable("a feature that is neither a plane, a cylinder nor a sphere")
            if len(sample.S) < (4 if feat.kind == "plane" else 8):
                raise _Unmeasurable(f"{len(sample.S)} measured points on a feature")
            S = sample.S if frame is None or not needs_frame else frame.move(sample.S)
            value, ls, U, how, bonus = _MEASURES[spec.kind](
                spec, S, sample, feat, frame, sizes, surf, faces
            )
            if frame is not None and needs_frame:  # the frame's own uncertainty
                width = 2.0 if spec.kind in _DIAMETRAL else 1.0
                U = float(np.hypot(U, width * frame.point_uncertainty(S)))
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # _Unmeasurable, a fit refused (too few points, a partial arc), a programme failed
            why = str(exc) if len(members) == 1 else f"faces {_faces(faces)}: {exc}"
            return _not_measured(spec, why)
        readings.append(
            CharacteristicResult(
                spec,
                value=value,
                least_squares=ls,
                uncertainty=U,
                reading=_reading(how, sample, frame if needs_frame else None),
                n_points=len(S),
                coverage=sample.coverage,
                bonus=bonus,
            )
        )
    # the worst member decides (each feature of a pattern has its own zone)
    k = int(np.argmax([r.value - (r.limit or 0.0) for r in readings]))
    res = readings[k]
    if len(readings) > 1:
        res.reading = (
            f"worst of {len(readings)} features (faces {_faces(members[k])}): {res.reading}"
        )
    _judge(res, rule, None, res.limit)
    return res


def _line_profile(
    spec: CharacteristicSpec, surf: MeasuredSurface, frame: DatumFrameResult | None, rule: str
) -> CharacteristicResult:
    """Profile of a line with datums (Y14.5 11.3.1.2): each line element of the faces within
    a zone of the tolerance's width, equally disposed about the true profile and located in
    the datum frame. The zone is one for every element, so the value is twice the largest
    deviation of the faces' measured vertices in the frame (exact when the frame fixes every
    motion; with motions left free, the frame's fit of them is kept, and the value bounds
    each element's from above)."""
    res = _not_measured(spec, "")
    feat = surf.nominal(spec.faces) if len(spec.faces) else None
    if feat is not None and feat.kind != "sphere":
        res.direction = feat.direction  # the sections' normal, for its QIF
    if not spec.datums:
        res.reason = "line profile without datums (the form of each line element): not measured"
        return res
    if any("unequal" in m for m in spec.modifiers):
        res.reason = "line profile with an unequally disposed zone: not measured"
        return res
    if frame is None or not frame.established:
        why = "; ".join(frame.problems) if frame is not None else "its datums are not defined"
        res.reason = f"datum frame not established: {why}"
        return res
    v = surf.own_vertices(spec.faces)
    v = v[np.isfinite(surf.dev[v])]
    if len(v) < MIN_VERTICES:
        res.reason = f"{len(v)} measured vertices on its faces"
        return res
    d = surf.dev[v] + frame.normal_shift(surf.V[v], surf.N[v])
    k = int(np.argmax(np.abs(d)))
    U = float(
        np.hypot(
            surf.U[v[k]], frame.shift_uncertainty(surf.V[v[k : k + 1]], surf.N[v[k : k + 1]])[0]
        )
    )
    out = CharacteristicResult(
        spec,
        value=2.0 * float(np.abs(d).max()),
        uncertainty=2.0 * U,
        reading=(
            f"twice the largest deviation ({d[k]:+.4f} mm) of {len(v)} measured vertices in "
            f"|{'|'.join(frame.labels)}|, one zone for every line element"
            + (f" (best fit: {', '.join(frame.free)}: an upper bound)" if frame.free else "")
        ),
        n_points=len(v),
        direction=res.direction,
    )
    _judge(out, rule, None, out.limit)
    return out


def _faces(faces) -> str:
    return " ".join(str(int(f)) for f in faces)


def _center_plane(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
) -> CharacteristicResult | None:
    """Position of a width feature (a slot or a tab: two opposed parallel planes): its
    center plane from true position, ``2 x`` the farthest center-plane point (each side's
    least-squares plane evaluated at every measured point of both); None when the members
    are not such a pair."""
    A, B = surf.nominal(members[0]), surf.nominal(members[1])
    if A is None or B is None or A.kind != "plane" or B.kind != "plane":
        return None
    if A.direction @ B.direction > -0.999:
        return None
    sa, sb = surf.sample(members[0]), surf.sample(members[1])
    if len(sa.S) < 3 or len(sb.S) < 3:
        return None
    Sa, Sb = (sa.S, sb.S) if frame is None else (frame.move(sa.S), frame.move(sb.S))
    n = A.direction
    E = axis_frame(n)
    mid0 = 0.5 * (A.origin + B.origin) @ n  # the nominal center plane's offset

    def side(S: np.ndarray) -> np.ndarray:  # w = a u + b v + c, least squares
        X = S @ E.T
        coef, *_ = np.linalg.lstsq(np.c_[X[:, :2], np.ones(len(X))], X[:, 2], rcond=None)
        return coef

    ca, cb = side(Sa), side(Sb)
    X = np.vstack([Sa, Sb]) @ E.T
    at = np.c_[X[:, :2], np.ones(len(X))]
    centre = 0.5 * (at @ ca + at @ cb) - mid0
    U = np.r_[sa.U, sb.U]
    res = CharacteristicResult(
        spec,
        value=2 * float(np.abs(centre).max()),
        uncertainty=2 * _fit_U(U, 3),
        reading=_reading(
            "center plane of the width feature from true position (2 x farthest)",
            FeatureSample(np.vstack([Sa, Sb]), U, sa.source, sa.coverage, A),
            frame,
        ),
        n_points=len(U),
        coverage=sa.coverage,
    )
    _judge(res, rule, None, res.limit)
    return res


class _Unmeasurable(ValueError):
    """The characteristic cannot be measured on this feature (the message says why)."""


def _reading(how: str, sample: FeatureSample, frame: DatumFrameResult | None) -> str:
    text = f"{how}; {len(sample.S)} {sample.source}"
    if frame is not None:
        text += f"; in |{'|'.join(frame.labels)}|"
        if frame.free:
            text += " (best fit: " + ", ".join(frame.free) + ")"
    return text


def _judge(res: CharacteristicResult, rule: str, lo: float | None, hi: float | None) -> None:
    """Set ``res.status`` from its value, uncertainty and limits ``[lo, hi]`` (None: open)."""
    v, U = res.value, res.uncertainty or 0.0
    lo_ = -math.inf if lo is None else lo
    hi_ = math.inf if hi is None else hi
    passed = lo_ <= v <= hi_
    proven_in = lo_ + U <= v <= hi_ - U
    proven_out = v < lo_ - U or v > hi_ + U
    status = decide(rule, passed, proven_in, proven_out)
    res.status = "INDETERMINATE" if status == "UNCERTAIN" else status
    if res.status == "FAIL":
        if lo is None:
            res.reason = f"{v:.4g} > {hi:g}"
        elif hi is None or v < lo:
            res.reason = f"{v:.4g} < {lo:g}" if v < lo else f"{v:.4g} > {hi:g}"
        else:
            res.reason = f"{v:.4g} > {hi:g}"


def zone_uncertainty(residuals: np.ndarray, U: np.ndarray) -> float:
    """Expanded uncertainty (mm) of a zone width: its two extremes' in quadrature.

    ``residuals`` (m,) mm: the points' signed distances from the fitted feature; ``U`` (m,)
    mm: each point's expanded uncertainty (k = 2).

    Each extreme's U is that of the points near it, weighted by how near: ``w = 1 - d / h``
    for a point ``d`` below the extreme (mm), ``h`` the median U, none beyond ``h``. A
    point that stands out by more than ``h`` gives its own U, as before. Where several points
    nearly tie, which one is the extreme is itself within the measurement's uncertainty, and
    the zone's U is their weighted U: a continuous function of the residuals. (The extreme
    point's U alone jumped by a third when round-off, a 1e-13 mm change of the fit, picked
    the other of two tied points of the sample panel's flatness G2.)
    """
    r = np.asarray(residuals, dtype=np.float64)
    U = np.asarray(U, dtype=np.float64)
    h = float(np.median(U))
    if not h > 0.0:
        return float(np.hypot(U[np.argmax(r)], U[np.argmin(r)]))

    def side(d: np.ndarray) -> float:
        w = np.clip(1.0 - d / h, 0.0, None)
        return float(w @ U / w.sum())

    return float(np.hypot(side(r.max() - r), side(r - r.min())))


def _fit_U(U: np.ndarray, n_params: int = 1) -> float:
    """Expanded uncertainty of a fitted parameter from ``len(U)`` values; neighbouring
    vertices share scan points, so a quarter of them count as independent."""
    n_eff = max(len(U) / 4.0, float(n_params))
    return float(np.median(U)) / math.sqrt(n_eff)


def _axial(S: np.ndarray, o: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X = (S - o) @ axis_frame(a).T
    return X[:, 2], np.hypot(X[:, 0], X[:, 1])


def _sections(z: np.ndarray, n_min: int = _SECTION_POINTS) -> list[np.ndarray]:
    """Index sets of cross-sections along ``z`` with at least ``n_min`` points each."""
    m = len(z)
    k = int(np.clip(m // (3 * n_min), 1, 12))
    edges = np.linspace(z.min(), z.max() + 1e-9, k + 1)
    out = []
    for i in range(k):
        sel = np.flatnonzero((z >= edges[i]) & (z < edges[i + 1]))
        if len(sel) >= n_min:
            out.append(sel)
    return out


def _form(fit, U: np.ndarray, how: str) -> tuple:
    """A minimum-zone form reading: value, least squares, ``U``, how, no bonus."""
    return fit.minimum_zone, fit.least_squares, zone_uncertainty(fit.residuals, U), how, 0.0


def _flatness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "plane":
        raise _Unmeasurable("flatness of a feature that is not a plane")
    unit = per_unit(spec.unit_basis)
    if unit is not None and unit[0] != "length":
        # a unit area is a few mm wide: the scan points on the face when they are denser
        on = np.isin(surf.P_face, np.asarray(list(faces), dtype=np.int64))
        if on.sum() > len(S):
            S, U = surf.P[on], surf.P_U[on]
        else:
            U = sample.U
        return _flatness_per_area(S, U, feat, unit)
    return _form(flatness(S), sample.U, "minimum zone (least squares beside)")


#: a unit area's window holds at least this many measured points to be judged
_WINDOW_POINTS = 6
#: the windows whose least-squares peak-to-valley is largest are then judged by the
#: minimum zone (the least-squares one is never below it), this many
_WINDOWS_EXACT = 8


def _flatness_per_area(S, U, feat: DatumFeature, unit: tuple[str, list[float]]) -> tuple:
    """Flatness per unit area (Y14.5-2018 5.4.2.1): the worst minimum-zone flatness of the
    surface within any unit area (a rectangle a x b, square to the plane's principal
    directions, or a circle), its windows centred on a grid of a quarter of the unit's size
    over the measured points; the worst few by least squares, then by the minimum zone."""
    kind, dims = unit
    E = axis_frame(feat.direction)
    X = (S - feat.origin) @ E.T
    # the face's own in-plane directions (its principal axes), for the rectangles
    C = np.cov(X[:, :2].T)
    _, vec = np.linalg.eigh(C)
    UV = X[:, :2] @ vec
    a = dims[0]
    b = dims[1] if kind == "rectangular" else dims[0]
    lo, hi = UV.min(axis=0), UV.max(axis=0)
    cu = np.arange(lo[0], hi[0] + a / 4, a / 4)
    cv = np.arange(lo[1], hi[1] + b / 4, b / 4)
    from scipy.spatial import cKDTree

    tree = cKDTree(UV)
    windows = []
    for u0 in cu:
        for v0 in cv:
            idx = np.array(tree.query_ball_point([u0, v0], 0.5 * np.hypot(a, b)), dtype=np.int64)
            if kind == "circular":
                idx = idx[np.hypot(*(UV[idx] - [u0, v0]).T) <= a / 2] if len(idx) else idx
            elif len(idx):
                d = np.abs(UV[idx] - [u0, v0])
                idx = idx[(d[:, 0] <= a / 2) & (d[:, 1] <= b / 2)]
            if len(idx) >= _WINDOW_POINTS:
                h = X[idx, 2]
                A = np.c_[UV[idx], np.ones(len(idx))]
                r = h - A @ np.linalg.lstsq(A, h, rcond=None)[0]
                windows.append((float(np.ptp(r)), idx, (u0, v0)))
    if not windows:
        raise _Unmeasurable(f"no unit area ({kind} {a:g} x {b:g} mm) holds enough points")
    windows.sort(key=lambda w: -w[0])
    best = None
    for ls, idx, at in windows[:_WINDOWS_EXACT]:
        fit = flatness(S[idx])
        if best is None or fit.minimum_zone > best[0].minimum_zone:
            best = (fit, idx, ls, at)
    fit, idx, ls, at = best
    size = f"{a:g} x {b:g} mm" if kind == "rectangular" else f"diameter {a:g} mm"
    return (
        fit.minimum_zone,
        ls,
        zone_uncertainty(fit.residuals, U[idx]),
        f"per unit area ({kind} {size}): worst of {len(windows)} windows, minimum zone "
        f"(least squares beside)",
        0.0,
    )


def per_unit(text: str | None) -> tuple[str, list[float]] | None:
    """A per-unit tolerance's unit from the PMI's text (mm): ``('length', [L])``,
    ``('rectangular', [a, b])``, ``('circular', [d])``; None when there is none."""
    if not text:
        return None
    nums = [float(x) for x in re.findall(r"[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?", text)]
    if not nums:
        return None
    if "length" in text:
        return "length", nums[:1]
    if "circular" in text:
        return "circular", nums[:1]
    return "rectangular", (nums + nums)[:2]  # a square area gives one side


def _cylindricity(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "cylinder":
        raise _Unmeasurable("cylindricity of a feature that is not a cylinder")
    fit = cylindricity(S, feat.origin, feat.direction, feat.radius)
    return _form(fit, sample.U, "minimum radial zone (least squares beside)")


def _roundness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "cylinder":
        raise _Unmeasurable("roundness of a feature that is not a cylinder")
    o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    E = axis_frame(a)
    X = (S - o) @ E.T
    worst = None
    for sel in _sections(X[:, 2]):
        fit = roundness(X[sel, :2])
        if worst is None or fit.minimum_zone > worst[0].minimum_zone:
            worst = (fit, sel)
    if worst is None:
        raise _Unmeasurable("no cross-section with enough points")
    fit, sel = worst
    return (
        fit.minimum_zone,
        fit.least_squares,
        zone_uncertainty(fit.residuals, sample.U[sel]),
        ("worst cross-section's minimum radial zone"),
        0.0,
    )


def _straightness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind == "cylinder":
        o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
        E = axis_frame(a)
        X = (S - o) @ E.T
        if spec.zone_form and "cylindrical" in spec.zone_form:
            # the derived median line: centres of the cross-sections
            centres = []
            for sel in _sections(X[:, 2]):
                c, _ = least_squares_circle(X[sel, :2])
                centres.append(np.r_[c, X[sel, 2].mean()])
            if len(centres) < 2:
                raise _Unmeasurable("fewer than two cross-sections with enough points")
            C = np.array(centres)
            lat = np.linalg.norm(C[:, :2] - C[:, :2].mean(axis=0), axis=1)
            return (
                2 * float(lat.max()),
                None,
                2 * _fit_U(sample.U, 3),
                ("derived median line (cross-section centres)"),
                0.0,
            )
        ang = np.arctan2(X[:, 1], X[:, 0])
        groups = [np.flatnonzero(np.floor((ang + np.pi) / (np.pi / 4)) == k) for k in range(8)]
        lines = [np.c_[X[g, 2], np.hypot(X[g, 0], X[g, 1])] for g in groups]
        what = "worst surface line element (8 sectors)"
    elif feat.kind == "plane":
        E = axis_frame(feat.direction)
        X = (S - feat.origin) @ E.T
        _, _, Vt = np.linalg.svd(X[:, :2] - X[:, :2].mean(axis=0), full_matrices=False)
        u, v = X[:, :2] @ Vt[0], X[:, :2] @ Vt[1]
        k = 8
        edges = np.linspace(v.min(), v.max() + 1e-9, k + 1)
        groups = [np.flatnonzero((v >= edges[i]) & (v < edges[i + 1])) for i in range(k)]
        lines = [np.c_[u[g], X[g, 2]] for g in groups]
        what = "worst line element along the face's length (8 strips)"
    else:
        raise _Unmeasurable("straightness of this feature")
    worst = None
    for g, Q in zip(groups, lines, strict=True):
        if len(Q) < _SECTION_POINTS:
            continue
        fit = line_straightness(Q)
        if worst is None or fit.minimum_zone > worst[0].minimum_zone:
            worst = (fit, g)
    if worst is None:
        raise _Unmeasurable("no line element with enough points")
    fit, g = worst
    return (
        fit.minimum_zone,
        fit.least_squares,
        zone_uncertainty(fit.residuals, sample.U[g]),
        what,
        0.0,
    )


def _orientation(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind == "sphere":
        raise _Unmeasurable(f"{spec.kind} of a sphere")
    if feat.kind == "plane":
        n = feat.direction
        w = S @ n
        rot = _free_rotation(frame)
        how = "planes at the nominal orientation in the frame"
        if rot is not None and abs(rot @ n) < 1 - 1e-9:
            u = S @ np.cross(rot, n)

            def width(th: float) -> float:
                return float(np.ptp(w + th * u))

            best = minimize_scalar(width, bounds=(-0.05, 0.05), method="bounded")
            w = w + best.x * u
            how += " (turned about the free axis)"
        res = w - 0.5 * (w.max() + w.min())
        return float(np.ptp(w)), None, zone_uncertainty(res, sample.U), how, 0.0
    o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    z = (S - o) @ a
    ends = o + np.outer([z.min(), z.max()], a)
    E = np.eye(3) - np.outer(feat.direction, feat.direction)
    run = float(np.linalg.norm(E @ (ends[1] - ends[0])))
    return run, None, 2 * _fit_U(sample.U, 4), "axis (least squares) across its length", 0.0


def _free_rotation(frame: DatumFrameResult | None) -> np.ndarray | None:
    """The axis of a rotation the frame leaves free (None: none)."""
    if frame is None or frame.free_basis is None or frame.free_basis.shape[1] == 0:
        return None
    W = frame.free_basis[:3]
    U_, sv, _ = np.linalg.svd(W, full_matrices=False)
    if sv[0] < 1e-9:
        return None
    return U_[:, 0]


def _position(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind == "sphere":  # a spherical zone about the true centre
        c, _ = least_squares_sphere(S)
        return (
            2 * float(np.linalg.norm(c - feat.origin)),
            None,
            2 * _fit_U(sample.U, 4),
            "centre (least-squares sphere) from true position",
            0.0,
        )
    if feat.kind == "plane":
        d = (S - feat.origin) @ feat.direction
        return (
            2 * float(np.abs(d).max()),
            None,
            float(sample.U[np.argmax(np.abs(d))]) * 2,
            ("surface from true position (2 x farthest)"),
            0.0,
        )
    return _axis_location(spec, S, sample, feat, sizes, faces, position=True)


def _coaxiality(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "cylinder":
        raise _Unmeasurable(f"{spec.kind} of a feature that is not a cylinder")
    return _axis_location(spec, S, sample, feat, sizes, faces, position=False)


def _axis_fit(
    S: np.ndarray, feat: DatumFeature
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The least-squares axis of a cylinder's points: origin, unit direction (as the
    nominal's), radius, and its two ends over the measured length (2, 3)."""
    if largest_gap(S, feat.origin, feat.direction) > MAX_OPEN_DEG:
        raise _Unmeasurable("too little of the cylinder's circumference measured")
    o, a, r_ls = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    a = a if a @ feat.direction > 0 else -a
    z = (S - o) @ a
    return o, a, r_ls, o + np.outer([z.min(), z.max()], a)


def _material_bonus(spec, S, o, a, r_ls, feat: DatumFeature, sizes, faces) -> tuple[float, str]:
    """The MMC/LMC bonus of a position from the feature's measured size and its size
    dimension's limits (0 without a material condition), and how it was found."""
    mods = " ".join(spec.modifiers)
    if not ("maximum_material" in mods or "least_material" in mods):
        return 0.0, ""
    size = next((s for s in sizes if set(faces) <= set(s.faces)), None)
    if size is None or size.lower_limit is None or size.upper_limit is None:
        return 0.0, "; no size limits for the material condition: no bonus"
    scale = 2.0 if size.dim_type == "radius" else 1.0
    lo, hi = size.lower_limit * scale, size.upper_limit * scale
    rho = np.linalg.norm((S - o) @ (np.eye(3) - np.outer(a, a)), axis=1)
    mmc = "maximum_material" in mods
    if mmc:  # the mating size about the axis
        actual = 2 * float(rho.min() if feat.internal else rho.max())
        bonus = actual - lo if feat.internal else hi - actual
    else:
        actual = 2 * r_ls
        bonus = hi - actual if feat.internal else actual - lo
    bonus = max(bonus, 0.0)
    return bonus, f"; {'MMC' if mmc else 'LMC'} bonus {bonus:.4f} mm (size {actual:.4f} mm)"


def _axis_location(spec, S, sample, feat: DatumFeature, sizes, faces, position: bool):
    """An axis from true position at both ends of its measured length, diametral; the
    axis is the least-squares cylinder's (ISO 14405's default association: a tangent
    mating cylinder rests on a few extreme points, and on the partial arc a scan sees of
    a hole it tilts with them), the mating size the largest inscribed (smallest
    circumscribed) cylinder about that axis (never more bonus than the true envelope)."""
    o, a, r_ls, ends = _axis_fit(S, feat)
    E = np.eye(3) - np.outer(feat.direction, feat.direction)
    off = np.linalg.norm((ends - feat.origin) @ E, axis=1)
    value = 2 * float(off.max())
    how = "axis (least squares) from true position at both ends"
    bonus = 0.0
    if position:
        bonus, more = _material_bonus(spec, S, o, a, r_ls, feat, sizes, faces)
        how += more
    return value, None, 2 * _fit_U(sample.U, 4), how, bonus


def _pattern_position(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
) -> CharacteristicResult:
    """The lower segment of a composite position (:mod:`.composite`): each member's
    least-squares axis in the orientation of the segment's frame, the pattern placed as a
    whole (translation, and rotation about what the segment's datums leave free) at the
    position that minimises its worst member's offset beyond its bonus; that member's
    diametral offset reported against the tolerance plus its bonus."""
    fo = None if frame is None else orientation_only(frame)
    rotations = free_rotations(fo)
    Q, P, axes, allow, owner, info = [], [], [], [], [], []
    for j, faces in enumerate(members):
        sample = surf.sample(faces)
        feat = sample.nominal
        why = None
        if feat is None or feat.kind != "cylinder":
            why = "a composite lower segment of a feature that is not a hole or a pin"
        elif len(sample.S) < 8:
            why = f"{len(sample.S)} measured points on a feature"
        try:
            if why is not None:
                raise _Unmeasurable(why)
            S = sample.S if fo is None else fo.move(sample.S)
            o, a, r_ls, ends = _axis_fit(S, feat)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            why = str(exc) if len(members) == 1 else f"faces {_faces(faces)}: {exc}"
            return _not_measured(spec, why)
        bonus, more = _material_bonus(spec, S, o, a, r_ls, feat, sizes, faces)
        d = feat.direction
        for e in ends:
            Q.append(e - (feat.origin + ((e - feat.origin) @ d) * d))
            P.append(e)
            axes.append(d)
            allow.append(bonus / 2)
            owner.append(j)
        U = 2 * _fit_U(sample.U, 4)
        if fo is not None:
            U = float(np.hypot(U, 2 * fo.point_uncertainty(S)))
        info.append((bonus, more, U, len(S), sample))
    try:
        _, _, off = minimax_offsets(
            np.array(Q), np.array(P), np.array(axes), rotations, np.array(allow)
        )
    except RuntimeError as exc:
        return _not_measured(spec, str(exc))
    owner = np.array(owner)
    values = np.array([2 * float(off[owner == j].max()) for j in range(len(members))])
    margin = values - np.array([b for b, *_ in info])
    k = int(np.argmax(margin))
    bonus, more, U, n, sample = info[k]
    moves = "translation" + (
        ", rotation about " + ", ".join(_axis_name(r) for r in rotations) if len(rotations) else ""
    )
    frame_txt = f"orientation in |{'|'.join(frame.labels)}|" if frame is not None else "no datums"
    res = CharacteristicResult(
        spec,
        value=float(values[k]),
        uncertainty=U,
        reading=(
            f"composite lower segment: axes (least squares) relative to the pattern of "
            f"{len(members)}, placed as a whole at its minimax position ({moves}); "
            f"{frame_txt}; worst: faces {_faces(members[k])}{more}"
        ),
        n_points=n,
        coverage=sample.coverage,
        bonus=bonus,
    )
    _judge(res, rule, None, res.limit)
    return res


def _axis_name(v: np.ndarray) -> str:
    i = int(np.argmax(np.abs(v)))
    return "xyz"[i] if abs(v[i]) > 1 - 1e-6 else "(" + ", ".join(f"{x:.3f}" for x in v) + ")"


def _runout(spec, S, sample, feat, frame, sizes, surf, faces):
    if frame is None or frame.axis is None:
        raise _Unmeasurable("runout needs a datum axis (a cylindrical datum)")
    o, a = frame.axis
    z, rho = _axial(S, o, a)
    if feat.kind == "cylinder":
        radial, along = rho, z
        how = "radial about the datum axis"
    elif feat.kind == "plane" and abs(feat.direction @ a) > 0.99:
        radial, along = z, rho
        how = "axial (face across the datum axis)"
    else:
        raise _Unmeasurable("runout of a feature neither coaxial with nor across the axis")
    if spec.kind == "total_runout":
        res = radial - 0.5 * (radial.max() + radial.min())
        return float(np.ptp(radial)), None, zone_uncertainty(res, sample.U), "total " + how, 0.0
    worst, worst_sel = -1.0, None
    for sel in _sections(along):
        if np.ptp(radial[sel]) > worst:
            worst, worst_sel = float(np.ptp(radial[sel])), sel
    if worst_sel is None:
        raise _Unmeasurable("no circular element with enough points")
    r = radial[worst_sel]
    return worst, None, zone_uncertainty(r - r.mean(), sample.U[worst_sel]), "circular " + how, 0.0


_MEASURES = {
    "flatness": _flatness,
    "cylindricity": _cylindricity,
    "roundness": _roundness,
    "straightness": _straightness,
    "perpendicularity": _orientation,
    "parallelism": _orientation,
    "angularity": _orientation,
    "position": _position,
    "coaxiality": _coaxiality,
    "concentricity": _coaxiality,
    "circular_runout": _runout,
    "total_runout": _runout,
}


# --------------------------------------------------------------------------- dimensions


def _cylinder_values(surf: MeasuredSurface, faces) -> tuple[dict, dict, np.ndarray] | None:
    """Nominal and measured diameter/radius of one cylindrical (or spherical) feature, and
    its ``U`` values; None when it is neither or too little of it was measured."""
    sample = surf.sample(faces)
    feat = sample.nominal
    if feat is None or feat.kind == "plane" or len(sample.S) < 8:
        return None
    if feat.kind == "cone":
        return _cone_values(surf, faces, sample, feat)[0]
    if feat.kind == "sphere":
        r = least_squares_sphere(sample.S)[1]
        return (
            {"diameter": 2 * feat.radius, "radius": feat.radius},
            {"diameter": 2 * r, "radius": r},
            sample.U,
        )
    r = least_squares_cylinder(sample.S, feat.origin, feat.direction, feat.radius)[2]
    nom = {"diameter": 2 * feat.radius, "radius": feat.radius}
    meas = {"diameter": 2 * r, "radius": r}
    # the same fit on the raw scan points: their difference is a systematic part of U
    on = np.isin(surf.P_face, faces)
    if sample.source == "vertices" and on.sum() >= 8:
        r_pts = least_squares_cylinder(surf.P[on], feat.origin, feat.direction, feat.radius)[2]
        meas["_systematic_radius"] = abs(r_pts - r)
    return nom, meas, sample.U


def _cone_values(
    surf: MeasuredSurface,
    faces,
    sample: FeatureSample,
    feat: DatumFeature,
    gauge: float | None = None,
) -> list[tuple[dict, dict, np.ndarray]]:
    """A cone's included angle (degrees) and its diameters at the model's two ends (a
    countersink's at the face it opens on, a taper's at either end), nominal and measured:
    the least-squares cone's, in the same planes across the nominal axis; each measured
    value's expanded uncertainty from the fit's own spread (``_U_<key>``: a cone seen on a
    few dozen points of a narrow band is poorly known). Widest end first; then, with a
    ``gauge`` diameter (mm) between the ends, the measured diameter in the plane where the
    model's is ``gauge`` (a basic diameter locating a taper's gauge section)."""
    tri = np.isin(surf.face_id, np.asarray(list(faces), dtype=np.int64))
    X = surf.V[unique_sorted(surf.F[tri])]
    z = (X - feat.origin) @ feat.direction
    draws = cone_draws(sample.S, feat.origin, feat.direction, feat.half_angle)
    out = []
    sections = [float(z.max()), float(z.min())]
    if gauge is not None:
        z_gauge = 0.5 * gauge / math.tan(feat.half_angle)
        if z.min() < z_gauge < z.max():
            sections.append(z_gauge)
    for z_end in sections:
        plane = feat.origin + z_end * feat.direction
        d = []
        for apex, axis, half in draws:
            t = float((plane - apex) @ feat.direction / (axis @ feat.direction))
            d.append(2 * t * np.tan(half))
        ang = [np.degrees(2 * h) for _, _, h in draws]
        d_nom = 2 * z_end * np.tan(feat.half_angle)
        out.append(
            (
                {"diameter": d_nom, "radius": d_nom / 2, "angle": np.degrees(2 * feat.half_angle)},
                {
                    "diameter": d[0],
                    "radius": d[0] / 2,
                    "angle": ang[0],
                    "_U_diameter": 2 * float(np.std(d[1:])),
                    "_U_radius": float(np.std(d[1:])),
                    "_U_angle": 2 * float(np.std(ang[1:])),
                },
                sample.U,
            )
        )
    return out


def _plane_pair_values(surf: MeasuredSurface, fa, fb) -> tuple[dict, dict, np.ndarray] | None:
    """Nominal and measured distance between two parallel planar features."""
    A, B = surf.nominal(fa), surf.nominal(fb)
    if A is None or B is None or A.kind != "plane" or B.kind != "plane":
        return None
    if abs(A.direction @ B.direction) < 0.999:
        return None
    ga, gb = surf.sample(fa), surf.sample(fb)
    if len(ga.S) < 3 or len(gb.S) < 3:
        return None
    n = A.direction
    nom = {"distance": abs(float((B.origin - A.origin) @ n))}
    meas = {"distance": abs(float((gb.S.mean(axis=0) - ga.S.mean(axis=0)) @ n))}
    return nom, meas, np.r_[ga.U, gb.U]


def _size_candidates(
    surf: MeasuredSurface, faces, pairs: bool, gauge: float | None = None
) -> list[tuple[dict, dict, np.ndarray]]:
    """The measurable sizes of a dimension's faces: each cylindrical (spherical) member's
    diameter and radius (a cone's at its ends, and at the ``gauge`` diameter's section,
    :func:`_cone_values`), or with ``pairs`` the distances (and angles) between every two
    members (parallel planes, a plane and an axis, two axes)."""
    members = surf.features(faces)
    if not pairs:
        out = []
        for m in members:
            feat = surf.nominal(m)
            if feat is not None and feat.kind == "cone":
                sample = surf.sample(m)
                if len(sample.S) >= 8:
                    out += _cone_values(surf, m, sample, feat, gauge)
                continue
            c = _cylinder_values(surf, m)
            if c is not None:
                out.append(c)
        return out
    out = []
    for i in range(len(members)):
        for j in range(i + 1, len(members)):
            v = _plane_pair_values(surf, members[i], members[j]) or _pair(
                surf, members[i], members[j]
            )
            if v is not None:
                out.append(v)
    return out


def _between(surf: MeasuredSurface, fa, fb) -> list[tuple[dict, dict, np.ndarray]]:
    """Distance and angle between two features (planes or axes), for each pair of their
    members; and a drilled hole's depth when one side is the plane it opens on and the
    other its cylinder and drill point (:func:`_depth_values`)."""
    out = []
    members_a, members_b = surf.features(fa), surf.features(fb)
    for ma in members_a:
        for mb in members_b:
            v = _pair(surf, ma, mb)
            if v is not None:
                out.append(v)
    for planes, hole in ((members_a, members_b), (members_b, members_a)):
        for m in planes:
            v = _depth_values(surf, m, hole)
            if v is not None:
                out.append(v)
    return out


def _depth_values(
    surf: MeasuredSurface, plane_faces, hole: list[np.ndarray]
) -> tuple[dict, dict, np.ndarray] | None:
    """A drilled hole's depth (mm): from the plane it opens on (``plane_faces``) along its
    axis to the circle where its cylinder meets its drill point (a coaxial cone), nominal
    and measured (the points' mean plane across the nominal normal; the least-squares
    cylinder's radius on the least-squares cone); None when ``hole`` is not one cylinder
    and one coaxial cone, or the plane is not across their axis."""
    P = surf.nominal(plane_faces)
    feats = [(m, surf.nominal(m)) for m in hole]
    cyl = [(m, f) for m, f in feats if f is not None and f.kind == "cylinder"]
    cone = [(m, f) for m, f in feats if f is not None and f.kind == "cone"]
    if P is None or P.kind != "plane" or len(cyl) != 1 or len(cone) != 1:
        return None
    (mc, C), (mk, K) = cyl[0], cone[0]
    if abs(C.direction @ K.direction) < 0.999 or abs(P.direction @ C.direction) < 0.999:
        return None
    off = K.origin - C.origin
    if np.linalg.norm(off - (off @ C.direction) * C.direction) > 1e-3 * max(C.radius, 1.0):
        return None
    sp, sc, sk = surf.sample(plane_faces), surf.sample(mc), surf.sample(mk)
    if len(sp.S) < 3 or len(sc.S) < 8 or len(sk.S) < 7:
        return None
    n = P.direction

    def depth(plane_point, r, apex, axis, half) -> float:
        edge = apex + axis * (r / math.tan(half))
        return abs(float((edge - plane_point) @ n))

    nom = {"distance": depth(P.origin, C.radius, K.origin, K.direction, K.half_angle)}
    r = least_squares_cylinder(sc.S, C.origin, C.direction, C.radius)[2]
    apex, axis, half = least_squares_cone(sk.S, K.origin, K.direction, K.half_angle)
    meas = {"distance": depth(sp.S.mean(axis=0), r, apex, axis, half)}
    return nom, meas, np.r_[sp.U, sc.U, sk.U]


def _pair(surf: MeasuredSurface, fa, fb) -> tuple[dict, dict, np.ndarray] | None:
    sa, sb = surf.sample(fa), surf.sample(fb)
    A, B = sa.nominal, sb.nominal
    if A is None or B is None or len(sa.S) < 8 or len(sb.S) < 8:
        return None
    if "cone" in (A.kind, B.kind):  # a drill point, a countersink: see _depth_values
        return None

    def fitted(sample: FeatureSample, feat: DatumFeature, nominal: bool):
        if feat.kind == "plane":
            if nominal:  # the nominal plane under the measured points
                P = sample.S - np.outer((sample.S - feat.origin) @ feat.direction, feat.direction)
                return P.mean(axis=0), feat.direction
            return sample.S.mean(axis=0), feat.direction
        if nominal:
            z = (sample.S - feat.origin) @ feat.direction
            return feat.origin + feat.direction * z.mean(), feat.direction
        o, a, _ = least_squares_cylinder(sample.S, feat.origin, feat.direction, feat.radius)
        z = (sample.S - o) @ a
        return o + a * z.mean(), a if a @ feat.direction > 0 else -a

    out: list[dict] = []
    for nominal in (True, False):
        (pa, da), (pb, db) = fitted(sa, A, nominal), fitted(sb, B, nominal)
        q: dict[str, float] = {}
        ang = math.degrees(math.acos(float(np.clip(abs(da @ db), 0.0, 1.0))))
        q["angle"] = ang
        q["angle_supplement"] = 180.0 - ang
        d = pb - pa
        if A.kind == "plane" and (B.kind != "plane" or abs(A.direction @ B.direction) > 0.999):
            q["distance"] = abs(float(d @ A.direction))
        elif B.kind == "plane":
            q["distance"] = abs(float(d @ B.direction))
        elif abs(A.direction @ B.direction) > 0.999:  # parallel axes: across them
            E = np.eye(3) - np.outer(A.direction, A.direction)
            q["distance"] = float(np.linalg.norm(E @ d))
        else:
            q["distance"] = float(np.linalg.norm(d))
        out.append(q)
    return out[0], out[1], np.r_[sa.U, sb.U]


def _reported(spec: CharacteristicSpec, cands: list, key: str, what: str) -> CharacteristicResult:
    """A dimension the drawing gives no value (and no limits): the size its faces give,
    measured and reported (status BASIC: a reference, not judged) when they give one
    quantity of its kind, not measured when they give none or several."""
    found = [(nom, meas, U_pts) for nom, meas, U_pts in cands if key in nom]
    values = sorted({round(nom[key], 6) for nom, _, _ in found})
    if len(values) != 1:
        return _not_measured(
            spec,
            "the drawing gives no value and its faces give "
            + ("no " + key if not values else f"several ({', '.join(f'{v:g}' for v in values)})"),
        )
    nom, meas, U_pts = max(found, key=lambda f: abs(f[1][key] - f[0][key]))
    U = None
    if spec.unit == "mm":
        sys_r = meas.get("_systematic_radius", 0.0) * (2.0 if key == "diameter" else 1.0)
        U = float(np.hypot(2 * _fit_U(U_pts, 2), sys_r))
    return CharacteristicResult(
        spec,
        value=float(meas[key]),
        uncertainty=U,
        status="BASIC",
        reading=f"{key} {what}; the drawing gives no value (nominal {nom[key]:.4g} on the "
        "model): reported, not judged",
        n_points=len(U_pts),
    )


def _target_area_size(
    spec: CharacteristicSpec, surf: MeasuredSurface, areas: Sequence[tuple[str, TargetSpec]]
) -> CharacteristicResult | None:
    """A basic dimension between two curves of one face that is a side (or the diameter)
    of a datum target area on that face: theoretically exact, the extent of the simulator
    that establishes the datum, applied as given (QIF ``BASIC_OR_TED``; nothing of the part
    to measure); None when it is not one."""
    if spec.nominal is None or spec.origin_faces is None:
        return None
    for label, tg in areas:
        faces = tg.faces
        if not len(faces):
            v = tg.area_vertices(surf)
            tri = np.isin(surf.F, v).any(axis=1)
            faces = unique_sorted(surf.face_id[tri])
        if not np.isin(spec.origin_faces, faces).any():
            continue
        sides = {"diameter": tg.diameter, "length": tg.length, "width": tg.width}
        for side, size in sides.items():
            if size is not None and abs(size - spec.nominal) <= 1e-3 * max(size, 1.0):
                return CharacteristicResult(
                    spec,
                    status="BASIC",
                    reading=(
                        f"the {side} of datum target area {tg.name} ({tg.size_text()}): "
                        f"theoretically exact, the extent of the simulator establishing datum "
                        f"{label}, applied as given; nothing of the part to measure"
                    ),
                )
    return None


def _dimension(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    rule: str,
    areas: Sequence[tuple[str, TargetSpec]] = (),
) -> CharacteristicResult:
    no_value = spec.nominal is None
    if spec.thread:
        return _not_measured(
            spec,
            f"a thread's dimension, given on supplemental geometry {spec.thread}: the model "
            "carries the thread as its tap-drill hole (a cosmetic thread), so its size and "
            "depth are no surface a scan measures (a thread gauge does)",
        )
    if no_value and (spec.lower_limit is not None or spec.upper_limit is not None):
        return _not_measured(spec, "the dimension's nominal could not be established")
    if spec.origin_faces is not None and spec.target_faces is not None:
        if not len(spec.origin_faces) or not len(spec.target_faces):
            return _not_measured(spec, "a feature of the location has no face on the part")
        if set(spec.origin_faces) == set(spec.target_faces):
            applied = _target_area_size(spec, surf, areas)
            if applied is not None:
                return applied
            return _not_measured(
                spec,
                "its origin and target are both on face(s) "
                f"{_faces(spec.origin_faces)} (curves of a face, not surfaces): not measured "
                "from the scanned surface",
            )
        cands = _between(surf, spec.origin_faces, spec.target_faces)
        what = "between its origin and target features"
    elif len(spec.faces):
        gauge = spec.nominal if spec.dim_type == "diameter" else None
        cands = _size_candidates(surf, spec.faces, pairs=False, gauge=gauge)
        what = "of its feature"
    else:
        return _not_measured(spec, "no B-rep face of the part is associated")
    if spec.unit == "deg":
        keys = ["angle", "angle_supplement"]
    elif spec.dim_type == "radius":
        keys = ["radius", "distance"]
    else:
        keys = ["diameter", "distance", "radius"]
    if no_value:
        natural = {"diameter": "diameter", "radius": "radius"}.get(spec.dim_type, "distance")
        return _reported(spec, cands, "angle" if spec.unit == "deg" else natural, what)
    tol = max(_NOMINAL_AGREEMENT * abs(spec.nominal), 0.02 if spec.unit == "mm" else 0.1)

    def matching(cands) -> list:
        found = []
        for nom, meas, U_pts in cands:
            k = next((k for k in keys if k in nom and abs(nom[k] - spec.nominal) <= tol), None)
            if k is not None:
                found.append((spec.nominal + (meas[k] - nom[k]), k, meas, U_pts))
        return found

    found = matching(cands)
    if not found and spec.origin_faces is None:  # not its members' sizes: between them
        cands = cands + _size_candidates(surf, spec.faces, pairs=True)
        found = matching(cands)
    if not found:
        seen = sorted({f"{k} {nom[k]:.4g}" for nom, _, _ in cands for k in keys if k in nom})
        why = (
            f"the faces' geometry ({', '.join(seen) or 'no plane pair or cylinder measured'}) "
            f"does not give the drawing's nominal {spec.nominal:g} {spec.unit}"
        )
        if spec.drawn:
            why = (
                "its origin and target are curves drawn on faces "
                f"{_faces(spec.origin_faces)} and {_faces(spec.target_faces)} (supplemental "
                f"geometry), not the faces themselves, and {why}"
            )
        return _not_measured(spec, why)
    lo, hi = spec.lower_limit, spec.upper_limit
    mid = 0.5 * (lo + hi) if lo is not None and hi is not None else spec.nominal
    value, k, meas, U_pts = max(found, key=lambda f: abs(f[0] - mid))  # the worst member
    U = None
    if spec.unit == "mm":
        sys_r = meas.get("_systematic_radius", 0.0) * (2.0 if k == "diameter" else 1.0)
        U = float(np.hypot(2 * _fit_U(U_pts, 2), sys_r))
    if f"_U_{k}" in meas:  # a fit's own spread (a cone's)
        U = float(np.hypot(U or 0.0, meas[f"_U_{k}"]))
    n_members = f"worst of {len(found)} features; " if len(found) > 1 else ""
    res = CharacteristicResult(
        spec,
        value=value,
        uncertainty=U,
        reading=f"{n_members}{k.replace('_', ' ')} {what} (drawing nominal + measured "
        "- mesh nominal)",
        n_points=len(U_pts),
    )
    if spec.basic or (lo is None and hi is None):
        res.status = "BASIC"
        return res
    _judge(res, rule, lo, hi)
    return res
