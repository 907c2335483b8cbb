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
@pytest.mark.parametrize("radius", [0.8, 2.0])
def test_one_skin_normals_are_its_steps(name, radius):
    P = CLOUDS[name]()
    prior = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    Ns = orient_normals_consistent(P, pca_normals(P))[0]
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


@pytest.mark.parametrize("name", ["grid", "grid, repeated points", "wavy"])
def test_the_outward_normals_do_not_depend_on_the_first_guess_of_each_side(name):
    """The inspection's scan normals (:func:`one_skin_normals`, then each sheet's side by
    the scan's own wall evidence or a vote against the nominal,
    :func:`~qifreport.registration.deformable.result.orient_scan_normals`) are the same,
    every bit, whatever side each point was guessed on: the nominal's prior, its opposite,
    or a random side per point. So no estimate of the scan's normals is needed before
    the scan is seated."""
    from qifreport.registration.deformable.result import orient_scan_normals

    P = CLOUDS[name]()
    prior = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    if name.startswith("grid"):
        prior[P[:, 2] < 0.35] *= -1.0  # the lower skin's nominal faces down
    signs = np.random.default_rng(5).choice([-1.0, 1.0], len(P))[:, None]
    outs = []
    for guess in (prior, -prior, signs * prior):
        N, sheets = one_skin_normals(P, guess, prior, 2.0)
        outs.append(orient_scan_normals(P, N, P, prior, sheets=sheets))
    assert np.array_equal(outs[0], outs[1]) and np.array_equal(outs[0], outs[2])
    assert np.mean(np.einsum("ij,ij->i", outs[0], prior) > 0) > 0.99


@pytest.mark.parametrize("name", list(CLOUDS))
@pytest.mark.parametrize("radius", [0.5, 0.8, 2.0])
def test_the_refit_searches_beyond_its_radius_only_what_it_weighs(name, radius, monkeypatch):
    """The refit searches every point's few nearest neighbours, and farther ones only
    within its radius (:func:`~qifreport.registration.normals._nearest_within`): its normals
    and sheets are those of a search of all its neighbours, every bit, at a radius holding
    fewer points than the few (0.5 mm on the 0.7 mm grid), about as many, and more."""
    import qifreport.registration.normals as normals

    P = CLOUDS[name]()
    prior = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    Ns = orient_normals_consistent(P, pca_normals(P))[0]
    bounded = one_skin_normals(P, Ns, prior, radius)
    monkeypatch.setattr(
        normals,
        "_nearest_within",
        lambda tree, X, k, lead, radius: tree.query(X, k=k, workers=-1),
    )
    every = one_skin_normals(P, Ns, prior, radius)
    assert np.array_equal(bounded[0], every[0]) and np.array_equal(bounded[1], every[1])
    if name == "wavy":  # refitted: the normals follow the waves, not the prior
        assert np.mean(np.abs(np.einsum("ij,ij->i", bounded[0], prior)) < 0.999) > 0.5
