"""Exact nearest vertices of points that move a little between queries (iterative fits).

An iterative rigid fit asks a k-d tree for the nearest model vertex of every scan point once
per iteration, though the points move by a small fraction of the mesh spacing per step.
:class:`TrackedNearest` keeps, for each point, its ``k`` nearest vertices where it was last
looked up (its anchor) and the ``k``-th distance ``r_k``. A point now at distance ``delta``
from its anchor has every other vertex at least ``r_k - delta`` away (triangle inequality),
so the closest of its ``k`` candidates is *the* nearest vertex whenever it is closer than
that; only the points this does not certify go back to the tree. The answers are the tree's
own, exactly (distance ties aside, which the tree breaks arbitrarily too).

:func:`ball_pairs` lists every pair of a point and a tree's point within a radius as two flat
arrays, from one dual-tree search: no list per point. :func:`nearest_distance` gives each
point's distance to the nearest of a large other set, searched only in the points' grown box;
:func:`farthest_from` the point of a set farthest from another, without measuring most of them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "PARALLEL_MIN",
    "TrackedNearest",
    "ball_pairs",
    "farthest_from",
    "nearest_distance",
    "workers_for",
]

#: points from which a query runs on every core
PARALLEL_MIN = 4096


def workers_for(n: int) -> int:
    """``workers`` for a k-d tree query of ``n`` points: every core (-1) for a large batch,
    one thread below :data:`PARALLEL_MIN` (starting the threads costs more than a few
    thousand points' search; the answers are the same)."""
    return -1 if n >= PARALLEL_MIN else 1


def ball_pairs(
    X: np.ndarray, tree: cKDTree, radius: float, min_points: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Every pair ``(i, j)`` of a point ``X[i]`` and a point ``j`` of ``tree`` within
    ``radius`` of it, for the points ``X[i]`` that have at least ``min_points`` such partners.

    One dual-tree search (``cKDTree.sparse_distance_matrix``), in its order.

    Parameters
    ----------
    X : (k, 3) points, mm.  tree : ``cKDTree`` of the other points.  radius : mm.
    min_points : fewest partners a point of ``X`` needs for its pairs to be listed.

    Returns
    -------
    i, j : (p,) int64 indices into ``X`` and into the tree's points.
    """
    pairs = cKDTree(X).sparse_distance_matrix(tree, radius, output_type="ndarray")
    i, j = pairs["i"], pairs["j"]
    enough = (np.bincount(i, minlength=len(X)) >= min_points)[i]
    return i[enough].astype(np.int64), j[enough].astype(np.int64)


class TrackedNearest:
    """Nearest vertex of ``V`` for a point set queried again and again as it moves.

    Parameters
    ----------
    tree : ``cKDTree(V)``.  V : (n, 3) the tree's points, mm.
    k : candidates kept per point (>= 2): more survive larger moves, each check costs more.

    Attributes
    ----------
    queried : points sent to the tree so far (the first call sends all of them).
    """

    def __init__(self, tree: cKDTree, V: np.ndarray, k: int = 3) -> None:
        if k < 2:
            raise ValueError(f"k must be at least 2, got {k}")
        self.tree = tree
        self.V = np.asarray(V, dtype=np.float64)
        self.k = min(int(k), len(self.V))
        self.queried = 0
        self._anchor = np.empty((3, 0))  # where each point was last looked up: x, y, z rows
        # candidate j of every point: its index (k, m) and x, y, z (3, k, m), each row a
        # packed vector, so the check runs on whole (m,) vectors
        self._cand = np.empty((self.k, 0), dtype=np.int64)
        self._coords = np.empty((3, self.k, 0))
        self._reach = np.empty(0)

    def query(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (m,) mm and index (m,) of the nearest vertex of each point of ``X`` (m, 3).

        ``X`` should hold the same points (same order) on every call; a call with another
        number of points starts afresh.
        """
        X = np.asarray(X, dtype=np.float64)
        m = len(X)
        if self._anchor.shape[1] != m:
            self._anchor = np.empty((3, m))
            self._cand = np.empty((self.k, m), dtype=np.int64)
            self._coords = np.empty((3, self.k, m))
            self._reach = np.empty(m)
            return self._requery(X, np.arange(m), np.empty(m), np.empty(m, dtype=np.int64))
        C = self._coords
        x, y, z = (np.ascontiguousarray(X[:, a]) for a in range(3))
        # the closest candidate, the first of equals (as argmin)
        best = idx = None
        for j in range(self.k):
            d2 = (C[0, j] - x) ** 2
            d2 += (C[1, j] - y) ** 2
            d2 += (C[2, j] - z) ** 2
            if best is None:
                best, idx = d2, self._cand[0].copy()
            else:
                closer = d2 < best
                np.copyto(best, d2, where=closer)
                np.copyto(idx, self._cand[j], where=closer)
        dist = np.sqrt(best)
        A = self._anchor
        moved = (x - A[0]) ** 2
        moved += (y - A[1]) ** 2
        moved += (z - A[2]) ** 2
        np.sqrt(moved, out=moved)
        # every vertex outside the candidates lies at least reach - moved from the point
        todo = np.flatnonzero(~(dist < self._reach - moved))
        return self._requery(X, todo, dist, idx)

    def _requery(
        self, X: np.ndarray, todo: np.ndarray, dist: np.ndarray, idx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ask the tree for the points ``todo``; anchor them where they are now."""
        if len(todo):
            d, i = self.tree.query(
                np.take(X, todo, axis=0), k=self.k, workers=workers_for(len(todo))
            )
            d, i = d.reshape(len(todo), self.k), i.reshape(len(todo), self.k)  # k = 1: 1-D
            self._anchor[:, todo] = np.take(X, todo, axis=0).T
            self._cand[:, todo] = i.T
            self._coords[:, :, todo] = np.moveaxis(np.take(self.V, i, axis=0), (2, 1), (0, 1))
            self._reach[todo] = d[:, -1]
            dist[todo] = d[:, 0]
            idx[todo] = i[:, 0]
            self.queried += len(todo)
        return dist, idx


def nearest_distance(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """(k,) each point of ``X`` (k, 3)'s distance to its nearest point of ``Y`` (q, 3), mm.

    Searched among the points of ``Y`` in ``X``'s bounding box grown by a margin (5 % of
    its diagonal, doubled until it holds every answer): a point outside the grown box is
    farther than the margin from every point of ``X``, so answers within the margin are
    exact. A surface's complement is most of a part, its near part a thin shell about it.
    """
    lo, hi = X.min(axis=0), X.max(axis=0)
    margin = 0.05 * float(np.linalg.norm(hi - lo)) + 1e-9
    while True:
        near = np.all((Y >= lo - margin) & (Y <= hi + margin), axis=1)
        if near.all():
            return cKDTree(Y).query(X)[0]
        if near.any():
            dist = cKDTree(Y[near]).query(X)[0]
            if dist.max() <= margin:
                return dist
        margin *= 2.0


#: cells per side of the grid :func:`farthest_from` bounds its points' distances on
FARTHEST_CELLS = 64


def farthest_from(X: np.ndarray, Y: np.ndarray) -> int:
    """The index of the point of ``X`` (k, 3) farthest from its nearest point of ``Y``
    (q, 3), mm: ``argmax(nearest_distance(X, Y))``, the first of equals.

    The points are grouped on a grid of :data:`FARTHEST_CELLS` cells along the largest side
    of their box. Each cell's first point is measured; its distance plus the cell's reach
    about it (the farthest of its points from it) bounds every distance in the cell, and the
    largest distance measured is a floor of the answer. Only the cells whose bound reaches
    the floor are measured whole: the others hold no point as far. The distances measured
    are those of :func:`nearest_distance`, so the answer is its argmax, ties and all.
    """
    X = np.asarray(X, dtype=np.float64)
    k = len(X)
    if k <= 4 * FARTHEST_CELLS:
        return int(np.argmax(nearest_distance(X, Y)))
    lo = X.min(axis=0)
    size = float(np.max(X.max(axis=0) - lo)) / FARTHEST_CELLS or 1.0
    cell = np.floor((X - lo) / size).astype(np.int64)
    key = (cell[:, 0] * (FARTHEST_CELLS + 1) + cell[:, 1]) * (FARTHEST_CELLS + 1) + cell[:, 2]
    order = np.argsort(key, kind="stable")
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    group = np.cumsum(first) - 1  # each point's cell, in ``order``
    rep = order[first]  # each cell's first point (lowest index)
    reach = np.zeros(len(rep))
    np.maximum.at(reach, group, np.linalg.norm(X[order] - X[rep][group], axis=1))
    d_rep = nearest_distance(X[rep], Y)
    floor = float(d_rep.max())
    # a cell's points lie within its reach of its first point: none is farther than this
    open_cell = d_rep + reach * (1.0 + 1e-12) + 1e-12 >= floor
    cand = np.sort(order[open_cell[group]])
    return int(cand[np.argmax(nearest_distance(X[cand], Y))])
