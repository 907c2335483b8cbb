"""The ``qifreport`` command line: argparse sub-commands over the application services.

* ``qifreport [inspect] NOMINAL SCAN [options]`` inspects a free-state scan against its
  nominal (:mod:`qifreport.pipeline`); ``inspect`` is the default sub-command, so
  ``qifreport part.step scan.ply`` is the short form. ``NOMINAL`` is a STEP file (AP242 with
  semantic PMI: the tolerance zones come from the part itself) or a mesh (STL/PLY/OBJ/OFF,
  with ``--tolerance``).
* ``qifreport pmi PART.step [--json]`` lists the semantic PMI read from a STEP file.
* ``qifreport validate FILE.qif [...]`` checks QIF files against the official QIF 3.0
  schemas (libxml2 and xmlschema, key/keyref included) and the DMSC XSLT checks.
* ``qifreport prepare PART`` stores the nominal's prepared state in the per-part cache
  (:mod:`qifreport.cache`); every inspection also uses the cache (``--cache``, ``--no-cache``).
* ``qifreport batch PART SCANS... --out DIR`` inspects many scans of one part, in parallel on
  local processes or a Dask cluster, resumably (:mod:`qifreport.batch`).

The options are declared group by group in :mod:`qifreport.cli_options`. The arguments
become typed options (:class:`qifreport.options.InspectOptions`,
:class:`~qifreport.options.InspectJob`, :class:`~qifreport.batch.BatchOptions`) here, once;
nothing below this module sees an ``argparse.Namespace``. Logging is configured once, from
``-v/--verbose``.

Exit codes: 0 the part passes, 1 the part fails, 2 the input cannot be inspected (one-line
error on stderr naming the problem, and no output file written), 3 not established.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from qifreport import __version__
from qifreport.errors import (
    EXIT_ERROR,
    InputError,
    Interrupted,
    leave_if_interrupted,
    raise_if_interrupted,
    require_file,
)

from .forked import in_fork

if TYPE_CHECKING:
    from .options import InspectJob, InspectOptions

__all__ = ["SUBCOMMANDS", "build_parser", "inspect_options", "main"]

log = logging.getLogger("qifreport")

#: the sub-commands; a first argument that is none of them (nor a top-level option) is the
#: nominal of the default ``inspect``
SUBCOMMANDS = ("inspect", "pmi", "plan", "validate", "prepare", "cache", "batch")


def parse_min_coverage(items: list[str] | None) -> dict:
    """``--min-coverage`` values (``FRACTION`` or ``TOL=FRACTION``) as the options'
    ``min_coverage`` and ``zone_min_coverage``; InputError for a value that is not a number."""
    out: dict = {}
    zones = []
    for item in items or []:
        sel, eq, val = item.rpartition("=")
        try:
            x = float(val)
        except ValueError:
            raise InputError(
                f"--min-coverage takes FRACTION or TOL=FRACTION (e.g. 0.7 or T2=0.9), got {item!r}"
            ) from None
        if eq:
            zones.append((sel.strip(), x))
        else:
            out["min_coverage"] = x
    if zones:
        out["zone_min_coverage"] = tuple(zones)
    return out


def inspect_options(args: argparse.Namespace) -> InspectOptions:
    """The typed options of parsed ``inspect`` / ``batch`` / ``prepare`` arguments (an
    option the sub-command does not have takes its default)."""
    from .cache import default_cache_dir
    from .options import InspectOptions

    special = ("cache_dir", "min_coverage", "zone_min_coverage")
    names = [f for f in InspectOptions.__dataclass_fields__ if f not in special]
    values = {k: getattr(args, k) for k in names if hasattr(args, k)}
    values.update(parse_min_coverage(getattr(args, "min_coverage", None)))
    if getattr(args, "no_cache", False):
        cache = None
    else:
        cache = args.cache if getattr(args, "cache", None) is not None else default_cache_dir()
    return InspectOptions(**values, cache_dir=cache)


# ------------------------------------------------------------------------- sub-commands


def _run_inspect(args: argparse.Namespace) -> int:
    from .options import InspectJob
    from .pipeline import run_job
    from .profile import Profiler

    job = InspectJob(
        nominal=args.nominal,
        scan=args.scan,
        out=args.out,
        options=inspect_options(args),
        serial=args.serial,
        name=args.name,
        json=args.json is True,
        export_mesh=args.export_mesh,
        force=args.force,
    )
    prof = Profiler().start() if args.profile else None
    outcome = run_job(job, progress=not args.quiet, prof=prof)
    with _reader_may_leave():  # the verdict stands whoever reads it
        _print_outcome(args, job, outcome, prof)
    return outcome.exit_code


def _print_outcome(args: argparse.Namespace, job: InspectJob, outcome, prof) -> None:
    """The inspection on stdout: its summary (or with ``--json -`` its JSON document), the
    profile when asked, where the QIF went."""
    from qifreport.qif.xsd import schema_advice

    from .console import summary
    from .jsonio import json_default

    if args.json == "-":  # the summary document instead of the text
        print(json.dumps(outcome.summary(job), indent=2, default=json_default, allow_nan=False))
        return
    print(summary(outcome.result))
    if prof is not None:
        prof.stop()
        print("profile (wall time and peak resident memory per stage):")
        print(prof.table())
    q = outcome.qif
    if q is not None:
        if q["valid"]:
            print(f"QIF: {q['path']} ({q['message']})")
        else:
            print(
                f"QIF: {q['path']} written, NOT validated: the official QIF 3.0 schemas were "
                f"not found ({schema_advice()})"
            )


@contextlib.contextmanager
def _reader_may_leave():
    """Printing to a reader that may leave early (``| head``): a broken pipe ends the
    printing quietly, the command's exit code unchanged."""
    try:
        yield
    except BrokenPipeError:
        _stdout_gone()


