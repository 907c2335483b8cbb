"""The batch data a trend page shows: the characteristics charted, and each scan's values,
statuses and verdict read from the batch summary, with their statistics."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from datetime import datetime

import numpy as np
import pandas as pd

from qifreport.metrology import spc
from qifreport.metrology.spc import CharacteristicStats

from ..kit import DASH

log = logging.getLogger("qifreport.reports.trend")

#: the widest serial number under a tick, points (ticks are at least 42 points apart)
SERIAL_LABEL_WIDTH = 38.0

__all__ = [
    "KINDS",
    "VERDICTS",
    "TrendCharacteristic",
    "TrendData",
    "characteristic_stats",
    "column",
    "fmt_rate",
]

#: verdicts of the summary table, in the order they are counted
VERDICTS = spc.VERDICTS
#: the kinds of :class:`TrendCharacteristic`
KINDS = ("profile", "geometric", "dimension")
#: point colour names, beside the verdicts: a value without a verdict (a basic dimension)
POINT_KINDS = ("BASIC", "PASS", "NOT ESTABLISHED", "FAIL")


@dataclass
class TrendCharacteristic:
    """A toleranced characteristic of the part, a column pair of the batch summary.

    Attributes
    ----------
    key : zone key, e.g. ``"T1"`` or ``"general"``, or a feature characteristic's key
        (``"G1"``, ``"D3"``); the summary columns are :attr:`value_column` and
        ``status_<key>``.
    description : what the tolerance is, e.g. ``"surface profile 1 mm |A|B|C| ..."``.
    tolerance_mm : a profile's or geometric tolerance's tolerance (the zone width), the
        upper limit of its value, mm; NaN for a dimension (its limits are ``lower`` and
        ``upper``).
    kind : ``"profile"`` (a toleranced surface, the default), ``"geometric"`` (a geometric
        tolerance of the drawing: flatness, position ...; one-sided like a profile) or
        ``"dimension"`` (two-sided: between ``lower`` and ``upper``).
    lower, upper : a dimension's limits, in ``unit``; None for a side without one (both
        None: a basic dimension, charted without limits or verdict).
    nominal : a dimension's nominal, in ``unit`` (None if not known).
    unit : of the values: ``"mm"``, or ``"deg"`` for an angle.
    quantity : what the value is, for the axis title (``"profile"``, ``"flatness"``,
        ``"diameter"`` ...).
    column : the summary column of the value; default ``profile_<key>_mm`` for a profile,
        ``value_<key>_<unit>`` otherwise (:func:`qifreport.batch.task.characteristic_columns`).
    """

    key: str
    description: str
    tolerance_mm: float
    kind: str = "profile"
    lower: float | None = None
    upper: float | None = None
    nominal: float | None = None
    unit: str = "mm"
    quantity: str = "profile"
    column: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind {self.kind!r} is not one of {KINDS}")

    @property
    def value_column(self) -> str:
        """The summary column of the value."""
        if self.column:
            return self.column
        if self.kind == "profile":
            return f"profile_{self.key}_mm"
        return f"value_{self.key}_{self.unit}"

    @property
    def two_sided(self) -> bool:
        """A dimension (its axis around its limits), not a one-sided tolerance from 0."""
        return self.kind == "dimension"

    def limits(self) -> list[tuple[str, float]]:
        """The limit lines of its chart, (label, value): ``tol`` or ``LSL``/``USL``."""
        if not self.two_sided:
            tol = float(self.tolerance_mm)
            return [("tol", tol)] if math.isfinite(tol) and tol > 0 else []
        out = []
        for label, x in (("USL", self.upper), ("LSL", self.lower)):
            if x is not None and math.isfinite(x):
                out.append((label, float(x)))
        return out


def column(df: pd.DataFrame, name: str, kind: type) -> np.ndarray:
    """Column ``name`` as floats (NaN where missing) or strings ("" where missing)."""
    if name not in df.columns:
        return np.full(len(df), np.nan) if kind is float else np.full(len(df), "", dtype=object)
    col = df[name]
    if kind is float:
        return pd.to_numeric(col, errors="coerce").to_numpy(dtype=float)
    return col.fillna("").astype(str).str.strip().to_numpy(dtype=object)


def characteristic_stats(df: pd.DataFrame, ch: TrendCharacteristic) -> CharacteristicStats:
    """The statistics printed above a characteristic's run chart: those of
    :func:`qifreport.metrology.spc.characteristic_stats` (a profile or geometric tolerance)
    or :func:`qifreport.metrology.spc.dimension_stats` (a dimension) on its columns of the
    summary.

    Parameters
    ----------
    df : the batch summary (one row per scan).
    ch : the characteristic.

    Returns
    -------
    CharacteristicStats
        Over every scan with a finite value (NOT ESTABLISHED ones included).
    """
    values = column(df, ch.value_column, float)
    status = column(df, f"status_{ch.key}", str)
    if ch.two_sided:
        return spc.dimension_stats(values, status, ch.lower, ch.upper, ch.nominal)
    return spc.characteristic_stats(values, status, ch.tolerance_mm)


def fmt_rate(rate: float) -> str:
    """A pass rate (0..1) as a percentage with one decimal, or a dash."""
    return f"{100.0 * rate:.1f} %" if math.isfinite(rate) else DASH


class TrendData:
    """The batch summary as the trend page reads it: per scan its sequence number, verdict
    and, per characteristic, value and status; the verdict counts, the pass rate and each
    characteristic's statistics.

    Attributes
    ----------
    df : the summary, index reset.  chars : the characteristics, in the caller's order.
    part_name, created, sha : the part, the batch's time, the nominal's SHA-256 ("" unknown).
    n : number of scans.  seq : each scan's sequence number, shape (n,) (NaN if not read).
    pos : x positions, the batch order 1..n, shape (n,).  verdict : shape (n,), strings.
    counts : scans per verdict.  rate : pass rate, 0..1 (NaN without a verdict).
    stats, values, status : per characteristic key: its statistics, values (shape (n,),
        NaN not measured) and statuses (shape (n,), strings).
    profiles_only : only surface profiles are charted (the page reads as before feature
        characteristics were).
    """

    def __init__(
        self,
        df: pd.DataFrame,
        characteristics: list[TrendCharacteristic],
        part_name: str,
        created: datetime,
        nominal_sha256: str | None,
    ):
        self.df = df.reset_index(drop=True)
        self.chars = list(characteristics)
        self.part_name = part_name
        self.created = created
        self.sha = nominal_sha256 or ""
        self.n = len(self.df)
        if "seq" in self.df.columns:
            self.seq = pd.to_numeric(self.df["seq"], errors="coerce").to_numpy(dtype=float)
        else:
            self.seq = np.arange(1, self.n + 1, dtype=float)
        # positions on the x axis: the batch order (seq is 1..n in the summary)
        self.pos = np.arange(1, self.n + 1, dtype=float)
        self.verdict = column(self.df, "verdict", str)
        self.counts = spc.verdict_counts(self.verdict)
        self.rate = spc.pass_rate(self.counts)
        self.stats = {ch.key: characteristic_stats(self.df, ch) for ch in self.chars}
        self.values = {ch.key: column(self.df, ch.value_column, float) for ch in self.chars}
        self.status = {ch.key: column(self.df, f"status_{ch.key}", str) for ch in self.chars}
        self.profiles_only = all(ch.kind == "profile" for ch in self.chars)
        missing = [
            name
            for ch in self.chars
            for name in (ch.value_column, f"status_{ch.key}")
            if name not in self.df.columns
        ]
        if missing:
            log.warning("batch summary has no column %s: read as not measured", ", ".join(missing))

    def by_key(self) -> dict[str, TrendCharacteristic]:
        """The characteristics by key."""
        return {ch.key: ch for ch in self.chars}

    def column(self, name: str, kind: type) -> np.ndarray:
        """Summary column ``name`` as floats or strings (:func:`column`)."""
        return column(self.df, name, kind)

    def seq_label(self, pos: int) -> str:
        """The label under x position ``pos`` (1-based batch order): the scan's serial
        number when it has one (the part a point is of), else its sequence number."""
        if pos <= self.n and "serial" in self.df.columns:
            serial = self.df["serial"].iloc[pos - 1]
            if isinstance(serial, str) and serial.strip():
                from ..kit import fit_text

                return fit_text(serial.strip(), SERIAL_LABEL_WIDTH, 6.0)
        if pos <= self.n and math.isfinite(self.seq[pos - 1]):
            return str(int(self.seq[pos - 1]))
        return str(pos)

    def rates(self) -> tuple[np.ndarray, np.ndarray | None, int]:
        """Cumulative and rolling pass rate (%) after each scan, and the rolling window.

        NaN until a scan has a verdict; the rolling rate (over the last ``window`` scans)
        only for batches of :data:`~qifreport.metrology.spc.ROLLING_MIN_SCANS` scans or more
        (else None and window 0).
        """
        cum = spc.cumulative_pass_rate(self.verdict)
        window = spc.rolling_window(self.n)
        if not window:
            return cum, None, 0
        return cum, spc.rolling_pass_rate(self.verdict, window), window

    def point_kinds(self, ch: TrendCharacteristic) -> np.ndarray:
        """Each scan's point colour (one of :data:`POINT_KINDS`): the characteristic's
        verdict; a value without one by its limits."""
        v, status = self.values[ch.key], self.status[ch.key]
        judged = ("PASS", "FAIL", "NOT ESTABLISHED")
        if not ch.two_sided:
            tol = float(ch.tolerance_mm)
            return np.where(
                np.isin(status, judged),
                status,
                np.where(np.isfinite(tol) & (v > tol), "FAIL", "PASS"),
            )
        beyond = np.zeros(len(v), dtype=bool)
        if ch.upper is not None:
            beyond |= v > ch.upper
        if ch.lower is not None:
            beyond |= v < ch.lower
        by_value = np.where(beyond, "FAIL", "PASS" if ch.limits() else "BASIC")
        return np.where(
            np.isin(status, judged),
            status,
            np.where(status == "BASIC", "BASIC", by_value),
        )
