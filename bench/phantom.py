"""Phantom deviations: mesh nominals scanned at their own vertices.

Every case writes a nominal mesh and a scan of its own vertices, each moved along its vertex
normal by Gaussian noise of ``--noise`` mm (5 um), and runs ``qifreport NOMINAL SCAN
--tolerance 0.5``. A perfect part: the verdict must be PASS and every scored vertex within
4 sigma of zero; the trim edge and the size must read about zero. Cases:

* ``shell``: ``samples/shell_nominal.ply`` (an open sheet, 8,436 vertices);
* ``fandisk``: ``../shared/meshes/fandisk.off`` scaled to a 100 mm diagonal and subdivided
  once (a closed CAD mesh with sharp creases, 28,910 vertices);
* ``organic``: an icosphere of radius 40 mm subdivided to 10,242 vertices and displaced
  along its normals by three low-frequency bumps (a smooth closed surface, no rim).

    python bench/phantom.py [--cases shell,fandisk,organic] [--noise 0.005] [--seed 0]

Prints per case: verdict, exit code, scored vertices, vertex RMS, max |dev|, P99.9, the
4-sigma bound, the trim edge's median and P05/P95, the size scale +/- sd, and the part
class (:mod:`qifreport.metrology.deviation.part_class`: whether the trim edges are judged).
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

from qifreport.registration.mesh import load_mesh, vertex_normals
from qifreport.simulate.shapes import bumpy_sphere, fandisk

sys.path.insert(0, str(Path(__file__).resolve().parent))
from big_scan import write_ply  # noqa: E402 - the benchmark's own writer, not a copy

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
EXE = Path(sys.executable).with_name("qifreport")


def nominal(case: str, work: Path) -> Path:
    """The nominal mesh file of ``case`` (written to ``work`` unless it is a sample)."""
    if case == "shell":
        return ROOT / "samples" / "shell_nominal.ply"
    if case == "fandisk":
        V, F = fandisk(str(SHARED / "meshes" / "fandisk.off"))
    elif case == "organic":
        V, F = bumpy_sphere()
    else:
        raise ValueError(f"unknown case {case!r}")
    path = work / f"{case}.ply"
    trimesh.Trimesh(V, F, process=False).export(path)
    return path


def run_case(case: str, noise: float, seed: int, work: Path) -> dict:
    """Write the case's nominal and its own-vertex scan, run the command, read its JSON."""
    nom = nominal(case, work)
    V, F = load_mesh(nom)
    N = vertex_normals(V, F)
    rng = np.random.default_rng(seed)
    scan = work / f"{case}_scan.ply"
    write_ply(scan, V + rng.normal(0.0, noise, len(V))[:, None] * N)
    out = work / f"{case}_out"
    r = subprocess.run(
        [
            str(EXE),
            str(nom),
            str(scan),
            "--tolerance",
            "0.5",
            "--out",
            str(out),
            "--force",
            "--json",
            "--no-pdf",
            "--no-cache",
        ],
        capture_output=True,
        text=True,
    )
    js = next(out.glob("*.json"), None)
    if js is None:
        raise RuntimeError(f"{case}: no JSON (exit {r.returncode}): {r.stderr[-2000:]}")
    d = json.loads(js.read_text())
    vd = d["vertex_deviation"]
    e = (d.get("edges") or {}).get("statistics_mm") or {}
    s = d.get("size") or {}
    return {
        "case": case,
        "verdict": d["verdict"],
        "exit": r.returncode,
        "vertices": len(V),
        "scored": vd["n"],
        "rms": vd["rms"],
        "max": vd["max_abs"],
        "p999": vd["p999"],
        "bound": 4.0 * noise,
        "edge": (e.get("median"), e.get("p05"), e.get("p95")),
        "edge_status": (d.get("edges") or {}).get("status"),
        "part": ((d.get("edges") or {}).get("part_class") or {}).get("kind", "-"),
        "judged": (d.get("edges") or {}).get("judged"),
        "size": (s.get("status"), s.get("scale"), s.get("scale_sd")),
    }


def _f(x: float | None, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="shell,fandisk,organic")
    ap.add_argument("--noise", type=float, default=0.005, help="mm, along the vertex normal")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    print(
        "| case | vertices | verdict (exit) | scored | RMS mm | max mm | P99.9 mm | 4 sigma mm "
        "| trim edge median (P05/P95) mm | size | part class (trim edges judged) |"
    )
    print("|---|---:|---|---:|---:|---:|---:|---:|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases.split(","):
            r = run_case(case, a.noise, a.seed, Path(tmp))
            med, p05, p95 = r["edge"]
            st, sc, sd = r["size"]
            edge = (
                f"{_f(med, '+.3f')} ({_f(p05, '+.3f')}/{_f(p95, '+.3f')})"
                if med is not None
                else r["edge_status"] or "-"
            )
            size = f"{st} {_f(sc, '.4f')} +/- {_f(sd, '.4f')}" if sc is not None else str(st)
            print(
                f"| {case} | {r['vertices']} | {r['verdict']} ({r['exit']}) | {r['scored']} "
                f"| {r['rms']:.4f} | {r['max']:.4f} | {r['p999']:.4f} | {r['bound']:.3f} "
                f"| {edge} | {size} | {r['part']} ({'yes' if r['judged'] else 'no'}) |",
                flush=True,
            )


if __name__ == "__main__":
    main()
