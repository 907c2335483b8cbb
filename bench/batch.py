"""Production throughput: 20 scans of the sample part, one at a time vs ``qifreport batch``.

Twenty simulated free-state scans of ``samples/panel.step`` are inspected. Each free state is
made by the part's elasticity, as the sample scans' (a truth model, not the product's, held
at the datum targets its drawing's restraint note names, A2 and A3 lifted by 0.5-1.5 mm each,
up or down: ``samples/make_samples.panel_target_warp``), so the drawing's restraint takes it
back: a scan without a defect should PASS; four carry a 0.45 mm bump on the crown (the 0.5 mm
profile band of T2) and should FAIL. Each scan has its own noise seed. They are inspected

1. by sequential single-scan commands without the cache (each one reads, tessellates and
   prepares the part: the workflow before the per-part cache),
2. by sequential single-scan commands with a warm cache (the cache alone),
3. by ``qifreport batch`` on local processes (``--jobs 2``, warm cache),
4. by ``qifreport batch --scheduler`` on a Dask ``LocalCluster`` of 2 worker processes
   (1 thread each; the cluster's start-up is reported apart),

and the preparation stages of a scan are timed cold (built) and warm (loaded). Printed:
wall time, scans per minute, speed-ups, peak resident memory per worker, and whether every
way reached the same verdicts.

Usage: ``python bench/batch.py [--scans 20] [--sequential 20] [--work DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "samples"))
PART = ROOT / "samples" / "panel.step"
EXE = Path(sys.executable).parent / "qifreport"
DEFECTS = {3: 0.0, 8: -8.0, 13: 6.0, 18: -4.0}  # scan index -> defect x shift, mm
POSED: tuple[int, ...] = ()  # the panel's 1.8 mm wall: the pose search refuses posed scans


#: the datum targets lifted in the free states, and the range of each lift, mm
LIFTED = ("A2", "A3")
LIFT_RANGE = (0.5, 1.5)


def cases(n: int) -> list[dict]:
    rng = np.random.default_rng(2026)
    out = []
    for k in range(n):
        lifts = rng.uniform(*LIFT_RANGE, len(LIFTED)) * rng.choice([-1.0, 1.0], len(LIFTED))
        c = {"lifts": dict(zip(LIFTED, lifts.tolist(), strict=True)), "scan_seed": 1000 + k}
        if k in DEFECTS:
            c.update(defect=(0.45, 6.0), defect_shift=DEFECTS[k])
        if k in POSED:
            A = rng.normal(size=(3, 3))
            Q, R = np.linalg.qr(A)
            Q = Q * np.sign(np.diag(R))
            if np.linalg.det(Q) < 0:
                Q[:, 0] *= -1
            c["pose"] = (Q, rng.uniform(-200, 200, 3))
        out.append(c)
    return out


def expected(n: int) -> dict[str, str]:
    """The verdict each scan should get: FAIL with a bump, else PASS."""
    return {f"panel_{k:02d}": "FAIL" if "defect" in c else "PASS" for k, c in enumerate(cases(n))}


def make_scans(work: Path, n: int) -> list[Path]:
    from make_samples import panel_scan_set, panel_target_warp

    d = work / "scans"
    paths = [d / f"panel_{k:02d}.ply" for k in range(n)]
    if all(p.is_file() for p in paths):
        return paths
    d.mkdir(parents=True, exist_ok=True)
    # the held free state is linear in the lifts: one field per lifted target, lifted 1 mm
    unit = {t: panel_target_warp(PART, {t: 1.0})[0] for t in LIFTED}

    def warp(lifts: dict[str, float]):
        return lambda X: sum(a * unit[t](X) for t, a in lifts.items())

    made = [dict(c, warp=warp(c.pop("lifts"))) for c in cases(n)]
    for p, P in zip(paths, panel_scan_set(PART, made, deflection=0.01), strict=True):
        trimesh.PointCloud(P).export(p)
    return paths


def run(cmd: list, env: dict | None = None) -> tuple[int, str, float]:
    t0 = time.perf_counter()
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, env=env)
    return r.returncode, r.stdout + r.stderr, time.perf_counter() - t0


def profile_row(text: str, stage: str) -> tuple[float, float]:
    """(seconds, peak MiB) of one ``--profile`` stage."""
    m = re.search(rf"^{re.escape(stage)}\s+([\d.]+)\s+([\d.]+)\s*$", text, re.M)
    return (float(m.group(1)), float(m.group(2))) if m else (float("nan"), float("nan"))


def sequential(scans: list[Path], out: Path, cache: Path | None) -> dict:
    """One ``qifreport PART SCAN`` per scan; verdicts, wall times, peak memory."""
    verdicts, walls, peaks, prep = {}, [], [], []
    flag = ["--no-cache"] if cache is None else ["--cache", cache]
    for s in scans:
        o = out / s.stem
        rc, text, wall = run([EXE, PART, s, "--out", o, "--quiet", "--profile", *flag])
        m = re.search(r"^verdict: (.+)$", text, re.M)
        verdicts[s.stem] = m.group(1) if m else f"ERROR rc {rc}"
        walls.append(wall)
        peaks.append(profile_row(text, "total")[1])
        prep.append(profile_row(text, "prepare part (cache)")[0])
    return {
        "verdicts": verdicts,
        "wall": sum(walls),
        "median": statistics.median(walls),
        "peak": max(peaks),
        "prepare": prep,
    }


def batch(scans: list[Path], out: Path, cache: Path, extra: list) -> dict:
    rc, text, wall = run(
        [EXE, "batch", PART, *scans, "--out", out, "--quiet", "--cache", cache, *extra]
    )
    recs = [json.loads(p.read_text()) for p in (out / "scans").glob("*.record.json")]
    by_worker: dict[str, float] = {}
    for r in recs:
        by_worker[r["worker"]] = max(by_worker.get(r["worker"], 0.0), r["peak_rss_mib"])
    return {
        "verdicts": {Path(r["scan"]).stem: r["row"]["verdict"] for r in recs},
        "wall": wall,
        "peak_by_worker": by_worker,
        "text": text,
        "rc": rc,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=20)
    ap.add_argument(
        "--sequential", type=int, default=None, help="scans run one at a time (default: all)"
    )
    ap.add_argument("--work", type=Path, default=None, help="keep the scans and outputs here")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="qifreport-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"work directory: {work}; {os.cpu_count()} cores")
    t0 = time.perf_counter()
    scans = make_scans(work, args.scans)
    print(f"{len(scans)} scans of {PART.name} simulated in {time.perf_counter() - t0:.0f} s")
    seq = scans[: args.sequential or len(scans)]
    cache = work / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    for d in ("seq-cold", "seq-warm", "batch-local", "batch-dask"):
        shutil.rmtree(work / d, ignore_errors=True)

    # preparation stages, cold and warm, in this process (5 loads)
    from qifreport.cache import NominalOptions, part_state
    from qifreport.metrology.inspection import InspectionParams

    t = time.perf_counter()
    part_state(PART, NominalOptions(), InspectionParams(), cache)
    build = time.perf_counter() - t
    loads = []
    for _ in range(5):
        t = time.perf_counter()
        _, outcome = part_state(PART, NominalOptions(), InspectionParams(), cache)
        loads.append(time.perf_counter() - t)
        assert outcome.status == "hit"
    load = statistics.median(loads)
    entry_mib = sum(p.stat().st_size for p in cache.glob("*.qprep")) / 2**20

    print(f"sequential, no cache ({len(seq)} scans) ...", flush=True)
    cold = sequential(seq, work / "seq-cold", None)
    print(f"sequential, warm cache ({len(seq)} scans) ...", flush=True)
    warm = sequential(seq, work / "seq-warm", cache)
    print(f"batch, local processes ({len(scans)} scans) ...", flush=True)
    local = batch(scans, work / "batch-local", cache, ["--jobs", "2"])

    print(f"batch, Dask LocalCluster ({len(scans)} scans) ...", flush=True)
    from distributed import LocalCluster

    t = time.perf_counter()
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        startup = time.perf_counter() - t
        dask = batch(scans, work / "batch-dask", cache, ["--scheduler", cluster.scheduler_address])

    def rate(n, wall):
        return 60.0 * n / wall

    n_seq, n = len(seq), len(scans)
    rows = [
        ("sequential, no cache", n_seq, cold["wall"], cold["median"], f"{cold['peak']:.0f}"),
        ("sequential, warm cache", n_seq, warm["wall"], warm["median"], f"{warm['peak']:.0f}"),
        (
            "batch, 2 local processes",
            n,
            local["wall"],
            local["wall"] / n,
            " / ".join(f"{v:.0f}" for v in sorted(local["peak_by_worker"].values())),
        ),
        (
            "batch, Dask 2 workers",
            n,
            dask["wall"],
            dask["wall"] / n,
            " / ".join(f"{v:.0f}" for v in sorted(dask["peak_by_worker"].values())),
        ),
    ]
    print()
    print(
        f"{'way':28s} {'scans':>5s} {'wall s':>8s} {'s/scan':>7s} {'scans/min':>9s} "
        f"{'x seq':>6s}  peak RSS MiB (per worker)"
    )
    base = rate(n_seq, cold["wall"])
    for name, k, wall, per, peak in rows:
        print(
            f"{name:28s} {k:5d} {wall:8.1f} {per:7.2f} {rate(k, wall):9.2f} "
            f"{rate(k, wall) / base:6.2f}  {peak}"
        )
    print()
    print(
        f"preparation stages (read STEP, tessellate, zones, operators, bands, bending "
        f"basis, pose-search model): built {build:.1f} s, loaded {load:.2f} s "
        f"(median of 5) -> {build / load:.0f}x; cache entry {entry_mib:.0f} MiB"
    )
    pc, pw = statistics.median(cold["prepare"]), statistics.median(warm["prepare"])
    print(
        f"  in the CLI ('prepare part' stage, median over scans): no cache {pc:.1f} s, "
        f"warm cache {pw:.2f} s -> {pc / pw:.0f}x"
    )
    print(
        f"  per scan, whole command: {cold['median']:.1f} s -> {warm['median']:.1f} s "
        f"({cold['median'] / warm['median']:.1f}x from the cache alone)"
    )
    print(f"Dask LocalCluster start-up (not in the wall time): {startup:.1f} s")
    ref = cold["verdicts"]
    for name, res in (("warm", warm), ("local", local), ("dask", dask)):
        same = sum(res["verdicts"].get(k) == v for k, v in ref.items())
        print(f"verdicts of '{name}' equal to the no-cache run: {same}/{len(ref)}")
    truth = expected(n)
    got = {k: v.split()[0] for k, v in local["verdicts"].items()}
    wrong = [k for k, v in got.items() if v in ("PASS", "FAIL") and v != truth[k]]
    undecided = [k for k, v in got.items() if v not in ("PASS", "FAIL")]
    print(
        f"batch verdicts against the free states made (PASS; FAIL with a bump): "
        f"{n - len(wrong) - len(undecided)}/{n} as made, {len(wrong)} wrong "
        f"({', '.join(wrong) or 'none'}), {len(undecided)} not established or measured"
    )
    counts = {}
    for v in local["verdicts"].values():
        counts[v] = counts.get(v, 0) + 1
    print("batch verdicts: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if args.work is None:
        print(f"(outputs kept in {work})")


if __name__ == "__main__":
    main()
