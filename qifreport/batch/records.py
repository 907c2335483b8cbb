"""Per-scan records of a batch: the digest of everything that made a scan's outputs, and
the atomic commit of the outputs followed by the record (which marks a finished scan).
"""

from __future__ import annotations

import hashlib
import json
from datetime import datetime, timezone
from pathlib import Path

from qifreport import __version__
from qifreport.atomic_io import atomic_write_many

from ..jsonio import finite, json_default
from ..options import InspectOptions
from .plan import ScanItem
from .task import TaskResult

__all__ = ["RECORD_FORMAT", "commit", "read_record", "record_digest", "record_path"]

#: version of the record files' layout (part of the digest: a new layout redoes the scans);
#: 2: the summary row has the feature characteristics' columns
#: (:func:`qifreport.batch.task.characteristic_columns`)
RECORD_FORMAT = 2


def record_digest(
    scan_sha256: str, nominal_sha256: str, item: ScanItem, options: InspectOptions
) -> str:
    """SHA-256 of everything that made a scan's outputs."""
    doc = {
        "format": RECORD_FORMAT,
        "software": __version__,
        "scan": scan_sha256,
        "nominal": nominal_sha256,
        "serial": item.serial,
        "id": item.id,
        "options": options.result_options(),
    }
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
    rec = {
        "format": RECORD_FORMAT,
        "digest": digest,
        "id": item.id,
        "seq": item.seq,
        "scan": str(item.scan),
        "nominal": str(item.nominal),
        "ok": result.ok,
        "error": result.error,
        "final": result.ok or result.final,
        "outputs": sorted(result.files),
        "worker": result.worker,
        "peak_rss_mib": result.peak_rss_mib,
        "seconds": result.seconds,
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "row": finite(result.row),
    }
    items = [(scans / name, _bytes_writer(data)) for name, data in result.files.items()]
    items.append(
        (
            record_path(out, item),
            lambda p: p.write_text(
                json.dumps(rec, indent=1, allow_nan=False, default=json_default)
            ),
        )
    )
    atomic_write_many(items)  # the record is renamed last: it marks a finished scan
    return rec


def _bytes_writer(data: bytes):
    return lambda p: p.write_bytes(data)
