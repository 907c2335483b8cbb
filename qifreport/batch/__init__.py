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
    ``scans/<id>.qif``, ``.pdf``, ``.json`` (and ``.html`` with ``--html``): exactly what
    ``qifreport NOMINAL SCAN --json`` writes, and ``scans/<id>.record.json``: the scan's summary row
    and the digest of everything that made it (scan and nominal SHA-256, the inspection options, the
    software version). The record is renamed into place last, after the outputs, so it marks a
    finished scan. A scan that cannot be inspected (bad file, pose not established, internal error)
    gets a record with its one-line error and no other output; it does not stop the batch.
    ``summary.csv`` and ``summary.parquet`` hold one row per scan in plan order; per nominal,
    ``<part>_statistics.qif`` (the QIF 3.0 Statistics document, :mod:`qifreport.qif.statistics`) and
    ``<part>_trend.pdf`` (run charts, :mod:`qifreport.reports.trend`). Every file is written
    atomically.

Resume
    Running the same command again skips every scan whose record and outputs exist and
    whose digest matches (a changed scan, nominal or option redoes it); recorded failures are
    skipped too unless ``--retry-failed``; ``--force`` redoes everything.

Exit code: 0 every scan passed, 1 any scan failed, was not established or could not be
inspected (see the summary), 2 the batch itself could not run.
"""

from .plan import ScanItem, plan, read_manifest
from .run import (
    VERDICTS,
    BatchOptions,
    BatchReport,
    add_batch_arguments,
    batch_options,
    run_batch,
    run_batch_command,
)
from .summaries import summary_frame

__all__ = [
    "VERDICTS",
    "BatchOptions",
    "BatchReport",
    "ScanItem",
    "add_batch_arguments",
    "batch_options",
    "plan",
    "read_manifest",
    "run_batch",
    "run_batch_command",
    "summary_frame",
]
