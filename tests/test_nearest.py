"""TrackedNearest: the k-d tree's nearest vertices, exactly, at a fraction of its queries."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from qifreport.registration.icp import rigid_icp
from qifreport.registration.nearest import TrackedNearest


def _moving_points(rng: np.random.Generator, steps: int) -> list[np.ndarray]:
    """A cloud near a sphere that turns and drifts by ~0.05 mm per step (mesh edge ~1 mm)."""
    X = rng.normal(size=(5000, 3))
    X = 20.0 * X / np.linalg.norm(X, axis=1, keepdims=True) + rng.normal(0, 0.2, (5000, 3))
    out = []
    for s in range(steps):
        a = 0.002 * s
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        out.append(X @ R.T + 0.01 * s)
    return out


@pytest.mark.parametrize("k", [2, 3, 5])
def test_same_answers_as_the_tree_with_fewer_queries(k: int) -> None:
    rng = np.random.default_rng(3)
    V = trimesh.creation.icosphere(subdivisions=5, radius=20.0).vertices  # ~1.2 mm edges
    tree = cKDTree(V)
    nearest = TrackedNearest(tree, V, k=k)
    frames = _moving_points(rng, 40)
    for X in frames:
        d, i = nearest.query(X)
        d_ref, i_ref = tree.query(X)
        np.testing.assert_array_equal(i, i_ref)
        np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-12)
    # the first call asks for every point; the 39 small moves after it for few
    total = sum(len(X) for X in frames)
    assert len(frames[0]) <= nearest.queried < 0.35 * total


def test_a_jump_is_answered_by_the_tree() -> None:
    """Points moved farther than their candidates' reach are all asked again."""
    V = trimesh.creation.icosphere(subdivisions=4, radius=20.0).vertices
    tree = cKDTree(V)
    nearest = TrackedNearest(tree, V)
    X = V[::7] * 1.01
    nearest.query(X)
    Y = X @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T  # a quarter turn
    _, i = nearest.query(Y)
    np.testing.assert_array_equal(i, tree.query(Y)[1])
    assert nearest.queried == 2 * len(X)


class _EveryPointAsked:
    """The reference: the tree asked for every point on every call (rigid_icp before)."""

    def __init__(self, tree: cKDTree, V: np.ndarray) -> None:
        self.tree = tree

    def query(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.tree.query(X, workers=-1)


def test_rigid_icp_pose_unchanged_by_the_tracking(monkeypatch: pytest.MonkeyPatch) -> None:
    """The rigid fit with tracked nearest vertices ends on the pose of one with a tree query
    per iteration, to the last bit (a bent, noisy scan that does not converge in 60 steps)."""
    import qifreport.registration.icp as icp

    rng = np.random.default_rng(0)
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=30.0)
    V, N = np.asarray(mesh.vertices), np.asarray(mesh.vertex_normals)
    P = V[V[:, 2] > 0][::2].copy()
    P[:, 2] += 0.002 * P[:, 0] ** 2 + rng.normal(0, 0.02, len(P))  # compliance + noise
    a = np.deg2rad(2.0)
    R0 = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t0 = np.array([0.5, -0.3, 0.2])
    tree = cKDTree(V)
    tracked = rigid_icp(V, N, P, R0=R0, t0=t0, tree=tree)
    monkeypatch.setattr(icp, "TrackedNearest", _EveryPointAsked)
    plain = rigid_icp(V, N, P, R0=R0, t0=t0, tree=tree)
    assert tracked.iterations == plain.iterations > 10
    np.testing.assert_array_equal(tracked.R, plain.R)
    np.testing.assert_array_equal(tracked.t, plain.t)
    assert np.linalg.norm(tracked.t - t0) > 0.05  # it moved: the check compares real paths


def test_a_model_of_one_vertex_and_an_empty_scan() -> None:
    V = np.array([[1.0, 2.0, 3.0]])
    nearest = TrackedNearest(cKDTree(V), V)
    X = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 4.0]])
    for _ in range(2):
        d, i = nearest.query(X)
        np.testing.assert_array_equal(i, [0, 0])
        np.testing.assert_allclose(d, [np.sqrt(14.0), 1.0])
    d, i = TrackedNearest(cKDTree(V), V).query(np.zeros((0, 3)))
    assert d.shape == i.shape == (0,)
