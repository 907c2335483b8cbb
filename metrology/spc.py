"""Statistical process control over a batch of inspections: capability and pass rates.

A batch inspects many scans of one part (``qifreport batch``); each scan gives, per toleranced
characteristic, a value and a verdict (``PASS``, ``FAIL``, ``NOT ESTABLISHED``), and the scan
as a whole a verdict or ``ERROR`` (no verdict). The value is a surface's *profile value* (mm:
the width of the smallest zone about the band centre holding every scored point, as in the
QIF ``Value``; at least 0), a geometric tolerance's zone (flatness, position ..., mm; at
least 0 too) or a dimension's size (mm, or degrees for an angle). This module computes, from
those plain arrays:

* **Capability of a one-sided characteristic** (:func:`characteristic_stats`: a profile or a
  geometric tolerance) over the scans with a finite value: n, mean, sample standard deviation
  ``s`` (``ddof=1``), minimum, maximum, the one-sided upper capability index

      Cpk = (T - mean) / (3 s)

  with ``T`` the tolerance (the upper limit; the value's lower limit is 0), and the relative
  margin ``(T - max) / T`` of the worst scan. Without rational subgroups the index is what
  AIAG SPC calls ``Ppk``; it is named Cpk as in the report and the QIF.
* **Capability of a dimension** (:func:`dimension_stats`), between its lower and upper limits
  ``LSL`` and ``USL`` (:func:`capability`)::

      Cp  = (USL - LSL) / (6 s)
      Cpk = min(USL - mean, mean - LSL) / (3 s)

  A capability index is an estimate from the batch: it is stated (in the report) only from
  :data:`MIN_CAPABILITY_N` values, with its 95 % confidence interval (:func:`cpk_interval`,
  Bissell's normal approximation); a shorter batch is "n too small".

  and the margin of the worst scan to the nearer limit, relative to half the tolerance
  width: ``min(USL - max, min - LSL) / ((USL - LSL) / 2)`` (1 with every value at the middle
  of the limits, 0 on a limit, negative beyond one).
* **Pass rates** -- counts of each verdict (:func:`verdict_counts`), the pass rate PASS /
  (PASS + FAIL + NOT ESTABLISHED) (:func:`pass_rate`), and after each scan the cumulative
  (:func:`cumulative_pass_rate`) and rolling (:func:`rolling_pass_rate`, over a window of
  :func:`rolling_window` scans) pass rates, in %.

Plain numpy; nothing here depends on how the batch is stored or drawn.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

__all__ = [
    "MIN_CAPABILITY_N",
    "VERDICTS",
    "JUDGED",
    "CharacteristicStats",
    "capability",
    "characteristic_stats",
    "cpk_interval",
    "dimension_stats",
    "upper_cpk",
    "verdict_counts",
    "pass_rate",
    "cumulative_pass_rate",
    "rolling_pass_rate",
    "rolling_window",
    "ROLLING_MIN_SCANS",
]

#: verdicts of a scan in a batch, in the order they are counted (ERROR: no verdict)
VERDICTS = ("PASS", "FAIL", "NOT ESTABLISHED", "ERROR")
#: the verdicts that count as judged (the denominator of a pass rate)
JUDGED = ("PASS", "FAIL", "NOT ESTABLISHED")
#: batches shorter than this have no rolling pass rate (scans)
ROLLING_MIN_SCANS = 30
#: values a capability index is stated from, at least (AIAG SPC: 25 subgroups; with fewer
#: the interval of a Cpk of 1.33 spans more than +/-0.4)
MIN_CAPABILITY_N = 25


@dataclass
class CharacteristicStats:
    """Statistics of one characteristic's value over the scans that measured it.

    Attributes
    ----------
    n : scans with a finite value.
    mean, sigma, max : in the value's unit (mm, or degrees for an angle); sigma is the sample
        standard deviation (n - 1), NaN for n < 2.
    cpk : capability index: one-sided upper ``(tolerance - mean) / (3 sigma)`` for a profile
        or a geometric tolerance, ``min(USL - mean, mean - LSL) / (3 sigma)`` for a dimension;
        NaN unless ``n >= 2`` and ``sigma > 0`` (and there is a limit).
    n_pass : scans on which the characteristic passed.
    n_judged : scans on which it has a verdict (PASS, FAIL or NOT ESTABLISHED).
    margin : the worst scan's relative room to its limit (negative beyond it):
        ``(tolerance - max) / tolerance`` for a one-sided tolerance, ``min(USL - max,
        min - LSL) / ((USL - LSL) / 2)`` for a dimension; +inf when nothing was measured or
        there is no limit.
    min : smallest value (NaN when nothing was measured).
    cp : two-sided capability index ``(USL - LSL) / (6 sigma)`` of a dimension with both
        limits; NaN otherwise (a one-sided tolerance has none).
    """

    n: int
    mean: float
    sigma: float
    max: float
    cpk: float
    n_pass: int
    n_judged: int
    margin: float
    min: float = math.nan
    cp: float = math.nan

    @property
    def capable_n(self) -> bool:
        """Enough values to state a capability index (:data:`MIN_CAPABILITY_N`)."""
        return self.n >= MIN_CAPABILITY_N

    def cpk_interval(self) -> tuple[float, float]:
        """The 95 % confidence interval of :attr:`cpk` (:func:`cpk_interval`)."""
        return cpk_interval(self.cpk, self.n)


def upper_cpk(mean: float, sigma: float, tolerance: float, n: int) -> float:
    """One-sided upper capability index ``(tolerance - mean) / (3 sigma)``.

    Parameters
    ----------
    mean, sigma : mean and sample standard deviation of the values, mm.
    tolerance : the upper specification limit, mm.
    n : number of values.

    Returns
    -------
    float
        The index (dimensionless); NaN unless ``n >= 2``, ``sigma > 0`` and the tolerance is
        finite and positive.
    """
    if n >= 2 and sigma > 0 and math.isfinite(tolerance) and tolerance > 0:
        return (tolerance - mean) / (3.0 * sigma)
    return math.nan


def cpk_interval(cpk: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The confidence interval of a capability index ``cpk`` estimated from ``n`` values
    (normal data): ``cpk -/+ z sqrt(1 / (9 n) + cpk^2 / (2 (n - 1)))`` (Bissell 1990;
    ``z`` 1.96: 95 %). NaN for a NaN index or ``n < 2``."""
    if not (math.isfinite(cpk) and n >= 2):
        return math.nan, math.nan
    half = z * math.sqrt(1.0 / (9.0 * n) + cpk * cpk / (2.0 * (n - 1)))
    return cpk - half, cpk + half


