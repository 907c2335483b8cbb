"""The whole command on the sample panel, as a user runs it: warm and cold cache.

``qifreport samples/panel.step samples/panel_scan.ply --profile`` (QIF + PDF written and
validated) is run ``--runs`` times with an empty per-part cache (cold: the part is read,
meshed and prepared) and ``--runs`` times with that cache filled (warm). Printed: the median
wall time and CPU-seconds (user + system of the command and its children) of each, the
median of every stage of ``--profile``, the peak resident memory, the cache entry's size,
and a machine unit measured in the same run (one k-d tree query of the scan's points
against the nominal's vertices, the physical floor of the command), so a figure can be
read as a ratio on another machine.

    python bench/speed.py [--runs 3] [--scan samples/panel_scan.ply]

The targets (warm, cold, the cache entry's size) are in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("qifreport")
STAGE = re.compile(r"^(\S.*?)\s{2,}([0-9.]+)\s+([0-9]+)\s*$")


def measure(argv: list[str]) -> tuple[str, float, float]:
    """Run ``argv`` to its end: its standard output, the CPU-seconds of its process tree
    (user + system, the command and its children) and its wall seconds; exits with the
    end of its standard error unless it exits 0, 1 or 3 (a verdict)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as fo, tempfile.TemporaryFile("w+") as fe:
        proc = subprocess.Popen(argv, stdout=fo, stderr=fe, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        fo.seek(0)
        fe.seek(0)
        stdout, stderr = fo.read(), fe.read()
    code = os.waitstatus_to_exitcode(status)
    if code not in (0, 1, 3):
        raise SystemExit(f"qifreport exited {code}: {stderr.strip()[-2000:]}")
    return stdout, usage.ru_utime + usage.ru_stime, wall


def run(
    part: Path, scan: Path, out: Path, cache: Path
) -> tuple[float, dict[str, float], int, float]:
    """Wall seconds, the profile's stage seconds, its peak RSS (MiB) and the CPU-seconds of
    the process tree (:func:`measure`) of one command."""
    argv = [str(EXE), str(part), str(scan), "--out", str(out), "--force", "--quiet"]
    argv += ["--cache", str(cache), "--profile"]
    stdout, cpu, wall = measure(argv)
    stages: dict[str, float] = {}
    peak = 0
    on = False
    for line in stdout.splitlines():
        if line.startswith("stage "):
            on = True
            continue
        m = STAGE.match(line) if on else None
        if m:
            stages[m.group(1).strip()] = float(m.group(2))
            peak = max(peak, int(m.group(3)))
    return wall, stages, peak, cpu


def unit(part: Path, scan: Path) -> float:
    """Median seconds of one k-d tree query of the scan against the nominal's vertices."""
    from scipy.spatial import cKDTree

    from qifreport.nominal import load_nominal
    from qifreport.registration.pointcloud import read_scan

    nominal, _ = load_nominal(part, None)
    P = read_scan(scan).points
    tree = cKDTree(nominal.V)
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        tree.query(P, workers=-1)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--part", type=Path, default=ROOT / "samples" / "panel.step")
    ap.add_argument("--scan", type=Path, default=ROOT / "samples" / "panel_scan.ply")
    a = ap.parse_args()
    u = unit(a.part, a.scan)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cold, warm = [], []
        for k in range(a.runs):
            cache = tmp / f"cold{k}"
            cold.append(run(a.part, a.scan, tmp / "out", cache))
        cache = tmp / "cold0"
        size = sum(f.stat().st_size for f in cache.rglob("*") if f.is_file()) / 2**20
        for _ in range(a.runs):
            warm.append(run(a.part, a.scan, tmp / "out", cache))
    print(f"unit: one k-d tree query of the scan against the nominal's vertices {u * 1e3:.1f} ms")
    print(f"{'':<28} {'cold':>8} {'warm':>8}")
    print(
        f"{'wall, s (median)':<28} {statistics.median(r[0] for r in cold):>8.2f} "
        f"{statistics.median(r[0] for r in warm):>8.2f}"
    )
    print(
        f"{'CPU-s, process tree (median)':<28} {statistics.median(r[3] for r in cold):>8.2f} "
        f"{statistics.median(r[3] for r in warm):>8.2f}"
    )
    print(
        f"{'wall / unit':<28} {statistics.median(r[0] for r in cold) / u:>8.0f} "
        f"{statistics.median(r[0] for r in warm) / u:>8.0f}"
    )
    print(
        f"{'peak RSS, MiB (max)':<28} {max(r[2] for r in cold):>8d} {max(r[2] for r in warm):>8d}"
    )
    print(f"{'cache entry, MiB':<28} {size:>8.1f}")
    print("stages, s (median):")
    names = list(dict.fromkeys([n for r in cold + warm for n in r[1]]))
    for n in names:
        c = statistics.median(r[1].get(n, 0.0) for r in cold)
        w = statistics.median(r[1].get(n, 0.0) for r in warm)
        print(f"  {n:<26} {c:>8.2f} {w:>8.2f}")


if __name__ == "__main__":
    main()
