"""Reading a nominal file into the :class:`~qifreport.metrology.model.Part` and its
:class:`~qifreport.metrology.model.Drawing`: a STEP part or a mesh.

:func:`load_nominal` reads a STEP AP242 file through :mod:`qifreport.step` (tessellation with
per-face ids, semantic PMI turned into tolerance zones by
:func:`qifreport.metrology.acceptance.bands.zones_from_pmi` and into feature characteristics
by :func:`qifreport.metrology.gdt.pmi_plan.specs_from_pmi`) or a mesh nominal
(STL/PLY/OBJ/OFF) with one general zone of the operator's tolerance.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qifreport.metrology.acceptance.bands import (
    NotEvaluated,
    ToleranceZone,
    symmetric_zone,
    zones_from_pmi,
)
from qifreport.metrology.gdt.pmi_plan import specs_from_pmi
from qifreport.metrology.model import Drawing, MaterialStatement, Part, RestraintStatement
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import (
    bounding_diagonal,
    consistent_winding,
    load_mesh,
    remove_unreferenced,
)
from qifreport.registration.restraint.designation import preset_of
from qifreport.step.reader import STEP_SUFFIXES
from qifreport.step.solids import SolidInfo, overlapping_pairs, pick_solid, solid_infos

from .errors import InputError

if TYPE_CHECKING:
    from qifreport.step.gmsh_mesh import SolidMesh
    from qifreport.step.reader import StepPart

log = logging.getLogger(__name__)

__all__ = [
    "load_nominal",
    "pick_part_solid",
    "seat_faces",
]


def load_nominal(
    path: Path,
    tolerance: float | None,
    max_edge: float | None = None,
    deflection: float | None = None,
    *,
    accept_tolerance_as_read: bool = False,
    mesher: str = "gmsh",
    solid: str | None = None,
    solid_mesh: bool = False,
    solid_mesh_for_material: bool = False,
) -> tuple[Part, Drawing]:
    """Read a STEP part (mesh + PMI zones and characteristics) or a mesh nominal (one general
    zone of ``tolerance``): the part and its drawing.

    A STEP part whose tolerances the plausibility check flags
    (:func:`qifreport.step.plausibility.implausible_tolerances`: a zone wider than 10 % of
    the part's diagonal, or unreadable as a length) is refused (:class:`InputError`, naming
    the first value) unless ``accept_tolerance_as_read``; then the reasons are kept in
    ``Part.info["implausible_tolerances"]``.

    ``tolerance``: the half-width (mm) of the general zone, required for a mesh nominal;
    for a STEP part, of the zone of the faces no profile of the PMI covers (None: the PMI's
    whole-part profile, else the default).

    ``mesher``: ``"gmsh"`` (:func:`qifreport.step.gmsh_mesh.gmsh_tessellate`, isotropic,
    welded and manifold; the default) or ``"brepmesh"``
    (:func:`qifreport.step.tessellate.tessellate`).

    ``solid``: the solid of a multi-solid STEP file to inspect, by index or name
    (:func:`pick_part_solid`; a file with several solids is refused without it).

    ``solid_mesh``: also fill a STEP part's solid with tetrahedra (``Part.solid_mesh``,
    edge :data:`qifreport.restraint.SOLID_EDGE_SHARE` of its diagonal), for the elastic
    model of a restrained inspection. ``solid_mesh_for_material``: fill it too when the
    drawing states a material that names a preset (:attr:`Drawing.material
    <qifreport.metrology.model.Drawing.material>`: the virtual fixture's load is then
    measured with it).
    """
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--tolerance must be a positive length in mm, got {tolerance}")
    if path.suffix.lower() in STEP_SUFFIXES:
        return _step_nominal(
            path,
            tolerance,
            max_edge,
            deflection,
            accept_tolerance_as_read=accept_tolerance_as_read,
            mesher=mesher,
            solid=solid,
            solid_mesh=solid_mesh,
            solid_mesh_for_material=solid_mesh_for_material,
        )
    return _mesh_nominal(path, tolerance)


def _step_nominal(
    path: Path,
    tolerance: float | None,
    max_edge: float | None,
    deflection: float | None,
    *,
    accept_tolerance_as_read: bool,
    mesher: str,
    solid: str | None,
    solid_mesh: bool,
    solid_mesh_for_material: bool = False,
) -> tuple[Part, Drawing]:
    """:func:`load_nominal` of a STEP file: tessellate the part (its solid ``solid``), seat
    the zones of its PMI on the faces kept (:func:`seat_faces`), the B-rep's corner normals,
    the solid's tetrahedra when ``solid_mesh`` (or ``solid_mesh_for_material`` and the
    drawing's material names a preset)."""
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import shape_diagonal

    step_part = read_step(path)
    if solid_mesh and step_part.tessellated:
        raise InputError(
            f"{path.name}: a tessellated part (triangles, no solid): the restrained "
            "inspection needs its solid for the elastic model; use the B-rep edition"
        )
    pmi = step_part.pmi
    diagonal = shape_diagonal(step_part.shape)
    implausible = _plausibility(path, pmi, diagonal, accept_tolerance_as_read)
    chosen, picked = pick_part_solid(step_part, solid)
    if picked is not None:  # the part is that solid: its size sets the mesh
        diagonal = float(np.linalg.norm(picked.hi - picked.lo))
    if max_edge is None:
        max_edge = diagonal / 60.0
    if step_part.tessellated:  # the file's own triangles: no surface for gmsh to mesh
        mesher = "brepmesh"
    mesh = _tessellate(step_part, mesher, deflection, max_edge)
    zones, skipped = zones_from_pmi(pmi, step_part.face_index(), tolerance)
    V, F, face_id = mesh.V, mesh.F, mesh.face_id
    supplemental: list[dict] = []
    face_solid = _face_solids(step_part)
    if chosen is not None or (face_solid < 0).any():
        V, F, face_id, zones, skipped, supplemental = seat_faces(
            V,
            F,
            face_id,
            face_solid,
            chosen,
            zones,
            skipped,
            step_part.face_step_ids,
            2.0 * mesh.deflection,
        )
    info = _step_info(step_part, mesh, mesher, max_edge, len(V), len(F))
    if implausible:
        info["implausible_tolerances"] = implausible
    if supplemental:
        info["supplemental_faces"] = supplemental
    if picked is not None:
        info["solid"] = {"index": chosen, "name": picked.name, "of": step_part.n_solids}
    datums = [d.label for d in pmi.datums] if pmi is not None else []
    t0 = time.perf_counter()
    normals = _corner_normals(step_part, V, F, face_id)
    info["timings_s"]["corner normals"] = time.perf_counter() - t0
    material = _material_statement(pmi)
    # a tessellated part has no solid to fill: the fixture's load is then not measured
    wanted = material is not None and material.preset is not None and not step_part.tessellated
    if solid_mesh_for_material and wanted:
        solid_mesh = True
    tets = _solid_tetrahedra(step_part, chosen, diagonal) if solid_mesh else None
    if tets is not None:
        info["timings_s"]["solid tetrahedra"] = tets.seconds
    part = Part(
        V,
        F,
        face_id,
        face_step_ids=np.asarray(step_part.face_step_ids, dtype=np.int64),
        brep_normals=normals,
        solid_mesh=tets,
        name=step_part.name,
        source=path,
        units=getattr(pmi, "length_unit", None),
        info=info,
    )
    drawing = Drawing(
        zones,
        skipped,
        list(dict.fromkeys(datums)),
        plan=specs_from_pmi(pmi, step_part.face_index()),
        source="pmi",
        restraint=_restraint_statement(pmi),
        material=material,
        warnings=pmi.reader_warnings() if pmi is not None else [],
    )
    return part, drawing