def clamps_table(rows: list[dict], source: str) -> str:
    """The clamps of ``qifreport pmi --clamps`` as text lines."""
    lines = [f"{len(rows)} clamp(s) from {source} (restrained condition, ISO 10579):"]
    for r in rows:
        limit = f"{r['max_force_N']:g} N" if r["max_force_N"] is not None else "no limit"
        datum = f", datum {r['datum']} feature" if r["datum"] else ""
        far = (
            f", {r['off_surface_mm']:.2f} mm off the surface" if r["off_surface_mm"] > 0.01 else ""
        )
        lines.append(
            f"  {r['name']:6s} ({r['x']:.2f}, {r['y']:.2f}, {r['z']:.2f}) mm  "
            f"restrains {r['directions']:3s}  {limit:9s}  on face {r['face']} "
            f"(#{r['face_step_id']}){datum}{far}"
        )
    return "\n".join(lines)


def _run_pmi(args: argparse.Namespace) -> int:
    from qifreport.step.reader import read_step
    from qifreport.step.solids import overlapping_pairs, solid_infos

    part = read_step(args.step)
    solids = solid_infos(part.shape, part.solid_names)
    overlaps = overlapping_pairs(part.shape, solids) if len(solids) > 1 else []
    clamps = None
    if args.clamps is not None:
        from .restraint import clamp_rows, read_clamps

        found, _ = read_clamps(args.clamps, args.step, args.max_clamp_force)
        clamps = clamp_rows(part, found)
    with _reader_may_leave():
        _print_pmi(args, part, solids, overlaps, clamps)
    return 0


def _print_pmi(args: argparse.Namespace, part, solids, overlaps, clamps) -> None:
    """``qifreport pmi``'s table (or JSON) of the part read."""
    from qifreport.step.report import pmi_rows, pmi_table

    from .atomic_io import sha256
    from .jsonio import json_default

    if args.json is not None:
        _print_or_write(
            args.json,
            json.dumps(
                {
                    "file": str(args.step),
                    "sha256": sha256(args.step),
                    "length_unit": part.pmi.length_unit,
                    "faces": len(part.faces),
                    "solids": [x.to_dict() for x in solids],
                    "overlapping_solids": [
                        {"solids": [a, b], "common_volume_mm3": v} for a, b, v in overlaps
                    ],
                    "items": pmi_rows(part),
                    **({"clamps": clamps} if clamps is not None else {}),
                },
                indent=2,
                default=json_default,
            ),
        )
    else:
        print(pmi_table(part))
        if clamps is not None:
            print(
                clamps_table(
                    clamps, "the datum targets" if str(args.clamps) == "pmi" else args.clamps.name
                )
            )
        if len(solids) > 1:
            print(f"{len(solids)} solids (inspect one with --solid NAME|INDEX):")
            for x in solids:
                print(f"  {x.describe()}")
            for a, b, v in overlaps:
                print(
                    f"  solids {a} and {b} overlap ({v:,.0f} mm^3 in common): nested or "
                    "overlapping, never one part"
                )


