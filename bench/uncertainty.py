"""Uncertainty budget of the deviation field on the thin shell (paper Section 9, Table 6).

Runs the validation ladder of :mod:`qifreport.simulate.ladder` through the real
inspection chain (``metrology.inspection.inspect``) and prints one Table-6-like table --
sensor noise propagated, case A chain floor, case B unremoved compliance, registration
repeatability, and their combination in quadrature -- beside the paper's values, followed
by the per-seed detail of the repeatability runs.

    python bench/uncertainty.py [--seeds 5] [--quick] [--noise 0.03]

``--quick``: the shell at a 3 mm pitch (2204 vertices) and at most 3 seeds.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from qifreport.registration.pose.curvature import scan_curvatures
from qifreport.simulate import ladder as L


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="repeatability seeds (default 5)")
    ap.add_argument("--quick", action="store_true", help="coarse shell, at most 3 seeds")
    ap.add_argument(
        "--noise",
        type=float,
        default=L.DEFAULT_NOISE,
        help=f"scanner range noise, mm (default {L.DEFAULT_NOISE}, paper Table 3)",
    )
    ap.add_argument(
        "--amplitude",
        type=float,
        default=L.DEFAULT_AMPLITUDE,
        help="case B free-state amplitude, fraction of the diagonal (default 0.02)",
    )
    ap.add_argument("--fraction", type=float, default=0.8, help="subset fraction (default 0.8)")
    args = ap.parse_args()
    seeds = list(range(min(args.seeds, 3) if args.quick else args.seeds))
    if len(seeds) < 2:
        ap.error("--seeds must be at least 2")
    t_start = time.perf_counter()
    V, F = L.ladder_shell(args.quick)
    print(
        f"thin shell: {len(V)} vertices, {len(F)} triangles; noise {args.noise} mm; "
        f"case B amplitude {100 * args.amplitude:g} % of the diagonal; seeds {seeds}"
    )

    # case A: end to end (posed, PLY in metres, pose search) and handed over in frame
    a_posed, res_a, case_a = L.chain_floor(V, F, seed=0, noise=args.noise, posed=True)
    a_frame, _, _ = L.chain_floor(V, F, seed=0, noise=args.noise, posed=False)

    # sensor noise: estimated from case A's scan, propagated over the deviation radius
    est = L.local_plane_noise(res_a.P)
    quadric = scan_curvatures(res_a.P).noise  # registration.curvature's quadric-fit estimate
    normal_true = L.true_normal_noise(case_a, args.noise)
    scored = np.flatnonzero(np.isfinite(res_a.deviation))
    prop = L.propagate_noise(est.sigma, res_a.V_registered, F, res_a.P, vertices=scored)
    direct = L.direct_noise_floor(V, F, 0, args.noise, scored)

    # case B: unremoved compliance
    b, res_b, case_b = L.unremoved_compliance(
        V, F, seed=0, noise=args.noise, amplitude=args.amplitude
    )

    # repeatability: scanner seed (same free state), and random subsets of one scan
    rows = L.repeat_scanner_seeds(
        V, F, seeds, noise=args.noise, amplitude=args.amplitude, done={0: res_b}
    )
    rows += L.repeat_subsets(V, F, case_b.P, seeds, fraction=args.fraction)
    per_seed = pd.DataFrame(rows)
    spreads = {}
    for variant, g in per_seed.groupby("variant", sort=False):
        spreads[variant] = {"rms": L.spread(g["rms"]), "max": L.spread(g["max"])}
    worst = max(spreads, key=lambda v: spreads[v]["rms"]["half_range"])
    rep_rms = spreads[worst]["rms"]["half_range"]
    rep_max = max(s["max"]["half_range"] for s in spreads.values())

    budget = L.Budget(
        noise_estimate=est.sigma,
        noise_setting=args.noise,
        noise_normal_true=normal_true,
        noise_propagated=prop["propagated"],
        mean_count=prop["mean_count"],
        floor_rms=a_posed["rms"],
        floor_max=a_posed["max"],
        compliance_rms=b["rms_after"],
        compliance_before=b["rms_before"],
        repeat_rms=rep_rms,
        repeat_max=rep_max,
        repeat_how=(
            f"half-range over {len(seeds)} seeds, larger variant ({worst}); "
            f"max: larger half-range of the max"
        ),
    )
    pd.set_option("display.width", 250)
    pd.set_option("display.max_colwidth", 120)
    table = pd.DataFrame(budget.rows()).set_index("contribution")
    print("\nUncertainty budget of the reported deviation (thin shell), mm")
    print(table.round(4).to_string())

    # the same combination with other readings of the repeatability term
    alt = {}
    for variant, s in spreads.items():
        for stat in ("half_range", "std"):
            alt[f"{variant}, {stat}"] = s["rms"][stat]
        alt[f"{variant}, full range"] = 2 * s["rms"]["half_range"]
    other = [budget.noise_propagated, budget.floor_rms, budget.compliance_rms]
    print(
        "\nCombined with other readings of the repeatability term (paper: Table 6 uses the "
        f"full range 0.043 -> {L.PAPER_TABLE6['combined'][0]}; the text the half-range "
        f"{L.PAPER_TEXT['repeatability_half_range']} -> {L.PAPER_TEXT['combined']})"
    )
    for k, v in alt.items():
        print(f"  {k:32s} {v:.4f}  ->  combined {L.combine_quadrature(other + [v]):.4f}")

    print("\nSensor noise")
    print(
        f"  plane-fit estimate {est.sigma:.4f} mm (radius {est.radius:.2f} mm = "
        f"{L.NOISE_RADIUS_SPACINGS:g} x spacing {est.spacing:.3f} mm, {est.neighbourhoods} "
        f"fits); quadric-fit estimate (registration.curvature) {quadric:.4f} mm"
    )
    print(
        f"  truth: setting {args.noise:.4f} mm along the view, {normal_true:.4f} mm along "
        f"the surface normal"
    )
    print(
        f"  neighbours within the deviation radius {prop['radius']:.2f} mm: mean "
        f"{prop['mean_count']:.1f} (P10-P90 {prop['count_p10']:.0f}-{prop['count_p90']:.0f})"
        f"; propagated {prop['propagated']:.4f} mm; measured directly (noisy minus "
        f"noise-free scan, same samples) {direct:.4f} mm"
    )

    print("\nCase A (rigid, defect-free)")
    print(pd.DataFrame([a_posed, a_frame]).round(4).to_string(index=False))
    print("\nCase B (compliant, defect-free)")
    print(pd.DataFrame([b]).round(4).to_string(index=False))

    print("\nRepeatability, per seed (case B; free state, pose and parameters fixed)")
    print(per_seed.round(4).to_string(index=False))
    sp = pd.DataFrame({(v, stat): s[stat] for v, s in spreads.items() for stat in ("rms", "max")})
    print("\nRepeatability spread, mm")
    print(sp.round(4).to_string())
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
