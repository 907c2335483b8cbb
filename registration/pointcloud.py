"""Scan point clouds: reading and validation.

A scan's points ``P`` are an (m, 3) float64 array in mm, as an optically tracked scanner
delivers them: unordered, partial, noisy, already merged from all views (paper Section 4.1).
:func:`read_scan` returns them as a :class:`qifreport.registration.scan.Scan`, with the
file's unit and format and how many points it held.

Reading checks that the file's content is the format
its suffix names (a PLY file named ``.npy`` is refused as "looks like a PLY file"), removes
exact duplicate points (:func:`unique_points`: a mesh format such as STL repeats every vertex
once per triangle, and a duplicate carries no new measurement but would weigh a point twice),
and refuses a scan that is too small or degenerate (:func:`validate_scan`: fewer than
:data:`MIN_POINTS` distinct points, or all of them on one line).
"""

from __future__ import annotations

import logging
import re
import warnings
from pathlib import Path

import numpy as np
import trimesh

from qifreport.errors import InputError, require_file

from .scan import Scan

__all__ = [
    "COLLINEAR_RATIO",
    "FORMAT_UNITS",
    "MIN_POINTS",
    "SCAN_SUFFIXES",
    "SCAN_UNITS",
    "check_declared_counts",
    "MalformedFile",
    "one_line",
    "read_scan",
    "principal_spreads",
    "read_trimesh",
    "sniff_format",
    "unique_points",
    "validate_scan",
]

log = logging.getLogger(__name__)

SCAN_SUFFIXES = (".ply", ".xyz", ".txt", ".csv", ".npy", ".stl", ".obj", ".off", ".e57")
MIN_POINTS = 100
#: a scan whose spread across its main direction is below this fraction of its spread along
#: it (second over first principal standard deviation) lies on a line: refused
COLLINEAR_RATIO = 1e-3


class MalformedFile(ValueError):
    """A file whose structure contradicts itself (truncated, counts that disagree); the
    reader that called the check wraps it into its own one-line :class:`InputError`
    ("cannot read scan NAME: ...", "cannot read nominal mesh NAME: ...")."""


#: length of one scan unit in mm (``--scan-units``)
SCAN_UNITS = {"mm": 1.0, "in": 25.4, "m": 1000.0}
#: the unit of a format whose standard fixes one (E57: metres, ASTM E2807); others: mm
FORMAT_UNITS = {".e57": "m"}

#: format name -> what messages call it
_FORMAT_NAMES = {
    "ply": "PLY",
    "npy": "NumPy .npy",
    "e57": "E57",
    "stl": "STL",
    "off": "OFF",
    "obj": "OBJ",
    "text": "text (XYZ, TXT, CSV)",
    "zip": "ZIP archive (NumPy .npz?)",
}
#: suffix -> the format its content must be
_SUFFIX_FORMATS = {
    ".ply": "ply",
    ".npy": "npy",
    ".e57": "e57",
    ".stl": "stl",
    ".off": "off",
    ".obj": "obj",
    ".xyz": "text",
    ".txt": "text",
    ".csv": "text",
}
#: formats recognised by a signature at the start of the file
_MAGIC_FORMATS = ("ply", "npy", "e57", "zip")


def sniff_format(path: Path) -> str | None:
    """The format a file's content shows, from its first bytes and its size.

    Recognised: ``"ply"`` (the ``ply`` magic line), ``"npy"`` (``\\x93NUMPY``), ``"e57"``
    (``ASTM-E57``), ``"zip"`` (``PK\\x03\\x04``: a ``.npz``), ``"stl"`` (binary: a size of
    exactly 84 + 50 n bytes for the n triangles its header declares; ASCII: ``solid`` and a
    ``facet`` in the first KiB) and ``"off"`` (an ``OFF`` first token). None: none of these
    (text point files and OBJ have no signature).
    """
    with open(path, "rb") as fh:
        head = fh.read(1024)
    size = path.stat().st_size
    if re.match(rb"ply[ \t]*\r?\n", head):
        return "ply"
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith(b"ASTM-E57"):
        return "e57"
    if head.startswith(b"PK\x03\x04"):
        return "zip"
    if size >= 84 + 50 and size == 84 + 50 * int.from_bytes(head[80:84], "little"):
        return "stl"
    text = head.lstrip()
    if text.startswith(b"solid") and b"facet" in head:
        return "stl"
    if re.match(rb"[CN]?OFF\s", text):
        return "off"
    return None


