"""Read a STEP part through OpenCASCADE's XDE: shape, faces, units, and the semantic PMI.

The B-rep comes from ``STEPCAFControl_Reader`` (GD&T and name modes on), which converts
every length to millimetres (OCCT's default ``xstep.cascade.unit``). The semantic PMI --
tolerances, dimensions, datums -- is read twice:

* by XDE, as OCCT understands it (``XCAFDoc_DimTolTool``), kept as :class:`XdeSummary` for
  cross-checking and for the ``pmi`` report;
* from the Part 21 text itself by :func:`qifreport.step.semantic.read_pmi_text`, which is the source
  of every *value* we use. XDE returns 0.0 for magnitudes stored as complex measure instances,
  mis-scales some units, and loses datum-to-face links that go through anything other than
  ``GEOMETRIC_ITEM_SPECIFIC_USAGE`` (``../shared/README.md``, "Known traps"; OCCT issues #1368,
  #384, #1138). The text reader resolves units recursively and follows every link.

The two are joined through the B-rep faces: the Part 21 reader names faces by their STEP
entity id (``#764 = ADVANCED_FACE(...)``); this module maps each face of the transferred shape
back to the entity it came from (``XSControl_TransferReader.EntityFromShapeResult``), and from
the entity's rank in the model to its ``#id`` (OCCT loads records in file order; the mapping
is checked on every face by entity type).

The Part 21 text is split once (:class:`qifreport.step.p21.P21Model`) and checked whole
before OCCT reads the file (:func:`qifreport.step.integrity.check_integrity`): a reference to a
record the file does not define, a file cut short (even if closed again with ``ENDSEC;
END-ISO-10303-21;``), duplicate ids or no solid are refused with one line naming the entity,
where OCCT would drop the missing records with a warning and the PMI that went with them. The
same split gives the PMI and the record order of the face mapping.

Face ids: the index of a face in ``TopExp.MapShapes(shape, TopAbs_FACE)`` (0-based). The
tessellation (:mod:`qifreport.step.tessellate`) tags every triangle with this id.
"""

from __future__ import annotations

import logging
import re
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qifreport.errors import InputError, require_file

from .integrity import SOLID_TYPES, TESSELLATED_TYPES, check_integrity
from .p21 import P21Error, P21Model

__all__ = [
    "STEP_SUFFIXES",
    "read_step",
    "StepPart",
    "XdeItem",
    "XdeSummary",
]

log = logging.getLogger(__name__)

STEP_SUFFIXES = (".step", ".stp", ".p21")
#: the first entity type name of a record body (of a complex instance: its first part)
_FIRST_TYPE = re.compile(r"\s*\(?\s*([A-Za-z_][A-Za-z0-9_]*)")


@dataclass
class XdeItem:
    """One GD&T item as OCCT's XDE reads it (for cross-checking only; values may be wrong).

    Attributes
    ----------
    kind : ``'tolerance'``, ``'dimension'`` or ``'datum'``.
    type : OCCT's type enumeration name without its prefix (e.g. ``'ProfileOfSurface'``).
    name : the semantic name, or the datum label.
    value : the value XDE returns (0.0 where it failed to read one).
    n_faces : number of shape labels XDE linked to the item.
    """

    kind: str
    type: str
    name: str
    value: float | None
    n_faces: int


@dataclass
class XdeSummary:
    """What XDE saw: items and counts (not used for any value)."""

    items: list[XdeItem] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        return dict(Counter(i.kind for i in self.items))


