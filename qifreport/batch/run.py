"""``qifreport batch``: plan, prepare, inspect, record and summarise many scans.

Each distinct nominal is prepared once, through the per-part cache, on this machine; the
scans run on local processes or a Dask cluster (:mod:`qifreport.batch.executors`); every
finished scan is committed with its record (:mod:`qifreport.batch.records`), so a re-run
resumes; the summaries come last (:mod:`qifreport.batch.summaries`).
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from qifreport.errors import InputError, file_problem

from ..cache import PartState, part_state, sha256
from ..options import InspectJob, InspectOptions
from ..pipeline import progress_bar
from .executors import run_dask, run_local
from .plan import ScanItem, plan
from .records import commit, read_record, record_digest
from .summaries import write_summaries
from .task import ScanTask, TaskResult, error_row

__all__ = [
    "VERDICTS",
    "BatchOptions",
    "BatchReport",
    "add_batch_arguments",
    "batch_options",
    "run_batch",
    "run_batch_command",
]

log = logging.getLogger("qifreport.batch")

VERDICTS = ("PASS", "FAIL", "NOT ESTABLISHED", "ERROR")


@dataclass(frozen=True)
class BatchOptions:
    """A batch run.

    Attributes
    ----------
    nominal : the default nominal (a manifest row may name another).
    scans : scan files, folders, glob patterns or manifest CSVs.
    out : output directory.  options : the inspection options of every scan.
    jobs : local worker processes (0: one per core; 1 runs in this process).
    scheduler : address of a Dask scheduler (None: local processes).
    retry_failed : inspect again the scans recorded as failed.
    force : redo every scan.  quiet : no progress bar.
    """

    nominal: Path
    scans: tuple[str, ...]
    out: Path
    options: InspectOptions = field(default_factory=InspectOptions)
    jobs: int = 0
    scheduler: str | None = None
    retry_failed: bool = False
    force: bool = False
    quiet: bool = False


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


def run_batch(opts: BatchOptions) -> BatchReport:
    """Plan, prepare, inspect, record and summarise (see the module docstring)."""
    t_start = time.perf_counter()
    out: Path = opts.out
    items = plan(opts.nominal, list(opts.scans))
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"output directory not writable: {out}")
    o = opts.options
    o.check()
    params = o.inspection_params()
    o.nominal_options(opts.nominal)  # bad options are refused before any work
    template = InspectJob(nominal=opts.nominal, scan=opts.nominal, out=out, options=o)

    # one prepared state per distinct nominal (here, through the cache)
    states: dict[Path, PartState | str] = {}
    outcomes = {}
    for nom in dict.fromkeys(i.nominal for i in items):
        if problem := file_problem(nom, "nominal"):
            states[nom] = problem
            continue
        try:
            states[nom], outcomes[str(nom)] = part_state(
                nom, o.nominal_options(nom), params, o.cache_dir
            )
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
            records[item.id] = commit(
                out, item, "", TaskResult(item.id, False, {}, error_row(item, "", st), error=st)
            )
            continue
        err = file_problem(item.scan, "scan") or ""
        sd = "" if err else sha256(item.scan)
        digest = record_digest(sd, st.nominal_sha256, item, o)
        rec = None if opts.force else read_record(out, item, digest)
        if rec is not None and (rec["ok"] or (rec.get("final") and not opts.retry_failed)):
            records[item.id] = rec
            skipped += 1
            continue
        if err:
            records[item.id] = commit(
                out,
                item,
                digest,
                TaskResult(item.id, False, {}, error_row(item, sd, err), error=err, final=True),
            )
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
    # drawn only on a terminal, its line ended before the summary (pipeline.progress_bar)
    with progress_bar(
        "scans", enabled=not opts.quiet and bool(todo), total=len(todo), unit="scan"
    ) as bar:
        if todo and opts.scheduler:
            results = run_dask(tasks(), part_states, template, opts.scheduler, 4 * jobs)
        else:
            results = run_local(tasks(), part_states, template, jobs, 2 * jobs)
        for res in results:
            item, digest = by_id[res.id]
            records[item.id] = commit(out, item, digest, res)
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(f"{item.id}: {res.row.get('verdict')}")

    ordered = [records[i.id] for i in items if i.id in records]
    counts = {v: sum(r["row"].get("verdict") == v for r in ordered) for v in VERDICTS}
    files = write_summaries(out, items, ordered, states, o.page, changed=bool(todo) or opts.force)
    return BatchReport(
        ordered, len(todo), skipped, counts, outcomes, time.perf_counter() - t_start, files
    )


# ------------------------------------------------------------------------------ command


def add_batch_arguments(ap: argparse.ArgumentParser) -> None:
    """The ``batch`` sub-command's own arguments (the inspection options come beside)."""
    ap.add_argument("nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh, mm")
    ap.add_argument(
        "scans",
        nargs="+",
        metavar="SCANS",
        help="scan files, folders, quoted glob patterns or manifest CSVs "
        "(columns scan[, serial][, nominal])",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=0,
        metavar="N",
        help="local worker processes (default: one per core; 1 runs in this process)",
    )
    ap.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster whose scheduler is at ADDRESS "
        "(e.g. tcp://10.0.0.5:8786) instead of local processes",
    )
    ap.add_argument(
        "--retry-failed", action="store_true", help="inspect again the scans recorded as failed"
    )


def batch_options(args: argparse.Namespace, options: InspectOptions) -> BatchOptions:
    """The typed options of parsed ``batch`` arguments."""
    return BatchOptions(
        nominal=args.nominal,
        scans=tuple(args.scans),
        out=args.out,
        options=options,
        jobs=args.jobs,
        scheduler=args.scheduler,
        retry_failed=args.retry_failed,
        force=args.force,
        quiet=args.quiet,
    )


def run_batch_command(opts: BatchOptions) -> int:
    """Run a batch and print its account; 0 when every scan passed, else 1."""
    rep = run_batch(opts)
    c = rep.counts
    print(
        f"{len(rep.records)} scans: {c['PASS']} PASS, {c['FAIL']} FAIL, "
        f"{c['NOT ESTABLISHED']} NOT ESTABLISHED, {c['ERROR']} ERROR "
        f"({rep.done} inspected now, {rep.skipped} done earlier) in {rep.seconds:.1f} s"
    )
    for r in rep.records:
        if not r["ok"]:
            print(f"  {r['id']}: error: {r['error']}")
    for nom, outcome in rep.cache.items():
        print(f"{Path(nom).name}: {outcome.describe()}")
    print("summary: " + ", ".join(str(p) for p in rep.summary_files))
    return 0 if c["PASS"] == len(rep.records) else 1