def _print_or_write(where: str, text: str) -> None:
    """``text`` on stdout (``where`` ``"-"``) or written to the file ``where`` (atomically)."""
    if where == "-":
        print(text)
        return
    from .atomic_io import atomic_write

    atomic_write(Path(where), lambda p: p.write_text(text + "\n"))
    print(f"JSON: {where}")


def _run_prepare(args: argparse.Namespace) -> int:
    from .cache import part_state

    require_file(args.nominal, "nominal")
    o = inspect_options(args)
    state, outcome = part_state(
        args.nominal,
        o.nominal_options(args.nominal),
        o.inspection_params(),
        o.cache_dir,
        rebuild=args.rebuild,
    )
    print(outcome.describe())
    if outcome.timings:
        print("  " + ", ".join(f"{k} {v:.2f} s" for k, v in outcome.timings.items()))
    part, zones = state.part, state.drawing.zones
    print(
        f"  {len(part.V)} vertices, {len(part.F)} triangles, {len(zones)} zone(s), "
        f"key {state.key[:16]}"
    )
    return 0


def _run_validate(args: argparse.Namespace) -> int:
    from .validate_command import run

    return run(args)


def _run_plan(args: argparse.Namespace) -> int:
    from .plan_command import run

    return run(args)


def _run_batch(args: argparse.Namespace) -> int:
    from .batch import batch_options, run_batch_command

    return run_batch_command(batch_options(args, inspect_options(args)))


def _add_validate_arguments(ap: argparse.ArgumentParser) -> None:
    """``validate``'s arguments (imported when the parser is built)."""
    from .validate_command import add_arguments

    add_arguments(ap)


def _add_plan_arguments(ap: argparse.ArgumentParser) -> None:
    """``plan``'s arguments (imported when the parser is built)."""
    from .plan_command import add_arguments

    add_arguments(ap)


def _add_batch_arguments(ap: argparse.ArgumentParser) -> None:
    """``batch``'s own arguments, then the inspection options (no single-scan ones)."""
    from .batch import add_batch_arguments
    from .cli_options import add_inspect_options

    add_batch_arguments(ap)
    add_inspect_options(ap, batch=True)


def _add_inspect_arguments(ap: argparse.ArgumentParser) -> None:
    from .cli_options import add_inspect_arguments

    add_inspect_arguments(ap)


def _add_pmi_arguments(ap: argparse.ArgumentParser) -> None:
    from .cli_options import add_pmi_arguments

    add_pmi_arguments(ap)


def _add_prepare_arguments(ap: argparse.ArgumentParser) -> None:
    from .cli_options import add_prepare_arguments

    add_prepare_arguments(ap)


def _add_cache_arguments(ap: argparse.ArgumentParser) -> None:
    """``cache``'s arguments."""
    ap.add_argument(
        "--cache",
        type=Path,
        metavar="DIR",
        help="the cache directory (default $QIFREPORT_CACHE or the user cache directory)",
    )
    ap.add_argument(
        "--prune",
        action="store_true",
        help="remove the entries used longest ago until the rest fit --max-size",
    )
    ap.add_argument(
        "--max-size",
        type=float,
        metavar="MB",
        help="the bound --prune keeps (default $QIFREPORT_CACHE_MAX_MB or 2048; 0 empties "
        "the cache)",
    )


def _run_cache(args: argparse.Namespace) -> int:
    from .cache import default_cache_dir
    from .cache_prune import cache_entries, prune, size_limit

    d = args.cache if args.cache is not None else default_cache_dir()
    limit = size_limit() if args.max_size is None else args.max_size * 1e6
    if args.max_size is not None and not args.max_size >= 0:
        raise InputError(f"--max-size must be a size >= 0 MB, got {args.max_size}")
    if not d.is_dir():
        print(f"cache {d}: no cache there (nothing stored yet)")
        return 0
    if args.prune:
        gone = prune(d, limit)
        freed = sum(e.size for e in gone) / 1e6
        what = f"{len(gone)} entr{'y' if len(gone) == 1 else 'ies'}"
        print(f"cache {d}: removed {what} ({freed:.1f} MB)")
    entries = cache_entries(d)
    total = sum(e.size for e in entries) / 1e6
    with _reader_may_leave():
        print(
            f"cache {d}: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}, "
            f"{total:.1f} MB (bound {limit / 1e6:g} MB; the least recently used go first)"
        )
        for e in entries:
            print(
                f"  {e.size / 1e6:9.1f} MB  last used {e.last_used:%Y-%m-%d %H:%M} UTC  "
                f"{e.part:24s} {e.path.name}"
            )
    return 0


