"""Order within groups: ``np.lexsort((x, group))`` by one stable sort of a float key.

The robust fits sort hundreds of thousands of (vertex, residual) pairs by vertex, then by
residual, to read each vertex's median; NumPy's ``lexsort`` does that with a merge sort per
key, several times slower than one stable sort of the key ``group + x scaled into [0, 0.5]``.
That key is non-decreasing in ``x`` within a group (rounding is monotone), so it can only
fail to separate two values it rounds to the same key; a stable sort then keeps their input
order, which is checked, and ``lexsort`` answers wherever it is wrong. The order returned is
always ``lexsort``'s, exactly.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sort_within_groups"]

#: groups spread wider than this fall back to lexsort (the key's integer part stays exact
#: and leaves the fraction enough bits to separate most values)
_MAX_GROUP_SPAN = 2**31


def sort_within_groups(group: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The permutation (m,) that sorts by ``group``, then by ``x`` (``np.lexsort((x, group))``).

    Parameters
    ----------
    group : (m,) integer group of each value.  x : (m,) values (any unit).

    Returns
    -------
    (m,) int indices; equal pairs keep their input order (a stable sort, as ``lexsort``).
    """
    group = np.asarray(group)
    x = np.asarray(x, dtype=np.float64)
    if len(x) < 2:
        return np.arange(len(x))
    lo, hi = float(x.min()), float(x.max())
    g0, g1 = int(group.min()), int(group.max())
    if not (np.isfinite(lo) and np.isfinite(hi)) or g1 - g0 >= _MAX_GROUP_SPAN:
        return np.lexsort((x, group))
    frac = (x - lo) * (0.5 / (hi - lo)) if hi > lo else np.zeros(len(x))
    order = np.argsort((group - g0).astype(np.float64) + frac, kind="stable")
    g, v = group[order], x[order]
    if np.any((g[1:] == g[:-1]) & (v[1:] < v[:-1])):  # two values the key did not separate
        return np.lexsort((x, group))
    return order
