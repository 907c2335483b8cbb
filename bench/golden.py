"""The sample inspections' numbers and verdicts, for comparing two trees of the code.

Runs the five sample inspections of ``samples/`` (the panel, its defect scan, the shell, its
defect scan, the warped panel held at its datum targets) with ``--no-cache --json --no-pdf``
into ``OUT/<case>/``, then, given ``--against`` another such folder (made by the same script
in another tree), compares every JSON value: floats within ``--rtol`` (default 0: bit for
bit), everything else equal, wall-clock timings and paths left out. A restructuring that
should not change a figure shows "0 differences".

    python bench/golden.py out/golden-new [--against out/golden-old] [--rtol 0]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
S = ROOT / "samples"
CASES = {
    "panel": [S / "panel.step", S / "panel_scan.ply"],
    "defect": [S / "panel.step", S / "panel_scan_defect.ply"],
    "shell": [S / "shell_nominal.ply", S / "shell_scan.ply", "--tolerance", "0.5"],
    "shelldef": [S / "shell_nominal.ply", S / "shell_scan_defect.ply", "--tolerance", "0.5"],
    "restrained": [
        S / "panel.step",
        S / "panel_scan_warped.ply",
        *("--clamps", "pmi", "--max-clamp-force", "20", "--material", "abs"),
    ],
}
#: keys whose values differ between runs or trees by nature
SKIPPED = {"created", "version", "host", "path", "out", "started", "finished", "seconds"}


def run_cases(out: Path) -> dict[str, int]:
    """Each case's exit code; its JSON in ``out/<case>/``."""
    exe = Path(sys.executable).with_name("qifreport")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    codes = {}
    for name, args in CASES.items():
        cmd = [str(exe), *map(str, args), "--no-cache", "--json", "--force", "--no-pdf"]
        r = subprocess.run([*cmd, "--out", str(out / name)], env=env, capture_output=True)
        codes[name] = r.returncode
        print(f"{name:11s} exit {r.returncode}")
    (out / "exit_codes.json").write_text(json.dumps(codes, indent=1))
    return codes


def differences(a, b, where: str, rtol: float) -> list[str]:
    """Where the JSON values ``a`` and ``b`` differ (floats beyond ``rtol``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k in SKIPPED or "time" in k or "timing" in k:
                continue
            if k not in a or k not in b:
                out.append(f"{where}/{k}: only in one")
            else:
                out += differences(a[k], b[k], f"{where}/{k}", rtol)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} items against {len(b)}"]
        return [
            d
            for i, (x, y) in enumerate(zip(a, b, strict=True))
            for d in differences(x, y, f"{where}[{i}]", rtol)
        ]
    if isinstance(a, float) and isinstance(b, float):
        same = a == b or (math.isnan(a) and math.isnan(b))
        if same or abs(a - b) <= rtol * max(abs(a), abs(b)):
            return []
    elif isinstance(a, str) and isinstance(b, str) and where.endswith("qif/message"):
        a, b = a.split(" in /")[0], b.split(" in /")[0]  # names the schema folder
    if a != b:
        return [f"{where}: {a!r} != {b!r}"]
    return []


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder for this tree's outputs")
    ap.add_argument("--against", type=Path, help="another tree's outputs to compare with")
    ap.add_argument("--rtol", type=float, default=0.0, help="relative tolerance of floats")
    a = ap.parse_args()
    run_cases(a.out)
    if a.against is None:
        return 0
    found = []
    files = sorted(f for f in a.out.rglob("*.json") if f.parent != a.out)
    for f in files:
        g = a.against / f.relative_to(a.out)
        if not g.exists():
            found.append(f"{g}: missing")
            continue
        found += differences(json.loads(g.read_text()), json.loads(f.read_text()), f.name, a.rtol)
    print(f"{len(files)} files compared; {len(found)} differences")
    for d in found[:50]:
        print("  " + d)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
