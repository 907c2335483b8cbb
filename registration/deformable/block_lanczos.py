"""Lowest eigenpairs of ``Q phi = mu M phi`` (``M`` diagonal) by block shift-invert Lanczos.

A block of ``b`` vectors goes through each solve with the shifted operator's factorisation:
a sparse triangular sweep over ``b`` right-hand sides costs a few single sweeps, not ``b``
(a block of 10 about 2.5 single solves on large parts; ``docs/benchmarks.md``). The Krylov
basis is kept and re-orthogonalised in full (two block Gram-Schmidt sweeps), so its Rayleigh
quotient is the exact projection and no restart is needed: the subspace grows until every
wanted Ritz pair meets ARPACK's own criterion,
``||OP x - theta x|| <= tol |theta|`` in the ``M`` norm.

In the coordinates ``z = M^(1/2) phi`` the operator ``S = M^(1/2) (Q - sigma M)^-1 M^(1/2)``
is symmetric; its largest eigenvalues ``theta = 1 / (mu - sigma)`` are the wanted modes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

log = logging.getLogger(__name__)

__all__ = ["LanczosResult", "lowest_modes"]


@dataclass
class LanczosResult:
    """The ``k`` lowest eigenpairs of ``Q phi = mu M phi``.

    Attributes
    ----------
    mu : (k,) eigenvalues, ascending (the units of ``Q`` over those of ``M``).
    Phi : (n, k) eigenvectors, M-orthonormal.
    solves : right-hand sides solved (columns, all blocks together).
    dimension : size of the Krylov basis at convergence.
    converged : every wanted pair met the tolerance.
    """

    mu: np.ndarray
    Phi: np.ndarray
    solves: int
    dimension: int
    converged: bool


def _sizes(mass: np.ndarray, k: int, block: int, max_dimension: int | None) -> tuple[int, int]:
    """The block size and the Krylov basis' largest size (a multiple of it) for ``k`` modes
    of the (n,) positive ``mass`` (arguments as :func:`lowest_modes`); ValueError when they
    do not fit."""
    n = len(mass)
    if not np.all(mass > 0):
        raise ValueError("the mass matrix must be positive definite")
    b = int(max(1, min(block, n)))
    if k < 1 or k + b > n:
        raise ValueError(f"{k} modes with blocks of {b} need more than {n} unknowns")
    cap = int(min(n, max_dimension or 4 * k + 8 * b))
    cap -= cap % b
    if cap < k + b:
        raise ValueError(f"a Krylov basis of {cap} cannot hold {k} modes and a block of {b}")
    return b, cap


def _ritz(H: np.ndarray, d: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` Ritz pairs of the basis' first ``d`` vectors (Rayleigh quotient ``H``,
    at least (d, d)) with the largest theta (the lowest mu), descending: (k,) values and
    (d, k) coordinates in the basis."""
    theta, Y = sla.eigh(0.5 * (H[:d, :d] + H[:d, :d].T))
    return theta[::-1][:k], Y[:, ::-1][:, :k]


def _orthogonalise(W: np.ndarray, Kt: np.ndarray, d: int) -> np.ndarray:
    """Two sweeps of block Gram-Schmidt of the rows of ``W`` (b, n), in place, against the
    basis' first ``d`` rows of ``Kt`` (full re-orthogonalisation). Returns the (b, d)
    projections removed: block row of ``K^T S K`` when ``W`` holds the images ``S K``."""
    C = W @ Kt[:d].T
    W -= C @ Kt[:d]
    C2 = W @ Kt[:d].T
    W -= C2 @ Kt[:d]
    C += C2
    return C


def _next_block(
    W: np.ndarray, Kt: np.ndarray, H: np.ndarray, j: int, d: int
) -> tuple[np.ndarray, np.ndarray]:
    """Take the images ``W`` (b, n) of the newest block (basis rows ``j..d`` of ``Kt``)
    into the Rayleigh quotient ``H`` (its block row and column ``j``, in place) and
    orthogonalise them against the basis (``W`` in place).

    Returns
    -------
    Qn : (n, b) the next block: the remainder, orthonormalised.
    weak : (b,) bool, its columns whose remainder vanished (the Krylov space closed on an
        invariant subspace), to be replaced by fresh directions.
    """
    size = float(np.sqrt(np.einsum("ij,ij->i", W, W).max()))  # the images' largest norm
    C = _orthogonalise(W, Kt, d)
    H[j:d, :d] = C  # block row j of K^T S K, and by symmetry its block column
    H[:d, j:d] = C.T
    Qn, R = np.linalg.qr(W.T)
    scale = np.abs(np.diag(R))
    weak = scale <= 1e-10 * max(size, 1e-300)
    return Qn, weak


