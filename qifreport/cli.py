"""``qifreport NOMINAL SCAN``: inspect a free-state scan against its nominal.

``NOMINAL`` is a STEP file (AP242 with semantic PMI: the tolerance zones come from the part
itself) or a mesh (STL/PLY/OBJ/OFF, with ``--tolerance``). Sub-commands:

* ``qifreport pmi PART.step [--json]`` lists the semantic PMI read from a STEP file.
* ``qifreport validate FILE.qif [...]`` checks QIF files against the official QIF 3.0 schemas
  (libxml2 and xmlschema, key/keyref included) and the DMSC XSLT checks.
* ``qifreport prepare PART`` stores the nominal's prepared state in the per-part cache
  (:mod:`qifreport.cache`); every inspection also uses the cache (``--cache DIR``, ``--no-cache``).
* ``qifreport batch PART SCANS... --out DIR`` inspects many scans of one part, in parallel on
  local processes or a Dask cluster, resumably (:mod:`qifreport.batch`).

Outputs (in ``--out``, all or none): ``<nominal>.qif``, the QIF 3.0 results document
(validated against the official schemas before it is published; never called valid when the
schemas are missing), ``<nominal>.pdf``, the one-page conformance report with the same
numbers, and with ``--json`` the summary ``<nominal>.json``
(``schemas/summary-1.schema.json``).

``--method`` chooses the virtual fixture's deformable method (GB-CICP or a paper baseline,
:mod:`qifreport.registration.methods`); ``--seeds N`` adds N resampled runs and keeps as findings of the
region criterion only the regions found in every run (:mod:`qifreport.metrology.repeatability`).

Exit codes: 0 the part passes, 1 the part fails, 2 the input cannot be inspected (one-line
error on stderr naming the problem, and no output file written), 3 not established.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from qifreport import __version__
from qifreport.metrology.inspection import InspectionParams, InspectionResult, inspect
from qifreport.metrology.repeatability import KEEP_FRACTION, resample_mask
from qifreport.metrology.repeatability import apply as apply_repeatability
from qifreport.registration.gbcicp import GBCICPParams
from qifreport.registration.methods import METHODS
from qifreport.registration.pointcloud import load_scan

from .atomic_io import atomic_write_many
from .cache import NominalOptions, default_cache_dir, part_state, sha256
from .errors import InputError
from .nominal import Nominal, load_nominal  # noqa: F401  (re-exported)
from .profile import Profiler
from .summary import SUMMARY_SCHEMA_VERSION

log = logging.getLogger("qifreport")

EXIT_PASS, EXIT_FAIL, EXIT_ERROR, EXIT_NOT_ESTABLISHED = 0, 1, 2, 3


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="qifreport",
        description="Virtual-fixturing inspection of a flexible part: nominal + free-state scan "
        "-> deviation field, statistics and a pass/fail decision.",
    )
    ap.add_argument("nominal", type=Path,
                    help="nominal: STEP (AP242 with PMI) or mesh (STL, PLY, OBJ, OFF), mm")
    ap.add_argument("scan", type=Path,
                    help="scan point cloud (PLY, STL, OBJ, OFF, XYZ, CSV, NPY, E57)")
    add_options(ap, batch=False)
    return ap


def add_options(ap: argparse.ArgumentParser, batch: bool) -> None:
    """The inspection options, shared by ``qifreport NOMINAL SCAN`` and ``qifreport batch``
    (``batch=True`` leaves out the single-scan ones: ``--json``, ``--serial``,
    ``--export-mesh``, ``--profile``)."""
    ap.add_argument("--tolerance", type=float, default=None, metavar="MM",
                    help="general profile tolerance half-width (|deviation| <= MM) on faces no "
                    "PMI profile covers; required for mesh nominals; STEP default 0.5")
    ap.add_argument("--max-edge", type=float, default=None, metavar="MM",
                    help="STEP: longest triangle edge of the tessellation (default diagonal/60)")
    ap.add_argument("--deflection", type=float, default=None, metavar="MM",
                    help="STEP: chord deflection of the tessellation (default 0.001 x diagonal)")
    ap.add_argument("--out", type=Path, default=Path("."), metavar="DIR",
                    help="output directory (default: current directory)")
    ap.add_argument("--scan-units", choices=["mm", "in", "m"], default=None,
                    help="length unit of the scan file, converted to mm (default: mm; E57: m, "
                    "the standard's unit)")
    ap.add_argument("--force", action="store_true",
                    help="overwrite existing output files (default: refuse, exit 2)")
    if not batch:
        ap.add_argument("--json", action="store_true",
                        help="write DIR/<nominal>.json with all statistics, verdict and regions")
    ap.add_argument("--no-qif", action="store_true",
                    help="do not write DIR/<nominal>.qif (the QIF 3.0 results document)")
    ap.add_argument("--no-pdf", action="store_true",
                    help="do not write DIR/<nominal>.pdf (the one-page conformance report)")
    ap.add_argument("--page", choices=["A4", "Letter"], default="A4",
                    help="paper size of the PDF report (default A4)")
    ap.add_argument("--author", metavar="NAME", help="QIF header: author of the report")
    ap.add_argument("--organization", metavar="NAME",
                    help="QIF header and traceability: inspecting organization")
    ap.add_argument("--operator", metavar="NAME", help="QIF traceability: inspection operator")
    if not batch:
        ap.add_argument("--serial", metavar="SN", help="serial number of the inspected part")
    if not batch:
        ap.add_argument("--export-mesh", type=Path, metavar="PATH",
                        help="write the registered nominal as PLY with a per-vertex 'deviation'")
    ap.add_argument("--min-fraction", type=float, default=0.95,
                    help="area criterion: in-tolerance fraction of scored area, 0..1 "
                    "(default 0.95)")
    ap.add_argument("--max-region-area", type=float, default=None, metavar="MM2",
                    help="region criterion: largest out-of-tolerance region (default 25 mm^2)")
    ap.add_argument("--energy", choices=["auto", "hessian", "laplacian"], default="auto",
                    help="bending energy of the virtual fixture (default auto: hessian for an "
                    "open sheet, laplacian for a closed solid)")
    ap.add_argument("--edge-band", type=float, default=None, metavar="MM",
                    help="do not score vertices within MM of a sharp crease (default: the "
                    "deviation's neighbourhood radius; 0 scores everything)")
    ap.add_argument("--boundary-band", type=float, default=None, metavar="MM",
                    help="vertices within MM of an open boundary of the nominal are not scored "
                    "(default 1.5 median edges; 0 scores the rim)")
    ap.add_argument("--band-limit", type=float, default=None, metavar="MM",
                    help="smoothing length of the first GB-CICP pass (default from part size)")
    ap.add_argument("--passes", type=int, default=3,
                    help="GB-CICP passes: 1 = single pass, >=2 = band-limited scheme (default 3)")
    ap.add_argument("--prealign", choices=["auto", "always", "never"], default="auto",
                    help="pose search from an arbitrary placement: auto (when the scan is not "
                    "already in the part frame), always, or never (scan and part share a "
                    "frame)")
    ap.add_argument("--fail-on-added-material", action="store_true",
                    help="fail the part when a scan region larger than --max-region-area "
                    "stands proud of the nominal beyond the threshold (default: report it)")
    ap.add_argument("--method", choices=list(METHODS), default="gbcicp",
                    help="deformable method of the virtual fixture: gbcicp (default, the "
                    "band-limited GB-CICP) or one of the paper's baselines nicp (optimal-step "
                    "NICP), cpd (coherent point drift), rbffem (clamp-driven RBF); "
                    "--band-limit and --passes apply to gbcicp only")
    ap.add_argument("--seeds", type=int, default=1, metavar="N",
                    help="repeatability (paper Section 9.2): besides the full scan, inspect N "
                    "random resamplings of it (each scan point kept with probability "
                    f"{KEEP_FRACTION:g}, seeds 0..N-1, from the full scan's pose) and count as "
                    "findings of the region criterion only the out-of-tolerance regions "
                    "found in every run; the figures reported are the full scan's. Default 1: "
                    "no resampling")
    ap.add_argument("--rigid-only", action="store_true", help="no virtual fixture (baseline)")
    ap.add_argument("--cache", type=Path, default=None, metavar="DIR",
                    help="per-part cache of the nominal's prepared state (default "
                    "$QIFREPORT_CACHE or the user cache directory; see `qifreport prepare`)")
    ap.add_argument("--no-cache", action="store_true",
                    help="prepare the nominal afresh and store nothing")
    if not batch:
        ap.add_argument("--profile", action="store_true",
                        help="print wall time and peak resident memory per stage")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    ap.add_argument("--version", action="version", version=f"qifreport {__version__}")


def write_ply_with_scalar(
    path: Path, V: np.ndarray, F: np.ndarray, name: str, s: np.ndarray
) -> None:
    """Binary little-endian PLY of a triangle mesh with one float per-vertex property."""
    vert = np.empty(len(V), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), (name, "<f4")])
    vert["x"], vert["y"], vert["z"] = V[:, 0], V[:, 1], V[:, 2]
    vert[name] = s
    face = np.empty(len(F), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, F
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment qifreport registered nominal\n"
        f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"property float {name}\nelement face {len(F)}\nproperty list uchar int vertex_indices\n"
        "end_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())


def summary(res: InspectionResult) -> str:
    """A short human-readable summary of the inspection."""
    a, s = res.acceptance, res.vertex_stats
    lines = [
        f"verdict: {res.verdict}",
        f"registration: {_fixture_text(res)}",
        f"deviation (area-weighted, {s.n} scored vertices): RMS {s.rms:.3f}  max {s.max_abs:.3f}"
        f"  P95 {s.p95:.3f}  P99.9 {s.p999:.3f}  mean {s.mean:+.3f} mm",
        f"area criterion: {100 * a.in_tolerance_fraction:.2f} % in tolerance "
        f"(>= {100 * a.min_fraction:.0f} %) {'ok' if a.area_ok else 'FAILED'}",
        f"region criterion: largest out-of-tolerance region {a.largest_region_area:.1f} mm^2 "
        f"(<= {a.max_region_area:g} mm^2) {'ok' if a.region_ok else 'FAILED'}; "
        f"{len(a.regions)} region(s)",
        f"coverage: {100 * a.coverage:.1f} % of the nominal area scored"
        + (f" ({res.edge_excluded_area:.0f} mm^2 along sharp creases not scored)"
           if res.edge_excluded_area > 0 else ""),
    ]
    if res.prealign is not None and res.prealign.method != "identity":
        lines.append(res.prealign.summary())
    for r in a.regions[:5]:
        c = r.centroid
        lines.append(
            f"  region {r.area:7.1f} mm^2  peak {r.peak:+.3f} mm"
            f"  at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f})"
        )
    lines.append("tolerances (each toleranced surface on its own faces):")
    for z in res.zones:
        za, zs = z.acceptance, z.stats
        lines.append(
            f"  {z.zone.key:8s} {'PASS' if za.passed else 'FAIL'}  {z.zone.describe()}: "
            f"{100 * za.in_tolerance_fraction:.1f} % in band, largest region "
            f"{za.largest_region_area:.1f} mm^2, max |dev| {zs.max_abs:.3f} mm"
            + ("" if z.fixtured else " (free state)")
        )
    if res.not_evaluated:
        lines.append(f"  {len(res.not_evaluated)} PMI item(s) listed, not scored "
                     "(see the JSON 'not_evaluated')")
    h = res.hygiene
    if h is not None and (h.boundary_edges or h.non_manifold_edges or h.degenerate_faces
                          or h.duplicate_faces):
        lines.append(f"nominal: {h.describe()}")
    if res.added is not None:
        a = res.added
        lines.append(
            f"added material (data-referenced, scan points): P99.9 signed "
            f"{a.p999_signed:+.3f} mm, {100 * a.frac_above:.3f} % beyond "
            f"+{a.threshold:g} mm; {a.describe()}"
            + ("" if a.passed else " FAILED") + ("" if a.fail_on or not a.found
                                                 else " (reported, not judged)"))
    if res.repeatability is not None:
        lines.append(res.repeatability.describe())
    lines += [f"warning: {w}" for w in res.trust_warnings()]
    return "\n".join(lines)


def _fixture_text(res: InspectionResult) -> str:
    """How the virtual fixture was made, for the summary."""
    from qifreport.metrology.inspection import method_label

    if res.fit is None:
        return "rigid ICP only (no virtual fixture)"
    fit = res.fit
    return (f"rigid ICP + virtual fixture {method_label(fit.method)} ({fit.iterations} "
            f"iterations, robust residual {fit.scale:.3f} mm)")


def _check_args_common(args: argparse.Namespace) -> None:
    """Checks of the options shared with ``qifreport batch``."""
    if not (np.isfinite(args.min_fraction) and 0.0 < args.min_fraction <= 1.0):
        raise InputError(f"--min-fraction must be a fraction in (0, 1], got {args.min_fraction}"
                         " (0.95 means 95 %)")
    if args.max_region_area is not None and not (np.isfinite(args.max_region_area)
                                                 and args.max_region_area >= 0):
        raise InputError(f"--max-region-area must be an area >= 0 mm^2, got "
                         f"{args.max_region_area}")
    if args.seeds < 1:
        raise InputError(f"--seeds must be a number of runs >= 1, got {args.seeds}")


def _check_args(args: argparse.Namespace) -> None:
    _check_args_common(args)
    for name in ("nominal", "scan"):
        path = getattr(args, name)
        if not path.is_file():
            raise InputError(f"{name} file not found: {path}")


def qif_writer(tree, state: dict):
    """A writer ``write(tmp)`` of the QIF document that validates it (libxml2) before it can
    be published, recording the outcome in ``state`` (the JSON summary's ``qif`` block).

    When the official schemas cannot be found the file is written and reported *not
    validated* (``valid: None``) with how to provide them; a document the schema rejects is a
    bug of qifreport: the writer raises, nothing is published (exit 2).
    """
    from qifreport.qif.validate import SchemasUnavailable, schema_dir, validate_lxml
    from qifreport.qif.writer import write_qif

    state.update(valid=None, validated_with=[], message="")

    def write(tmp: Path) -> None:
        write_qif(tmp, tree)
        try:
            xsd = schema_dir()
        except SchemasUnavailable as exc:
            state["message"] = f"not validated: {exc}"
            return
        errors = [f for f in validate_lxml(tmp) if f.severity == "error"]
        if errors:
            first = errors[0]
            raise RuntimeError(f"the QIF document qifreport wrote is not valid against {xsd} "
                               f"(line {first.line}: {first.message}); nothing written")
        state.update(valid=True, validated_with=["lxml"],
                     message=f"valid against the QIF 3.0 schemas in {xsd}")

    return write


def _stage(prof: Profiler | None, name: str):
    """``prof.stage(name)``, or a no-op context without ``--profile``."""
    return prof.stage(name) if prof is not None else contextlib.nullcontext()


def output_paths(args: argparse.Namespace, stem: str | None = None) -> dict[str, Path]:
    """The files this run will write: ``qif``, ``pdf``, ``json``, ``mesh`` (those asked for),
    named ``<stem>.*`` in ``args.out`` (default stem: the nominal's)."""
    stem = args.nominal.stem if stem is None else stem
    out = {"qif": None if args.no_qif else args.out / f"{stem}.qif",
           "pdf": None if args.no_pdf else args.out / f"{stem}.pdf",
           "json": args.out / f"{stem}.json" if args.json else None,
           "mesh": args.export_mesh}
    return {k: v for k, v in out.items() if v is not None}


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse before any work: an output that exists (without ``--force``) or a directory
    that cannot be written."""
    for path in output_paths(args).values():
        if path.exists() and not args.force:
            raise InputError(f"output exists: {path} (use --force to overwrite)")
        if path.is_dir():
            raise InputError(f"output path is a directory: {path}")
        parent = path.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"output directory not writable: {parent}")


def resampled_runs(res: InspectionResult, params: InspectionParams, nom: Nominal,
                   seeds: int, bar=None, prepared=None) -> None:
    """Inspect ``seeds`` resamplings of the scan and keep only the persistent regions of
    ``res`` (:mod:`qifreport.metrology.repeatability`; ``res`` is changed in place).

    Resampling ``k`` keeps each point of the scan with probability
    :data:`qifreport.metrology.repeatability.KEEP_FRACTION` (seed ``k``). It starts from ``res``'s pose:
    the scan already moved into the nominal frame, no pose search (``prealign="never"``).
    """
    t0 = time.perf_counter()
    p = replace(params, prealign="never")
    runs = []
    for k in range(seeds):
        if bar is not None:
            bar.set_description(f"resampling {k + 1}/{seeds}")
        keep = resample_mask(len(res.P), k, KEEP_FRACTION)
        runs.append(inspect(res.V, res.F, res.P[keep], p,
                            progress=None if bar is None else bar.update,
                            face_id=nom.face_id, zones=nom.zones,
                            not_evaluated=nom.not_evaluated, basis=res.basis,
                            prepared=prepared))
    seconds = time.perf_counter() - t0
    apply_repeatability(res, runs, KEEP_FRACTION, seconds=seconds)
    res.timings["repeatability"] = seconds


def output_writers(res: InspectionResult, nom: Nominal, args: argparse.Namespace,
                   paths: dict[str, Path], digests: dict[str, str], started: datetime,
                   finished: datetime) -> tuple[list, dict | None]:
    """The writers ``[(path, write(tmp))]`` of one inspection's outputs, in writing order
    (the QIF first: the JSON summary reports its validation), and the QIF's state block.

    ``args`` gives the names recorded in the outputs (``nominal``, ``scan``), the header
    fields (``author``, ``organization``, ``operator``, ``serial``) and the choices
    (``no_qif``, ``no_pdf``, ``json``, ``page``); ``paths`` is :func:`output_paths`.
    """
    F = nom.F
    outputs: list = []
    qif_state = None
    prov = None
    if not (args.no_qif and args.no_pdf):
        from qifreport.qif.writer import Provenance

        prov = Provenance(
            part_name=args.nominal.stem, nominal_path=str(args.nominal),
            scan_path=str(args.scan), nominal_sha256=digests["nominal"],
            scan_sha256=digests["scan"], started=started, finished=finished,
            datums=nom.datums, nominal_info=nom.info, author=args.author,
            organization=args.organization, operator=args.operator,
            serial_number=args.serial,
        )
    if not args.no_qif:
        from qifreport.qif.writer import build_qif

        qif_state = {"path": str(paths["qif"])}
        outputs.append((paths["qif"], qif_writer(build_qif(res, prov), qif_state)))
    if not args.no_pdf:
        from qifreport.reports.pdf import write_pdf

        qif_name = paths["qif"].name if "qif" in paths else ""
        outputs.append((paths["pdf"], lambda p: write_pdf(p, res, prov, page=args.page,
                                                      qif_name=qif_name)))
    if args.json:
        doc = res.to_dict()
        doc = {"schema": SUMMARY_SCHEMA_VERSION, **doc}
        doc["software"] = {"name": "qifreport", "version": __version__}
        doc["nominal"] = nom.info
        doc["inputs"] = {
            "nominal": {"path": str(args.nominal), "sha256": digests["nominal"]},
            "scan": {"path": str(args.scan), "sha256": digests["scan"]},
        }

        def write_json(p: Path) -> None:  # runs after the QIF writer: its state is known
            if qif_state is not None:
                doc["qif"] = qif_state
            p.write_text(json.dumps(_finite(doc), indent=2, default=_json_default,
                                    allow_nan=False))

        outputs.append((paths["json"], write_json))
    if "mesh" in paths:
        outputs.append((paths["mesh"], lambda p: write_ply_with_scalar(
            p, res.V_registered, F, "deviation", res.deviation)))
    return outputs, qif_state


def inspection_params(args: argparse.Namespace) -> InspectionParams:
    """The :class:`InspectionParams` of the command line."""
    g = GBCICPParams(passes=max(1, args.passes), band_limit=args.band_limit)
    params = InspectionParams(
        tolerance=args.tolerance, min_fraction=args.min_fraction, energy=args.energy,
        edge_band=args.edge_band, boundary_band=args.boundary_band,
        rigid_only=args.rigid_only, prealign=args.prealign,
        fail_on_added_material=args.fail_on_added_material, method=args.method, gbcicp=g,
    )
    if args.max_region_area is not None:
        params.max_region_area = args.max_region_area
    return params


def nominal_options(args: argparse.Namespace) -> NominalOptions:
    """How the command line reads the nominal."""
    if args.tolerance is not None and not (np.isfinite(args.tolerance) and args.tolerance > 0):
        raise InputError(f"--tolerance must be a positive length in mm, got {args.tolerance}")
    return NominalOptions(args.tolerance, args.max_edge, args.deflection)


def cache_dir(args: argparse.Namespace) -> Path | None:
    """The cache directory of the command line (None with ``--no-cache``)."""
    if getattr(args, "no_cache", False):
        return None
    return args.cache if args.cache is not None else default_cache_dir()


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    _check_outputs(args)
    started = datetime.now(timezone.utc)
    prof = Profiler().start() if args.profile else None
    params = inspection_params(args)
    with _stage(prof, "load scan"):  # first: a bad scan is reported before any heavy work
        P = load_scan(args.scan, units=args.scan_units)
    with _stage(prof, "prepare part (cache)"):
        state, cache = part_state(args.nominal, nominal_options(args), params,
                                  cache_dir(args))
    log.info("%s", cache.describe())
    nom = state.nominal
    V, F = nom.V, nom.F

    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(desc="virtual fixturing", unit="it", file=sys.stderr, leave=False)
    t_inspect = time.perf_counter()
    try:
        res = inspect(V, F, P, params, progress=None if bar is None else bar.update,
                      scan_units=args.scan_units, face_id=nom.face_id, zones=nom.zones,
                      not_evaluated=nom.not_evaluated, prepared=state.prepared)
        if args.seeds > 1:
            with _stage(prof, f"repeatability ({args.seeds} resamplings)"):
                resampled_runs(res, params, nom, args.seeds, bar, prepared=state.prepared)
    finally:
        if bar is not None:
            bar.close()
    if prof is not None:
        prof.add_stages(t_inspect, res.timings, prefix="inspect: ")
    finished = datetime.now(timezone.utc)
    digests = {"nominal": state.nominal_sha256, "scan": sha256(args.scan)}

    paths = output_paths(args)
    outputs, qif_state = output_writers(res, nom, args, paths, digests, started, finished)
    # all outputs or none: a failure in any writer publishes nothing
    with _stage(prof, "write outputs"):
        atomic_write_many(outputs)
    print(summary(res))
    if prof is not None:
        prof.stop()
        print("profile (wall time and peak resident memory per stage):")
        print(prof.table())
    if qif_state is not None:
        if qif_state["valid"]:
            print(f"QIF: {qif_state['path']} ({qif_state['message']})")
        else:
            print(f"QIF: {qif_state['path']} written, NOT validated: the official QIF 3.0 "
                  "schemas were not found (run `make install` with ../shared present, or set "
                  "QIFREPORT_XSD_DIR)")
    return {"PASS": EXIT_PASS, "FAIL": EXIT_FAIL,
            "NOT ESTABLISHED": EXIT_NOT_ESTABLISHED}[res.verdict]


def _finite(o):
    """The document with every non-finite float replaced by None (strict JSON)."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)


def _pmi_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="qifreport pmi",
                                 description="List the semantic PMI of a STEP file.")
    ap.add_argument("step", type=Path, help="STEP AP242 file")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = ap.parse_args(argv)
    from qifreport.step.reader import read_step
    from qifreport.step.report import pmi_rows, pmi_table

    part = read_step(args.step)
    if args.json:
        print(json.dumps({"file": str(args.step), "sha256": sha256(args.step),
                          "length_unit": part.pmi.length_unit, "faces": len(part.faces),
                          "items": pmi_rows(part)}, indent=2, default=_json_default))
    else:
        print(pmi_table(part))
    return 0


def _prepare_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="qifreport prepare",
        description="Read a nominal and store its prepared state (tessellation, zones, "
        "operators, bands, bending basis, pose-search model) in the per-part cache, so "
        "every later inspection of the part loads it instead of building it.")
    ap.add_argument("nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh, mm")
    for flag in ("--tolerance", "--max-edge", "--deflection", "--edge-band",
                 "--boundary-band"):
        ap.add_argument(flag, type=float, default=None, metavar="MM",
                        help="as for the inspection (the cache key includes it)")
    ap.add_argument("--energy", choices=["auto", "hessian", "laplacian"], default="auto")
    ap.add_argument("--cache", type=Path, default=None, metavar="DIR",
                    help="cache directory (default $QIFREPORT_CACHE or the user cache dir)")
    ap.add_argument("--rebuild", action="store_true", help="ignore an existing entry")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    if not args.nominal.is_file():
        raise InputError(f"nominal file not found: {args.nominal}")
    defaults = _parser().parse_args([str(args.nominal), "-"])
    for k in ("tolerance", "max_edge", "deflection", "edge_band", "boundary_band", "energy",
              "cache"):
        setattr(defaults, k, getattr(args, k))
    state, outcome = part_state(args.nominal, nominal_options(defaults),
                                inspection_params(defaults), cache_dir(defaults),
                                rebuild=args.rebuild)
    print(outcome.describe())
    if outcome.timings:
        print("  " + ", ".join(f"{k} {v:.2f} s" for k, v in outcome.timings.items()))
    n = state.nominal
    print(f"  {len(n.V)} vertices, {len(n.F)} triangles, {len(n.zones)} zone(s), "
          f"key {state.key[:16]}")
    return 0