@dataclass
class StepPart:
    """A STEP part read for inspection.

    Attributes
    ----------
    path : the file read.
    name : product name from the file (or the file stem).
    shape : ``TopoDS_Shape`` in mm (compound of the free shapes).
    faces : list of ``TopoDS_Face``; the list index is the face id.
    face_step_ids : (n_faces,) int64, STEP entity id of each face, -1 if unknown.
    n_solids : number of solids in the shape.
    tessellated : whether the part is an AP242 tessellated shape (triangulated faces, no
        solid and no surface: :func:`read_step` lets it through for its PMI and its mesh).
    solid_names : the name of each solid (its XDE label's, '' when none), in the order of
        ``TopExp.MapShapes(shape, TopAbs_SOLID)`` (:mod:`qifreport.step.solids`).
    pmi : :class:`qifreport.step.pmi.PMI`, semantic PMI read from the text (values in mm / deg).
    xde : :class:`XdeSummary`, the same PMI as OCCT's XDE reads it.
    timings : seconds per stage.
    """

    path: Path
    name: str
    shape: object
    faces: list
    face_step_ids: np.ndarray
    n_solids: int
    pmi: object
    xde: XdeSummary
    timings: dict[str, float] = field(default_factory=dict)
    solid_names: list[str] = field(default_factory=list)
    tessellated: bool = False

    def face_index(self) -> dict[int, int]:
        """Map STEP entity id -> face id."""
        return {int(s): i for i, s in enumerate(self.face_step_ids) if s >= 0}

    def faces_of(self, step_ids) -> list[int]:
        """Face ids of the given STEP face entity ids (unknown ids are dropped)."""
        idx = self.face_index()
        return sorted({idx[int(s)] for s in step_ids if int(s) in idx})


def _enum_name(e) -> str:
    s = getattr(e, "name", str(e))
    return s.split("_", 1)[1] if "_" in s else s


def _record_ids(model: P21Model) -> list[tuple[int, str]]:
    """``(#id, first type name)`` of every DATA record, in file order (model ranks).

    The records of the Part 21 split, in file order (the integrity check has refused
    duplicate ids); the count is checked against OCCT's model.
    """
    out = []
    for eid, body in model.raw.items():
        m = _FIRST_TYPE.match(body)
        out.append((eid, m.group(1).upper() if m else ""))
    return out


def _xde_items(doc) -> XdeSummary:
    from OCP.TDF import TDF_LabelSequence
    from OCP.XCAFDoc import (
        XCAFDoc_Datum,
        XCAFDoc_Dimension,
        XCAFDoc_DimTolTool,
        XCAFDoc_DocumentTool,
        XCAFDoc_GeomTolerance,
    )

    dt = XCAFDoc_DocumentTool.DimTolTool_s(doc.Main())
    out = XdeSummary()

    def nref(label) -> int:
        f, s = TDF_LabelSequence(), TDF_LabelSequence()
        XCAFDoc_DimTolTool.GetRefShapeLabel_s(label, f, s)
        return f.Length() + s.Length()

    labs = TDF_LabelSequence()
    dt.GetGeomToleranceLabels(labs)
    for i in range(1, labs.Length() + 1):
        lab = labs.Value(i)
        obj = XCAFDoc_GeomTolerance.Set_s(lab).GetObject()
        nm = obj.GetSemanticName()
        out.items.append(
            XdeItem(
                "tolerance",
                _enum_name(obj.GetType()),
                nm.ToCString() if nm is not None else "",
                float(obj.GetValue()),
                nref(lab),
            )
        )
    labs = TDF_LabelSequence()
    dt.GetDimensionLabels(labs)
    for i in range(1, labs.Length() + 1):
        lab = labs.Value(i)
        obj = XCAFDoc_Dimension.Set_s(lab).GetObject()
        typ = _enum_name(obj.GetType())
        if typ.endswith("DimensionPresentation"):
            continue  # graphical-only dimension, no semantic content
        out.items.append(XdeItem("dimension", typ, "", float(obj.GetValue()), nref(lab)))
    labs = TDF_LabelSequence()
    dt.GetDatumLabels(labs)
    for i in range(1, labs.Length() + 1):
        lab = labs.Value(i)
        obj = XCAFDoc_Datum.Set_s(lab).GetObject()
        nm = obj.GetName()
        out.items.append(
            XdeItem("datum", "Datum", nm.ToCString() if nm is not None else "", None, nref(lab))
        )
    return out


