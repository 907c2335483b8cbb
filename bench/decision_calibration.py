"""Is each deviation's expanded uncertainty right? The decision rule's U held against the truth.

For every NIST file given (default: all of ``../shared/step/nist``), a perfect scan sampled
from the exact B-rep (:func:`qifreport.simulate.brep_scan.perfect_scan`: four planned views,
``--noise`` mm range noise) is inspected in the free state (rigid only, the part frame
known). The truth of every vertex's deviation is 0, so ``dev / sqrt(var)`` should spread
like a standard normal (:mod:`qifreport.metrology.acceptance.decision`). One row per PMI zone:
scored
vertices, median U, the spread of ``dev / sqrt(var)`` (1 when U is right; above 1 when it is
low), the share of vertices beyond +/-2 (4.6 % for a normal), and the share *proven out* of
the zone (beyond its band by more than U: nonzero on a perfect face only on a limit).

    python bench/decision_calibration.py [--noise 0.01] [--points 150000] [FILE ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT.parent / "shared" / "step" / "nist"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--points", type=int, default=150_000)
    ap.add_argument("--noise", type=float, default=0.01, help="range noise sigma, mm")
    a = ap.parse_args()
    from qifreport.metrology.inspection import InspectionInputs, inspect
    from qifreport.metrology.params import InspectionParams
    from qifreport.nominal import load_nominal
    from qifreport.simulate.brep_scan import technician_scan
    from qifreport.step.reader import read_step

    head = (
        f"{'part':<12} {'zone':<8} {'band mm':<16} {'n':>6} {'U med mm':>9} {'z spread':>9} "
        f"{'|z|>2':>7} {'proven out':>10}"
    )
    print(head)
    print("-" * len(head))
    for f in a.files or sorted(NIST.glob("*.stp")):
        scan, _ = technician_scan(read_step(f), noise=a.noise, points=a.points)
        part, drawing = load_nominal(f, None)
        res = inspect(
            part.V,
            part.F,
            scan.P,
            InspectionParams(rigid_only=True, prealign="never"),
            InspectionInputs(
                face_id=part.face_id,
                brep_normals=part.brep_normals,
                zones=drawing.zones,
                not_evaluated=drawing.not_evaluated,
                solid=True,
            ),
        )
        var = res.deviation_variance
        for z in res.zones:
            d = z.deviation
            ok = np.isfinite(d) & np.isfinite(var)
            if not ok.any():
                continue
            zs = d[ok] / np.sqrt(var[ok])
            U = 2.0 * np.sqrt(var[ok])
            out = np.abs(d[ok] - z.zone.center) > z.zone.half_width + U
            band = f"[{z.zone.lower:+.3f}, {z.zone.upper:+.3f}]"
            print(
                f"{f.stem.split('_asme')[0]:<12} {z.zone.key:<8} {band:<16} {ok.sum():>6} "
                f"{np.median(U):>9.4f} {np.std(zs):>9.2f} {np.mean(np.abs(zs) > 2):>7.3f} "
                f"{np.mean(out):>10.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
