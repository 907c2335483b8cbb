"""Tolerance zones on the nominal surface: which band applies where, and where it came from.

A **zone** is one toleranced surface: a set of B-rep faces and a band ``[lower, upper]`` on the
signed normal deviation (mm; positive = material proud of the nominal, i.e. along the outward
normal). Zones come from the part's semantic PMI (:func:`zones_from_pmi`) or from the general
tolerance of the command line.

Profile of a surface, width ``t``:

* **bilateral, equally disposed** (the default): ``[-t/2, +t/2]``.
* **unequally disposed** (ASME Y14.5 "UZ", AP242 ``UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE``
  with displacement ``d``): ``d`` is the part of the zone lying outside the material (toward
  the +normal side), so the band is ``[d - t, d]``. ``d = t`` is unilateral outward
  (``[0, t]``), ``d = 0`` unilateral inward (``[-t, 0]``). A displacement outside ``[0, t]``
  is rejected as unreadable PMI rather than guessed.

Other PMI is listed but not scored by the area/region criteria: form and orientation
tolerances of features (flatness, position, perpendicularity, ...) and dimensions need a
feature fit, not a surface band. They are reported as "not evaluated" with the reason.

Datum reference frames. The datums of a profile tolerance say how the part is held while it
is measured. qifreport's virtual fixture replaces the physical datum fixture for a compliant
part (paper Section 10): every profile zone is evaluated on the same virtually fixtured
nominal, and the datum reference frame is reported with the zone. A tolerance carrying the
**free-state** modifier (ASME "F") is, by definition, checked *unrestrained*: it is evaluated
on the rigidly aligned deviation, without the virtual fixture.

Whole-part profile. A surface-profile tolerance on "all surfaces" (the STEP reader's
``whole_part``: its toleranced shape aspect is the product shape itself, or a shape aspect with
no face link, as NIST FTC 07 #16292 and FTC 10 #18552 encode the general profile) *is* the
general zone: faces ``None``, its width and disposition, datums and modifiers, source ``"pmi"``
and the STEP id and name of the item. Several whole-part profiles: the tightest one (ties: the
first in file order) governs every face and the others are listed as not evaluated. The
drawing wins over the command line: a ``--tolerance`` that does not give the same band is
refused (:class:`~qifreport.errors.InputError` naming both); one that agrees is accepted and
the zone keeps its PMI source.

Overlaps and gaps. A vertex where several zones meet (a face boundary, or a face under two
profile tolerances) takes the **tightest** zone (smallest width; ties: the first in file
order) in the combined map. Faces under no profile tolerance belong to the **general** zone:
a whole-part profile of the PMI (source ``"pmi"``), else the ``--tolerance`` of the command
line (source ``"general"``), else
:data:`DEFAULT_GENERAL_TOLERANCE` (source ``"default"``); the report says which.
Each zone is *also* evaluated on its own faces with its own band (area and region criteria
per toleranced surface).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from qifreport.errors import InputError
from qifreport.kinds import kind_label, lookup_kind, unapplied_modifiers
from qifreport.registration.arrays import unique_sorted

__all__ = [
    "DEFAULT_GENERAL_TOLERANCE",
    "BandField",
    "composite_segment",
    "composite_upper",
    "lay_bands",
    "material_boundary",
    "NotEvaluated",
    "profile_band",
    "symmetric_zone",
    "ToleranceZone",
    "triangle_zone_mask",
    "zone_vertex_areas",
    "zones_from_pmi",
]

log = logging.getLogger(__name__)

#: mm, half-width of the general profile band (zone 1.0 mm) used on faces that no profile
#: tolerance covers when the command line gives none: a common title-block general
#: profile tolerance for moulded and sheet-metal parts. Always reported as source "default".
DEFAULT_GENERAL_TOLERANCE = 0.5


def composite_segment(tol, tolerances) -> str:
    """A PMI tolerance's place in a composite feature control frame: ``'upper'`` (the
    pattern-locating segment: the group's largest value), ``'lower'`` (a feature-relating
    segment: its datums orient only, its zone may translate as a whole) or ``''`` (not
    composite). ``tolerances``: every tolerance of the PMI."""
    if not getattr(tol, "composite_with", None):
        return ""
    by_id = {t.step_id: t for t in tolerances}
    group = [tol] + [by_id[i] for i in tol.composite_with if i in by_id]
    values = [t.value for t in group if t.value is not None]
    if tol.value is None or not values:
        return ""
    return "upper" if tol.value >= max(values) else "lower"


def composite_upper(tol, tolerances) -> int | None:
    """The STEP entity id of the upper segment of the composite frame whose lower segment
    is ``tol`` (None: ``tol`` is not a lower segment). ``tolerances``: every tolerance of
    the PMI."""
    if composite_segment(tol, tolerances) != "lower":
        return None
    by_id = {t.step_id: t for t in tolerances}
    group = [by_id[i] for i in tol.composite_with if i in by_id]
    upper = [t for t in group if composite_segment(t, tolerances) == "upper"]
    return upper[0].step_id if upper else None


def material_boundary(modifiers: list[str]) -> str:
    """The material boundary a datum reference or tolerance names among its (PMI) modifiers:
    ``'MAXIMUM'``, ``'LEAST'`` or ``'NONE'`` (regardless of material boundary)."""
    text = " ".join(modifiers)
    if "maximum_material" in text:
        return "MAXIMUM"
    if "least_material" in text:
        return "LEAST"
    return "NONE"


@dataclass
class ToleranceZone:
    """One toleranced surface and its band.

    Attributes
    ----------
    key : short unique key, e.g. ``"T1"``, ``"general"``.
    name : the tolerance's name in the file (or a description).
    kind : tolerance type, e.g. ``"surface_profile"``.
    width : zone width ``t``, mm.
    lower, upper : the band on the signed deviation, mm (``upper - lower == width``).
    faces : (k,) int64 face ids, or None for "every face not otherwise covered" (general).
    source : ``"pmi"``, ``"general"`` (command line) or ``"default"``.
    datums : datum labels in precedence order.
    modifiers : lowercase modifier names from the PMI.
    step_id : STEP entity id of the tolerance, None for general zones.
    free_state : evaluate without the virtual fixture (ASME free-state modifier).
    min_coverage : this surface's own least scored share (None: the inspection's
        ``min_coverage``), :mod:`qifreport.metrology.acceptance.coverage`.
    triangles : (k,) int64 triangles of the mesh that belong to the zone besides its faces'
        own: the footprint on the solid of a supplemental face the tolerance names
        (:mod:`qifreport.step.supplemental`); None: none.
    datum_materials : each datum reference's material boundary as drawn
        (:func:`material_boundary`), same order as ``datums``.
    composite : ``'upper'``/``'lower'`` segment of a composite profile
        (:func:`composite_segment`), ``''`` for a single-segment one.
    composite_of : a lower segment's upper segment, by STEP entity id
        (:func:`composite_upper`); None for any other zone.
    """

    key: str
    name: str
    kind: str
    width: float
    lower: float
    upper: float
    faces: np.ndarray | None
    source: str
    datums: list[str] = field(default_factory=list)
    modifiers: list[str] = field(default_factory=list)
    step_id: int | None = None
    free_state: bool = False
    min_coverage: float | None = None
    triangles: np.ndarray | None = None
    datum_materials: list[str] = field(default_factory=list)
    composite: str = ""
    composite_of: int | None = None

    @property
    def center(self) -> float:
        return 0.5 * (self.lower + self.upper)

    @property
    def half_width(self) -> float:
        return 0.5 * (self.upper - self.lower)

    def describe(self) -> str:
        """One line, e.g. ``surface profile 0.5 mm |A|B|C| [-0.25, +0.25] (pmi #1234)``."""
        drf = "|" + "|".join(self.datums) + "|" if self.datums else ""
        src = self.source if self.step_id is None else f"{self.source} #{self.step_id}"
        return (
            f"{kind_label(self.kind)} {self.width:g} mm {drf} "
            f"[{self.lower:+g}, {self.upper:+g}] ({src})"
        ).replace("  ", " ")

    def to_dict(self) -> dict:
        return {
            "key": self.key,
            "name": self.name,
            "kind": self.kind,
            "width_mm": self.width,
            "lower_mm": self.lower,
            "upper_mm": self.upper,
            "source": self.source,
            "datums": list(self.datums),
            "modifiers": list(self.modifiers),
            "step_id": self.step_id,
            "free_state": self.free_state,
            "min_coverage": self.min_coverage,
            "n_faces": None if self.faces is None else int(len(self.faces)),
            "faces": None if self.faces is None else [int(f) for f in self.faces],
        }


@dataclass
class NotEvaluated:
    """A PMI item listed in the report but not scored, with the reason."""

    kind: str
    name: str
    step_id: int | None
    reason: str

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "name": self.name,
            "step_id": self.step_id,
            "reason": self.reason,
        }


