"""The qifreport console script on the bundled samples and on bad inputs."""

import fcntl
import json
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tests.conftest import assert_valid_summary

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"


def run(*args, cwd=None):
    return subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
def test_demo_sample_passes_with_outputs(tmp_path):
    mesh_out = tmp_path / "reg.ply"
    r = run(
        SAMPLES / "shell_nominal.ply",
        SAMPLES / "shell_scan.ply",
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--json",
        "--export-mesh",
        mesh_out,
        "--quiet",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "verdict: PASS" in r.stdout
    doc = json.loads((tmp_path / "shell_nominal.json").read_text())
    assert_valid_summary(doc)
    assert doc["verdict"] == "PASS"
    vd = doc["vertex_deviation"]
    assert vd["rms"] < 0.05 and vd["p999"] < 0.2  # compliance (~4 mm) removed
    assert doc["acceptance"]["area_ok"] and doc["acceptance"]["region_ok"]
    assert 0.5 < doc["coverage"]["coverage"] <= 1.0
    assert len(doc["inputs"]["scan"]["sha256"]) == 64
    m = trimesh.load(mesh_out, process=False)
    dev = np.asarray(m.metadata["_ply_raw"]["vertex"]["data"]["deviation"])
    assert len(dev) == len(m.vertices) == 8436
    assert np.isnan(dev).sum() > 0  # unscored vertices are NaN, not 0
    assert np.nanmax(np.abs(dev)) < 0.5


@pytest.mark.slow
def test_defect_sample_fails_by_region(tmp_path):
    r = run(
        SAMPLES / "shell_nominal.ply",
        SAMPLES / "shell_scan_defect.ply",
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--json",
    )  # with the progress bar
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Error" not in r.stderr and "Traceback" not in r.stderr
    doc = json.loads((tmp_path / "shell_nominal.json").read_text())
    assert_valid_summary(doc)
    assert doc["verdict"] == "FAIL"
    acc = doc["acceptance"]
    assert acc["area_ok"] and not acc["region_ok"]
    assert acc["regions"][0]["area"] > 25.0
    assert 0.6 < acc["regions"][0]["peak"] < 1.1


def write_points(path, P):
    trimesh.PointCloud(P).export(path)


@pytest.fixture(scope="module")
def scan_points():
    return np.asarray(trimesh.load(SAMPLES / "shell_scan.ply", process=False).vertices)


def bad_inputs(tmp: Path, P: np.ndarray):
    nominal = SAMPLES / "shell_nominal.ply"
    corrupt = tmp / "corrupt.ply"
    corrupt.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 500\n"
        b"property float x\nend_header\n\x01\x02"
    )
    empty = tmp / "empty.xyz"
    empty.write_text("")
    nan = tmp / "nan.npy"
    Pn = P.copy()
    Pn[::100] = np.nan
    np.save(nan, Pn)
    inch = tmp / "inch.ply"
    write_points(inch, P * 25.4)
    far = tmp / "far.ply"
    write_points(far, P + [500.0, 0.0, 0.0])
    # a scan of another object: a hemisphere of the shell's extent, somewhere else
    rng = np.random.default_rng(0)
    d = rng.normal(size=(8000, 3))
    d[:, 2] = np.abs(d[:, 2])
    other = tmp / "other.ply"
    write_points(
        other,
        70.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
        + [400.0, -300.0, 250.0]
        + 0.02 * rng.standard_normal(d.shape),
    )
    return {
        "missing nominal": ([tmp / "nope.stl", SAMPLES / "shell_scan.ply"], "not found"),
        "missing scan": ([nominal, tmp / "nope.ply"], "not found"),
        "corrupt scan": ([nominal, corrupt], "cannot read scan"),
        "corrupt nominal": ([corrupt, SAMPLES / "shell_scan.ply"], "nominal"),
        "empty scan": ([nominal, empty], "empty"),
        "NaN scan": ([nominal, nan], "NaN"),
        "inch scan": ([nominal, inch], "units"),
        # the user vouches that scan and part share a frame: no pose search, no overlap
        "no overlap": ([nominal, far, "--prealign", "never"], "does not overlap"),
        # the pose search finds no placement of another object on the part
        "another part": ([nominal, other], "does not overlap"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "missing nominal",
        "missing scan",
        "corrupt scan",
        "corrupt nominal",
        "empty scan",
        "NaN scan",
        "inch scan",
        "no overlap",
        "another part",
    ],
)
def test_bad_input_one_line_exit_2_no_output(tmp_path, scan_points, case):
    args, expect = bad_inputs(tmp_path, scan_points)[case]
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
    assert r.returncode == 2, (case, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qifreport: error:"), r.stderr
    assert expect in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())  # no partial output
    assert r.stdout == ""


def test_bad_tolerance_is_an_error():
    r = run(SAMPLES / "shell_nominal.ply", SAMPLES / "shell_scan.ply", "--tolerance", "-1")
    assert r.returncode == 2 and "tolerance" in r.stderr


# ------------------------------------------------------------- the progress bar on a terminal


