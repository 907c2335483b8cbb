"""Stray points: does a share of points that are not on the part change the verdict?

Each case's scan (the demo panel, conforming and with its defect; the thin shell) is
inspected as delivered and with uniform stray points added in the scan's box grown 40 %
(reflections, dust, ghosts: ``share`` of its point count, seeded), through the command line
exactly as a user runs it (``--json --no-pdf --no-qif``).

Printed per case and share: the verdict, the stray points left out and the spikes (seated
points alone off their neighbourhood) with their sum against the points added, and the
flatness readings (the panel's flanges, G1 and G2, mm): the outlier model holds when every
row up to 2 % gives the clean row's verdict and readings, and a row above 2 % is NOT
ESTABLISHED with the share named.

    python bench/stray_points.py [--shares 0,0.001,0.01,0.03] [--cases panel,...] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from qifreport.registration.pointcloud import read_scan
from qifreport.simulate.scanner import with_stray_points

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).with_name("qifreport")

#: case name -> (nominal, scan, extra command-line arguments)
CASES: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "panel": ("panel.step", "panel_scan.ply", ()),
    "panel_defect": ("panel.step", "panel_scan_defect.ply", ()),
    "shell": ("shell_nominal.ply", "shell_scan.ply", ("--tolerance", "0.5")),
}


def run(nominal: Path, scan: Path, out: Path, extra: tuple[str, ...]) -> dict:
    """The command's JSON summary."""
    cmd = [str(EXE), str(nominal), str(scan), "--out", str(out), "--json", "--no-pdf"]
    r = subprocess.run([*cmd, "--no-qif", "--force", "--quiet", *extra], capture_output=True)
    if r.returncode not in (0, 1, 3):
        raise SystemExit(r.stderr.decode()[-2000:])
    return json.loads((out / f"{nominal.stem}.json").read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shares", default="0,0.001,0.01,0.03")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    shares = [float(s) for s in a.shares.split(",")]
    head = f"{'case':<14}{'share':>7}  {'verdict':<16}{'stray':>7}{'spikes':>7}{'added':>7}"
    print(head + "  flatness (mm)")
    with tempfile.TemporaryDirectory() as td:
        for name in a.cases.split(","):
            nominal, scan, extra = CASES[name]
            P = read_scan(SAMPLES / scan).points
            for share in shares:
                path = Path(td) / f"{name}_{share:g}.npy"
                np.save(path, with_stray_points(P, share, a.seed) if share else P)
                doc = run(SAMPLES / nominal, path, Path(td) / path.stem, extra)
                stray = (doc.get("stray_points") or {}).get("count", 0)
                flat = {
                    c["key"]: c["value"]
                    for c in doc["characteristics"]
                    if c["kind"] == "flatness" and c["value"] is not None
                }
                flats = " ".join(f"{k} {v:.4f}" for k, v in flat.items()) or "-"
                print(
                    f"{name:<14}{share:>7g}  {doc['verdict']:<16}{stray:>7}"
                    f"{doc.get('spike_points') or 0:>7}{int(round(share * len(P))):>7}  {flats}"
                )


if __name__ == "__main__":
    main()
