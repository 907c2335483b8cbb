"""Faster paths that must give the same numbers as the slower ones (issue 23).

:func:`qifreport.registration.pose.descriptors.farthest_points` updates only the points within
the current covering radius of each new sample. The reference here measures every point at
every step, as the definition does; the two must agree index for index, and a prefix of a
longer run must be the shorter run (``prepare_model`` takes its keypoints and its coarse
vertices from one run). :func:`~qifreport.registration.pose.descriptors.geodesic_balls` with the
nodes' tree runs Dijkstra on the nodes near each group of sources; its balls must equal the
whole graph's, entry for entry. The scan normals' spanning tree is built from each edge
once (the upper triangle of the symmetric graph): Kruskal's stable order meets the edges in
the same order, so the tree must be the one of the whole matrix, also where weights tie.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial import cKDTree

from qifreport.registration.pose.descriptors import (
    farthest_points,
    geodesic_balls,
    knn_graph,
    mesh_graph,
)


def full_sweep(X: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """Farthest-point sample by definition: every point's distance updated at every step."""
    n = len(X)
    out = np.empty(k, dtype=np.int64)
    out[0] = np.random.default_rng(seed).integers(n)
    d = np.full(n, np.inf)
    for i in range(k):
        if i:
            out[i] = int(np.argmax(d))
        p = X[out[i]]
        dd = (X[:, 0] - p[0]) ** 2
        dd += (X[:, 1] - p[1]) ** 2
        dd += (X[:, 2] - p[2]) ** 2
        d = np.minimum(d, dd)
    return out


def wavy_sheet(n: int, seed: int) -> np.ndarray:
    """Points on a 600 x 400 mm sheet with a 5 mm wave (a panel's spread of distances)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 600, n), rng.uniform(0, 400, n)
    return np.c_[u, v, 5.0 * np.sin(u / 30.0)]


@pytest.mark.parametrize("seed", [0, 3])
def test_same_sample_as_the_full_sweep(seed):
    X = wavy_sheet(20_000, seed)
    # clustered points too: distances that tie and balls that hold most of the cloud
    X[:2000] = np.round(X[:2000] / 50.0) * 50.0
    got = farthest_points(X, 1500, seed=seed)
    ref = full_sweep(X, 1500, seed=seed)
    assert np.array_equal(got, ref)
    # a sample covers the sheet: its covering radius is a small share of the diagonal
    d, _ = cKDTree(X[got]).query(X)
    assert d.max() < 0.05 * np.linalg.norm(X.max(0) - X.min(0))


def test_a_shorter_run_is_a_prefix_and_small_clouds_are_whole():
    X = wavy_sheet(5000, 1)
    long = farthest_points(X, 3000)
    assert np.array_equal(farthest_points(X, 800), long[:800])
    assert np.array_equal(farthest_points(X[:100], 100), np.arange(100))
    # a one-vertex cloud: prepare_model asks for min(k, n - 1) = 0 samples, then all of it
    assert len(farthest_points(X[:1], 0)) == 0
    assert np.array_equal(farthest_points(X[:1], 2000), [0])


@pytest.mark.parametrize("graph", ["mesh", "knn"])
def test_geodesic_balls_near_the_sources_equal_the_whole_graphs(graph):
    sphere = trimesh.creation.icosphere(5, radius=150.0)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    tree = cKDTree(V)
    G = mesh_graph(V, F) if graph == "mesh" else knn_graph(V, tree=tree)
    sources = farthest_points(V, 300, tree=tree)
    for radius in (20.0, 60.0):  # balls of ~40 and ~340 of the 10k nodes
        whole = geodesic_balls(G, sources, radius, chunk=32)
        near = geodesic_balls(G, sources, radius, chunk=32, tree=tree)
        assert len(whole.rows) > 30 * len(sources)
        for name in ("sources", "rows", "cols", "g2"):
            assert np.array_equal(getattr(near, name), getattr(whole, name)), name


@pytest.mark.parametrize("levels", [3, 1000])  # many ties, few
def test_spanning_tree_of_the_upper_triangle_is_the_whole_graphs(levels):
    rng = np.random.default_rng(levels)
    n = 3000
    i, j = rng.integers(0, n, (2, 6 * n))
    w = 1.0 + rng.integers(0, levels, len(i)) / levels
    G = sp.coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    G = G.maximum(G.T)
    G.setdiag(0)
    G.eliminate_zeros()
    whole = minimum_spanning_tree(G)
    upper = minimum_spanning_tree(sp.triu(G, format="csr"))
    assert whole.nnz > n // 2
    assert (whole != upper).nnz == 0
    assert np.array_equal(whole.indices, upper.indices)


def test_point_groups_of_nested_sets_reuse_the_links_and_equal_a_fresh_grouping():
    from qifreport.metrology.acceptance.point_regions import ScanSamples, linked_groups

    rng = np.random.default_rng(5)
    P = np.c_[rng.uniform(0, 100, (20_000, 2)), rng.normal(0, 0.01, 20_000)]
    s = ScanSamples(
        P=P,
        value=np.zeros(len(P)),
        U=np.zeros(len(P)),
        vertex=np.zeros(len(P), dtype=np.int64),
        spacing=0.7,
        tree=cKDTree(P),
        spike=np.zeros(len(P), dtype=bool),
    )
    score = rng.uniform(0, 1, len(P))
    wide = np.flatnonzero(score > 0.3)  # the band reduced: the most points out
    asked = []
    for sel in (wide, np.flatnonzero(score > 0.5), np.flatnonzero(score > 0.8), wide[::-1]):
        got = s.groups(sel, 0.45)
        asked.append(s._links[1] is wide)
        ref = linked_groups(P[sel], 0.45)
        assert np.array_equal(got, ref)
        assert len(np.unique(ref)) > 10  # many groups: a test of the numbering too
    assert asked == [True, True, True, True]  # the subsets (and a reordering) reused it
    other = np.flatnonzero(score < 0.2)  # not a subset: grouped afresh
    assert np.array_equal(s.groups(other, 0.45), linked_groups(P[other], 0.45))
    assert s._links[1] is not wide


def test_unique_rows_are_numpys():
    from qifreport.registration.arrays import unique_rows

    rng = np.random.default_rng(2)
    a = np.round(rng.normal(size=(50_000, 3)), 1)  # many equal rows and equal columns
    a[::7, 2] = -0.0
    np.testing.assert_array_equal(unique_rows(a), np.unique(a, axis=0))
    assert len(unique_rows(a)) < len(a)
    np.testing.assert_array_equal(unique_rows(a[:1]), a[:1])
