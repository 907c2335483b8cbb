"""Scale run: a 600 mm part, a ~200k-vertex nominal and a ~400k-point scan.

The thin shell (:func:`qifreport.simulate.shapes.thin_shell`) scaled to 600 mm and meshed
at ~200k vertices, deformed by the analytic free state to about the paper's real-part
deflection (4.6 mm), scanned from 3 views; the nominal and the scan are written as PLY and
``qifreport --profile`` runs on them in a fresh process (so its peak memory is its own).
Prints the part, the scan, the CLI's per-stage table (wall time, peak resident memory) and
the child's own peak RSS (its ``VmHWM``, from the profile; ``--no-cache``: a cold run), and
the peak memory of it and the processes it forks together (the command judges the free
state and measures the trim edges in forked children): their proportional set sizes summed.

    python bench/scale.py [--vertices 200000] [--points 400000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import trimesh

from qifreport.registration.mesh import bounding_diagonal
from qifreport.simulate.cases import make_case
from qifreport.simulate.scanner import ScanSpec
from qifreport.simulate.shapes import thin_shell


def build(vertices: int, points: int, length: float = 600.0, deflection: float = 4.6):
    """The part (V, F) and its free-state scan P (mm)."""
    base_len, base_w = 170.0, 110.0
    spacing = float(np.sqrt(base_len * base_w / vertices))
    V, F = thin_shell(base_len, base_w, spacing)
    V = V * (length / base_len)
    diag = bounding_diagonal(V)
    h = spacing * length / base_len
    # pixel pitch for ~`points` samples over 3 views of the ~length x 0.65 length sheet
    pixel = float(np.sqrt(3 * 0.81 * length * length * base_w / base_len / points))
    case = make_case(
        V,
        F,
        generator="analytic",
        amplitude=deflection / diag,
        seed=0,
        spec=ScanSpec(views=3, noise=0.02, pixel=pixel, seed=0),
    )
    return V, F, case.P, h


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=200_000)
    ap.add_argument("--points", type=int, default=400_000)
    ap.add_argument("--keep", type=Path, default=None, help="keep the inputs and outputs here")
    args = ap.parse_args()
    t0 = time.perf_counter()
    V, F, P, h = build(args.vertices, args.points)
    t_build = time.perf_counter() - t0
    work = args.keep or Path(tempfile.mkdtemp(prefix="qifreport-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    nominal, scan = work / "cover600.ply", work / "scan.ply"
    trimesh.Trimesh(V, F, process=False).export(nominal)
    trimesh.PointCloud(P).export(scan)
    print(
        f"part: {len(V)} vertices, {len(F)} triangles, diagonal {bounding_diagonal(V):.0f} mm, "
        f"edge ~{h:.2f} mm; scan: {len(P)} points (3 views, 0.02 mm noise); generated in "
        f"{t_build:.0f} s",
        flush=True,
    )
    exe = Path(sys.executable).parent / "qifreport"
    cmd = [str(exe), nominal, scan, "--tolerance", "1.0", "--out", work / "out"]
    cmd += ["--json", "--profile", "--quiet", "--force", "--no-cache"]
    t1 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tree_peak = TreePeak(proc.pid)
    out, err = proc.communicate()
    tree_peak.stop()
    wall = time.perf_counter() - t1
    print(out)
    if proc.returncode not in (0, 1, 3):
        print(err)
        raise SystemExit(f"qifreport exited {proc.returncode}")
    # the profile's total row: the command's own high-water mark (VmHWM). Not the kernel's
    # RUSAGE_CHILDREN ru_maxrss: Linux carries ru_maxrss across exec, so the child would
    # report this (large) process's size at fork as its own peak
    m = re.search(r"^total\s+[\d.]+\s+([\d.]+)\s*$", out, re.M)
    child = float(m.group(1)) / 1024 if m else float("nan")  # MiB -> GiB
    print(
        f"exit {proc.returncode}; wall {wall:.0f} s; peak RSS of the qifreport process "
        f"{child:.2f} GiB; of it and the children it forks together {tree_peak.peak / 2**30:.2f} "
        f"GiB (proportional set sizes; their RSS summed {tree_peak.peak_rss / 2**30:.2f} GiB, "
        "shared pages counted twice; limit 1.5 GiB)"
    )


class TreePeak:
    """The largest memory held by a process and its descendants together, sampled every
    ``interval`` s from ``/proc``: the sum of their proportional set sizes (``Pss`` of
    ``smaps_rollup``: a page shared by k processes, as a forked child shares its parent's
    until either writes it, counts 1/k in each, so the sum is the memory the tree holds),
    and the sum of their resident set sizes (shared pages counted in each: an upper
    bound)."""

    def __init__(self, pid: int, interval: float = 0.05) -> None:
        self.pid, self.interval = pid, interval
        self.peak = self.peak_rss = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _tree(self, pid: int) -> list[int]:
        pids = [pid]
        try:
            for task in Path(f"/proc/{pid}/task").iterdir():
                for c in (task / "children").read_text().split():
                    pids += self._tree(int(c))
        except OSError:
            pass
        return pids

    @staticmethod
    def _pss_rss(pid: int) -> tuple[int, int]:
        """(Pss, Rss) of one process, bytes, from one read of its ``smaps_rollup`` (the
        kernel walks the page tables for each read); (0, 0) once it has gone."""
        kib = {}
        try:
            for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
                key, _, rest = line.partition(":")
                if key in ("Pss", "Rss"):
                    kib[key] = int(rest.split()[0])
        except (OSError, ValueError, IndexError):
            pass
        return kib.get("Pss", 0) * 1024, kib.get("Rss", 0) * 1024

    def _run(self) -> None:
        while not self._done.wait(self.interval):
            sizes = [self._pss_rss(p) for p in self._tree(self.pid)]
            pss, rss = sum(s[0] for s in sizes), sum(s[1] for s in sizes)
            self.peak, self.peak_rss = max(self.peak, pss), max(self.peak_rss, rss)

    def stop(self) -> None:
        self._done.set()
        self._thread.join()


if __name__ == "__main__":
    main()
