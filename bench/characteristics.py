"""How much of each NIST drawing qifreport measures: per shared NIST AP242 model,
its PMI items (geometric tolerances other than surface profiles, and dimensions), how many
are measured on the perfect part (every vertex at zero deviation and a full-coverage sample
of the exact B-rep as its scan points, so what is counted is what the part's geometry and the
PMI allow, not what a scan happened to see), how many of
those PASS (a perfect part must), how many are theoretically exact and applied as given
(TED: a datum target area's sides, nothing of the part to measure), and the reasons of the
rest, grouped.

    python bench/characteristics.py [FILE ...]

Prints one row per model and the not-measured reasons with their counts.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT.parent / "shared" / "step" / "nist"


def _surface(part, step: Path):
    """The perfect part: every vertex at zero deviation, and a full-coverage sample of the
    exact B-rep (one point per (diagonal / 300)^2, as a CT scan sees a part) as its scan
    points, so a face narrower than the mesh (a thin wall's hole) is measured on them."""
    from qifreport.metrology.gdt.measured_surface import MeasuredSurface
    from qifreport.simulate.brep_scan import surface_sample
    from qifreport.step.reader import read_step

    step_part = read_step(step)
    diag = float(np.linalg.norm(np.ptp(part.V, axis=0)))
    scan = surface_sample(step_part.shape, step_part.faces, diag / 300.0)
    n, m = len(part.V), len(scan.P)
    return MeasuredSurface(
        part.V,
        part.F,
        part.face_id,
        part.brep_normals,
        np.zeros(n),
        np.full(n, 0.002),
        scan.P,
        scan.face.astype(np.int64),
        np.zeros(m),
        np.full(m, 0.002),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    a = ap.parse_args()
    from qifreport.metrology.gdt.characteristics import measure_characteristics
    from qifreport.nominal import load_nominal

    files = a.files or sorted(NIST.glob("*.stp"))
    head = (
        f"{'model':<10} {'items':>5} {'measured':>8} {'share':>6} {'PASS':>5} {'other':>5} "
        f"{'TED':>4} {'s':>5}"
    )
    print(head)
    print("-" * len(head))
    reasons: Counter = Counter()
    total = measured_total = 0
    for f in files:
        part, drawing = load_nominal(f, None, accept_tolerance_as_read=True)
        if drawing.plan is None or not drawing.plan.specs:
            print(f"{f.stem.split('_asme')[0]:<10} {0:>5}")
            continue
        t0 = time.perf_counter()
        res, _ = measure_characteristics(
            drawing.plan.specs, drawing.plan.datums, _surface(part, f), "iso14253"
        )
        dt = time.perf_counter() - t0
        # a basic dimension of supplemental geometry (a datum target area's side) is applied
        # as given, nothing measured: counted apart (TED), not as measured
        ted = [r for r in res if r.status == "BASIC" and r.value is None]
        measured = [r for r in res if r.status != "NOT_MEASURED" and r.value is not None]
        ok = [r for r in measured if r.status in ("PASS", "BASIC")]
        for r in res:
            if r.status == "NOT_MEASURED":
                reasons[re.sub(r"[0-9.]+", "#", r.reason)[:110]] += 1
        total += len(res)
        measured_total += len(measured)
        print(
            f"{f.stem.split('_asme')[0]:<10} {len(res):>5} {len(measured):>8} "
            f"{100 * len(measured) / len(res):>5.0f}% {len(ok):>5} "
            f"{len(measured) - len(ok):>5} {len(ted):>4} {dt:>5.1f}",
            flush=True,
        )
    print("-" * len(head))
    print(
        f"{'all':<10} {total:>5} {measured_total:>8} {100 * measured_total / max(total, 1):>5.0f}%"
    )
    print("\nnot measured, by reason (numbers as #):")
    for why, n in reasons.most_common():
        print(f"{n:>4}  {why}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
