"""Accuracy benchmark: rigid baseline vs GB-CICP on generated parts with exact ground truth.

Prints, for the thin shell and the fandisk (paper Section 7.1 protocol), the inspection
deviation ``|(V_hat - V_true) . n|`` on the measured vertices (RMS / max / P95, mm) and the
wall time, beside the paper's figures. Median over ``--seeds`` seeds.

    python bench/accuracy.py [--seeds 3] [--fandisk PATH]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from qifreport.registration.deformable.gbcicp import GBCICPParams, gbcicp
from qifreport.registration.icp import rigid_icp
from qifreport.registration.mesh import bending_operator
from qifreport.simulate.cases import inspection_error, make_case
from qifreport.simulate.scanner import ScanSpec
from qifreport.simulate.shapes import fandisk, thin_shell

ROOT = Path(__file__).resolve().parents[1]
PAPER = {  # paper Table 5 / Section 7.1, fandisk: RMS, max, P95 (mm), seconds
    ("fandisk", "rigid"): (1.41, np.nan, np.nan, np.nan),
    ("fandisk", "GB-CICP"): (0.12, 1.40, 0.05, 2.5),
}


def run(part: str, V, F, seed: int, **case_kw) -> list[dict]:
    case = make_case(V, F, seed=seed, **case_kw)
    t0 = time.perf_counter()
    ops = bending_operator(V, F, "hessian")
    rigid = rigid_icp(V, ops.normals, case.P)
    t_rigid = time.perf_counter() - t0
    Pm = rigid.apply(case.P)
    V_true = case.V_true @ rigid.R.T + rigid.t
    S = case.measured_vertices()
    t1 = time.perf_counter()
    fit = gbcicp(V, F, ops, Pm, GBCICPParams())
    t_fit = time.perf_counter() - t1
    rows = []
    for method, Vh, secs in (("rigid", V, t_rigid), ("GB-CICP", fit.V, t_rigid + t_fit)):
        e = inspection_error(Vh, V_true, F)[S]
        rows.append(
            dict(
                part=part,
                method=method,
                seed=seed,
                rms=np.sqrt(np.mean(e**2)),
                max=e.max(),
                p95=np.percentile(e, 95),
                seconds=secs,
                points=len(case.P),
                vertices=len(V),
                iterations=fit.iterations,
            )
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--fandisk", type=Path, default=ROOT.parent / "shared/meshes/fandisk.off")
    args = ap.parse_args()
    rows: list[dict] = []
    Vs, Fs = thin_shell()
    Vf, Ff = fandisk(str(args.fandisk), diagonal=100.0, subdivide=1)
    for seed in range(args.seeds):
        # shell: analytic free state (no shared prior), 2 % of the diagonal, 3 views
        rows += run("shell", Vs, Fs, seed, generator="analytic", amplitude=0.02)
        # fandisk: 100 mm diagonal, subdivided once, 2 views, bend + mild twist at a = 2 mm
        rows += run(
            "fandisk",
            Vf,
            Ff,
            seed,
            generator="biharmonic",
            amplitude=0.02,
            modes={"bend": 1.0, "twist": 0.5},
            spec=ScanSpec(views=2, noise=0.02, dropout_radius=3.0, seed=seed),
        )
    df = pd.DataFrame(rows)
    med = df.groupby(["part", "method"], sort=False)[
        ["rms", "max", "p95", "seconds", "points", "vertices", "iterations"]
    ].median()
    for key, (rms, mx, p95, secs) in PAPER.items():
        if key in med.index:
            med.loc[key, ["paper_rms", "paper_max", "paper_p95", "paper_s"]] = [rms, mx, p95, secs]
    pd.set_option("display.width", 200)
    print(f"median over {args.seeds} seeds; inspection deviation on measured vertices, mm")
    print(med.round(4).to_string())


if __name__ == "__main__":
    main()
