"""The vertices an inspection does not score, decided from the nominal alone: the bands
along sharp creases and along the open boundary (rim, holes, unwelded seams)."""

from __future__ import annotations

import numpy as np

from qifreport.metrology.deviation.hygiene import near_boundary
from qifreport.metrology.params import InspectionParams
from qifreport.registration.mesh import crease_band, median_edge_length

__all__ = ["unscored_bands"]


def unscored_bands(
    V: np.ndarray,
    F: np.ndarray,
    boundary: np.ndarray,
    params: InspectionParams,
) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The vertices an inspection does not score, from the nominal alone.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    boundary : (n,) open-boundary vertices (:func:`qifreport.registration.mesh.boundary_vertices`).
    params : ``edge_band`` (default 1.5 median edges), ``crease_angle``, ``boundary_band``
        (default the edge band).

    Returns
    -------
    near_crease : (n,) bool within the edge band of a sharp crease, or None when the band
        is 0.  near_rim : (n,) bool within the rim band of an open boundary.
    rim_band : the rim band, mm.
    """
    band = 1.5 * median_edge_length(V, F) if params.edge_band is None else float(params.edge_band)
    near_crease = crease_band(V, F, band, params.crease_angle) if band > 0 else None
    rim_band = band if params.boundary_band is None else float(params.boundary_band)
    return near_crease, near_boundary(V, boundary, rim_band), rim_band
