"""The command line's options, as one short function per group.

The inspection options (:func:`add_inspect_options`, shared by ``inspect`` and ``batch``) are
added group by group, in the order ``--help`` lists them: the nominal and its tessellation,
the scan's units and the output directory, the outputs, the acceptance criteria, the prepared
state's scoring bands, the registration, the restrained condition, the tolerance check, the
cache, and how the command runs. The ``pmi`` and ``prepare`` sub-commands' arguments are
here too; ``validate``, ``plan`` and ``batch`` keep theirs beside their commands. Nothing
here parses: :mod:`qifreport.cli` turns the parsed arguments into typed options.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from qifreport import __version__

__all__ = [
    "add_accept_option",
    "add_cache_options",
    "add_criteria_options",
    "add_file_options",
    "add_inspect_arguments",
    "add_inspect_options",
    "add_nominal_options",
    "add_output_options",
    "add_pmi_arguments",
    "add_prepare_arguments",
    "add_registration_options",
    "add_restraint_options",
    "add_run_options",
    "add_scoring_band_options",
    "add_solid_option",
]

#: the bending energies of the virtual fixture
ENERGIES = ["auto", "hessian", "laplacian"]


def add_inspect_options(ap: argparse.ArgumentParser, batch: bool) -> None:
    """The inspection options, shared by ``inspect`` and ``batch`` (``batch=True`` leaves
    out the single-scan ones: ``--json``, ``--serial``, ``--export-mesh``, ``--profile``)."""
    add_nominal_options(ap)
    add_file_options(ap)
    add_output_options(ap, batch)
    add_criteria_options(ap)
    add_scoring_band_options(ap)
    add_registration_options(ap)
    add_restraint_options(ap)
    add_accept_option(ap)
    add_cache_options(ap)
    add_run_options(ap, batch)


def add_nominal_options(ap: argparse.ArgumentParser) -> None:
    """The nominal: the general tolerance, the tessellation of a STEP part, its solid."""
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
    add_solid_option(ap)
    ap.add_argument(
        "--mesher",
        choices=("gmsh", "brepmesh"),
        default="gmsh",
        help="STEP: surface mesher (default gmsh: isotropic, welded, manifold; brepmesh: "
        "OpenCASCADE's BRepMesh with long-edge bisection)",
    )


def add_solid_option(ap: argparse.ArgumentParser) -> None:
    """``--solid``: which solid of a STEP file with several."""
    ap.add_argument(
        "--solid",
        default=None,
        metavar="NAME|INDEX",
        help="STEP: the solid to inspect, by index (0, 1, ...) or name, in a file with several "
        "(qifreport pmi lists them); without it such a file is refused",
    )


def add_file_options(ap: argparse.ArgumentParser) -> None:
    """The output directory, the scan's length unit, and whether outputs are overwritten."""
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


def add_output_options(ap: argparse.ArgumentParser, batch: bool) -> None:
    """Which outputs are written, and the names in their headers (``batch=True``: no
    ``--json``, ``--serial`` or ``--export-mesh``)."""
    if not batch:
        ap.add_argument(
            "--json",
            nargs="?",
            const=True,
            default=False,
            choices=[True, "-"],
            metavar="-",
            help="write DIR/<nominal>.json with all statistics, verdict and regions; "
            "--json - prints it to stdout instead of the summary (the files are written as "
            "usual)",
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
    ap.add_argument(
        "--part-number",
        metavar="PN",
        help="the part's number (default: the STEP product's id)",
    )
    ap.add_argument(
        "--revision",
        metavar="REV",
        help="the drawing's revision (default: the STEP product's version)",
    )
    if not batch:
        ap.add_argument("--serial", metavar="SN", help="serial number of the inspected part")
        ap.add_argument(
            "--temperature",
            type=float,
            metavar="C",
            help="the part's temperature while scanned, deg C (in every output; with the "
            "scanner profile's expansion coefficient it enters the uncertainty budgets)",
        )
        ap.add_argument(
            "--name",
            metavar="TEMPLATE",
            default="{part}[_{serial}]",
            help="the output files' name: {part} the nominal's stem, {serial}, {scan} the "
            "scan's stem; [...] is left out when a field in it is empty (default "
            "'{part}[_{serial}]': panel.qif, or panel_SN-0042.qif with --serial SN-0042)",
        )
        ap.add_argument(
            "--export-mesh",
            type=Path,
            metavar="PATH",
            help="write the registered nominal as PLY with a per-vertex 'deviation'",
        )


def add_criteria_options(ap: argparse.ArgumentParser) -> None:
    """The acceptance criteria (area, region, coverage) and the decision rule with the
    measurement uncertainty."""
    from qifreport.metrology.acceptance.decision import DECISION_RULES, DEFAULT_DECISION_RULE

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
        "--scanner",
        type=Path,
        default=None,
        metavar="FILE",
        help="the scanner's acceptance figures (JSON or TOML: name, probing_form, "
        "probing_size, length_a, length_k, optional flatness, temperature, cte; ISO 10360-8 / "
        "VDI/VDE 2634-2), the instrument terms of each characteristic's uncertainty budget "
        "(default: the documented default scanner class, said in every output)",
    )