def _face_solids(step_part: StepPart) -> np.ndarray:
    """(n_faces,) the solid of each face (:func:`qifreport.step.supplemental.face_solids`);
    a tessellated part's shell is the part itself: every face is its (no supplemental)."""
    from qifreport.step.supplemental import face_solids

    if step_part.tessellated:
        return np.zeros(len(step_part.faces), dtype=np.int64)
    return face_solids(step_part.shape, step_part.faces)


def _corner_normals(step_part: StepPart, V: np.ndarray, F: np.ndarray, face_id: np.ndarray):
    """(f, 3, 3) outward normals at the triangles' corners: the B-rep's exact ones, or a
    tessellated part's triangles' own (its faces have no surface)."""
    from qifreport.step.normals import corner_normals_exact, corner_normals_of_faces

    if step_part.tessellated:
        return corner_normals_of_faces(V, F, face_id)
    return corner_normals_exact(step_part.faces, V, F, face_id)


def _material_statement(pmi) -> MaterialStatement | None:
    """The part's material as the STEP file states it (:attr:`PMI.material
    <qifreport.step.pmi.PMI.material>`) and the preset it names, if any."""
    note = getattr(pmi, "material", None)
    if note is None:
        return None
    return MaterialStatement(note.text, preset_of(note.text), note.source)


