"""Hard inputs (issue 7): bad input exits 2 with one line naming the problem and writes
nothing; every scan format reads back its points; damaged files are refused by name.

The CLI cases here are the ones ``tests/test_cli.py::bad_inputs`` does not already cover
(empty .xyz, NaN .npy, inch-sized scan, no overlap and another part are there). Every one
fails before the registration starts (about 1-3 s each); one run goes end to end
(``--scan-units in``).
"""

from __future__ import annotations

import json
import logging
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from qifreport.errors import InputError
from qifreport.registration.mesh import load_mesh
from qifreport.registration.pointcloud import read_scan
from tests.conftest import assert_valid_summary
from tests.test_cli import SAMPLES, run, write_points
from tests.test_fuzz_readers import FORMATS, encode, expected_points, grid_mesh, seed

NOMINAL = SAMPLES / "shell_nominal.ply"
SCAN = SAMPLES / "shell_scan.ply"

#: a valid Part 21 file with no geometry to inspect: one point, no solid, shell or face
STEP_NO_SOLID = """ISO-10303-21;
HEADER;
FILE_DESCRIPTION((''),'2;1');
FILE_NAME('point.step','2026-01-01T00:00:00',(''),(''),'','','');
FILE_SCHEMA(('AP242_MANAGED_MODEL_BASED_3D_ENGINEERING_MIM_LF { 1 0 10303 442 1 1 4 }'));
ENDSEC;
DATA;
#1=CARTESIAN_POINT('origin',(0.,0.,0.));
ENDSEC;
END-ISO-10303-21;
"""


@pytest.fixture(scope="module")
def shell_points() -> np.ndarray:
    """The demo scan's points (mm)."""
    return read_scan(SCAN).points


def assert_refused(r, word: str, out: Path) -> None:
    """Exit 2, one stderr line ``qifreport: error: ...`` containing ``word``, nothing on
    stdout, nothing in ``out``."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qifreport: error:"), r.stderr
    assert word in lines[0], lines[0]
    assert r.stdout == ""
    assert not out.exists() or not any(out.iterdir()), list(out.iterdir())


# ------------------------------------------------------------------------------------------
# the CLI on bad inputs


def _one_point(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "one.xyz"
    np.savetxt(f, P[:1])
    return [NOMINAL, f]


def _inf(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "inf.ply"
    Q = P.copy()
    Q[::500, 1] = np.inf
    write_points(f, Q)
    return [NOMINAL, f]


def _no_vertices(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "none.ply"
    f.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 0\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    return [NOMINAL, f]


def _truncated_ply(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "cut.ply"
    write_points(f, P)  # binary little-endian float32
    data = f.read_bytes()
    f.write_bytes(data[: int(0.6 * len(data))])
    return [NOMINAL, f]


def _not_step(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "part.step"
    f.write_text("This is a text file that someone renamed to .step.\nx = 1\n")
    return [f, SCAN]


def _step_no_solid(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "point.step"
    f.write_text(STEP_NO_SOLID)
    return [f, SCAN]


def _step_truncated(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "half.step"
    data = (SAMPLES / "panel.step").read_bytes()
    f.write_bytes(data[: len(data) // 2])
    return [f, SAMPLES / "panel_scan.ply"]


def _scan_1000x(tmp: Path, P: np.ndarray) -> list:
    f = tmp / "big.ply"
    write_points(f, 1000.0 * P)
    return [NOMINAL, f]


def _units_m_on_mm(tmp: Path, P: np.ndarray) -> list:
    return [NOMINAL, SCAN, "--scan-units", "m"]


BAD = {
    "one-point scan": (_one_point, "at least 100"),
    "inf coordinates": (_inf, "NaN/inf"),
    "PLY without vertices": (_no_vertices, "empty"),
    "truncated binary PLY": (_truncated_ply, "truncated"),
    "not STEP": (_not_step, "not a STEP file"),
    "STEP without solid": (_step_no_solid, "no solid"),
    # OCCT's parse error, which it prints to stdout, becomes the reason in the one line
    "truncated STEP": (_step_truncated, "unexpected end of file"),
    "scan 1000x too large": (_scan_1000x, "units"),
    "--scan-units m on a mm scan": (_units_m_on_mm, "units"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exits_2_one_line_nothing_written(tmp_path, shell_points, case):
    make, word = BAD[case]
    args = make(tmp_path, shell_points)
    out = tmp_path / "out"
    r = run(
        *args,
        "--tolerance",
        "0.5",
        "--out",
        out,
        "--json",
        "--export-mesh",
        out / "m.ply",
        "--quiet",
    )
    assert_refused(r, word, out)


def test_read_only_output_directory(tmp_path):
    if os.geteuid() == 0:  # root writes through mode 0o555; procfs refuses even root
        out = Path("/proc/self/qifreport-out")
        if os.access("/proc/self", os.W_OK):
            pytest.skip("no directory here that root cannot write")
    else:
        out = tmp_path / "ro"
        out.mkdir()
        out.chmod(0o555)
    try:
        r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", out, "--json", "--quiet")
        assert_refused(r, "not writable", out)
    finally:
        if out.is_relative_to(tmp_path):
            out.chmod(0o755)


def test_existing_output_needs_force(tmp_path):
    qif = tmp_path / "shell_nominal.qif"
    qif.write_text("an earlier report\n")
    r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", tmp_path, "--json", "--quiet")
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qifreport: error:"), r.stderr
    assert "output exists" in lines[0] and "--force" in lines[0], lines[0]
    assert r.stdout == ""
    assert qif.read_text() == "an earlier report\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shell_nominal.qif"]


@pytest.mark.slow
def test_scan_units_in_reads_an_inch_scan(tmp_path, shell_points):
    inch = tmp_path / "scan_in.ply"
    write_points(inch, shell_points / 25.4)
    out = tmp_path / "out"
    r = run(
        NOMINAL,
        inch,
        "--scan-units",
        "in",
        "--tolerance",
        "0.5",
        "--out",
        out,
        "--json",
        "--no-pdf",
        "--no-qif",
        "--quiet",
    )
    assert r.returncode in (0, 1), r.stdout + r.stderr
    assert "verdict:" in r.stdout
    doc = json.loads((out / "shell_nominal.json").read_text())
    assert_valid_summary(doc)
    assert doc["vertex_deviation"]["rms"] < 0.05  # the demo scan, back in mm


# ------------------------------------------------------------------------------------------
# scan formats: round trips


def _need_pye57(fmt: str) -> None:
    if fmt == "e57":
        try:
            import pye57  # noqa: F401
        except ImportError as exc:
            if os.environ.get("CI") == "true":
                pytest.fail(f"pye57 missing (pip install -e '.[dev]'): {exc}")
            pytest.skip(f"pye57 missing: {exc}")


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_scan_format_round_trip(tmp_path, fmt):
    """The points written in ``fmt`` come back in order, within the format's precision."""
    _need_pye57(fmt)
    V, F = grid_mesh()
    f = tmp_path / f"scan{FORMATS[fmt][0]}"
    f.write_bytes(encode(fmt, V, F))
    P = read_scan(f).points
    want, tol = expected_points(fmt, V, F)
    assert P.dtype == np.float64 and P.shape == want.shape, (P.shape, want.shape)
    np.testing.assert_allclose(P, want, rtol=0, atol=tol)


