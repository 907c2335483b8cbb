"""``qifreport batch``: every scan recorded, failures isolated, resume, local processes and a
real Dask cluster (scheduler and two worker processes on loopback) that loses a worker."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from qifreport.batch import plan
from qifreport.errors import InputError
from qifreport.registration.pointcloud import read_scan
from tests.consumers import poppler_tool

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
NOMINAL = SAMPLES / "shell_nominal.ply"
EXE = Path(sys.executable).parent / "qifreport"
GOOD = ["noisy_0", "noisy_1", "noisy_2", "shell_scan", "shell_scan_defect"]


def batch(*args, **kw):
    return subprocess.Popen(
        [str(EXE), "batch", NOMINAL, *map(str, args), "--tolerance", "0.5", "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def finish(proc, timeout=600):
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """Six scans of the shell: the two samples, three re-noised copies, one corrupt file."""
    d = tmp_path_factory.mktemp("scans")
    for name in ("shell_scan.ply", "shell_scan_defect.ply"):
        (d / name).write_bytes((SAMPLES / name).read_bytes())
    P = read_scan(SAMPLES / "shell_scan.ply").points
    rng = np.random.default_rng(7)
    for k in range(3):
        Q = P + rng.normal(0.0, 0.005, P.shape)
        trimesh.PointCloud(Q).export(d / f"noisy_{k}.ply")
    (d / "broken.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nend_header\n1\n2\n"
    )
    return d


def assert_close(a, b, where=""):
    """Equal structures; floats to 1e-6 relative (the batch worker runs one BLAS thread)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            assert_close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_close(x, y, f"{where}[{k}]")
    elif isinstance(a, float):
        assert b == pytest.approx(a, rel=1e-6, abs=1e-9), where
    else:
        assert a == b, where


def records(out: Path) -> dict[str, dict]:
    return {
        p.name.removesuffix(".record.json"): json.loads(p.read_text())
        for p in (out / "scans").glob("*.record.json")
    }


def check_complete(out: Path, html: bool = False) -> pd.DataFrame:
    """Every scan has its record and outputs (with ``html``, its HTML viewer too, in the
    record's outputs); the summary has a row for each, in order."""
    rec = records(out)
    assert sorted(rec) == sorted([*GOOD, "broken"])
    for name in GOOD:
        r = rec[name]
        assert r["ok"], r
        for ext in ("qif", "pdf", "json", *(("html",) if html else ())):
            assert (out / "scans" / f"{name}.{ext}").stat().st_size > 1000
        assert (f"{name}.html" in r["outputs"]) == html, r["outputs"]
    assert not rec["broken"]["ok"] and "broken.ply" in rec["broken"]["error"]
    assert "\n" not in rec["broken"]["error"]
    assert not list((out / "scans").glob("broken.*[!n]"))  # only its record
    df = pd.read_csv(out / "summary.csv", keep_default_na=False)
    pq = pd.read_parquet(out / "summary.parquet")
    assert list(df["id"]) == list(pq["id"]) == ["broken", *GOOD]  # plan order (by name)
    v = dict(zip(df["id"], df["verdict"], strict=True))
    assert v["broken"] == "ERROR"
    assert (
        v["shell_scan_defect"] == "FAIL"
        and "region" in df.set_index("id").loc["shell_scan_defect", "criterion"]
    )
    assert all(v[n] == "PASS" for n in GOOD if n != "shell_scan_defect")
    # the profile column is the per-scan QIF's value (written to 4 decimals), read back
    from qifreport.qif.reader import read_results

    for name in GOOD:
        q = read_results(out / "scans" / f"{name}.qif").characteristic("general")
        assert pq.set_index("id").loc[name, "profile_general_mm"] == pytest.approx(
            q.value, abs=5.1e-5
        )
    check_statistics(out, pq)
    return pq


