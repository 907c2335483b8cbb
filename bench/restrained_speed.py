"""Restrained against free: what holding the part at its clamps costs (the bar:
a restrained inspection of the panel with a warm cache costs no more than the free one).

The whole command as a user runs it (QIF + PDF), the sample panel's warped scan, each
fixture's per-part state built once beforehand (warm cache), then ``--repeats`` runs of
each, alternated so that both see the same machine load. Printed: the median wall time of
each and their ratio.

    python bench/restrained_speed.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).parent / "qifreport"
PART = ROOT / "samples" / "panel.step"
SCAN = ROOT / "samples" / "panel_scan_warped.ply"
RUNS = {
    "restrained": ["--clamps", "pmi", "--max-clamp-force", "20", "--material", "abs"],
    "free": ["--fixture", "free"],
}


def run(name: str, work: Path) -> tuple[float, int]:
    """One command: wall seconds and exit code."""
    args = [EXE, PART, SCAN, *RUNS[name], "--out", work / name, "--force", "--quiet"]
    args += ["--cache", work / "cache"]
    t0 = time.perf_counter()
    r = subprocess.run([str(a) for a in args], capture_output=True)
    return time.perf_counter() - t0, r.returncode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="qifreport-restrained-speed-"))
    for name in RUNS:  # build each per-part state (cold), not timed
        secs, rc = run(name, work)
        print(f"{name}: cold {secs:.1f} s (exit {rc})", file=sys.stderr)
    times: dict[str, list[float]] = {name: [] for name in RUNS}
    codes: dict[str, set[int]] = {name: set() for name in RUNS}
    for _ in range(args.repeats):
        for name in RUNS:
            secs, rc = run(name, work)
            times[name].append(secs)
            codes[name].add(rc)
    med = {name: statistics.median(t) for name, t in times.items()}
    print(f"panel, warm cache, whole command with QIF + PDF, median of {args.repeats}:")
    print("| fixture | median s | runs, s | exit |")
    print("|---|---|---|---|")
    for name in RUNS:
        runs = ", ".join(f"{t:.2f}" for t in times[name])
        print(f"| {name} | {med[name]:.2f} | {runs} | {sorted(codes[name])} |")
    print(f"restrained / free: {med['restrained'] / med['free']:.2f}")


if __name__ == "__main__":
    main()