def test_e57_scans_posed_concatenated_invalid_dropped(tmp_path):
    """Two scans, one under a pose, 7 invalid points: the file-frame points in mm."""
    _need_pye57("e57")
    import pye57

    V, F = grid_mesh()
    f = tmp_path / "scan.e57"
    f.write_bytes(seed("e57"))
    e = pye57.E57(str(f))
    try:
        assert e.scan_count == 2
        assert e.get_header(0).has_pose()
        raw0 = e.read_scan_raw(0)
    finally:
        e.close()
    local = np.column_stack([raw0["cartesianX"], raw0["cartesianY"], raw0["cartesianZ"]])
    assert np.abs(local * 1000.0 - V[: len(local)]).max() > 10.0  # the pose matters
    P = read_scan(f).points  # E57 is in metres: read back in mm
    assert len(P) == len(V) and np.abs(P).max() < 100.0  # no invalid point (1 km away)
    np.testing.assert_allclose(P, V, rtol=0, atol=1e-4)
    np.testing.assert_allclose(read_scan(f, units="mm").points, V / 1000.0, rtol=0, atol=1e-7)


def test_e57_without_pye57_is_one_clear_line(tmp_path, monkeypatch):
    f = tmp_path / "scan.e57"
    f.write_bytes(b"ASTM-E57" + bytes(1000))
    monkeypatch.setitem(sys.modules, "pye57", None)  # import pye57 -> ImportError
    with pytest.raises(InputError) as exc:
        read_scan(f)
    msg = str(exc.value)
    assert "\n" not in msg and "scan.e57" in msg and "pye57" in msg and "qifreport[e57]" in msg


def test_scan_units(tmp_path, shell_points):
    f = tmp_path / "scan.npy"
    np.save(f, shell_points)
    np.testing.assert_allclose(read_scan(f, units="in").points, 25.4 * shell_points)
    np.testing.assert_allclose(read_scan(f, units="m").points, 1000.0 * shell_points)
    np.testing.assert_array_equal(read_scan(f, units="mm").points, shell_points)
    with pytest.raises(InputError, match="unknown scan units"):
        read_scan(f, units="furlong")
    np.save(f, np.full((200, 3), 1e306))  # finite in the file, inf in mm
    with pytest.raises(InputError, match="NaN/inf"):
        read_scan(f, units="m")