def symmetric_zone(
    half_width: float, source: str, key: str = "general", name: str = "general profile tolerance"
) -> ToleranceZone:
    """A bilateral surface-profile zone ``[-h, +h]`` on every face not otherwise covered."""
    h = float(half_width)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"tolerance half-width must be positive, got {half_width}")
    return ToleranceZone(
        key=key,
        name=name,
        kind="surface_profile",
        width=2 * h,
        lower=-h,
        upper=h,
        faces=None,
        source=source,
    )


def profile_band(width: float, displacement: float | None) -> tuple[float, float]:
    """Band ``(lower, upper)`` of a surface-profile zone of width ``t`` (module docstring).

    Raises ValueError for a non-positive width or a displacement outside ``[0, t]``.
    """
    t = float(width)
    if not (np.isfinite(t) and t > 0):
        raise ValueError(f"zone width must be positive, got {width}")
    if displacement is None:
        return -0.5 * t, 0.5 * t
    d = float(displacement)
    if not (np.isfinite(d) and -1e-12 <= d <= t * (1 + 1e-12)):
        raise ValueError(f"unequal displacement {d} outside [0, {t}]")
    return d - t, d


def zones_from_pmi(
    pmi,
    face_index: dict[int, int],
    general: float | None,
) -> tuple[list[ToleranceZone], list[NotEvaluated]]:
    """Tolerance zones of a part from its semantic PMI.

    Parameters
    ----------
    pmi : :class:`qifreport.step.pmi.PMI` (values in mm) or None.
    face_index : STEP face entity id -> face id of the tessellated part.
    general : half-width of the general zone from the command line (mm), or None for
        :data:`DEFAULT_GENERAL_TOLERANCE`.

    Returns
    -------
    zones : one zone per surface-profile tolerance with a value and faces, in file order,
        then the general zone (always present; it applies to the faces no profile covers):
        the tightest whole-part profile of the PMI if there is one (module docstring).
    skipped : profile tolerances that are not scored, with the reason (the other
        tolerances and the dimensions are feature characteristics:
        :func:`qifreport.metrology.gdt.pmi_plan.specs_from_pmi`).

    Raises
    ------
    InputError
        ``general`` is given and does not give the band of the PMI's whole-part profile.
    """
    zones: list[ToleranceZone] = []
    skipped: list[NotEvaluated] = []
    whole: list[ToleranceZone] = []
    if pmi is not None:
        for tol in pmi.tolerances:
            kind = lookup_kind(tol.type)
            if kind is None or not kind.band:
                continue  # a feature characteristic (:mod:`.characteristics`)
            zone = _profile_zone(tol, face_index, f"T{len(zones) + 1}", pmi.tolerances)
            if isinstance(zone, NotEvaluated):
                skipped.append(zone)
            else:
                (whole if zone.faces is None else zones).append(zone)
    if whole:
        zones.append(_whole_part_zone(whole, general, skipped))
    elif general is None:
        zones.append(symmetric_zone(DEFAULT_GENERAL_TOLERANCE, "default"))
    else:
        zones.append(symmetric_zone(general, "general"))
    return zones, skipped


