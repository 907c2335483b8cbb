"""Simulation toolkit: shapes, free-state generators, virtual scanner, defects."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.registration.mesh import (
    bending_operator,
    boundary_vertices,
    bounding_diagonal,
    vertex_areas,
    vertex_normals,
)
from qifreport.simulate.defects import gaussian_bump
from qifreport.simulate.deform import (
    MODES,
    analytic_deformation,
    biharmonic_deformation,
    clamp_handles,
    pca_frame,
)
from qifreport.simulate.scanner import ScanSpec, aim_views, virtual_scan
from qifreport.simulate.shapes import fandisk, shell_height, thin_shell

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FANDISK = SHARED / "meshes" / "fandisk.off"


def _require(path: Path) -> None:
    if not path.is_file():
        msg = f"reference file missing: {path}"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)


@pytest.fixture(scope="module")
def shell():
    return thin_shell()


@pytest.fixture(scope="module")
def fandisk_mesh():
    _require(FANDISK)
    return fandisk(str(FANDISK))


# ---------------------------------------------------------------------------- shapes


def test_thin_shell_size_curvature_orientation(shell):
    V, F = shell
    assert 8000 <= len(V) <= 9000
    ext = V.max(axis=0) - V.min(axis=0)
    np.testing.assert_allclose(ext[:2], [170.0, 110.0], atol=1e-9)
    assert 15.0 <= ext[2] <= 40.0
    np.testing.assert_allclose(V[:, :2].min(axis=0) + V[:, :2].max(axis=0), 0.0, atol=1e-9)
    # discrete mean curvature |H| = |L V| / (2 A) at interior vertices
    ops = bending_operator(V, F)
    H = np.linalg.norm(ops.L @ V, axis=1) / (2.0 * ops.area)
    interior = ~boundary_vertices(F, len(V))
    assert 3e-3 <= np.median(H[interior]) <= 8e-3
    # single-sided, consistently oriented towards +z
    N = vertex_normals(V, F)
    assert N[:, 2].min() > 0.5 and N[:, 2].mean() > 0.9
    # not a symmetric bowl: mirroring in x or y changes the height by millimetres
    x, y = V[:, 0], V[:, 1]
    assert np.abs(shell_height(-x, y) - V[:, 2]).max() > 2.0
    assert np.abs(shell_height(x, -y) - V[:, 2]).max() > 2.0


def test_thin_shell_triangles_regular_and_unbiased(shell):
    V, F = shell
    e = [V[F[:, (k + 1) % 3]] - V[F[:, k]] for k in range(3)]
    cosang = [
        np.einsum("ij,ij->i", -e[k - 1], e[k])
        / (np.linalg.norm(e[k - 1], axis=1) * np.linalg.norm(e[k], axis=1))
        for k in range(3)
    ]
    min_angle = np.degrees(np.arccos(np.clip(np.max(cosang, axis=0), -1, 1)))
    assert min_angle.min() > 35.0  # right isosceles (45 deg), sheared by the slope at corners
    # diagonal directions in xy: half go one way, half the other
    d = np.concatenate(e)[:, :2]
    diag = d[(np.abs(d[:, 0]) > 1e-6) & (np.abs(d[:, 1]) > 1e-6)]
    frac = np.mean(np.sign(diag[:, 0]) == np.sign(diag[:, 1]))
    assert abs(frac - 0.5) < 0.02


def test_fandisk_scaled_and_subdivided(fandisk_mesh):
    V, F = fandisk_mesh
    assert bounding_diagonal(V) == pytest.approx(100.0, abs=1e-9)
    np.testing.assert_allclose(V.min(axis=0) + V.max(axis=0), 0.0, atol=1e-9)
    assert len(V) == 28910 and len(F) == 4 * 14454
    assert F.dtype == np.int64 and V.dtype == np.float64


# ---------------------------------------------------------------------------- PCA / handles


def test_pca_frame_recovers_rotated_axes():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(4000, 3)) * [30.0, 10.0, 2.0]
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    V = X @ Q.T + [5.0, -2.0, 7.0]
    c, U = pca_frame(V)
    np.testing.assert_allclose(c, V.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(np.abs(U.T @ Q), np.eye(3), atol=0.02)
    assert np.linalg.det(U) == pytest.approx(1.0)
    # area weights move the centroid
    w = np.where(V @ Q[:, 0] > 0, 3.0, 1.0)
    cw, _ = pca_frame(V, w)
    np.testing.assert_allclose(cw, (w @ V) / w.sum(), atol=1e-12)


def test_clamp_handles_corners_edges_anchor(shell):
    V, F = shell
    H = clamp_handles(V, F, include_edges=True)
    assert H.kind == ["corner"] * 4 + ["edge"] * 4 + ["anchor"]
    c, U = pca_frame(V, vertex_areas(V, F))
    xy = (H.centers - c) @ U[:, :2]
    corners, edges_, anchor = xy[:4], xy[4:8], xy[8]
    # corners counter-clockwise: positive shoelace area close to the full rectangle
    x, y = corners[:, 0], corners[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert area == pytest.approx(170.0 * 110.0, rel=0.05)
    # corner seeds at the rectangle's corners, i.e. at the shell's corner vertices
    shell_corners = np.array([[sx * 85.0, sy * 55.0] for sx in (-1, 1) for sy in (-1, 1)])
    d = np.linalg.norm(H.centers[:4, None, :2] - shell_corners[None], axis=2).min(axis=1)
    assert d.max() < 1e-9
    # edges at +u1, +u2, -u1, -u2
    along = np.abs(edges_[:, 0]) > np.abs(edges_[:, 1])
    assert along.tolist() == [True, False, True, False]
    assert edges_[0, 0] > 0 and edges_[1, 1] > 0 and edges_[2, 0] < 0 and edges_[3, 1] < 0
    assert np.linalg.norm(anchor) < 2.0  # vertex nearest the centroid (grid pitch 1.5 mm)
    # default radius 1.5 % of the diagonal; every group nonempty and within it
    r = 0.015 * bounding_diagonal(V)
    for g, ctr in zip(H.groups, H.centers, strict=True):
        assert len(g) >= 1 and np.linalg.norm(V[g] - ctr, axis=1).max() <= r
    assert len(H.indices) == len(np.unique(np.concatenate(H.groups)))


# ---------------------------------------------------------------------------- biharmonic


def _check_minimiser(V, F, D, energy="laplacian"):
    """Constraints exact and the free block stationary: Q_ff d_f + Q_fh g = 0."""
    h = D.handles.indices
    assert np.abs(D.d[h] - D.g).max() < 1e-8
    Q = bending_operator(V, F, energy).Q
    r = Q @ D.d
    free = np.ones(len(V), dtype=bool)
    free[h] = False
    assert np.abs(r[free]).max() < 1e-8 * np.abs(Q @ np.where(free[:, None], 0.0, D.d)).max()


def test_bend_reaches_corners_anchor_fixed(shell):
    V, F = shell
    a = 0.02 * bounding_diagonal(V)
    D = biharmonic_deformation(V, F, a, {"bend": 1.0})
    _check_minimiser(V, F, D)
    N = vertex_normals(V, F)
    assert D.handles.kind == ["corner"] * 4 + ["anchor"]
    for g, kind in zip(D.handles.groups, D.handles.kind, strict=True):
        if kind == "corner":
            # the clamp translates its patch rigidly along the patch's mean normal
            nc = N[g].sum(axis=0) / np.linalg.norm(N[g].sum(axis=0))
            np.testing.assert_allclose(D.d[g], np.tile(a * nc, (len(g), 1)), atol=1e-10)
            assert np.ptp(D.d[g], axis=0).max() < 1e-10
        else:
            assert np.abs(D.d[g]).max() == 0.0
    # a bow, not a translation: the field grows from the anchor towards the corners
    dz = D.d[:, 2]
    r = np.linalg.norm(V[:, :2] - D.handles.centers[-1, :2], axis=1)
    assert dz[r > 80].mean() > 0.5 * a and abs(dz[r < 10].mean()) < 0.1 * a
    assert np.linalg.norm(D.d, axis=1).max() < 1.5 * a


def test_twist_and_saddle_sign_patterns(shell):
    V, F = shell
    a = 3.0
    D = biharmonic_deformation(V, F, a, {"twist": 1.0})
    _check_minimiser(V, F, D)
    z = [D.d[g, 2].mean() for g in D.handles.groups[:4]]
    assert np.sign(z).tolist() == [1, -1, 1, -1] and min(np.abs(z)) > 0.8 * a
    # twist ~ xi1 * xi2 (corner (-u1, -u2) is +1): quadrant signs follow x * y
    q = (np.abs(V[:, 0]) > 40) & (np.abs(V[:, 1]) > 25)
    assert np.mean(np.sign(D.d[q, 2]) == np.sign(V[q, 0] * V[q, 1])) > 0.95

    S = biharmonic_deformation(V, F, a, {"saddle": 1.0})
    _check_minimiser(V, F, S)
    assert S.handles.kind == ["edge"] * 4 + ["anchor"]  # corners left free
    z = [S.d[g, 2].mean() for g in S.handles.groups[:4]]
    assert np.sign(z).tolist() == [1, -1, 1, -1] and min(np.abs(z)) > 0.8 * a
    # anticlastic along the axes: up at the x ends, down at the y ends
    assert S.d[np.abs(V[:, 0]) > 80, 2].mean() > 0 > S.d[np.abs(V[:, 1]) > 50, 2].mean()


def test_mode_weights_and_hessian_energy():
    V, F = thin_shell(spacing=3.0)  # coarse: the Hessian energy is slower to assemble
    D = biharmonic_deformation(V, F, 2.0, {"bend": 1.0, "twist": 0.5}, energy="hessian")
    np.testing.assert_allclose(D.signs, [1.5, 0.5, 1.5, 0.5, 0.0])
    _check_minimiser(V, F, D, energy="hessian")
    assert set(MODES) == {"bend", "twist", "saddle"}
    with pytest.raises(ValueError):
        biharmonic_deformation(V, F, 1.0, {"wobble": 1.0})


def test_fandisk_biharmonic_and_scan(fandisk_mesh):
    """The generator and scanner on the fandisk (their speed: bench/io_speed.py)."""
    V, F = fandisk_mesh
    D = biharmonic_deformation(V, F, 2.0, {"bend": 1.0, "twist": 0.5})
    assert np.abs(D.d[D.handles.indices] - D.g).max() < 1e-8
    assert np.isfinite(D.d).all() and len(D.handles.groups) == 5
    S = virtual_scan(V + D.d, F, ScanSpec(views=2, seed=1))
    assert len(S.P) > 10000 and set(np.unique(S.view)) == {0, 1}
    # a closed solid: aimed along -u3, two opposing tilted views
    dirs = aim_views(V, F, 2, 25.0)
    assert np.degrees(np.arccos(dirs[0] @ dirs[1])) == pytest.approx(50.0, abs=1e-6)


# ---------------------------------------------------------------------------- analytic


def test_analytic_deformation(shell):
    V, F = shell
    N = vertex_normals(V, F)
    d = analytic_deformation(V, F, 2.5)
    assert np.linalg.norm(d, axis=1).max() == pytest.approx(2.5, rel=1e-12)
    assert np.abs(np.cross(d, N)).max() < 1e-12  # along the normal
    f = np.einsum("ij,ij->i", d, N)
    assert abs(f.mean()) > 0.1  # not zero-mean
    np.testing.assert_array_equal(d, analytic_deformation(V, F, 2.5))
    d1, d2 = analytic_deformation(V, F, 2.5, seed=1), analytic_deformation(V, F, 2.5, seed=2)
    assert np.linalg.norm(d1, axis=1).max() == pytest.approx(2.5, rel=1e-12)
    assert np.abs(d1 - d2).max() > 0.5
    np.testing.assert_array_equal(d1, analytic_deformation(V, F, 2.5, seed=1))
    # not a minimiser of the bending energy with its own values as constraints
    D = biharmonic_deformation(V, F, 1.0)
    Q = bending_operator(V, F).Q
    free = np.ones(len(V), dtype=bool)
    free[D.handles.indices] = False
    assert np.abs((Q @ d)[free]).max() > 1e3 * 1e-8 * np.abs(Q @ d).max()


# ---------------------------------------------------------------------------- scanner


def test_scan_deterministic_from_seed(shell):
    V, F = shell
    a = virtual_scan(V, F, ScanSpec(views=2, seed=5))
    b = virtual_scan(V, F, ScanSpec(views=2, seed=5))
    c = virtual_scan(V, F, ScanSpec(views=2, seed=6))
    np.testing.assert_array_equal(a.P, b.P)
    np.testing.assert_array_equal(a.vertex, b.vertex)
    assert len(a.P) != len(c.P) or np.abs(a.P - c.P).max() > 1e-3
    assert a.vertex.dtype == np.int64 and a.P.shape == a.true_normals.shape
    # the open shell is seen from its front (+z side), so every view looks down
    assert (a.directions[:, 2] < -0.8).all()
    # generator vertex is a vertex of the hit triangle, close to the sample
    assert np.linalg.norm(a.P - V[a.vertex], axis=1).max() < 1.5


def test_range_noise_along_view_direction(shell):
    V, F = shell
    sigma = 0.05
    clean = virtual_scan(V, F, ScanSpec(views=2, noise=0.0, thinning=0.1, seed=9))
    noisy = virtual_scan(V, F, ScanSpec(views=2, noise=sigma, thinning=0.1, seed=9))
    assert len(clean.P) == len(noisy.P) > 20000
    np.testing.assert_array_equal(clean.vertex, noisy.vertex)
    v = noisy.directions[noisy.view]
    diff = noisy.P - clean.P
    eta = np.einsum("ij,ij->i", diff, v)
    assert np.abs(diff - eta[:, None] * v).max() < 1e-9  # purely along the view direction
    assert abs(eta.std() / sigma - 1.0) < 0.1
    assert abs(eta.mean()) < 0.1 * sigma
    # thinning removes the requested fraction
    full = virtual_scan(V, F, ScanSpec(views=2, noise=0.0, thinning=0.0, seed=9))
    assert len(clean.P) / len(full.P) == pytest.approx(0.9, abs=0.01)


def test_clamp_dropout(shell):
    V, F = shell
    H = clamp_handles(V, F)
    radius = 8.0
    spec = ScanSpec(views=2, clamp_centers=H.centers, seed=2)
    full = virtual_scan(V, F, spec)
    spec.dropout_radius = radius
    cut = virtual_scan(V, F, spec)
    dist = lambda P: np.linalg.norm(P[:, None] - H.centers[None], axis=2).min(axis=1)  # noqa: E731
    assert dist(cut.P).min() > radius
    assert (dist(full.P) <= radius).sum() > 100  # the dropout did remove something


def test_grazing_cutoff_on_box():
    box = trimesh.creation.box(extents=(20.0, 20.0, 20.0))
    V, F = np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)
    t = np.radians(10.0)  # the -x face is seen at |n . v| = sin 10 deg = 0.17
    v = np.array([[np.sin(t), 0.0, -np.cos(t)]])
    base = dict(pixel=0.5, noise=0.0, thinning=0.0, directions=v)
    strict = virtual_scan(V, F, ScanSpec(grazing=0.2, **base))
    loose = virtual_scan(V, F, ScanSpec(grazing=0.1, **base))
    side = lambda s: np.isclose(s.P[:, 0], -10.0) & (s.P[:, 2] < 9.99)  # noqa: E731
    assert side(strict).sum() == 0
    assert side(loose).sum() > 200  # 20 x 20 x sin 10 deg / 0.5^2 = 278
    assert np.allclose(strict.P[:, 2], 10.0)  # only the top face
    down = virtual_scan(V, F, ScanSpec(**{**base, "directions": [[0.0, 0.0, -1.0]]}))
    assert np.allclose(down.P[:, 2], 10.0) and len(down.P) == pytest.approx(1600, rel=0.06)


def test_depth_buffer_sphere_front_hemisphere_only():
    r, pixel = 10.0, 0.25
    ball = trimesh.creation.icosphere(subdivisions=4, radius=r)
    V, F = np.asarray(ball.vertices, float), np.asarray(ball.faces, np.int64)
    spec = ScanSpec(
        directions=[[0.0, 0.0, -1.0]], pixel=pixel, noise=0.0, thinning=0.0, grazing=0.0
    )
    S = virtual_scan(V, F, spec)
    assert S.P[:, 2].min() > -0.05 * r  # nothing from the back hemisphere
    assert (S.true_normals[:, 2] > 0).mean() > 0.99
    # one sample per pixel of the projected disk (an all-hits raster would give twice this)
    assert len(S.P) == pytest.approx(np.pi * r**2 / pixel**2, rel=0.03)


# ---------------------------------------------------------------------------- defects


def test_gaussian_bump_width_convention(shell):
    a, sigma = 0.8, 5.0
    P = np.array([[0.0, 0, 0], [sigma, 0, 0], [0, 2 * sigma, 0], [0, 0, 30.0]])
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    b = gaussian_bump(P, n, P[0], a, sigma)
    np.testing.assert_allclose(b[:, 2], a * np.exp([0.0, -1.0, -4.0, -36.0]), rtol=1e-12)
    assert np.abs(b[:, :2]).max() == 0.0
    V, F = shell
    N = vertex_normals(V, F)
    i = int(np.argmin(np.linalg.norm(V[:, :2] - [20.0, 10.0], axis=1)))
    delta = gaussian_bump(V, N, V[i], -0.5, 7.0)
    np.testing.assert_allclose(delta[i], -0.5 * N[i], atol=1e-15)
    assert np.linalg.norm(delta, axis=1).max() == pytest.approx(0.5)


def test_the_elastic_free_state_of_a_square_plate_is_its_twist():
    """The lowest elastic mode of a free square plate is the twist w ~ x y (Leissa, free
    plate, nu ~ 0.3): with one mode the generator must give that shape at the asked peak."""
    from qifreport.simulate.deform import elastic_deformation
    from qifreport.simulate.shapes import grid_triangles

    n = 17
    x, y = np.meshgrid(np.linspace(-50, 50, n), np.linspace(-50, 50, n), indexing="ij")
    V = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    F = grid_triangles(n, n)
    d = elastic_deformation(V, F, 1.5, n_modes=1, thickness=2.0)
    assert np.linalg.norm(d, axis=1).max() == pytest.approx(1.5, rel=1e-9)
    w = d[:, 2]
    twist = V[:, 0] * V[:, 1]
    r = np.corrcoef(w, twist)[0, 1]
    assert abs(r) > 0.98, r  # a bending mode (x^2 - y^2 saddle or a bend) correlates ~0
    assert np.abs(d[:, :2]).max() < 0.1 * np.abs(w).max()  # a plate mode moves out of plane


def test_the_hat_bracket_is_one_solid_of_its_section_and_wall():
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    from qifreport.simulate.shapes import HAT_LENGTH, HAT_WALL, hat_bracket, hat_profile

    S = hat_profile()
    k = len(S) // 2
    upper, lower = S[:k], S[k:][::-1]
    for i in range(k - 1):  # every segment of each skin lies one wall from the other's
        t = upper[i + 1] - upper[i]
        nrm = np.array([-t[1], t[0]]) / np.linalg.norm(t)
        assert abs((upper[i] - lower[i]) @ nrm) == pytest.approx(HAT_WALL, abs=1e-9)
    x, z = S[:, 0], S[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(z, -1)) - np.dot(z, np.roll(x, -1)))
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(hat_bracket(), props)
    assert props.Mass() == pytest.approx(area * HAT_LENGTH, rel=1e-9)
    # the mid-line: flanges 2 x 20, walls 2 x |(10, 28)|, top 2 x 21 + 10, bead sides 2 x 5
    assert area == pytest.approx(HAT_WALL * (40 + 2 * np.hypot(10, 28) + 52 + 10), rel=1e-3)
