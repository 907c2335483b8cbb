"""The bending basis by block shift-invert Lanczos (issue 23).

:func:`qifreport.registration.deformable.block_lanczos.lowest_modes` replaces ARPACK's
one-vector Lanczos in :func:`~qifreport.registration.deformable.bending_basis.bending_basis`.
Its modes are checked against LAPACK's dense generalized eigen-decomposition (software we did
not write): the eigenvalues to 1e-10, the modes (in the canonical basis) to 1e-8 of their
largest entry, which a Krylov basis missing a Gram-Schmidt sweep, a Rayleigh quotient missing
its lower blocks or a convergence test that stopped early all miss. The blocks must be real: a
hundred modes in at most 40 block solves, where ARPACK made 202 single ones.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from qifreport.registration.deformable.bending_basis import (
    BASIS_BLOCK,
    bending_basis,
    canonical_modes,
)
from qifreport.registration.deformable.block_lanczos import lowest_modes
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import bending_operator
from qifreport.simulate.shapes import thin_shell


def dense_modes(ops, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` lowest modes by LAPACK (dense ``Q phi = mu M phi``), canonical."""
    mu, Phi = sla.eigh(ops.Q.toarray(), np.diag(ops.area), subset_by_index=(0, k - 1))
    return canonical_modes(mu, Phi, ops.area)


@pytest.mark.parametrize(
    ("spacing", "energy", "k"), [(6.0, "hessian", 24), (3.0, "laplacian", 100)]
)
def test_bending_basis_matches_lapack(spacing, energy, k):
    V, F = thin_shell(spacing=spacing)
    ops = bending_operator(V, F, energy)
    n = len(V)
    assert n > 4 * (k + BASIS_BLOCK)  # the Krylov path, not the dense one
    calls = []
    B = bending_basis(ops, k, solver=SPDSolver(points=V), check=lambda: calls.append(1))
    mu, Phi = dense_modes(ops, k)
    top = float(mu[-1])
    np.testing.assert_allclose(B.mu, mu, rtol=1e-10, atol=1e-12 * top)
    np.testing.assert_allclose(B.Phi, Phi, rtol=0, atol=1e-8 * np.abs(Phi).max())
    # M-orthonormal, and Q diagonal in the basis
    np.testing.assert_allclose(B.Phi.T @ (ops.M @ B.Phi), np.eye(k), atol=1e-12)
    H = B.Phi.T @ (ops.Q @ B.Phi)
    np.testing.assert_allclose(H, np.diag(B.mu), atol=1e-9 * top)
    # blocks: each check precedes one solve of BASIS_BLOCK columns
    assert 2 <= len(calls) <= (40 if k == 100 else 15), len(calls)


@pytest.mark.parametrize("levels", [(1.0, 2.0, 3.0), (1.0, 1e3, 1e6, 1e9)])
def test_lowest_modes_survives_a_closed_krylov_space(levels):
    """A diagonal operator with a few distinct eigenvalues, each many-fold: every block's
    Krylov space closes after as many steps, on ten directions of each eigenspace. The
    solver must not take that closed space for convergence (its Ritz pairs are exact): it
    restarts the closed columns with fresh directions and finds 15 modes of the lowest
    eigenvalue, more than one block holds. The spread levels cancel nearly all of each
    image in the Gram-Schmidt sweeps, where one sweep leaves the basis far from orthogonal.
    """
    n, k = 60 * len(levels), 15
    q = np.repeat(levels, 60)
    mass = np.full(n, 2.0)
    sigma = -0.5
    solve = SPDSolver("superlu").factor(sp.diags(q - sigma * mass).tocsc())
    r = lowest_modes(solve, mass, k, sigma, np.random.default_rng(1), tol=1e-10, block=10)
    assert r.converged
    np.testing.assert_allclose(r.mu, 0.5, rtol=1e-12)  # q / m of the lowest eigenspace
    np.testing.assert_allclose(r.Phi.T @ (mass[:, None] * r.Phi), np.eye(k), atol=1e-10)
    assert np.abs(r.Phi[60:]).max() < 1e-10  # nothing in the other eigenspaces


def test_lowest_modes_refuses_a_singular_mass():
    with pytest.raises(ValueError, match="mass"):
        lowest_modes(
            lambda X: X, np.r_[1.0, 0.0, 1.0] * np.ones(3), 1, -1.0, np.random.default_rng(0)
        )


def test_a_small_part_is_solved_densely_with_the_same_modes():
    """Below 4 (k + block) unknowns the basis comes from LAPACK: the same modes as the block
    Lanczos gives the same problem (the generalized one, with the mass)."""
    V, F = thin_shell(spacing=12.0)
    ops = bending_operator(V, F, "hessian")
    k = 30
    assert len(V) <= 4 * (k + BASIS_BLOCK)
    calls = []
    B = bending_basis(ops, k, check=lambda: calls.append(1))
    assert len(calls) == 1  # asked once, before the decomposition
    shift = -1e-3 * float(B.mu[-1])
    solve = SPDSolver("superlu").factor((ops.Q - shift * ops.M).tocsc())
    r = lowest_modes(solve, ops.area, k, shift, np.random.default_rng(0), tol=1e-12, block=5)
    mu, Phi = canonical_modes(r.mu, r.Phi, ops.area)
    np.testing.assert_allclose(B.mu, mu, rtol=1e-9, atol=1e-12 * float(mu[-1]))
    np.testing.assert_allclose(B.Phi, Phi, rtol=0, atol=1e-8 * np.abs(Phi).max())


def test_a_part_in_more_pieces_than_a_block_finds_every_null_mode(caplog):
    """Twelve separate shells: the Laplacian energy's null space has twelve directions (a
    constant per piece), more than a block of ten. The basis converges and holds all
    twelve, with the dense decomposition's eigenvalues."""
    import logging

    V0, F0 = thin_shell(spacing=12.0)
    pieces, k = 12, 24
    V = np.vstack([V0 + [300.0 * i, 0.0, 0.0] for i in range(pieces)])
    F = np.vstack([F0 + len(V0) * i for i in range(pieces)])
    ops = bending_operator(V, F, "laplacian")
    assert len(V) > 4 * (k + BASIS_BLOCK)
    with caplog.at_level(logging.WARNING, logger="qifreport.registration.deformable.block_lanczos"):
        B = bending_basis(ops, k, solver=SPDSolver(points=V))
    assert not caplog.records, [r.getMessage() for r in caplog.records]
    mu, _ = dense_modes(ops, k)
    assert int((B.mu == 0).sum()) == int((mu == 0).sum()) == pieces
    np.testing.assert_allclose(B.mu, mu, rtol=1e-9, atol=1e-12 * float(mu[-1]))
