"""Array primitives the mesh and metrology code need faster than NumPy gives them.

``np.unique`` of a 1-D integer array with many distinct values takes NumPy >= 2.3's hashing
path, which is an order of magnitude slower than a sort on a million distinct keys (the
edges of a 400k-triangle mesh, once per vertex adjacency). :func:`unique_sorted` is the
sort, for integer arrays; anything else goes to ``np.unique`` (NaN handling included).
:func:`unique_rows` is ``np.unique(a, axis=0)`` of finite rows by one ``lexsort``, about
twice as fast. :class:`LabelIndex` finds the items of given labels (the triangles of some
faces, the corners at some vertices) from one sort of the labels, not a pass over all of
them per question.

One rule needs no function: rows of a narrow array are gathered with
``np.take(A, idx, axis=0)``, not ``A[idx]``. NumPy 2.4's fancy indexing of 3-wide rows is
several times slower for the same array, small or large; the hot gathers of the registration
and the judgement follow it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LabelIndex", "unique_rows", "unique_sorted"]


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


class LabelIndex:
    """The items of each integer label, from one stable sort of the labels (l,).

    ``LabelIndex(face_id).of(faces)`` is ``np.flatnonzero(np.isin(face_id, faces))``,
    found by bisection in the sorted labels: the cost of the answer, not of all the
    labels, per question.
    """

    def __init__(self, labels: np.ndarray):
        labels = np.asarray(labels, dtype=np.int64).ravel()
        self.n = len(labels)
        self.order = np.argsort(labels, kind="stable")  # each label's items ascending
        self.sorted = labels[self.order]

    def of(self, labels) -> np.ndarray:
        """(k,) the items (ids, ascending) whose label is one of ``labels``."""
        if not isinstance(labels, np.ndarray):
            labels = list(labels)  # any iterable of ints
        labels = unique_sorted(np.asarray(labels, dtype=np.int64))
        lo = np.searchsorted(self.sorted, labels, side="left")
        hi = np.searchsorted(self.sorted, labels, side="right")
        if len(labels) <= 1:
            return self.order[lo[0] : hi[0]] if len(labels) else self.order[:0]
        counts = hi - lo
        at = np.arange(int(counts.sum())) + np.repeat(lo - np.cumsum(counts) + counts, counts)
        return np.sort(self.order[at])

    def mask(self, labels) -> np.ndarray:
        """(l,) bool, the items whose label is one of ``labels``."""
        out = np.zeros(self.n, dtype=bool)
        out[self.of(labels)] = True
        return out
