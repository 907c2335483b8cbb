"""Start-up of the command line: ``qifreport --help``, ``qifreport pmi --help`` and
``qifreport pmi`` on the sample panel, against ``python -c pass`` and ``python -c "import
numpy"`` measured in the same run (wall time of the whole process, medians of ``--runs``).

The command line builds only the sub-command it runs and imports the measurement stack
(SciPy, trimesh, the registration and metrology code) only for the commands that measure:
``--help`` is a parser, ``pmi`` reads the STEP file with OCP and prints a table.

    python bench/startup.py [--runs 7]

Prints one row per command: the median, its ratio to ``python -c pass``, and the target of
``TARGETS``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = str(Path(sys.executable).parent / "qifreport")

COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
    "qifreport --help": [EXE, "--help"],
    "qifreport pmi --help": [EXE, "pmi", "--help"],
    "qifreport inspect --help": [EXE, "inspect", "--help"],
    "qifreport pmi panel.step": [EXE, "pmi", str(ROOT / "samples" / "panel.step")],
}
TARGETS = {"qifreport --help": 0.5}


def wall(cmd: list[str], runs: int) -> float:
    """Median wall time, s, of ``cmd`` run ``runs`` times (output discarded)."""
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    times = {name: wall(cmd, args.runs) for name, cmd in COMMANDS.items()}
    unit = times["python -c pass"]
    print(f"{'command':28s} {'median s':>9s} {'x pass':>8s}  target")
    ok = True
    for name, t in times.items():
        target = TARGETS.get(name)
        met = "" if target is None else f"<= {target} s: {'met' if t <= target else 'MISSED'}"
        ok &= target is None or t <= target
        print(f"{name:28s} {t:9.3f} {t / unit:8.1f}  {met}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