def _check_format(path: Path) -> None:
    """Refuse a file whose content is another known format than its suffix names, or a
    format with a signature (PLY, NPY, E57) without it; one line (:class:`InputError`)."""
    want = _SUFFIX_FORMATS[path.suffix.lower()]
    found = sniff_format(path)
    if found is not None and found != want:
        article = "an" if found in ("e57", "stl", "off", "obj") else "a"  # an STL, a PLY
        raise InputError(
            f"cannot read scan {path.name}: the file looks like {article} "
            f"{_FORMAT_NAMES[found]} file, "
            f"not {_FORMAT_NAMES[want]} (rename it or convert it)"
        )
    if found is None and want in _MAGIC_FORMATS:
        raise InputError(
            f"cannot read scan {path.name}: not a {_FORMAT_NAMES[want]} file (it does not "
            "start with the format's signature)"
        )


def read_scan(path: str | Path, units: str | None = None, *, deduplicate: bool = True) -> Scan:
    """Read a scan point cloud: its points in mm, its unit, how many points the file held.

    Formats, by suffix: PLY (points, or the vertices of a mesh; ASCII or binary), STL (ASCII
    or binary), OBJ and OFF (vertices), XYZ/TXT/CSV (one point a row; ``#`` comments; a
    first line of column names selects the columns named ``x``, ``y``, ``z``, in any case and
    with a unit suffix such as ``x_mm`` or ``X (mm)``; without one, the first three
    columns), NPY ((m, 3) numeric array) and E57 (every scan in the file, each in the file
    frame through its pose, invalid points dropped; needs the optional package ``pye57``,
    ``pip install 'qifreport[e57]'``). The content must be the format the suffix names.

    Exact duplicate points are removed (:func:`unique_points`, the first of each kept, in
    file order): a mesh format repeats every vertex once per face that uses it (STL: three
    corners per triangle), and a scanner that merges overlapping views may repeat points.

    Parameters
    ----------
    path : the scan file.
    units : the length unit of the numbers in the file, one of :data:`SCAN_UNITS` (``"mm"``,
        ``"in"``, ``"m"``); the points are converted to mm. None: the format's own unit,
        metres for E57 (the standard's unit, :data:`FORMAT_UNITS`), mm for the others.
    deduplicate : remove exact duplicates (default); False keeps every point read (for
        timing the reader alone).

    Returns
    -------
    Scan
        ``points``: (m, 3) float64 C-contiguous array of finite points, mm,
        ``m >= MIN_POINTS``; ``points_read``: the number of valid points in the file (``m``
        plus the duplicates); ``units``: the unit converted from; ``source``: ``path``;
        ``format``: the format read; no ``normals``.

    Raises
    ------
    InputError
        Unknown units, missing, unsupported or unreadable file (whatever the third-party
        reader raised is wrapped), content of another format than the suffix names, fewer
        than ``MIN_POINTS`` distinct points, non-finite coordinates, or all points on one
        line; the message is one line naming the file and the problem.
    """
    path = Path(path)
    if units is not None and units not in SCAN_UNITS:
        raise InputError(f"unknown scan units {units!r} (use {', '.join(SCAN_UNITS)})")
    require_file(path, "scan")
    suffix = path.suffix.lower()
    if suffix not in SCAN_SUFFIXES:
        raise InputError(
            f"{path.name}: unsupported scan format {path.suffix!r} "
            "(use PLY, STL, OBJ, OFF, XYZ, TXT, CSV, NPY or E57)"
        )
    units = FORMAT_UNITS.get(suffix, "mm") if units is None else units
    try:
        _check_format(path)
        with warnings.catch_warnings():  # reader noise; problems are reported below, once
            warnings.simplefilter("ignore")
            P = _finite_points(_points_in_file(path, suffix), path.name)
            if units != "mm":
                P = _finite_points(P * SCAN_UNITS[units], path.name)  # may overflow to inf
            n_read = len(P)
            if deduplicate:
                P = _deduplicated(P, path.name)
            P = validate_scan(P, path.name)
    except InputError:
        raise
    except Exception as exc:  # third-party readers raise many types on corrupt input
        raise InputError(f"cannot read scan {path.name}: {one_line(exc)}") from None
    return Scan(
        points=P, units=units, source=path, points_read=n_read, format=_SUFFIX_FORMATS[suffix]
    )