def run_in_terminal(*args, columns: int = 100, timeout: float = 180.0) -> tuple[int, bytes]:
    """Run the console script with stdin, stdout and stderr on one pseudo-terminal
    ``columns`` wide (as in an interactive shell: the progress bar is live), and return its
    exit code and every byte it wrote to the terminal."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    proc = subprocess.Popen(
        [str(EXE), *map(str, args)], stdin=slave, stdout=slave, stderr=slave, close_fds=True
    )
    os.close(slave)
    chunks = []
    deadline = time.monotonic() + timeout
    try:
        while True:
            ready, _, _ = select.select([master], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise TimeoutError(f"no end after {timeout} s: {b''.join(chunks)[-500:]!r}")
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the program has closed the terminal (it exited)
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
        code = proc.wait()
    return code, b"".join(chunks)


def terminal_lines(stream: str) -> list[tuple[str, str]]:
    """The lines of a terminal's byte stream: ``(shown, written)`` per line, where ``shown``
    is what the terminal displays (a carriage return goes back to column 0 and what follows
    overwrites the line's characters; trailing blanks dropped) and ``written`` is all the
    text sent to that line, overwritten or not, carriage returns removed."""
    out = []
    for raw in stream.split("\n"):
        cells: list[str] = []
        col = 0
        for ch in raw:
            if ch == "\r":
                col = 0
                continue
            if col < len(cells):
                cells[col] = ch
            else:
                cells.append(ch)
            col += 1
        out.append(("".join(cells).rstrip(), raw.replace("\r", "").rstrip()))
    return out


def test_progress_bar_never_shares_the_summary_line(tmp_path):
    """On a terminal (stdout and stderr one pseudo-terminal, the bar live) the summary's
    first line is a line of its own: no progress bar text was written on it, even text a
    carriage return overwrote (a terminal's scrollback, ``script`` logs and ``2>&1 | tee``
    show that text), and the bar's own line is ended before the summary is printed."""
    code, raw = run_in_terminal(
        SAMPLES / "shell_nominal.ply",
        SAMPLES / "shell_scan.ply",
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--no-pdf",
        "--no-qif",
        "--no-cache",
    )
    stream = raw.decode("utf-8", errors="replace")
    assert code == 0, stream
    lines = terminal_lines(stream)
    assert re.search(r"virtual fixturing: [1-9]\d*it \[", stream), stream  # the bar was live
    verdict = [(shown, written) for shown, written in lines if "verdict:" in written]
    assert len(verdict) == 1, stream
    shown, written = verdict[0]
    assert shown == "verdict: PASS", repr(shown)
    assert written == "verdict: PASS", repr(written)
    # every line of the summary is whole; the bar wrote on no line but its own
    for shown, written in lines:
        if "virtual fixturing" not in written:
            assert shown == written, (shown, written)


def test_json_dash_prints_the_summary_and_a_reader_that_leaves_is_no_error(tmp_path):
    """``--json -`` prints the summary document on stdout (every command that has
    ``--json``); a reader that closes the pipe early ends the command quietly."""
    args = [SAMPLES / "shell_nominal.ply", SAMPLES / "shell_scan.ply", "--tolerance", "0.5"]
    r = run(*args, "--out", tmp_path / "a", "--json", "-", "--no-pdf", "--quiet")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert_valid_summary(doc)
    assert doc["verdict"] == "PASS" and doc["qif"]["path"].endswith("shell_nominal.qif")
    assert not (tmp_path / "a" / "shell_nominal.json").exists()  # printed, not written
    # a reader that leaves before the summary is printed (`true` reads nothing): the
    # summary's write meets a closed pipe
    cmd = " ".join(f"'{a}'" for a in [EXE, *args, "--out", tmp_path / "b", "--json", "-"])
    p = subprocess.run(
        f"{cmd} --no-pdf --no-qif --quiet | true; exit ${{PIPESTATUS[0]}}",
        shell=True,
        executable="/bin/bash",
        capture_output=True,
        text=True,
    )
    assert p.stderr == "" and p.returncode == 0
    # pmi: --json and --json - print, --json FILE writes
    step = SAMPLES / "panel.step"
    printed = json.loads(run("pmi", step, "--json", "-").stdout)
    w = run("pmi", step, "--json", tmp_path / "pmi.json")
    assert w.returncode == 0 and json.loads((tmp_path / "pmi.json").read_text()) == printed
    assert len(printed["items"]) == 7


@pytest.mark.parametrize(
    "argv, heavy",
    [
        (["--help"], ("numpy", "scipy", "trimesh", "qifreport.metrology", "OCP")),
        (["pmi", "--help"], ("numpy", "scipy", "trimesh", "qifreport.metrology", "OCP")),
        (["pmi", str(SAMPLES / "panel.step")], ("scipy", "trimesh", "qifreport.metrology")),
    ],
)
def test_help_and_pmi_do_not_load_the_measurement_stack(argv, heavy):
    """``qifreport --help`` is a parser and ``pmi`` a STEP reader: neither imports SciPy,
    trimesh or the measurement code (bench/startup.py times them)."""
    code = (
        "import sys\n"
        "from qifreport.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "print('MODULES', ' '.join(sorted(sys.modules)), file=sys.stderr)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    line = next(x for x in r.stderr.splitlines() if x.startswith("MODULES "))
    loaded = set(line.split()[1:])
    assert "argparse" in loaded and "qifreport.cli" in loaded
    found = sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in heavy))
    assert not found, found[:10]
