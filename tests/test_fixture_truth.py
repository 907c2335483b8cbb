"""The simulated physical fixture (:mod:`qifreport.simulate.fixture_truth`), the truth of
``bench/fixture.py``: what it must do whatever the product does.

A thin shell (2 mm PP sheet, 8 mm grid) at four corner clamps and two pins: a free state
made only of pushed clamp points is held back to nominal with the forces that pushed it; a
rigid motion is held back with no force; a plastic dent between the clamps stays; the
lowest elastic modes are mass-orthonormal and carry no rigid motion; an uneven wall is
within its stated spread.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.registration.mesh import vertex_normals
from qifreport.registration.restraint.elastic import MATERIALS, elastic_model
from qifreport.registration.restraint.sheet_solid import sheet_solid
from qifreport.simulate.fixture_truth import (
    FreeState,
    dent,
    hold,
    simulated_fixture,
    springback,
    uneven_wall,
)
from qifreport.simulate.shapes import rim_clamps, thin_shell


@pytest.fixture(scope="module")
def shell():
    V, F = thin_shell(spacing=8.0)
    N = vertex_normals(V, F)
    solid = sheet_solid(V, F, N, 2.0)
    scale = uneven_wall(solid.X[solid.T].mean(axis=1), 0.1, 60.0, np.random.default_rng(1))
    model = elastic_model(solid.X, solid.T, MATERIALS["pp"], stiffness_scale=scale)
    clamps, normals = rim_clamps(V, N, inset=6.0)
    fx = simulated_fixture(model, clamps, np.array(normals), pad_radius=9.0, n_modes=4)
    return V, N, fx, scale


def test_pushed_clamp_points_are_held_back_with_the_force_that_pushed_them(shell):
    V, _, fx, _ = shell
    lifts = np.zeros(len(fx.pads))
    lifts[[0, 3]] = [1.5, -0.8]  # A1 and A4 along their normals, mm
    held = hold(fx, FreeState(fx.D @ lifts), V)
    assert np.abs(held.u).max() < 1e-6  # back at nominal
    np.testing.assert_allclose(held.drives, -lifts, atol=1e-9)
    f = fx.G @ -lifts
    assert np.abs(f).max() > 0.01  # it took force (N) ...
    np.testing.assert_allclose(np.linalg.norm(held.forces, axis=1)[:4], np.abs(f[:4]), rtol=1e-9)


def test_a_rigid_motion_is_held_back_without_force(shell):
    V, _, fx, _ = shell
    X = fx.model.X
    w, t = np.array([0.002, -0.001, 0.003]), np.array([0.4, -0.2, 0.3])
    rigid = np.cross(w, X - X.mean(axis=0)) + t
    dofs = np.zeros(fx.model.n_dofs)
    dofs[fx.model.vertex_dofs] = rigid
    # the mid-edge nodes move with their edge (a rigid field is linear)
    dofs[fx.model.edge_dofs] = 0.5 * (rigid[fx.model.edges[:, 0]] + rigid[fx.model.edges[:, 1]])
    held = hold(fx, FreeState(dofs), V)
    assert np.abs(held.u).max() < 1e-6
    assert held.force.max() < 1e-6


def test_a_dent_between_the_clamps_stays_and_a_flange_springback_is_a_rotation(shell):
    V, N, fx, _ = shell
    c = int(np.argmin(np.linalg.norm(V[:, :2], axis=1)))
    d = dent(V[c], N[c], -0.8, 10.0)
    held = hold(fx, FreeState(np.zeros(fx.model.n_dofs), (d,)), V)
    depth = held.u[c] @ N[c]
    assert depth == pytest.approx(-0.8, abs=0.02)  # the clamps are far: it stays
    s = springback(np.array([50.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([1, 0, 0]), 0.01)
    P = np.array([[40.0, 0.0, 0.0], [60.0, 0.0, 0.0], [70.0, 5.0, 2.0]])
    np.testing.assert_allclose(s(P), [[0, 0, 0], [0, 0, -0.1], [0.02, 0, -0.2]], atol=1e-12)


def test_the_modes_are_elastic_and_the_wall_uneven_within_its_spread(shell):
    _, _, fx, scale = shell
    M = fx.model.mass()
    G = fx.modes.T @ M @ fx.modes
    np.testing.assert_allclose(G, np.eye(len(fx.omega2)), atol=1e-8)
    assert np.all(np.diff(fx.omega2) >= 0) and fx.omega2[0] > 0
    # no rigid motion in them: orthogonal (in M) to a translation
    X = fx.model.X
    trans = np.zeros(fx.model.n_dofs)
    trans[fx.model.vertex_dofs[:, 0]] = 1.0
    trans[fx.model.edge_dofs[:, 0]] = 1.0
    assert np.abs(fx.modes.T @ M @ trans).max() < 1e-6 * np.sqrt(trans @ M @ trans)
    t = np.cbrt(scale)
    assert 0.9 - 1e-12 <= t.min() < 0.95 and 1.05 < t.max() <= 1.1 + 1e-12
    assert len(X)  # the model exists
