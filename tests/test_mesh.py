"""Mesh layer: loading, welding, operators."""

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from qifreport.errors import InputError
from qifreport.registration.mesh import (
    bending_operator,
    boundary_vertices,
    load_mesh,
    vertex_areas,
    weld,
)

from .conftest import shared_file


def test_weld_restores_watertight_closed_mesh():
    m = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    soup = m.vertices[m.faces].reshape(-1, 3)
    Fs = np.arange(len(soup)).reshape(-1, 3)
    assert not trimesh.Trimesh(soup, Fs, process=False).is_watertight
    V, F = weld(soup, Fs)
    assert len(V) == len(m.vertices)
    assert trimesh.Trimesh(V, F, process=False).is_watertight


def test_weld_tolerance_is_relative_to_diagonal():
    # a soup whose copies differ by 1e-8 of the diagonal still welds; 1e-4 does not
    m = trimesh.creation.box(extents=(100, 60, 20))
    soup = m.vertices[m.faces].reshape(-1, 3)
    Fs = np.arange(len(soup)).reshape(-1, 3)
    diag = np.linalg.norm([100, 60, 20])
    rng = np.random.default_rng(0)
    V1, _ = weld(soup + rng.uniform(-1, 1, soup.shape) * 1e-8 * diag, Fs)
    V2, _ = weld(soup + rng.uniform(-1, 1, soup.shape) * 1e-4 * diag, Fs)
    assert len(V1) == 8
    assert len(V2) > 8


def test_load_soup_stl_is_welded(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    path = tmp_path / "soup.stl"
    m.export(path)  # STL stores a triangle soup
    V, F = load_mesh(path)
    assert len(V) == len(m.vertices)
    assert trimesh.Trimesh(V, F, process=False).is_watertight


def test_load_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_mesh(tmp_path / "nope.stl")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\nend_header\n\x00")
    with pytest.raises(InputError):
        load_mesh(bad)


def test_operators_on_fandisk():
    V, F = load_mesh(shared_file("meshes/fandisk.off"))
    assert len(V) == 7229
    assert trimesh.Trimesh(V, F, process=False).is_watertight
    for energy in ("laplacian", "hessian"):
        ops = bending_operator(V, F, energy)
        Q = ops.Q
        assert abs(Q - Q.T).max() < 1e-9 * abs(Q).max()
        # constants are in the null space of both energies; random fields are not
        one = np.ones(len(V))
        assert np.abs(Q @ one).max() < 1e-8 * abs(Q).max()
        x = np.random.default_rng(0).normal(size=len(V))
        assert x @ (Q @ x) > 0
    ops = bending_operator(V, F, "laplacian")
    # cotangent Laplacian rows sum to zero; mass is one third of the incident area
    assert np.abs(np.asarray(ops.L.sum(axis=1))).max() < 1e-9
    area = trimesh.Trimesh(V, F, process=False).area
    assert ops.area.sum() == pytest.approx(area, rel=1e-12)
    assert sp.issparse(ops.M)


def test_hessian_energy_has_natural_boundary_conditions():
    # on a flat open plate, the Hessian energy vanishes for linear functions (no boundary
    # penalty), while L M^-1 L charges them at the boundary: the reason it is the default
    from qifreport.simulate.shapes import grid_triangles

    xs, ys = np.meshgrid(np.linspace(0, 60, 31), np.linspace(0, 40, 21))  # index j * nx + i
    V = np.c_[xs.ravel(), ys.ravel(), np.zeros(xs.size)]
    F = grid_triangles(31, 21)
    lin = V[:, 0] + 0.5 * V[:, 1]
    rough = np.random.default_rng(0).normal(size=len(V))
    for energy, expect_zero in (("hessian", True), ("laplacian", False)):
        Q = bending_operator(V, F, energy).Q
        ratio = (lin @ (Q @ lin)) / (rough @ (Q @ rough)) * (rough @ rough) / (lin @ lin)
        assert (ratio < 1e-9) == expect_zero, (energy, ratio)


def test_vertex_areas_and_boundary(shell):
    V, F = shell
    a = vertex_areas(V, F)
    assert a.sum() == pytest.approx(trimesh.Trimesh(V, F, process=False).area)
    b = boundary_vertices(F, len(V))
    assert 0 < b.sum() < 0.1 * len(V)
