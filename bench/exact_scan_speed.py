"""Cost of the whole command on a dense exact scan of a machined part with many
characteristics: FTC 08 at 2 points/mm^2 (383k points), the scan the suite's
``tests/test_nist_exact_scan.py`` inspects.

The scan is made as that test makes it (:func:`qifreport.simulate.brep_scan.exact_scan`,
5 um noise along the exact normal, seed 1). The command is the test's, ``qifreport
nist_ftc_08_asme1_ap242-e1.stp SCAN.npy --json --no-pdf --no-qif --rigid-only``, run once
to fill the part's cache, then ``--runs`` times warm, each in a fresh process. Printed:
the median CPU-seconds of the process tree (user + system of the command and its
children, :func:`os.wait4`) and wall seconds, every run's CPU-seconds, and the verdict.

    python bench/exact_scan_speed.py [--runs 3] [--density 2] [--exe PATH]

``--exe`` runs another installation's ``qifreport`` on the same scan (a before/after pair
in one session).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from speed import measure  # bench/: the script's own folder

ROOT = Path(__file__).resolve().parents[1]
STEP = ROOT.parent / "shared" / "step" / "nist" / "nist_ftc_08_asme1_ap242-e1.stp"
EXE = Path(sys.executable).with_name("qifreport")


def exact_points(density: float) -> np.ndarray:
    """FTC 08's exact scan at ``density`` points/mm^2, as the suite's test makes it."""
    from qifreport.simulate.brep_scan import brep_surface_mesh, exact_scan
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import shape_diagonal

    part = read_step(STEP)
    mesh = brep_surface_mesh(part.shape, part.faces, 2e-4 * shape_diagonal(part.shape))
    return exact_scan(part.shape, part.faces, density, noise=0.005, seed=1, mesh=mesh).P


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="warm runs (medians)")
    ap.add_argument("--density", type=float, default=2.0, help="points/mm^2")
    ap.add_argument("--exe", type=Path, default=EXE, help="the qifreport to run")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        scan = Path(d) / "scan.npy"
        np.save(scan, exact_points(a.density))
        argv = [str(a.exe), str(STEP), str(scan), "--out", d, "--json", "--no-pdf", "--no-qif"]
        argv += ["--force", "--rigid-only", "--quiet", "--cache", str(Path(d) / "cache")]
        measure(argv)  # the part's cache filled
        cpu, wall = [], []
        for _ in range(a.runs):
            _, c, w = measure(argv)
            cpu.append(c)
            wall.append(w)
        doc = json.loads((Path(d) / f"{STEP.stem}.json").read_text())
    print(f"{a.exe}: FTC 08 exact scan, {doc['scan_input']['points_used']:,} points, warm")
    print(f"CPU-s, process tree (median of {a.runs}): {statistics.median(cpu):.2f}")
    print(f"wall, s (median): {statistics.median(wall):.2f}")
    print(f"runs, CPU-s: {' '.join(f'{c:.2f}' for c in cpu)}; verdict {doc['verdict']}")


if __name__ == "__main__":
    main()