def _guard(fn, verbose: bool) -> int:
    """Run ``fn()``; map input errors and internal errors to exit 2 with one line."""
    try:
        return fn()
    except InputError as exc:
        print(f"qifreport: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except (OSError, MemoryError) as exc:
        print(f"qifreport: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as exc:  # a bug must never read as "part failed" (exit 1)
        log.debug("internal error", exc_info=True)
        print(f"qifreport: internal error: {type(exc).__name__}: {exc} (run with -v for the "
              "traceback)", file=sys.stderr)
        if verbose:
            import traceback

            traceback.print_exc()
        return EXIT_ERROR


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns (and exits with) 0 pass, 1 fail, 2 error, 3 not established."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "validate":
        from qifreport.qif.validate import validate_main

        logging.basicConfig(level=logging.WARNING, format="qifreport: %(levelname)s: %(message)s")
        sys.exit(validate_main(argv[1:]))
    if argv and argv[0] == "batch":
        from .batch import batch_main

        sys.exit(_guard(lambda: batch_main(argv[1:]), verbose="-v" in argv))
    if argv and argv[0] == "prepare":
        logging.basicConfig(level=logging.INFO if "-v" in argv else logging.WARNING,
                            format="qifreport: %(levelname)s: %(message)s")
        sys.exit(_guard(lambda: _prepare_main(argv[1:]), verbose="-v" in argv))
    if argv and argv[0] == "pmi":
        logging.basicConfig(level=logging.WARNING, format="qifreport: %(levelname)s: %(message)s")
        sys.exit(_guard(lambda: _pmi_main(argv[1:]), verbose="-v" in argv))
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="qifreport: %(levelname)s: %(message)s",
    )
    sys.exit(_guard(lambda: run(args), args.verbose))
