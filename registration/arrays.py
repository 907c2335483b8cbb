"""Array primitives the mesh and metrology code need faster than NumPy gives them.

``np.unique`` of a 1-D integer array with many distinct values takes NumPy >= 2.3's hashing
path, which is an order of magnitude slower than a sort on a million distinct keys (the
edges of a 400k-triangle mesh, once per vertex adjacency). :func:`unique_sorted` is the
sort, for integer arrays; anything else goes to ``np.unique`` (NaN handling included).
:func:`unique_rows` is ``np.unique(a, axis=0)`` of finite rows by one ``lexsort``, about
twice as fast.

One rule needs no function: rows of a narrow array are gathered with
``np.take(A, idx, axis=0)``, not ``A[idx]``. NumPy 2.4's fancy indexing of 3-wide rows is
several times slower for the same array, small or large; the hot gathers of the registration
and the judgement follow it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["unique_rows", "unique_sorted"]


def unique_sorted(a: np.ndarray) -> np.ndarray:
    """The sorted distinct values of ``a`` (flattened): ``np.unique(a)``, by one sort.

    Parameters
    ----------
    a : array of any shape.

    Returns
    -------
    (k,) sorted distinct values, the dtype of ``a``.
    """
    a = np.asarray(a)
    if a.dtype.kind not in "iub":
        return np.unique(a)
    s = np.sort(a, axis=None)
    if len(s) < 2:
        return s
    return s[np.r_[True, s[1:] != s[:-1]]]


def unique_rows(a: np.ndarray) -> np.ndarray:
    """The distinct rows of the finite 2-D array ``a`` (m, d), sorted lexicographically:
    ``np.unique(a, axis=0)`` by one ``np.lexsort``.

    Parameters
    ----------
    a : (m, d) finite numbers (rows equal in value are one row: ``-0.0`` is ``0.0``).

    Returns
    -------
    (k, d) the distinct rows, first column first in the order.
    """
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(f"unique_rows takes a 2-D array, got shape {a.shape}")
    if len(a) < 2:
        return a.copy()
    s = a[np.lexsort(a.T[::-1])]
    return s[np.r_[True, np.any(s[1:] != s[:-1], axis=1)]]
