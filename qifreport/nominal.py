"""The nominal as an inspection needs it: a STEP part (mesh + PMI zones) or a mesh.

:func:`load_nominal` reads a STEP AP242 file through :mod:`qifreport.step` (tessellation with
per-face ids, semantic PMI turned into tolerance zones by
:func:`qifreport.metrology.bands.zones_from_pmi`) or a mesh nominal (STL/PLY/OBJ/OFF) with one
general zone of the given tolerance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qifreport.metrology.bands import NotEvaluated, ToleranceZone, symmetric_zone, zones_from_pmi
from qifreport.registration.mesh import bounding_diagonal, consistent_winding, load_mesh
from qifreport.step.reader import STEP_SUFFIXES

from .errors import InputError

log = logging.getLogger(__name__)

__all__ = [
    "Nominal",
    "load_nominal",
]


@dataclass
class Nominal:
    """The nominal as the inspection needs it: mesh, face ids, zones, provenance."""

    V: np.ndarray
    F: np.ndarray
    face_id: np.ndarray | None
    zones: list[ToleranceZone]
    not_evaluated: list[NotEvaluated]
    info: dict
    datums: list[str] = field(default_factory=list)


def load_nominal(
    path: Path,
    tolerance: float | None,
    max_edge: float | None = None,
    deflection: float | None = None,
    *,
    accept_tolerance_as_read: bool = False,
    mesher: str = "gmsh",
) -> Nominal:
    """Read a STEP part (mesh + PMI zones) or a mesh nominal (one general zone).

    A STEP part whose tolerances the plausibility check flags
    (:func:`qifreport.step.plausibility.implausible_tolerances`: a zone wider than 10 % of
    the part's diagonal, or unreadable as a length) is refused (:class:`InputError`, naming
    the first value) unless ``accept_tolerance_as_read``; then the reasons are kept in
    ``info["implausible_tolerances"]``.

    ``mesher``: ``"gmsh"`` (:func:`qifreport.step.gmsh_mesh.gmsh_tessellate`, isotropic,
    welded and manifold; the default) or ``"brepmesh"``
    (:func:`qifreport.step.tessellate.tessellate`).
    """
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--tolerance must be a positive length in mm, got {tolerance}")
    if path.suffix.lower() in STEP_SUFFIXES:
        from qifreport.step.plausibility import implausible_tolerances
        from qifreport.step.reader import read_step
        from qifreport.step.tessellate import shape_diagonal, tessellate

        part = read_step(path)
        diagonal = shape_diagonal(part.shape)
        implausible = implausible_tolerances(part.pmi, diagonal)
        if implausible and not accept_tolerance_as_read:
            more = f" (and {len(implausible) - 1} more)" if len(implausible) > 1 else ""
            raise InputError(
                f"{path.name}: implausible tolerance read from the file: {implausible[0]}{more}; "
                "if the drawing really means it, run with --accept-tolerance-as-read"
            )
        if max_edge is None:
            max_edge = diagonal / 60.0
        if mesher == "gmsh":
            from qifreport.step.gmsh_mesh import gmsh_tessellate

            mesh = gmsh_tessellate(part.shape, part.faces, deflection=deflection, max_edge=max_edge)
        else:
            mesh = tessellate(part.shape, part.faces, deflection=deflection, max_edge=max_edge)
        zones, skipped = zones_from_pmi(part.pmi, part.face_index(), tolerance)
        pmi = part.pmi
        info = {
            "format": "step",
            "schema": getattr(pmi, "schema", None),
            "length_unit": getattr(pmi, "length_unit", None),
            "b_rep_faces": len(part.faces),
            "solids": part.n_solids,
            "tessellation": {
                "mesher": mesher,
                "deflection_mm": mesh.deflection,
                "max_edge_mm": max_edge,
                "vertices": len(mesh.V),
                "triangles": len(mesh.F),
            },
            "pmi_counts": {
                "tolerances": len(pmi.tolerances) if pmi else 0,
                "dimensions": len(pmi.dimensions) if pmi else 0,
                "datums": len(pmi.datums) if pmi else 0,
            },
            "timings_s": {**part.timings, "tessellate": mesh.seconds},
        }
        if implausible:
            info["implausible_tolerances"] = implausible
        datums = [d.label for d in pmi.datums] if pmi is not None else []
        return Nominal(
            mesh.V, mesh.F, mesh.face_id, zones, skipped, info, list(dict.fromkeys(datums))
        )
    if tolerance is None:
        raise InputError(
            f"{path.name} is a mesh nominal: it carries no tolerance, give "
            "--tolerance MM (or use the STEP file with PMI)"
        )
    V, F = load_mesh(path)
    F, flipped, unorientable = consistent_winding(V, F)
    if flipped:
        log.warning(
            "%s: %d triangle(s) wound against their neighbours were turned over", path.name, flipped
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
    return Nominal(V, F, None, [symmetric_zone(tolerance, "general")], [], info)