#: the sub-commands as (name, help, description, adds its arguments, runs it), in the
#: order ``qifreport --help`` lists them
_COMMANDS: tuple[tuple[str, str, str, Callable, Callable], ...] = (
    (
        "inspect",
        "inspect one scan (the default)",
        "Inspect a free-state scan against its nominal.",
        _add_inspect_arguments,
        _run_inspect,
    ),
    (
        "pmi",
        "list the semantic PMI of a STEP file",
        "List the semantic PMI of a STEP file.",
        _add_pmi_arguments,
        _run_pmi,
    ),
    (
        "validate",
        "validate QIF files",
        "Validate QIF 3.0 files against the official schemas and the DMSC checks.",
        _add_validate_arguments,
        _run_validate,
    ),
    (
        "prepare",
        "store a nominal's prepared state in the cache",
        "Read a nominal and store its prepared state (tessellation, zones, "
        "operators, bands, bending basis, pose-search model) in the per-part cache, so "
        "every later inspection of the part loads it instead of building it.",
        _add_prepare_arguments,
        _run_prepare,
    ),
    (
        "plan",
        "write a STEP part's QIF measurement plan",
        "Write the QIF 3.0 measurement plan of a STEP part (<stem>_plan.qif): "
        "its features, datums, datum reference frames and one characteristic per PMI item, "
        "no results. --compare checks it item by item against another QIF document.",
        _add_plan_arguments,
        _run_plan,
    ),
    (
        "cache",
        "list or prune the per-part cache",
        "List the per-part cache's entries (size, last use), or prune it to a size: the "
        "entries used longest ago go first. Every new entry keeps the cache within "
        "$QIFREPORT_CACHE_MAX_MB (default 2048 MB) the same way.",
        _add_cache_arguments,
        _run_cache,
    ),
    (
        "batch",
        "inspect many scans of one part",
        "Inspect many scans of one part: per-scan QIF + PDF, a summary table, a "
        "QIF Statistics document and a trend report; resumable, in parallel.",
        _add_batch_arguments,
        _run_batch,
    ),
)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``qifreport`` parser: one sub-parser per entry of :data:`SUBCOMMANDS`, each with
    its arguments, or (``command`` given) only that one's: the others' arguments import
    the modules that declare them, which ``qifreport --help`` or ``qifreport pmi`` do not
    need (the measurement stack)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    ap = argparse.ArgumentParser(
        prog="qifreport",
        description="Virtual-fixturing inspection of a flexible part: nominal + free-state scan "
        "-> deviation field, statistics and a pass/fail decision. `qifreport NOMINAL SCAN` is "
        "short for `qifreport inspect NOMINAL SCAN`.",
    )
    ap.add_argument("--version", action="version", version=f"qifreport {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, short, description, add_arguments, run in _COMMANDS:
        p = sub.add_parser(name, parents=[common], help=short, description=description)
        if command is None or command == name:
            add_arguments(p)
        p.set_defaults(run=run)
    return ap


def _with_default_command(argv: list[str]) -> list[str]:
    """``qifreport NOMINAL SCAN ...`` is ``qifreport inspect NOMINAL SCAN ...``."""
    if argv and argv[0] not in SUBCOMMANDS and argv[0] not in ("-h", "--help", "--version"):
        return ["inspect", *argv]
    return argv


def _guard(fn: Callable[[], int], verbose: bool) -> int:
    """Run ``fn()``; map input errors and internal errors to exit 2 with one line."""
    try:
        return fn()
    except BrokenPipeError:  # the reader of stdout left (`qifreport pmi X | head`): quietly
        _stdout_gone()
        return EXIT_ERROR
    except Interrupted as exc:
        # the outputs were cleaned up on the way here; leave now, while the traceback still
        # holds the interrupted frames: freeing their arrays (or the interpreter's
        # finalisation) can crash in an extension caught mid-computation (SIGSEGV seen after
        # the one-line message under load)
        exc.leave()
    except Exception as exc:
        # a signal that a library turned into its own error (lxml's schema parser reports
        # a Ctrl-C as an XMLSchemaParseError) is still the signal
        leave_if_interrupted(exc)
        return _error_exit(exc, verbose)


def _stdout_gone() -> None:
    """stdout's reader has left: send what is left to /dev/null (the interpreter's last
    flush would otherwise print "Exception ignored ... BrokenPipeError")."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _error_exit(exc: Exception, verbose: bool) -> int:
    """The one line of an error, and its exit code (2)."""
    if isinstance(exc, InputError):
        print(f"qifreport: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(exc, (OSError, MemoryError)):
        print(f"qifreport: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR
    # a bug must never read as "part failed" (exit 1)
    log.debug("internal error", exc_info=True)
    print(
        f"qifreport: internal error: {type(exc).__name__}: {exc} (run with -v for the traceback)",
        file=sys.stderr,
    )
    if verbose:
        import traceback

        traceback.print_exc()
    return EXIT_ERROR


def main(argv: list[str] | None = None) -> int:
    """Console entry point; exits with 0 pass, 1 fail, 2 error, 3 not established."""
    argv = sys.argv[1:] if argv is None else list(argv)
    _catch_signals()
    try:
        argv = _with_default_command(argv)
        command = argv[0] if argv and argv[0] in SUBCOMMANDS else ""
        args = build_parser(command).parse_args(argv)
    except BaseException as exc:
        # a signal while the parser's modules load, or that a library turned into its own
        # error (NumPy's import reports a Ctrl-C during its C set-up as an ImportError)
        leave_if_interrupted(exc)
        raise
    verbose = bool(getattr(args, "verbose", False))
    level = logging.INFO if verbose and args.command != "validate" else logging.WARNING
    logging.basicConfig(level=level, format="qifreport: %(levelname)s: %(message)s")

    def run() -> int:
        raise_if_interrupted()  # a signal during the imports that a library swallowed
        return args.run(args)

    with _blas_threads():
        rc = _guard(run, verbose)
    try:  # what is still buffered: a reader that left takes none of it, and says nothing
        sys.stdout.flush()
    except BrokenPipeError:
        _stdout_gone()
    if Interrupted.received:
        # a signal that arrived after the work was done: its outputs stand (an error wrote
        # none), the exit says so
        Interrupted(Interrupted.received[0]).leave(written=rc != EXIT_ERROR)
    sys.exit(rc)


#: environment variables by which a user sets the BLAS thread count themselves
_BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _blas_threads() -> contextlib.AbstractContextManager:
    """One BLAS thread for the command, unless the user set a count (``OPENBLAS_NUM_THREADS``
    and the like).

    The inspection's linear algebra is many small products (3 x 3 rotations of 66k points,
    batched 3 x 3 solves) between k-d tree queries that already run on every core: a BLAS
    pool's threads, spinning after each product, take the cores from the tree's workers: on a
    busy machine the rigid stage and GB-CICP are several times faster with one thread, and no
    stage is slower on an idle one.
    """
    if any(os.environ.get(v) for v in _BLAS_ENV):
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


#: a signal waiting for worker threads to finish (see :func:`_raise_interrupted`)
_DEFERRED: list[int] = []


#: long-lived threads that never touch the main thread's arrays (tqdm's monitor, our RSS
#: sampler and DMSC runner)
_BYSTANDERS = ("tqdm_monitor", "rss-sampler", "qifreport-dmsc")


def _workers_alive() -> bool:
    """Whether a worker thread runs besides the main one: scipy's ``cKDTree.query`` with
    ``workers=-1`` runs its chunks in (daemon) threads on the caller's arrays."""
    main = threading.main_thread()
    return any(
        t is not main and t.is_alive() and not t.name.startswith(_BYSTANDERS)
        for t in threading.enumerate()
    )


def _raise_interrupted(signum: int, frame) -> None:
    """Raise :class:`Interrupted`, but not while worker threads still use the arrays the
    main thread's frames own: unwinding then frees them under the workers (SIGSEGV), nor
    inside ``os.fork`` (:func:`~qifreport.forked.in_fork`: its at-fork handlers print and
    drop an exception). The signal is kept and re-checked every 20 ms (SIGALRM) until
    then."""
    if signum == getattr(signal, "SIGALRM", None):
        if not _DEFERRED:
            return
        signum = _DEFERRED[0]
    if (_workers_alive() or in_fork()) and hasattr(signal, "setitimer"):
        if not _DEFERRED:
            _DEFERRED.append(signum)
        signal.setitimer(signal.ITIMER_REAL, 0.02)
        return
    _DEFERRED.clear()
    raise Interrupted(signum)


def _catch_signals() -> None:
    """Turn SIGINT, SIGTERM and SIGHUP into :class:`Interrupted` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGALRM"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), _raise_interrupted)