def _points_in_file(path: Path, suffix: str) -> np.ndarray:
    """The points (or vertices) of a scan file as its format's reader gives them, in the
    file's unit; ``suffix`` lower case."""
    if suffix == ".npy":
        return np.load(path, allow_pickle=False)
    if suffix in (".xyz", ".txt", ".csv"):
        return _read_text_points(path, "," if suffix == ".csv" else None)
    if suffix == ".e57":
        return _read_e57(path)
    if suffix == ".obj":
        return _read_obj_vertices(path)
    geom = read_trimesh(path)
    if isinstance(geom, trimesh.Scene):
        geom = geom.to_geometry() if geom.geometry else None
    P = np.asarray(getattr(geom, "vertices", np.empty((0, 3))))
    check_declared_counts(path, len(P))
    return P


def _deduplicated(P: np.ndarray, name: str) -> np.ndarray:
    """``P`` without its exact duplicates (:func:`unique_points`).

    Raises
    ------
    InputError
        When removing them leaves fewer than :data:`MIN_POINTS` points.
    """
    n_read = len(P)
    P, n_dup = unique_points(P)
    if n_dup and len(P) < MIN_POINTS:
        raise InputError(
            f"{name}: only {len(P)} distinct point{'s' if len(P) > 1 else ''}"
            f" ({n_read} read, {n_dup} duplicates; at least {MIN_POINTS} needed)"
        )
    if n_dup:
        log.debug("%s: %d duplicate points removed", name, n_dup)
    return P


