"""Options that would weaken a guard, text options, output paths, the output lock, stale
temporary files and signals: each refused or handled with one line and no partial output.

Inputs are generated here (the shell sample scan with its own defect, temporary files,
signals sent to a real run), not the cases of the issue that asked for them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from qifreport.atomic_io import output_lock

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"
NOMINAL, SCAN = SAMPLES / "shell_nominal.ply", SAMPLES / "shell_scan.ply"
DEFECT = SAMPLES / "shell_scan_defect.ply"


def run(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [os.fsencode(EXE), *(a if isinstance(a, bytes) else os.fsencode(str(a)) for a in args)],
        capture_output=True,
        **kw,
    )


def one_line_error(r: subprocess.CompletedProcess) -> str:
    err = r.stderr.decode("utf-8", "replace").strip()
    assert r.returncode == 2, (r.returncode, err)
    assert len(err.splitlines()) == 1 and err.startswith("qifreport: error:"), err
    return err


def files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


@pytest.mark.parametrize(
    "flag, value, named",
    [
        ("--passes", "0", "--passes"),
        ("--passes", "-3", "--passes"),
        ("--band-limit", "0", "--band-limit"),
        ("--edge-band", "-1", "--edge-band"),
        ("--boundary-band", "nan", "--boundary-band"),
        ("--max-edge", "-2", "--max-edge"),
    ],
)
def test_a_guard_cannot_be_switched_off_by_a_bad_number(tmp_path, flag, value, named):
    t0 = time.perf_counter()
    r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", tmp_path / "o", flag, value, "--quiet")
    assert named in one_line_error(r)
    assert files(tmp_path / "o") == []
    assert time.perf_counter() - t0 < 30  # refused before any inspection (no fit ran)


@pytest.mark.slow
def test_single_pass_never_claims_a_pass(tmp_path):
    """``--passes 1`` turns the two-pass guard off: a conforming part is NOT ESTABLISHED (3)
    and says why in every output, and so is the defect scan the single pass half absorbs."""
    out = tmp_path / "o"
    r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", out, "--passes", "1", "--json", "--quiet")
    text = r.stdout.decode()
    assert r.returncode == 3, text + r.stderr.decode()
    assert "NOT ESTABLISHED" in text and "--passes 1" in text
    doc = json.loads((out / "shell_nominal.json").read_text())
    assert doc["verdict"] == "NOT ESTABLISHED"
    assert any("--passes 1" in w for w in doc["warnings"])
    qif = "".join((out / "shell_nominal.qif").read_text().split())
    assert "<InspectionStatus><InspectionStatusEnum>UNKNOWN</InspectionStatusEnum>" in qif
    # the defect scan: the single pass fits most of the bump away (its region falls under
    # the limit), so it would PASS; it is not established instead
    r = run(NOMINAL, DEFECT, "--tolerance", "0.5", "--out", out, "--passes", "1", "--force")
    assert r.returncode == 3, r.stdout.decode()


@pytest.mark.parametrize(
    "flag, value",
    [
        (b"--serial", b"SN-1\x07"),
        (b"--operator", b"J\xffrg"),  # not UTF-8
        (b"--author", b"line\nbreak"),
        (b"--organization", b"x" * 201),
    ],
)
def test_text_options_are_checked_before_any_work(tmp_path, flag, value):
    t0 = time.perf_counter()
    r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", tmp_path, flag, value, "--quiet")
    assert flag.decode() in one_line_error(r)
    assert files(tmp_path) == [] and time.perf_counter() - t0 < 30


def test_an_output_path_that_another_output_uses_is_refused(tmp_path):
    r = run(
        NOMINAL,
        SCAN,
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--export-mesh",
        tmp_path / "shell_nominal.qif",
        "--quiet",
    )
    assert "same file" in one_line_error(r)
    assert files(tmp_path) == []


def test_a_second_run_into_a_locked_folder_is_refused(tmp_path):
    """While one run holds ``--out``, another one is refused, naming the folder."""
    out = tmp_path / "o"
    out.mkdir()
    with output_lock(out):
        r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", out, "--quiet")
    err = one_line_error(r)
    assert "another qifreport run" in err and str(out) in err
    assert files(out) == []


def test_runs_into_new_sibling_folders_do_not_contend(tmp_path):
    """Two runs into two folders that do not exist yet, under one parent, each get their own
    lock (not the parent's); a folder made for a run that wrote nothing is removed again."""
    with output_lock(tmp_path / "a" / "deep"), output_lock(tmp_path / "b"):
        assert (tmp_path / "a" / "deep").is_dir() and (tmp_path / "b").is_dir()
        (tmp_path / "b" / "part.qif").write_text("written")
    assert not (tmp_path / "a").exists()  # made for the run, left empty: removed
    assert (tmp_path / "b" / "part.qif").is_file()


@pytest.mark.slow
def test_stale_temporary_files_of_a_killed_run_are_removed(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    stale = [out / ".shell_nominal.qif.k1lled.tmp", out / ".shell_nominal.pdf.x9.tmp"]
    for p in stale:
        p.write_bytes(b"partial")
    foreign = out / ".notes.txt.tmp"  # not of our naming for these outputs: left alone
    foreign.write_text("mine")
    r = run(NOMINAL, SCAN, "--tolerance", "0.5", "--out", out, "--quiet")
    assert r.returncode == 0, r.stdout.decode() + r.stderr.decode()
    assert not any(p.exists() for p in stale)
    assert foreign.exists()
    assert files(out) == [".notes.txt.tmp", "shell_nominal.pdf", "shell_nominal.qif"]


def _loading_numpy(pid: int, timeout: float = 60.0) -> None:
    """Wait until process ``pid`` has mapped NumPy's core extension: the command is importing
    its libraries (its entry point installs the signal handlers before it imports any)."""
    maps = Path(f"/proc/{pid}/maps")
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            if "_multiarray_umath" in maps.read_text():
                return
        except OSError:
            pass
        time.sleep(0.002)
    pytest.fail("the command never loaded NumPy")


@pytest.mark.skipif(
    not Path("/proc/self/maps").exists() and os.environ.get("CI") != "true",
    reason="needs Linux's /proc",
)
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT])
def test_a_signal_while_the_command_loads_ends_it_the_same_way(tmp_path, sig):
    """A signal while the command imports its libraries (about a second, from NumPy on) ends
    it with the same one line and exit code as mid-run, not by the signal's default action
    (SIGHUP: killed, no message) or a traceback (SIGINT)."""
    out = tmp_path / "o"
    p = subprocess.Popen(
        [str(EXE), str(NOMINAL), str(SCAN), "--tolerance", "0.5", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    _loading_numpy(p.pid)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=120)
    err = stderr.decode().strip()
    assert p.returncode == 128 + sig, (p.returncode, err, stdout.decode())
    assert err.splitlines() == [
        f"qifreport: interrupted by {signal.Signals(sig).name}: nothing written"
    ], err
    assert not out.exists() or files(out) == []


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_signal_ends_the_run_with_one_line_and_no_files(tmp_path, sig):
    out = tmp_path / "o"
    p = subprocess.Popen(
        [
            str(EXE),
            str(NOMINAL),
            str(SCAN),
            "--tolerance",
            "0.5",
            "--out",
            str(out),
            "--quiet",
            "--no-cache",
            "--json",
            # resampled runs: the run lasts well beyond the signal on any machine
            "--seeds",
            "3",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    timer = threading.Timer(3.0, lambda: p.send_signal(sig))
    timer.start()
    try:
        stdout, stderr = p.communicate(timeout=300)
    finally:
        timer.cancel()
    err = stderr.decode().strip()
    assert p.returncode == 128 + sig, (p.returncode, err, stdout.decode())
    assert err.splitlines() == [
        f"qifreport: interrupted by {signal.Signals(sig).name}: nothing written"
    ], err
    assert files(out) == []


def test_a_signal_an_import_turned_into_another_error_is_still_the_signal(monkeypatch):
    """NumPy's import reports a Ctrl-C in its C set-up as an ImportError: the entry point
    still ends the run as interrupted, from the signal it received."""
    from qifreport.errors import Interrupted, pending_interrupt

    monkeypatch.setattr(Interrupted, "received", [])
    assert pending_interrupt(ImportError("numpy: could not import module datetime")) is None
    Interrupted.received.append(int(signal.SIGINT))
    got = pending_interrupt(ImportError("numpy: could not import module datetime"))
    assert got is not None and got.signum == signal.SIGINT and got.name == "SIGINT"


def test_a_signal_numpy_turned_into_an_import_error_while_the_parser_loads_is_the_signal():
    """NumPy's import reports a Ctrl-C during its C set-up as an ``ImportError`` (``could
    not import module "datetime"``); the parser's options import NumPy: a signal there ends
    the command as interrupted (one line, exit 130), not with a traceback."""
    code = """
import sys
from qifreport import cli
from qifreport.errors import Interrupted

def build_parser(command):
    try:
        raise Interrupted(2)  # the handler, inside NumPy's C import
    except Interrupted:
        raise ImportError('PyCapsule_Import could not import module "datetime"') from None

cli.build_parser = build_parser
cli.main(["inspect", "a.step", "b.ply"])
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 130, (r.returncode, r.stderr)
    assert r.stderr.splitlines() == ["qifreport: interrupted by SIGINT: nothing written"], r.stderr


@pytest.mark.parametrize("after", [False, True])
def test_a_signal_a_library_turned_into_its_error_ends_the_run_as_the_signal(after):
    """lxml's schema parser reports a Ctrl-C as an ``XMLSchemaParseError``: the command
    still ends as interrupted (one line, exit 130), never as an internal error (exit 2). A
    signal after the outputs were published ends with exit 130 too, saying they stand."""
    code = f"""
import sys
from qifreport import cli
from qifreport.errors import Interrupted

def run():
    Interrupted.received.append(2)
    if {after}:
        return 0
    raise RuntimeError("Failed to parse the XML resource")

rc = cli._guard(run, verbose=False)
if Interrupted.received:
    Interrupted(Interrupted.received[0]).leave(written=True)
sys.exit(rc)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    done = "after the outputs were written" if after else "nothing written"
    assert r.returncode == 130, (r.returncode, r.stderr)
    assert r.stderr.splitlines() == [f"qifreport: interrupted by SIGINT: {done}"], r.stderr
