"""Semantic PMI (product and manufacturing information) of a STEP AP242 part, as plain data.

These dataclasses are the interface between the STEP readers (:mod:`qifreport.step.semantic`) and
the rest of the tool. Lengths are in millimetres and angles in degrees whatever the file's units;
the text the file actually carries is kept alongside (``value_text``) for traceability. STEP entity
ids (``#n`` in the file) identify tolerances, dimensions, datums and faces.

A value that could not be established is ``None`` (never ``0`` as a placeholder) and each
object says why in its ``problems`` list. Everything converts to JSON through
:func:`dataclasses.asdict` (see :meth:`PMI.to_dict`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from .product import ProductIdentity

__all__ = [
    "ALL_TARGETS",
    "PMI",
    "Datum",
    "DatumRef",
    "Dimension",
    "GeometricTolerance",
    "MaterialNote",
    "RestraintNote",
]


#: :attr:`RestraintNote.targets` of a note that holds the part at all its datum targets
ALL_TARGETS = ("*",)


@dataclass
class DatumRef:
    """One entry of a datum reference frame.

    Attributes
    ----------
    label : str
        Datum label, ``'A'``, or a common datum ``'A-B'``.
    precedence : int
        1 primary, 2 secondary, 3 tertiary.
    modifiers : list of str
        Lower-case enumeration names, e.g. ``['maximum_material_requirement']``; a modifier
        with a value reads ``'<name> <value> mm'``.
    datum_step_ids : list of int
        The DATUM entities referenced (two or more for a common datum).
    """

    label: str
    precedence: int
    modifiers: list[str] = field(default_factory=list)
    datum_step_ids: list[int] = field(default_factory=list)


@dataclass
class DatumTarget:
    """A datum target (PLACED_DATUM_TARGET_FEATURE or DATUM_TARGET) and where it is.

    Attributes
    ----------
    name : e.g. ``'A1'`` (its datum's label and its number).
    step_id : the target entity.  kind : ``'point'``, ``'line'``, ``'rectangle'``,
        ``'circle'``, ``'area'`` (its description), or ``''``.
    position : [x, y, z] mm of its placement's origin (None: not placed in the file).
    direction : [x, y, z] unit, its placement's axis (None: not placed).
    face_step_ids : the faces it lies on (FEATURE_FOR_DATUM_TARGET_RELATIONSHIP).
    x_direction : [x, y, z] unit, its placement's reference direction: a rectangle's length
        lies along it, its width across (None: not given).
    length, width : mm, a rectangular target area's sides ('target length', 'target width');
        None for another kind.
    diameter : mm, a circular target area's ('target diameter'); None for another kind.
    """

    name: str
    step_id: int
    kind: str = ""
    position: list[float] | None = None
    direction: list[float] | None = None
    face_step_ids: list[int] = field(default_factory=list)
    x_direction: list[float] | None = None
    length: float | None = None
    width: float | None = None
    diameter: float | None = None


@dataclass
class Datum:
    """A datum (DATUM entity) and the faces of its datum feature(s) or target features.

    Attributes
    ----------
    step_id : int
        The DATUM entity.
    label : str
        Its identification, e.g. ``'A'``.
    face_step_ids : list of int
        Faces (ADVANCED_FACE or other FACE entities) of the datum feature(s), sorted unique.
    targets : list of str
        Datum target names like ``'A1'`` when the datum is defined by targets, else ``[]``.
    problems : list of str
        Anything that could not be resolved.
    feature_step_ids : list of int
        The DATUM_FEATURE / DATUM_TARGET entities related to the datum.
    face_notes : list of str
        How faces were derived when the file links the feature to non-face geometry (edges,
        datum target points and curves, axes, thread cylinders), e.g. ``'faces carrying the
        geometry: 3 CARTESIAN_POINT'``; ``[]`` when the file names the faces directly.
    target_details : list of DatumTarget
        The targets with their kind, placement and faces (same order as ``targets``).
    """

    step_id: int
    label: str
    face_step_ids: list[int] = field(default_factory=list)
    targets: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    feature_step_ids: list[int] = field(default_factory=list)
    face_notes: list[str] = field(default_factory=list)
    target_details: list[DatumTarget] = field(default_factory=list)


@dataclass
class GeometricTolerance:
    """A geometric tolerance (feature control frame).

    Attributes
    ----------
    step_id : int
        The GEOMETRIC_TOLERANCE entity (simple or complex instance).
    name : str
        Its name attribute.
    type : str
        Snake case characteristic: ``'surface_profile'``, ``'line_profile'``, ``'flatness'``,
        ``'straightness'``, ``'roundness'``, ``'cylindricity'``, ``'position'``,
        ``'perpendicularity'``, ``'parallelism'``, ``'angularity'``, ``'circular_runout'``,
        ``'total_runout'``, ``'coaxiality'``, ``'concentricity'``, ``'symmetry'``.
    value : float or None
        Zone magnitude in mm; ``None`` when it cannot be established.
    value_text : str
        What the file says, e.g. ``'0.03 INCH'`` or ``'0.75 MILLI METRE'``.
    zone_form : str or None
        From TOLERANCE_ZONE / TOLERANCE_ZONE_FORM, e.g. ``'cylindrical or circular'``.
    modifiers : list of str
        Lower-case enumeration names (GEOMETRIC_TOLERANCE_WITH_MODIFIERS, MODIFIED_GEOMETRIC_
        TOLERANCE, ``'all_around'`` for an ALL_AROUND_SHAPE_ASPECT ...).
    unequal_displacement : float or None
        mm, from UNEQUALLY_DISPOSED_GEOMETRIC_TOLERANCE (UZ); ``None`` otherwise.
    max_value : float or None
        mm, from GEOMETRIC_TOLERANCE_WITH_MAXIMUM_TOLERANCE.
    unit_basis : str or None
        GEOMETRIC_TOLERANCE_WITH_DEFINED_UNIT / _AREA_UNIT summary, e.g. ``'per 25 mm'``.
    datums : list of DatumRef
        Datum reference frame in precedence order; ``[]`` when none.
    face_step_ids : list of int
        Faces of the toleranced feature(s), sorted unique.
    problems : list of str
        Anything that could not be resolved, human readable.
    shape_aspect_step_id : int or None
        The toleranced_shape_aspect entity.
    composite_with : list of int
        Other tolerances joined to this one by GEOMETRIC_TOLERANCE_RELATIONSHIP (composite
        feature control frames), in file order.
    face_notes : list of str
        How faces were derived when the file links the feature to non-face geometry (edges,
        datum target points and curves, axes, thread cylinders), e.g. ``'faces carrying the
        geometry: 3 CARTESIAN_POINT'``; ``[]`` when the file names the faces directly.
    whole_part : bool
        The tolerance applies to the whole part ("all surfaces"): its toleranced shape aspect
        is the product shape itself, or a shape aspect with no face link. ``face_step_ids``
        are then every face of the part and ``face_notes`` say why.
    """

    step_id: int
    name: str
    type: str
    value: float | None
    value_text: str
    zone_form: str | None = None
    modifiers: list[str] = field(default_factory=list)
    unequal_displacement: float | None = None
    max_value: float | None = None
    unit_basis: str | None = None
    datums: list[DatumRef] = field(default_factory=list)
    face_step_ids: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    shape_aspect_step_id: int | None = None
    composite_with: list[int] = field(default_factory=list)
    face_notes: list[str] = field(default_factory=list)
    whole_part: bool = False


@dataclass
class Dimension:
    """A dimensional size or location with its value and tolerance.

    Attributes
    ----------
    step_id : int
        The DIMENSIONAL_SIZE / DIMENSIONAL_LOCATION (or angular, with-path ...) entity.
    name : str
        Its name attribute (``'diameter'``, ``'linear distance'`` ...).
    kind : str
        ``'size'`` or ``'location'``.
    type : str
        ``'diameter'``, ``'radius'``, ``'linear distance'``, ``'angle'``, ``'thickness'``,
        ``'curved distance'`` ...: the name when it is one of the AP242 names, else derived
        from the entity type.
    unit : str
        ``'mm'`` or ``'deg'``.
    nominal : float or None
        mm or degrees.
    lower, upper : float or None
        Signed deviations from nominal (e.g. ``-0.1``, ``0.2``), from PLUS_MINUS_TOLERANCE /
        TOLERANCE_VALUE.
    lower_limit, upper_limit : float or None
        When the file gives limits (``'lower limit'`` / ``'upper limit'`` items).
    fit : str or None
        LIMITS_AND_FITS text, e.g. ``'H7'``.
    qualifiers : list of str
        ``'basic'`` (dimensional note 'theoretical'), ``'reference'`` ('auxiliary'),
        ``'diameter'``, TYPE_QUALIFIER values ...
    face_step_ids : list of int
        Faces of the dimensioned feature(s) (both ends of a location), sorted unique.
    problems : list of str
        Anything that could not be resolved.
    warnings : list of str
        An exporter's quirk the reader put right, named so every output can say it (bounds
        given in reverse order: read as the interval they span).
    origin_face_step_ids, target_face_step_ids : list of int
        For a location: the faces of the relating (origin) and related (target) feature.
    value_text : str
        The nominal (or limits) as the file says it, e.g. ``'0.238 INCH'``.
    value_format : str or None
        VALUE_FORMAT_TYPE_QUALIFIER of the nominal, e.g. ``'NR2 1.3'``.
    face_notes : list of str
        How faces were derived when the file links the feature to non-face geometry (edges,
        datum target points and curves, axes, thread cylinders), e.g. ``'faces carrying the
        geometry: 3 CARTESIAN_POINT'``; ``[]`` when the file names the faces directly.
    target_details : list of DatumTarget
        The targets with their kind, placement and faces (same order as ``targets``).
    """

    step_id: int
    name: str
    kind: str
    type: str
    unit: str
    nominal: float | None = None
    lower: float | None = None
    upper: float | None = None
    lower_limit: float | None = None
    upper_limit: float | None = None
    fit: str | None = None
    qualifiers: list[str] = field(default_factory=list)
    face_step_ids: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    origin_face_step_ids: list[int] = field(default_factory=list)
    target_face_step_ids: list[int] = field(default_factory=list)
    value_text: str = ""
    value_format: str | None = None
    face_notes: list[str] = field(default_factory=list)


@dataclass
class RestraintNote:
    """A drawing note that states a restraint (:func:`qifreport.step.notes.restraint_note`).

    Attributes
    ----------
    text : the note around the statement, whitespace collapsed (at most 400 characters).
    phrase : what was found, upper case: ``'ISO 10579-NR'``, ``'RESTRAINED'`` ...
    step_id : the entity carrying the text (a ``REPRESENTATION`` of its lines, a
        ``DESCRIPTIVE_REPRESENTATION_ITEM`` or a ``TEXT_LITERAL``).
    force_limit : the restraint force the note allows per contact, N ("RESTRAINT FORCE AT
        MOST 20 N PER TARGET"; :func:`qifreport.step.notes.restraint_force`), and
        ``force_text`` the words it was read from; None / ``""``: the note states none.
    targets : the datum targets the note holds the part at, as it names them
        (:func:`qifreport.step.notes.restraint_targets`: ``('A1', ..., 'C2')``;
        :data:`ALL_TARGETS` all of them; ``()`` none named).
    """

    text: str
    phrase: str
    step_id: int
    force_limit: float | None = None
    force_text: str = ""
    targets: tuple[str, ...] = ()


@dataclass
class MaterialNote:
    """The part's material as the drawing states it
    (:func:`qifreport.step.material.material_note`).

    Attributes
    ----------
    text : the designation, whitespace collapsed (``'ABS, UNFILLED'``), as written.
    source : ``'material designation'`` (an AP242 ``MATERIAL_DESIGNATION``) or
        ``'drawing note'`` (a note's ``MATERIAL:`` line).
    step_id : the entity carrying it.
    """

    text: str
    source: str
    step_id: int


@dataclass
class PMI:
    """All semantic PMI of one STEP file.

    Attributes
    ----------
    schema : str
        FILE_SCHEMA text.
    length_unit : str
        The context length unit of the shape: ``'mm'``, ``'inch'``, ``'m'`` ...
    length_scale : float
        Millimetres per file length unit (25.4 for inch).
    tolerances : list of GeometricTolerance
    dimensions : list of Dimension
    datums : list of Datum
    problems : list of str
        File-level problems (unreadable records, missing units ...).
    restraint : the first drawing note that states a restraint (ISO 10579-NR, "part
        restrained"), None when the file carries none.
    material : the part's material as the file states it, None when it states none.
    product : the part's number, name and revision as the file states them
        (:func:`qifreport.step.product.product_identity`), None without a product.
    """

    schema: str
    length_unit: str
    length_scale: float
    tolerances: list[GeometricTolerance] = field(default_factory=list)
    dimensions: list[Dimension] = field(default_factory=list)
    datums: list[Datum] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    restraint: RestraintNote | None = None
    material: MaterialNote | None = None
    product: ProductIdentity | None = None

    def reader_warnings(self) -> list[str]:
        """The exporter quirks the reader put right, one line each naming the item
        (:attr:`Dimension.warnings`)."""
        return [
            f"dimension {d.name or '#' + str(d.step_id)} (#{d.step_id}): {w}"
            for d in self.dimensions
            for w in d.warnings
        ]

    def held_targets(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The datum targets the restraint note holds the part at
        (:attr:`RestraintNote.targets`) that the file places, and those it names but does
        not place; ``((), ())`` without such a note. A note that holds the part "at the datum
        targets" without naming them names every target the file has."""
        note = self.restraint
        if note is None or not note.targets:
            return (), ()
        placed = [
            t.name
            for d in self.datums
            for t in d.target_details
            if t.position is not None and t.direction is not None
        ]
        if note.targets == ALL_TARGETS:
            named = [t for d in self.datums for t in d.targets]
            return tuple(placed), tuple(n for n in named if n not in placed)
        held = tuple(n for n in note.targets if n in placed)
        return held, tuple(n for n in note.targets if n not in placed)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dictionary (:func:`dataclasses.asdict`)."""
        return asdict(self)
