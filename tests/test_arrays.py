"""unique_sorted is np.unique; the adjacency and edge uses are the unique edges' (faster)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import adjacency, edge_uses, edges


@settings(max_examples=200, deadline=None)
@given(
    st.one_of(
        arrays(np.int64, st.integers(0, 300), elements=st.integers(-(2**62), 2**62)),
        arrays(np.int32, st.tuples(st.integers(0, 20), st.integers(1, 3))),
        arrays(np.uint8, st.integers(0, 50)),
        arrays(np.float64, st.integers(0, 50)),
    )
)
def test_unique_sorted_is_numpy_unique(a: np.ndarray) -> None:
    got, want = unique_sorted(a), np.unique(a)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


def test_adjacency_is_the_unique_edges() -> None:
    """On a sphere, a mesh with a degenerate triangle and a non-manifold fan."""
    sphere = trimesh.creation.icosphere(4)
    cases = [np.asarray(sphere.faces), np.array([[0, 1, 2], [2, 1, 2], [3, 4, 1], [1, 4, 5]])]
    cases.append(np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]]))  # three triangles on one edge
    for F in cases:
        n = int(F.max()) + 1
        E = edges(F)
        half = sp.coo_matrix((np.ones(len(E), dtype=bool), (E[:, 0], E[:, 1])), shape=(n, n))
        want = (half + half.T).tocsr()
        got = adjacency(F, n)
        assert got.dtype == bool and got.has_canonical_format
        assert (got != want).nnz == 0 and got.nnz == want.nnz


def test_edge_uses_is_the_row_wise_unique() -> None:
    """The edges, their use counts and each triangle's edges, as ``np.unique(axis=0)`` gives
    them, for int64 and int32 triangles and a non-manifold fan."""
    sphere = np.asarray(trimesh.creation.icosphere(3).faces)
    fan = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4], [4, 5, 0]])
    for F in (sphere, sphere.astype(np.int32), fan):
        half = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        E0, inv0, count0 = np.unique(half, axis=0, return_inverse=True, return_counts=True)
        E, count, of = edge_uses(F)
        assert E.dtype == E0.dtype
        np.testing.assert_array_equal(E, E0)
        np.testing.assert_array_equal(count, count0)
        np.testing.assert_array_equal(of, inv0.ravel().reshape(3, len(F)).T)
