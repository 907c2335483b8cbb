"""Real STEP files from many exporters through ``qifreport pmi`` and ``qifreport plan``.

Nothing in OpenCASCADE may take the process down: each file is read by both commands, one
at a time, each under ``timeout -s KILL`` (``--timeout``), and every outcome is classed: ``read``
(exit 0), ``refused`` (exit 2 with one line ``qifreport: error: ...``), or a crash (a signal,
a Python traceback, ``internal error``, the time limit). The corpus is not in the repository:
``bench/step_sweep_sources.tsv`` names each file's public repository, path and commit (OCCT's
CAx-IF test data and models by Fusion 360, CATIA V5, SolidWorks, Creo, NX, Inventor, I-DEAS,
FreeCAD and some twenty other exporters); fetch them into one folder under the names given.

    python bench/step_sweep.py FOLDER [--timeout 120] [--csv OUT.csv]

Prints the table (files, read, refused with their reasons, crashed, over the limit) and the
counts per exporter (the header's originating system); exits 1 when anything crashed.
"""

from __future__ import annotations

import argparse
import collections
import csv
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXE = Path(sys.executable).parent / "qifreport"
COMMANDS = ("pmi", "plan")


def exporter(path: Path) -> str:
    """The header's originating system (else its preprocessor), for the per-exporter counts."""
    head = path.read_bytes()[:65536].decode("latin-1")
    m = re.search(r"FILE_NAME\s*\((.*?)\)\s*;", head, re.S | re.I)
    if not m:
        return "(no FILE_NAME)"
    quoted = [q.replace("''", "'").strip() for q in re.findall(r"'((?:[^']|'')*)'", m.group(1))]
    # name, time stamp, author(s), organisation(s), preprocessor, originating system, ...
    tail = [q for q in quoted[-3:] if q and q.lower() not in ("unknown", "none")]
    return (tail[1] if len(tail) > 1 else tail[0] if tail else "(blank)")[:40]


def outcome(cmd: list[str], timeout: float) -> tuple[str, float, str]:
    """``(class, seconds, last stderr line)`` of one command."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        try:
            r = subprocess.run(
                [
                    "timeout",
                    "-s",
                    "KILL",
                    str(timeout),
                    *cmd,
                    *(["--out", tmp] * (cmd[1] == "plan")),
                ],
                capture_output=True,
                text=True,
                cwd=tmp,
            )
        except OSError as exc:
            return "crashed", 0.0, str(exc)
    seconds = time.perf_counter() - t0
    err = r.stderr.strip().splitlines()
    last = err[-1] if err else ""
    if r.returncode in (137, -9) and seconds >= timeout - 1:
        return "over the limit", seconds, last
    if r.returncode >= 128 or r.returncode < 0 or "Traceback" in r.stderr:
        return "crashed", seconds, last
    if "internal error" in r.stderr:
        return "crashed", seconds, last
    if r.returncode == 0:
        return "read", seconds, last
    if r.returncode == 2 and len(err) == 1 and last.startswith("qifreport: error: "):
        return "refused", seconds, last
    return f"exit {r.returncode}", seconds, last


def reason(line: str, name: str) -> str:
    """A refusal's reason with the file's name and numbers taken out (to group them)."""
    text = line.removeprefix("qifreport: error: ").replace(name, "FILE")
    return re.sub(r"#?\d+(\.\d+)?", "N", text)[:100]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--csv", type=Path, default=None, help="one row per file and command")
    a = ap.parse_args()
    files = sorted(
        p for p in a.folder.iterdir() if p.is_file() and p.suffix.lower() in (".stp", ".step")
    )
    rows = []
    for k, path in enumerate(files, start=1):
        for command in COMMANDS:
            cls, seconds, last = outcome([str(EXE), command, str(path)], a.timeout)
            rows.append((path.name, exporter(path), command, cls, seconds, last))
            print(f"[{k}/{len(files)}] {command} {path.name}: {cls} in {seconds:.1f} s", flush=True)
    if a.csv:
        with open(a.csv, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["file", "exporter", "command", "outcome", "seconds", "last_stderr_line"])
            w.writerows(rows)
    print(f"\n{len(files)} files")
    for command in COMMANDS:
        mine = [r for r in rows if r[2] == command]
        counts = collections.Counter(r[3] for r in mine)
        times = sorted(r[4] for r in mine)
        print(
            f"{command}: {counts.get('read', 0)} read, {counts.get('refused', 0)} refused, "
            f"{counts.get('crashed', 0)} crashed, {counts.get('over the limit', 0)} over "
            f"{a.timeout:g} s, other {sum(v for c, v in counts.items() if c.startswith('exit'))}; "
            f"median {times[len(times) // 2]:.1f} s, max {times[-1]:.1f} s"
        )
    refusals = collections.Counter(reason(r[5], r[0]) for r in rows if r[3] == "refused")
    for text, n in refusals.most_common():
        print(f"  refused x{n}: {text}")
    per = collections.defaultdict(collections.Counter)
    for _, exp, command, cls, _, _ in rows:
        if command == "pmi":
            per[exp][cls] += 1
    print("\nexporter                                  files  read  refused  crashed")
    for exp, c in sorted(per.items(), key=lambda kv: -sum(kv[1].values())):
        print(f"{exp:<40} {sum(c.values()):>6} {c['read']:>5} {c['refused']:>8} {c['crashed']:>8}")
    bad = [r for r in rows if r[3] in ("crashed", "over the limit")]
    for name, _, command, cls, _, last in bad:
        print(f"{cls}: {command} {name}: {last}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
