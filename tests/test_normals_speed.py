"""The scan normals measured with one neighbour query shared between their steps are the
normals of the steps measured each on its own, bit for bit, also where neighbours lie at
equal distances (a grid, repeated points), whose order a second query may not repeat."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from qifreport.registration.normals import (
    one_skin_normals,
    orient_normals_consistent,
    oriented_normals,
    pca_normals,
    refined_normals,
    wall_sides,
)


def _grid_wall() -> np.ndarray:
    """Two skins 0.7 mm apart on a 0.7 mm grid (every neighbourhood full of ties)."""
    g = np.stack(np.meshgrid(np.arange(30.0), np.arange(20.0), [0.0, 1.0]), -1).reshape(-1, 3)
    return 0.7 * g


def _wavy() -> np.ndarray:
    x = np.random.default_rng(3).uniform(0.0, 25.0, (2500, 2))
    return np.c_[x, 0.3 * np.sin(0.4 * x[:, 0])]


CLOUDS = {
    "grid": _grid_wall,
    "grid, repeated points": lambda: np.vstack([_grid_wall(), _grid_wall()[::7]]),
    "wavy": _wavy,
    "few": lambda: np.random.default_rng(4).normal(size=(9, 3)),
}


@pytest.mark.parametrize("name", list(CLOUDS))
def test_oriented_normals_are_its_steps(name):
    P = CLOUDS[name]()
    N, sheets = oriented_normals(P)
    N0, sheets0 = orient_normals_consistent(P, pca_normals(P))
    assert np.array_equal(N, N0)
    assert np.array_equal(sheets, sheets0)


@pytest.mark.parametrize("name", list(CLOUDS))
@pytest.mark.parametrize("radius", [0.8, 2.0])
def test_one_skin_normals_are_its_steps(name, radius):
    P = CLOUDS[name]()
    prior = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    Ns = oriented_normals(P)[0]
    N, sheets = one_skin_normals(P, Ns, prior, radius)
    tree = cKDTree(P)
    N0, sheets0 = orient_normals_consistent(
        P, refined_normals(P, Ns, prior, radius, tree), 10, tree
    )
    assert np.array_equal(N, N0)
    assert np.array_equal(sheets, sheets0)


def test_the_grid_walls_sides_are_found():
    P = _grid_wall()
    N = np.where(P[:, 2:] > 0.1, 1.0, -1.0) * np.array([0.0, 0.0, 1.0])
    assert np.all(wall_sides(P, N) == 1)
    assert np.all(wall_sides(P, -N) == -1)
