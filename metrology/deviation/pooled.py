"""The variance of a vertex's deviation: its own points' scatter pooled with its face's.

A vertex's few points estimate their scatter about the local fit poorly;
:func:`pooled_variance` steadies it with the median scatter of the vertex's B-rep face (or
of the whole part), as :func:`~qifreport.metrology.deviation.local_planes.nominal_referenced`
and :func:`~qifreport.metrology.deviation.residual_fit.residual_referenced` report it.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "pooled_variance",
]


#: pseudo degrees of freedom of the part-wide scatter in each vertex's variance (a vertex's
#: own few points estimate their scatter poorly; the part's median scatter steadies it)
_PRIOR_DOF = 10.0


#: a B-rep face's own median scatter is its vertices' prior when it has this many scored
_MIN_GROUP = 20


def pooled_variance(
    h: np.ndarray, sse: np.ndarray, dof: np.ndarray, group: np.ndarray | None = None
) -> np.ndarray:
    """Variance (n,) mm^2 of each vertex's deviation: its variance factor ``h`` times the
    scatter of its points about their fit, ``sse / dof``, pooled (weight :data:`_PRIOR_DOF`)
    with the median scatter of its ``group`` (the vertex's B-rep face: a face seen at a
    steeper angle carries more range noise along its normal) when that has at least
    :data:`_MIN_GROUP` scored vertices, else of the whole part; NaN where ``h`` is."""
    ok = np.isfinite(h) & (dof > 0)
    prior: float | np.ndarray = float(np.median(sse[ok] / dof[ok])) if ok.any() else 0.0
    if group is not None and ok.any():
        g = np.asarray(group, dtype=np.int64)
        per_group = np.full(int(g.max()) + 2, prior)  # the last slot: no group (-1)
        idx = np.flatnonzero(ok & (g >= 0))
        order = idx[np.argsort(g[idx], kind="stable")]
        keys, starts, counts = np.unique(g[order], return_index=True, return_counts=True)
        for k, s0, c in zip(keys, starts, counts, strict=True):
            if c >= _MIN_GROUP:
                members = order[s0 : s0 + c]
                per_group[k] = float(np.median(sse[members] / dof[members]))
        prior = per_group[g]
    with np.errstate(invalid="ignore", divide="ignore"):
        s2 = (np.where(ok, sse, 0.0) + _PRIOR_DOF * prior) / (np.where(ok, dof, 0.0) + _PRIOR_DOF)
    return np.where(np.isfinite(h), h * s2, np.nan)