def capability(
    mean: float, sigma: float, n: int, lower: float | None, upper: float | None
) -> tuple[float, float]:
    """Capability indices of values against their specification limits.

    Parameters
    ----------
    mean, sigma : mean and sample standard deviation of the values (their unit).
    n : number of values.
    lower, upper : the lower and upper specification limits (same unit); None for a side
        without a limit.

    Returns
    -------
    cp : float
        ``(upper - lower) / (6 sigma)``; NaN unless both limits are given.
    cpk : float
        ``min(upper - mean, mean - lower) / (3 sigma)`` over the sides with a limit; NaN
        without a limit.

    Both are NaN unless ``n >= 2`` and ``sigma > 0`` (finite).
    """
    if not (n >= 2 and math.isfinite(sigma) and sigma > 0 and math.isfinite(mean)):
        return math.nan, math.nan
    sides = []
    if upper is not None and math.isfinite(upper):
        sides.append((upper - mean) / (3.0 * sigma))
    if lower is not None and math.isfinite(lower):
        sides.append((mean - lower) / (3.0 * sigma))
    cpk = min(sides) if sides else math.nan
    cp = math.nan
    if len(sides) == 2:
        cp = (upper - lower) / (6.0 * sigma)
    return cp, cpk


def _summary(values: np.ndarray, statuses: np.ndarray) -> dict:
    """The statistics every characteristic has (``CharacteristicStats`` fields)."""
    v = np.asarray(values, dtype=float)
    status = np.asarray(statuses, dtype=object)
    v = v[np.isfinite(v)]
    n = len(v)
    return {
        "n": n,
        "mean": float(v.mean()) if n else math.nan,
        "sigma": float(v.std(ddof=1)) if n >= 2 else math.nan,
        "max": float(v.max()) if n else math.nan,
        "min": float(v.min()) if n else math.nan,
        "n_pass": int(np.sum(status == "PASS")),
        "n_judged": int(np.isin(status, JUDGED).sum()),
    }


def characteristic_stats(
    values: np.ndarray, statuses: np.ndarray, tolerance: float
) -> CharacteristicStats:
    """Capability statistics of a one-sided characteristic (a profile or a geometric
    tolerance: its value is at least 0 and at most the tolerance) over a batch.

    Parameters
    ----------
    values : (n_scans,) values (profile values, zone widths), mm; NaN where the scan did
        not measure it.
    statuses : (n_scans,) the characteristic's verdict per scan (``"PASS"``, ``"FAIL"``,
        ``"NOT ESTABLISHED"``, anything else: none).
    tolerance : the tolerance (upper limit), mm.

    Returns
    -------
    CharacteristicStats
        Over every scan with a finite value (NOT ESTABLISHED ones included); ``cp`` NaN.
    """
    st = _summary(values, statuses)
    n, vmax = st["n"], st["max"]
    tol = float(tolerance)
    cpk = upper_cpk(st["mean"], st["sigma"], tol, n)
    margin = (tol - vmax) / tol if n and math.isfinite(tol) and tol > 0 else math.inf
    return CharacteristicStats(cpk=cpk, margin=margin, **st)


