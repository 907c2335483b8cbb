"""Fuzzing the file readers: ``read_scan`` and ``load_mesh`` on arbitrary and damaged files.

The property: for any file content, a reader either returns finite float64 arrays of the
right shape (scan: (m, 3) points, ``m >= MIN_POINTS``; mesh: (n, 3) vertices and (f, 3)
int64 faces indexing them) or raises :class:`qifreport.errors.InputError` with a one-line
message naming the file. Any other exception, or a read that outlives :data:`TIMEOUT_S`,
is a failure.

The cases are arbitrary bytes (optionally behind a format's magic, so the bytes reach the
format's parser) and mutations of small valid files of every supported format (:data:`FORMATS`):
byte flips and writes, truncation, insertion, deletion, duplication, and header edits (a
number in the header replaced by an extreme value, or a keyword swapped for another).

This module is also the library of ``bench/fuzz_readers.py``, which runs the same properties
with many more cases from a fixed seed, and of the format round trips in
``tests/test_robustness.py`` (:func:`encode`, :func:`expected_points`, :func:`grid_mesh`).
"""

from __future__ import annotations

import io
import re
import signal
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from qifreport.errors import InputError
from qifreport.registration.mesh import load_mesh
from qifreport.registration.pointcloud import MIN_POINTS, read_scan
from qifreport.registration.scan import Scan

#: longest a reader may take on one case (s) before the case counts as a hang
TIMEOUT_S = 10.0

# ------------------------------------------------------------------------------------------
# valid files of every format


def grid_mesh(n: int = 11, size: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    """A small bumpy square sheet: ``n * n`` vertices (mm) and ``2 (n-1)^2`` triangles.

    Returns
    -------
    V : (n*n, 3) float64, mm, in ``[0, size]^2`` with a bump of height ``0.2 size``.
    F : (2 (n-1)^2, 3) int64.
    """
    u = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    Z = 0.2 * size * np.exp(-((X - size / 2) ** 2 + (Y - size / 3) ** 2) / (0.1 * size**2))
    V = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()]) + [1.0, -2.0, 3.0]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate(
        [np.column_stack([a, a + n, a + 1]), np.column_stack([a + 1, a + n, a + n + 1])]
    )
    return V, F.astype(np.int64)


