"""Work beside the caller in a forked child (:mod:`qifreport.forked`): the outcome is the
sequential one, bit for bit, whatever the child does.

The command's schedule gives the free-state judgement and the trim edges to the child
(:func:`qifreport.schedule.inspect_beside`, ``executor=``): on a thin shell whose free
state conforms (the free state stands: the child's judgement is the result) and on one
warped beyond its band (the fixture's judgement, with the child's free-state verdict), every
number of the result equals the sequential run's. The child's failures (an exception, a
crash, no answer in time) fall back to the caller's own computation; a cancelled child is
gone; the reports written beside the other outputs are published with them, or none is.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np
import pytest

from qifreport.atomic_io import atomic_write_many
from qifreport.forked import ForkExecutor, fork_executor
from qifreport.metrology.inspection import inspect
from qifreport.metrology.params import InspectionParams
from qifreport.profile import peak_rss_bytes
from qifreport.registration.mesh import vertex_normals
from qifreport.schedule import inspect_beside
from qifreport.simulate.shapes import thin_shell
from tests.test_determinism import flatten

PARENT = os.getpid()


def where() -> int:
    return os.getpid()


def fails_in_child(x: int) -> int:
    if os.getpid() != PARENT:
        raise RuntimeError("child")
    return 2 * x


def dies_in_child(x: int) -> int:
    if os.getpid() != PARENT:
        os._exit(7)
    return 3 * x


def hangs_in_child(x: int) -> int:
    if os.getpid() != PARENT:
        time.sleep(60)
    return 4 * x


def always_fails(x: int) -> int:
    raise ValueError(f"bad {x}")


def test_the_call_runs_in_a_child_and_its_value_comes_back():
    assert fork_executor() is not None  # Linux, 2 CPUs: the CI machine
    future = ForkExecutor().submit(where)
    assert future.result() not in (PARENT, 0)
    big = ForkExecutor().submit(np.arange, 3_000_000)  # larger than a pipe's buffer
    assert np.array_equal(big.result(), np.arange(3_000_000))


@pytest.mark.parametrize("fn, factor", [(fails_in_child, 2), (dies_in_child, 3)])
def test_a_failing_child_is_replaced_by_the_callers_own_computation(fn, factor):
    assert ForkExecutor().submit(fn, 21).result() == 21 * factor


def test_a_child_without_an_answer_in_time_is_killed_and_replaced():
    t0 = time.monotonic()
    future = ForkExecutor(timeout=0.5).submit(hangs_in_child, 5)
    assert future.result() == 20
    assert time.monotonic() - t0 < 10
    with pytest.raises(ChildProcessError):
        os.waitpid(future._pid, os.WNOHANG)  # reaped: no zombie left


def test_no_child_to_be_had_means_the_caller_computes_it():
    """Out of file descriptors (no pipe), the call is made in the caller: same value."""
    import subprocess
    import sys

    code = (
        "import os, resource\n"
        "from qifreport.forked import ForkExecutor\n"
        "ex = ForkExecutor()\n"
        "high = max(int(f) for f in os.listdir('/proc/self/fd'))\n"
        "hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]\n"
        "resource.setrlimit(resource.RLIMIT_NOFILE, (high + 1, hard))\n"
        "while True:\n"
        "    try:\n"
        "        os.open('/dev/null', os.O_RDONLY)\n"
        "    except OSError:\n"
        "        break\n"
        "f = ex.submit(os.getpid)\n"
        "print(f.result() == os.getpid(), f.cancel())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.split() == ["True", "False"], out.stderr[-2000:]


def test_an_error_of_the_call_itself_reaches_the_caller():
    with pytest.raises(ValueError, match="bad 9"):
        ForkExecutor().submit(always_fails, 9).result()


def allocates(mib: int) -> int:
    a = np.ones(mib * 2**20 // 8)
    a[::512] += 1.0  # resident
    return int(a.size)


def test_the_childrens_memory_is_reported_not_lost():
    ex = ForkExecutor()
    before = peak_rss_bytes()
    assert ex.submit(allocates, 300).result() == 300 * 2**17
    assert ex.peaks and ex.peaks[-1] >= 300 * 2**20  # the child's own high-water mark
    assert peak_rss_bytes() < before + 100 * 2**20  # it was not this process's


def test_a_cancelled_child_is_gone():
    future = ForkExecutor().submit(hangs_in_child, 1)
    t0 = time.monotonic()
    assert future.cancel()
    assert time.monotonic() - t0 < 5
    with pytest.raises(ProcessLookupError):
        os.kill(future._pid, 0)


def write_text(text: str):
    def write(p: Path) -> None:
        p.write_text(text)

    return write


def write_fails(p: Path) -> None:
    p.write_text("half")
    raise OSError("disk full")


def test_reports_written_beside_are_published_with_the_others(tmp_path):
    a, b = tmp_path / "a.qif", tmp_path / "a.pdf"
    atomic_write_many(
        [(a, write_text("qif")), (b, write_text("pdf"))], executor=ForkExecutor(), beside=[b]
    )
    assert a.read_text() == "qif" and b.read_text() == "pdf"
    c, d = tmp_path / "c.qif", tmp_path / "c.pdf"
    with pytest.raises(OSError, match="disk full"):
        atomic_write_many(
            [(c, write_text("qif")), (d, write_fails)], executor=ForkExecutor(), beside=[d]
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pdf", "a.qif"]


def shell_scan(V, F, lift: float, seed: int = 3) -> np.ndarray:
    """20,000 points on the shell, its corners lifted quadratically by ``lift`` mm (0: the
    nominal shape), 10 um noise."""
    rng = np.random.default_rng(seed)
    A = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    t = rng.choice(len(F), 20_000, p=A / A.sum())
    b = rng.dirichlet(np.ones(3), len(t))
    N = vertex_normals(V, F)
    P = np.einsum("ij,ijk->ik", b, V[F[t]])
    n = np.einsum("ij,ijk->ik", b, N[F[t]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    x, y = (P[:, :2] / np.abs(V[:, :2]).max(axis=0)).T
    return P + (lift * x * y + rng.normal(0.0, 0.01, len(P)))[:, None] * n


@pytest.mark.parametrize("always_beside", [False, True])
@pytest.mark.parametrize("lift, stands", [(0.0, True), (3.0, False)])
def test_the_inspection_beside_the_fixture_is_the_sequential_one(
    lift, stands, always_beside, caplog, monkeypatch
):
    """The inspection with children gives the sequential one's result, whether the fixture
    starts beside the free state's judgement (the lifted part, seated far outside its zone;
    every part with ``always_beside``, where the flat part's fixture is given up when its
    free state stands) or after it."""
    import qifreport.schedule as schedule

    V, F = thin_shell(spacing=3.0)
    P = shell_scan(V, F, lift)
    params = InspectionParams(tolerance=0.3, prealign="never")
    alone = inspect(V, F, P, params)
    if always_beside:
        monkeypatch.setattr(schedule, "FIXTURE_LIKELY", 0.0)
    with caplog.at_level(logging.INFO, logger="qifreport.forked"):
        beside = inspect_beside(V, F, P, params, executor=ForkExecutor())
    assert not caplog.records  # the children answered: nothing was computed again here
    # started beside it, the fixture waits for the free state's result when it needs it
    assert ("free state (waited)" in beside.timings) == (always_beside or not stands)
    assert ("free state" in alone.timings) != stands
    assert (alone.fit is None) == stands, alone.fixture_decision
    assert beside.verdict == alone.verdict
    assert beside.fixture_decision == alone.fixture_decision
    assert beside.free_state == alone.free_state
    # the part had no bending basis: built beside the free state (and stopped when it
    # stood), the same basis as the fixture builds alone
    assert (alone.basis is None) == stands and (beside.basis is None) == stands
    x, y = flatten(alone), flatten(beside)
    assert x.keys() == y.keys()
    differ = [k for k in x if not np.array_equal(x[k], y[k], equal_nan=True)]
    assert not differ, differ[:10]


def test_a_part_that_cannot_be_prepared_leaves_no_child_behind(tmp_path, monkeypatch):
    """When the part's preparation fails, the command leaves no child of its own running
    or unreaped (the traceback keeps the run's frames alive: nothing is left to the garbage
    collector) and writes nothing."""
    import qifreport.cache as cache
    from qifreport.options import InspectJob, InspectOptions
    from qifreport.pipeline import run_job

    def broken(*args, **kwargs):
        raise RuntimeError("preparation failed")

    monkeypatch.setattr(cache, "prepare_part", broken)
    samples = Path(__file__).resolve().parents[1] / "samples"
    job = InspectJob(
        nominal=samples / "shell_nominal.ply",
        scan=samples / "shell_scan_defect.ply",
        out=tmp_path,
        options=InspectOptions(tolerance=0.5, cache_dir=None),
    )
    with pytest.raises(RuntimeError, match="preparation failed") as failed:
        run_job(job, progress=False)
    assert failed.traceback  # the frames (and the pending child's handle) are still alive
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # no child of this process is left, running or not
    assert not [p for p in tmp_path.rglob("*") if p.suffix in (".qif", ".pdf")]  # nothing written


def test_the_command_with_and_without_its_children_writes_the_same(tmp_path):
    """``qifreport`` with its forked children (the default) and ``--one-process`` write the
    same summary, every number equal; both write the PDF report."""
    import json
    import subprocess
    import sys

    from tests.test_determinism import VOLATILE

    exe = Path(sys.executable).parent / "qifreport"
    samples = Path(__file__).resolve().parents[1] / "samples"
    docs = {}
    for way in ("default", "one"):
        cmd = [str(exe), samples / "shell_nominal.ply", samples / "shell_scan_defect.ply"]
        cmd += ["--tolerance", "0.5", "--out", tmp_path / way, "--json", "--quiet"]
        cmd += ["--no-cache"] + (["--one-process"] if way == "one" else [])
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 1, r.stderr[-2000:]  # the sample's dent fails
        assert (tmp_path / way / "shell_nominal.pdf").stat().st_size > 10_000
        docs[way] = json.loads((tmp_path / way / "shell_nominal.json").read_text())

    def strip(d):
        if isinstance(d, dict):
            return {
                k: strip(v) for k, v in d.items() if not any(s in k for s in VOLATILE + ("qif",))
            }
        if isinstance(d, list):
            return [strip(v) for v in d]
        return d

    assert strip(docs["default"]) == strip(docs["one"])
    assert docs["default"]["verdict"] == "FAIL"


def test_a_free_state_that_stands_does_not_wait_for_the_bending_basis(tmp_path):
    """A new part's bending basis (a fixture's costliest step) is not built for a free state
    that stands (this scan seats well inside the zone, so the fixture does not even start
    beside it): the new cache entry has none, as when the command runs on one CPU; the
    part's first fixtured scan builds it."""
    import json
    import subprocess
    import sys

    import trimesh

    from qifreport.cache import part_state
    from qifreport.options import InspectOptions

    nominal = Path(__file__).resolve().parents[1] / "samples" / "shell_nominal.ply"
    mesh = trimesh.load(nominal, process=False)
    P, _ = trimesh.sample.sample_surface_even(mesh, 20_000, seed=4)
    scan = tmp_path / "conforming.ply"
    trimesh.PointCloud(np.asarray(P) + np.random.default_rng(4).normal(0, 0.005, P.shape)).export(
        scan
    )
    cache = tmp_path / "cache"
    exe = Path(sys.executable).parent / "qifreport"
    cmd = [str(exe), nominal, scan, "--tolerance", "0.5", "--out", tmp_path / "out"]
    cmd += ["--cache", cache, "--json", "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr[-2000:]
    doc = json.loads((tmp_path / "out" / "shell_nominal.json").read_text())
    assert doc["registration"]["fixture"]["decision"] == "free state conforms"
    o = InspectOptions(tolerance=0.5, cache_dir=cache)
    state, outcome = part_state(nominal, o.nominal_options(nominal), o.inspection_params(), cache)
    assert outcome.status == "hit"
    assert state.prepared.basis is None
