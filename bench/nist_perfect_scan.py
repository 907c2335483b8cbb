"""Perfect scans of the NIST AP242 parts: what the inspection says, and what it costs.

For every file in ``../shared/step/nist``: a perfect scan sampled from the exact B-rep
(:func:`qifreport.simulate.brep_scan.perfect_scan`: four planned views, 10 um noise), inspected
by the CLI cold (an empty per-part cache) and warm, then warm with ``--rigid-only`` and with
``--always-fixture``. Prints one row per part: the verdict (free state first, the default),
the ``--rigid-only`` verdict, whether the free state stood (``free``: it conformed, lay
within the uncertainty of a zone limit, or failed only narrower than the mesh) or the
fixture was applied (``fix``), the rigid fit's robust residual, the largest displacement of
a fixture forced on the part (``--always-fixture``) and its verdict, the largest |deviation|
scored,
the scored share of the part, the PMI zones that PASS / are NOT MEASURED / FAIL, wall
seconds and peak memory (cold, warm). The views are aimed at the toleranced faces first
(:func:`qifreport.simulate.brep_scan.toleranced_weight`), as in the tests.

    python bench/nist_perfect_scan.py [--points 150000] [--noise 0.01] [FILE ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT.parent / "shared" / "step" / "nist"
EXE = Path(sys.executable).with_name("qifreport")


def timed(args: list[str]) -> tuple[int, float, float]:
    """(exit code, wall seconds, peak resident MiB) of one CLI run."""
    r = subprocess.run(
        ["/usr/bin/time", "-f", "%e %M", str(EXE), *args], capture_output=True, text=True
    )
    wall, kb = r.stderr.strip().splitlines()[-1].split()
    return r.returncode, float(wall), float(kb) / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--points", type=int, default=150_000)
    ap.add_argument("--noise", type=float, default=0.01, help="range noise sigma, mm")
    a = ap.parse_args()
    from qifreport.simulate.brep_scan import technician_scan
    from qifreport.step.reader import read_step

    files = a.files or sorted(NIST.glob("*.stp"))
    head = (
        f"{'part':<12} {'pts':>7} {'verdict':<13} {'rigid-only':<13} {'how':<4} {'resid':>6} "
        f"{'forced':<13} {'moved':>6} {'|dev|':>6} {'scored':>6} {'P/NM/F':>8} {'cold s':>6} "
        f"{'MiB':>5} {'warm s':>6} {'MiB':>5}"
    )
    print(head)
    print("-" * len(head))
    for f in files:
        part = read_step(f)
        scan, _ = technician_scan(part, noise=a.noise, points=a.points)
        with tempfile.TemporaryDirectory() as tmp:
            t = Path(tmp)
            np.save(t / "scan.npy", scan.P)
            base = [str(f), str(t / "scan.npy"), "--json", "--no-pdf", "--force"]
            base += ["--cache", str(t / "cache")]
            _, cold_s, cold_m = timed(base + ["--out", str(t / "cold")])
            _, warm_s, warm_m = timed(base + ["--out", str(t / "free")])
            timed(base + ["--out", str(t / "rigid"), "--rigid-only"])
            timed(base + ["--out", str(t / "forced"), "--always-fixture"])
            doc = json.loads((t / "free" / f"{f.stem}.json").read_text())
            rig = json.loads((t / "rigid" / f"{f.stem}.json").read_text())
            forced = json.loads((t / "forced" / f"{f.stem}.json").read_text())
        reg = doc["registration"]
        how = "fix" if reg["fit"] is not None else "free"  # the free state stood, or not
        moved = forced["registration"]["fit"]["max_displacement_mm"]
        pmi = [z["verdict"] for z in doc["tolerances"] if z["source"] == "pmi"]
        counts = f"{pmi.count('PASS')}/{pmi.count('NOT MEASURED')}/{pmi.count('FAIL')}"
        cov = doc["coverage"]["measured"]["coverage"]
        print(
            f"{f.stem.split('_asme')[0]:<12} {len(scan.P):>7} {doc['verdict']:<13} "
            f"{rig['verdict']:<13} {how:<4} {reg['rigid']['residual_scale_mm']:>6.3f} "
            f"{forced['verdict']:<13} {moved:>6.3f} {doc['vertex_deviation']['max_abs']:>6.3f} "
            f"{cov:>6.2f} {counts:>8} {cold_s:>6.1f} {cold_m:>5.0f} {warm_s:>6.1f} "
            f"{warm_m:>5.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
