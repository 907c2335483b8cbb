"""Density invariance: does the verdict depend on how many points the scan has?

Each sample scan (the demo panel's and the thin shell's, and their defect scans) is
inspected in full and after a seeded random subsample to 50 % and 33 % of its points
(each point kept or not, without replacement, seed 0), through the command line exactly as
a user runs it (``--no-cache --json --no-pdf --no-qif``). The virtual fixture is applied
whatever the free state gives (``--always-fixture``) so that it is what is compared; the
``*_held`` cases judge the panel as its drawing says (held at the datum targets its
restraint note names).

Printed per case and level: the points inspected, the verdict, the area-weighted vertex
deviation RMS and P99.9 (mm), the largest out-of-tolerance region and the total area of the
out-of-tolerance regions (mm^2). A density-invariant product gives the same verdict on
every row of a case; the defect scans must FAIL on every row.

    python bench/density.py [--levels 1,0.5,0.33] [--seed 0] [--cases panel,shell,...]
                            [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from big_scan import write_ply  # bench/: the script's own folder

from qifreport.registration.pointcloud import read_scan

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"

#: case name -> (nominal, scan, extra command-line arguments)
VIRTUAL = ("--always-fixture",)
CASES: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "panel": ("panel.step", "panel_scan.ply", VIRTUAL),
    "panel_defect": ("panel.step", "panel_scan_defect.ply", VIRTUAL),
    "panel_held": ("panel.step", "panel_scan.ply", ()),
    "panel_held_defect": ("panel.step", "panel_scan_defect.ply", ()),
    "shell": ("shell_nominal.ply", "shell_scan.ply", ("--tolerance", "0.5", *VIRTUAL)),
    "shell_defect": (
        "shell_nominal.ply",
        "shell_scan_defect.ply",
        ("--tolerance", "0.5", *VIRTUAL),
    ),
}


def subsample(points: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """A seeded random subset of ``round(fraction * m)`` of the (m, 3) points, file order."""
    if fraction >= 1.0:
        return points
    rng = np.random.default_rng(seed)
    keep = np.sort(rng.choice(len(points), round(fraction * len(points)), replace=False))
    return points[keep]


def run_case(name: str, fraction: float, seed: int, work: Path) -> dict:
    """Inspect one case at one density level; the row of the table as a dict."""
    nominal, scan, extra = CASES[name]
    points = read_scan(SAMPLES / scan).points
    sub = work / f"{name}_{round(100 * fraction)}.ply"
    write_ply(sub, subsample(points, fraction, seed))
    out = work / f"{name}_{round(100 * fraction)}"
    cmd = [
        sys.executable, "-m", "qifreport", str(SAMPLES / nominal), str(sub), *extra,
        "--no-cache", "--json", "--no-pdf", "--no-qif", "--quiet",
        "--force", "--out", str(out),
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    js = out / (Path(nominal).stem + ".json")
    if not js.is_file():
        return {"case": name, "pct": 100 * fraction, "points": len(points), "verdict": "ERROR",
                "detail": proc.stderr.strip().splitlines()[-1:]}  # fmt: skip
    d = json.loads(js.read_text())
    regions = d["acceptance"].get("regions") or []
    items = [*d.get("tolerances", []), *d.get("characteristics", [])]
    status = {t["key"]: t.get("verdict") or t.get("status") for t in items}
    failed = [k for k, v in status.items() if v == "FAIL"]
    unmeasured = [k for k, v in status.items() if v == "NOT MEASURED"]
    return {
        "case": name,
        "pct": 100 * fraction,
        "points": d["scan_input"]["points_used"],
        "verdict": d["verdict"],
        "rms": d["vertex_deviation"]["rms"],
        "p999": d["vertex_deviation"]["p999"],
        "largest": d["acceptance"]["largest_region_area"],
        "regions": sum(r.get("area", 0.0) for r in regions),
        "n_regions": len(regions),
        "failed": failed,
        "not_measured": unmeasured,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", default="1,0.5,0.33", help="fractions of the scan kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--keep", type=Path, help="keep the subsampled scans and JSONs here")
    a = ap.parse_args()
    levels = [float(x) for x in a.levels.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        work = a.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print("| case | scan % | points | verdict | vertex RMS mm | P99.9 mm "
              "| largest region mm^2 | regions mm^2 (n) |")  # fmt: skip
        print("|---|---:|---:|---|---:|---:|---:|---:|")
        for name in a.cases.split(","):
            for f in levels:
                r = run_case(name, f, a.seed, work)
                if r["verdict"] == "ERROR":
                    print(f"| {name} | {r['pct']:.0f} | {r['points']} | ERROR {r['detail']} |")
                    continue
                nm = "".join(
                    f" ({label}: {', '.join(r[k])})"
                    for k, label in (("failed", "fail"), ("not_measured", "not measured"))
                    if r[k]
                )
                print(
                    f"| {name} | {r['pct']:.0f} | {r['points']} | {r['verdict']}{nm} "
                    f"| {r['rms']:.3f} | {r['p999']:.3f} | {r['largest']:.1f} "
                    f"| {r['regions']:.1f} ({r['n_regions']}) |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
