"""Fill-reducing orders for sparse factorisations of mesh operators.

SuperLU (scipy) offers minimum-degree orders only. On the 2-manifold meshes of the parts a
*nested dissection* fills less: the unknowns are split into two halves by a separator, the
separator ordered last, recursively, so eliminating one half never fills the other. Here the
split is geometric (at the median of the longest extent of the points' positions) and the
separator is read off the matrix's own graph: the points of one half coupled to the other.
With the graph of a wide stencil (the Hessian bending energy couples 2-rings) the separator
is as wide as the stencil, as it must be for the halves to decouple.

Against SuperLU's minimum-degree order (SuperLU in symmetric mode on GB-CICP's full-step
matrix; ``python bench/factorisation.py``, figures in ``docs/benchmarks.md``): about the
same factorisation on the 28,910-vertex fandisk, about half of it on the 201k-vertex sheet
of ``bench/scale.py``, with fewer nonzeros in the factors.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = [
    "nested_dissection",
]


def nested_dissection(X: np.ndarray, adjacency: sp.spmatrix, leaf: int = 16) -> np.ndarray:
    """A fill-reducing order (n,) of the unknowns at points ``X`` by geometric nested dissection.

    The points are split at the median of their longest extent; the points of one half
    adjacent to the other (in ``adjacency``) form the separator, ordered after both halves,
    recursively, down to ``leaf`` points.

    Parameters
    ----------
    X : (n, d) positions of the unknowns (mm; only their order along each axis matters).
    adjacency : (n, n) sparse, the coupling pattern (the matrix to factorise, or the mesh's
        vertex graph, :func:`qifreport.registration.mesh.adjacency`); its values are
        ignored, the diagonal may be present.
    leaf : size below which a part is not split further.

    Returns
    -------
    (n,) int64 permutation: ``A[p][:, p]`` is the reordered matrix.
    """
    n = len(X)
    adj = sp.csr_matrix(adjacency, dtype=np.float64, copy=True)
    adj.data[:] = 1.0
    out: list[np.ndarray] = []
    stack: list[tuple[np.ndarray, int]] = [(np.arange(n), 0)]
    # iterative post-order: (idx, 0) = split, (idx, 1) = emit
    while stack:
        idx, emit = stack.pop()
        if emit or len(idx) <= leaf:
            out.append(idx)
            continue
        P = X[idx]
        ax = int(np.argmax(P.max(axis=0) - P.min(axis=0)))
        left = P[:, ax] <= np.median(P[:, ax])
        if left.all() or not left.any():
            out.append(idx)
            continue
        right = np.zeros(n)
        right[idx[~left]] = 1.0
        touches = np.asarray(adj[idx[left]] @ right).ravel() > 0
        L, S, R = idx[left][~touches], idx[left][touches], idx[~left]
        stack += [(S, 1), (R, 0), (L, 0)]  # popped as L, R, then the separator
    return np.concatenate(out).astype(np.int64, copy=False)
