"""Dent verdicts on the shell: is a failing dent ever PASSed, a conforming one ever FAILed?

Crosses a proud Gaussian dent's depth ``a`` (mm) with its width (``sigma``, Eq. 16
convention ``a exp(-r^2 / sigma^2)``; the ``--std`` widths are a normal distribution's
standard deviations, ``sigma = sqrt(2) std``) on :func:`thin_shell`, deformed by the analytic
generator (2 % of the diagonal) and scanned by the simulator (``--seed``). Each cell runs
the real pipeline (:func:`qifreport.metrology.inspection.inspect`, +/-0.5 mm, 25 mm^2 region
limit) and prints the dent's true out-of-band area (``pi sigma^2 ln(a / 0.5)``), the largest
region read, the read share the product states for itself and the verdict. A cell is
*wrong* when a dent beyond the limit PASSes or one within it FAILs; NOT ESTABLISHED is the
honest answer near the limit.

    python bench/dent_verdicts.py [--seed 5] [--std 2,3,4,5] [--depths 0.5,0.8,1.0,1.2] [--sunk]

``--sunk`` lays the dents into the material (the scan points then read them too: a point
proud beyond the band is judged as added material, a sunk one is not).
"""

from __future__ import annotations

import argparse
import math

import pandas as pd

from qifreport.metrology.inspection import InspectionParams, inspect
from qifreport.simulate.cases import make_case
from qifreport.simulate.shapes import thin_shell

HALF = 0.5  # mm, the band's half-width
LIMIT = 25.0  # mm^2, the region limit


def cell(V, F, a: float, sigma: float, seed: int) -> dict:
    """One dent judged: its true area, what was read and the verdict."""
    case = make_case(V, F, generator="analytic", amplitude=0.02, seed=seed, defect=(a, sigma))
    res = inspect(V, F, case.P, InspectionParams(tolerance=HALF))
    true = math.pi * sigma**2 * math.log(abs(a) / HALF) if abs(a) > HALF else 0.0
    det = res.detectable
    wrong = (res.verdict == "PASS" and true > LIMIT) or (res.verdict == "FAIL" and true <= LIMIT)
    return {
        "a_mm": a,
        "sigma_mm": round(sigma, 2),
        "true_mm2": round(true, 1),
        "read_mm2": round(res.acceptance.largest_region_area, 1),
        "read_share": None if det is None else round(det.read_share, 2),
        "verdict": res.verdict,
        "wrong": wrong,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--std", default="2,3,4,5", help="dent widths as standard deviations, mm")
    ap.add_argument("--depths", default="0.5,0.8,1.0,1.2", help="dent depths, mm")
    ap.add_argument("--sunk", action="store_true", help="dents into the material")
    args = ap.parse_args(argv)
    sign = -1.0 if args.sunk else 1.0
    V, F = thin_shell()
    rows = [
        cell(V, F, sign * float(a), math.sqrt(2.0) * float(s), args.seed)
        for s in args.std.split(",")
        for a in args.depths.split(",")
    ]
    table = pd.DataFrame(rows)
    print(table.to_string(index=False))
    wrong = int(table["wrong"].sum())
    print(f"wrong verdicts: {wrong} of {len(table)}")
    return 1 if wrong else 0


if __name__ == "__main__":
    raise SystemExit(main())