class _OcctMessages:
    """Context: route OCCT's default messenger (which prints to stdout) to a temporary file.

    The CLI's stdout carries only its own report and an error is one line on stderr, so
    OCCT's diagnostics while a file is read are collected instead: :meth:`first` gives the
    first failure for the error message, and every line is logged at DEBUG level.
    """

    def __enter__(self) -> _OcctMessages:
        import os
        import tempfile

        from OCP.Message import Message, Message_Gravity, Message_PrinterOStream

        self.lines: list[str] = []
        self._messenger = Message.DefaultMessenger_s()
        self._saved = list(self._messenger.Printers())
        fd, self._file = tempfile.mkstemp(prefix="qifreport-occt-", suffix=".log")
        os.close(fd)
        self._printer = Message_PrinterOStream(self._file, False, Message_Gravity.Message_Fail)
        for pr in self._saved:
            self._messenger.RemovePrinter(pr)
        self._messenger.AddPrinter(self._printer)
        return self

    def __exit__(self, *exc) -> bool:
        import os

        self._messenger.RemovePrinter(self._printer)
        self._printer.Close()
        for pr in self._saved:
            self._messenger.AddPrinter(pr)
        try:
            text = Path(self._file).read_text(encoding="utf-8", errors="replace")
        finally:
            os.unlink(self._file)
        for ln in text.splitlines():
            ln = re.sub(r"\x1b\[[0-9;]*m", "", ln).strip(" *\t")
            ln = re.sub(r"^ERR\s+\w+\s*:\s*(Undefined Parsing:\s*)?", "", ln)
            if ln:
                self.lines.append(ln)
                log.debug("OCCT: %s", ln)
        return False

    def first(self) -> str:
        """The first collected message, cut to 200 characters ('' if none)."""
        return self.lines[0][:200] if self.lines else ""


def read_step(path: str | Path, *, pmi: bool = True) -> StepPart:
    """Read a STEP file: the B-rep (mm), its faces with their entity ids, and the PMI.

    Parameters
    ----------
    path : STEP AP203/AP214/AP242 file.
    pmi : also read the semantic PMI (text reader + XDE cross-check).

    Raises
    ------
    InputError
        Missing or unreadable file, not STEP, a damaged file (a reference to a record the
        file does not define, a file cut short even if closed again, duplicate ids), no solid
        (:mod:`qifreport.step.integrity`, checked on the text before OCCT reads it), or no
        solid or face in OCCT's result.
    """
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    path = Path(path)
    _check_header(path)
    timings: dict[str, float] = {}
    # the Part 21 text, split once: checked whole before OCCT's result is used, then the
    # source of the face ids and of the PMI
    t0 = time.perf_counter()
    try:
        p21 = P21Model.read(path)
    except P21Error:
        raise InputError(f"{path.name}: not a STEP Part 21 file (no DATA section)") from None
    timings["p21_read"] = time.perf_counter() - t0
    timings["integrity"] = check_integrity(p21, path.name)
    t0 = time.perf_counter()
    doc, reader, occt = _xde_transfer(path)
    timings["xde_read"] = time.perf_counter() - t0

    st = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    shape = _free_shape(st, path)
    faces, solids = _faces_and_solids(shape, path, p21, occt)
    solid_names = _solid_names(st, solids)

    t0 = time.perf_counter()
    face_ids = _face_step_ids(reader, p21, faces, path)
    timings["face_map"] = time.perf_counter() - t0
    n_unmapped = int(np.sum(face_ids < 0))
    if n_unmapped:
        log.info("%s: %d of %d faces without a STEP entity id", path.name, n_unmapped, len(faces))

    pmi_data = None
    xde = XdeSummary()
    if pmi:
        pmi_data, xde = _read_pmi(p21, doc, path, timings)
    return StepPart(
        path=path,
        name=path.stem,
        shape=shape,
        faces=faces,
        face_step_ids=face_ids,
        n_solids=len(solids),
        solid_names=solid_names,
        pmi=pmi_data,
        xde=xde,
        timings=timings,
        tessellated=not solids and _tessellated(p21),
    )