def dimension_stats(
    values: np.ndarray,
    statuses: np.ndarray,
    lower: float | None,
    upper: float | None,
    nominal: float | None = None,
) -> CharacteristicStats:
    """Capability statistics of a dimension (a size, a distance, an angle) between its
    limits, over a batch.

    Parameters
    ----------
    values : (n_scans,) the measured sizes, mm (degrees for an angle); NaN where the scan
        did not measure it.
    statuses : (n_scans,) the characteristic's verdict per scan, as for
        :func:`characteristic_stats`.
    lower, upper : the lower and upper limits (the value's unit); None for a side without
        one (both None: a basic dimension, reported without a verdict).
    nominal : the dimension's nominal: with a single limit, the margin is relative to the
        distance from the nominal to it.

    Returns
    -------
    CharacteristicStats
        Over every scan with a finite value: ``cp`` and ``cpk`` from :func:`capability`;
        ``margin`` the worst scan's room to the nearer limit relative to half the tolerance
        width (with one limit, to the nominal's distance from it; +inf without a limit, a
        nominal on its single limit, or no value).
    """
    st = _summary(values, statuses)
    n = st["n"]
    lo = float(lower) if lower is not None and math.isfinite(lower) else None
    hi = float(upper) if upper is not None and math.isfinite(upper) else None
    cp, cpk = capability(st["mean"], st["sigma"], n, lo, hi)
    rooms = []
    if hi is not None and n:
        rooms.append(hi - st["max"])
    if lo is not None and n:
        rooms.append(st["min"] - lo)
    if lo is not None and hi is not None:
        scale = 0.5 * (hi - lo)
    elif nominal is not None and (lo is not None or hi is not None):
        scale = abs((hi if hi is not None else lo) - float(nominal))
    else:
        scale = 0.0
    margin = min(rooms) / scale if rooms and scale > 0 else math.inf
    return CharacteristicStats(cpk=cpk, margin=margin, cp=cp, **st)


def verdict_counts(verdicts: np.ndarray) -> dict[str, int]:
    """How many scans have each verdict of :data:`VERDICTS`.

    Parameters
    ----------
    verdicts : (n_scans,) the scans' verdicts (strings).

    Returns
    -------
    dict
        Verdict -> count, every verdict of :data:`VERDICTS` present (0 when none).
    """
    verdicts = np.asarray(verdicts, dtype=object)
    return {v: int(np.sum(verdicts == v)) for v in VERDICTS}


def pass_rate(counts: Mapping[str, int]) -> float:
    """PASS over the scans that produced a verdict (PASS, FAIL, NOT ESTABLISHED).

    Parameters
    ----------
    counts : verdict counts (:func:`verdict_counts`).

    Returns
    -------
    float
        The pass rate as a fraction 0..1; NaN when no scan has a verdict.
    """
    judged = counts["PASS"] + counts["FAIL"] + counts["NOT ESTABLISHED"]
    return counts["PASS"] / judged if judged else math.nan


def cumulative_pass_rate(verdicts: np.ndarray) -> np.ndarray:
    """Pass rate after each scan, over the scans so far, %.

    Parameters
    ----------
    verdicts : (n_scans,) the scans' verdicts in batch order.

    Returns
    -------
    (n_scans,) float array
        100 PASS / (PASS + FAIL + NOT ESTABLISHED) of scans 1..k; NaN until a scan has a
        verdict.
    """
    verdicts = np.asarray(verdicts, dtype=object)
    judged = np.isin(verdicts, JUDGED).astype(float)
    passed = (verdicts == "PASS").astype(float)
    cum_j = np.cumsum(judged)
    cum = np.full(len(verdicts), np.nan)
    np.divide(100.0 * np.cumsum(passed), cum_j, out=cum, where=cum_j > 0)
    return cum


def rolling_window(n_scans: int) -> int:
    """Window of the rolling pass rate for a batch of ``n_scans`` scans.

    Returns
    -------
    int
        A tenth of the batch, between 10 and 200 scans; 0 (no rolling rate) for batches
        shorter than :data:`ROLLING_MIN_SCANS`.
    """
    if n_scans < ROLLING_MIN_SCANS:
        return 0
    return int(np.clip(round(n_scans / 10), 10, 200))


def rolling_pass_rate(verdicts: np.ndarray, window: int) -> np.ndarray:
    """Pass rate after each scan over the last ``window`` scans, %.

    Parameters
    ----------
    verdicts : (n_scans,) the scans' verdicts in batch order.
    window : scans in the window (>= 1).

    Returns
    -------
    (n_scans,) float array
        100 PASS / (PASS + FAIL + NOT ESTABLISHED) of scans ``k - window + 1 .. k``; NaN for
        the first ``window - 1`` scans and for windows without a verdict.
    """
    verdicts = np.asarray(verdicts, dtype=object)
    n = len(verdicts)
    judged = np.isin(verdicts, JUDGED).astype(float)
    passed = (verdicts == "PASS").astype(float)
    kern = np.ones(window)
    rj = np.convolve(judged, kern)[:n]
    rp = np.convolve(passed, kern)[:n]
    roll = np.full(n, np.nan)
    np.divide(100.0 * rp, rj, out=roll, where=(rj > 0) & (np.arange(n) >= window - 1))
    return roll