def _restraint_statement(pmi) -> RestraintStatement:
    """What the STEP file's notes state about restraint (:attr:`PMI.restraint
    <qifreport.step.pmi.PMI.restraint>`)."""
    note = getattr(pmi, "restraint", None)
    if note is None:
        return RestraintStatement(False, "", "drawing")
    held, unplaced = pmi.held_targets()
    return RestraintStatement(True, note.text, "drawing note", held, unplaced)


def _plausibility(path: Path, pmi, diagonal: float, accept: bool) -> list:
    """The reasons :func:`qifreport.step.plausibility.implausible_tolerances` finds the PMI's
    tolerances implausible for a part of ``diagonal`` mm; any refuses the part
    (:class:`InputError`, naming the first) unless ``accept``."""
    from qifreport.step.plausibility import implausible_tolerances

    implausible = implausible_tolerances(pmi, diagonal)
    if implausible and not accept:
        more = f" (and {len(implausible) - 1} more)" if len(implausible) > 1 else ""
        raise InputError(
            f"{path.name}: implausible tolerance read from the file: {implausible[0]}{more}; "
            "if the drawing really means it, run with --accept-tolerance-as-read"
        )
    return implausible


def _tessellate(step_part: StepPart, mesher: str, deflection: float | None, max_edge: float):
    """The STEP part's inspection mesh with face ids, by ``mesher`` (:func:`load_nominal`)."""
    if mesher == "gmsh":
        from qifreport.step.gmsh_mesh import gmsh_tessellate

        return gmsh_tessellate(
            step_part.shape, step_part.faces, deflection=deflection, max_edge=max_edge
        )
    from qifreport.step.tessellate import tessellate

    return tessellate(step_part.shape, step_part.faces, deflection=deflection, max_edge=max_edge)


def _step_info(
    step_part: StepPart, mesh, mesher: str, max_edge: float, n_vertices: int, n_triangles: int
) -> dict:
    """The provenance of a STEP part (``Part.info``, the JSON summary's ``nominal`` block):
    schema, unit, faces, solids, the tessellation (``n_vertices`` and ``n_triangles`` of
    the mesh kept), the PMI's counts, the timings."""
    pmi = step_part.pmi
    return {
        "format": "step",
        "schema": getattr(pmi, "schema", None),
        "length_unit": getattr(pmi, "length_unit", None),
        "b_rep_faces": len(step_part.faces),
        "solids": step_part.n_solids,
        "tessellated": step_part.tessellated,
        "tessellation": {
            "mesher": mesher,
            "deflection_mm": mesh.deflection,
            "max_edge_mm": max_edge,
            "vertices": n_vertices,
            "triangles": n_triangles,
        },
        "product": pmi.product.to_dict() if pmi is not None and pmi.product else None,
        "pmi_counts": {
            "tolerances": len(pmi.tolerances) if pmi else 0,
            "dimensions": len(pmi.dimensions) if pmi else 0,
            "datums": len(pmi.datums) if pmi else 0,
        },
        "timings_s": {**step_part.timings, "tessellate": mesh.seconds},
    }


