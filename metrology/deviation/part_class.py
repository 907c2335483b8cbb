"""The part's class for its trim-edge readings: a sheet, or a solid.

A trim edge is the sheet-metal notion of an open edge's position: where a sheet (a stamped
or formed panel, a moulded shell) was cut. On a sheet the outline is the edge of one large
surface, and its position along the surface is what a normal deviation cannot see, so the
trim edge and the size read from it (:mod:`qifreport.metrology.deviation.size`) are judged.
A machined solid (a block whose walls are not thin against its size) has no such edge: its
sharp creases bound faces that its drawing measures themselves (sizes, profiles, positions);
the strip about a crease holds the points of a face that turns away at the crease (their
normals tilt within a point spacing of it), so the "edge" read there is where the scan's
face stops being seen, not where the part ends (on a perfect NIST CTC 04 scan, P05/P95
-2.59/+1.53 mm). Its trim edges and size are reported, not judged.

:func:`part_class` decides from the geometry: an open mesh (no B-rep solid) is a sheet; a
closed mesh or a B-rep solid is a sheet when its wall is thin against its size: over at
least half of its area (sampled at up to 2,000 vertices) a ray cast inward along the normal
leaves the material within 2 % of the bounding diagonal; else a solid. Measured: the sample
panel (1.8 mm wall, 189 mm diagonal) 99 % of its area thin, a sheet; NIST CTC 03 (1.9 mm,
595 mm) 100 %, a sheet; FTC 08 (a 6.35 mm plate, 386 mm) 68 %, a sheet; CTC 01, 02, 04,
05 and FTC 06 (machined blocks, median walls 28 to 58 mm, 3 to 8 % of their diagonals)
1 to 2 %, solids; the fandisk (21 mm, 100 mm) 0 %, a solid.

All lengths are mm; ``V`` (n, 3), ``F`` (f, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np

from qifreport.metrology.acceptance.statistics import json_float
from qifreport.registration.mesh import (
    boundary_vertices,
    bounding_diagonal,
    vertex_areas,
    vertex_normals,
)

__all__ = [
    "PartClass",
    "SHEET",
    "SOLID",
    "part_class",
]

#: the part classes
SHEET, SOLID = "sheet", "solid"
#: a wall is thin when its opposite skin lies within this share of the bounding diagonal
THIN_WALL = 0.02
#: a part is a sheet when at least this share of its area has a thin wall
_SHEET_AREA = 0.5
#: vertices sampled for the wall thickness
_SAMPLES = 2000


@dataclass(frozen=True)
class PartClass:
    """The part's class for its trim-edge readings (module docstring).

    Attributes
    ----------
    kind : :data:`SHEET` or :data:`SOLID`.
    open_rim : the nominal is an open mesh (not a B-rep solid).
    thin_area : share of the area whose opposite skin lies within ``reach``; NaN for an
        open mesh (not measured).
    wall : the median wall thickness over that area, mm (NaN: none).
    reach : ``THIN_WALL`` x the bounding diagonal, mm.
    """

    kind: str
    open_rim: bool
    thin_area: float
    wall: float
    reach: float

    @property
    def judges_trim_edges(self) -> bool:
        """Whether the trim edges and the size read from them take part in the verdict."""
        return self.kind == SHEET

    def describe(self) -> str:
        """One phrase: the class and why."""
        if self.open_rim:
            return "a sheet (an open surface)"
        pct = 100 * self.thin_area
        if self.kind == SHEET:
            return f"a sheet ({self.wall:.2g} mm wall over {pct:.0f} % of its area)"
        return (
            f"a solid (walls under {100 * THIN_WALL:.0f} % of its size, {self.reach:.2g} mm, "
            f"over {pct:.0f} % of its area only)"
        )

    def to_dict(self) -> dict:
        """JSON-ready summary (NaN -> None)."""
        return {
            "kind": self.kind,
            "open_rim": self.open_rim,
            "thin_area_fraction": json_float(self.thin_area),
            "wall_mm": json_float(self.wall),
            "reach_mm": json_float(self.reach),
            "trim_edges_judged": self.judges_trim_edges,
        }


def part_class(
    V: np.ndarray,
    F: np.ndarray,
    *,
    solid: bool,
    normals: np.ndarray | None = None,
) -> PartClass:
    """The class of the nominal ``(V, F)`` for its trim-edge readings (module docstring).

    Parameters
    ----------
    V : (n, 3) mm.  F : (f, 3), consistently wound (outward normals).
    solid : the nominal is a B-rep solid (its mesh's open edges are sewing gaps, no rim).
    normals : (n, 3) unit outward vertex normals; default
        :func:`qifreport.registration.mesh.vertex_normals`.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    reach = THIN_WALL * bounding_diagonal(V)
    if not solid and boundary_vertices(F, len(V)).any():
        return PartClass(SHEET, True, float("nan"), float("nan"), reach)
    N = vertex_normals(V, F) if normals is None else np.asarray(normals, dtype=np.float64)
    area = vertex_areas(V, F)
    used = np.flatnonzero(area > 0)
    at = used[np.linspace(0, len(used) - 1, min(_SAMPLES, len(used))).astype(np.int64)]
    t = _inward_depth(V, F, N, at)
    w = area[at]
    thin = t <= reach
    share = float(w[thin].sum() / max(float(w.sum()), 1e-300))
    wall = float(np.median(t[thin])) if thin.any() else float("nan")
    kind = SHEET if share >= _SHEET_AREA else SOLID
    return PartClass(kind, False, share, wall, reach)


def _inward_depth(V: np.ndarray, F: np.ndarray, N: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(k,) mm: how far a ray from each vertex ``at`` (k,) along its inward normal ``-N``
    runs in the material before it meets the mesh again (inf: never)."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    tree = igl.AABB()
    tree.init(V, F)
    start = 1e-6 * bounding_diagonal(V)  # off the vertex's own triangles
    D = np.ascontiguousarray(-N[at])
    hit, t, _ = tree.intersect_ray_first(V, F, np.ascontiguousarray(V[at] + start * D), D)
    return np.where(hit >= 0, t + start, np.inf)