@pytest.mark.parametrize(
    "array",
    [
        np.array([["1", "2", "3"]] * 200),
        np.ones((200, 3), dtype=complex),
        np.zeros(200, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")]),
    ],
    ids=["strings", "complex", "structured"],
)
def test_npy_of_non_numbers_is_refused(tmp_path, array):
    f = tmp_path / "scan.npy"
    np.save(f, array)
    with pytest.raises(InputError, match="scan.npy"):
        read_scan(f)


def test_obj_scan_keeps_points_no_face_uses(tmp_path):
    V, F = grid_mesh()
    f = tmp_path / "scan.obj"
    f.write_bytes(encode("obj", V, F[:-1]))  # the last corner is on no face
    P = read_scan(f).points
    assert len(P) == len(V)
    np.testing.assert_allclose(P, V, atol=1e-8)


# ------------------------------------------------------------------------------------------
# damaged files: refused by name, never a crash, never a silent partial read


def _refuses(reader, path: Path, word: str) -> None:
    with pytest.raises(InputError) as exc:
        reader(path)
    msg = str(exc.value)
    assert "\n" not in msg and path.name in msg and word in msg, msg


def test_mesh_face_index_out_of_range(tmp_path):
    """Used to crash the interpreter (igl with indices past the vertices); found by
    bench/fuzz_readers.py from a byte flip in a binary PLY's faces."""
    f = tmp_path / "bad.ply"
    f.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n3 0 1 -5\n"
    )
    _refuses(load_mesh, f, "outside")
    V, F = grid_mesh()
    data = bytearray(encode("ply-binary-mesh", V, F))
    data[-2] = 0x7F  # the high byte of the last face's last index
    f.write_bytes(bytes(data))
    _refuses(load_mesh, f, "outside")


@pytest.mark.parametrize("fmt", ["ply-ascii-mesh", "off"])
def test_truncated_ascii_mesh_is_refused(tmp_path, fmt):
    """trimesh reads what is there: a nominal cut short would lose triangles silently."""
    data = seed(fmt)
    f = tmp_path / f"cut{FORMATS[fmt][0]}"
    f.write_bytes(data[: int(0.95 * len(data))])
    _refuses(load_mesh, f, "truncated")
    _refuses(read_scan, f, "truncated")


def test_ply_header_count_edited_is_refused(tmp_path):
    f = tmp_path / "fewer.ply"
    f.write_bytes(seed("ply-ascii-points").replace(b"element vertex 121", b"element vertex 110"))
    _refuses(read_scan, f, "truncated or corrupt")


def test_obj_face_index_zero_is_refused(tmp_path):
    f = tmp_path / "zero.obj"
    f.write_bytes(seed("obj").replace(b"\nf 1 ", b"\nf 0 ", 1))
    _refuses(load_mesh, f, "index 0")


def test_trimesh_log_does_not_reach_the_console(tmp_path, caplog):
    """trimesh logs a WARNING with a traceback for a bad STL normal; the CLI's stderr must
    carry one line only (the file still reads: normals are not used)."""
    f = tmp_path / "badnormal.stl"
    f.write_bytes(seed("stl-ascii").replace(b"facet normal", b"facet normal x", 1))
    with caplog.at_level(logging.DEBUG):
        P = read_scan(f).points
        load_mesh(f)
    assert len(P) == len(grid_mesh()[0])  # the distinct corners (STL repeats them)
    assert not [r for r in caplog.records if r.name.startswith("trimesh")], caplog.text


def test_a_scan_in_metres_is_named_before_it_is_thinned(tmp_path):
    """The panel's scan written in metres (0.19 "mm" across): the unit check runs before
    the thinning, which would put it in one cell of the part's grid (the message was
    "scan extent 0 mm" with divide-by-zero warnings)."""
    import trimesh

    P = np.asarray(trimesh.load(SAMPLES / "panel_scan.ply").vertices) / 1000.0
    f = tmp_path / "scan.npy"
    np.save(f, P)
    out = tmp_path / "out"
    r = run(SAMPLES / "panel.step", f, "--out", out)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "use --scan-units m" in lines[0] and "0.189" in lines[0]
    assert "Warning" not in r.stderr and not (out.exists() and any(out.iterdir()))


def test_a_run_owns_the_whole_set_of_reports_under_its_name(tmp_path):
    """An earlier run's PDF beside this run's QIF would read as this run's report: without
    --force the run is refused (nothing written), with it the stale PDF is removed once
    this run's outputs are published."""
    out = tmp_path / "out"
    scan, nominal = SAMPLES / "shell_scan.ply", SAMPLES / "shell_nominal.ply"
    first = run(nominal, scan, "--tolerance", "0.5", "--out", out, "--no-qif", "--quiet")
    assert first.returncode == 0, first.stderr
    assert sorted(p.name for p in out.iterdir()) == ["shell_nominal.pdf"]
    again = ("--tolerance", "0.5", "--out", out, "--no-pdf", "--quiet")
    refused = run(nominal, scan, *again)
    assert refused.returncode == 2 and "shell_nominal.pdf" in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == ["shell_nominal.pdf"]
    forced = run(nominal, scan, *again, "--force")
    assert forced.returncode == 0, forced.stderr
    assert sorted(p.name for p in out.iterdir()) == ["shell_nominal.qif"]
