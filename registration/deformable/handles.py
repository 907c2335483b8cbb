"""Clamp handles: small vertex groups at the corners, edge midpoints and centre of a part's
principal (PCA) bounding rectangle (paper Section 7.1).

They drive the RBF-FEM baseline (:mod:`qifreport.registration.deformable.rbffem`) and the
simulator's
biharmonic free states (:mod:`qifreport.simulate.deform`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.registration.arrays import unique_sorted
from qifreport.registration.mesh import bounding_diagonal, vertex_areas

__all__ = ["Handles", "clamp_handles", "pca_frame"]


def pca_frame(V: np.ndarray, area: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroid and principal axes of the points ``V``.

    Parameters
    ----------
    V : (n, 3) float, mm.
    area : (n,) non-negative weights (e.g. vertex areas, mm^2); uniform when ``None``.

    Returns
    -------
    c : (3,) weighted centroid, mm.
    U : (3, 3) orthonormal, columns ``u1`` (largest extent), ``u2``, ``u3`` (smallest: the
        normal of the mid-plane), right-handed (``u3 = u1 x u2``). Signs are fixed so the
        largest-magnitude component of ``u1`` and of ``u2`` is positive, which makes the
        frame deterministic (but, like any PCA frame, not equivariant under reflections).
    """
    V = np.asarray(V, dtype=np.float64)
    w = np.ones(len(V)) if area is None else np.asarray(area, dtype=np.float64)
    w = w / w.sum()
    c = w @ V
    X = V - c
    C = (X * w[:, None]).T @ X
    _, vecs = np.linalg.eigh(C)
    U = vecs[:, ::-1].copy()
    for k in range(2):
        if U[np.argmax(np.abs(U[:, k])), k] < 0:
            U[:, k] = -U[:, k]
    U[:, 2] = np.cross(U[:, 0], U[:, 1])
    return c, U


@dataclass
class Handles:
    """Clamp handles: small vertex groups whose displacement is prescribed.

    Attributes
    ----------
    groups : one int64 index array per clamp.
    centers : (k, 3) position of each clamp's seed vertex, mm.
    kind : ``"corner"``, ``"edge"`` or ``"anchor"`` per group.
    """

    groups: list[np.ndarray]
    centers: np.ndarray
    kind: list[str]

    @property
    def indices(self) -> np.ndarray:
        """All handle vertex indices, unique and sorted (int64)."""
        if not self.groups:
            return np.zeros(0, dtype=np.int64)
        return unique_sorted(np.concatenate(self.groups)).astype(np.int64)


def clamp_handles(
    V: np.ndarray, F: np.ndarray, radius: float | None = None, include_edges: bool = False
) -> Handles:
    """Clamp handles from the part's principal (PCA) bounding rectangle (paper Section 7.1).

    The rectangle spans all vertices in the (u1, u2) coordinates of :func:`pca_frame`
    (area-weighted). For each target point the seed vertex is the one nearest it in the
    u1-u2 plane, and its group is every vertex within ``radius`` (3D distance) of the seed.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    radius : group radius, mm; default 1.5 % of the bounding diagonal.
    include_edges : also place handles at the four edge midpoints (needed by ``saddle``).

    Returns
    -------
    Handles with groups in this order: 4 corners counter-clockwise in (u1, u2) starting at
    (-u1, -u2); if ``include_edges``, the edge midpoints at +u1, +u2, -u1, -u2; last the
    ``"anchor"`` at the vertex nearest the centroid.
    """
    V = np.asarray(V, dtype=np.float64)
    if radius is None:
        radius = 0.015 * bounding_diagonal(V)
    c, U = pca_frame(V, vertex_areas(V, F))
    xi = (V - c) @ U[:, :2]
    lo, hi = xi.min(axis=0), xi.max(axis=0)
    mid = 0.5 * (lo + hi)
    targets = [
        (lo[0], lo[1]),
        (hi[0], lo[1]),
        (hi[0], hi[1]),
        (lo[0], hi[1]),
    ]
    kinds = ["corner"] * 4
    if include_edges:
        targets += [(hi[0], mid[1]), (mid[0], hi[1]), (lo[0], mid[1]), (mid[0], lo[1])]
        kinds += ["edge"] * 4
    targets.append((0.0, 0.0))  # the centroid
    kinds.append("anchor")
    groups, centers = [], []
    for t in targets:
        seed = int(np.argmin(np.sum((xi - np.asarray(t)) ** 2, axis=1)))
        dist = np.linalg.norm(V - V[seed], axis=1)
        groups.append(np.flatnonzero(dist <= radius).astype(np.int64))
        centers.append(V[seed])
    return Handles(groups=groups, centers=np.array(centers), kind=kinds)
