"""Speed of three input/output stages, formerly timed inside unit tests (the suite asserts
what they compute, this script how long they take; medians of ``--runs``).

* ``step parse``: :class:`qifreport.step.p21.P21Model` read + ``parse_all`` of the largest
  shared NIST file (FTC 06, 3.2 MB, 16,954 entities), and the whole semantic PMI read
  (:func:`qifreport.step.semantic.read_pmi_text`);
* ``virtual scan``: one view of the simulator's scanner on the deformed fandisk
  (:func:`qifreport.simulate.scanner.virtual_scan`, ~29k vertices);
* ``trend pdf``: the batch trend report of 2,000 scans
  (:func:`qifreport.reports.trend.write_trend_pdf`).

Each row is printed beside a unit measured in the same run: one ``numpy.linalg.svd`` of a
600 x 600 matrix, so that the ratio column is comparable across machines. The former test
bounds are printed beside them.

    python bench/io_speed.py [--runs 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


def _median_time(fn, runs: int) -> float:
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _unit(runs: int) -> float:
    A = np.random.default_rng(0).standard_normal((600, 600))
    return _median_time(lambda: np.linalg.svd(A), runs)


def _step_cases():
    from qifreport.step.p21 import P21Model
    from qifreport.step.semantic import read_pmi_text

    path = SHARED / "step" / "nist" / "nist_ftc_06_asme1_ap242-e1.stp"

    def parse():
        m = P21Model.read(path)
        m.parse_all()
        assert len(m) == 16954

    return [
        ("step parse (FTC 06)", parse, 2.0),
        ("semantic PMI read (FTC 06)", lambda: read_pmi_text(path), 3.0),
    ]


def _scan_case():
    from qifreport.simulate.deform import biharmonic_deformation
    from qifreport.simulate.scanner import ScanSpec, virtual_scan
    from qifreport.simulate.shapes import fandisk

    V, F = fandisk(str(SHARED / "meshes" / "fandisk.off"))
    D = biharmonic_deformation(V, F, 2.0, {"bend": 1.0, "twist": 0.5})
    return [
        (
            "virtual scan, one view (fandisk)",
            lambda: virtual_scan(V + D.d, F, ScanSpec(views=1, seed=1)),
            2.0,
        )
    ]


def _trend_case(tmp: Path):
    import pandas as pd

    from qifreport.reports.trend import TrendCharacteristic, write_trend_pdf

    rng = np.random.default_rng(0)
    n = 2000
    df = pd.DataFrame(
        {
            "seq": np.arange(1, n + 1),
            "id": [f"s{i}" for i in range(n)],
            "verdict": np.where(rng.random(n) < 0.95, "PASS", "FAIL"),
            "profile_T1_mm": rng.normal(0.3, 0.05, n),
            "status_T1": "PASS",
        }
    )
    chars = [TrendCharacteristic("T1", "surface profile 1 mm", 1.0)]
    created = datetime(2026, 1, 1, tzinfo=timezone.utc)
    return [
        (
            "trend pdf, 2000 scans",
            lambda: write_trend_pdf(
                tmp / "t.pdf",
                df,
                chars,
                part_name="bench",
                created=created,
                nominal_sha256="0" * 64,
            ),
            10.0,
        )
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    unit = _unit(a.runs)
    with tempfile.TemporaryDirectory() as td:
        cases = _step_cases() + _scan_case() + _trend_case(Path(td))
        print(f"unit: numpy svd 600x600, median {unit * 1e3:.1f} ms")
        print(f"{'stage':36s} {'median s':>9s} {'x unit':>8s} {'former bound s':>15s}")
        for name, fn, bound in cases:
            fn()  # warm-up: imports, caches
            t = _median_time(fn, a.runs)
            print(f"{name:36s} {t:9.3f} {t / unit:8.1f} {bound:15.1f}")


if __name__ == "__main__":
    main()