def check_statistics(out: Path, pq: pd.DataFrame) -> None:
    """The QIF Statistics document is valid and its count, mean and pass/fail counts equal
    those of the per-scan QIF files (both read with plain XPath); the trend PDF is one page
    with the pass rate."""
    from lxml import etree

    from qifreport.qif.validate import validate

    stats = out / "shell_nominal_statistics.qif"
    rep = validate(stats, strict=True, checks=True)
    assert not rep.errors(), rep.errors()
    ns = {"q": "http://qifstandards.org/xsd/qif3"}
    values, status = [], []
    for name in GOOD:
        t = etree.parse(str(out / "scans" / f"{name}.qif"))
        m = t.find(".//q:SurfaceProfileCharacteristicMeasurement", ns)
        values.append(float(m.findtext("q:Value", namespaces=ns)))
        status.append(m.findtext("q:Status/q:CharacteristicStatusEnum", namespaces=ns))
    block = etree.parse(str(stats)).find(".//q:SurfaceProfileCharacteristicStats", ns)
    vs = block.find("q:ValueStats", ns)
    assert int(vs.findtext("q:EffectiveNumber/q:Value", namespaces=ns)) == len(GOOD)
    assert float(vs.findtext("q:Average/q:Value", namespaces=ns)) == pytest.approx(
        np.mean(values), abs=1e-9
    )
    attrs = {a.get("name"): a.get("value") for a in block.find("q:Attributes", ns)}
    assert int(attrs["n_pass"]) == status.count("PASS") == 4
    assert int(attrs["n_fail"]) == status.count("FAIL") == 1
    trend = out / "shell_nominal_trend.pdf"
    info = subprocess.run([poppler_tool("pdfinfo"), trend], capture_output=True, text=True).stdout
    assert re.search(r"^Pages:\s+1$", info, re.M), info
    text = subprocess.run(
        [poppler_tool("pdftotext"), trend, "-"], capture_output=True, text=True
    ).stdout
    assert "80.0 %" in text  # 4 PASS of 5 scans with a verdict (the corrupt one has none)


def test_plan_folders_globs_and_manifest(scans, tmp_path):
    items = plan(NOMINAL, [str(scans)])
    assert [i.id for i in items] == ["broken", *GOOD]
    items = plan(NOMINAL, [str(scans / "noisy_*.ply"), str(scans / "noisy_1.ply")])
    assert [i.id for i in items] == ["noisy_0", "noisy_1", "noisy_2"]  # each scan once
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "noisy_0.ply").write_bytes((scans / "noisy_0.ply").read_bytes())
    m = tmp_path / "manifest.csv"
    m.write_text(
        f"scan,serial\n{scans / 'noisy_0.ply'},SN-001\nsub/noisy_0.ply,\n"
        f"{scans / 'shell_scan.ply'},SN 002/b\n"
    )
    items = plan(NOMINAL, [str(m)])
    assert items[0].id == "SN-001" and items[0].serial == "SN-001"
    assert items[1].id == "noisy_0" and items[1].scan == tmp_path / "sub" / "noisy_0.ply"
    assert items[2].id == "SN_002_b"  # made a safe file name
    with pytest.raises(InputError, match="no file matches"):
        plan(NOMINAL, [str(tmp_path / "*.e57")])
    points = tmp_path / "points.csv"
    points.write_text("x (mm),y (mm),z (mm)\n1,2,3\n")
    assert plan(NOMINAL, [str(points)])[0].scan == points  # not a manifest: a (CSV) scan


def test_a_bad_manifest_is_refused_naming_its_line_or_column(tmp_path, caplog):
    """A manifest's problem is one line naming the line or the column, never a row read
    wrong: an unclosed quote swallowed the rest of the file into one scan name, a misspelt
    ``serail`` lost every serial number, a first line of names without ``scan`` was read as
    a point cloud."""
    m = tmp_path / "m.csv"
    cases = {
        'scan,serial\na.ply,1\n"b.ply,2\nc.ply,3\n': r"m.csv line 3: a quote is never closed",
        "scan,serial\na.ply,1\nb.ply,2,x\n": r"m.csv line 3: 1 more cell\(s\) than columns \('x'\)",
        "scan,serail\na.ply,1\n": r"column 'serail' is not one of .* \(did you mean 'serial'",
        "scan,serial\na.ply,1\n,2\n": r"m.csv line 3: empty 'scan'",
    }
    for text, match in cases.items():
        m.write_text(text)
        with pytest.raises(InputError, match=match):
            plan(NOMINAL, [str(m)])
    m.write_text("file,serial\na.ply,1\n")
    with pytest.raises(InputError, match=r"neither a point cloud .* no 'scan' column"):
        plan(NOMINAL, [str(m)])
    m.write_text("scan,operator\na.ply,Ann\n")
    assert plan(NOMINAL, [str(m)])[0].scan == tmp_path / "a.ply"
    assert "column 'operator' is not read" in caplog.text


@pytest.mark.slow
def test_a_special_file_in_a_manifest_is_an_error_row_named_by_its_kind(tmp_path):
    """``/dev/zero``, a FIFO and a directory are refused by kind (reading either never ends), as
    rows of the batch: the summary lists them, no statistics of nothing is written and the
    command ends with its account, not an internal error."""
    pipe = tmp_path / "pipe.ply"
    os.mkfifo(pipe)
    m = tmp_path / "m.csv"
    m.write_text(f"scan,serial\n/dev/zero,Z-1\n{pipe},P-1\n{tmp_path},D-1\n")
    out = tmp_path / "out"
    rc, stdout, stderr = finish(batch(m, "--out", out, "--jobs", "1"), timeout=300)
    assert rc == 1 and "internal error" not in stderr, stdout + stderr
    assert "3 scans: 0 PASS, 0 FAIL, 0 NOT ESTABLISHED, 3 ERROR" in stdout, stdout
    df = pd.read_csv(out / "summary.csv", keep_default_na=False).set_index("id")
    assert df.loc["Z-1", "error"] == "scan /dev/zero is a character device, not a regular file"
    assert df.loc["P-1", "error"] == f"scan {pipe} is a FIFO, not a regular file"
    assert df.loc["D-1", "error"] == f"scan {tmp_path} is a directory, not a regular file"
    assert not list(out.glob("*_statistics.qif")) and not list(out.glob("*_trend.pdf"))


