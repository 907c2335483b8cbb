"""Sparse symmetric positive-definite solves, with CHOLMOD when available.

CHOLMOD (``scikit-sparse``) is an optional accelerator: it reuses the symbolic analysis
across the GB-CICP iterations (the sparsity pattern of ``W + lambda Q`` never changes).
Without it, SuperLU from scipy is used in symmetric mode.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = [
    "have_cholmod",
    "SPDSolver",
]

try:  # optional accelerator
    from sksparse.cholmod import analyze as _cholmod_analyze
except Exception:  # pragma: no cover - depends on the machine
    _cholmod_analyze = None


def have_cholmod() -> bool:
    """Whether the CHOLMOD accelerator is importable."""
    return _cholmod_analyze is not None


class SPDSolver:
    """Factorise a sequence of SPD matrices sharing one sparsity pattern.

    Parameters
    ----------
    backend : ``"auto"`` (CHOLMOD if importable, else SuperLU), ``"cholmod"`` or ``"superlu"``.
    """

    def __init__(self, backend: str = "auto") -> None:
        if backend == "auto":
            backend = "cholmod" if have_cholmod() else "superlu"
        if backend == "cholmod" and not have_cholmod():
            raise RuntimeError("CHOLMOD requested but scikit-sparse is not installed")
        self.backend = backend
        self._symbolic = None

    def factor(self, A: sp.spmatrix) -> Callable[[np.ndarray], np.ndarray]:
        """Factorise ``A`` (symmetric positive definite) and return ``solve(b)``."""
        A = sp.csc_matrix(A)
        if self.backend == "cholmod":
            if self._symbolic is None:
                self._symbolic = _cholmod_analyze(A)
            f = self._symbolic.cholesky(A)
            return f
        lu = spla.splu(
            A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
        return lu.solve
