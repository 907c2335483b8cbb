"""The trend page's table of the scans that did not pass.

Failed, not established and errored scans in batch order: sequence number, serial or scan,
verdict (``N/E`` for NOT ESTABLISHED) and the deciding criterion or the error, cut to
:data:`MAX_FAILURE_ROWS` rows with the rest counted by verdict.
"""

from __future__ import annotations

import math

import numpy as np

from .kit import DASH, Table

__all__ = ["MAX_FAILURE_ROWS", "failure_table"]

#: rows of the table of scans that did not pass
MAX_FAILURE_ROWS = 8


def _failure_rows(
    verdict: np.ndarray,
    seq: np.ndarray,
    serial: np.ndarray,
    scan: np.ndarray,
    decided: np.ndarray,
    error: np.ndarray,
) -> tuple[list[list[str]], list[bool], str, int]:
    """Rows of the table (batch order), their emphasis, the note and how many in all."""
    idx = np.flatnonzero(np.isin(verdict, ("FAIL", "NOT ESTABLISHED", "ERROR")))
    shown = idx[:MAX_FAILURE_ROWS] if len(idx) <= MAX_FAILURE_ROWS else idx[: MAX_FAILURE_ROWS - 1]
    rows, emph = [], []
    for i in shown:
        v = verdict[i]
        who = (
            f"{serial[i]} \u00b7 {scan[i]}"
            if serial[i] and scan[i]
            else (serial[i] or scan[i] or DASH)
        )
        why = error[i] if v == "ERROR" else decided[i]
        s = seq[i]
        rows.append(
            [
                str(int(s)) if math.isfinite(s) else str(i + 1),
                who,
                "N/E" if v == "NOT ESTABLISHED" else v,
                " ".join(why.split()) or DASH,
            ]
        )
        emph.append(v == "FAIL")
    note = ""
    rest = idx[len(shown) :]
    if len(rest):
        parts = [
            f"{int(np.sum(verdict[rest] == v))} {v if v != 'NOT ESTABLISHED' else 'N/E'}"
            for v in ("FAIL", "NOT ESTABLISHED", "ERROR")
            if np.any(verdict[rest] == v)
        ]
        note = f"+{len(rest)} more ({', '.join(parts)}): see the batch summary"
    return rows, emph, note, len(idx)


def failure_table(
    verdict: np.ndarray,
    seq: np.ndarray,
    serial: np.ndarray,
    scan: np.ndarray,
    decided_by: np.ndarray,
    error: np.ndarray,
    width: float,
) -> Table:
    """The table of the scans that did not pass, ``width`` points wide.

    Parameters
    ----------
    verdict : (n_scans,) the scans' verdicts in batch order.
    seq : (n_scans,) their sequence numbers (NaN: printed as the batch position).
    serial, scan, decided_by, error : (n_scans,) strings ("" where none): serial number, scan
        file, the deciding criteria of a FAIL or NOT ESTABLISHED, the error of an ERROR.
    width : of the table, points.

    Returns
    -------
    Table
        Failed, not established and errored scans in batch order, at most
        :data:`MAX_FAILURE_ROWS` rows (the rest counted in the note); "none" without them.
    """
    rows, emph, note, total = _failure_rows(verdict, seq, serial, scan, decided_by, error)
    cols = [("Seq", 24.0, "r"), ("Serial / scan", 100.0, "l"), ("Verdict", 36.0, "c")]
    cols.append(("Deciding criterion / error", width - sum(w for _, w, _ in cols), "l"))
    if not rows:
        rows = [["", "none", "", "every scan passed" if len(verdict) else "no scans"]]
        emph = [False]
    return Table(
        columns=cols,
        rows=rows,
        note=note,
        emphasis=emph,
        title=f"Scans that did not pass ({total}: failed, not established or errored)",
    )
