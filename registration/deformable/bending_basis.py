"""The bending basis of a part: the lowest modes of ``Q phi = mu M phi``.

GB-CICP's modal first pass (:mod:`qifreport.registration.deformable.gbcicp`) works in the
span of the part's lowest bending modes. They depend on the nominal only, so they are
computed once per part (:func:`bending_basis`, block shift-invert Lanczos about a small
negative shift, or LAPACK on a small part), made deterministic by fixing every choice the
eigen-decomposition leaves open (:func:`canonical_modes`), and reused by every scan, with
the fill-reducing order of their factorisation (:func:`part_solver`).

``Q`` is the bending operator (1/mm^2), ``M`` the diagonal mass matrix (mm^2).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from threadpoolctl import ThreadpoolController

from qifreport.registration.deformable.block_lanczos import lowest_modes
from qifreport.registration.linalg import SPDSolver, default_backend
from qifreport.registration.mesh import MeshOperators

__all__ = [
    "BASIS_BLOCK",
    "BASIS_SEED",
    "BendingBasis",
    "bending_basis",
    "canonical_modes",
    "part_solver",
]


@dataclass
class BendingBasis:
    """The lowest bending modes of a part: ``Q phi = mu M phi``, ``Phi^T M Phi = I``.

    A per-part precomputation (it depends only on the nominal): every scan of the part
    reuses it, and so does every iteration of the modal first pass.

    Attributes
    ----------
    Phi : (n, k) M-orthonormal modes (dimensionless x mm^-1).
    mu : (k,) bending eigenvalues, ascending, 1/mm^4 (0 for the rigid/affine modes).
    energy : the bending energy of the operator they diagonalise.
    seconds : time the eigen-decomposition took.
    order : (n,) the fill-reducing order its sparse factorisation used (the pattern of
        ``Q``, which every bending system of the part shares), and ``order_backend`` the
        solver's backend; None when solved densely. A later solver of the part starts from
        it (:func:`part_solver`) instead of searching it again.
    """

    Phi: np.ndarray
    mu: np.ndarray
    energy: str
    seconds: float = 0.0
    order: np.ndarray | None = None
    order_backend: str | None = None


def part_solver(V: np.ndarray, basis: BendingBasis | None = None) -> SPDSolver:
    """The sparse solver for the bending systems of the part with vertices ``V`` (n, 3) mm
    (GB-CICP's full steps, the basis' shifted operator): a nested dissection orders them
    (SuperLU's of ``V``, CHOLMOD's METIS), unless the part's ``basis`` carries the order its
    own factorisation found with this backend. Then that order is taken as is: the same
    factors, bit for bit, without the search (on a large part the search costs far more
    than the analysis in a given order)."""
    known = (
        basis is not None
        and basis.order is not None
        and basis.order_backend == default_backend()
        and len(basis.order) == len(V)
    )
    return SPDSolver(points=V, order=basis.order if known else None)


#: seed of every pseudo-random vector of :func:`bending_basis` (start vector, restarts and
#: the reference fields of the sign and null-space conventions): a fixed seed makes the basis a
#: function of the operators alone, bit-identical from one build to the next
BASIS_SEED = 20240607

#: vectors per solve of :func:`bending_basis`'s block Lanczos: a sparse triangular sweep of
#: ten right-hand sides costs about 2.5 single sweeps
BASIS_BLOCK = 10


def bending_basis(
    ops: MeshOperators,
    k: int = 100,
    tol: float = 1e-6,
    solver: SPDSolver | None = None,
    check: Callable[[], None] | None = None,
) -> BendingBasis:
    """The ``k`` lowest modes of the generalized problem ``Q phi = mu M phi``.

    Block shift-invert Lanczos
    (:func:`~qifreport.registration.deformable.block_lanczos.lowest_modes`)
    around a small negative shift, so the singular operator (its null space holds the affine
    fields) factorises: each solve takes a block of :data:`BASIS_BLOCK` vectors through the
    factorisation (CHOLMOD with the accelerator), and the Ritz pairs meet ARPACK's criterion
    ``||OP x - theta x|| <= 0.01 tol |theta|``. A part too small for a Krylov basis (``n`` at
    most ``4 (k + block)``) is solved densely (LAPACK).

    Deterministic: the start block comes from a generator seeded with :data:`BASIS_SEED`,
    and every choice an eigen-decomposition leaves open is fixed by a convention
    (:func:`canonical_modes`): the sign of each mode, and the basis of every cluster of
    numerically equal eigenvalues (the null space among them). Two builds of one nominal
    give bit-identical arrays.

    Parameters
    ----------
    ops : operators of the nominal (``Q`` 1/mm^2, ``M`` mm^2, diagonal).
    k : number of modes (capped at ``n - 2``).
    tol : relative accuracy of the eigenvalues; the modes are then M-orthonormal to
        round-off and ``Phi^T Q Phi`` diagonal to ~1e-10 of the largest eigenvalue
        (measured on shells of 550 to 19,000 vertices).
    solver : the sparse factorisation of the shifted operator (default
        :class:`~qifreport.registration.linalg.SPDSolver` without positions; give it the
        vertices, ``SPDSolver(points=V)``, for SuperLU's nested-dissection order).
    check : called before every block solve; an exception it raises abandons the basis (a
        caller that learns it no longer needs it).
    """
    t0 = time.perf_counter()
    n = ops.Q.shape[0]
    k = int(max(1, min(k, n - 2)))
    area = float(ops.area.sum())
    # eigenvalue of the k-th mode of a plate of this area, ~ (pi sqrt(k / area))^4: shift
    # well below it, so the modes nearest the shift are the lowest ones
    shift = -1e-3 * (np.pi * np.sqrt(k / max(area, 1e-300))) ** 4
    mass = np.asarray(ops.M.diagonal(), dtype=np.float64)
    mu, Phi, solver = _eigenpairs(ops, k, tol, shift, mass, solver, check)
    order = np.argsort(mu, kind="stable")
    mu, Phi = canonical_modes(mu[order], Phi[:, order], ops.area, tol=tol)
    sparse = solver is not None and solver.order is not None
    return BendingBasis(
        Phi=np.ascontiguousarray(Phi),
        mu=mu,
        energy=ops.energy,
        seconds=time.perf_counter() - t0,
        order=solver.order if sparse else None,
        order_backend=solver.backend if sparse else None,
    )


def _eigenpairs(
    ops: MeshOperators,
    k: int,
    tol: float,
    shift: float,
    mass: np.ndarray,
    solver: SPDSolver | None,
    check: Callable[[], None] | None,
) -> tuple[np.ndarray, np.ndarray, SPDSolver | None]:
    """The ``k`` lowest pairs of ``Q phi = mu M phi`` for :func:`bending_basis` (arguments
    as there; ``shift`` below the lowest eigenvalue, 1/mm^4, ``mass`` (n,) the diagonal of
    ``M``, mm^2): densely for a small part, else by block shift-invert Lanczos.

    Returns
    -------
    mu : (k,) eigenvalues, 1/mm^4 (unsorted).  Phi : (n, k) M-orthonormal modes.
    solver : the sparse solver that factorised the shifted operator (None when dense and
        none was given).
    """
    n = ops.Q.shape[0]
    # one thread for every BLAS and OpenMP pool: the basis is built beside other work (the
    # free state's judgement), whose core a second thread's spinning waits would take
    # (beside another busy process, many times slower with two threads than with one); the
    # command line sets the same for the whole run
    with ThreadpoolController().limit(limits=1):
        if n <= 4 * (k + BASIS_BLOCK):
            if check is not None:
                check()
            mu, Phi = sla.eigh(ops.Q.toarray(), np.diag(mass), subset_by_index=(0, k - 1))
        else:
            A = (ops.Q - shift * ops.M).tocsc()
            # the shifted operator is SPD: a Cholesky (CHOLMOD) or a symmetric-mode SuperLU
            # factorisation
            solver = solver or SPDSolver()
            fac = solver.factor(A)

            def solve(B: np.ndarray) -> np.ndarray:
                if check is not None:
                    check()
                return fac(B)

            rng = np.random.default_rng(BASIS_SEED)
            # Ritz residuals 100 times below the eigenvalue accuracy: the modes then agree
            # with fully converged ones to ~1e-9 (ARPACK, which always ran its whole Lanczos
            # basis, over-converged as much at tol)
            found = lowest_modes(solve, mass, k, shift, rng, tol=1e-2 * tol, block=BASIS_BLOCK)
            mu, Phi = found.mu, found.Phi
    return mu, Phi, solver


def canonical_modes(
    mu: np.ndarray,
    Phi: np.ndarray,
    mass: np.ndarray,
    tol: float = 1e-6,
    null_rtol: float = 1e-7,
    seed: int = BASIS_SEED,
) -> tuple[np.ndarray, np.ndarray]:
    """Fix the choices an eigen-decomposition ``Q phi = mu M phi`` leaves open.

    * **Sign.** Each mode of a simple eigenvalue is turned to make ``phi^T M g`` positive,
      ``g`` a fixed pseudo-random field (standard normal per vertex, seeded): a generic
      field, so ``|phi^T M g|`` is never near zero by symmetry of the part (as the largest
      component or a coordinate field would be on a mirror-symmetric part, where the
      antisymmetric modes tie); a perturbation ``eps`` of the modes flips a sign with
      probability ~``eps``.
    * **Clusters.** Eigenvalues closer than ``10 tol`` (relative; the eigen-solver cannot
      tell them apart) span a subspace whose basis the solver picks arbitrarily. It is
      replaced by a canonical one: the successive M-orthonormalised projections of fixed
      fields onto the subspace (QR with a positive diagonal), all sharing the cluster's mean
      eigenvalue, so the subspace's stiffness does not depend on the rotation either.
    * **Null space.** The modes with ``mu <= null_rtol * max(mu)`` (the affine or constant
      fields, round-off eigenvalues) form one cluster whose eigenvalue is set to 0; the
      first field is the constant (in the null space of both bending energies), so its
      first mode is the M-normalised constant.

    Parameters
    ----------
    mu : (k,) eigenvalues, ascending.
    Phi : (n, k) M-orthonormal modes.
    mass : (n,) diagonal of ``M``.
    tol : relative accuracy of the eigenvalues (the cluster width is ``10 tol``).
    null_rtol : null-space threshold relative to the largest eigenvalue.
    seed : seed of the reference fields.

    Returns
    -------
    mu, Phi : the same spectrum (clusters at their mean, the null space at 0) and modes of
        the same subspaces, M-orthonormal, in a canonical basis.
    """
    mu = np.maximum(np.array(mu, dtype=np.float64), 0.0)
    Phi = np.array(Phi, dtype=np.float64)
    n, k = Phi.shape
    if k == 0:
        return mu, Phi
    top = float(mu[-1])
    null = mu <= null_rtol * top if top > 0 else np.ones(k, dtype=bool)
    # cluster boundaries: a new cluster starts where the gap exceeds 10 tol (relative)
    starts = [0]
    for j in range(1, k):
        if null[j] and null[j - 1]:
            continue
        if null[j] != null[j - 1] or mu[j] - mu[j - 1] > 10.0 * tol * mu[j]:
            starts.append(j)
    bounds = list(zip(starts, starts[1:] + [k], strict=True))
    widest = max(b - a for a, b in bounds)
    # reference fields: the constant (the null space holds it), then standard normal fields,
    # each its own block of draws (the sign field does not depend on the widest cluster)
    G = np.ones((widest + 1, n))
    G[1:] = np.random.default_rng(seed).standard_normal((widest, n))
    S = Phi.T @ (mass[:, None] * G.T)  # (k, widest + 1): the fields' projections on the modes
    flip = np.ones(k)
    for a, b in bounds:
        c = b - a
        B = S[a:b, :c] if null[a] else S[a:b, 1 : c + 1]  # the fields in the cluster's basis
        if c == 1:
            flip[a] = -1.0 if B[0, 0] < 0.0 else 1.0
        else:
            U, R = np.linalg.qr(B)
            U *= np.where(np.diag(R) < 0.0, -1.0, 1.0)
            Phi[:, a:b] = Phi[:, a:b] @ U
        mu[a:b] = 0.0 if null[a] else float(mu[a:b].mean())
    Phi *= flip  # exact: a sign
    return mu, Phi