def _solid_tetrahedra(step_part: StepPart, chosen: int | None, diagonal: float) -> SolidMesh:
    """The tetrahedra filling the part's solid (solid ``chosen``, every solid's when None),
    edge :data:`qifreport.restraint.SOLID_EDGE_SHARE` of ``diagonal`` mm."""
    from qifreport.step.gmsh_mesh import gmsh_solid_mesh
    from qifreport.step.solids import solid_shape

    from .restraint import SOLID_EDGE_SHARE

    shape = step_part.shape if chosen is None else solid_shape(step_part.shape, chosen)
    return gmsh_solid_mesh(shape, SOLID_EDGE_SHARE * diagonal)


def _mesh_nominal(path: Path, tolerance: float | None) -> tuple[Part, Drawing]:
    """:func:`load_nominal` of a mesh file: its triangles wound consistently, one general
    zone of the operator's ``tolerance`` (required)."""
    if tolerance is None:
        raise InputError(
            f"{path.name} is a mesh nominal: it carries no tolerance, give "
            "--tolerance MM (or use the STEP file with PMI)"
        )
    V, F = load_mesh(path)
    F, flipped, unorientable = consistent_winding(V, F)
    if flipped:
        log.warning(
            "%s: %d triangle(s) turned over (wound against their neighbours, or a closed "
            "surface wound inward)",
            path.name,
            flipped,
        )
    if unorientable:
        log.warning(
            "%s: %d triangle(s) lie on a piece no winding can orient", path.name, unorientable
        )
    info = {
        "format": "mesh",
        "diagonal_mm": bounding_diagonal(V),
        "winding": {"flipped_triangles": flipped, "unorientable_triangles": unorientable},
    }
    part = Part(V, F, name=path.stem, source=path, units="mm", info=info)
    return part, Drawing([symmetric_zone(tolerance, "general")], source="operator")


def seat_faces(
    V: np.ndarray,
    F: np.ndarray,
    face_id: np.ndarray,
    face_solid: np.ndarray,
    solid: int | None,
    zones: list[ToleranceZone],
    skipped: list[NotEvaluated],
    face_step_ids: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[ToleranceZone], list[NotEvaluated], list]:
    """Keep the mesh of the part inspected: the faces of solid ``solid`` (every solid's when
    None) without the supplemental faces (in no solid), and judge the tolerances that name a
    supplemental face on the solid beneath it (:mod:`qifreport.step.supplemental`).

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3).  face_id : (f,) face of each triangle.
    face_solid : (n_faces,) solid of each face, -1 for none
        (:func:`qifreport.step.supplemental.face_solids`).
    solid : the solid inspected (``--solid``), or None.
    zones, skipped : from ``zones_from_pmi``.
    face_step_ids : (n_faces,) STEP id of each face (-1 unknown).
    tol : mm, how far from a supplemental face the solid's triangles beneath it may lie.

    Returns
    -------
    V, F, face_id : the mesh kept (unused vertices dropped).
    zones : each zone on the faces kept; a zone naming a supplemental face on the solid takes
        its footprint's triangles (``ToleranceZone.triangles``); a zone left with no surface
        is moved to
    skipped : with the reason.
    supplemental : one dict per supplemental face (the JSON's ``nominal.supplemental_faces``).
    """
    from qifreport.step.supplemental import footprints

    free = face_solid < 0
    other = (
        np.zeros(len(face_solid), dtype=bool)
        if solid is None
        else (face_solid >= 0) & (face_solid != solid)
    )
    keep = ~other[face_id]
    F1, fid1 = F[keep], face_id[keep]
    prints = {fp.face: fp for fp in footprints(V, F1, fid1, free, tol)}
    keep2 = ~free[fid1]
    new_tri = np.cumsum(keep2) - 1
    F2, fid2 = F1[keep2], fid1[keep2]
    V2, F2 = remove_unreferenced(V, F2)
    out_zones, out_skipped = [], list(skipped)
    for z in zones:
        if z.faces is None or not (free[z.faces].any() or other[z.faces].any()):
            out_zones.append(z)
            continue
        mine = [int(f) for f in z.faces if free[f]]
        tris = [new_tri[prints[f].triangles] for f in mine if f in prints]
        tris = unique_sorted(np.concatenate(tris)) if tris else np.zeros(0, dtype=np.int64)
        kept = np.array([f for f in z.faces if not free[f] and not other[f]], dtype=np.int64)
        if len(tris) == 0 and len(kept) == 0:
            reason = _unseated(z.faces, mine, other, face_solid, solid, face_step_ids)
            out_skipped.append(
                NotEvaluated(kind=z.kind, name=z.name, step_id=z.step_id, reason=reason)
            )
            continue
        faces = np.array([f for f in z.faces if not other[f]], dtype=np.int64)
        out_zones.append(replace(z, faces=faces, triangles=tris if len(tris) else None))
    return V2, F2, fid2, out_zones, out_skipped, _supplemental_faces(prints, face_step_ids)


