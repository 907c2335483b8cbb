"""A sheet's solid: a mid-surface triangle mesh thickened into tetrahedra.

A mesh nominal (an open sheet: a thin moulding, a panel) carries no solid for the elastic
model of :mod:`qifreport.registration.restraint.elastic`. With its wall thickness (``--thickness``)
each triangle becomes a prism between the two skins ``V -/+ t/2 n`` (``n`` the vertex
normals), and each prism three tetrahedra. The split follows the global vertex order
(each prism's quadrilateral faces are cut on the diagonal through their lowest-numbered
vertex), so neighbouring prisms cut their shared face alike and the mesh is conforming.
With quadratic elements one layer through the thickness carries the sheet's bending.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SheetSolid", "sheet_solid"]


@dataclass
class SheetSolid:
    """Tetrahedra filling a thickened sheet.

    Attributes
    ----------
    X : (2n, 3) vertices, mm: the lower skin (``V - t/2 n``) then the upper (``V + t/2 n``).
    T : (3f, 4) tetrahedra.
    n : number of mid-surface vertices (vertex ``i`` of the sheet is ``i`` and ``n + i``).
    thickness : mm.
    """

    X: np.ndarray
    T: np.ndarray
    n: int
    thickness: float

    def mid_surface(self, u: np.ndarray) -> np.ndarray:
        """(n, 3) the mid-surface's value of a per-vertex field ``u`` (2n, 3): the mean of
        the two skins'."""
        return 0.5 * (u[: self.n] + u[self.n :])


def sheet_solid(V: np.ndarray, F: np.ndarray, normals: np.ndarray, thickness: float) -> SheetSolid:
    """Thicken a mid-surface mesh into a layer of tetrahedra.

    Parameters
    ----------
    V : (n, 3) mid-surface vertices, mm.  F : (f, 3) triangles.
    normals : (n, 3) unit vertex normals.  thickness : wall thickness, mm.

    Raises
    ------
    ValueError
        A thickness that is not a positive length.
    """
    if not (np.isfinite(thickness) and thickness > 0):
        raise ValueError(f"thickness must be a positive length in mm, got {thickness}")
    V = np.asarray(V, dtype=np.float64)
    N = np.asarray(normals, dtype=np.float64)
    n = len(V)
    X = np.vstack([V - 0.5 * thickness * N, V + 0.5 * thickness * N])
    S = np.sort(np.asarray(F, dtype=np.int64), axis=1)  # a < b < c
    a, b, c = S[:, 0], S[:, 1], S[:, 2]
    A, B, C = a + n, b + n, c + n
    T = np.concatenate(
        [
            np.stack([a, b, c, C], axis=1),
            np.stack([a, b, B, C], axis=1),
            np.stack([a, A, B, C], axis=1),
        ]
    )
    return SheetSolid(X=X, T=T, n=n, thickness=float(thickness))
