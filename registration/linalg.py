"""Sparse symmetric positive-definite solves, with CHOLMOD when available.

CHOLMOD (``scikit-sparse``) is an optional accelerator: a sparse Cholesky factorisation
that reuses its symbolic analysis across the GB-CICP iterations (the sparsity pattern of
``W + lambda Q`` never changes). Without it, SuperLU from scipy is used in symmetric mode;
given the unknowns' positions, on the matrix reordered by a geometric nested dissection
(:func:`qifreport.registration.ordering.nested_dissection`), which factorises the bending
systems of large parts about twice as fast as SuperLU's own minimum-degree order (the same
on tens of thousands of vertices).

The environment variable ``QIFREPORT_SPARSE=superlu`` makes ``"auto"`` take SuperLU even
where CHOLMOD is installed (to compare the two paths on one machine).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from threadpoolctl import ThreadpoolController

from .ordering import nested_dissection

__all__ = [
    "have_cholmod",
    "default_backend",
    "NotPositiveDefinite",
    "SPDSolver",
]

try:  # optional accelerator
    from sksparse.cholmod import CholmodError
    from sksparse.cholmod import analyze as _cholmod_analyze
except Exception:  # pragma: no cover - depends on the machine
    _cholmod_analyze = None
    CholmodError = RuntimeError

log = logging.getLogger(__name__)

#: environment variable that overrides the ``"auto"`` choice (``superlu`` or ``cholmod``)
BACKEND_ENV = "QIFREPORT_SPARSE"

#: CHOLMOD's ordering of a mesh's system (a solver given the unknowns' ``points``). Its
#: default takes AMD unless AMD's fill is large, and so AMD on the fandisk's bending system,
#: where METIS's nested dissection fills a quarter less and factorises faster, for an
#: analysis paid once per part (the basis keeps the order); on the large sheet of
#: ``bench/scale.py`` the default takes METIS already (``python bench/factorisation.py``).
CHOLMOD_MESH_ORDERING = "metis"


def have_cholmod() -> bool:
    """Whether the CHOLMOD accelerator is importable."""
    return _cholmod_analyze is not None


def default_backend() -> str:
    """The backend ``"auto"`` takes: ``$QIFREPORT_SPARSE`` if set, else ``"cholmod"`` when
    scikit-sparse is importable, else ``"superlu"``."""
    chosen = os.environ.get(BACKEND_ENV, "").strip().lower()
    if chosen:
        if chosen not in ("cholmod", "superlu"):
            raise ValueError(f"{BACKEND_ENV}={chosen!r}: expected 'cholmod' or 'superlu'")
        return chosen
    return "cholmod" if have_cholmod() else "superlu"


class NotPositiveDefinite(ValueError):
    """A factorisation of :class:`SPDSolver` broke down."""


class SPDSolver:
    """Factorise a sequence of SPD matrices sharing one sparsity pattern.

    Parameters
    ----------
    backend : ``"auto"`` (:func:`default_backend`), ``"cholmod"`` or ``"superlu"``.
    points : (n, d) positions of the unknowns (mm), optional: the unknowns lie on a surface
        mesh, whose systems a nested dissection orders best. With SuperLU, the first
        matrix's pattern and these positions give a geometric nested-dissection order; with
        CHOLMOD, its analysis takes METIS's (:data:`CHOLMOD_MESH_ORDERING`) instead of its
        default choice. Either is kept for the sequence.
    order : (n,) a fill-reducing permutation of the unknowns, instead of finding one: for
        SuperLU instead of ``points`` (e.g. a block order keeping each vertex's unknowns
        together; with neither, SuperLU's own minimum-degree order is used); for CHOLMOD
        instead of its analysis' ordering (AMD or METIS, whose search is costly on a large
        part). An earlier solver's :attr:`order` for the same pattern gives its very
        factors: the same solutions, bit for bit.
    """

    def __init__(
        self,
        backend: str = "auto",
        points: np.ndarray | None = None,
        order: np.ndarray | None = None,
    ) -> None:
        if backend == "auto":
            backend = default_backend()
        if backend not in ("cholmod", "superlu"):
            raise ValueError(f"unknown sparse backend {backend!r}")
        if backend == "cholmod" and not have_cholmod():
            raise RuntimeError("CHOLMOD requested but scikit-sparse is not installed")
        self.backend = backend
        self.points = None if points is None else np.asarray(points, dtype=np.float64)
        self._symbolic = None
        self._pools: ThreadpoolController | None = None
        self._perm: np.ndarray | None = None
        self._inv: np.ndarray | None = None
        if order is not None:
            self._set_order(np.asarray(order, dtype=np.int64))

    def _set_order(self, perm: np.ndarray) -> None:
        self._perm = perm
        self._inv = np.empty_like(perm)
        self._inv[perm] = np.arange(len(perm))

    def _one_thread(self):
        """CHOLMOD's BLAS (the system's OpenBLAS) and OpenMP on one thread for the call.

        A solve of one vector is a pair of triangular sweeps: a second BLAS thread gains
        nothing, and its spinning wait takes the core from other work: beside another busy
        process, the fandisk's bending basis (202 solves) is several times slower with every
        pool at two threads than with CHOLMOD's at one, and fastest with all at one, as
        :func:`~qifreport.registration.deformable.bending_basis.bending_basis` and the command
        line set; a large factorisation is only slightly slower on one thread."""
        if self._pools is None:
            self._pools = ThreadpoolController()
        return self._pools.limit(limits=1)

    @property
    def order(self) -> np.ndarray | None:
        """(n,) the fill-reducing permutation the factorisations use, once the first one is
        made (None before, and for SuperLU's own minimum-degree order): CHOLMOD's choice, or
        the one given. Another solver of the same pattern and backend given it
        (``SPDSolver(order=...)``) skips the search and factorises exactly as this one."""
        if self._perm is not None:
            return self._perm
        if self.backend == "cholmod" and self._symbolic is not None:
            return np.asarray(self._symbolic.P(), dtype=np.int64)
        return None

    def factor(self, A: sp.spmatrix) -> Callable[[np.ndarray], np.ndarray]:
        """Factorise ``A`` (symmetric positive definite) and return ``solve(b)`` for (n,) or
        (n, k) ``b``.

        Raises
        ------
        NotPositiveDefinite
            The factorisation breaks down: ``A`` is not positive definite in floating
            point (singular, or too ill-conditioned)."""
        try:
            return self._factor(sp.csc_matrix(A))
        except (CholmodError, RuntimeError) as e:
            raise NotPositiveDefinite(f"the matrix is not positive definite ({e})") from None

    def _factor(self, A: sp.csc_matrix) -> Callable[[np.ndarray], np.ndarray]:
        if self.backend == "cholmod":
            if self._perm is not None:
                return self._factor_cholmod_ordered(A)
            with self._one_thread():
                if self._symbolic is None:
                    self._symbolic = self._analyze(A)
                f = self._symbolic.cholesky(A)

            def solve_cholmod(b: np.ndarray) -> np.ndarray:
                with self._one_thread():
                    return f(b)

            return solve_cholmod
        if self._perm is None and self.points is not None:
            if len(self.points) != A.shape[0]:
                raise ValueError(f"{len(self.points)} points for a {A.shape[0]}-unknown system")
            self._set_order(nested_dissection(self.points, A))
        if self._perm is None:
            lu = spla.splu(
                A,
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.0,
                options={"SymmetricMode": True},
            )
            return lu.solve
        p, inv = self._perm, self._inv
        lu = spla.splu(
            self._reordered(A),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )

        def solve(b: np.ndarray) -> np.ndarray:
            return lu.solve(np.ascontiguousarray(b[p]))[inv]

        return solve

    def _reordered(self, A: sp.csc_matrix) -> sp.csc_matrix:
        """``A`` with its rows and columns in the solver's order (``ValueError`` for an order
        of another size)."""
        p = self._perm
        if len(p) != A.shape[0]:
            raise ValueError(f"an order of {len(p)} for a {A.shape[0]}-unknown system")
        return sp.csc_matrix(A[p][:, p])

    def _analyze(self, A: sp.csc_matrix):
        """CHOLMOD's symbolic analysis of ``A``: METIS's order for a mesh's system (given
        ``points``), its default choice otherwise or where CHOLMOD was built without METIS."""
        if self.points is not None:
            try:
                return _cholmod_analyze(A, ordering_method=CHOLMOD_MESH_ORDERING)
            except CholmodError as exc:  # a CHOLMOD without METIS (its Partition module)
                log.info(
                    "CHOLMOD ordering %s unavailable (%s): its default", CHOLMOD_MESH_ORDERING, exc
                )
        return _cholmod_analyze(A)

    def _factor_cholmod_ordered(self, A: sp.csc_matrix) -> Callable[[np.ndarray], np.ndarray]:
        """CHOLMOD on ``A`` reordered by the given permutation, analysed in that (natural)
        order: the factors CHOLMOD makes of ``A`` when its own analysis chose this order (its
        postorder included), so the same solutions, without the search (METIS's, costly on a
        large part)."""
        p, inv = self._perm, self._inv
        Ap = self._reordered(A)
        with self._one_thread():
            if self._symbolic is None:
                self._symbolic = _cholmod_analyze(Ap, ordering_method="natural")
            f = self._symbolic.cholesky(Ap)

        def solve(b: np.ndarray) -> np.ndarray:
            with self._one_thread():
                return np.take(f(np.take(b, p, axis=0)), inv, axis=0)

        return solve
