"""A machined block held by a virtual fixture it could not physically take.

FTC 06 or 08 (``../shared/step/nist``): a perfect scan of its exact B-rep
(:func:`qifreport.simulate.brep_scan.perfect_scan`, 10 um noise) with its largest planar
face bowed outward by a parabolic dome of ``--bow`` mm (0 at the face's rim), inspected with
``--always-fixture --material aluminium``: prints the verdict, the fixture's load line and
the refusals. The load must exceed the limit and a PASS be refused with the forces named.

    python bench/fixture_load_block.py [--part 06] [--bow 0.3] [--material aluminium]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT.parent / "shared" / "step" / "nist"
EXE = Path(sys.executable).with_name("qifreport")


def bowed_scan(path: Path, bow: float) -> tuple[np.ndarray, int]:
    """A perfect scan of ``path`` with its largest planar face domed by ``bow`` mm."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepGProp import BRepGProp
    from OCP.GeomAbs import GeomAbs_Plane
    from OCP.GProp import GProp_GProps

    from qifreport.simulate.brep_scan import dome, perfect_scan
    from qifreport.step.reader import read_step

    part = read_step(path)
    areas = []
    for f in part.faces:
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(f, props)
        plane = BRepAdaptor_Surface(f).GetType() == GeomAbs_Plane
        areas.append(props.Mass() if plane else 0.0)
    face = int(np.argmax(areas))
    scan, _ = perfect_scan(part.shape, part.faces, noise=0.01, points=150_000)
    P, _ = dome(scan.P, scan.normal, scan.face, face, bow)
    return P, face


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="06", choices=("06", "08"))
    ap.add_argument("--bow", type=float, default=0.3)
    ap.add_argument("--material", default="aluminium")
    a = ap.parse_args()
    step = NIST / f"nist_ftc_{a.part}_asme1_ap242-e1.stp"
    P, face = bowed_scan(step, a.bow)
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "scan.ply"
        trimesh.PointCloud(P).export(ply)
        args = [str(step), str(ply), "--always-fixture", "--material", a.material]
        args += ["--no-cache", "--json", "--no-pdf", "--force", "--out", tmp]
        r = subprocess.run([str(EXE), *args], capture_output=True, text=True)
        print(f"FTC {a.part}: face {face} bowed {a.bow} mm, exit {r.returncode}")
        for line in r.stdout.splitlines():
            if line.startswith(("verdict", "fixture load", "warning: the virtual")):
                print("  " + line)
        js = next(Path(tmp).glob("*.json"), None)
        if js is not None:
            reg = json.loads(js.read_text()).get("registration", {})
            print("  " + json.dumps(reg.get("fixture_load")))


if __name__ == "__main__":
    main()
