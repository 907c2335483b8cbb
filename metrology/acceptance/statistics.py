"""Summary statistics of a deviation field (paper Sections 7.2, 8.4.5 and 10).

The report states the bulk statistics (RMS, mean, 95th percentile, maximum) *and* the tail
statistics (99th and 99.9th percentiles, the fraction beyond a stated threshold), because
a localized defect barely moves the former while it dominates the latter (Section 8.4.5).

Weights
-------
With ``weights`` (typically the vertex areas of the scored nominal vertices, mm^2) every
statistic is a statistic of the *area* rather than of the vertex count: the RMS is
``sqrt(sum w e^2 / sum w)``, the mean ``sum w e / sum w``, a fraction is the share of the
total weight, and the percentiles are taken from the weighted distribution function
(below). A weight of 2 is exactly equivalent to listing the sample twice. Extremes (max,
min) do not depend on weights. Samples whose deviation is NaN (unscored) or whose weight is
zero are ignored.

Weighted percentile (inverted CDF)
----------------------------------
Sort the values ``x_1 <= ... <= x_n`` with weights ``w_k > 0`` and cumulative weights
``W_k = w_1 + ... + w_k``; the ``p``-th percentile is the smallest ``x_k`` with
``W_k >= (p / 100) * W_n``. It is always one of the samples (no interpolation), and with
equal weights it is exactly ``np.percentile(x, p, method="inverted_cdf")``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "deviation_statistics",
    "DeviationStats",
    "json_float",
    "tail_fractions",
    "weighted_percentile",
]


def json_float(x: float | None) -> float | None:
    """Plain ``float``, with NaN/inf mapped to ``None`` so the result is strict JSON."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass
class DeviationStats:
    """Summary of a (signed) deviation field, mm.

    Attributes
    ----------
    n : number of samples used (non-NaN deviation and, if weighted, positive weight).
    rms : root mean square of the deviation, mm.
    mean : signed mean, mm.
    max_abs : largest ``|dev|``, mm.
    max_pos : largest signed deviation (most proud), mm.
    min_neg : smallest signed deviation (most sunk), mm. ``max_pos`` and ``min_neg`` are
        the signed extremes; if every deviation is negative, ``max_pos`` is negative too.
    p95, p99, p999 : 95th, 99th and 99.9th percentiles of ``|dev|`` (inverted CDF), mm.
    threshold : the threshold of the fractions below, mm, or None.
    frac_above : share with ``dev > +threshold``.
    frac_below : share with ``dev < -threshold``.
    frac_beyond : share with ``|dev| > threshold`` (= frac_above + frac_below).
    weighted : whether shares, means and percentiles are weighted (area-weighted).

    Statistics of an empty field are NaN; the fractions are NaN without a threshold.
    """

    n: int
    rms: float
    mean: float
    max_abs: float
    max_pos: float
    min_neg: float
    p95: float
    p99: float
    p999: float
    threshold: float | None
    frac_above: float
    frac_below: float
    frac_beyond: float
    weighted: bool

    def to_dict(self) -> dict:
        """JSON-ready dict: plain ``int``/``float``/``bool``; NaN becomes ``None``."""
        out: dict = {}
        for key, value in asdict(self).items():
            if isinstance(value, (bool, np.bool_)):
                out[key] = bool(value)
            elif key == "n":
                out[key] = int(value)
            else:
                out[key] = json_float(value)
        return out