def _profile_zone(
    tol, face_index: dict[int, int], key: str, tolerances: list
) -> ToleranceZone | NotEvaluated:
    """The zone of one surface-profile tolerance of the PMI (``key``: its key unless it is
    the whole part's, ``"general"``), or why it is not scored (:func:`zones_from_pmi`;
    ``tolerances``: every tolerance of the PMI, for a composite's segments)."""
    if tol.value is None:
        return NotEvaluated(
            tol.type,
            tol.name,
            tol.step_id,
            "tolerance value could not be established: " + "; ".join(tol.problems),
        )
    is_whole = bool(getattr(tol, "whole_part", False))
    faces = sorted({face_index[s] for s in tol.face_step_ids if s in face_index})
    if not faces and not is_whole:
        return NotEvaluated(tol.type, tol.name, tol.step_id, "no B-rep face could be associated")
    unapplied = unapplied_modifiers(tol.type, tol.modifiers)
    if unapplied:
        what = ", ".join(m.replace("_", " ") for m in unapplied)
        return NotEvaluated(
            tol.type,
            tol.name,
            tol.step_id,
            f"modifier {what} not applied by qifreport: a band without it would be another "
            "requirement",
        )
    try:
        lo, hi = profile_band(tol.value, tol.unequal_displacement)
    except ValueError as exc:
        return NotEvaluated(tol.type, tol.name, tol.step_id, str(exc))
    mods = list(tol.modifiers)
    return ToleranceZone(
        key="general" if is_whole else key,
        name=tol.name or f"#{tol.step_id}",
        kind=tol.type,
        width=float(tol.value),
        lower=lo,
        upper=hi,
        faces=None if is_whole else np.asarray(faces, dtype=np.int64),
        source="pmi",
        datums=[d.label for d in sorted(tol.datums, key=lambda d: d.precedence)],
        modifiers=mods,
        step_id=tol.step_id,
        free_state="free_state" in mods,
        datum_materials=[
            material_boundary(d.modifiers) for d in sorted(tol.datums, key=lambda d: d.precedence)
        ],
        composite=composite_segment(tol, tolerances),
        composite_of=composite_upper(tol, tolerances),
    )


