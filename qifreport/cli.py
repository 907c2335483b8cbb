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

The arguments become typed options (:class:`qifreport.options.InspectOptions`,
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

from qifreport import __version__
from qifreport.errors import InputError, Interrupted, raise_if_interrupted
from qifreport.metrology.acceptance.decision import DECISION_RULES, DEFAULT_DECISION_RULE
from qifreport.metrology.acceptance.repeatability import KEEP_FRACTION
from qifreport.registration.deformable.methods import METHODS
from qifreport.restraint import DEFAULT_PAD_RADIUS

from .cache import default_cache_dir, part_state, sha256
from .console import summary
from .jsonio import json_default
from .options import InspectJob, InspectOptions
from .pipeline import EXIT_ERROR, run_job
from .profile import Profiler

__all__ = ["SUBCOMMANDS", "build_parser", "inspect_options", "main"]

log = logging.getLogger("qifreport")

#: the sub-commands; a first argument that is none of them (nor a top-level option) is the
#: nominal of the default ``inspect``
SUBCOMMANDS = ("inspect", "pmi", "plan", "validate", "prepare", "batch")


def add_inspect_options(ap: argparse.ArgumentParser, batch: bool) -> None:
    """The inspection options, shared by ``inspect`` and ``batch`` (``batch=True`` leaves
    out the single-scan ones: ``--json``, ``--serial``, ``--export-mesh``, ``--profile``)."""
    ap.add_argument(
        "--tolerance",
        type=float,
        default=None,
        metavar="MM",
        help="general profile tolerance half-width (|deviation| <= MM) on faces no "
        "PMI profile covers; required for mesh nominals; STEP default 0.5",
    )
    ap.add_argument(
        "--max-edge",
        type=float,
        default=None,
        metavar="MM",
        help="STEP: longest triangle edge of the tessellation (default diagonal/60)",
    )
    ap.add_argument(
        "--deflection",
        type=float,
        default=None,
        metavar="MM",
        help="STEP: chord deflection of the tessellation (default 0.001 x diagonal)",
    )
    ap.add_argument(
        "--solid",
        default=None,
        metavar="NAME|INDEX",
        help="STEP: the solid to inspect, by index (0, 1, ...) or name, in a file with several "
        "(qifreport pmi lists them); without it such a file is refused",
    )
    ap.add_argument(
        "--mesher",
        choices=("gmsh", "brepmesh"),
        default="gmsh",
        help="STEP: surface mesher (default gmsh: isotropic, welded, manifold; brepmesh: "
        "OpenCASCADE's BRepMesh with long-edge bisection)",
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=Path("."),
        metavar="DIR",
        help="output directory (default: current directory)",
    )
    ap.add_argument(
        "--scan-units",
        choices=["mm", "in", "m"],
        default=None,
        help="length unit of the scan file, converted to mm (default: mm; E57: m, "
        "the standard's unit)",
    )
    ap.add_argument(
        "--force",
        action="store_true",
        help="overwrite existing output files (default: refuse, exit 2)",
    )
    if not batch:
        ap.add_argument(
            "--json",
            action="store_true",
            help="write DIR/<nominal>.json with all statistics, verdict and regions",
        )
    ap.add_argument(
        "--no-qif",
        action="store_true",
        help="do not write DIR/<nominal>.qif (the QIF 3.0 results document)",
    )
    ap.add_argument(
        "--no-pdf",
        action="store_true",
        help="do not write DIR/<nominal>.pdf (the one-page conformance report)",
    )
    ap.add_argument(
        "--html",
        action="store_true",
        help="also write DIR/<nominal>.html: the deviation map in 3-D with a readout at the "
        "pointer (one self-contained file: any browser, offline)",
    )
    ap.add_argument(
        "--page",
        choices=["A4", "Letter"],
        default="A4",
        help="paper size of the PDF report (default A4)",
    )
    ap.add_argument("--author", metavar="NAME", help="QIF header: author of the report")
    ap.add_argument(
        "--organization",
        metavar="NAME",
        help="QIF header and traceability: inspecting organization",
    )
    ap.add_argument("--operator", metavar="NAME", help="QIF traceability: inspection operator")
    if not batch:
        ap.add_argument("--serial", metavar="SN", help="serial number of the inspected part")
        ap.add_argument(
            "--export-mesh",
            type=Path,
            metavar="PATH",
            help="write the registered nominal as PLY with a per-vertex 'deviation'",
        )
    ap.add_argument(
        "--min-fraction",
        type=float,
        default=0.95,
        help="area criterion: in-tolerance fraction of scored area, 0..1 (default 0.95)",
    )
    ap.add_argument(
        "--max-region-area",
        type=float,
        default=None,
        metavar="MM2",
        help="region criterion: largest out-of-tolerance region (default 25 mm^2)",
    )
    ap.add_argument(
        "--min-coverage",
        action="append",
        default=None,
        metavar="[TOL=]FRACTION",
        help="a toleranced surface is measured when at least FRACTION of its area was "
        "scored (default 0.7; below it: NOT MEASURED, never PASS); TOL=FRACTION sets one "
        "tolerance's own, TOL its key (T2), name or STEP id (#1452); repeatable",
    )
    ap.add_argument(
        "--max-gap-area",
        type=float,
        default=None,
        metavar="MM2",
        help="largest unmeasured patch on a toleranced surface (default 4 x "
        "--max-region-area = 100 mm^2); larger: NOT MEASURED",
    )
    ap.add_argument(
        "--decision-rule",
        choices=DECISION_RULES,
        default=DEFAULT_DECISION_RULE,
        help="how the measurement uncertainty U (k = 2) of each deviation enters the decision: "
        "iso14253 (default, ISO 14253-1: PASS when conformance is proven, FAIL when "
        "non-conformance is, otherwise NOT ESTABLISHED), guarded-acceptance (PASS only when "
        "proven), guarded-rejection (FAIL only when proven), simple (U not used)",
    )
    ap.add_argument(
        "--scanner-uncertainty",
        type=float,
        default=0.0,
        metavar="MM",
        help="the scanner's stated expanded uncertainty (k = 2), combined with each "
        "deviation's own from the scan's range noise (default 0: none stated)",
    )
    ap.add_argument(
        "--energy",
        choices=["auto", "hessian", "laplacian"],
        default="auto",
        help="bending energy of the virtual fixture (default auto: hessian for an "
        "open sheet, laplacian for a closed solid)",
    )
    ap.add_argument(
        "--edge-band",
        type=float,
        default=None,
        metavar="MM",
        help="do not score vertices within MM of a sharp crease (default: the "
        "deviation's neighbourhood radius; 0 scores everything)",
    )
    ap.add_argument(
        "--boundary-band",
        type=float,
        default=None,
        metavar="MM",
        help="vertices within MM of an open boundary of the nominal are not scored "
        "(default 1.5 median edges; 0 scores the rim)",
    )
    ap.add_argument(
        "--band-limit",
        type=float,
        default=None,
        metavar="MM",
        help="smoothing length of the first GB-CICP pass (default from part size)",
    )
    ap.add_argument(
        "--passes",
        type=int,
        default=3,
        help="GB-CICP passes: 1 = single pass, >=2 = band-limited scheme (default 3)",
    )
    ap.add_argument(
        "--prealign",
        choices=["auto", "always", "never"],
        default="auto",
        help="pose search from an arbitrary placement: auto (when the scan is not "
        "already in the part frame), always, or never (scan and part share a "
        "frame)",
    )
    ap.add_argument(
        "--fail-on-added-material",
        action="store_true",
        help="fail the part when a scan region larger than --max-region-area "
        "stands proud of the nominal beyond the threshold (default: report it)",
    )
    ap.add_argument(
        "--method",
        choices=list(METHODS),
        default="gbcicp",
        help="deformable method of the virtual fixture: gbcicp (default, the "
        "band-limited GB-CICP) or one of the paper's baselines nicp (optimal-step "
        "NICP), cpd (coherent point drift), rbffem (clamp-driven RBF); "
        "--band-limit and --passes apply to gbcicp only",
    )
    ap.add_argument(
        "--seeds",
        type=int,
        default=1,
        metavar="N",
        help="repeatability (paper Section 9.2): besides the full scan, inspect N "
        "random resamplings of it (each scan point kept with probability "
        f"{KEEP_FRACTION:g}, seeds 0..N-1, from the full scan's pose) and count as "
        "findings of the region criterion only the out-of-tolerance regions "
        "found in every run; the figures reported are the full scan's. Default 1: "
        "no resampling",
    )
    fixture = ap.add_mutually_exclusive_group()
    fixture.add_argument("--rigid-only", action="store_true", help="no virtual fixture (baseline)")
    fixture.add_argument(
        "--always-fixture",
        action="store_true",
        help="apply the virtual fixture even when the free state conforms (default: the "
        "free state is judged first and a part that conforms without restraint is not "
        "fixtured, ISO 10579); for comparing registration methods",
    )
    held = ap.add_argument_group(
        "restrained condition (ISO 10579, ASME Y14.5 restraint notes)",
        "hold the part at its clamps by its elastic model instead of the free virtual fixture",
    )
    held.add_argument(
        "--fixture",
        choices=("auto", "restrained", "free"),
        default="auto",
        help="restrained: the part held at its clamps (--clamps) by its elastic model, "
        "judged as held; free: the free state, then the virtual fixture (--method) when it "
        "does not conform; auto (default): restrained when clamps are given, else free",
    )
    held.add_argument(
        "--clamps",
        type=Path,
        default=None,
        metavar="FILE|pmi",
        help="the clamps and supports (CSV rows: name, x, y, z, directions, optional "
        "max_force_N; directions n (the surface normal) or axes from xyz; mm, part frame), "
        "or pmi: the STEP nominal's datum targets (the primary datum's hold along the "
        "normal, the others along their axis; force limits from --max-clamp-force)",
    )
    held.add_argument(
        "--material",
        default=None,
        metavar="NAME|E=..,nu=..",
        help="the part's material: steel, aluminium, pp, abs, pa6-gf30, or "
        "E=MPa,nu=..[,density=t/mm^3]; without it the held shape is solved (it does not "
        "depend on the modulus) but no clamp force is stated or checked",
    )
    held.add_argument(
        "--thickness",
        type=float,
        default=None,
        metavar="MM",
        help="wall thickness of a mesh nominal (an open sheet) for its elastic model",
    )
    held.add_argument(
        "--max-clamp-force",
        type=float,
        default=None,
        metavar="N",
        help="force limit of the clamps whose file states none: a part that needs more "
        "FAILs as not restrainable",
    )
    held.add_argument(
        "--pad-radius",
        type=float,
        default=DEFAULT_PAD_RADIUS,
        metavar="MM",
        help=f"contact radius of each clamp (default {DEFAULT_PAD_RADIUS:g})",
    )
    held.add_argument(
        "--gravity",
        default=None,
        metavar="DIR",
        help="the direction of gravity in the part frame while it is held (-z, +x, ... or "
        "x,y,z): the held part sags under its own weight (needs --material); the scan's own "
        "support is taken as loading it no more than the fixture does",
    )
    add_accept_option(ap)
    add_cache_options(ap)
    if not batch:
        ap.add_argument(
            "--profile",
            action="store_true",
            help="print wall time and peak resident memory per stage",
        )
        ap.add_argument(
            "--one-process",
            action="store_true",
            help="run on one CPU: no forked child processes (by default the free state, the "
            "scan's normals and the reports are worked on beside the main work: the same "
            "results, sooner, for the memory a child changes)",
        )
    ap.add_argument("--quiet", action="store_true", help="no progress bar")


def add_accept_option(ap: argparse.ArgumentParser) -> None:
    """``--accept-tolerance-as-read``."""
    ap.add_argument(
        "--accept-tolerance-as-read",
        action="store_true",
        help="inspect a STEP part even when a tolerance it states is implausible (wider than "
        "10 %% of the part's diagonal, e.g. a file stating mm values in metres); default: "
        "refuse it (exit 2)",
    )


def add_cache_options(ap: argparse.ArgumentParser) -> None:
    """``--cache DIR`` and ``--no-cache``."""
    ap.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="per-part cache of the nominal's prepared state (default "
        "$QIFREPORT_CACHE or the user cache directory; see `qifreport prepare`)",
    )
    ap.add_argument(
        "--no-cache", action="store_true", help="prepare the nominal afresh and store nothing"
    )


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
    job = InspectJob(
        nominal=args.nominal,
        scan=args.scan,
        out=args.out,
        options=inspect_options(args),
        serial=args.serial,
        json=args.json,
        export_mesh=args.export_mesh,
        force=args.force,
    )
    prof = Profiler().start() if args.profile else None
    outcome = run_job(job, progress=not args.quiet, prof=prof)
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
                f"QIF: {q['path']} written, NOT validated: the official QIF 3.0 "
                "schemas were not found (run `make install` with ../shared present, or set "
                "QIFREPORT_XSD_DIR)"
            )
    return outcome.exit_code


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
    from qifreport.step.report import pmi_rows, pmi_table
    from qifreport.step.solids import overlapping_pairs, solid_infos

    part = read_step(args.step)
    solids = solid_infos(part.shape, part.solid_names)
    overlaps = overlapping_pairs(part.shape, solids) if len(solids) > 1 else []
    clamps = None
    if args.clamps is not None:
        from .restraint import clamp_rows, read_clamps

        found, _ = read_clamps(args.clamps, args.step, args.max_clamp_force)
        clamps = clamp_rows(part, found)
    if args.json:
        print(
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
            )
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
    return 0


