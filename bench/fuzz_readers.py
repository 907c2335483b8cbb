"""Fuzz the file readers: ``read_scan`` and ``load_mesh`` on many arbitrary and damaged files.

The property of ``tests/test_fuzz_readers.py``, with many more cases and a fixed seed: for
any file content a reader returns finite float64 arrays of the right shape or raises
``InputError`` with a one-line message naming the file; any other exception, a wrong result,
or a read longer than ``--timeout`` seconds escapes. A third of the cases of each reader are
arbitrary bytes (behind a format's magic, or not), the rest mutations of small valid files of
every format (byte flips and writes, truncation, insertion, deletion, duplication, header
edits).

Printed per reader (and per format below it): cases run, clean errors (InputError),
successes, and escapes; then the first traceback of each kind of escape (exception type and
the line that raised it). Exit status 1 if anything escaped, else 0.

    python bench/fuzz_readers.py [--cases 2000] [--seed 0] [--timeout 10] [--mem-gb 8]
                                 [--reader read_scan|load_mesh] [--save DIR]

``--cases`` is per reader. ``--save DIR`` keeps the first input of each escape kind there,
and the current input as ``last-case`` (reader, format and suffix in ``last-case.txt``): the
input of a crash, which ends the run (the fault handler prints where). ``--reader`` limits
the run to one reader.
The address space is capped at ``--mem-gb`` GiB so a header that declares billions of
points fails as a MemoryError instead of swapping the machine.
"""

from __future__ import annotations

import argparse
import faulthandler
import random
import resource
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tests.test_fuzz_readers as props  # noqa: E402  (after the path set-up)
from tests.test_fuzz_readers import (  # noqa: E402
    FORMATS,
    KINDS,
    MAGICS,
    READER_FORMATS,
    READER_SUFFIXES,
    READERS,
    available_formats,
    check_read,
    mutated,
)


def random_ops(rng: random.Random) -> list[tuple[str, int, int, bytes]]:
    """1 to 4 mutation ops, drawn like the test's hypothesis strategy."""
    return [
        (
            rng.choice(KINDS),
            rng.randrange(2**31),
            rng.randrange(2**31),
            rng.randbytes(rng.randint(1, 12)),
        )
        for _ in range(rng.randint(1, 4))
    ]


def random_case(rng: random.Random, reader: str) -> tuple[str, str, bytes]:
    """``(label, suffix, data)`` of one case: arbitrary bytes (a third) or a mutated seed."""
    if rng.random() < 1 / 3:
        suffix = rng.choice(READER_SUFFIXES[reader])
        size = rng.choice([0, 1, 8, 64, 512, 4096, 20000])
        return f"bytes{suffix}", suffix, rng.choice(MAGICS) + rng.randbytes(rng.randint(0, size))
    fmt = rng.choice([f for f in READER_FORMATS[reader] if f in available_formats()])
    return fmt, FORMATS[fmt][0], mutated(fmt, random_ops(rng))


def escape_kind(exc: BaseException) -> str:
    """Exception type and the innermost line that raised it."""
    tb = traceback.extract_tb(exc.__traceback__)
    where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
    return f"{type(exc).__name__} at {where}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=2000, help="cases per reader (default 2000)")
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument(
        "--timeout",
        type=float,
        default=10.0,
        help="seconds one read may take before it counts as a hang (default 10)",
    )
    ap.add_argument(
        "--mem-gb",
        type=float,
        default=8.0,
        help="address-space cap of this process, GiB (default 8; 0: none)",
    )
    ap.add_argument(
        "--reader",
        choices=list(READERS),
        action="append",
        help="fuzz only this reader (repeatable; default all)",
    )
    ap.add_argument(
        "--save",
        type=Path,
        default=None,
        metavar="DIR",
        help="keep the first input of each escape kind in DIR",
    )
    args = ap.parse_args(argv)
    props.TIMEOUT_S = args.timeout
    faulthandler.enable()  # a reader that crashes the interpreter shows where
    if args.mem_gb > 0:
        cap = int(args.mem_gb * 2**30)
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    if args.save:
        args.save.mkdir(parents=True, exist_ok=True)

    print(
        f"fuzz_readers: {args.cases} cases per reader, seed {args.seed}, timeout "
        f"{args.timeout:g} s, formats: {', '.join(available_formats())}"
    )
    rng = random.Random(args.seed)
    first: dict[str, tuple[str, str]] = {}  # escape kind -> (reader/label, traceback)
    total_escapes = 0
    with tempfile.TemporaryDirectory(prefix="qifreport-fuzz-") as tmp:
        for reader in args.reader or list(READERS):
            counts: dict[str, Counter] = defaultdict(Counter)
            t0 = time.perf_counter()
            for k in range(args.cases):
                label, suffix, data = random_case(rng, reader)
                c = counts[label]
                c["cases"] += 1
                if args.save:  # the input of a crash survives it
                    (args.save / "last-case").write_bytes(data)
                    (args.save / "last-case.txt").write_text(f"{reader} {label} {suffix}\n")
                try:
                    c[check_read(reader, suffix, data, Path(tmp))] += 1
                except BaseException as exc:  # noqa: BLE001 - counting is the point
                    if isinstance(exc, KeyboardInterrupt):
                        raise
                    c["escapes"] += 1
                    kind = escape_kind(exc)
                    if kind not in first:
                        first[kind] = (
                            f"{reader} {label} (case {k})",
                            "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)),
                        )
                        if args.save:
                            name = f"{reader}-{len(first):02d}-{label}{suffix}"
                            (args.save / name).write_bytes(data)
            tot = sum(counts.values(), Counter())
            total_escapes += tot["escapes"]
            print(
                f"{reader}: {tot['cases']} cases, {tot['error']} clean errors, {tot['ok']} "
                f"successes, {tot['escapes']} escapes ({time.perf_counter() - t0:.1f} s)"
            )
            for label in sorted(counts):
                c = counts[label]
                print(
                    f"  {label:20s} {c['cases']:5d} cases {c['error']:5d} errors "
                    f"{c['ok']:5d} ok {c['escapes']:4d} escapes"
                )
    for kind, (where, tb) in first.items():
        print(f"\nescape: {kind}, first in {where}:\n{tb}")
    print(f"{'FAIL' if total_escapes else 'OK'}: {total_escapes} escapes, {len(first)} kind(s)")
    return 1 if total_escapes else 0


if __name__ == "__main__":
    sys.exit(main())
