"""Big scans: 1 M and 10 M point scans of the sample shell, end to end.

The scans are made from ``samples/shell_scan.ply``'s free-state scan (3 views, 0.02 mm
noise): each new point lies in the triangle of a scan point and two of its 8 nearest
neighbours (uniform barycentric coordinates, so the dense scan covers the surface the sample
does, with its deformation), plus 0.015 mm normal noise; written as binary little-endian PLY
(float32). Per size the table gives the median over ``--runs`` of

* ``read s``: :func:`qifreport.registration.pointcloud.read_scan` without de-duplication;
* ``dedup s``: :func:`qifreport.registration.pointcloud.unique_points`;
* ``thin s``: :func:`qifreport.registration.thinning.thin_scan` on the nominal's grid;
* ``inspect s``: the wall time of ``qifreport NOMINAL SCAN --tolerance 0.5 --no-pdf --json
  --profile`` in a fresh process (the part state from the cache, built once beforehand);
* ``peak GiB``: that process's own peak resident memory (its ``VmHWM``, the profile's total
  row; not ``ru_maxrss``, which Linux carries across ``exec`` from this larger process).

    python bench/big_scan.py [--points 1e6 1e7] [--runs 1] [--keep DIR]

The targets for 10 M points (time and memory on the 2-core reference machine) are in
``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from qifreport.registration.mesh import load_mesh
from qifreport.registration.normals import pca_normals
from qifreport.registration.pointcloud import read_scan, unique_points
from qifreport.registration.thinning import nominal_spacing, thin_scan

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "samples" / "shell_nominal.ply"
SCAN = ROOT / "samples" / "shell_scan.ply"


def dense_scan(n: int, seed: int = 0, k: int = 8, noise: float = 0.015) -> np.ndarray:
    """``n`` points (float32, mm) on the surface of the sample shell scan (module docstring)."""
    S = read_scan(SCAN).points
    _, nb = cKDTree(S).query(S, k=k + 1)
    N = pca_normals(S)
    rng = np.random.default_rng(seed)
    out = np.empty((n, 3), np.float32)
    chunk = 1_000_000
    for a in range(0, n, chunk):
        c = min(chunk, n - a)
        i = rng.integers(0, len(S), c)
        jl = rng.integers(1, k + 1, (c, 2))
        j, l = nb[i, jl[:, 0]], nb[i, jl[:, 1]]
        u, v = rng.random(c), rng.random(c)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        X = S[i] + u[:, None] * (S[j] - S[i]) + v[:, None] * (S[l] - S[i])
        out[a : a + c] = X + rng.normal(0.0, noise, (c, 1)) * N[i]
    return out


def write_ply(path: Path, P: np.ndarray) -> None:
    """A binary little-endian PLY of float32 points."""
    head = (
        "ply\nformat binary_little_endian 1.0\ncomment qifreport bench/big_scan.py\n"
        f"element vertex {len(P)}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(head.encode("ascii"))
        fh.write(np.ascontiguousarray(P, dtype="<f4").tobytes())


def _median(fn, runs: int):
    ts, out = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), out


def stages(scan: Path, spacing: float, runs: int) -> dict:
    """Median seconds of reading, de-duplicating and thinning ``scan`` in this process."""
    t_read, read = _median(lambda: read_scan(scan, deduplicate=False), runs)
    P, n_read = read.points, read.points_read
    t_dedup, (Q, _) = _median(lambda: unique_points(P), runs)
    t_thin, (_, report) = _median(lambda: thin_scan(Q, spacing, points_read=n_read), runs)
    return {"read": t_read, "dedup": t_dedup, "thin": t_thin, "report": report}


def inspect(scan: Path, out: Path) -> tuple[float, float, int, dict]:
    """One ``qifreport`` run in a fresh process: wall s, peak GiB, exit code, JSON doc."""
    exe = Path(sys.executable).parent / "qifreport"
    argv = [str(exe), str(NOMINAL), str(scan), "--tolerance", "0.5", "--out", str(out)]
    argv += ["--force", "--no-pdf", "--json", "--quiet", "--profile"]
    t0 = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode not in (0, 1, 3):
        raise SystemExit(f"qifreport exited {r.returncode}: {r.stderr.strip()}")
    m = re.search(r"^total\s+[\d.]+\s+([\d.]+)\s*$", r.stdout, re.M)
    peak = float(m.group(1)) / 1024 if m else float("nan")  # MiB -> GiB
    doc = json.loads((out / f"{NOMINAL.stem}.json").read_text())
    return wall, peak, r.returncode, doc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=float, nargs="+", default=[1e6, 1e7])
    ap.add_argument("--runs", type=int, default=1, help="runs per size (medians)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the scans and outputs here")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="qifreport-bigscan-"))
    work.mkdir(parents=True, exist_ok=True)
    V, F = load_mesh(NOMINAL)
    spacing = nominal_spacing(V, F)
    inspect(SCAN, work / "warm")  # builds the part's cache entry once: not timed below
    print(f"nominal {NOMINAL.name}: thinning grid {spacing:.3f} mm; work folder {work}")
    head = (
        f"{'points':>11} {'read s':>7} {'dedup s':>8} {'thin s':>7} {'inspect s':>10} "
        f"{'peak GiB':>9} {'used':>8} {'voxel mm':>9} verdict"
    )
    print(head)
    for n in [int(p) for p in args.points]:
        scan = work / f"shell_{n}.ply"
        if not scan.is_file():
            write_ply(scan, dense_scan(n))
        st = stages(scan, spacing, args.runs)
        runs = [inspect(scan, work / f"out_{n}") for _ in range(args.runs)]
        wall = statistics.median(r[0] for r in runs)
        peak = max(r[1] for r in runs)
        doc = runs[-1][3]
        used = doc.get("scan_input", {}).get("points_used", st["report"].points_used)
        voxel = doc.get("scan_input", {}).get("voxel_mm")
        print(
            f"{n:>11,} {st['read']:>7.2f} {st['dedup']:>8.2f} {st['thin']:>7.2f} "
            f"{wall:>10.1f} {peak:>9.2f} {used:>8,} "
            f"{'-' if voxel is None else f'{voxel:.3f}':>9} {doc['verdict']}",
            flush=True,
        )


if __name__ == "__main__":
    main()