def _run_prepare(args: argparse.Namespace) -> int:
    if not args.nominal.is_file():
        raise InputError(f"nominal file not found: {args.nominal}")
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


def build_parser() -> argparse.ArgumentParser:
    """The ``qifreport`` parser: one sub-parser per entry of :data:`SUBCOMMANDS`."""
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

    p = sub.add_parser(
        "inspect",
        parents=[common],
        help="inspect one scan (the default)",
        description="Inspect a free-state scan against its nominal.",
    )
    p.add_argument(
        "nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh (STL, PLY, OBJ, OFF), mm"
    )
    p.add_argument(
        "scan", type=Path, help="scan point cloud (PLY, STL, OBJ, OFF, XYZ, CSV, NPY, E57)"
    )
    add_inspect_options(p, batch=False)
    p.add_argument("--version", action="version", version=f"qifreport {__version__}")
    p.set_defaults(run=_run_inspect)

    p = sub.add_parser(
        "pmi",
        parents=[common],
        help="list the semantic PMI of a STEP file",
        description="List the semantic PMI of a STEP file.",
    )
    p.add_argument("step", type=Path, help="STEP AP242 file")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument(
        "--clamps",
        type=Path,
        metavar="FILE|pmi",
        help="also list the clamps of this CSV, or of the datum targets (pmi), as --clamps of "
        "inspect: the face and datum feature each sits on",
    )
    p.add_argument(
        "--max-clamp-force",
        type=float,
        metavar="N",
        help="force limit of the clamps that state none, N",
    )
    p.set_defaults(run=_run_pmi)

    from .validate_command import add_arguments as add_validate_arguments

    p = sub.add_parser(
        "validate",
        parents=[common],
        help="validate QIF files",
        description="Validate QIF 3.0 files against the official schemas and the DMSC checks.",
    )
    add_validate_arguments(p)
    p.set_defaults(run=_run_validate)

    p = sub.add_parser(
        "prepare",
        parents=[common],
        help="store a nominal's prepared state in the cache",
        description="Read a nominal and store its prepared state (tessellation, zones, "
        "operators, bands, bending basis, pose-search model) in the per-part cache, so "
        "every later inspection of the part loads it instead of building it.",
    )
    p.add_argument("nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh, mm")
    for flag in ("--tolerance", "--max-edge", "--deflection", "--edge-band", "--boundary-band"):
        p.add_argument(
            flag,
            type=float,
            default=None,
            metavar="MM",
            help="as for the inspection (the cache key includes it)",
        )
    p.add_argument("--energy", choices=["auto", "hessian", "laplacian"], default="auto")
    p.add_argument(
        "--solid",
        default=None,
        metavar="NAME|INDEX",
        help="STEP: the solid to inspect, by index (0, 1, ...) or name, in a file with several "
        "(qifreport pmi lists them); without it such a file is refused",
    )
    p.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="cache directory (default $QIFREPORT_CACHE or the user cache dir)",
    )
    p.add_argument("--rebuild", action="store_true", help="ignore an existing entry")
    add_accept_option(p)
    p.set_defaults(run=_run_prepare)

    from .plan_command import add_arguments as add_plan_arguments

    p = sub.add_parser(
        "plan",
        parents=[common],
        help="write a STEP part's QIF measurement plan",
        description="Write the QIF 3.0 measurement plan of a STEP part (<stem>_plan.qif): "
        "its features, datums, datum reference frames and one characteristic per PMI item, "
        "no results. --compare checks it item by item against another QIF document.",
    )
    add_plan_arguments(p)
    p.set_defaults(run=_run_plan)

    from .batch import add_batch_arguments

    p = sub.add_parser(
        "batch",
        parents=[common],
        help="inspect many scans of one part",
        description="Inspect many scans of one part: per-scan QIF + PDF, a summary table, a "
        "QIF Statistics document and a trend report; resumable, in parallel.",
    )
    add_batch_arguments(p)
    add_inspect_options(p, batch=True)
    p.set_defaults(run=_run_batch)
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
    except Interrupted as exc:
        # the outputs were cleaned up on the way here; leave now, while the traceback still
        # holds the interrupted frames: freeing their arrays (or the interpreter's
        # finalisation) can crash in an extension caught mid-computation (SIGSEGV seen after
        # the one-line message under load)
        exc.leave()
    except InputError as exc:
        print(f"qifreport: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except (OSError, MemoryError) as exc:
        print(f"qifreport: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as exc:  # a bug must never read as "part failed" (exit 1)
        log.debug("internal error", exc_info=True)
        print(
            f"qifreport: internal error: {type(exc).__name__}: {exc} (run with -v for the "
            "traceback)",
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
        args = build_parser().parse_args(_with_default_command(argv))
    except Interrupted as exc:  # while the parser's modules load
        exc.leave()
    verbose = bool(getattr(args, "verbose", False))
    level = logging.INFO if verbose and args.command != "validate" else logging.WARNING
    logging.basicConfig(level=level, format="qifreport: %(levelname)s: %(message)s")

    def run() -> int:
        raise_if_interrupted()  # a signal during the imports that a library swallowed
        return args.run(args)

    with _blas_threads():
        rc = _guard(run, verbose)
    if Interrupted.received:
        # a signal that arrived after the work was done: leave without the finalisation
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
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
    main thread's frames own: unwinding then frees them under the workers (SIGSEGV). The
    signal is kept and re-checked every 20 ms (SIGALRM) until the workers are done."""
    if signum == getattr(signal, "SIGALRM", None):
        if not _DEFERRED:
            return
        signum = _DEFERRED[0]
    if _workers_alive() and hasattr(signal, "setitimer"):
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
