"""One scan of a batch on a worker: inspect it against the prepared part, render its outputs
to bytes, and summarise it as one row of the summary table.

A task carries the scan's bytes and returns the bytes of its outputs, so workers need no
shared file system; the client does all the file writing.

The row (:func:`summary_row`) holds the whole part's results, then per toleranced surface
(zone key ``K``: ``T1``, ``general`` ...) ``profile_K_mm``, ``tolerance_K_mm``, ``status_K``
and ``in_tolerance_K_pct``, then per feature characteristic of the drawing
(:func:`characteristic_columns`, key ``K``: ``G1``, ``D3`` ...) ``value_K_U`` (its value in
its unit ``U``, ``mm`` or ``deg``), its limits (``tolerance_K_mm`` for a geometric tolerance,
``lower_K_U`` and ``upper_K_U`` for a dimension) and ``status_K``.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import tempfile
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

from qifreport.errors import InputError
from qifreport.metrology.gdt.characteristic_types import CharacteristicResult
from qifreport.qif.feature_characteristics import qif_status
from qifreport.qif.profile_characteristics import characteristic_status, profile_value
from qifreport.registration.pointcloud import read_scan

from ..cache import PartState
from ..options import InspectJob
from ..pipeline import inspect_state, output_writers, scan_input, traceability
from ..profile import peak_rss_bytes
from .plan import ScanItem

__all__ = [
    "STATUS_WORDS",
    "ScanTask",
    "TaskResult",
    "characteristic_columns",
    "deciding_criteria",
    "error_row",
    "run_task",
    "summary_row",
]

log = logging.getLogger("qifreport.batch")

#: the QIF characteristic status -> the summary's words (``BASIC_OR_TED``: a basic or
#: reference dimension, reported without a verdict)
STATUS_WORDS = {
    "PASS": "PASS",
    "FAIL": "FAIL",
    "INDETERMINATE": "NOT ESTABLISHED",
    "NOT_ANALYZED": "NOT MEASURED",
    "BASIC_OR_TED": "BASIC",
}
#: feature characteristic statuses whose value is judged against limits (the row gives them)
JUDGED_STATUSES = ("PASS", "FAIL", "INDETERMINATE")


@dataclass
class ScanTask:
    """What a worker needs for one scan (the part state travels separately)."""

    item: ScanItem
    scan_bytes: bytes
    scan_sha256: str
    part_key: str


@dataclass
class TaskResult:
    """What a worker returns: the outputs' bytes by file name, or the error.

    Attributes
    ----------
    id : the scan's id.  ok : inspected (any verdict).  files : name -> bytes.
    row : the summary row.  error : one-line error ("" when ok).
    worker : host:pid of the process that ran it.  peak_rss_mib : its peak resident memory.
    """

    id: str
    ok: bool
    files: dict[str, bytes] = field(default_factory=dict)
    row: dict = field(default_factory=dict)
    error: str = ""
    final: bool = False
    worker: str = ""
    peak_rss_mib: float = 0.0
    seconds: float = 0.0


def _peak_rss_mib() -> float:
    return peak_rss_bytes() / 2**20


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def run_task(task: ScanTask, state: PartState, job: InspectJob) -> TaskResult:
    """Inspect one scan against a prepared part and render its outputs (runs on a worker).

    ``job`` is the batch's template (output directory and options); the task's scan,
    nominal, serial and id fill it in. Never raises for a problem of the scan: the error
    comes back in the result.
    """
    t0 = time.perf_counter()
    item = task.item
    started = datetime.now(timezone.utc)
    try:
        if state.key != task.part_key:
            raise RuntimeError("worker holds another part's state")
        with tempfile.TemporaryDirectory(prefix="qifreport-") as td:
            scan_file = Path(td) / item.scan.name
            scan_file.write_bytes(task.scan_bytes)
            scan = read_scan(scan_file, units=job.options.scan_units)
            P, scan_report, stray = scan_input(scan, state.part, job.options.scan_units)
            del scan  # the inspection uses its thinned points
            this = replace(
                job,
                nominal=item.nominal,
                scan=item.scan,
                stem=item.id,
                serial=item.serial or None,
                json=True,
                export_mesh=None,
            )
            res = inspect_state(P, state, this, stray=stray)
            finished = datetime.now(timezone.utc)
            digests = {"nominal": state.nominal_sha256, "scan": task.scan_sha256}
            writers, _ = output_writers(
                res,
                state.part,
                state.drawing,
                this,
                this.output_paths(),
                digests,
                started,
                finished,
                scan_report=scan_report,
            )
            files = {}
            for path, write in writers:  # in order: the JSON reports the QIF's validation
                tmp = Path(td) / path.name
                write(tmp)
                files[path.name] = tmp.read_bytes()
        row = summary_row(res, item, task.scan_sha256, time.perf_counter() - t0)
        trace = traceability(res, state.part, this, started, finished)
        row.update({k: trace[k] for k in TRACE_COLUMNS})
        return TaskResult(
            item.id,
            True,
            files,
            row,
            worker=_worker_name(),
            peak_rss_mib=_peak_rss_mib(),
            seconds=time.perf_counter() - t0,
        )
    except InputError as exc:
        error, final = str(exc), True
    except (OSError, MemoryError) as exc:
        error, final = f"{type(exc).__name__}: {exc}", False
    except Exception as exc:  # a bug: recorded, the batch goes on
        log.debug("internal error on %s", item.scan, exc_info=True)
        error, final = f"internal error: {type(exc).__name__}: {exc}", False
    error = " ".join(error.split())
    return TaskResult(
        item.id,
        False,
        {},
        error_row(item, task.scan_sha256, error),
        error=error,
        final=final,
        worker=_worker_name(),
        peak_rss_mib=_peak_rss_mib(),
        seconds=time.perf_counter() - t0,
    )


def summary_row(res, item: ScanItem, scan_sha256: str, seconds: float) -> dict:
    """One row of ``summary.csv`` for an inspected scan (lengths mm, areas mm^2)."""
    s, a = res.vertex_stats, res.acceptance
    fit = res.fit
    row = {
        "seq": item.seq,
        "id": item.id,
        "scan": item.scan.name,
        "serial": item.serial,
        "nominal": item.nominal.name,
        "verdict": res.verdict,
        "criterion": deciding_criteria(res),
        "decided_by": "; ".join(res.decided_by()),
        "error": "",
        "rms_mm": s.rms,
        "max_abs_mm": s.max_abs,
        "p95_mm": s.p95,
        "p999_mm": s.p999,
        "mean_mm": s.mean,
        "tail_above": s.frac_above,
        "tail_below": s.frac_below,
        "tail_beyond": s.frac_beyond,
        "in_tolerance_pct": 100.0 * a.in_tolerance_fraction,
        "coverage_pct": 100.0 * a.coverage,
        "regions": len(a.regions),
        "largest_region_mm2": a.largest_region_area,
        "rigid_rms_mm": res.rigid.rms,
        "fit_residual_mm": fit.scale if fit is not None else float("nan"),
        "flagged_fraction": fit.flagged_fraction if fit is not None else float("nan"),
        "seconds": seconds,
        "scan_sha256": scan_sha256,
    }
    for z in res.zones:
        k = z.zone.key
        row[f"profile_{k}_mm"] = profile_value(z)
        row[f"tolerance_{k}_mm"] = z.zone.upper - z.zone.lower
        # as in the QIF
        row[f"status_{k}"] = STATUS_WORDS[characteristic_status(z, res.established)]
        row[f"in_tolerance_{k}_pct"] = 100.0 * z.acceptance.in_tolerance_fraction
    for c in res.characteristics:
        row.update(characteristic_columns(c))
    return row


def characteristic_columns(c: CharacteristicResult) -> dict:
    """The summary columns of one feature characteristic (key ``K``) of a scan.

    Parameters
    ----------
    c : the characteristic as measured on the scan.

    Returns
    -------
    dict
        ``value_K_U``: the measured value in its unit ``U`` (``mm``; ``deg`` for an angle):
        a geometric tolerance's zone, a dimension's size; its limits: ``tolerance_K_mm`` (a
        geometric tolerance: the stated tolerance, without an MMC/LMC bonus), or
        ``lower_K_U`` and ``upper_K_U`` (a dimension; a side without a limit has no column);
        ``status_K``: the QIF status in the summary's words (:data:`STATUS_WORDS`). A
        characteristic not measured has its status only; a basic dimension its value and
        status (``BASIC``), no limits.
    """
    s = c.spec
    k, unit = s.key, s.unit
    out: dict = {}
    judged = c.status in JUDGED_STATUSES
    if (judged or c.status == "BASIC") and c.value is not None and math.isfinite(c.value):
        out[f"value_{k}_{unit}"] = float(c.value)
    if judged:
        if s.kind == "dimension":
            if s.lower_limit is not None:
                out[f"lower_{k}_{unit}"] = float(s.lower_limit)
            if s.upper_limit is not None:
                out[f"upper_{k}_{unit}"] = float(s.upper_limit)
        elif s.tolerance is not None:
            out[f"tolerance_{k}_mm"] = float(s.tolerance)
    out[f"status_{k}"] = STATUS_WORDS[qif_status(c)]  # as in the QIF
    return out


def deciding_criteria(res) -> str:
    """The criteria that decided a verdict other than PASS, short: ``"T2:region"``,
    ``"part:area"``, ``"G1:limit"`` (a feature characteristic beyond its limit),
    ``"added material"``, ``"not established"`` (``;``-separated)."""
    out = []
    for name, acc in [("part", res.acceptance)] + [(z.zone.key, z.acceptance) for z in res.zones]:
        if not acc.area_ok:
            out.append(f"{name}:area")
        if not acc.region_ok:
            out.append(f"{name}:region")
    out += [f"{c.spec.key}:limit" for c in res.characteristics if c.status == "FAIL"]
    if res.added is not None and not res.added.passed:
        out.append("added material")
    if res.passed and not res.established:
        out.append("not established")
    elif res.passed:
        if res.coverage is not None and not res.coverage.measured:
            out.append("part:not measured")
        out += [f"{z.zone.key}:not measured" for z in res.zones if not z.measured]
    return ";".join(out)


#: the traceability fields each row of the summary carries (:func:`traceability`)
TRACE_COLUMNS = ("started", "part_number", "revision", "operator", "instrument", "temperature_C")


def error_row(item: ScanItem, scan_sha256: str, error: str) -> dict:
    """The row of a scan that could not be inspected."""
    return {
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "seq": item.seq,
        "id": item.id,
        "scan": item.scan.name,
        "serial": item.serial,
        "nominal": item.nominal.name,
        "verdict": "ERROR",
        "criterion": "error",
        "decided_by": "",
        "error": error,
        "scan_sha256": scan_sha256,
    }