def add_scoring_band_options(ap: argparse.ArgumentParser) -> None:
    """The prepared state's bending energy and the bands left unscored (creases, rim); the
    cache key includes them."""
    ap.add_argument(
        "--energy",
        choices=ENERGIES,
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


def add_registration_options(ap: argparse.ArgumentParser) -> None:
    """The registration: the GB-CICP scheme, the pose search, the deformable method, the
    repeatability seeds and whether the virtual fixture applies (with the added-material
    criterion, which ``--help`` lists among them)."""
    from qifreport.metrology.acceptance.repeatability import KEEP_FRACTION
    from qifreport.registration.deformable.methods import METHODS

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
        default=12,
        help="GB-CICP passes at most: 1 = single pass, >=2 = band-limited scheme, its "
        "defect hold-outs grown until they settle (default 12)",
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
    fixture.add_argument(
        "--rigid-only",
        action="store_true",
        help="the free state only, no virtual fixture (the same as --restraint free)",
    )
    fixture.add_argument(
        "--always-fixture",
        action="store_true",
        help="with a virtual restraint, apply the virtual fixture even when the free state "
        "conforms (default: the free state is judged first and a part that conforms "
        "without restraint is not fixtured, ISO 10579); for comparing registration methods",
    )


def add_restraint_options(ap: argparse.ArgumentParser) -> None:
    """The restrained condition: clamps, material and loads (a group of its own in
    ``--help``)."""
    from qifreport.metrology.params import RESTRAINT_CONDITIONS
    from qifreport.registration.restraint.fixture_load import DEFAULT_MAX_FORCE

    from .restraint import DEFAULT_PAD_RADIUS

    held = ap.add_argument_group(
        "restrained condition (ISO 10579, ASME Y14.5 restraint notes)",
        "hold the part at its clamps by its elastic model instead of the free virtual fixture",
    )
    held.add_argument(
        "--restraint",
        choices=RESTRAINT_CONDITIONS,
        default=None,
        help="the condition the part is judged in, stated by the operator: free (the free "
        "state only, no fixture), virtual (the free state first, then the virtual fixture "
        "--method when it does not conform) or clamps (held at --clamps by its elastic "
        "model). Default: the drawing's statement (a STEP restraint note such as ISO "
        "10579-NR: virtual; none: free, ASME Y14.5); a mesh nominal, which has no drawing: "
        "virtual. --clamps implies clamps",
    )
    held.add_argument(
        "--judge-free-state",
        action="store_true",
        help="held at clamps, judge the free state too (in its own best fit), for what the "
        "outputs say it gave; it decides nothing (default: only the stated condition is "
        "judged, and the outputs say the free state was not)",
    )
    held.add_argument(
        "--fixture",
        choices=("auto", "restrained", "free"),
        default="auto",
        help="older spelling of --restraint: restrained = --restraint clamps, free = "
        "--restraint virtual; auto (default): --restraint's default",
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
        "--max-restraint-force",
        type=float,
        default=None,
        metavar="N",
        help="the force a physical fixture may use to hold the part in the virtual "
        "fixture's shape (measured on its elastic model: needs --material, and a mesh "
        f"nominal's --thickness); a PASS that needs more is NOT ESTABLISHED (default "
        f"{DEFAULT_MAX_FORCE:g} N)",
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


def add_run_options(ap: argparse.ArgumentParser, batch: bool) -> None:
    """How the command runs: profiling, one process, the progress bar (``batch=True``: only
    ``--quiet``)."""
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
            "trim edges and the reports are worked on beside the main work: the same "
            "results, sooner, for the memory a child changes)",
        )
    ap.add_argument("--quiet", action="store_true", help="no progress bar")


def add_inspect_arguments(ap: argparse.ArgumentParser) -> None:
    """The ``inspect`` sub-command: the nominal, the scan and the inspection options."""
    ap.add_argument(
        "nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh (STL, PLY, OBJ, OFF), mm"
    )
    ap.add_argument(
        "scan", type=Path, help="scan point cloud (PLY, STL, OBJ, OFF, XYZ, CSV, NPY, E57)"
    )
    add_inspect_options(ap, batch=False)
    ap.add_argument("--version", action="version", version=f"qifreport {__version__}")


def add_pmi_arguments(ap: argparse.ArgumentParser) -> None:
    """The ``pmi`` sub-command: the STEP file, JSON output, and clamps to list."""
    ap.add_argument("step", type=Path, help="STEP AP242 file")
    ap.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="-|FILE",
        help="JSON instead of a table: on stdout (--json or --json -) or written to FILE",
    )
    ap.add_argument(
        "--clamps",
        type=Path,
        metavar="FILE|pmi",
        help="also list the clamps of this CSV, or of the datum targets (pmi), as --clamps of "
        "inspect: the face and datum feature each sits on",
    )
    ap.add_argument(
        "--max-clamp-force",
        type=float,
        metavar="N",
        help="force limit of the clamps that state none, N",
    )


def add_prepare_arguments(ap: argparse.ArgumentParser) -> None:
    """The ``prepare`` sub-command: the nominal and the options its cache key includes."""
    ap.add_argument("nominal", type=Path, help="nominal: STEP (AP242 with PMI) or mesh, mm")
    for flag in ("--tolerance", "--max-edge", "--deflection", "--edge-band", "--boundary-band"):
        ap.add_argument(
            flag,
            type=float,
            default=None,
            metavar="MM",
            help="as for the inspection (the cache key includes it)",
        )
    ap.add_argument("--energy", choices=ENERGIES, default="auto")
    add_solid_option(ap)
    ap.add_argument(
        "--cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="cache directory (default $QIFREPORT_CACHE or the user cache dir)",
    )
    ap.add_argument("--rebuild", action="store_true", help="ignore an existing entry")
    add_accept_option(ap)
