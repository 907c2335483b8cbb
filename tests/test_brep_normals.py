"""The B-rep's exact normals at the triangle corners (:mod:`qifreport.step.normals`) and the
scan points' distance to the curved surface read with them
(:func:`qifreport.metrology.deviation.surface.surface_distance`).

A 20 mm cube with its four vertical edges filleted (R 4 mm), meshed coarsely by gmsh (5 mm
edges, 0.5 mm chord height, 46 degrees a segment: two per quarter turn), and a perfect scan
of it sampled on the exact B-rep (:func:`qifreport.simulate.brep_scan.perfect_scan`, no
noise): its points lie on the surface, so their distances must read 0. With the mesh's own
corner normals the fillets' points read tens of micrometres (a corner normal averaged from
one side only is off by half a segment); with the B-rep's they read under 5 um. Also: the
normals turned with a rigidly moved mesh
(:func:`qifreport.metrology.deviation.surface.follow_triangles`) are the moved normals.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.deviation.closest import closest_points
from qifreport.metrology.deviation.surface import (
    corner_normals,
    follow_triangles,
    point_faces,
    surface_distance,
)


@pytest.fixture(scope="module")
def filleted_cube(tmp_path_factory):
    """The cube written to STEP by cadquery and read back by the product's reader."""
    import cadquery as cq

    from qifreport.simulate.brep_scan import perfect_scan
    from qifreport.step.gmsh_mesh import gmsh_tessellate
    from qifreport.step.normals import corner_normals_exact
    from qifreport.step.reader import read_step

    path = tmp_path_factory.mktemp("fillet") / "cube.step"
    cq.exporters.export(cq.Workplane().box(20, 20, 20).edges("|Z").fillet(4.0), str(path))
    part = read_step(path, pmi=False)
    shape, faces = part.shape, part.faces
    mesh = gmsh_tessellate(shape, faces, max_edge=5.0, deflection=0.5, angle=0.8)
    exact = corner_normals_exact(faces, mesh.V, mesh.F, mesh.face_id)
    scan, _ = perfect_scan(shape, faces, views=6, noise=0.0, points=40_000)
    return mesh, exact, scan, faces


def test_exact_normals_are_the_surface_normals(filleted_cube):
    mesh, exact, _, faces = filleted_cube
    assert not np.isnan(exact).any()
    assert np.allclose(np.linalg.norm(exact, axis=2), 1.0)
    # on the planar faces every corner's normal is the face's axis; on a fillet it is
    # horizontal and radial from the fillet's axis (the corner's offset from the nearest
    # vertical cube edge inset by R, in the xy plane)
    V, F = mesh.V, mesh.F
    P = V[F]  # (f, 3, 3) corner positions
    flat = np.abs(exact).max(axis=2) > 1 - 1e-9
    curved = ~flat
    assert curved.any() and flat.any()
    n = exact[curved]
    assert np.abs(n[:, 2]).max() < 1e-9
    axis = np.sign(P[curved][:, :2]) * 6.0  # fillet axes at (+/-6, +/-6)
    radial = P[curved][:, :2] - axis
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert np.abs(n[:, :2] - radial).max() < 1e-6


def test_points_on_a_fillet_read_zero_with_the_brep_normals(filleted_cube):
    """On the fillets' points (those whose closest triangle is on their own B-rep face:
    near a tangent edge of so coarse a mesh, a few dozen fall on the plane's chord and read
    its distance), the distance read with the mesh's normals is off by tens of micrometres
    (measured: p99 56 um), with the B-rep's by about 1 um."""
    mesh, exact, scan, _ = filleted_cube
    V, F, fid = mesh.V, mesh.F, mesh.face_id
    C, cface, pdev = closest_points(V, F, scan.P)
    fillets = np.unique(fid[np.abs(exact).max(axis=(1, 2)) < 1 - 1e-9])
    own = point_faces(cface, fid) == scan.face
    on_fillet = np.isin(scan.face, fillets) & own
    assert on_fillet.sum() > 3000 and own.mean() > 0.99
    with_mesh = np.abs(surface_distance(V, F, C, cface, pdev, fid)[on_fillet])
    with_brep = np.abs(surface_distance(V, F, C, cface, pdev, fid, exact)[on_fillet])
    assert with_brep.max() < 0.005
    assert np.percentile(with_mesh, 99) > 0.02 > 10 * np.percentile(with_brep, 99)


def test_points_nearer_another_faces_chord_read_their_own_surface(filleted_cube):
    """The fillets' points whose closest chord is the plane's (near the tangent edge) read
    the plane's distance, up to 0.07 mm; with the points given, the faces around the
    closest chord are tried and all but one or two points of the scan read under 5 um
    (measured: one, 15 um, at a corner where three faces meet and its own face's chord
    shares no vertex with the closest one)."""
    mesh, exact, scan, _ = filleted_cube
    V, F, fid = mesh.V, mesh.F, mesh.face_id
    C, cface, pdev = closest_points(V, F, scan.P)
    stray = point_faces(cface, fid) != scan.face
    assert stray.sum() >= 20
    chord = np.abs(surface_distance(V, F, C, cface, pdev, fid, exact))
    assert chord[stray].max() > 0.03
    tried = np.abs(surface_distance(V, F, C, cface, pdev, fid, exact, scan.P))
    assert (tried > 0.005).sum() <= 2 and tried.max() < 0.02


def test_normals_follow_a_moved_mesh(filleted_cube):
    mesh, exact, _, _ = filleted_cube
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))
    moved = follow_triangles(exact, mesh.V, mesh.V @ R.T + 5.0, mesh.F)
    assert np.abs(moved - exact @ R.T).max() < 1e-9
    # and the mesh's own normals are not what the B-rep says at a fillet's edge (about
    # half a segment: the mesh has two per quarter turn)
    own = corner_normals(mesh.V, mesh.F, mesh.face_id)
    turn = np.degrees(np.arccos(np.clip(np.einsum("fij,fij->fi", own, exact), -1, 1)))
    assert turn.max() > 10.0
