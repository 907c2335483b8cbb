"""Generate the demo inputs in samples/ (deterministic; re-run to regenerate).

* ``shell_nominal.ply``: the 170 x 110 mm doubly curved thin shell (8,436 vertices).
* ``shell_scan.ply``: a simulated free-state scan of it: analytic compliance at 2 % of the
  diagonal (~4 mm), 3 views, 0.02 mm range noise, clamp dropout. Conforming at +/-0.5 mm.
* ``shell_scan_defect.ply``: the same with a 1.0 mm / sigma 7 mm Gaussian bump: fails the
  region criterion at +/-0.5 mm.

Usage: ``python samples/make_samples.py [OUTDIR]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

from registration.simulate.cases import make_case
from registration.simulate.shapes import thin_shell

SEED = 1


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    V, F = thin_shell()
    trimesh.Trimesh(V, F, process=False).export(out / "shell_nominal.ply")
    for name, defect in (("shell_scan.ply", None), ("shell_scan_defect.ply", (1.0, 7.0))):
        case = make_case(V, F, generator="analytic", amplitude=0.02, defect=defect, seed=SEED)
        P = case.P.astype(np.float32)  # scanners deliver single precision
        trimesh.PointCloud(P).export(out / name)
        print(f"{name}: {len(P)} points")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)
