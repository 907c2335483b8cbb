"""Nominal hygiene: what is wrong with the nominal mesh, and the rim band left unscored.

The paper's real part (Section 8.4) came as an unwelded patchwork: 29,101 open boundary edges
survived welding and the boundary exclusion removed 18.7 % of its area from scoring. A
deviation at an open rim is not a measurement: the vertex normal there is one-sided, the
scan's neighbourhood is a half disk, and the compliance the fit could not remove concentrates
along the rim (the paper's fit was "excellent on most of the surface and poor along the
rim"). So vertices within ``band`` (mm) of an open boundary are not scored, and what was
excluded is reported with the mesh's defects.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from qifreport.registration.mesh import adjacency, edge_uses

__all__ = [
    "mesh_hygiene",
    "MeshHygiene",
    "near_boundary",
]


@dataclass
class MeshHygiene:
    """Defects of a nominal mesh and the rim band (counts; lengths mm, areas mm^2).

    Attributes
    ----------
    boundary_edges : edges used by one triangle (open rim, holes, unwelded seams).
    non_manifold_edges : edges used by more than two triangles.
    degenerate_faces : triangles of (near) zero area (< 1e-12 of the mean).
    duplicate_faces : triangles repeating another's three vertices.
    components : connected pieces of the mesh.
    boundary_band : the unscored rim band, mm (0: none).
    boundary_excluded_area : nominal area within the band, mm^2.
    boundary_excluded_fraction : the same as a share of the nominal area.
    """

    boundary_edges: int
    non_manifold_edges: int
    degenerate_faces: int
    duplicate_faces: int
    components: int
    boundary_band: float = 0.0
    boundary_excluded_area: float = 0.0
    boundary_excluded_fraction: float = 0.0

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, float) else int(v)) for k, v in asdict(self).items()}

    def describe(self) -> str:
        return (
            f"{self.boundary_edges} open boundary edges, {self.non_manifold_edges} "
            f"non-manifold, {self.degenerate_faces} degenerate and {self.duplicate_faces} "
            f"duplicate triangles, {self.components} piece(s); "
            f"{100 * self.boundary_excluded_fraction:.1f} % of the area within "
            f"{self.boundary_band:.2g} mm of the rim not scored"
        )


def mesh_hygiene(V: np.ndarray, F: np.ndarray) -> MeshHygiene:
    """Count the defects of the mesh ``(V, F)`` (mm)."""
    F = np.asarray(F, dtype=np.int64)
    _, count, _ = edge_uses(F)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    degenerate = int(np.sum(area <= 1e-12 * max(float(area.mean()), 1e-300)))
    duplicate = len(F) - len(np.unique(np.sort(F, axis=1), axis=0))
    n_comp, _ = connected_components(adjacency(F, len(V)), directed=False)
    return MeshHygiene(
        boundary_edges=int(np.sum(count == 1)),
        non_manifold_edges=int(np.sum(count > 2)),
        degenerate_faces=degenerate,
        duplicate_faces=int(duplicate),
        components=int(n_comp),
    )


def near_boundary(V: np.ndarray, boundary: np.ndarray, band: float) -> np.ndarray:
    """Vertices within ``band`` mm (straight-line distance) of an open-boundary vertex.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  boundary : (n,) bool, open-boundary vertices.  band : mm.

    Returns
    -------
    (n,) bool (all False when there is no boundary or ``band <= 0``).
    """
    out = np.zeros(len(V), dtype=bool)
    if band <= 0 or not np.any(boundary):
        return out
    d, _ = cKDTree(V[boundary]).query(V, distance_upper_bound=band, workers=-1)
    return np.isfinite(d)
