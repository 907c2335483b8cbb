"""Where a batch's tasks run: local processes (each receives the prepared states once, at
start-up) or a Dask cluster (the states are scattered once; Dask reschedules the tasks of a
worker that dies).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterable, Iterator

from qifreport.errors import InputError

from ..cache import PartState
from ..options import InspectJob
from .task import ScanTask, TaskResult, error_row, run_task

__all__ = ["run_dask", "run_local"]

log = logging.getLogger("qifreport.batch")


_WORKER_STATES: dict[str, PartState] = {}


def _init_worker(states: dict[str, PartState], blas_threads: int) -> None:
    """Process-pool initializer: receive the prepared states once."""
    _WORKER_STATES.update(states)
    with contextlib.suppress(ImportError):
        from threadpoolctl import threadpool_limits

        threadpool_limits(blas_threads)
    logging.getLogger().setLevel(logging.WARNING)


def _run_local(task: ScanTask, job: InspectJob) -> TaskResult:
    return run_task(task, _WORKER_STATES[task.part_key], job)


def run_local(
    tasks: Iterable[ScanTask], states: dict[str, PartState], job: InspectJob, jobs: int, window: int
) -> Iterator[TaskResult]:
    """Run tasks on ``jobs`` local processes (in this process when ``jobs == 1``).

    A pool broken by a dying worker is replaced and its unfinished tasks resubmitted (up to
    three times).
    """
    if jobs <= 1:
        for t in tasks:
            yield run_task(t, states[t.part_key], job)
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
        with ProcessPoolExecutor(
            jobs, mp_context=ctx, initializer=_init_worker, initargs=(states, blas)
        ) as pool:
            running: dict = {}
            broken = False
            while True:
                while len(running) < window and not broken:
                    t = retry.pop() if retry else next(pending, None)
                    if t is None:
                        break
                    running[pool.submit(_run_local, t, job)] = t
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
                yield TaskResult(
                    t.item.id,
                    False,
                    {},
                    error_row(t.item, t.scan_sha256, "worker process died (3 times)"),
                    error="worker process died (3 times)",
                )
            retry = []


def run_dask(
    tasks: Iterable[ScanTask],
    states: dict[str, PartState],
    job: InspectJob,
    address: str,
    window: int,
) -> Iterator[TaskResult]:
    """Run tasks on the Dask cluster at ``address``; the states are scattered once."""
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise InputError(
            "--scheduler needs Dask's 'distributed' package (pip install distributed)"
        ) from exc
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {address}: {exc}") from exc
    with client:
        n = max(1, len(client.scheduler_info().get("workers", {})))
        window = max(window, 2 * n)
        futures = {k: client.scatter(s, broadcast=True, hash=False) for k, s in states.items()}
        pending = iter(tasks)
        ac = as_completed()
        meta = {}

        def submit(t: ScanTask) -> None:
            f = client.submit(
                run_task,
                t,
                futures[t.part_key],
                job,
                pure=False,
                key=f"qifreport-{t.item.id}-{t.scan_sha256[:12]}",
            )
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
                yield TaskResult(
                    t.item.id, False, {}, error_row(t.item, t.scan_sha256, msg), error=msg
                )
            f.release()
            nxt = next(pending, None)
            if nxt is not None:
                submit(nxt)