def _check_header(path: Path) -> None:
    """Refuse a missing file or one that does not start with the Part 21 header."""
    require_file(path, "STEP")
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head.lstrip().startswith(b"ISO-10303-21"):
        raise InputError(f"{path.name}: not a STEP file (no ISO-10303-21 header)")


def _xde_transfer(path: Path) -> tuple[object, object, _OcctMessages]:
    """OCCT's XDE read of the file (GD&T and name modes on): ``(document, reader, messages)``,
    the messages OCCT printed while reading collected (:class:`_OcctMessages`).

    Raises
    ------
    InputError
        OCCT could not parse the file, or transferred no shape.
    """
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPCAFControl import STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document

    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    reader = STEPCAFControl_Reader()
    reader.SetGDTMode(True)
    reader.SetNameMode(True)
    reader.SetColorMode(False)
    reader.SetLayerMode(False)
    with _OcctMessages() as occt:  # OCCT prints its diagnostics to stdout: collect them
        read_ok = reader.ReadFile(str(path)) == IFSelect_RetDone
        transferred = read_ok and reader.Transfer(doc)
    if not read_ok:
        why = f" ({occt.first()})" if occt.first() else ""
        raise InputError(f"{path.name}: the STEP reader could not parse the file{why}")
    if not transferred:
        raise InputError(
            f"{path.name}: the STEP file has no solid, shell or face to inspect "
            "(no transferable shape)"
        )
    return doc, reader, occt


def _free_shape(st, path: Path):
    """The document's free shapes: the one shape, or a compound of them all.

    Parameters
    ----------
    st : the document's ``XCAFDoc_ShapeTool``.
    """
    from OCP.BRep import BRep_Builder
    from OCP.TDF import TDF_LabelSequence
    from OCP.TopoDS import TopoDS_Compound

    labs = TDF_LabelSequence()
    st.GetFreeShapes(labs)
    shapes = [st.GetShape_s(labs.Value(i)) for i in range(1, labs.Length() + 1)]
    shapes = [s for s in shapes if not s.IsNull()]
    if not shapes:
        raise InputError(
            f"{path.name}: the STEP file has no solid, shell or face to inspect (no shape)"
        )
    if len(shapes) == 1:
        return shapes[0]
    shape = TopoDS_Compound()
    b = BRep_Builder()
    b.MakeCompound(shape)
    for s in shapes:
        b.Add(shape, s)
    return shape


def _faces_and_solids(shape, path: Path, p21: P21Model, occt: _OcctMessages):
    """The shape's faces and solids, in ``TopExp.MapShapes`` order (the face ids).

    Raises
    ------
    InputError
        No face, or no solid (naming the file's solid records and OCCT's first message).
    """
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
    from OCP.TopExp import TopExp
    from OCP.TopoDS import TopoDS
    from OCP.TopTools import TopTools_IndexedMapOfShape

    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    faces = [TopoDS.Face_s(fmap.FindKey(i)) for i in range(1, fmap.Size() + 1)]
    if not faces:
        raise InputError(
            f"{path.name}: the STEP file has no solid, shell or face to inspect (no surface)"
        )
    smap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_SOLID, smap)
    if smap.Size() == 0 and _tessellated(p21):
        return faces, []  # an AP242 tessellated part: its faces are triangles, no solid
    if smap.Size() == 0:
        n = sum(len(p21.by_type(t)) for t in SOLID_TYPES)
        raise InputError(
            f"{path.name}: no solid in OpenCASCADE's result ({len(faces)} faces): the "
            f"file's {n} solid records gave none ({occt.first() or 'no message'})"
        )
    return faces, [smap.FindKey(i) for i in range(1, smap.Size() + 1)]


def _tessellated(p21: P21Model) -> bool:
    """Whether the file's shape is an AP242 tessellated solid or shell."""
    return any(p21.by_type(t) for t in TESSELLATED_TYPES)


