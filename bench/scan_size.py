"""Cost against scan size: the whole command's CPU-seconds from 10 k to 1 M points.

Scans of ``--points`` sizes are made on the sample shell's surface as ``bench/big_scan.py``
makes them (each point in the triangle of a sample point and two of its neighbours, 0.015
mm normal noise), so every size holds the same surface at another density. Each is
inspected ``--runs`` times by ``qifreport samples/shell_nominal.ply SCAN --tolerance 0.5
--no-pdf --json --quiet`` with the part's cache filled beforehand (warm), in a fresh
process. Printed per size: the median CPU-seconds of the process tree (user + system of
the command and its children, :func:`os.wait4`), the median wall, the points the
inspection used (after thinning), the verdict; then the log-log slope of CPU-s between
neighbouring sizes and from the first to the last (1.0: cost proportional to the points),
and every **cliff**: a size that costs more than 1.1 times the next larger one.

    python bench/scan_size.py [--points 1e4 3e4 1e5 3e5 1e6] [--runs 3] [--keep DIR]

The targets (slope, no cliff) are in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path

from big_scan import NOMINAL, SCAN, dense_scan, write_ply  # bench/: the script's own folder
from speed import measure

EXE = Path(sys.executable).with_name("qifreport")


def run(scan: Path, out: Path, cache: Path) -> tuple[float, float, dict]:
    """One warm command in a fresh process: CPU-s of its process tree, wall s, JSON doc."""
    argv = [str(EXE), str(NOMINAL), str(scan), "--tolerance", "0.5", "--out", str(out)]
    argv += ["--force", "--no-pdf", "--json", "--quiet", "--cache", str(cache)]
    _, cpu, wall = measure(argv)
    return cpu, wall, json.loads((out / f"{NOMINAL.stem}.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=float, nargs="+", default=[1e4, 3e4, 1e5, 3e5, 1e6])
    ap.add_argument("--runs", type=int, default=3, help="runs per size (medians)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the scans and outputs here")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="qifreport-scansize-"))
    work.mkdir(parents=True, exist_ok=True)
    cache = work / "cache"
    run(SCAN, work / "warm", cache)  # the part's cache entry, built once: not timed below
    print(f"nominal {NOMINAL.name}, warm cache; work folder {work}")
    print(f"{'points':>10} {'CPU-s':>7} {'wall s':>7} {'used':>8} verdict")
    sizes = [int(p) for p in args.points]
    cpu: list[float] = []
    for n in sizes:
        scan = work / f"shell_{n}.ply"
        if not scan.is_file():
            write_ply(scan, dense_scan(n))
        runs = [run(scan, work / f"out_{n}", cache) for _ in range(args.runs)]
        cpu.append(statistics.median(r[0] for r in runs))
        wall = statistics.median(r[1] for r in runs)
        doc = runs[-1][2]
        used = doc.get("scan_input", {}).get("points_used", n)
        print(f"{n:>10,} {cpu[-1]:>7.2f} {wall:>7.2f} {used:>8,} {doc['verdict']}", flush=True)

    def slope(a: int, b: int) -> float:
        return math.log(cpu[b] / cpu[a]) / math.log(sizes[b] / sizes[a])

    for i in range(len(sizes) - 1):
        print(f"slope {sizes[i]:,} -> {sizes[i + 1]:,}: {slope(i, i + 1):.2f}")
    print(f"slope {sizes[0]:,} -> {sizes[-1]:,}: {slope(0, len(sizes) - 1):.2f}")
    cliffs = [sizes[i] for i in range(len(sizes) - 1) if cpu[i] > 1.1 * cpu[i + 1]]
    print("cliffs: " + (", ".join(f"{c:,}" for c in cliffs) if cliffs else "none"))


if __name__ == "__main__":
    main()
