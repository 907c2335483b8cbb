"""The bending basis of a large part from a coarse mesh, against the exact one.

The basis (:func:`qifreport.registration.deformable.bending_basis.bending_basis`, the 100
lowest modes of ``Q phi = mu M phi``) is the largest cost of a cold inspection of a large
part (`bench/scale.py`). This bench measures what a multi-resolution basis would give on
the part of `bench/scale.py` (the 600 mm shell, ~200k vertices, Hessian energy):

* **exact**: the product's block shift-invert Lanczos on the whole mesh;
* **coarse**: the mesh decimated to ``--coarse`` vertices (libigl's edge collapse), the
  basis of the coarse mesh's own operators (``--extra`` modes beyond 100), prolonged to the
  whole mesh by the barycentric coordinates of each vertex's closest point on the coarse
  mesh, and a Rayleigh-Ritz step on the whole mesh's operators (so the modes are
  M-orthonormal and diagonalise ``Q`` on the whole mesh, their ``mu`` the whole mesh's
  energies of them);
* **coarse + 1**: the same, with one block inverse iteration on the whole mesh (a
  factorisation of the shifted operator and one solve of all the modes) before the
  Rayleigh-Ritz step.

Printed per way: seconds, the ratio of its eigenvalues to the exact ones (modes 4-99,
beyond the affine null space), and how much of each exact mode lies outside its span
(``1 - ||Phi^T M phi||^2``).

    python bench/coarse_basis.py [--vertices 200000] [--coarse 25000] [--extra 20]
"""

from __future__ import annotations

import argparse
import time

import igl
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scale import build  # bench/: the script's own folder

from qifreport.registration.deformable.bending_basis import bending_basis
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import bending_operator

MODES = 100


def prolongation(V: np.ndarray, U: np.ndarray, G: np.ndarray) -> sp.csr_matrix:
    """(n, c) barycentric interpolation of the coarse mesh ``(U, G)`` at the vertices ``V``
    (their closest points on it)."""
    _, face, C = igl.point_mesh_squared_distance(V, U, G)
    tri = G[face]
    B = igl.barycentric_coordinates(C, U[tri[:, 0]], U[tri[:, 1]], U[tri[:, 2]])
    rows = np.repeat(np.arange(len(V)), 3)
    return sp.csr_matrix((B.ravel(), (rows, tri.ravel())), shape=(len(V), len(U)))


def ritz(ops, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``MODES`` lowest Rayleigh-Ritz pairs of the whole mesh's operators in span(X)."""
    mass = ops.M.diagonal()
    Gq = X.T @ (ops.Q @ X)
    Gm = X.T @ (mass[:, None] * X)
    mu, Y = sla.eigh(0.5 * (Gq + Gq.T), 0.5 * (Gm + Gm.T))
    return mu[:MODES], X @ Y[:, :MODES]


def coarse_basis(ops, V, F, coarse: int, extra: int, inverse: int) -> tuple:
    """(mu, Phi, seconds) of the coarse way (``inverse`` block inverse iterations)."""
    t0 = time.perf_counter()
    U, G, _, _ = igl.decimate(
        np.asfortranarray(V), np.asfortranarray(F.astype(np.int32)), 2 * coarse
    )
    U, G = np.asarray(U, dtype=np.float64), np.asarray(G, dtype=np.int64)
    small = bending_basis(bending_operator(U, G, energy="hessian"), MODES + extra)
    X = prolongation(V, U, G) @ small.Phi
    if inverse:
        area = float(ops.area.sum())
        shift = -1e-3 * (np.pi * np.sqrt(X.shape[1] / area)) ** 4
        solve = SPDSolver(points=V).factor((ops.Q - shift * ops.M).tocsc())
        mass = ops.M.diagonal()
        for _ in range(inverse):
            X, _ = np.linalg.qr(solve(mass[:, None] * X))
    mu, Phi = ritz(ops, X)
    return mu, Phi, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=200_000)
    ap.add_argument("--coarse", type=int, default=25_000, help="coarse mesh vertices")
    ap.add_argument("--extra", type=int, default=20, help="coarse modes beyond 100")
    a = ap.parse_args()
    V, F, _, _ = build(a.vertices, 1000)
    ops = bending_operator(V, F, energy="hessian")
    mass = ops.M.diagonal()
    t0 = time.perf_counter()
    exact = bending_basis(ops, MODES)
    print(f"part: {len(V)} vertices; exact basis {time.perf_counter() - t0:.1f} s")
    for name, inverse in (("coarse", 0), ("coarse + 1", 1)):
        mu, Phi, seconds = coarse_basis(ops, V, F, a.coarse, a.extra, inverse)
        ratio = mu[4:] / np.maximum(exact.mu[4:], 1e-300)
        outside = 1.0 - ((Phi.T @ (mass[:, None] * exact.Phi)) ** 2).sum(axis=0)
        print(
            f"{name:11s} {seconds:5.1f} s; eigenvalue ratio median {np.median(ratio):.4f}, "
            f"max {ratio.max():.4f}; exact modes outside its span: median "
            f"{np.median(outside):.1e}, modes 0-49 max {outside[:50].max():.1e}, "
            f"50-99 max {outside[50:].max():.1e}"
        )


if __name__ == "__main__":
    main()