def _face_step_ids(reader, p21: P21Model, faces: list, path: Path) -> np.ndarray:
    """(n_faces,) int64 STEP entity id of each face, -1 where unknown: through the transfer
    process and the model's record order (best effort: a failure leaves the ids at -1)."""
    face_ids = np.full(len(faces), -1, dtype=np.int64)
    try:
        model = reader.Reader().StepModel()
        tr = reader.Reader().WS().TransferReader()
        records = _record_ids(p21)
        if len(records) != model.NbEntities():
            log.warning(
                "%s: %d records in the text, %d in OCCT's model; face ids not mapped",
                path.name,
                len(records),
                model.NbEntities(),
            )
        else:
            # keep every wrapper alive: OCP reuses the Python object of a live C++ handle,
            # so identity of the returned entity finds its rank
            ents = [model.Value(i) for i in range(1, model.NbEntities() + 1)]
            rank = {id(e): i for i, e in enumerate(ents)}
            bad = 0
            for k, f in enumerate(faces):
                e = tr.EntityFromShapeResult(f, 1)
                if e is None:
                    e = tr.EntityFromShapeResult(f, -1)
                r = rank.get(id(e)) if e is not None else None
                if r is None:
                    continue
                sid, typ = records[r]
                if "FACE" not in typ:
                    bad += 1
                    continue
                face_ids[k] = sid
            del ents
            if bad:
                log.warning("%s: %d faces mapped to non-face records; ids dropped", path.name, bad)
    except InputError:
        raise
    except Exception as exc:  # the mapping is best effort: PMI then has no face links
        log.warning("%s: could not map faces to STEP entities: %s", path.name, exc)
    return face_ids


def _read_pmi(p21: P21Model, doc, path: Path, timings: dict[str, float]):
    """The semantic PMI from the text and XDE's cross-check: ``(PMI, XdeSummary)``; the
    stages' seconds go into ``timings``."""
    from .semantic import pmi_from_model

    t0 = time.perf_counter()
    pmi_data = pmi_from_model(p21)
    timings["pmi_text"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    xde = XdeSummary()
    try:
        xde = _xde_items(doc)
    except Exception as exc:  # cross-check only
        log.warning("%s: XDE GD&T cross-check failed: %s", path.name, exc)
    timings["pmi_xde"] = time.perf_counter() - t0
    return pmi_data, xde


def _solid_names(st, solids: list) -> list[str]:
    """The XDE label name of each solid ('' when it has none or only a generic one).
    Only when there are several: a single solid needs no name to be picked."""
    if len(solids) < 2:
        return [""] * len(solids)
    from OCP.TDF import TDF_Label

    out = []
    for s in solids:
        lab = TDF_Label()
        name = ""
        try:
            if st.Search(s, lab, True, True, True):
                name = _label_name(lab)
                ref = TDF_Label()
                # an assembly instance's own name is XDE's reference ("=>[0:1:1:2]"): the
                # part it places is named on the referred label
                if (not name or name.startswith("=>")) and st.GetReferredShape_s(lab, ref):
                    name = _label_name(ref)
                if name.startswith("=>"):
                    name = ""
        except Exception as exc:  # names are a convenience: index selection always works
            log.debug("solid name not read: %s", exc)
        out.append(name)
    return out


def _label_name(lab) -> str:
    """An XDE label's ``TDataStd_Name`` ('' when it has none).

    OCP's ``FindAttribute`` takes the process down (SIGSEGV) on a label without the
    attribute (an unnamed solid of a multi-solid export), so it is asked only where
    ``IsAttribute`` says the attribute is there."""
    from OCP.TDataStd import TDataStd_Name

    gid = TDataStd_Name.GetID_s()
    if not lab.IsAttribute(gid):
        return ""
    attr = TDataStd_Name()
    if lab.FindAttribute(gid, attr):
        return attr.Get().ToExtString().strip()
    return ""
