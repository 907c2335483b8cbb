"""Statistical process control over a batch of inspections: capability and pass rates.

A batch inspects many scans of one part (``qifreport batch``); each scan gives, per toleranced
characteristic, a *profile value* (mm: the width of the smallest zone about the band centre
holding every scored point, as in the QIF ``Value``; at least 0) and a verdict (``PASS``,
``FAIL``, ``NOT ESTABLISHED``), and the scan as a whole a verdict or ``ERROR`` (no verdict).
This module computes, from those plain arrays:

* **Capability of a characteristic** (:func:`characteristic_stats`) over the scans with a
  finite profile value: n, mean, sample standard deviation ``s`` (``ddof=1``), maximum, the
  one-sided upper capability index

      Cpk = (T - mean) / (3 s)

  with ``T`` the profile tolerance (the upper limit; a profile value's lower limit is 0), and
  the relative margin ``(T - max) / T`` of the worst scan. Without rational subgroups the
  index is what AIAG SPC calls ``Ppk``; it is named Cpk as in the report and the QIF.
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
    "VERDICTS",
    "JUDGED",
    "CharacteristicStats",
    "characteristic_stats",
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


@dataclass
class CharacteristicStats:
    """Statistics of one characteristic's profile value over the scans that measured it.

    Attributes
    ----------
    n : scans with a finite profile value.
    mean, sigma, max : mm; sigma is the sample standard deviation (n - 1), NaN for n < 2.
    cpk : one-sided upper capability ``(tolerance - mean) / (3 sigma)``; NaN unless
        ``n >= 2`` and ``sigma > 0`` (and the tolerance is positive).
    n_pass : scans on which the characteristic passed.
    n_judged : scans on which it has a verdict (PASS, FAIL or NOT ESTABLISHED).
    margin : ``(tolerance - max) / tolerance``, the worst scan's relative room below the
        tolerance (negative beyond it); +inf when nothing was measured.
    """

    n: int
    mean: float
    sigma: float
    max: float
    cpk: float
    n_pass: int
    n_judged: int
    margin: float


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


def characteristic_stats(
    values: np.ndarray, statuses: np.ndarray, tolerance: float
) -> CharacteristicStats:
    """Capability statistics of one characteristic over a batch.

    Parameters
    ----------
    values : (n_scans,) profile values, mm; NaN where the scan did not measure it.
    statuses : (n_scans,) the characteristic's verdict per scan (``"PASS"``, ``"FAIL"``,
        ``"NOT ESTABLISHED"``, anything else: none).
    tolerance : the profile tolerance (upper limit), mm.

    Returns
    -------
    CharacteristicStats
        Over every scan with a finite profile value (NOT ESTABLISHED ones included).
    """
    v = np.asarray(values, dtype=float)
    status = np.asarray(statuses, dtype=object)
    v = v[np.isfinite(v)]
    n = len(v)
    tol = float(tolerance)
    mean = float(v.mean()) if n else math.nan
    sigma = float(v.std(ddof=1)) if n >= 2 else math.nan
    vmax = float(v.max()) if n else math.nan
    cpk = upper_cpk(mean, sigma, tol, n)
    margin = (tol - vmax) / tol if n and math.isfinite(tol) and tol > 0 else math.inf
    judged = np.isin(status, JUDGED)
    return CharacteristicStats(
        n=n,
        mean=mean,
        sigma=sigma,
        max=vmax,
        cpk=cpk,
        n_pass=int(np.sum(status == "PASS")),
        n_judged=int(judged.sum()),
        margin=margin,
    )


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