def _unseated(
    faces: np.ndarray,
    mine: list[int],
    other: np.ndarray,
    face_solid: np.ndarray,
    solid: int | None,
    face_step_ids: np.ndarray,
) -> str:
    """Why a zone on ``faces`` is left with no surface (:func:`seat_faces`): they are on
    another solid than the one inspected, or they are the supplemental faces ``mine`` with
    no footprint on the solid."""
    if other[faces].any():
        where = sorted({int(face_solid[f]) for f in faces if other[f]})
        return (
            f"its faces are on solid {', '.join(map(str, where))}, not on the solid "
            f"inspected ({solid})"
        )
    ids = ", ".join(f"#{face_step_ids[f]}" for f in mine)
    return (
        f"its face {ids} is supplemental geometry off the part's solid: no scan "
        "of the part can measure it"
    )


def _supplemental_faces(prints: dict, face_step_ids: np.ndarray) -> list[dict]:
    """One dict per supplemental face left out of the mesh (its footprint ``prints[face]``,
    :func:`qifreport.step.supplemental.footprints`), each logged (INFO)."""
    supplemental = [
        {
            "face": f,
            "step_id": int(face_step_ids[f]) if face_step_ids[f] >= 0 else None,
            "area_mm2": fp.free_area,
            "footprint_area_mm2": fp.area,
            "on_faces": [int(x) for x in fp.on_faces],
        }
        for f, fp in sorted(prints.items())
    ]
    for f, fp in sorted(prints.items()):
        where = (
            f"on face(s) {', '.join(str(int(x)) for x in fp.on_faces)}"
            if len(fp.triangles)
            else "off the solid"
        )
        log.info(
            "supplemental face %d (#%d, %.1f mm^2) %s: left out of the mesh",
            f,
            face_step_ids[f],
            fp.free_area,
            where,
        )
    return supplemental


def pick_part_solid(part, solid: str | None) -> tuple[int | None, SolidInfo | None]:
    """The solid of a STEP part to inspect: ``(index, its SolidInfo)``, ``(None, None)`` for
    a part with one solid. Several solids without ``solid`` are refused (:class:`InputError`):
    overlapping or nested ones as never one part, separate ones with a request to pick one
    with ``--solid NAME|INDEX``, listing them."""
    if part.n_solids < 2:
        if solid is not None and solid.strip() not in ("0", *part.solid_names):
            raise InputError(f"--solid {solid}: {part.path.name} has one solid (0)")
        return None, None
    infos = solid_infos(part.shape, part.solid_names)
    listing = "; ".join(x.describe() for x in infos)
    if solid is None:
        pairs = overlapping_pairs(part.shape, infos)
        if pairs:
            a, b, v = pairs[0]
            raise InputError(
                f"{part.path.name}: solids {infos[a].describe()} and {infos[b].describe()} "
                f"overlap ({v:,.0f} mm^3 in common; {len(pairs)} overlapping pair(s)): "
                "nested or overlapping solids are not one part; pick one with --solid "
                "NAME|INDEX"
            )
        raise InputError(
            f"{part.path.name} holds {len(infos)} separate solids ({listing}): one part per "
            "inspection, pick one with --solid NAME|INDEX"
        )
    try:
        k = pick_solid(infos, solid)
    except KeyError as exc:
        raise InputError(f"--solid {solid}: {exc.args[0]}; the solids are {listing}") from None
    return k, infos[k]
