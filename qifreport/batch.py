"""``qifreport batch NOMINAL SCANS... --out DIR``: many scans of one part, nothing lost.

Plan
    ``SCANS`` are scan files, folders (every scan file in them, by name), glob patterns
    (quoted, expanded here) or manifest CSVs with a ``scan`` column and optional ``serial``
    and ``nominal`` columns (paths relative to the manifest). Each scan gets an id: its
    serial number when the manifest gives one, else its file stem (made unique).

Work
    Each distinct nominal is prepared once, through the per-part cache (:mod:`qifreport.cache`), on
    this machine. The scans then run in parallel: on local processes by default (``--jobs``,
    each process receives the prepared state once, at start-up), or on a Dask cluster with
    ``--scheduler ADDRESS`` (the state is scattered to the workers once and every task
    refers to it; Dask reschedules the tasks of a worker that dies). A task carries the
    scan's bytes and returns the bytes of its outputs, so workers need no shared file system;
    this process does all the file writing.

Outputs (``DIR``)
    ``scans/<id>.qif``, ``.pdf``, ``.json``: exactly what ``qifreport NOMINAL SCAN --json``
    writes, and ``scans/<id>.record.json``: the scan's summary row and the digest of
    everything that made it (scan and nominal SHA-256, the inspection options, the
    software version). The record is renamed into place last, after the outputs, so it
    marks a finished scan. A scan that cannot be inspected (bad file, pose not established,
    internal error) gets a record with its one-line error and no other output; it does not
    stop the batch. ``summary.csv`` and ``summary.parquet`` hold one row per scan in plan
    order; per nominal, ``<part>_statistics.qif`` (the QIF 3.0 Statistics document,
    :mod:`qifreport.qif.statistics`) and ``<part>_trend.pdf`` (run charts, :mod:`qifreport.reports.trend`). Every
    file is written atomically.

Resume
    Running the same command again skips every scan whose record and outputs exist and
    whose digest matches (a changed scan, nominal or option redoes it); recorded failures are
    skipped too unless ``--retry-failed``; ``--force`` redoes everything.

Exit code: 0 every scan passed, 1 any scan failed, was not established or could not be
inspected (see the summary), 2 the batch itself could not run.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import csv
import glob
import hashlib
import json
import logging
import os
import re
import socket
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from qifreport import __version__
from qifreport.registration.pointcloud import SCAN_SUFFIXES, load_scan

from .atomic_io import atomic_write_many
from .cache import PartState, part_state, sha256
from .cli import _finite, _json_default
from .errors import InputError

log = logging.getLogger("qifreport.batch")

#: version of the record files' layout (part of the digest: a new layout redoes the scans)
RECORD_FORMAT = 1
#: options of the command line that change a scan's outputs (the record digest covers them)
_RESULT_OPTIONS = (
    "tolerance", "max_edge", "deflection", "scan_units", "no_qif", "no_pdf", "page",
    "author", "organization", "operator", "min_fraction", "max_region_area", "energy",
    "edge_band", "boundary_band", "band_limit", "passes", "prealign",
    "fail_on_added_material", "method", "seeds", "rigid_only",
)
VERDICTS = ("PASS", "FAIL", "NOT ESTABLISHED", "ERROR")
#: column order of the summary table (per-tolerance columns follow, then _TAIL)
_COLUMNS = (
    "seq", "id", "serial", "scan", "nominal", "verdict", "criterion", "error", "rms_mm",
    "max_abs_mm", "p95_mm", "p999_mm", "mean_mm", "tail_above", "tail_below", "tail_beyond",
    "in_tolerance_pct", "coverage_pct", "regions", "largest_region_mm2", "rigid_rms_mm",
    "fit_residual_mm", "flagged_fraction",
)
#: the QIF characteristic status -> the summary's words
_STATUS = {"PASS": "PASS", "FAIL": "FAIL", "INDETERMINATE": "NOT ESTABLISHED",
           "NOT_ANALYZED": "NOT ANALYZED"}
_TAIL = ("decided_by", "seconds", "worker", "peak_rss_mib", "scan_sha256")


# ---------------------------------------------------------------------------------- plan


@dataclass
class ScanItem:
    """One scan of the batch.

    Attributes
    ----------
    seq : 1-based position in the plan.  id : output stem (``scans/<id>.*``).
    scan : the scan file.  nominal : its nominal.  serial : serial number ("" if none).
    """

    seq: int
    id: str
    scan: Path
    nominal: Path
    serial: str = ""


def _is_glob(s: str) -> bool:
    return any(c in s for c in "*?[")


def _scan_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in SCAN_SUFFIXES
                  and not p.name.startswith("."))


def read_manifest(path: Path, nominal: Path) -> list[tuple[Path, str, Path]]:
    """Rows ``(scan, serial, nominal)`` of a manifest CSV (header row with ``scan``; optional
    ``serial`` and ``nominal``; relative paths are relative to the manifest's folder)."""
    base = path.parent
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            cols = [c.strip().lower() for c in (reader.fieldnames or [])]
            if "scan" not in cols:
                raise InputError(f"manifest {path} has no 'scan' column (columns: "
                                 f"{', '.join(cols) or 'none'})")
            rows = []
            for k, raw in enumerate(reader, start=2):
                row = {str(a).strip().lower(): (b or "").strip() for a, b in raw.items()
                       if a is not None}
                if not row.get("scan"):
                    raise InputError(f"manifest {path} line {k}: empty 'scan'")
                scan = Path(row["scan"])
                nom = Path(row["nominal"]) if row.get("nominal") else nominal
                rows.append((scan if scan.is_absolute() else base / scan,
                             row.get("serial", ""),
                             nom if nom.is_absolute() or nom is nominal else base / nom))
    except UnicodeDecodeError as exc:
        raise InputError(f"manifest {path} is not UTF-8 text") from exc
    return rows


def _safe_id(s: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", s).strip("._")
    return s[:80] or "scan"


def plan(nominal: Path, sources: list[str]) -> list[ScanItem]:
    """The scans named by ``sources`` (files, folders, globs, manifest CSVs), in order,
    each once, with unique ids."""
    rows: list[tuple[Path, str, Path]] = []
    for src in sources:
        p = Path(src)
        if p.is_dir():
            found = _scan_files(p)
            if not found:
                raise InputError(f"no scan files ({', '.join(SCAN_SUFFIXES)}) in folder {p}")
            rows += [(f, "", nominal) for f in found]
        elif p.is_file() and p.suffix.lower() == ".csv" and _looks_like_manifest(p):
            rows += read_manifest(p, nominal)
        elif p.is_file():
            rows.append((p, "", nominal))
        elif _is_glob(src):
            found = sorted(Path(f) for f in glob.glob(src) if Path(f).is_file())
            if not found:
                raise InputError(f"no file matches {src!r}")
            rows += [(f, "", nominal) for f in found]
        else:
            # a missing scan is a per-scan failure, recorded, not a batch failure
            rows.append((p, "", nominal))
    seen: set[Path] = set()
    unique = []
    for scan, serial, nom in rows:
        key = scan.resolve()
        if key in seen:
            continue
        seen.add(key)
        unique.append((scan, serial, nom))
    if not unique:
        raise InputError("no scans given")
    ids = [_safe_id(serial or scan.stem) for scan, serial, _ in unique]
    dup = {i for i in ids if ids.count(i) > 1}
    items = []
    for k, ((scan, serial, nom), i) in enumerate(zip(unique, ids, strict=True), start=1):
        if i in dup:  # same stem in two folders: a stable suffix from the path
            i = f"{i}-{hashlib.sha256(str(scan.resolve()).encode()).hexdigest()[:8]}"
        items.append(ScanItem(seq=k, id=i, scan=scan, nominal=nom, serial=serial))
    return items


def _looks_like_manifest(p: Path) -> bool:
    """A CSV whose first line names a ``scan`` column (a CSV point cloud has numbers)."""
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            first = fh.readline()
    except OSError:
        return False
    return "scan" in [c.strip().lower() for c in first.split(",")]


# ---------------------------------------------------------------------------------- tasks


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
    from .profile import peak_rss_bytes

    return peak_rss_bytes() / 2**20


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def run_task(task: ScanTask, state: PartState, opts: argparse.Namespace) -> TaskResult:
    """Inspect one scan against a prepared part and render its outputs (runs on a worker).

    Never raises for a problem of the scan: the error comes back in the result.
    """
    from qifreport.metrology.inspection import inspect

    from .cli import (
        inspection_params,
        output_paths,
        output_writers,
        resampled_runs,
    )

    t0 = time.perf_counter()
    item = task.item
    started = datetime.now(timezone.utc)
    try:
        if state.key != task.part_key:
            raise RuntimeError("worker holds another part's state")
        with tempfile.TemporaryDirectory(prefix="qifreport-") as td:
            scan_file = Path(td) / item.scan.name
            scan_file.write_bytes(task.scan_bytes)
            P = load_scan(scan_file, units=opts.scan_units)
            params = inspection_params(opts)
            nom = state.nominal
            res = inspect(nom.V, nom.F, P, params, scan_units=opts.scan_units,
                          face_id=nom.face_id, zones=nom.zones,
                          not_evaluated=nom.not_evaluated, prepared=state.prepared)
            if opts.seeds > 1:
                resampled_runs(res, params, nom, opts.seeds, prepared=state.prepared)
            finished = datetime.now(timezone.utc)
            args = copy.copy(opts)
            args.nominal, args.scan, args.serial = item.nominal, item.scan, item.serial or None
            args.json, args.export_mesh = True, None
            paths = output_paths(args, stem=item.id)
            digests = {"nominal": state.nominal_sha256, "scan": task.scan_sha256}
            writers, _ = output_writers(res, nom, args, paths, digests, started, finished)
            files = {}
            for path, write in writers:  # in order: the JSON reports the QIF's validation
                tmp = Path(td) / path.name
                write(tmp)
                files[path.name] = tmp.read_bytes()
        row = summary_row(res, item, task.scan_sha256, time.perf_counter() - t0)
        return TaskResult(item.id, True, files, row, worker=_worker_name(),
                          peak_rss_mib=_peak_rss_mib(), seconds=time.perf_counter() - t0)
    except InputError as exc:
        error, final = str(exc), True
    except (OSError, MemoryError) as exc:
        error, final = f"{type(exc).__name__}: {exc}", False
    except Exception as exc:  # a bug: recorded, the batch goes on
        log.debug("internal error on %s", item.scan, exc_info=True)
        error, final = f"internal error: {type(exc).__name__}: {exc}", False
    error = " ".join(error.split())
    return TaskResult(item.id, False, {}, error_row(item, task.scan_sha256, error),
                      error=error, final=final, worker=_worker_name(), peak_rss_mib=_peak_rss_mib(),
                      seconds=time.perf_counter() - t0)


def summary_row(res, item: ScanItem, scan_sha256: str, seconds: float) -> dict:
    """One row of ``summary.csv`` for an inspected scan (lengths mm, areas mm^2)."""
    from qifreport.qif.writer import _status, profile_value

    s, a = res.vertex_stats, res.acceptance
    fit = res.fit
    row = {
        "seq": item.seq, "id": item.id, "scan": item.scan.name, "serial": item.serial,
        "nominal": item.nominal.name, "verdict": res.verdict,
        "criterion": deciding_criteria(res),
        "decided_by": "; ".join(res.decided_by()),
        "error": "",
        "rms_mm": s.rms, "max_abs_mm": s.max_abs, "p95_mm": s.p95, "p999_mm": s.p999,
        "mean_mm": s.mean, "tail_above": s.frac_above, "tail_below": s.frac_below,
        "tail_beyond": s.frac_beyond,
        "in_tolerance_pct": 100.0 * a.in_tolerance_fraction,
        "coverage_pct": 100.0 * a.coverage, "regions": len(a.regions),
        "largest_region_mm2": a.largest_region_area,
        "rigid_rms_mm": res.rigid.rms,
        "fit_residual_mm": fit.scale if fit is not None else float("nan"),
        "flagged_fraction": fit.flagged_fraction if fit is not None else float("nan"),
        "seconds": seconds, "scan_sha256": scan_sha256,
    }
    for z in res.zones:
        k = z.zone.key
        row[f"profile_{k}_mm"] = profile_value(z)
        row[f"tolerance_{k}_mm"] = z.zone.upper - z.zone.lower
        row[f"status_{k}"] = _STATUS[_status(z, res.established)]  # as in the QIF
        row[f"in_tolerance_{k}_pct"] = 100.0 * z.acceptance.in_tolerance_fraction
    return row


def deciding_criteria(res) -> str:
    """The criteria that decided a verdict other than PASS, short: ``"T2:region"``,
    ``"part:area"``, ``"added material"``, ``"not established"`` (``;``-separated)."""
    out = []
    for name, acc in [("part", res.acceptance)] + [(z.zone.key, z.acceptance)
                                                     for z in res.zones]:
        if not acc.area_ok:
            out.append(f"{name}:area")
        if not acc.region_ok:
            out.append(f"{name}:region")
    if res.added is not None and not res.added.passed:
        out.append("added material")
    if res.passed and not res.established:
        out.append("not established")
    return ";".join(out)


def error_row(item: ScanItem, scan_sha256: str, error: str) -> dict:
    """The row of a scan that could not be inspected."""
    return {"seq": item.seq, "id": item.id, "scan": item.scan.name, "serial": item.serial,
            "nominal": item.nominal.name, "verdict": "ERROR", "criterion": "error",
            "decided_by": "",
            "error": error, "scan_sha256": scan_sha256}


# ------------------------------------------------------------------------------- records


def options_dict(opts: argparse.Namespace) -> dict:
    """The options that change a scan's outputs (JSON-able)."""
    return {k: getattr(opts, k, None) for k in _RESULT_OPTIONS}


def record_digest(scan_sha256: str, nominal_sha256: str, item: ScanItem,
                  opts: argparse.Namespace) -> str:
    """SHA-256 of everything that made a scan's outputs."""
    doc = {"format": RECORD_FORMAT, "software": __version__, "scan": scan_sha256,
           "nominal": nominal_sha256, "serial": item.serial, "id": item.id,
           "options": options_dict(opts)}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def record_path(out: Path, item: ScanItem) -> Path:
    return out / "scans" / f"{item.id}.record.json"


def read_record(out: Path, item: ScanItem, digest: str) -> dict | None:
    """The scan's record when it is complete and current (digest, outputs present)."""
    p = record_path(out, item)
    try:
        rec = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("digest") != digest:
        return None
    if not all((out / "scans" / name).is_file() for name in rec.get("outputs", [])):
        return None
    return rec


def commit(out: Path, item: ScanItem, digest: str, result: TaskResult) -> dict:
    """Write a scan's outputs and then its record, all or none; return the record."""
    scans = out / "scans"
    rec = {"format": RECORD_FORMAT, "digest": digest, "id": item.id, "seq": item.seq,
           "scan": str(item.scan), "nominal": str(item.nominal), "ok": result.ok,
           "error": result.error, "final": result.ok or result.final,
           "outputs": sorted(result.files),
           "worker": result.worker, "peak_rss_mib": result.peak_rss_mib,
           "seconds": result.seconds,
           "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "row": _finite(result.row)}
    items = [(scans / name, _bytes_writer(data)) for name, data in result.files.items()]
    items.append((record_path(out, item),
                  lambda p: p.write_text(json.dumps(rec, indent=1, allow_nan=False,
                                                    default=_json_default))))
    atomic_write_many(items)  # the record is renamed last: it marks a finished scan
    return rec


def _bytes_writer(data: bytes):
    return lambda p: p.write_bytes(data)


# ------------------------------------------------------------------------------ executors


_WORKER_STATES: dict[str, PartState] = {}


def _init_worker(states: dict[str, PartState], blas_threads: int) -> None:
    """Process-pool initializer: receive the prepared states once."""
    _WORKER_STATES.update(states)
    with contextlib.suppress(ImportError):
        from threadpoolctl import threadpool_limits

        threadpool_limits(blas_threads)
    logging.getLogger().setLevel(logging.WARNING)


def _run_local(task: ScanTask, opts: argparse.Namespace) -> TaskResult:
    return run_task(task, _WORKER_STATES[task.part_key], opts)


def run_local(tasks: Iterable[ScanTask], states: dict[str, PartState],
              opts: argparse.Namespace, jobs: int, window: int) -> Iterator[TaskResult]:
    """Run tasks on ``jobs`` local processes (in this process when ``jobs == 1``).

    A pool broken by a dying worker is replaced and its unfinished tasks resubmitted (up to
    three times).
    """
    if jobs <= 1:
        for t in tasks:
            yield run_task(t, states[t.part_key], opts)
        return
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = multiprocessing.get_context("spawn")  # no fork of a threaded process
    blas = max(1, (os.cpu_count() or 1) // jobs)
    pending = iter(tasks)
    retry: list[ScanTask] = []
    breaks = 0
    while True:
        with ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_init_worker,
                                 initargs=(states, blas)) as pool:
            running: dict = {}
            broken = False
            while True:
                while len(running) < window and not broken:
                    t = retry.pop() if retry else next(pending, None)
                    if t is None:
                        break
                    running[pool.submit(_run_local, t, opts)] = t
                if not running:
                    return
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    t = running.pop(fut)
                    try:
                        yield fut.result()
                    except BrokenProcessPool:
                        retry.append(t)
                        broken = True
                if broken:
                    retry.extend(running.values())
                    break
        breaks += 1
        log.warning("a worker process died: %d task(s) resubmitted on a new pool", len(retry))
        if breaks > 3:
            for t in retry:
                yield TaskResult(t.item.id, False, {}, error_row(
                    t.item, t.scan_sha256, "worker process died (3 times)"),
                    error="worker process died (3 times)")
            retry = []


def run_dask(tasks: Iterable[ScanTask], states: dict[str, PartState],
             opts: argparse.Namespace, address: str, window: int) -> Iterator[TaskResult]:
    """Run tasks on the Dask cluster at ``address``; the states are scattered once."""
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise InputError("--scheduler needs Dask's 'distributed' package "
                         "(pip install distributed)") from exc
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {address}: {exc}") from exc
    with client:
        n = max(1, len(client.scheduler_info().get("workers", {})))
        window = max(window, 2 * n)
        futures = {k: client.scatter(s, broadcast=True, hash=False)
                   for k, s in states.items()}
        pending = iter(tasks)
        ac = as_completed()
        meta = {}

        def submit(t: ScanTask) -> None:
            f = client.submit(run_task, t, futures[t.part_key], opts, pure=False,
                              key=f"qifreport-{t.item.id}-{t.scan_sha256[:12]}")
            meta[f.key] = t
            ac.add(f)

        for t in pending:
            submit(t)
            if ac.count() >= window:
                break
        for f in ac:
            t = meta.pop(f.key)
            try:
                yield f.result()
            except Exception as exc:  # e.g. KilledWorker after the scheduler's retries
                msg = " ".join(f"{type(exc).__name__}: {exc}".split())
                yield TaskResult(t.item.id, False, {}, error_row(t.item, t.scan_sha256,
                                                                 msg), error=msg)
            f.release()
            nxt = next(pending, None)
            if nxt is not None:
                submit(nxt)


# ----------------------------------------------------------------------------- the batch


@dataclass
class BatchReport:
    """What a batch did.

    Attributes
    ----------
    records : one per scan, plan order.  done : scans inspected in this run.
    skipped : scans whose current record was found.  counts : verdict -> scans.
    cache : nominal -> :class:`qifreport.cache.CacheOutcome`.  seconds : wall time.
    """

    records: list[dict]
    done: int
    skipped: int
    counts: dict[str, int]
    cache: dict = field(default_factory=dict)
    seconds: float = 0.0
    summary_files: list[Path] = field(default_factory=list)


def run_batch(opts: argparse.Namespace) -> BatchReport:
    """Plan, prepare, inspect, record and summarise (see the module docstring)."""
    from .cli import cache_dir, inspection_params, nominal_options

    t_start = time.perf_counter()
    out: Path = opts.out
    items = plan(opts.nominal, opts.scans)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"output directory not writable: {out}")
    params = inspection_params(opts)
    nopts = nominal_options(opts)

    # one prepared state per distinct nominal (here, through the cache)
    states: dict[Path, PartState | str] = {}
    outcomes = {}
    for nom in dict.fromkeys(i.nominal for i in items):
        if not nom.is_file():
            states[nom] = f"nominal file not found: {nom}"
            continue
        try:
            states[nom], outcomes[str(nom)] = part_state(nom, nopts, params, cache_dir(opts))
            log.info("%s: %s", nom, outcomes[str(nom)].describe())
        except InputError as exc:
            states[nom] = str(exc)
    if all(isinstance(s, str) for s in states.values()):
        raise InputError(next(iter(states.values())))

    records: dict[str, dict] = {}
    todo: list[tuple[ScanItem, str, str]] = []  # item, scan digest, record digest
    skipped = 0
    for item in items:
        st = states[item.nominal]
        if isinstance(st, str):
            records[item.id] = commit(out, item, "", TaskResult(
                item.id, False, {}, error_row(item, "", st), error=st))
            continue
        if not item.scan.is_file():
            sd, err = "", f"scan file not found: {item.scan}"
        else:
            sd, err = sha256(item.scan), ""
        digest = record_digest(sd, st.nominal_sha256, item, opts)
        rec = None if opts.force else read_record(out, item, digest)
        if rec is not None and (rec["ok"] or (rec.get("final") and not opts.retry_failed)):
            records[item.id] = rec
            skipped += 1
            continue
        if err:
            records[item.id] = commit(out, item, digest, TaskResult(
                item.id, False, {}, error_row(item, sd, err), error=err, final=True))
            continue
        todo.append((item, sd, digest))

    by_id = {i.id: (i, d) for i, _, d in todo}
    part_states = {s.key: s for s in states.values() if not isinstance(s, str)}

    def tasks() -> Iterator[ScanTask]:
        for item, sd, _ in todo:
            try:
                data = item.scan.read_bytes()
            except OSError as exc:
                data = b""
                log.warning("cannot read %s: %s", item.scan, exc)
            yield ScanTask(item, data, sd, states[item.nominal].key)

    jobs = opts.jobs or max(1, min(os.cpu_count() or 1, len(todo)))
    bar = None
    if not opts.quiet and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="scans", unit="scan", file=sys.stderr)
    try:
        if todo and opts.scheduler:
            results = run_dask(tasks(), part_states, opts, opts.scheduler, 4 * jobs)
        else:
            results = run_local(tasks(), part_states, opts, jobs, 2 * jobs)
        for res in results:
            item, digest = by_id[res.id]
            records[item.id] = commit(out, item, digest, res)
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(f"{item.id}: {res.row.get('verdict')}")
    finally:
        if bar is not None:
            bar.close()

    ordered = [records[i.id] for i in items if i.id in records]
    counts = {v: sum(r["row"].get("verdict") == v for r in ordered) for v in VERDICTS}
    files = write_summaries(out, items, ordered, states, opts,
                            changed=bool(todo) or opts.force)
    return BatchReport(ordered, len(todo), skipped, counts, outcomes,
                       time.perf_counter() - t_start, files)


def summary_frame(records: list[dict]):
    """The summary table (pandas DataFrame), one row per scan in plan order."""
    import pandas as pd

    df = pd.DataFrame([{**r["row"], "worker": r.get("worker", ""),
                        "peak_rss_mib": r.get("peak_rss_mib", np.nan)} for r in records])
    first = [c for c in _COLUMNS if c in df.columns]
    zones = [c for c in df.columns if c not in first and c not in _TAIL]
    df = df[first + zones + [c for c in _TAIL if c in df.columns]]
    for col in ("serial", "criterion", "decided_by", "error"):
        if col in df:
            df[col] = df[col].fillna("")
    status = [c for c in df.columns if c.startswith("status_")]
    df[status] = df[status].fillna("")
    return df


def write_summaries(out: Path, items: list[ScanItem], records: list[dict],
                    states: dict, opts: argparse.Namespace, changed: bool) -> list[Path]:
    """``summary.csv``, ``summary.parquet`` and, per nominal, the statistics QIF and the
    trend PDF (rewritten when a scan was inspected in this run or a file is missing)."""
    df = summary_frame(records)
    files = [out / "summary.csv", out / "summary.parquet"]
    per_part = []
    for nom, st in states.items():
        if isinstance(st, str):
            continue
        stem = _safe_id(nom.stem)
        per_part.append((nom, st, out / f"{stem}_statistics.qif", out / f"{stem}_trend.pdf"))
        files += per_part[-1][2:]
    if not changed and all(f.is_file() for f in files) and _same_rows(files[0], df):
        return files
    writers = [(files[0], lambda p: df.to_csv(p, index=False)),
               (files[1], lambda p: df.to_parquet(p, index=False))]
    for nom, st, qif_path, pdf_path in per_part:
        recs = [r for r in records if r["nominal"] == str(nom)]
        sub = df[df["nominal"] == nom.name].reset_index(drop=True)
        writers.append((qif_path, _statistics_writer(out, recs, st, nom.stem, qif_path)))
        writers.append((pdf_path, _trend_writer(sub, st, nom.stem, opts)))
    atomic_write_many(writers)
    return files


def _same_rows(csv_path: Path, df) -> bool:
    """Does the existing ``summary.csv`` list the same scans, in order, with the same
    digests and verdicts (a re-run over a subset or a new order rewrites it)?"""
    import pandas as pd

    try:
        old = pd.read_csv(csv_path, keep_default_na=False, dtype=str)
    except (OSError, ValueError):
        return False
    cols = ["id", "scan_sha256", "verdict"]
    if any(c not in old.columns for c in cols) or len(old) != len(df):
        return False
    return all(list(old[c]) == [str(v) for v in df[c]] for c in cols)


def _statistics_writer(out: Path, recs: list[dict], st: PartState, part_name: str,
                       target: Path):
    """The writer of the statistics document: validated before it is published, as the
    results documents are (:func:`qifreport.cli.qif_writer`)."""
    def write(p: Path) -> None:
        from qifreport.qif.reader import read_results
        from qifreport.qif.statistics import build_statistics

        from .cli import qif_writer

        names = [n for r in recs if r["ok"] for n in r["outputs"] if n.endswith(".qif")]
        results = [read_results(out / "scans" / n) for n in names]
        tree = build_statistics(
            results, part_name=part_name, created=datetime.now(timezone.utc),
            nominal_sha256=st.nominal_sha256, sources=[f"scans/{n}" for n in names],
            software_version=__version__)
        state: dict = {}
        qif_writer(tree, state)(p)
        if state["valid"] is None:
            log.warning("%s written, %s", target, state["message"])

    return write


def _trend_writer(df, st: PartState, part_name: str, opts: argparse.Namespace):
    def write(p: Path) -> None:
        from qifreport.reports.trend import TrendCharacteristic, write_trend_pdf

        chars = [TrendCharacteristic(z.key, z.describe(), float(z.upper - z.lower))
                 for z in st.nominal.zones if f"profile_{z.key}_mm" in df]
        write_trend_pdf(p, df, chars, part_name=part_name,
                        created=datetime.now(timezone.utc),
                        nominal_sha256=st.nominal_sha256, page=opts.page)

    return write


# ------------------------------------------------------------------------------------ CLI


def batch_parser() -> argparse.ArgumentParser:
    from .cli import add_options

    ap = argparse.ArgumentParser(
        prog="qifreport batch",
        description="Inspect many scans of one part: per-scan QIF + PDF, a summary table, a "
        "QIF Statistics document and a trend report; resumable, in parallel.")
    ap.add_argument("nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh, mm")
    ap.add_argument("scans", nargs="+", metavar="SCANS",
                    help="scan files, folders, quoted glob patterns or manifest CSVs "
                    "(columns scan[, serial][, nominal])")
    add_options(ap, batch=True)
    ap.add_argument("--jobs", type=int, default=0, metavar="N",
                    help="local worker processes (default: one per core; 1 runs in this "
                    "process)")
    ap.add_argument("--scheduler", metavar="ADDRESS",
                    help="run on the Dask cluster whose scheduler is at ADDRESS "
                    "(e.g. tcp://10.0.0.5:8786) instead of local processes")
    ap.add_argument("--retry-failed", action="store_true",
                    help="inspect again the scans recorded as failed")
    return ap


def batch_main(argv: list[str]) -> int:
    opts = batch_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if opts.verbose else logging.WARNING,
                        format="qifreport: %(levelname)s: %(message)s")
    from .cli import _check_args_common

    _check_args_common(opts)
    rep = run_batch(opts)
    c = rep.counts
    print(f"{len(rep.records)} scans: {c['PASS']} PASS, {c['FAIL']} FAIL, "
          f"{c['NOT ESTABLISHED']} NOT ESTABLISHED, {c['ERROR']} ERROR "
          f"({rep.done} inspected now, {rep.skipped} done earlier) in {rep.seconds:.1f} s")
    for r in rep.records:
        if not r["ok"]:
            print(f"  {r['id']}: error: {r['error']}")
    for nom, outcome in rep.cache.items():
        print(f"{Path(nom).name}: {outcome.describe()}")
    print("summary: " + ", ".join(str(p) for p in rep.summary_files))
    return 0 if c["PASS"] == len(rep.records) else 1

