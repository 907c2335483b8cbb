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
import difflib
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

#: the columns a manifest may have (``scan`` required)
MANIFEST_COLUMNS = ("scan", "serial", "nominal")

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
    """:func:`read_manifest`'s rows, each with its line (``"manifest.csv line 3"``).

    Raises
    ------
    InputError
        Naming the line: an unclosed quote, more cells than columns, an empty ``scan``; or
        the manifest: no ``scan`` column, a column that misspells a known one.
    """
    base = path.parent
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh, strict=True)
            _check_columns(path, [c.strip().lower() for c in (reader.fieldnames or [])])
            rows: list[_Row] = []
            done = reader.line_num  # the last line of the records read so far
            try:
                for raw in reader:
                    rows.append(_manifest_row(path, base, nominal, raw, reader.line_num))
                    done = reader.line_num
            except csv.Error as exc:
                why = "a quote is never closed" if "end of data" in str(exc) else str(exc)
                raise InputError(f"manifest {path} line {done + 1}: {why}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"manifest {path} is not UTF-8 text") from exc
    except csv.Error as exc:
        raise InputError(f"manifest {path} line 1: {exc}") from None
    return rows


def _check_columns(path: Path, cols: list[str]) -> None:
    """Refuse a manifest without a ``scan`` column or with a misspelt known column (a
    ``serail`` column would lose every serial number); warn of other columns, not read."""
    if "scan" not in cols:
        raise InputError(
            f"manifest {path} has no 'scan' column (columns: {', '.join(cols) or 'none'})"
        )
    for c in cols:
        if c in MANIFEST_COLUMNS:
            continue
        near = difflib.get_close_matches(c, MANIFEST_COLUMNS, n=1, cutoff=0.7)
        if near:
            raise InputError(
                f"manifest {path}: column {c!r} is not one of {', '.join(MANIFEST_COLUMNS)} "
                f"(did you mean {near[0]!r}?)"
            )
        log.warning(
            "manifest %s: column %r is not read (only %s)", path, c, ", ".join(MANIFEST_COLUMNS)
        )


def _manifest_row(path: Path, base: Path, nominal: Path, raw: dict, line: int) -> _Row:
    """One manifest record (``raw`` from :class:`csv.DictReader`, ending on ``line``)."""
    if raw.get(None):
        raise InputError(
            f"manifest {path} line {line}: {len(raw[None])} more cell(s) than columns "
            f"({', '.join(map(repr, raw[None]))})"
        )
    row = {str(a).strip().lower(): (b or "").strip() for a, b in raw.items() if a is not None}
    if not row.get("scan"):
        raise InputError(f"manifest {path} line {line}: empty 'scan'")
    scan = Path(row["scan"])
    nom = Path(row["nominal"]) if row.get("nominal") else nominal
    return (
        scan if scan.is_absolute() else base / scan,
        row.get("serial", ""),
        nom if nom.is_absolute() or nom is nominal else base / nom,
        f"{path.name} line {line}",
    )


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
    """A CSV whose first line names a ``scan`` column; a CSV point cloud starts with numbers
    or names x, y, z columns.

    Raises
    ------
    InputError
        A first line of names that is neither (``file,serial``): a manifest without its
        ``scan`` column.
    """
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            first = fh.readline()
    except OSError:
        return False
    cells = [c.strip().strip("\"'").strip().lower() for c in first.split("#", 1)[0].split(",")]
    if "scan" in cells:
        return True
    names = [c for c in cells if c]
    if not names or any(_NUMBER.fullmatch(c) for c in names):
        return False
    if sum(bool(_AXIS.fullmatch(c)) for c in names) >= 3:
        return False
    raise InputError(
        f"{p} is neither a point cloud (no x, y, z columns) nor a manifest: no 'scan' "
        f"column (columns: {', '.join(names)})"
    )


_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
_AXIS = re.compile(r"[xyz](\W.*|_.*)?")