def one_line(exc: BaseException, limit: int = 200) -> str:
    """The first non-empty line of an exception's message (its type name if it has none),
    cut to ``limit`` characters: for one-line error messages."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    why = lines[0] if lines else type(exc).__name__
    return why if len(why) <= limit else why[: limit - 3] + "..."


def read_trimesh(path: Path, force: str | None = None):
    """``trimesh.load`` of a local file, unprocessed, with trimesh's log records silenced.

    trimesh logs (WARNING, ERROR, with tracebacks) on malformed files before it raises or
    returns; the caller reports the problem itself, in one line, so nothing else may reach
    the console. A binary PLY shorter than its header says is refused first
    (:class:`MalformedFile`, "truncated PLY").
    """
    if path.suffix.lower() == ".ply":
        _check_ply_size(path)
    tlog = logging.getLogger("trimesh")  # its modules log to children that inherit its level
    level = tlog.level
    tlog.setLevel(logging.CRITICAL + 1)
    try:
        return trimesh.load(str(path), force=force, process=False)
    finally:
        tlog.setLevel(level)


def check_declared_counts(path: Path, n_vertices: int, faces: bool = False) -> None:
    """Hold a PLY or OFF file's declared element counts against what was read.

    trimesh reads these formats leniently: an ASCII PLY or OFF cut short, or whose header
    counts were edited, comes back with fewer vertices or faces, or with face rows read as
    vertices, and no error. A truncated file must not pass for a complete scan or nominal.

    Parameters
    ----------
    path : the file that was read (checked by suffix: ``.ply``, ``.off``; with ``faces``
        also ``.obj``).
    n_vertices : the number of vertices the reader returned.
    faces : also check the faces (nominal meshes): OBJ indices are 1-based, 0 is invalid.

    Raises
    ------
    MalformedFile
        A count that disagrees with the file body (the caller names the file).
    """
    suffix = path.suffix.lower()
    if suffix == ".ply":
        head = _ply_header(path)
        if head is None:
            return
        fmt, elements, data_start = head
        counts = {name: n for name, n, _ in elements}
        nv = counts.get("vertex")
        if nv is not None and nv != n_vertices:
            raise MalformedFile(
                f"the PLY header declares {nv} vertices, {n_vertices} were "
                "read (truncated or corrupt file)"
            )
        if fmt == "ascii":  # one element a line
            with open(path, "rb") as fh:
                fh.seek(data_start)
                rows = sum(1 for ln in fh if ln.strip())
            if rows != sum(counts.values()):
                raise MalformedFile(
                    f"the PLY header declares {sum(counts.values())} data "
                    f"rows, the file has {rows} (truncated or corrupt file)"
                )
    elif suffix == ".off":
        text = path.read_bytes().decode("utf-8", "replace")
        rows = [ln.split("#", 1)[0].strip() for ln in text.split("OFF", 1)[-1].splitlines()]
        rows = [r for r in rows if r]
        if not rows:
            return
        nv, nf = (int(t) for t in rows[0].split()[:2])
        if nv != n_vertices or len(rows) - 1 != nv + nf:
            raise MalformedFile(
                f"the OFF header declares {nv} vertices and {nf} faces, the "
                f"file has {len(rows) - 1} rows (truncated or corrupt file)"
            )
    elif suffix == ".obj" and faces:
        with open(path, "rb") as fh:
            for ln in fh:
                tok = ln.split()
                if (
                    tok
                    and tok[0] == b"f"
                    and any(t.split(b"/")[0] in (b"0", b"-0", b"+0") for t in tok[1:])
                ):
                    raise MalformedFile(
                        "a face has vertex index 0 (OBJ indices start at 1; corrupt file)"
                    )


#: bytes of the PLY scalar types
_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


def _ply_header(path: Path) -> tuple[str, list[tuple[str, int, int | None]], int] | None:
    """A PLY file's format, elements and data offset, or None if the header is unreadable.

    Returns
    -------
    fmt : ``"ascii"``, ``"binary_little_endian"`` or ``"binary_big_endian"``.
    elements : ``(name, count, min_row_bytes)`` in file order; ``min_row_bytes`` is the size
        of one binary row with every list empty (None for an unknown type).
    data_start : byte offset of the first data byte.
    """
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    nl = head.find(b"\n", end)
    if end < 0 or nl < 0:
        return None
    fmt, elements = "", []
    for ln in head[:end].decode("ascii", "replace").splitlines():
        tok = ln.split()
        if len(tok) >= 2 and tok[0] == "format":
            fmt = tok[1]
        elif len(tok) == 3 and tok[0] == "element":
            if not tok[2].isdigit():
                return None  # the reader reports what it makes of it
            elements.append([tok[1], int(tok[2]), 0])
        elif len(tok) >= 3 and tok[0] == "property" and elements:
            size = _PLY_SIZES.get(tok[2] if tok[1] == "list" else tok[1])
            row = elements[-1][2]
            elements[-1][2] = None if size is None or row is None else row + size
    return fmt, [(n, c, r) for n, c, r in elements], nl + 1


def _check_ply_size(path: Path) -> None:
    """Refuse a binary PLY whose data is shorter than its header's element counts need
    (:class:`MalformedFile`, "truncated PLY: ...")."""
    head = _ply_header(path)
    if head is None or not head[0].startswith("binary"):
        return
    _, elements, data_start = head
    if any(r is None for _, _, r in elements):
        return  # the reader reports what it makes of it
    need = sum(n * r for _, n, r in elements)
    have = path.stat().st_size - data_start
    if have < need:
        what = ", ".join(f"{n} {name!r}" for name, n, _ in elements)
        raise MalformedFile(
            f"truncated PLY: the header declares {what} elements (at least "
            f"{need} bytes of data), the file has {have} bytes"
        )


def _read_obj_vertices(path: Path) -> np.ndarray:
    """The ``v x y z`` rows of an OBJ file, every one (trimesh drops the vertices no face
    uses, which for a scan are points); (m, 3) float64."""
    rows = []
    with open(path, "rb") as fh:
        for ln in fh:
            tok = ln.split()
            if tok and tok[0] == b"v":
                if len(tok) < 4:
                    raise MalformedFile(f"a vertex row with {len(tok) - 1} coordinates (3 needed)")
                rows.append(b" ".join(tok[1:4]))
    if not rows:
        return np.empty((0, 3))
    return np.array([float(t) for r in rows for t in r.split()], dtype=np.float64).reshape(-1, 3)


def _read_text_points(path: Path, delimiter: str | None) -> np.ndarray:
    """The points of a text point file (XYZ/TXT/CSV), one a row; (m, 3) float64.

    Lines after ``#`` are comments. A first line without a single number is a header of
    column names: the columns named x, y and z (:func:`_xyz_columns`) are read. Without a
    header, the first three columns.

    Raises
    ------
    InputError
        A header that names no x, y and z columns (naming the columns found).
    """
    cols = (0, 1, 2)
    skip = 0
    with open(path, "rb") as fh:
        for ln in fh:
            skip += 1
            text = ln.split(b"#", 1)[0].decode("latin-1")
            if not text.strip():
                continue
            if not any(_is_number(t) for t in text.replace(",", " ").split()):
                names = [t.strip().strip("\"'").strip() for t in text.split(delimiter)]
                cols = _xyz_columns(names, path.name)
                break
            skip = 0  # no header: read from the top
            break
    return np.loadtxt(
        path,
        delimiter=delimiter,
        usecols=cols,
        ndmin=2,
        comments="#",
        dtype=np.float64,
        skiprows=skip,
    )


#: a coordinate column name: x, y or z, optionally with a unit (``x_mm``, ``X (mm)``, ``x[mm]``)
_AXIS_NAME = re.compile(r"([xyz])(?:\s*[_\-\s/\[(]\s*(?:mm|m|cm|in|inch)?\s*[\])]?)?", re.I)


def _xyz_columns(names: list[str], name: str) -> tuple[int, int, int]:
    """The indices of the x, y, z columns in a header's column ``names``.

    Raises
    ------
    InputError
        No column, or more than one, for one of the axes; the message lists the columns.
    """
    found: dict[str, list[int]] = {"x": [], "y": [], "z": []}
    for k, col in enumerate(names):
        m = _AXIS_NAME.fullmatch(col)
        if m:
            found[m.group(1).lower()].append(k)
    listed = ", ".join(repr(c) for c in names) or "none"
    missing = [a for a, ks in found.items() if not ks]
    if missing:
        raise InputError(
            f"{name}: the header names no {', '.join(missing)} column "
            f"(columns: {listed}; name the coordinates x, y, z)"
        )
    twice = [a for a, ks in found.items() if len(ks) > 1]
    if twice:
        raise InputError(f"{name}: the header names {', '.join(twice)} twice (columns: {listed})")
    return found["x"][0], found["y"][0], found["z"][0]


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_e57(path: Path) -> np.ndarray:
    """All points of an E57 file: every scan, in the file frame (each scan's pose applied),
    points flagged invalid dropped; (m, 3) float64 in the file's unit (metres, by the
    standard).

    Raises
    ------
    InputError
        When the optional package ``pye57`` is not installed.
    """
    try:
        import pye57
    except ImportError as exc:
        raise InputError(
            f"cannot read scan {path.name}: E57 needs the optional package pye57 "
            f"(pip install 'qifreport[e57]'), which is unavailable: {one_line(exc)}"
        ) from None
    e57 = pye57.E57(str(path), mode="r")
    try:
        parts = []
        for i in range(e57.scan_count):
            # transform=True applies the scan's pose when it has one; read_scan drops the
            # points whose cartesian/spherical invalid state is set
            d = e57.read_scan(i, ignore_missing_fields=True, transform=True)
            parts.append(
                np.column_stack(
                    [
                        np.asarray(d[k], dtype=np.float64).ravel()
                        for k in ("cartesianX", "cartesianY", "cartesianZ")
                    ]
                )
            )
    finally:
        e57.close()
    return np.concatenate(parts) if parts else np.empty((0, 3))


def _finite_points(P: np.ndarray, name: str) -> np.ndarray:
    """``P`` as contiguous float64 (m, 3) finite points, or :class:`InputError` (shape, type,
    empty, NaN/inf)."""
    P = np.asarray(P)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"{name}: expected (m, 3) points, got shape {P.shape}")
    if P.dtype.kind not in "iuf":
        raise InputError(f"{name}: expected numeric coordinates, got type {P.dtype}")
    P = np.ascontiguousarray(P, dtype=np.float64)
    if len(P) == 0:
        raise InputError(f"{name}: the scan is empty (no points)")
    bad = ~np.isfinite(P).all(axis=1)
    if bad.any():
        raise InputError(f"{name}: {int(bad.sum())} of {len(P)} points have NaN/inf coordinates")
    return P


def validate_scan(P: np.ndarray, name: str = "scan") -> np.ndarray:
    """Check an (m, 3) point array; return it as contiguous float64 or raise :class:`InputError`.

    A scan must span a surface: points on one line (the second principal standard deviation
    below :data:`COLLINEAR_RATIO` of the first) fix no pose and measure no surface. A flat
    panel is planar and valid.

    Parameters
    ----------
    P : (m, 3) array of real numbers (integer or float), mm.
    name : what to call the points in the message (the file name).

    Raises
    ------
    InputError
        Wrong shape or non-numeric type, no points, non-finite coordinates, fewer than
        ``MIN_POINTS`` points, or all points on one line (or one point); one line naming
        ``name``.
    """
    P = _finite_points(P, name)
    if len(P) < MIN_POINTS:
        raise InputError(
            f"{name}: only {len(P)} point{'s' if len(P) > 1 else ''} (at least {MIN_POINTS} needed)"
        )
    s = principal_spreads(P)
    if s[0] == 0.0:
        raise InputError(f"{name}: all {len(P)} points coincide (a degenerate scan)")
    if s[1] <= COLLINEAR_RATIO * s[0]:
        raise InputError(
            f"{name}: the {len(P)} points lie on a line ({s[0]:.3g} mm along it, "
            f"{s[1]:.3g} mm across: a degenerate scan, no surface to inspect)"
        )
    return P


def principal_spreads(P: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
    """Standard deviations (3,) of the points along their principal axes, largest first, mm.

    The covariance is summed over chunks of ``chunk`` rows (no (m, 3) temporary).
    """
    c = P[:: max(1, len(P) // 4096)].mean(axis=0)  # a shift near the centroid, for accuracy
    C = np.zeros((3, 3))
    s = np.zeros(3)
    for i in range(0, len(P), chunk):
        X = P[i : i + chunk] - c
        C += X.T @ X
        s += X.sum(axis=0)
    mu = s / len(P)
    C = C / len(P) - np.outer(mu, mu)
    ev = np.linalg.eigvalsh(C)[::-1]
    return np.sqrt(np.clip(ev, 0.0, None))


def unique_points(P: np.ndarray) -> tuple[np.ndarray, int]:
    """The distinct points of ``P``, the first of each in the original order, and the
    number of duplicates removed.

    Two points are duplicates when their coordinates are equal (``-0.0 == 0.0``). Each row is
    hashed to 64 bits; a sort of the hashes finds the candidates (no duplicate: done, one
    ``np.sort``); equal hashes are confirmed on the coordinates, and a hash collision between
    distinct points (odds ~ m^2 / 2^65) falls back to an exact row sort. O(m log m).

    Parameters
    ----------
    P : (m, 3) float64 points, mm (finite).

    Returns
    -------
    Q : (k, 3) the distinct points (``P`` itself when there is no duplicate).
    removed : ``m - k``.
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    m = len(P)
    if m < 2:
        return P, 0
    h = _row_hash(P)
    hs = np.sort(h)  # much faster than argsort: enough to tell that there is no duplicate
    if not (hs[1:] == hs[:-1]).any():
        return P, 0
    order = np.argsort(h)
    hs = h[order]
    del h
    dup = hs[1:] == hs[:-1]  # dup[i]: order[i + 1] has the hash of order[i]
    del hs
    i = np.flatnonzero(dup)
    if not (P[order[i]] == P[order[i + 1]]).all():  # a collision: exact row sort
        _, first = np.unique(P + 0.0, axis=0, return_index=True)
        keep = np.sort(first)
        return P[keep], m - len(keep)
    # every run of equal hashes is one point, repeated
    starts = np.flatnonzero(np.r_[True, ~dup])
    keep = np.minimum.reduceat(order, starts)  # the first occurrence of each point
    keep.sort()
    return P[keep], m - len(keep)


def _row_hash(P: np.ndarray) -> np.ndarray:
    """A 64-bit hash (m,) of each point's coordinates (``-0.0`` hashed as ``0.0``)."""
    bits = P.view(np.uint64)
    h = np.zeros(len(P), dtype=np.uint64)
    neg0 = np.uint64(1 << 63)
    for j, mult in enumerate((0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9)):
        c = bits[:, j].copy()
        c[c == neg0] = 0
        h ^= c
        h *= np.uint64(mult)
        h ^= h >> np.uint64(29)
    return h
