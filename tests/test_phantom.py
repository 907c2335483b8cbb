"""No phantom deviation: mesh nominals scanned at their own vertices read their noise.

Every point lies on the nominal mesh (5 um noise along the vertex normal), so every scored
vertex must read within 4 sigma of zero. A plane fitted to the points about a vertex reads
a curved surface's sag inside its ball as deviation (0.025 mm on the 40 mm bumpy sphere,
up to 0.14 mm beside the fandisk's creases); the fit of the points' own distances to the
mesh does not.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.deviation.local_planes import nominal_referenced
from qifreport.metrology.stages.deviation import vertex_deviation
from qifreport.registration.mesh import crease_band, median_edge_length, vertex_normals
from qifreport.simulate.shapes import bumpy_sphere, fandisk
from tests.conftest import shared_file

NOISE = 0.005


def own_vertices(V: np.ndarray, F: np.ndarray, seed: int = 0) -> np.ndarray:
    """The vertices moved along their normals by Gaussian noise of ``NOISE`` mm."""
    rng = np.random.default_rng(seed)
    return V + rng.normal(0.0, NOISE, len(V))[:, None] * vertex_normals(V, F)


@pytest.mark.parametrize("shape", ["bumpy sphere", "fandisk"])
def test_mesh_nominal_at_its_own_vertices_reads_its_noise(shape):
    if shape == "fandisk":
        V, F = fandisk(str(shared_file("meshes/fandisk.off")))
    else:
        V, F = bumpy_sphere()
    P = own_vertices(V, F)
    N = vertex_normals(V, F)
    scored = ~crease_band(V, F, 1.5 * median_edge_length(V, F), 45.0)
    dev, var = vertex_deviation(V, F, P, N, None)
    d = dev[scored]
    assert np.isfinite(d).mean() > 0.99
    assert np.nanmax(np.abs(d)) <= 4 * NOISE
    assert np.sqrt(np.nanmean(d**2)) < NOISE
    assert np.all(np.isfinite(var[scored][np.isfinite(d)]))
    # the plane fit this replaces: the curvature's sag, several sigma
    plane = nominal_referenced(V, F, P, normals=N)[scored]
    assert np.nanmax(np.abs(plane)) > 8 * NOISE
