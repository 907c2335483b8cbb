"""Write a part as tessellated AP242: triangulated faces only, with its semantic PMI.

An AP242 file may carry the part as ``TRIANGULATED_FACE`` s in a ``TESSELLATED_SHELL`` and
no B-rep (NIST's ``-tg`` editions of its test models). Its PMI then names the triangulated
faces: a tolerance's ``GEOMETRIC_ITEM_SPECIFIC_USAGE`` has the ``TESSELLATED_SHAPE_REPRESENTATION``
as its representation and a ``TRIANGULATED_FACE`` as its item.

OCCT 7.9 writes a shape whose faces carry only a triangulation as such a file
(``write.step.tessellated``), but its XDE writer transfers no GD&T onto those faces. This
module therefore writes the two halves with OCCT and joins them as text:

1. the B-rep part with its PMI (:func:`qifreport.step.write.write_step_with_pmi`);
2. the same faces, meshed, as a triangulation-only shell (``STEPControl_Writer``);
3. the PMI records of the first file, renumbered after the second file's records, with each
   ``ADVANCED_FACE`` replaced by the triangulated face made from it, the B-rep shape
   representation by the tessellated one and the product records by the second file's.

The faces keep the index order of ``TopExp.MapShapes(shape, TopAbs_FACE)``: the closed
shell lists them in that order in the first file and the tessellated shell in the second.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Collection, Sequence
from pathlib import Path

from OCP.BRep import BRep_Builder, BRep_Tool
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.IFSelect import IFSelect_ReturnStatus
from OCP.Interface import Interface_Static
from OCP.STEPControl import STEPControl_AsIs, STEPControl_Controller, STEPControl_Writer
from OCP.TopAbs import TopAbs_FACE
from OCP.TopExp import TopExp
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Face, TopoDS_Shape, TopoDS_Shell
from OCP.TopTools import TopTools_IndexedMapOfShape

from qifreport.atomic_io import atomic_write

from .p21 import P21Model
from .write import PMISpecDatum, PMISpecTolerance, write_step_with_pmi

__all__ = ["write_tessellated_with_pmi"]

#: records that describe the product, one each in both files: the B-rep file's are replaced
#: by the tessellated file's
_PRODUCT_TYPES = (
    "PRODUCT_DEFINITION_SHAPE",
    "PRODUCT_DEFINITION",
    "PRODUCT_DEFINITION_FORMATION",
    "PRODUCT",
    "PRODUCT_CONTEXT",
    "PRODUCT_DEFINITION_CONTEXT",
    "APPLICATION_CONTEXT",
)
#: records of the B-rep file that are not PMI and not reached from its shape
_SKIP_TYPES = ("APPLICATION_PROTOCOL_DEFINITION", "PRODUCT_RELATED_PRODUCT_CATEGORY")
_TOKEN = re.compile(r"'(?:[^']|'')*'|#(\d+)")


def write_tessellated_with_pmi(
    shape: TopoDS_Shape,
    path: str | os.PathLike[str],
    tolerances: Sequence[PMISpecTolerance],
    datums: Sequence[PMISpecDatum],
    part_name: str = "part",
    *,
    deflection: float = 0.05,
    notes: Sequence[str] = (),
) -> Path:
    """Write ``shape`` as a tessellated AP242 file (mm) with its datums and tolerances.

    Parameters
    ----------
    shape : the part (one solid), mm.
    path : the output file, written atomically.
    tolerances, datums : as for :func:`~qifreport.step.write.write_step_with_pmi`; face
        indices name faces of ``shape`` in ``TopExp.MapShapes`` order.
    part_name : the product's name.
    deflection : mm, the chordal deflection of the triangulation.
    notes : drawing notes, as :func:`~qifreport.step.write.write_step_with_pmi` writes them.

    Returns
    -------
    Path of the written file.
    """
    path = Path(path)
    with tempfile.TemporaryDirectory() as tmp:
        brep_path = Path(tmp) / "brep.stp"
        tess_path = Path(tmp) / "tess.stp"
        write_step_with_pmi(
            shape, brep_path, tolerances, datums, part_name, timestamp="", notes=notes
        )
        _write_triangulated(shape, tess_path, deflection)
        text = _joined(P21Model.read(brep_path), tess_path.read_text())
    atomic_write(path, lambda tmp_path: Path(tmp_path).write_text(text))
    return path


def _write_triangulated(shape: TopoDS_Shape, path: Path, deflection: float) -> None:
    """The faces of ``shape``, meshed, as one shell of triangulation-only faces (AP242)."""
    BRepMesh_IncrementalMesh(shape, deflection)
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    for i in range(1, fmap.Size() + 1):
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(TopoDS.Face_s(fmap.FindKey(i)), loc)
        if tri is None:
            raise RuntimeError(f"face {i - 1} was not meshed")
        face = TopoDS_Face()
        builder.MakeFace(face, tri)
        builder.Add(shell, face)
    STEPControl_Controller.Init_s()
    saved = (
        Interface_Static.CVal_s("write.step.schema"),
        Interface_Static.IVal_s("write.step.tessellated"),
    )
    try:
        Interface_Static.SetCVal_s("write.step.schema", "AP242DIS")
        Interface_Static.SetIVal_s("write.step.tessellated", 1)
        writer = STEPControl_Writer()
        writer.Transfer(shell, STEPControl_AsIs)
        if writer.Write(str(path)) != IFSelect_ReturnStatus.IFSelect_RetDone:
            raise RuntimeError("STEPControl_Writer: write failed")
    finally:
        Interface_Static.SetCVal_s("write.step.schema", saved[0])
        Interface_Static.SetIVal_s("write.step.tessellated", saved[1])


def _joined(brep: P21Model, tess_text: str) -> str:
    """The tessellated file's text with the B-rep file's PMI records added to its DATA."""
    tess = P21Model.from_text(tess_text)
    mapped = _replacements(brep, tess)
    geometry = _closure(brep, [e.id for e in brep.by_type("SHAPE_DEFINITION_REPRESENTATION")])
    skip = {e.id for t in _SKIP_TYPES for e in brep.by_type(t)}
    roots = [i for i in brep if i not in geometry and i not in skip and i not in mapped]
    copied = sorted(_closure(brep, roots, stop=set(mapped)) - set(mapped))
    base = max(tess)
    new_id = dict(mapped)
    new_id.update({old: base + k + 1 for k, old in enumerate(copied)})

    def renumber(body: str) -> str:
        return _TOKEN.sub(lambda m: f"#{new_id[int(m[1])]}" if m[1] else m[0], body)

    records = "".join(f"#{new_id[i]}={renumber(brep.raw[i])};\n" for i in copied)
    end = tess_text.rindex("ENDSEC;")
    return tess_text[:end] + records + tess_text[end:]


def _replacements(brep: P21Model, tess: P21Model) -> dict[int, int]:
    """B-rep file id -> tessellated file id: faces in shell order, the shape
    representation and the product records."""
    faces = [r.id for s in brep.by_type("CLOSED_SHELL") for r in s.params[1]]
    tfaces = [r.id for s in tess.by_type("TESSELLATED_SHELL") for r in s.params[1]]
    if len(faces) != len(tfaces):
        raise RuntimeError(f"{len(faces)} B-rep faces but {len(tfaces)} triangulated faces")
    out = dict(zip(faces, tfaces, strict=True))
    (tsr,) = tess.by_type("TESSELLATED_SHAPE_REPRESENTATION")
    for rep in brep.by_type("ADVANCED_BREP_SHAPE_REPRESENTATION"):
        out[rep.id] = tsr.id
    for t in _PRODUCT_TYPES:
        for a, b in zip(brep.by_type(t), tess.by_type(t), strict=True):
            out[a.id] = b.id
    return out


def _closure(model: P21Model, roots: Sequence[int], stop: Collection[int] = ()) -> set[int]:
    """Ids reached from ``roots`` by references (not through ``stop``)."""
    seen: set[int] = set()
    todo = list(roots)
    while todo:
        i = todo.pop()
        if i in seen:
            continue
        seen.add(i)
        if i not in stop:
            todo.extend(r for r in model[i].refs() if r in model)
    return seen
