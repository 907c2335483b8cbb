"""The plan of a batch: which scans, in which order, under which ids.

``SCANS`` are scan files, folders (every scan file in them, by name), glob patterns (quoted,
expanded here) or manifest CSVs with a ``scan`` column and optional ``serial`` and
``nominal`` columns (paths relative to the manifest). Each scan gets an id: its serial number
when the manifest gives one, else its file stem (made unique).

A scan file named twice (by two manifest rows, or a folder and a row) is inspected once, with
a warning, when the two agree; one scan cannot be two parts, so two different serial numbers
(or nominals) for one scan file are refused (:class:`InputError` naming the rows).
"""

from __future__ import annotations

import csv
import glob
import hashlib
import logging
import re
from dataclasses import dataclass
from pathlib import Path

from qifreport.errors import InputError
from qifreport.registration.pointcloud import SCAN_SUFFIXES

__all__ = ["ScanItem", "plan", "read_manifest", "safe_id"]

log = logging.getLogger("qifreport.batch")

#: a planned row: scan, serial ("" if none), nominal, where it was named (for messages)
_Row = tuple[Path, str, Path, str]


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
    return sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in SCAN_SUFFIXES and not p.name.startswith(".")
    )


def read_manifest(path: Path, nominal: Path) -> list[tuple[Path, str, Path]]:
    """Rows ``(scan, serial, nominal)`` of a manifest CSV (header row with ``scan``; optional
    ``serial`` and ``nominal``; relative paths are relative to the manifest's folder)."""
    return [row[:3] for row in _manifest_rows(path, nominal)]


def _manifest_rows(path: Path, nominal: Path) -> list[_Row]:
    """:func:`read_manifest`'s rows, each with its line (``"manifest.csv line 3"``)."""
    base = path.parent
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            cols = [c.strip().lower() for c in (reader.fieldnames or [])]
            if "scan" not in cols:
                raise InputError(
                    f"manifest {path} has no 'scan' column (columns: {', '.join(cols) or 'none'})"
                )
            rows = []
            for k, raw in enumerate(reader, start=2):
                row = {
                    str(a).strip().lower(): (b or "").strip()
                    for a, b in raw.items()
                    if a is not None
                }
                if not row.get("scan"):
                    raise InputError(f"manifest {path} line {k}: empty 'scan'")
                scan = Path(row["scan"])
                nom = Path(row["nominal"]) if row.get("nominal") else nominal
                rows.append(
                    (
                        scan if scan.is_absolute() else base / scan,
                        row.get("serial", ""),
                        nom if nom.is_absolute() or nom is nominal else base / nom,
                        f"{path.name} line {k}",
                    )
                )
    except UnicodeDecodeError as exc:
        raise InputError(f"manifest {path} is not UTF-8 text") from exc
    return rows


def safe_id(s: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", s).strip("._")
    return s[:80] or "scan"


def plan(nominal: Path, sources: list[str]) -> list[ScanItem]:
    """The scans named by ``sources`` (files, folders, globs, manifest CSVs), in order,
    each once, with unique ids."""
    rows: list[_Row] = []
    for src in sources:
        p = Path(src)
        if p.is_dir():
            found = _scan_files(p)
            if not found:
                raise InputError(f"no scan files ({', '.join(SCAN_SUFFIXES)}) in folder {p}")
            rows += [(f, "", nominal, f"folder {p}") for f in found]
        elif p.is_file() and p.suffix.lower() == ".csv" and _looks_like_manifest(p):
            rows += _manifest_rows(p, nominal)
        elif p.is_file():
            rows.append((p, "", nominal, "the command line"))
        elif _is_glob(src):
            found = sorted(Path(f) for f in glob.glob(src) if Path(f).is_file())
            if not found:
                raise InputError(f"no file matches {src!r}")
            rows += [(f, "", nominal, f"pattern {src!r}") for f in found]
        else:
            # a missing scan is a per-scan failure, recorded, not a batch failure
            rows.append((p, "", nominal, "the command line"))
    unique = _each_scan_once(rows)
    if not unique:
        raise InputError("no scans given")
    ids = [safe_id(serial or scan.stem) for scan, serial, _ in unique]
    dup = {i for i in ids if ids.count(i) > 1}
    items = []
    for k, ((scan, serial, nom), i) in enumerate(zip(unique, ids, strict=True), start=1):
        if i in dup:  # same stem in two folders: a stable suffix from the path
            i = f"{i}-{hashlib.sha256(str(scan.resolve()).encode()).hexdigest()[:8]}"
        items.append(ScanItem(seq=k, id=i, scan=scan, nominal=nom, serial=serial))
    return items


def _each_scan_once(rows: list[_Row]) -> list[tuple[Path, str, Path]]:
    """The rows with each scan file (by resolved path) once, at its first place.

    A repeat that agrees with the first row (same serial or none, same nominal) is dropped
    with a warning; its serial is kept when only the repeat gives one.

    Raises
    ------
    InputError
        One scan file named with two different serial numbers, or against two nominals.
    """
    first: dict[Path, int] = {}
    unique: list[list] = []
    for scan, serial, nom, origin in rows:
        key = scan.resolve()
        if key not in first:
            first[key] = len(unique)
            unique.append([scan, serial, nom, origin])
            continue
        kept = unique[first[key]]
        if serial and kept[1] and serial != kept[1]:
            raise InputError(
                f"scan {scan} is listed twice with different serial numbers ({kept[1]!r} "
                f"at {kept[3]}, {serial!r} at {origin}): one scan cannot be two parts"
            )
        if nom.resolve() != kept[2].resolve():
            raise InputError(
                f"scan {scan} is listed twice against different nominals ({kept[2].name} "
                f"at {kept[3]}, {nom.name} at {origin}): name each scan once"
            )
        log.warning("scan %s is listed twice (%s and %s): inspected once", scan, kept[3], origin)
        if serial and not kept[1]:
            kept[1] = serial
    return [(scan, serial, nom) for scan, serial, nom, _ in unique]


def _looks_like_manifest(p: Path) -> bool:
    """A CSV whose first line names a ``scan`` column (a CSV point cloud has numbers)."""
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            first = fh.readline()
    except OSError:
        return False
    return "scan" in [c.strip().lower() for c in first.split(",")]