def _clean(dev: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Drop NaN deviations and zero weights; validate shapes and signs."""
    dev = np.asarray(dev, dtype=np.float64).ravel()
    if weights is None:
        return dev[~np.isnan(dev)], None
    w = np.asarray(weights, dtype=np.float64).ravel()
    if w.shape != dev.shape:
        raise ValueError(f"weights shape {w.shape} does not match deviations {dev.shape}")
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    keep = ~np.isnan(dev) & (w > 0)
    w = w[keep]
    # scale to a maximum of 1: equal weights become exactly 1.0, so cumulative sums are
    # exact integers and the percentiles match numpy's inverted_cdf bit for bit
    if len(w):
        w = w / w.max()
    return dev[keep], w


def weighted_percentile(
    x: np.ndarray, q: float | np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Percentile(s) ``q`` (0-100) of ``x`` by the inverted weighted CDF (module docstring).

    NaN entries of ``x`` and zero weights are ignored; an empty input gives NaN.
    """
    x, w = _clean(x, weights)
    q = np.asarray(q, dtype=np.float64)
    if np.any((q < 0) | (q > 100)):
        raise ValueError("percentiles must lie in [0, 100]")
    if len(x) == 0:
        return np.full(q.shape, np.nan)
    order = np.argsort(x, kind="stable")
    xs = x[order]
    cw = np.arange(1.0, len(x) + 1.0) if w is None else np.cumsum(w[order])
    target = (q / 100.0) * cw[-1]
    k = np.searchsorted(cw, target, side="left")  # first k with cw[k] >= target
    return xs[np.minimum(k, len(xs) - 1)]


def _share(mask: np.ndarray, w: np.ndarray | None) -> float:
    if len(mask) == 0:
        return math.nan
    if w is None:
        return float(np.count_nonzero(mask)) / len(mask)
    return float(w[mask].sum() / w.sum())


def deviation_statistics(
    dev: np.ndarray, weights: np.ndarray | None = None, threshold: float | None = None
) -> DeviationStats:
    """Bulk and tail statistics of a signed deviation field.

    Parameters
    ----------
    dev : (n,) signed deviations, mm; NaN marks unscored samples and is ignored.
    weights : (n,) non-negative weights, e.g. vertex areas in mm^2; every statistic
        (rms, mean, percentiles, fractions) is then weighted (module docstring).
    threshold : mm; if given, the shares above ``+threshold``, below ``-threshold`` and
        beyond ``|threshold|`` are reported (strict inequalities).

    Returns
    -------
    DeviationStats. An empty (or all-NaN) field gives ``n = 0`` and NaN statistics.
    """
    x, w = _clean(dev, weights)
    n = len(x)
    if threshold is not None:
        threshold = float(threshold)
    nan = math.nan
    if n == 0:
        return DeviationStats(
            n=0,
            rms=nan,
            mean=nan,
            max_abs=nan,
            max_pos=nan,
            min_neg=nan,
            p95=nan,
            p99=nan,
            p999=nan,
            threshold=threshold,
            frac_above=nan,
            frac_below=nan,
            frac_beyond=nan,
            weighted=weights is not None,
        )
    a = np.abs(x)
    if w is None:
        rms = float(np.sqrt(np.mean(x * x)))
        mean = float(np.mean(x))
    else:
        rms = float(np.sqrt(np.sum(w * x * x) / w.sum()))
        mean = float(np.sum(w * x) / w.sum())
    p95, p99, p999 = (float(v) for v in weighted_percentile(a, [95.0, 99.0, 99.9], w))
    if threshold is None:
        above = below = beyond = nan
    else:
        above = _share(x > threshold, w)
        below = _share(x < -threshold, w)
        beyond = _share(a > threshold, w)
    return DeviationStats(
        n=n,
        rms=rms,
        mean=mean,
        max_abs=float(a.max()),
        max_pos=float(x.max()),
        min_neg=float(x.min()),
        p95=p95,
        p99=p99,
        p999=p999,
        threshold=threshold,
        frac_above=above,
        frac_below=below,
        frac_beyond=beyond,
        weighted=weights is not None,
    )


def tail_fractions(
    dev: np.ndarray, thresholds, weights: np.ndarray | None = None
) -> dict[float, float]:
    """Share of the field with ``|dev| > t`` for each threshold ``t`` (mm).

    NaN deviations are ignored; with ``weights`` the shares are weighted (area shares).
    Returns ``{float(t): share}``; shares are NaN for an empty field.
    """
    x, w = _clean(dev, weights)
    a = np.abs(x)
    return {float(t): _share(a > float(t), w) for t in np.atleast_1d(thresholds)}