def _converged_pairs(
    H: np.ndarray, W: np.ndarray, j: int, d: int, k: int, tol: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The ``k`` Ritz pairs of the first ``d`` basis vectors (as :func:`_ritz`) if each
    meets ``||S z - theta z|| <= tol theta``, else None; ``W`` (b, n) is the orthogonalised
    remainder of the newest block (rows ``j..d``)."""
    theta, Y = _ritz(H, d, k)
    # S (K y) - theta (K y) = W^T y_last: the residual of each Ritz pair, its norm from the
    # (b, b) Gram matrix of W
    Yl = Y[j:d]
    res = np.sqrt(np.maximum(np.einsum("ij,ij->j", Yl, (W @ W.T) @ Yl), 0.0))
    return (theta, Y) if np.all(res <= tol * np.abs(theta)) else None


def _fresh_directions(
    Qn: np.ndarray, weak: np.ndarray, Kt: np.ndarray, d: int, rng: np.random.Generator
) -> None:
    """Replace the columns ``weak`` (b,) bool of the next block ``Qn`` (n, b), in place, by
    random directions orthonormal to the basis' first ``d`` rows of ``Kt`` and to the
    block's other columns (where the Krylov space closed on an invariant subspace)."""
    n = Qn.shape[0]
    Ft = rng.standard_normal((int(weak.sum()), n))
    for _ in range(2):
        Ft -= (Ft @ Kt[:d].T) @ Kt[:d]
        Ft -= (Ft @ Qn[:, ~weak]) @ Qn[:, ~weak].T
    Fq, _ = np.linalg.qr(Ft.T)
    Qn[:, weak] = Fq


def lowest_modes(
    solve: Callable[[np.ndarray], np.ndarray],
    mass: np.ndarray,
    k: int,
    sigma: float,
    rng: np.random.Generator,
    tol: float = 1e-6,
    block: int = 10,
    max_dimension: int | None = None,
) -> LanczosResult:
    """The ``k`` eigenpairs of ``Q phi = mu M phi`` nearest above the shift ``sigma``.

    Parameters
    ----------
    solve : ``X -> (Q - sigma M)^-1 X`` for (n, b) blocks (a factorisation's solve).
    mass : (n,) the diagonal of ``M`` (positive).
    k : number of pairs wanted (``k + block <= n``).
    sigma : the shift, below the lowest eigenvalue (``Q - sigma M`` positive definite).
    rng : generator of the start block (standard normal); seeded, the result is
        deterministic.
    tol : relative accuracy of each Ritz value ``theta = 1 / (mu - sigma)``: its residual
        ``||S z - theta z||`` at most ``tol theta`` (ARPACK's criterion).
    block : columns per solve.
    max_dimension : largest Krylov basis (default ``min(n, 4 k + 8 block)``); without
        convergence by then, the pairs are returned with ``converged=False``. A hundred
        modes converge at 250-280; an eigenvalue of more directions than a block (a part
        in more than ten separate pieces, each with its own null mode) needs more.

    Returns
    -------
    LanczosResult
    """
    mass = np.asarray(mass, dtype=np.float64)
    n = len(mass)
    b, cap = _sizes(mass, k, block, max_dimension)
    root = np.sqrt(mass)

    def op(Z: np.ndarray) -> np.ndarray:
        """``S`` applied to the rows of ``Z`` (b, n): the images as rows, contiguous."""
        return np.ascontiguousarray((root[:, None] * solve(root[:, None] * Z.T)).T)

    # The orthonormal Krylov basis in the z coordinates, one vector per row, and the block
    # being orthogonalised as rows too: each block product is then a GEMM of contiguous
    # rows, ~35 % faster than on columns (they read the whole basis, memory-bound).
    Kt = np.empty((cap, n))
    H = np.zeros((cap, cap))  # its Rayleigh quotient K^T S K
    X, _ = np.linalg.qr(rng.standard_normal((n, b)))
    Kt[:b] = X.T
    d, solves = b, 0
    converged = False

    while True:
        j = d - b  # the newest block: rows j..d
        W = op(Kt[j:d])
        solves += b
        Qn, weak = _next_block(W, Kt, H, j, d)
        # where the space closed, its Ritz pairs are exact but may miss a multiple
        # eigenvalue's other directions: no convergence is declared until they had a chance
        if d >= k + b and not weak.any():
            pairs = _converged_pairs(H, W, j, d, k, tol)
            if pairs is not None:
                theta, Y = pairs
                converged = True
                break
        if d + b > cap:
            break
        if weak.any():
            _fresh_directions(Qn, weak, Kt, d, rng)
        Kt[d : d + b] = Qn.T
        d += b
    if not converged:
        theta, Y = _ritz(H, d, k)
        log.warning("block Lanczos: %d modes not converged in a basis of %d", k, d)
    # the modes as rows, the basis then released before they are scaled and transposed
    Zt = Y.T @ Kt[:d]
    del Kt
    Zt /= root
    return LanczosResult(
        mu=sigma + 1.0 / theta, Phi=Zt.T, solves=solves, dimension=d, converged=converged
    )
