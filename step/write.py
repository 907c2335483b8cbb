"""Write a part as STEP AP242 with semantic PMI (datums and geometric tolerances) via OCP XDE.

The shape, its datums and its geometric tolerances are put in an XDE document
(``XCAFDoc_ShapeTool`` / ``XCAFDoc_DimTolTool``) and written with ``STEPCAFControl_Writer``
in AP242 (``AP242_MANAGED_MODEL_BASED_3D_ENGINEERING_MIM_LF``), lengths in millimetres.
Datums and tolerances are linked to faces of the part, named by their index in
``TopExp.MapShapes(shape, TopAbs_FACE)`` (0-based). In the file each link is a
``SHAPE_ASPECT`` (``DATUM_FEATURE`` for a datum) with a ``GEOMETRIC_ITEM_SPECIFIC_USAGE``
naming the ``ADVANCED_FACE``; a tolerance with datums carries a ``DATUM_SYSTEM`` whose
``DATUM_REFERENCE_COMPARTMENT`` list is in precedence order (primary first).

A **whole-part** surface profile (``faces=[]``: "all surfaces", a general profile tolerance)
is written the way real CAD exports encode it (NIST FTC 07 #16292, FTC 10 #18552): the
tolerance's ``toleranced_shape_aspect`` is the part's ``PRODUCT_DEFINITION_SHAPE`` itself, so
no shape aspect links it to a face. XDE writes no tolerance without a face, so the tolerance is
transferred on a placeholder face and re-targeted in the STEP model before it is serialised
(the placeholder's ``SHAPE_ASPECT`` and usage stay in the file, referenced by nothing).

OCCT 7.9 unit defect and its correction
---------------------------------------
``STEPCAFControl_Writer::writeDGTsAP242`` passes a representation context to
``writeGeomTolerance`` (and ``WriteDatumSystem``, for datum modifier values, which this
module never writes) that is only assigned while *dimensions* are written. With geometric
tolerances and no dimension it stays null, and ``GetUnit`` then falls back to a
default-constructed ``StepBasic_SiUnitAndLengthUnit``, which is written as
``SI_UNIT($,.METRE.)``. The magnitude itself is written unscaled, in the document unit
(mm). A 0.5 mm profile tolerance therefore came out as::

    #362 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(0.5),#363);
    #363 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT($,.METRE.) );

that is 0.5 m, which ``STEPCAFControl_Reader`` correctly converts to 500 mm. The reader is
right; the file was wrong. No setting helps (``write.step.unit``, the document length unit
and ``xstep.cascade.unit`` only govern the context unit, which this code path never looks
up; the same code is in OCCT master). :func:`write_step_with_pmi` therefore corrects the
STEP model in memory, after the transfer and before it is serialised: the unit entity of
each tolerance magnitude (and of a maximum-tolerance bound, if any) is given the prefix and
name of the length unit of the geometry's representation context, which the function sets
to millimetre. Only those unit entities are touched; each becomes
``SI_UNIT(.MILLI.,.METRE.)``, so no dangling unit entity is left. If OCCT is fixed and
already references the context unit, the correction changes nothing. The model is then
checked (each magnitude equals the requested value, in mm) before the file is written.

``Interface_Static`` parameters are process-global: they are set for the write and
restored afterwards, and the function is not thread-safe.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import OCP.XCAFDimTolObjects as xcaf_dimtol
from OCP.APIHeaderSection import APIHeaderSection_MakeHeader
from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
from OCP.IFSelect import IFSelect_ReturnStatus
from OCP.Interface import Interface_Static
from OCP.StepBasic import (
    StepBasic_SiPrefix,
    StepBasic_SiUnitAndLengthUnit,
    StepBasic_SiUnitName,
    StepBasic_Unit,
)
from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Writer
from OCP.STEPControl import STEPControl_AsIs
from OCP.StepDimTol import (
    StepDimTol_GeometricTolerance,
    StepDimTol_GeometricToleranceTarget,
    StepDimTol_GeoTolAndGeoTolWthDatRefAndGeoTolWthMaxTol,
    StepDimTol_GeoTolAndGeoTolWthMaxTol,
)
from OCP.StepGeom import (
    StepGeom_GeometricRepresentationContextAndGlobalUnitAssignedContext,
    StepGeom_GeomRepContextAndGlobUnitAssCtxAndGlobUncertaintyAssCtx,
)
from OCP.StepRepr import (
    StepRepr_CharacterizedDefinition,
    StepRepr_DescriptiveRepresentationItem,
    StepRepr_HArray1OfRepresentationItem,
    StepRepr_ProductDefinitionShape,
    StepRepr_PropertyDefinition,
    StepRepr_PropertyDefinitionRepresentation,
    StepRepr_Representation,
    StepRepr_RepresentedDefinition,
)
from OCP.StepShape import StepShape_ShapeDefinitionRepresentation
from OCP.TCollection import (
    TCollection_ExtendedString,
    TCollection_HAsciiString,
)
from OCP.TDataStd import TDataStd_Name
from OCP.TDF import TDF_Label, TDF_LabelSequence
from OCP.TDocStd import TDocStd_Document
from OCP.TopAbs import TopAbs_FACE
from OCP.TopExp import TopExp
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS_Shape
from OCP.TopTools import TopTools_IndexedMapOfShape
from OCP.XCAFApp import XCAFApp_Application
from OCP.XCAFDimTolObjects import (
    XCAFDimTolObjects_DatumTargetType,
    XCAFDimTolObjects_GeomToleranceType,
    XCAFDimTolObjects_GeomToleranceTypeValue_None,
)
from OCP.XCAFDoc import XCAFDoc_Datum, XCAFDoc_DocumentTool, XCAFDoc_GeomTolerance

from qifreport.atomic_io import atomic_write
from qifreport.kinds import KINDS

__all__ = [
    "DATUM_REQUIRED_TYPES",
    "FORM_TYPES",
    "TOLERANCE_TYPES",
    "WHOLE_PART_TYPES",
    "PMISpecDatum",
    "PMISpecTarget",
    "PMISpecTolerance",
    "write_step_solids",
    "write_step_with_pmi",
]

logger = logging.getLogger(__name__)

_T = XCAFDimTolObjects_GeomToleranceType
#: Tolerance type names accepted in :class:`PMISpecTolerance` and their XDE types (the
#: registered kinds' :attr:`~qifreport.kinds.CharacteristicKind.writer_name`).
TOLERANCE_TYPES: dict[str, XCAFDimTolObjects_GeomToleranceType] = {
    k.writer_name: getattr(_T, f"XCAFDimTolObjects_GeomToleranceType_{k.xcaf_type}")
    for k in sorted(KINDS.values(), key=lambda k: k.writer_name)
    if k.xcaf_type is not None
}
#: Form tolerances: never related to a datum.
FORM_TYPES = frozenset(k.writer_name for k in KINDS.values() if k.datums == "never")
#: Orientation, runout and the older location types: need at least one datum.
DATUM_REQUIRED_TYPES = frozenset(k.writer_name for k in KINDS.values() if k.datums == "required")

#: Tolerance types that may be given with ``faces=[]``: a whole-part tolerance.
WHOLE_PART_TYPES = frozenset(k.writer_name for k in KINDS.values() if k.whole_part)

#: AP242 schema selector of ``write.step.schema`` ("AP242DIS" is OCCT's name; value 5).
_AP242_SCHEMA = ("AP242DIS", 5)


@dataclass
class PMISpecTarget:
    """A datum target point (ASME Y14.5 / ISO 5459): where a fixture touches the part.

    Attributes
    ----------
    number : int
        Its number on the datum: target ``A1`` is number 1 of datum ``A`` (>= 1).
    position : (x, y, z) mm, on the part's surface.
    direction : (x, y, z), the target's axis: the direction the contact holds (the outward
        normal of the face it touches, for a support on a face).
    face : int
        The face it lies on (0-based index into ``TopExp.MapShapes(shape, TopAbs_FACE)``).

    Written as a ``PLACED_DATUM_TARGET_FEATURE`` ('point') whose
    ``SHAPE_REPRESENTATION_WITH_PARAMETERS`` holds its placement (an ``AXIS2_PLACEMENT_3D``
    named 'orientation'), linked to its face and its datum.
    """

    number: int
    position: tuple[float, float, float]
    direction: tuple[float, float, float]
    face: int


@dataclass
class PMISpecDatum:
    """A datum feature.

    Attributes
    ----------
    label : str
        Datum letter, e.g. ``"A"``.
    faces : list of int
        Faces of the datum feature: 0-based indices into
        ``TopExp.MapShapes(shape, TopAbs_FACE)``. Several faces make one (composite)
        datum feature, e.g. two coplanar flange faces.
    targets : list of PMISpecTarget
        Its datum target points (a restrained inspection's clamps), if any.
    """

    label: str
    faces: list[int]
    targets: list[PMISpecTarget] = field(default_factory=list)


#: the XDE name of a tolerance modifier, before its title-cased AP242 name
_MODIFIER = "XCAFDimTolObjects_GeomToleranceModif_"


@dataclass
class PMISpecTolerance:
    """A geometric tolerance.

    Attributes
    ----------
    type : str
        One of :data:`TOLERANCE_TYPES`, e.g. ``"surface_profile"``, ``"flatness"``,
        ``"position"``.
    value : float
        Tolerance zone magnitude, mm (> 0).
    faces : list of int
        Toleranced faces (0-based indices into ``TopExp.MapShapes(shape, TopAbs_FACE)``).
        ``[]`` for a whole-part surface profile (every face; see the module docstring).
    datums : list of str
        Datum labels in precedence order (primary first), e.g. ``["A", "B", "C"]``.
    name : str
        Identifier, written as the name of the ``GEOMETRIC_TOLERANCE`` and of its
        ``SHAPE_ASPECT``; empty gives ``"<type>_<n>"`` (n = 1-based position in the list).
    modifiers : list of str
        AP242 tolerance modifiers, lower case (``"separate_requirement"``,
        ``"free_state"``, ``"tangent_plane"`` ...), written as the tolerance's
        ``GEOMETRIC_TOLERANCE_WITH_MODIFIERS``.
    """

    type: str
    value: float
    faces: list[int]
    datums: list[str] = field(default_factory=list)
    name: str = ""
    modifiers: list[str] = field(default_factory=list)


def write_step_with_pmi(
    shape: TopoDS_Shape,
    path: str | os.PathLike[str],
    tolerances: Sequence[PMISpecTolerance],
    datums: Sequence[PMISpecDatum],
    part_name: str = "part",
    *,
    timestamp: str | None = None,
    notes: Sequence[str] = (),
) -> None:
    """Write ``shape`` as STEP AP242 (mm) with semantic datums and geometric tolerances.

    Parameters
    ----------
    shape : TopoDS_Shape
        The part (a solid, or a compound of solids), in mm. A non-identity location is
        baked into the geometry (face indices are unaffected).
    path : path-like
        Output file. Written atomically: a temporary file in the same directory, renamed
        over ``path`` on success; nothing is left behind on failure.
    tolerances : sequence of PMISpecTolerance
        Geometric tolerances. Datum references must name datums in ``datums``.
    datums : sequence of PMISpecDatum
        Datum features, with unique labels.
    part_name : str
        Product name written in the file.
    timestamp : str, optional
        ``FILE_NAME`` time stamp (ISO 8601, e.g. ``"2025-01-01T00:00:00"``); default the
        current time. Fix it for byte-reproducible output.
    notes : sequence of str
        Drawing notes (e.g. an ISO 10579-NR restraint note), each written as AP242
        "semantic text": a ``PROPERTY_DEFINITION('semantic text', '', <the part's
        PRODUCT_DEFINITION_SHAPE>)`` whose ``REPRESENTATION`` holds one
        ``DESCRIPTIVE_REPRESENTATION_ITEM('note', <line>)`` per line of the note, as CAD
        systems export notes (NIST FTC 08 #12879).

    Raises
    ------
    ValueError
        Inconsistent specification (unknown type, bad face index, undefined or duplicate
        datum, datum on a form tolerance, non-positive value, duplicate name).
    RuntimeError
        OCCT failed to transfer or write, or the written model does not state each
        tolerance magnitude in millimetres as requested.

    Notes
    -----
    A tolerance's magnitude is stated in the file as a ``LENGTH_MEASURE_WITH_UNIT`` whose
    unit is ``SI_UNIT(.MILLI.,.METRE.)``, exactly the requested value; see the module
    docstring for the OCCT 7.9 writer defect this corrects.
    """
    path = Path(path)
    shape, faces = _located_free(shape)
    names = _validate(tolerances, datums, len(faces))

    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)  # a transient document: never opened in the session, not closed
    _fill_document(doc, shape, faces, tolerances, names, datums, part_name)
    _write_atomic(doc, path, tolerances, names, timestamp, notes)
    logger.info(
        "wrote %s: %d faces, %d datums, %d tolerances",
        path,
        len(faces),
        len(datums),
        len(tolerances),
    )


# --------------------------------------------------------------------------- internals


def _face_list(shape: TopoDS_Shape) -> list[TopoDS_Shape]:
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    return [fmap.FindKey(i) for i in range(1, fmap.Extent() + 1)]


def _located_free(shape: TopoDS_Shape) -> tuple[TopoDS_Shape, list[TopoDS_Shape]]:
    """The shape without a top-level location, and its faces in the caller's index order.

    XDE stores a located top-level shape as a reference to an unlocated prototype (an
    assembly instance), on which sub-shape labels cannot be added; the location is baked
    into the geometry instead, and each face is followed through the transformation.
    """
    if shape.IsNull():
        raise ValueError("shape is null")
    if shape.Location().IsIdentity():
        return shape, _face_list(shape)
    base = shape.Located(TopLoc_Location())
    xform = BRepBuilderAPI_Transform(base, shape.Location().Transformation(), True)
    moved = xform.Shape()
    faces = [xform.ModifiedShape(f) for f in _face_list(base)]
    if not moved.Location().IsIdentity() or len(faces) != len(_face_list(moved)):
        raise RuntimeError("could not bake the shape's location into its geometry")
    return moved, faces


def _validate(
    tolerances: Sequence[PMISpecTolerance], datums: Sequence[PMISpecDatum], n_faces: int
) -> list[str]:
    """Check the specification; return the tolerance names (defaults filled in)."""

    def check_faces(what: str, faces: Sequence[int]) -> None:
        if len(faces) == 0:
            raise ValueError(f"{what}: no faces")
        if len(set(faces)) != len(faces):
            raise ValueError(f"{what}: repeated face index")
        for k in faces:
            if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < n_faces:
                raise ValueError(f"{what}: face index {k!r} not in [0, {n_faces})")

    labels = [d.label for d in datums]
    for d in datums:
        if not d.label or not d.label.isascii() or not d.label.isprintable():
            raise ValueError(f"datum label {d.label!r}: must be non-empty printable ASCII")
        check_faces(f"datum {d.label}", d.faces)
        numbers = [tg.number for tg in d.targets]
        if len(set(numbers)) != len(numbers) or any(n < 1 for n in numbers):
            raise ValueError(f"datum {d.label}: target numbers must be unique and >= 1")
        for tg in d.targets:
            check_faces(f"datum target {d.label}{tg.number}", [tg.face])
            if not all(math.isfinite(x) for x in (*tg.position, *tg.direction)):
                raise ValueError(f"datum target {d.label}{tg.number}: non-finite placement")
            if math.hypot(*tg.direction) < 1e-9:
                raise ValueError(f"datum target {d.label}{tg.number}: zero direction")
    if len(set(labels)) != len(labels):
        raise ValueError(f"duplicate datum labels in {labels}")

    names = []
    for i, t in enumerate(tolerances):
        name = t.name or f"{t.type}_{i + 1}"
        what = f"tolerance {name!r}"
        if t.type not in TOLERANCE_TYPES:
            raise ValueError(f"{what}: unknown type {t.type!r}; one of {sorted(TOLERANCE_TYPES)}")
        if not (isinstance(t.value, int | float) and math.isfinite(t.value) and t.value > 0):
            raise ValueError(f"{what}: value must be a finite number > 0 mm, got {t.value!r}")
        if t.faces or t.type not in WHOLE_PART_TYPES:
            check_faces(what, t.faces)
        if len(set(t.datums)) != len(t.datums):
            raise ValueError(f"{what}: repeated datum in {t.datums}")
        for m in t.modifiers:
            if not hasattr(xcaf_dimtol, _MODIFIER + m.title()):
                raise ValueError(f"{what}: unknown modifier {m!r}")
        for lab in t.datums:
            if lab not in labels:
                raise ValueError(f"{what}: datum {lab!r} is not defined")
        if t.type in FORM_TYPES and t.datums:
            raise ValueError(f"{what}: a {t.type} tolerance takes no datum")
        if t.type in DATUM_REQUIRED_TYPES and not t.datums:
            raise ValueError(f"{what}: a {t.type} tolerance needs a datum")
        if not name.isascii() or not name.isprintable():
            raise ValueError(f"{what}: name must be printable ASCII")
        names.append(name)
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate tolerance names in {names}")
    return names


def _fill_document(
    doc: TDocStd_Document,
    shape: TopoDS_Shape,
    faces: list[TopoDS_Shape],
    tolerances: Sequence[PMISpecTolerance],
    names: list[str],
    datums: Sequence[PMISpecDatum],
    part_name: str,
) -> None:
    """Put the shape, its datums and its tolerances into the XDE document ``doc``."""
    XCAFDoc_DocumentTool.SetLengthUnit_s(doc, 0.001)  # document unit: mm (value in metres)
    xde = _XdeGdt(doc, shape, faces, part_name)
    # One definition label per datum, in the given order: the writer writes each datum
    # (DATUM_FEATURE + DATUM) once, from the first label carrying its name.
    by_label = {d.label: d for d in datums}
    for d in datums:
        xde.add_datum(d, 0)
    for d in datums:
        for tg in d.targets:
            xde.add_target(d.label, tg)
    for t, name in zip(tolerances, names, strict=True):
        xde.add_tolerance(t, name, by_label)


class _XdeGdt:
    """The part of an XDE document and its GD&T labels, added one by one.

    Parameters
    ----------
    doc : the document; the shape is added to it as a single part named ``part_name``.
    faces : the shape's faces in face-id order; a face gets its sub-shape label the first
        time an item refers to it.
    """

    def __init__(
        self, doc: TDocStd_Document, shape: TopoDS_Shape, faces: list[TopoDS_Shape], part_name: str
    ) -> None:
        self.shape_tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
        self.dimtol = XCAFDoc_DocumentTool.DimTolTool_s(doc.Main())
        self.part = self.shape_tool.AddShape(shape, False)  # a single part, never an assembly
        TDataStd_Name.Set_s(self.part, TCollection_ExtendedString(part_name))
        self.faces = faces
        self.face_labels: dict[int, TDF_Label] = {}

    def labels_of(self, indices: Sequence[int]) -> TDF_LabelSequence:
        """The sub-shape labels of faces ``indices``."""
        seq = TDF_LabelSequence()
        for k in indices:
            if k not in self.face_labels:
                lab = self.shape_tool.AddSubShape(self.part, self.faces[k])
                if lab.IsNull():
                    raise RuntimeError(f"face {k} is not a sub-shape of the part")
                self.face_labels[k] = lab
            seq.Append(self.face_labels[k])
        return seq

    def add_datum(self, spec: PMISpecDatum, position: int) -> TDF_Label:
        """A datum label on the datum's faces, at ``position`` (a tolerance's 1-based
        precedence, 0 for the datum's definition)."""
        lab = self.dimtol.AddDatum()
        attr = XCAFDoc_Datum.Set_s(lab)
        obj = attr.GetObject()
        obj.SetName(TCollection_HAsciiString(spec.label))
        obj.SetPosition(position)
        attr.SetObject(obj)
        TDataStd_Name.Set_s(lab, TCollection_ExtendedString(f"Datum {spec.label}"))
        self.dimtol.SetDatum(self.labels_of(spec.faces), lab)
        return lab

    def add_target(self, label: str, tg: PMISpecTarget) -> None:
        """A point datum target of datum ``label`` on its face."""
        lab = self.dimtol.AddDatum()
        attr = XCAFDoc_Datum.Set_s(lab)
        obj = attr.GetObject()
        obj.SetName(TCollection_HAsciiString(label))
        obj.IsDatumTarget(True)
        obj.SetDatumTargetType(
            XCAFDimTolObjects_DatumTargetType.XCAFDimTolObjects_DatumTargetType_Point
        )
        obj.SetDatumTargetAxis(
            gp_Ax2(gp_Pnt(*map(float, tg.position)), gp_Dir(*map(float, tg.direction)))
        )
        obj.SetDatumTargetNumber(int(tg.number))
        obj.SetPosition(0)
        attr.SetObject(obj)
        TDataStd_Name.Set_s(lab, TCollection_ExtendedString(f"Datum target {label}{tg.number}"))
        self.dimtol.SetDatum(self.labels_of([tg.face]), lab)

    def add_tolerance(
        self, t: PMISpecTolerance, name: str, by_label: dict[str, PMISpecDatum]
    ) -> None:
        """A geometric tolerance on its faces, with its own datum references."""
        lab = self.dimtol.AddGeomTolerance()
        attr = XCAFDoc_GeomTolerance.Set_s(lab)
        obj = attr.GetObject()
        obj.SetType(TOLERANCE_TYPES[t.type])
        obj.SetValue(float(t.value))
        obj.SetTypeOfValue(XCAFDimTolObjects_GeomToleranceTypeValue_None)
        for m in t.modifiers:
            obj.AddModifier(getattr(xcaf_dimtol, _MODIFIER + m.title()))
        attr.SetObject(obj)
        # The writer names the tolerance's SHAPE_ASPECT with the words after the first.
        TDataStd_Name.Set_s(lab, TCollection_ExtendedString(f"{t.type} {name}"))
        # a whole-part tolerance goes on a placeholder face, re-targeted after the transfer
        self.dimtol.SetGeomTolerance(self.labels_of(t.faces or [0]), lab)
        # Precedence is the datum object's position, so a tolerance gets its own datum
        # references (same name and faces, position = 1-based precedence).
        for position, dlabel in enumerate(t.datums, start=1):
            self.dimtol.SetDatumToGeomTol(self.add_datum(by_label[dlabel], position), lab)


@contextlib.contextmanager
def _ap242_in_mm():
    """Select the AP242 schema and mm for the writes inside; the process-global
    ``Interface_Static`` parameters are restored after them."""
    # Declares the write.step.* parameters. Without it the settings below are refused, the
    # writer falls back to AP214, and its AP214 GD&T path crashed (segfault) in tests.
    STEPCAFControl_Controller.Init_s()
    saved = {
        "write.step.schema": Interface_Static.IVal_s("write.step.schema"),
        "write.step.unit": Interface_Static.CVal_s("write.step.unit"),
    }
    try:
        if (
            not (
                Interface_Static.SetCVal_s("write.step.schema", _AP242_SCHEMA[0])
                and Interface_Static.SetCVal_s("write.step.unit", "MM")
            )
            or Interface_Static.IVal_s("write.step.schema") != _AP242_SCHEMA[1]
        ):
            raise RuntimeError("could not select STEP AP242 in mm (Interface_Static)")
        yield
    finally:
        Interface_Static.SetIVal_s("write.step.schema", saved["write.step.schema"])
        Interface_Static.SetCVal_s("write.step.unit", saved["write.step.unit"])


def _write_file(writer: STEPCAFControl_Writer, path: Path) -> None:
    """Write the transferred model of ``writer`` to ``path`` atomically."""

    def _write(tmp: Path) -> None:
        status = writer.Write(str(tmp))
        if status != IFSelect_ReturnStatus.IFSelect_RetDone:
            raise RuntimeError(f"STEPCAFControl_Writer: write failed ({status})")

    atomic_write(path, _write)


def _write_atomic(
    doc: TDocStd_Document,
    path: Path,
    tolerances: Sequence[PMISpecTolerance],
    names: list[str],
    timestamp: str | None,
    notes: Sequence[str] = (),
) -> None:
    """Transfer ``doc`` to an AP242 model, correct and check it, add the ``notes``
    (:func:`_add_notes`), write it atomically."""
    with _ap242_in_mm():
        writer = STEPCAFControl_Writer()
        writer.SetNameMode(True)
        writer.SetDimTolMode(True)
        writer.SetColorMode(False)
        writer.SetLayerMode(False)
        writer.SetPropsMode(False)
        if not writer.Transfer(doc, STEPControl_AsIs):
            raise RuntimeError("STEPCAFControl_Writer: transfer failed")
        model = writer.ChangeWriter().Model()
        _name_tolerances(model)
        whole = [n for t, n in zip(tolerances, names, strict=True) if not t.faces]
        _target_whole_part(model, whole)
        _correct_tolerance_units(model)
        _check_magnitudes(model, tolerances, names)
        _add_notes(model, notes)

        header = APIHeaderSection_MakeHeader(model)
        header.SetName(TCollection_HAsciiString(path.name))
        if timestamp is not None:
            header.SetTimeStamp(TCollection_HAsciiString(timestamp))

        _write_file(writer, path)


def _add_notes(model, notes: Sequence[str]) -> None:
    """Add each note to the STEP ``model`` as AP242 semantic text on the part's shape
    (:func:`write_step_with_pmi`), its lines as descriptive items in the shape
    representation's context."""
    if not notes:
        return
    shape_rep = next(
        (
            model.Value(i)
            for i in range(1, model.NbEntities() + 1)
            if isinstance(model.Value(i), StepShape_ShapeDefinitionRepresentation)
            and isinstance(model.Value(i).Definition().Value(), StepRepr_ProductDefinitionShape)
        ),
        None,
    )
    if shape_rep is None:
        raise RuntimeError("STEP model: no shape representation of the part to attach notes to")
    pds = shape_rep.Definition().Value()
    context = shape_rep.UsedRepresentation().ContextOfItems()
    for note in notes:
        lines = note.splitlines() or [""]
        items = StepRepr_HArray1OfRepresentationItem(1, len(lines))
        for k, line in enumerate(lines, start=1):
            item = StepRepr_DescriptiveRepresentationItem()
            item.Init(TCollection_HAsciiString("note"), TCollection_HAsciiString(line))
            items.SetValue(k, item)
        rep = StepRepr_Representation()
        rep.Init(TCollection_HAsciiString(""), items, context)
        owner = StepRepr_CharacterizedDefinition()
        owner.SetValue(pds)
        prop = StepRepr_PropertyDefinition()
        prop.Init(
            TCollection_HAsciiString("semantic text"), True, TCollection_HAsciiString(""), owner
        )
        used = StepRepr_RepresentedDefinition()
        used.SetValue(prop)
        link = StepRepr_PropertyDefinitionRepresentation()
        link.Init(used, rep)
        model.AddWithRefs(link)


def _context_length_unit(model) -> StepBasic_SiUnitAndLengthUnit:
    """The SI length unit of the model's geometric context(s); all must agree."""
    contexts = (
        StepGeom_GeomRepContextAndGlobUnitAssCtxAndGlobUncertaintyAssCtx,
        StepGeom_GeometricRepresentationContextAndGlobalUnitAssignedContext,
    )
    found = []
    for i in range(1, model.NbEntities() + 1):
        ent = model.Value(i)
        if isinstance(ent, contexts):
            units = ent.Units()
            for k in range(units.Lower(), units.Upper() + 1):
                unit = units.Value(k)
                if isinstance(unit, StepBasic_SiUnitAndLengthUnit):
                    found.append(unit)
    if not found:
        raise RuntimeError("STEP model: no SI length unit in the geometric context")
    kinds = {(u.HasPrefix(), u.Prefix() if u.HasPrefix() else None, u.Name()) for u in found}
    if len(kinds) != 1:
        raise RuntimeError(f"STEP model: inconsistent context length units {kinds}")
    unit = found[0]
    if not (
        unit.HasPrefix()
        and unit.Prefix() == StepBasic_SiPrefix.StepBasic_spMilli
        and unit.Name() == StepBasic_SiUnitName.StepBasic_sunMetre
    ):
        raise RuntimeError("STEP model: the context length unit is not the millimetre")
    return unit


def _measures_of(tol: StepDimTol_GeometricTolerance) -> list:
    """The length measures of a tolerance: its magnitude and, if any, its upper bound."""
    measures = [tol.Magnitude()]
    if isinstance(
        tol,
        StepDimTol_GeoTolAndGeoTolWthMaxTol | StepDimTol_GeoTolAndGeoTolWthDatRefAndGeoTolWthMaxTol,
    ):
        measures.append(tol.GetMaxTolerance())
    return [m for m in measures if m is not None]


def _name_tolerances(model) -> None:
    """Name each ``GEOMETRIC_TOLERANCE`` after its ``SHAPE_ASPECT``.

    The writer names the shape aspect from the tolerance label's name (its words after
    the first) and leaves the tolerance's own name empty.
    """
    for i in range(1, model.NbEntities() + 1):
        tol = model.Value(i)
        if isinstance(tol, StepDimTol_GeometricTolerance):
            aspect = tol.TolerancedShapeAspect().ShapeAspect()
            if aspect is not None and aspect.Name() is not None:
                tol.SetName(TCollection_HAsciiString(aspect.Name().ToCString()))


def _target_whole_part(model, whole: list[str]) -> None:
    """Point each named whole-part tolerance at the part's ``PRODUCT_DEFINITION_SHAPE``."""
    if not whole:
        return
    done = set()
    for i in range(1, model.NbEntities() + 1):
        tol = model.Value(i)
        if not isinstance(tol, StepDimTol_GeometricTolerance) or tol.Name() is None:
            continue
        name = tol.Name().ToCString()
        aspect = tol.TolerancedShapeAspect().ShapeAspect()
        if name not in whole or aspect is None:
            continue
        target = StepDimTol_GeometricToleranceTarget()
        target.SetValue(aspect.OfShape())
        tol.SetTolerancedShapeAspect(target)
        done.add(name)
    if done != set(whole):
        raise RuntimeError(f"whole-part tolerances not re-targeted: {sorted(set(whole) - done)}")


def _correct_tolerance_units(model) -> int:
    """Give each tolerance measure the context's length unit (see the module docstring).

    Returns the number of unit entities changed.
    """
    ctx = _context_length_unit(model)
    changed = 0
    for i in range(1, model.NbEntities() + 1):
        tol = model.Value(i)
        if not isinstance(tol, StepDimTol_GeometricTolerance):
            continue
        for measure in _measures_of(tol):
            unit = measure.UnitComponent().NamedUnit()
            if isinstance(unit, StepBasic_SiUnitAndLengthUnit):
                if not (
                    unit.HasPrefix() and unit.Prefix() == ctx.Prefix() and unit.Name() == ctx.Name()
                ):
                    unit.SetPrefix(ctx.Prefix())  # also sets HasPrefix
                    unit.SetName(ctx.Name())
                    changed += 1
            else:  # conversion-based or missing: reference the context unit itself
                ref = StepBasic_Unit()
                ref.SetValue(ctx)
                measure.SetUnitComponent(ref)
                changed += 1
    if changed:
        logger.debug("corrected %d tolerance unit(s) to the context length unit", changed)
    return changed


def _check_magnitudes(model, tolerances: Sequence[PMISpecTolerance], names: list[str]) -> None:
    """Each named tolerance in the model states its requested value in mm, exactly."""
    ctx = _context_length_unit(model)
    stated: dict[str, float] = {}
    for i in range(1, model.NbEntities() + 1):
        tol = model.Value(i)
        if not isinstance(tol, StepDimTol_GeometricTolerance):
            continue
        measure = tol.Magnitude()
        unit = measure.UnitComponent().NamedUnit()
        if not (
            isinstance(unit, StepBasic_SiUnitAndLengthUnit)
            and unit.HasPrefix()
            and unit.Prefix() == ctx.Prefix()
            and unit.Name() == ctx.Name()
        ):
            raise RuntimeError(f"tolerance entity #{i}: magnitude not in millimetres")
        stated[tol.Name().ToCString()] = measure.ValueComponent()
    for t, name in zip(tolerances, names, strict=True):
        if stated.get(name) != float(t.value):
            raise RuntimeError(
                f"tolerance {name!r}: model states {stated.get(name)!r} mm, "
                f"requested {float(t.value)!r} mm"
            )
    if len(stated) != len(tolerances):
        raise RuntimeError(f"{len(stated)} tolerances in the model, {len(tolerances)} requested")


def write_step_solids(path: str | Path, solids: Sequence[tuple[str, TopoDS_Shape]]) -> Path:
    """Write named solids (no PMI) as one AP242 file in mm, each a free shape with its name,
    as a CAD export of several bodies does (for the multi-solid tests and samples).

    Parameters
    ----------
    path : the file to write (atomically).  solids : ``(name, shape)`` pairs, mm.
    """
    path = Path(path)
    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)
    XCAFDoc_DocumentTool.SetLengthUnit_s(doc, 0.001)
    st = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    for name, shape in solids:
        lab = st.AddShape(shape, False)
        TDataStd_Name.Set_s(lab, TCollection_ExtendedString(name))
    with _ap242_in_mm():
        writer = STEPCAFControl_Writer()
        writer.SetNameMode(True)
        if not writer.Transfer(doc, STEPControl_AsIs):
            raise RuntimeError("STEPCAFControl_Writer: transfer failed")
        _write_file(writer, path)
    return path
