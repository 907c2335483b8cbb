"""The characteristic kinds of a drawing's geometric tolerances, defined once.

Each kind (``"flatness"``, ``"position"``, ``"circular_runout"`` ...) is one
:class:`CharacteristicKind`: how the STEP reader recognises it, how the STEP writer writes
it, whether it is read in a datum frame, the function that measures it, its QIF
characteristic type and definition elements, and how a batch's statistics carry it. Every
layer asks the registry (:data:`KINDS`, :func:`lookup_kind`) instead of keeping its own list
of names, so a new kind is one :func:`register_kind` call.

This module is part of the foundation: it imports nothing else of qifreport. A measurement
function is a lazy ``"module:function"`` reference, imported on first use.

Dimensions (sizes, distances, angles) are not kinds here: their characteristic is the
dimension's type (:mod:`qifreport.metrology.gdt.dimensions`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "APPLIED_EVERYWHERE",
    "SEPARATE",
    "FAMILIES",
    "KINDS",
    "MATERIAL_REQUIREMENTS",
    "CharacteristicKind",
    "QifRules",
    "StatisticsRule",
    "kind_for_qif_type",
    "kind_for_step_entity",
    "kind_label",
    "lookup_kind",
    "register_kind",
    "registered",
    "resolve",
    "unapplied_material",
    "unapplied_modifiers",
    "unregister_kind",
]

#: the families of geometric tolerances (ASME Y14.5-2018 table 8-1; ISO 1101)
FAMILIES = ("form", "orientation", "location", "profile", "runout")
#: how a kind relates to datums: never (form), optional (position, profiles), required
_DATUM_RULES = ("never", "optional", "required")


def resolve(ref: str) -> Callable[..., Any]:
    """The object a ``"package.module:function"`` reference names (imported now)."""
    module, _, name = ref.partition(":")
    if not module or not name:
        raise ValueError(f"not a 'module:function' reference: {ref!r}")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class QifRules:
    """The elements of a kind's QIF characteristic definition and measurement
    (:mod:`qifreport.qif.feature_characteristics`), in the schema's order.

    Attributes
    ----------
    datum_frame : its definition names the ``DatumReferenceFrameId`` of its datums.
    material_condition : its definition states a ``MaterialCondition``.
    zone_shape : its definition states a ``ZoneShape``: ``DiametricalZone`` for a
        cylindrical zone form, else this default, ``"planar"`` (``PlanarZone``) or
        ``"non-diametrical"`` (``NonDiametricalZone``); None: no ``ZoneShape``.
    spherical_zone : a spherical zone form gives ``SphericalZone``.
    bonus : its measurement states the ``Bonus`` of a material condition.
    outer_disposition : its definition states half the tolerance as ``OuterDisposition``.
    section_vector : its nominal states the sections' direction (``Vector``); without a
        known direction the item is a ``UserDefinedAttribute``.
    per_unit : the per-unit zones its definition can state (``"length"``: a
        ``ToleranceZonePerUnitLength``; ``"area"``: a ``ToleranceZonePerUnitArea``).
    max_tolerance : its definition can state a MAX tolerance (``MaximumToleranceValue``,
        the zone's cap when a bonus is available).
    tangent_plane : its definition can state a tangent plane (``TangentPlane``).
    projected : its definition can state a projected zone's height
        (``ProjectedToleranceZoneValue``).
    extent : its definition can state a profile's extent (``Extent``: all around ...).
    """

    datum_frame: bool = False
    material_condition: bool = False
    zone_shape: str | None = None
    spherical_zone: bool = False
    bonus: bool = False
    outer_disposition: bool = False
    section_vector: bool = False
    per_unit: tuple[str, ...] = ()
    max_tolerance: bool = False
    tangent_plane: bool = False
    projected: bool = False
    extent: bool = False


@dataclass(frozen=True)
class StatisticsRule:
    """How a batch's statistics carry a kind (:mod:`qifreport.qif.statistics`): its value is a
    zone width (mm), at most the definition's ``ToleranceValue`` (one-sided: the upper
    ``Cpk`` only).

    Attributes
    ----------
    worst_deviations : its measurements' worst positive and negative deviations are copied
        and summarised (a profile's).
    from_results : its definition is written from the results read back (a surface
        profile's, carried by every results document), not copied from its results
        document.
    """

    worst_deviations: bool = False
    from_results: bool = False


@dataclass(frozen=True)
class CharacteristicKind:
    """One kind of geometric tolerance, everything the layers need to know of it.

    Attributes
    ----------
    name : the kind as the PMI and the characteristics name it (``"flatness"``).
    family : one of :data:`FAMILIES`.
    step_entities : the STEP AP242 entity types of a tolerance of this kind
        (``"FLATNESS_TOLERANCE"``).
    xcaf_type : OCCT's ``XCAFDimTolObjects_GeomToleranceType_<xcaf_type>`` the STEP writer
        gives it (``"Flatness"``); None: not written.
    writer_name : the type name of :class:`qifreport.step.write.PMISpecTolerance` when it is
        not ``name`` (``"circularity"`` for roundness).
    datums : ``"never"`` (form: never related to a datum), ``"optional"`` (position and the
        profiles: in a datum frame when they name one) or ``"required"`` (not measured
        without datums).
    band : judged as a band about the surface (:mod:`qifreport.metrology.acceptance.bands`), not as
    a
        feature characteristic.
    whole_part : may apply to every face of the part (written with no face).
    measure : ``"module:function"`` measuring one feature of it:
        ``f(spec, S, sample, feat, frame, sizes, surf, faces)`` -> ``(value, least_squares,
        U, how, bonus)`` (:mod:`qifreport.metrology.gdt.characteristics`); None: not measured
        per feature.
    measure_whole : ``"module:function"`` measuring it over its faces at once, before any
        feature is formed: ``f(spec, surf, frame, rule)`` -> ``CharacteristicResult``.
    measure_pattern : ``"module:function"`` measuring its features as one pattern when it
        can (a composite lower segment, a width feature): ``f(spec, surf, members, frame,
        rule, sizes)`` -> ``CharacteristicResult`` or None (then per feature).
    diametral : its value is a diameter (twice an offset): the frame's uncertainty counts
        twice.
    measured_per_unit : the per-unit bases it is measured with (``"area"``: flatness per
        unit area); any other per-unit tolerance is not evaluated.
    qif_type : its QIF characteristic type, the stem of ``<qif_type>CharacteristicDefinition``,
        ``...Nominal``, ``...Item``, ``...Measurement`` and ``...Stats``; None: QIF has none
        (a ``UserDefinedAttribute``).
    qif : its QIF definition's elements.
    statistics : how a batch's statistics carry it; None: not carried.
    label : its name in reports (default: the name with spaces).
    modifiers : the drawing's modifiers its measurement applies besides those every kind
        applies (:data:`APPLIED_EVERYWHERE`); with any other one the characteristic is
        not measured (:func:`unapplied_modifiers`), except a material requirement, whose
        bonus can only widen the zone (:data:`MATERIAL_REQUIREMENTS`).
    """

    name: str
    family: str
    step_entities: tuple[str, ...] = ()
    xcaf_type: str | None = None
    writer_name: str = ""
    datums: str = "required"
    band: bool = False
    whole_part: bool = False
    measure: str | None = None
    measure_whole: str | None = None
    measure_pattern: str | None = None
    diametral: bool = False
    measured_per_unit: tuple[str, ...] = ()
    qif_type: str | None = None
    qif: QifRules = field(default_factory=QifRules)
    statistics: StatisticsRule | None = field(default_factory=StatisticsRule)
    label: str = ""
    modifiers: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"{self.name}: family {self.family!r} is not one of {FAMILIES}")
        if self.datums not in _DATUM_RULES:
            raise ValueError(f"{self.name}: datums {self.datums!r} is not one of {_DATUM_RULES}")
        if not self.label:
            object.__setattr__(self, "label", self.name.replace("_", " "))
        if not self.writer_name:
            object.__setattr__(self, "writer_name", self.name)

    @property
    def needs_frame(self) -> bool:
        """Whether it is read in the frame of its datums (every kind but form)."""
        return self.datums != "never"

    @property
    def measured(self) -> bool:
        """Whether qifreport measures it as a feature characteristic."""
        return self.measure is not None or self.measure_whole is not None

    def measure_function(self) -> Callable[..., tuple]:
        """The per-feature measurement function (:attr:`measure`), imported now."""
        if self.measure is None:
            raise ValueError(f"{self.name} is not measured per feature")
        return resolve(self.measure)


#: the modifiers every kind applies: free state (judged on the free state's surface)
APPLIED_EVERYWHERE = ("free_state",)
#: material requirements: their bonus widens the zone, so a kind that does not apply them
#: reads against the stricter zone: its PASS stands, a FAIL is not established
MATERIAL_REQUIREMENTS = ("maximum_material_requirement", "least_material_requirement")
#: the extents a profile's faces already carry (the file lists every face of the extent)
_EXTENTS = ("all_around", "all_over", "between", "continuous_feature")
#: a separate requirement (SEP REQT): each characteristic in its own frame placement. The
#: datum features are simulated regardless of material boundary, so every characteristic
#: of a frame has that frame's one placement: separate and simultaneous read the same
SEPARATE = "separate_requirement"

_M = "qifreport.metrology.gdt"
_FORM = dict(family="form", datums="never")
_ORIENTATION = dict(
    family="orientation",
    measure=f"{_M}.geometric:measure_orientation",
    # a plane's tangent plane (T) is held in the zone, not its surface
    modifiers=("tangent_plane",),
    qif=QifRules(
        datum_frame=True,
        material_condition=True,
        zone_shape="planar",
        max_tolerance=True,
        tangent_plane=True,
        projected=True,
    ),
)
_COAXIAL = dict(
    family="location",
    measure=f"{_M}.location:measure_coaxiality",
    diametral=True,
    qif=QifRules(datum_frame=True, zone_shape="non-diametrical"),
)
_RUNOUT = dict(family="runout", qif=QifRules(datum_frame=True))

#: the registered kinds by name, in the STEP reader's order
KINDS: dict[str, CharacteristicKind] = {
    k.name: k
    for k in (
        CharacteristicKind(
            "surface_profile",
            family="profile",
            step_entities=("SURFACE_PROFILE_TOLERANCE",),
            xcaf_type="ProfileOfSurface",
            datums="optional",
            band=True,
            whole_part=True,
            modifiers=(*_EXTENTS, SEPARATE),
            qif_type="SurfaceProfile",
            statistics=StatisticsRule(worst_deviations=True, from_results=True),
        ),
        CharacteristicKind(
            "line_profile",
            family="profile",
            step_entities=("LINE_PROFILE_TOLERANCE",),
            xcaf_type="ProfileOfLine",
            datums="optional",
            measure_whole=f"{_M}.geometric:measure_line_profile",
            modifiers=("all_around", "between"),
            qif_type="LineProfile",
            qif=QifRules(outer_disposition=True, section_vector=True, extent=True),
            statistics=StatisticsRule(worst_deviations=True),
        ),
        CharacteristicKind(
            "flatness",
            **_FORM,
            step_entities=("FLATNESS_TOLERANCE",),
            xcaf_type="Flatness",
            measure=f"{_M}.geometric:measure_flatness",
            measured_per_unit=("area",),
            # coplanar faces are one feature (MeasuredSurface.features)
            modifiers=("continuous_feature",),
            qif_type="Flatness",
            qif=QifRules(per_unit=("area",), max_tolerance=True),
        ),
        CharacteristicKind(
            "straightness",
            **_FORM,
            step_entities=("STRAIGHTNESS_TOLERANCE",),
            xcaf_type="Straightness",
            measure=f"{_M}.geometric:measure_straightness",
            qif_type="Straightness",
            qif=QifRules(zone_shape="non-diametrical", per_unit=("length",), max_tolerance=True),
        ),
        CharacteristicKind(
            "roundness",
            **_FORM,
            step_entities=("ROUNDNESS_TOLERANCE",),
            xcaf_type="CircularityOrRoundness",
            writer_name="circularity",
            measure=f"{_M}.geometric:measure_roundness",
            qif_type="Circularity",
            qif=QifRules(per_unit=("length",)),
        ),
        CharacteristicKind(
            "cylindricity",
            **_FORM,
            step_entities=("CYLINDRICITY_TOLERANCE",),
            xcaf_type="Cylindricity",
            measure=f"{_M}.geometric:measure_cylindricity",
            qif_type="Cylindricity",
            qif=QifRules(per_unit=("length", "area")),
        ),
        CharacteristicKind(
            "position",
            family="location",
            step_entities=("POSITION_TOLERANCE",),
            xcaf_type="Position",
            datums="optional",
            measure=f"{_M}.location:measure_position",
            measure_pattern=f"{_M}.location:measure_position_pattern",
            diametral=True,
            # a projected zone: over its height beyond the feature's open end
            modifiers=(*MATERIAL_REQUIREMENTS, "projected", SEPARATE),
            qif_type="Position",
            qif=QifRules(
                datum_frame=True,
                material_condition=True,
                zone_shape="non-diametrical",
                spherical_zone=True,
                bonus=True,
                max_tolerance=True,
                projected=True,
            ),
        ),
        *(
            CharacteristicKind(
                name,
                **_ORIENTATION,
                step_entities=(f"{name.upper()}_TOLERANCE",),
                xcaf_type=name.capitalize(),
                qif_type=name.capitalize(),
            )
            for name in ("perpendicularity", "parallelism", "angularity")
        ),
        CharacteristicKind(
            "circular_runout",
            **_RUNOUT,
            step_entities=("CIRCULAR_RUNOUT_TOLERANCE",),
            xcaf_type="CircularRunout",
            measure=f"{_M}.geometric:measure_circular_runout",
            qif_type="CircularRunout",
        ),
        CharacteristicKind(
            "total_runout",
            **_RUNOUT,
            step_entities=("TOTAL_RUNOUT_TOLERANCE",),
            xcaf_type="TotalRunout",
            measure=f"{_M}.geometric:measure_total_runout",
            qif_type="TotalRunout",
        ),
        *(
            CharacteristicKind(
                name,
                **_COAXIAL,
                step_entities=(f"{name.upper()}_TOLERANCE",),
                xcaf_type=name.capitalize(),
                qif_type=name.capitalize(),
            )
            for name in ("coaxiality", "concentricity")
        ),
        CharacteristicKind(
            "symmetry",
            family="location",
            step_entities=("SYMMETRY_TOLERANCE",),
            xcaf_type="Symmetry",
            qif_type="Symmetry",
            qif=QifRules(datum_frame=True),
        ),
    )
}


def unapplied_modifiers(kind: str, modifiers: list[str]) -> list[str]:
    """The drawing's ``modifiers`` (as the PMI reads them: ``"tangent_plane"``,
    ``"projected 10.795 mm"``) that a characteristic of ``kind`` does not apply, material
    requirements apart (:data:`MATERIAL_REQUIREMENTS`); a kind qifreport does not know
    applies none."""
    k = lookup_kind(kind)
    applied = APPLIED_EVERYWHERE + MATERIAL_REQUIREMENTS + (() if k is None else k.modifiers)
    return [m for m in modifiers if m.split()[0] not in applied]


def unapplied_material(kind: str, modifiers: list[str]) -> list[str]:
    """The material requirements among ``modifiers`` a characteristic of ``kind`` does not
    apply (read regardless of feature size: a stricter zone than the drawing's)."""
    k = lookup_kind(kind)
    own = () if k is None else k.modifiers
    return [m for m in modifiers if m in MATERIAL_REQUIREMENTS and m not in own]


def lookup_kind(name: str | None) -> CharacteristicKind | None:
    """The registered kind called ``name`` (None: no such kind, e.g. ``"dimension"``)."""
    return KINDS.get(name) if name is not None else None


def kind_label(name: str) -> str:
    """The report label of kind ``name`` (an unregistered name with spaces for ``_``)."""
    kind = lookup_kind(name)
    return kind.label if kind is not None else name.replace("_", " ")


def kind_for_step_entity(entity: str) -> CharacteristicKind | None:
    """The kind of a STEP geometric tolerance entity type (None: not a kind's)."""
    return next((k for k in KINDS.values() if entity in k.step_entities), None)


def kind_for_qif_type(qif_type: str) -> CharacteristicKind | None:
    """The kind whose QIF characteristic type is ``qif_type`` (None: none is)."""
    return next((k for k in KINDS.values() if k.qif_type == qif_type), None)


def register_kind(kind: CharacteristicKind) -> CharacteristicKind:
    """Add ``kind`` to :data:`KINDS`; ValueError when its name, a STEP entity or its QIF type
    is another kind's."""
    if kind.name in KINDS:
        raise ValueError(f"kind {kind.name!r} is already registered")
    for other in KINDS.values():
        if set(kind.step_entities) & set(other.step_entities):
            raise ValueError(f"{kind.name}: a STEP entity of {other.name} ({kind.step_entities})")
        if kind.qif_type is not None and kind.qif_type == other.qif_type:
            raise ValueError(f"{kind.name}: QIF type {kind.qif_type} is {other.name}'s")
    KINDS[kind.name] = kind
    return kind


def unregister_kind(name: str) -> None:
    """Remove kind ``name`` from :data:`KINDS` (KeyError when it is not registered)."""
    del KINDS[name]


@contextmanager
def registered(kind: CharacteristicKind) -> Iterator[CharacteristicKind]:
    """``kind`` registered for the ``with`` block only (a test's, a plug-in's)."""
    register_kind(kind)
    try:
        yield kind
    finally:
        unregister_kind(kind.name)