def _ply_points(V: np.ndarray, binary: bool) -> bytes:
    head = (
        "ply\nformat {} 1.0\ncomment qifreport fuzz seed\nelement vertex {}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    V32 = np.asarray(V, dtype="<f4")
    if binary:
        return head.format("binary_little_endian", len(V)).encode() + V32.tobytes()
    body = "".join(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V32.astype(float))
    return (head.format("ascii", len(V)) + body).encode()


def _e57(V: np.ndarray) -> bytes:
    """Two E57 scans of ``V`` (mm), stored in metres as the standard wants: the first half
    under a non-trivial pose (points in the scanner frame), the second half with the identity
    pose and 7 points flagged invalid."""
    import pye57

    V = np.asarray(V, dtype=np.float64) / 1000.0
    half = len(V) // 2
    ang = 0.4
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    q = np.r_[np.cos(ang / 2), np.sin(ang / 2) * axis]  # w, x, y, z
    t = np.array([0.1, -0.05, 0.025])
    R = _quat_matrix(q)
    L = (V[:half] - t) @ R  # scanner frame: V = R L + t
    bad = np.full((7, 3), 1e3)
    W = np.concatenate([V[half:], bad])
    invalid = np.r_[np.zeros(len(V) - half, np.int8), np.full(7, 2, np.int8)]
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "seed.e57"
        e = pye57.E57(str(f), mode="w")
        try:
            e.write_scan_raw(
                {"cartesianX": L[:, 0], "cartesianY": L[:, 1], "cartesianZ": L[:, 2]},
                rotation=q,
                translation=t,
            )
            e.write_scan_raw(
                {
                    "cartesianX": W[:, 0],
                    "cartesianY": W[:, 1],
                    "cartesianZ": W[:, 2],
                    "cartesianInvalidState": invalid,
                }
            )
        finally:
            e.close()
        return f.read_bytes()


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of the unit quaternion ``q = (w, x, y, z)``."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _have_pye57() -> bool:
    try:
        import pye57  # noqa: F401
    except ImportError:
        return False
    return True


#: format name -> (suffix, has triangles, stores float32)
FORMATS = {
    "ply-binary-points": (".ply", False, True),
    "ply-ascii-points": (".ply", False, True),
    "ply-binary-mesh": (".ply", True, True),
    "ply-ascii-mesh": (".ply", True, False),
    "stl-binary": (".stl", True, True),
    "stl-ascii": (".stl", True, False),
    "obj": (".obj", True, False),
    "off": (".off", True, False),
    "xyz": (".xyz", False, False),
    "csv": (".csv", False, False),
    "npy": (".npy", False, False),
    "e57": (".e57", False, True),
}


def available_formats() -> list[str]:
    """:data:`FORMATS` this environment can write and read (E57 needs ``pye57``)."""
    return [f for f in FORMATS if f != "e57" or _have_pye57()]


def encode(fmt: str, V: np.ndarray, F: np.ndarray) -> bytes:
    """The bytes of a valid ``fmt`` file (:data:`FORMATS`) of the mesh ``(V, F)`` (mm); point
    formats keep only the vertices. E57 stores metres (the standard's unit), which
    ``read_scan`` reads back in mm by default."""
    import trimesh
    from trimesh.exchange.obj import export_obj
    from trimesh.exchange.off import export_off
    from trimesh.exchange.ply import export_ply
    from trimesh.exchange.stl import export_stl, export_stl_ascii

    tm = trimesh.Trimesh(V, F, process=False)
    if fmt == "ply-binary-points":
        return _ply_points(V, binary=True)
    if fmt == "ply-ascii-points":
        return _ply_points(V, binary=False)
    if fmt == "ply-binary-mesh":
        return export_ply(tm, encoding="binary")
    if fmt == "ply-ascii-mesh":
        return export_ply(tm, encoding="ascii")
    if fmt == "stl-binary":
        return export_stl(tm)
    if fmt == "stl-ascii":
        return export_stl_ascii(tm).encode()
    if fmt == "obj":
        return export_obj(tm, digits=10).encode()
    if fmt == "off":
        return export_off(tm, digits=10).encode()
    if fmt == "xyz":
        buf = io.StringIO()
        np.savetxt(buf, V, fmt="%.17g")
        return ("# x y z (mm)\n" + buf.getvalue()).encode()
    if fmt == "csv":
        buf = io.StringIO()
        np.savetxt(buf, V, fmt="%.17g", delimiter=",")
        return ("x,y,z\n" + buf.getvalue()).encode()  # a header line of column names
    if fmt == "npy":
        buf = io.BytesIO()
        np.save(buf, V)
        return buf.getvalue()
    if fmt == "e57":
        return _e57(V)
    raise ValueError(fmt)


def expected_points(fmt: str, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, float]:
    """The points ``read_scan`` must return for :func:`encode` ``(fmt, V, F)``, in order
    (duplicates removed: the first occurrence of each point), and the absolute tolerance
    (mm): float32 rounding where the format stores float32, the printed digits for text
    formats."""
    suffix, _, f32 = FORMATS[fmt]
    P = V
    if suffix == ".stl":  # STL: three corners per triangle, each point read once
        corners = V[F].reshape(-1, 3)
        _, first = np.unique(corners, axis=0, return_index=True)
        P = corners[np.sort(first)]
    scale = float(np.abs(P).max())
    if fmt == "e57":  # float32 metres in the scanner frame, then posed and scaled to mm
        return P, 4 * np.finfo(np.float32).eps * (scale + 200.0)
    if f32:
        return P, np.finfo(np.float32).eps * scale
    if fmt in ("obj", "off", "stl-ascii", "ply-ascii-mesh"):  # printed digits
        return P, 1e-6 * max(scale, 1.0)
    return P, 0.0


# ------------------------------------------------------------------------------------------
# the property


class ReaderTimeout(BaseException):
    """A read that took longer than :data:`TIMEOUT_S` (not an ``Exception``: a reader's
    ``except Exception`` must not turn a hang into a clean error)."""


@contextmanager
def time_limit(seconds: float):
    """Raise :class:`ReaderTimeout` in the block after ``seconds`` (SIGALRM, main thread)."""

    def _alarm(signum, frame):
        raise ReaderTimeout(f"read took longer than {seconds:g} s")

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


READERS = {"read_scan": read_scan, "load_mesh": load_mesh}
#: reader -> formats it reads (load_mesh needs triangles)
READER_FORMATS = {
    "read_scan": list(FORMATS),
    "load_mesh": [f for f, (_, tri, _) in FORMATS.items() if tri],
}
#: reader -> file suffixes tried with arbitrary bytes
READER_SUFFIXES = {
    "read_scan": [".ply", ".stl", ".obj", ".off", ".xyz", ".csv", ".npy", ".e57"],
    "load_mesh": [".ply", ".stl", ".obj", ".off"],
}


def check_read(reader: str, suffix: str, data: bytes, directory: Path) -> str:
    """Write ``data`` to a ``suffix`` file in ``directory`` and read it with ``reader``.

    Returns
    -------
    ``"ok"`` (valid arrays returned) or ``"error"`` (a one-line InputError naming the file).

    Raises
    ------
    AssertionError
        The reader returned arrays of the wrong type, shape or content, or an InputError
        whose message is not one line naming the file.
    ReaderTimeout
        The read took longer than :data:`TIMEOUT_S`.
    Exception
        Whatever else the reader let escape.
    """
    path = Path(directory) / f"fuzz-case{suffix}"
    path.write_bytes(data)
    try:
        with time_limit(TIMEOUT_S):
            out = READERS[reader](path)
    except InputError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg and "\r" not in msg, f"message not one line: {msg!r}"
        assert path.name in msg, f"message does not name the file: {msg!r}"
        return "error"
    if reader == "read_scan":
        assert isinstance(out, Scan) and out.points_read >= out.n, type(out)
        P = out.points
        assert isinstance(P, np.ndarray) and P.dtype == np.float64, type(P)
        assert P.ndim == 2 and P.shape[1] == 3 and len(P) >= MIN_POINTS, P.shape
        assert P.flags.c_contiguous and np.isfinite(P).all()
    else:
        V, F = out
        assert isinstance(V, np.ndarray) and V.dtype == np.float64, type(V)
        assert isinstance(F, np.ndarray) and F.dtype == np.int64, type(F)
        assert V.ndim == 2 and V.shape[1] == 3 and F.ndim == 2 and F.shape[1] == 3
        assert len(F) > 0 and np.isfinite(V).all()
        assert F.min() >= 0 and F.max() < len(V)
    return "ok"


# ------------------------------------------------------------------------------------------
# mutations

#: mutation kinds of one step; an op is ``(kind, a, b, payload)``, ``a``/``b`` free integers
KINDS = ("flip", "set", "truncate", "insert", "delete", "duplicate", "header")
#: how much of a file is its header (numbers and keywords there are edited)
HEADER_BYTES = 600
_NUMBER = re.compile(rb"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
_EXTREME = [
    b"0",
    b"1",
    b"2",
    b"-1",
    b"3",
    b"99",
    b"100",
    b"255",
    b"256",
    b"65536",
    b"2147483647",
    b"2147483648",
    b"4294967295",
    b"4294967296",
    b"-2147483648",
    b"9223372036854775807",
    b"18446744073709551616",
    b"1000000000000",
    b"1e308",
    b"-1e308",
    b"1e-320",
    b"nan",
    b"inf",
    b"-inf",
    b"0x10",
    b"1.5",
    b"",
    b" ",
    b"x",
]
#: keyword -> replacements (PLY header, NPY header, OFF/OBJ/STL tokens)
_SWAPS = {
    b"binary_little_endian": [b"binary_big_endian", b"ascii", b"binary"],
    b"ascii": [b"binary_little_endian", b"binary_big_endian"],
    b"float": [b"double", b"uchar", b"int", b"char", b"list uchar float", b"float16", b""],
    b"double": [b"float", b"uint", b"short"],
    b"uchar": [b"int", b"uint", b"char", b"double", b"float"],
    b"int": [b"uchar", b"short", b"float", b"int64"],
    b"vertex": [b"face", b"edge", b"vertex vertex", b"VERTEX"],
    b"face": [b"vertex", b"edge", b"faces"],
    b"end_header": [b"end_heade", b"", b"end_header\nend_header", b"property float w\nend_header"],
    b"element": [b"elements", b"comment", b"property"],
    b"property": [b"element", b"comment", b"propertyfloat"],
    b"<f8": [b"<f4", b">f8", b"|O", b"<c16", b"|S8", b"<M8[s]", b"<i8", b"|b1", b"<U4", b"V24"],
    b"'fortran_order': False": [b"'fortran_order': True"],
    b"'shape': (": [b"'shape': (0, ", b"'shape': (1, 2, ", b"'shape': ()"],
    b"OFF": [b"COFF", b"NOFF", b"OF", b"OFF OFF"],
    b"facet normal": [b"facet", b"normal facet", b"endfacet"],
    b"outer loop": [b"loop", b"endloop"],
    b"endsolid": [b"solid", b""],
    b"\nv ": [b"\nvn ", b"\nf ", b"\nvt "],
    b"\nf ": [b"\nv ", b"\nl ", b"\nf -", b"\nf 0 "],
    b'type="Float"': [
        b'type="Integer"',
        b'type="ScaledInteger"',
        b'type="String"',
        b'type="Structure"',
        b'type="Vector"',
        b'type="CompressedVector"',
    ],
    b'precision="single"': [b'precision="double"', b'precision=""'],
    b'type="CompressedVector"': [b'type="Vector"', b'type="Structure"'],
    b'recordCount="': [b'recordCount="-', b'recordCount="9999999999', b'recordCount="x'],
    b'fileOffset="': [b'fileOffset="9', b'fileOffset="-', b'fileOffset="x'],
    b'allowHeterogeneousChildren="1"': [b'allowHeterogeneousChildren="0"'],
    b"cartesianX": [b"cartesianQ", b"sphericalRange", b"cartesianY"],
    b"</": [b"<", b"</x", b""],
}
#: prefixes put before arbitrary bytes so that they reach a format's parser
MAGICS = [
    b"",
    b"ply\nformat ascii 1.0\n",
    b"ply\nformat binary_little_endian 1.0\n",
    b"ply\nformat binary_little_endian 1.0\nelement vertex 200\nproperty float x\n"
    b"property float y\nproperty float z\nend_header\n",
    b"\x93NUMPY\x01\x00",
    b"solid x\n",
    b"OFF\n",
    b"v 0 0 0\n",
    b"ASTM-E57",
]


def _header_edit(data: bytes, a: int, b: int) -> bytes:
    h0 = 0
    if data.startswith(b"ASTM-E57"):  # E57: the XML section holds the structure
        h0 = max(data.find(b"<e57Root"), 0)
    head = data[h0 : h0 + (4 if h0 else 1) * HEADER_BYTES]
    if (
        a % 3 == 0
        and len(data) >= 84
        and not h0
        and not head.lstrip().startswith((b"solid", b"ply"))
    ):
        # binary STL: the little-endian uint32 triangle count after the 80-byte header
        return data[:80] + (b % 2**32).to_bytes(4, "little") + data[84:]
    if a % 3 == 1:
        keys = [k for k in _SWAPS if k in head]
        if keys:
            k = keys[b % len(keys)]
            repl = _SWAPS[k][(b // len(keys)) % len(_SWAPS[k])]
            i = h0 + head.find(k)
            return data[:i] + repl + data[i + len(k) :]
    nums = list(_NUMBER.finditer(head))
    if not nums:
        return data
    m = nums[b % len(nums)]
    repl = _EXTREME[(b // len(nums)) % len(_EXTREME)]
    return data[: h0 + m.start()] + repl + data[h0 + m.end() :]


#: E57 files are 1024-byte pages, each 1020 bytes of content and a big-endian CRC-32C
E57_PAGE = 1024


def _crc32c_table() -> list[int]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    return table


_CRC32C = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli) of ``data``, the checksum of an E57 page."""
    c = 0xFFFFFFFF
    for x in data:
        c = _CRC32C[(c ^ x) & 0xFF] ^ (c >> 8)
    return c ^ 0xFFFFFFFF


def e57_pages(logical: bytes) -> bytes:
    """E57 physical bytes of ``logical`` content: 1020-byte pages (the last one padded with
    zeros), each followed by its CRC-32C."""
    n = E57_PAGE - 4
    out = bytearray()
    for i in range(0, max(len(logical), 1), n):
        page = logical[i : i + n].ljust(n, b"\0")
        out += page + crc32c(page).to_bytes(4, "big")
    return bytes(out)


def e57_content(physical: bytes) -> bytes:
    """The logical content of E57 ``physical`` bytes (the checksums removed)."""
    return b"".join(physical[i : i + E57_PAGE - 4] for i in range(0, len(physical), E57_PAGE))


def mutated(fmt: str, ops) -> bytes:
    """The seed of ``fmt`` under the mutation ``ops``. For E57, when the first op's ``a`` is
    even, the content is mutated and the page checksums recomputed, so that the damage
    reaches the XML and binary sections instead of failing the checksum."""
    data = seed(fmt)
    if fmt == "e57" and ops and ops[0][1] % 2 == 0:
        content = mutate(e57_content(data), ops)
        if len(content) >= 24:  # the header's physical file length follows the edit
            n = -(-max(len(content), 1) // (E57_PAGE - 4)) * E57_PAGE
            content = content[:16] + n.to_bytes(8, "little") + content[24:]
        return e57_pages(content)
    return mutate(data, ops)


def mutate(data: bytes, ops) -> bytes:
    """Apply the mutation ``ops`` (a sequence of ``(kind, a, b, payload)``, kinds from
    :data:`KINDS`) to ``data``, in order; a deterministic function of its arguments."""
    for kind, a, b, payload in ops:
        n = len(data)
        if kind == "header":
            data = _header_edit(data, a, b)
        elif n == 0:
            data = bytes(payload)
        elif kind == "flip":
            i = a % n
            data = data[:i] + bytes([data[i] ^ (1 << (b % 8))]) + data[i + 1 :]
        elif kind == "set":  # overwrite in place, the length kept
            i = a % n
            w = bytes(payload[: 1 + b % 8] or b"\x00")[: n - i]
            data = data[:i] + w + data[i + len(w) :]
        elif kind == "truncate":
            data = data[: a % (n + 1)]
        elif kind == "insert":
            i = a % (n + 1)
            data = data[:i] + bytes(payload) * (1 + b % 4) + data[i:]
        elif kind == "delete":
            i = a % n
            data = data[:i] + data[i + 1 + b % 64 :]
        elif kind == "duplicate":
            i = a % n
            data = data[:i] + data[i : i + 1 + b % 256] + data[i:]
    return data


_SEEDS: dict[str, bytes] = {}


def seed(fmt: str) -> bytes:
    """The valid ``fmt`` file of :func:`grid_mesh` (cached)."""
    if fmt not in _SEEDS:
        _SEEDS[fmt] = encode(fmt, *grid_mesh())
    return _SEEDS[fmt]


# ------------------------------------------------------------------------------------------
# the in-suite run: 150 cases per reader (50 arbitrary, 100 mutated), deterministic

_SETTINGS = dict(
    deadline=None,
    derandomize=True,
    database=None,
    print_blob=True,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.function_scoped_fixture,
    ],
)
_op = st.tuples(
    st.sampled_from(KINDS),
    st.integers(0, 2**31 - 1),
    st.integers(0, 2**31 - 1),
    st.binary(min_size=1, max_size=12),
)
_ops = st.lists(_op, min_size=1, max_size=4)


@pytest.fixture(scope="module")
def case_dir():
    with tempfile.TemporaryDirectory(prefix="qifreport-fuzz-") as d:
        yield Path(d)


def test_seed_files_read(case_dir):
    """Every seed is valid: the property's mutations start from files that read."""
    for reader, fmts in READER_FORMATS.items():
        for fmt in fmts:
            if fmt in available_formats():
                assert check_read(reader, FORMATS[fmt][0], seed(fmt), case_dir) == "ok", fmt


@pytest.mark.parametrize("reader", list(READERS))
@settings(max_examples=50, **_SETTINGS)
@given(data=st.data())
def test_arbitrary_bytes(reader, data, case_dir):
    suffix = data.draw(st.sampled_from(READER_SUFFIXES[reader]), label="suffix")
    body = data.draw(st.sampled_from(MAGICS), label="magic") + data.draw(
        st.binary(max_size=4096), label="bytes"
    )
    check_read(reader, suffix, body, case_dir)


@pytest.mark.parametrize("reader", list(READERS))
@settings(max_examples=100, **_SETTINGS)
@given(data=st.data())
def test_mutated_valid_files(reader, data, case_dir):
    fmts = [f for f in READER_FORMATS[reader] if f in available_formats()]
    fmt = data.draw(st.sampled_from(fmts), label="format")
    ops = data.draw(_ops, label="ops")
    check_read(reader, FORMATS[fmt][0], mutated(fmt, ops), case_dir)
