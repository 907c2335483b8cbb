"""Exact perfect scans of the NIST AP242 parts: what a perfect part must not get.

For every file in ``../shared/step/nist`` and every density asked: an exact all-faces scan
(:func:`qifreport.simulate.brep_scan.exact_scan`: points area-sampled on the B-rep at that
many points per mm^2, on each face's own surface, noise along the exact normal), inspected
by the CLI in the free state (``--rigid-only``). Prints one row per part and density: the
points, the verdict, the zones and characteristics that PASS / are NOT ESTABLISHED / NOT
MEASURED / FAIL, the zone whose largest scored |deviation| comes nearest its bound
``4 sigma + U`` (:mod:`qifreport.simulate.perfect_check`) and wall seconds; then every
characteristic or zone that did not PASS, with its reason.

    python bench/nist_exact_scan.py [--density 2 8] [--noise 0.005] [--keep DIR] [FILE ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT.parent / "shared" / "step" / "nist"
EXE = Path(sys.executable).with_name("qifreport")


def inspect(step: Path, P: np.ndarray, out: Path, cache: Path) -> tuple[dict, float]:
    """The CLI's JSON summary of scan ``P`` in the free state (``--rigid-only``), and its
    wall seconds."""
    out.mkdir(parents=True, exist_ok=True)
    scan = out / "scan.npy"
    np.save(scan, P)
    t = time.perf_counter()
    r = subprocess.run(
        [str(EXE), str(step), str(scan), "--json", "--no-pdf", "--no-qif", "--force"]
        + ["--rigid-only", "--cache", str(cache), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t
    scan.unlink()
    if r.returncode not in (0, 1, 3):
        raise RuntimeError(r.stderr[-2000:])
    return json.loads((out / f"{step.stem}.json").read_text()), wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--density", type=float, nargs="+", default=[2.0, 8.0], help="points/mm^2")
    ap.add_argument("--noise", type=float, default=0.005, help="normal noise sigma, mm")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, help="keep each run's JSON summary under DIR")
    a = ap.parse_args()
    from qifreport.simulate.brep_scan import brep_surface_mesh, exact_scan
    from qifreport.simulate.perfect_check import review_perfect_scan
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import shape_diagonal

    files = a.files or sorted(NIST.glob("*.stp"))
    head = (
        f"{'part':<12} {'pts/mm2':>7} {'points':>9} {'verdict':<16} {'P/NE/NM/F':>11} "
        f"{'worst zone':<10} {'|dev|':>7} {'4s+U':>7} {'s':>5}"
    )
    print(head)
    print("-" * len(head))
    with tempfile.TemporaryDirectory() as tmp:
        work = a.keep or Path(tmp)
        for f in files:
            part = read_step(f)
            mesh = brep_surface_mesh(part.shape, part.faces, 2e-4 * shape_diagonal(part.shape))
            for density in a.density:
                scan = exact_scan(
                    part.shape, part.faces, density, noise=a.noise, seed=a.seed, mesh=mesh
                )
                name = f.stem.split("_asme")[0]
                doc, wall = inspect(f, scan.P, work / f"{name}_{density:g}", work / "cache")
                del scan
                rev = review_perfect_scan(doc, a.noise)
                st = [z["verdict"] for z in doc["tolerances"]]
                st += [c["status"].replace("_", " ") for c in doc["characteristics"]]
                st = ["NOT ESTABLISHED" if s == "INDETERMINATE" else s for s in st]
                counts = "/".join(
                    str(st.count(s)) for s in ("PASS", "NOT ESTABLISHED", "NOT MEASURED", "FAIL")
                )
                print(
                    f"{name:<12} {density:>7g} {doc['scan_input']['points_read']:>9} "
                    f"{doc['verdict']:<16} {counts:>11} {rev.worst_key:<10} "
                    f"{rev.worst_dev:>7.4f} {rev.worst_bound:>7.4f} {wall:>5.0f}",
                    flush=True,
                )
                for x in rev.findings:
                    print(f"    {x.key:<6} {x.status:<15} {x.what[:70]}: {x.reason[:160]}")


if __name__ == "__main__":
    main()