@pytest.mark.slow
def test_local_batch_records_everything_and_resumes(scans, tmp_path):
    out = tmp_path / "out"
    rc, stdout, stderr = finish(batch(scans, "--out", out, "--jobs", "2", "--html"))
    assert rc == 1, stdout + stderr  # a FAIL and an ERROR among the scans
    assert "6 scans: 4 PASS, 1 FAIL, 0 NOT ESTABLISHED, 1 ERROR (6 inspected now" in stdout
    df = check_complete(out, html=True)
    assert df["worker"].nunique() == 2  # two processes shared the work
    # a batch output is what the single-scan command writes for that scan
    from qifreport.qif.reader import read_results

    one = tmp_path / "one"
    r = subprocess.run(
        [
            str(EXE),
            NOMINAL,
            scans / "shell_scan_defect.ply",
            "--tolerance",
            "0.5",
            "--out",
            one,
            "--json",
            "--html",
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 1, r.stderr
    # --html writes the viewer with the other outputs, as the batch does for each scan
    assert sorted(p.name for p in one.iterdir()) == [
        f"shell_nominal.{ext}" for ext in ("html", "json", "pdf", "qif")
    ]
    page = (one / "shell_nominal.html").read_text(encoding="utf-8")
    assert ">FAIL</div>" in page and 'id="viewer-data"' in page
    a = read_results(one / "shell_nominal.qif")
    b = read_results(out / "scans" / "shell_scan_defect.qif")
    assert a.status == b.status == "FAIL"
    assert [(c.spec.key, c.status) for c in a.characteristics] == [
        (c.spec.key, c.status) for c in b.characteristics
    ]
    assert [c.value for c in a.characteristics] == pytest.approx(
        [c.value for c in b.characteristics], abs=1.01e-4
    )  # 4 decimals in the QIF
    ja = json.loads((one / "shell_nominal.json").read_text())
    jb = json.loads((out / "scans" / "shell_scan_defect.json").read_text())
    for key in ("verdict", "acceptance", "vertex_deviation", "tolerances", "coverage"):
        assert_close(ja[key], jb[key], key)
    # the same command again does no work and rewrites nothing
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    rc, stdout, _ = finish(batch(scans, "--out", out, "--jobs", "2", "--html"))
    assert rc == 1 and "(0 inspected now, 6 done earlier)" in stdout, stdout
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before
    # a changed scan is redone, alone; --retry-failed retries the corrupt file
    P = read_scan(scans / "noisy_2.ply").points
    trimesh.PointCloud(P + 0.001).export(scans / "noisy_2.ply")
    rc, stdout, _ = finish(batch(scans, "--out", out, "--jobs", "1", "--retry-failed", "--html"))
    assert "(2 inspected now, 4 done earlier)" in stdout, stdout
    assert records(out)["noisy_2"]["ok"]
    # a re-run over a subset inspects nothing and summarises just that subset
    rc, stdout, _ = finish(
        batch(scans / "noisy_0.ply", scans / "shell_scan.ply", "--out", out, "--html")
    )
    assert rc == 0 and "2 scans: 2 PASS" in stdout and "(0 inspected now, 2 done" in stdout
    assert list(pd.read_csv(out / "summary.csv")["id"]) == ["noisy_0", "shell_scan"]


@pytest.mark.slow
def test_dask_batch_survives_a_killed_worker(scans, tmp_path):
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "out"
    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        proc = batch(scans, "--out", out, "--scheduler", cluster.scheduler_address)
        # wait for the first finished scan, then kill a worker that is busy with another
        deadline = time.monotonic() + 300
        victim, keys = None, []
        while victim is None and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            if (
                not any(r["ok"] for r in records(out).values())
                if (out / "scans").exists()
                else True
            ):
                continue
            busy = {w: ks for w, ks in client.processing().items() if ks}
            if busy:
                victim, keys = next(iter(busy.items()))
        assert victim is not None, "the batch finished before a worker could be killed"
        pid = client.run(os.getpid, workers=[victim])[victim]
        os.kill(pid, signal.SIGKILL)
        # the scans the victim held (task keys "qifreport-<id>-<digest>")
        lost = [str(k).removeprefix("qifreport-").rsplit("-", 1)[0] for k in keys]
        rc, stdout, stderr = finish(proc)
        assert rc == 1, stdout + stderr
        assert "6 scans: 4 PASS, 1 FAIL, 0 NOT ESTABLISHED, 1 ERROR" in stdout, stdout
        check_complete(out)
        rec = records(out)
        # the scans the killed worker held were rescheduled and finished by another worker
        assert lost and all(i in rec for i in lost), (lost, sorted(rec))
        for i in lost:
            assert rec[i]["worker"] != victim, rec[i]
        assert victim not in client.scheduler_info()["workers"]
        # a second run of the same command does no work
        before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
        rc, stdout, _ = finish(batch(scans, "--out", out, "--scheduler", cluster.scheduler_address))
        assert "(0 inspected now, 6 done earlier)" in stdout, stdout
        assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before


def _pool_workers(pid: int) -> list[int]:
    """The process-pool workers among the children of ``pid`` (not the resource tracker)."""
    kids = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/children") as fh:
            kids += [int(c) for c in fh.read().split()]
    out = []
    for k in kids:
        try:
            cmd = Path(f"/proc/{k}/cmdline").read_bytes().replace(b"\0", b" ")
        except OSError:
            continue
        if b"spawn_main" in cmd and b"resource_tracker" not in cmd:
            out.append(k)
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_local_batch_survives_a_killed_process(scans, tmp_path):
    out = tmp_path / "out"
    proc = batch(scans, "--out", out, "--jobs", "2")
    deadline = time.monotonic() + 300
    killed = None
    while killed is None and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        if not (out / "scans").exists() or not any(r["ok"] for r in records(out).values()):
            continue
        workers = _pool_workers(proc.pid)
        if workers:
            killed = workers[0]
            os.kill(killed, signal.SIGKILL)
    assert killed is not None, "the batch finished before a worker could be killed"
    rc, stdout, stderr = finish(proc)
    assert rc == 1, stdout + stderr
    assert "6 scans: 4 PASS, 1 FAIL, 0 NOT ESTABLISHED, 1 ERROR (6 inspected now" in stdout
    assert "a worker process died" in stderr  # the pool was replaced, its tasks resubmitted
    check_complete(out)


def test_batch_bad_nominal_and_no_scans(tmp_path):
    r = subprocess.run(
        [str(EXE), "batch", tmp_path / "missing.step", SAMPLES, "--out", tmp_path / "o", "--quiet"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "nominal file not found" in r.stderr
    (tmp_path / "empty").mkdir()
    r = subprocess.run(
        [
            str(EXE),
            "batch",
            NOMINAL,
            tmp_path / "empty",
            "--tolerance",
            "0.5",
            "--out",
            tmp_path / "o",
            "--quiet",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "no scan files" in r.stderr
    assert r.stderr.count("\n") == 1


@pytest.mark.slow
def test_manifest_with_a_nominal_per_row(scans, tmp_path):
    """Rows may name their own nominal: each is prepared once and summarised on its own; a
    row whose nominal is missing is recorded as an error and the others go on."""
    for name in ("left.ply", "right.ply"):
        (tmp_path / name).write_bytes(NOMINAL.read_bytes())
    m = tmp_path / "manifest.csv"
    m.write_text(
        "scan,serial,nominal\n"
        f"{scans / 'shell_scan.ply'},L-1,left.ply\n"
        f"{scans / 'noisy_0.ply'},R-1,right.ply\n"
        f"{scans / 'noisy_1.ply'},X-1,missing.ply\n"
    )
    out = tmp_path / "out"
    rc, stdout, stderr = finish(batch(m, "--out", out, "--jobs", "1"))
    assert rc == 1, stdout + stderr
    assert "3 scans: 2 PASS, 0 FAIL, 0 NOT ESTABLISHED, 1 ERROR" in stdout, stdout
    df = pd.read_csv(out / "summary.csv", keep_default_na=False).set_index("id")
    assert list(df.index) == ["L-1", "R-1", "X-1"]
    assert list(df["serial"]) == ["L-1", "R-1", "X-1"]
    assert list(df["nominal"]) == ["left.ply", "right.ply", "missing.ply"]
    assert "nominal file not found" in df.loc["X-1", "error"]
    from qifreport.qif.reader import read_results

    assert read_results(out / "scans" / "L-1.qif").serial_number == "L-1"
    for part in ("left", "right"):
        stats = out / f"{part}_statistics.qif"
        assert stats.is_file() and (out / f"{part}_trend.pdf").is_file()
        text = stats.read_text()
        assert text.count("<SurfaceProfileCharacteristicMeasurement ") == 1  # its own scan
