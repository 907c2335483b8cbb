"""Nominal hygiene: defect counts and the unscored rim band (metrology/deviation/hygiene.py)."""

from __future__ import annotations

import numpy as np

from qifreport.metrology.deviation.hygiene import mesh_hygiene, near_boundary
from qifreport.metrology.inspection import InspectionParams, inspect
from qifreport.registration.mesh import boundary_vertices
from qifreport.simulate.cases import make_case
from qifreport.simulate.shapes import grid_triangles, thin_shell


def test_defects_are_counted():
    n = 5
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    F = grid_triangles(n, n)  # 4 x 4 cells, 32 triangles, 16 boundary edges
    clean = mesh_hygiene(V, F)
    assert (
        clean.boundary_edges,
        clean.non_manifold_edges,
        clean.degenerate_faces,
        clean.duplicate_faces,
        clean.components,
    ) == (16, 0, 0, 0, 1)
    # a repeated triangle (its edges now used 3 times or twice more), a fin on an inner edge,
    # a zero-area triangle and a detached triangle
    V2 = np.vstack([V, [[1.0, 1.0, 1.0], [10, 10, 0], [11, 10, 0], [10, 11, 0]]])
    a, b = F[10][0], F[10][1]
    F2 = np.vstack([F, F[10], [a, b, 25], [0, 1, 2], [26, 27, 28]])
    h = mesh_hygiene(V2, F2)
    assert h.duplicate_faces == 1 and h.degenerate_faces == 1
    assert h.non_manifold_edges >= 1 and h.components == 2


def test_rim_band_is_not_scored_and_reported():
    V, F = thin_shell()
    edge = boundary_vertices(F, len(V))
    band = near_boundary(V, edge, 3.0)
    assert band[edge].all() and not near_boundary(V, edge, 0.0).any()
    # every banded vertex lies within 3 mm of the rim, the others do not
    d_rim = np.min(np.linalg.norm(V[:, None, :2] - V[edge][None, :, :2], axis=2), axis=1)
    assert np.all(d_rim[band] <= 3.0 + 1e-9) and np.all(d_rim[~band] > 3.0 - 0.5)
    case = make_case(V, F, generator="analytic", amplitude=0.02, seed=0)
    res = inspect(V, F, case.P, InspectionParams(tolerance=0.5, boundary_band=3.0, rigid_only=True))
    assert np.isnan(res.deviation[band]).all()
    h = res.hygiene
    assert h.boundary_edges == int(np.sum(edge)) and h.boundary_band == 3.0
    # 3 mm along the 560 mm rim of a 170 x 110 mm sheet: about 9 % of its area
    assert 0.06 < h.boundary_excluded_fraction < 0.12
    assert res.to_dict()["mesh"]["boundary_excluded_area"] == h.boundary_excluded_area
