"""Linear programmes with many more inequality rows than unknowns, solved on their active
rows.

A minimum-zone or tangent fit of ``m`` scan points is a linear programme in a handful of
unknowns with ``m`` (or ``2 m``) inequality rows, of which only a few (the points that
touch the zone) bind at the optimum. :func:`linprog_active` solves it on a small set of
rows, checks every row against that solution, adds the rows it violates and solves again
(constraint generation, a cutting-plane method). A solution of the reduced programme that
satisfies every row is optimal for the whole programme: it minimises over a larger set
with the same objective. The result is the whole programme's optimum, reached on a few
hundred rows instead of tens of thousands.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import OptimizeResult, linprog

__all__ = ["FEASIBILITY", "linprog_active"]

#: a row holds when ``A_ub x - b_ub`` is at most this times ``1 + max |b_ub|`` (HiGHS'
#: own primal feasibility tolerance is 1e-7 absolute)
FEASIBILITY = 1e-10
#: rows solved on first, and added per round (the most violated)
_START = 64
#: rounds before the whole programme is solved instead
_ROUNDS = 30


def linprog_active(
    c: np.ndarray,
    A_ub: np.ndarray,
    b_ub: np.ndarray,
    bounds: list[tuple[float | None, float | None]],
) -> OptimizeResult:
    """``min c x`` subject to ``A_ub x <= b_ub`` and ``bounds`` (HiGHS), solved on the rows
    tightest at ``x = 0`` and grown by the violated ones until its solution satisfies all.

    The first rows are the :data:`_START` smallest ``b_ub`` (the tightest at 0: the
    callers' unknowns are small changes of an estimate) and :data:`_START` rows spread
    evenly over all (the rows of a point cloud come in its order: the spread ones keep a
    programme bounded); each round adds up to :data:`_START` of the most violated.

    Parameters
    ----------
    c : (k,) objective.  A_ub : (M, k) inequality rows.  b_ub : (M,) their bounds.
    bounds : per unknown, as :func:`scipy.optimize.linprog`'s.

    Returns
    -------
    scipy.optimize.OptimizeResult
        :func:`~scipy.optimize.linprog`'s result on the last reduced programme (``status``
        0 when solved; its ``x`` satisfies every row within :data:`FEASIBILITY`), or on
        the whole programme when it is small or the rounds did not settle.
    """
    M, start = len(b_ub), _START
    if M <= 4 * start:
        return linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    tol = FEASIBILITY * (1.0 + float(np.abs(b_ub).max()))
    rows = np.union1d(np.argpartition(b_ub, start)[:start], _spread(M, start, 0))
    for k in range(1, _ROUNDS + 1):
        res = linprog(c, A_ub=A_ub[rows], b_ub=b_ub[rows], bounds=bounds, method="highs")
        if res.status != 0:
            # unbounded or degenerate on these rows: more of them, spread over all
            if len(rows) > M // 4:
                break
            rows = np.union1d(rows, _spread(M, 4 * len(rows), k))
            continue
        excess = A_ub @ res.x - b_ub
        out = np.flatnonzero(excess > tol)
        if not len(out):
            return res
        worst = out[np.argsort(-excess[out], kind="stable")[:start]]
        rows = np.union1d(rows, worst)
    return linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")


def _spread(M: int, n: int, shift: int) -> np.ndarray:
    """``n`` row indices of ``0..M-1`` spread evenly, started ``shift`` rows in."""
    return np.unique((np.linspace(0, M, n, endpoint=False).astype(np.int64) + shift) % M)