def _whole_part_zone(
    whole: list[ToleranceZone], general: float | None, skipped: list[NotEvaluated]
) -> ToleranceZone:
    """The governing whole-part profile (the tightest; ties: the first in file order).

    The others are appended to ``skipped``; a command-line half-width that does not give the
    governing band raises :class:`InputError`.
    """
    zone = min(whole, key=lambda z: z.width)  # min keeps the first of equal widths
    for z in whole:
        if z is not zone:
            skipped.append(
                NotEvaluated(
                    z.kind,
                    z.name,
                    z.step_id,
                    f"whole-part profile {z.width:g} mm: the tighter whole-part profile "
                    f"{zone.name} #{zone.step_id} ({zone.width:g} mm) governs every face",
                )
            )
    if general is not None and not (
        np.isclose(zone.lower, -general, rtol=0, atol=1e-9)
        and np.isclose(zone.upper, general, rtol=0, atol=1e-9)
    ):
        raise InputError(
            f"--tolerance {general:g} (band [-{general:g}, +{general:g}] mm) conflicts with the "
            f"drawing's whole-part profile {zone.name!r} #{zone.step_id} ({zone.width:g} mm, "
            f"band [{zone.lower:+g}, {zone.upper:+g}] mm): the drawing's general profile "
            "governs; drop --tolerance or give the same band"
        )
    return zone


def triangle_zone_mask(
    face_id: np.ndarray, zone: ToleranceZone, covered: np.ndarray | None = None
) -> np.ndarray:
    """(f,) bool: triangles of the zone (a general zone takes the uncovered triangles)."""
    if zone.faces is not None:
        mask = np.isin(face_id, zone.faces)
        if zone.triangles is not None:
            mask[zone.triangles] = True
        return mask
    if covered is None:
        return np.ones(len(face_id), dtype=bool)
    return ~covered


@dataclass
class BandField:
    """The zones laid on the mesh.

    Attributes
    ----------
    zones : all zones (general last).
    tri_masks : per zone, (f,) bool triangles it covers (the general zone: the rest).
    lower, upper : (n,) per-vertex band of the tightest zone touching the vertex, mm.
    governing : (n,) int index into ``zones`` of that zone.
    """

    zones: list[ToleranceZone]
    tri_masks: list[np.ndarray]
    lower: np.ndarray
    upper: np.ndarray
    governing: np.ndarray

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (self.lower + self.upper)

    @property
    def half_width(self) -> np.ndarray:
        return 0.5 * (self.upper - self.lower)


def lay_bands(
    F: np.ndarray, n: int, face_id: np.ndarray | None, zones: list[ToleranceZone]
) -> BandField:
    """Lay the zones on the mesh; each vertex takes the tightest zone around it.

    Parameters
    ----------
    F : (f, 3) triangles.  n : number of vertices.
    face_id : (f,) B-rep face id per triangle, or None (a mesh nominal: only general zones).
    zones : from :func:`zones_from_pmi` (zones with ``faces=None`` cover the rest).
    """
    F = np.asarray(F, dtype=np.int64)
    if face_id is None:
        face_id = np.zeros(len(F), dtype=np.int64)
        if any(z.faces is not None for z in zones):
            raise ValueError("face-based zones need per-triangle face ids")
    covered = np.zeros(len(F), dtype=bool)
    for z in zones:
        if z.faces is not None:
            covered |= triangle_zone_mask(face_id, z)
    masks = [triangle_zone_mask(face_id, z, covered) for z in zones]
    width = np.full(n, np.inf)
    gov = np.full(n, -1, dtype=np.int64)
    # tightest first wins; ties keep the earlier zone (stable order)
    order = sorted(range(len(zones)), key=lambda i: (zones[i].width, i))
    for i in order:
        verts = unique_sorted(F[masks[i]].ravel())
        free = verts[gov[verts] < 0]
        gov[free] = i
        width[free] = zones[i].width
    lower = np.full(n, np.nan)
    upper = np.full(n, np.nan)
    has = gov >= 0
    lower[has] = np.array([zones[i].lower for i in gov[has]])
    upper[has] = np.array([zones[i].upper for i in gov[has]])
    return BandField(zones=zones, tri_masks=masks, lower=lower, upper=upper, governing=gov)


def zone_vertex_areas(V: np.ndarray, F: np.ndarray, tri_mask: np.ndarray) -> np.ndarray:
    """(n,) barycentric vertex areas (mm^2) counting only the triangles in ``tri_mask``."""
    V = np.asarray(V, dtype=np.float64)
    Fz = np.asarray(F, dtype=np.int64)[tri_mask]
    a = 0.5 * np.linalg.norm(np.cross(V[Fz[:, 1]] - V[Fz[:, 0]], V[Fz[:, 2]] - V[Fz[:, 0]]), axis=1)
    out = np.zeros(len(V))
    np.add.at(out, Fz.ravel(), np.repeat(a / 3.0, 3))
    return out
