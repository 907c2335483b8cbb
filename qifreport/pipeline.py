"""One inspection from files to outputs: read, prepare (through the cache), inspect, write.

:func:`run_job` is what ``qifreport NOMINAL SCAN`` runs; :func:`inspect_state` and
:func:`output_writers` are shared with the batch workers (:mod:`qifreport.batch`), which get
the prepared part from their parent and return the outputs' bytes instead of writing them.

Outputs (``job.out``, all or none): ``<stem>.qif``, the QIF 3.0 results document, validated
against the official schemas before it is published (never called valid when the schemas are
missing); ``<stem>.pdf``, the one-page conformance report; with ``html`` the interactive
deviation map ``<stem>.html`` (:mod:`qifreport.reports.html`); with ``json`` the summary
``<stem>.json`` (``schemas/summary-1.schema.json``); with ``export_mesh`` the registered
nominal as PLY with a per-vertex ``deviation``.

The text the command prints on stdout (the summary) is :mod:`qifreport.console`'s.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from qifreport import __version__
from qifreport.atomic_io import atomic_write_many, output_lock, remove_stale_temps
from qifreport.errors import (
    EXIT_ERROR,
    EXIT_FAIL,
    EXIT_NOT_ESTABLISHED,
    EXIT_PASS,
    InputError,
    require_file,
)
from qifreport.metrology.acceptance.bands import ToleranceZone
from qifreport.metrology.acceptance.repeatability import KEEP_FRACTION, resample_mask
from qifreport.metrology.acceptance.repeatability import apply as apply_repeatability
from qifreport.metrology.gdt.budgets import registration_term
from qifreport.metrology.inspection import (
    InspectionInputs,
    InspectionParams,
    InspectionResult,
    check_units,
    inspect,
)
from qifreport.metrology.model import Drawing, Part
from qifreport.metrology.params import CLAMPS
from qifreport.registration.linalg import default_backend
from qifreport.registration.mesh import bounding_diagonal
from qifreport.registration.outliers import StrayPoints, without_stray
from qifreport.registration.pointcloud import read_scan
from qifreport.registration.scan import Scan
from qifreport.registration.thinning import ThinningReport, nominal_spacing, thin_scan

from .cache import CacheOutcome, PartState, part_state, sha256, store_basis
from .forked import fork_executor
from .jsonio import finite, json_default
from .options import InspectJob
from .profile import Profiler
from .schedule import inspect_beside
from .summary import SUMMARY_SCHEMA_VERSION

__all__ = [
    "EXIT_ERROR",
    "EXIT_FAIL",
    "EXIT_NOT_ESTABLISHED",
    "EXIT_PASS",
    "Inspected",
    "JobOutcome",
    "check_job",
    "exit_code",
    "inspect_job",
    "inspect_state",
    "output_writers",
    "part_inputs",
    "progress_bar",
    "qif_writer",
    "resampled_runs",
    "run_job",
    "remove_stale",
    "scan_input",
    "stale_siblings",
    "summary_document",
    "traceability",
    "write_ply_with_scalar",
]

log = logging.getLogger(__name__)


#: a writer of one output: called with the temporary path to write
Writer = Callable[[Path], object]


def write_ply_with_scalar(
    path: Path, V: np.ndarray, F: np.ndarray, name: str, s: np.ndarray
) -> None:
    """Binary little-endian PLY of a triangle mesh with one float per-vertex property.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) int triangles.  name : the property's name.
    s : (n,) its values (float32 in the file).
    """
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


def exit_code(res: InspectionResult) -> int:
    """0 pass, 1 fail, 3 not established or not measured (no pass can be claimed)."""
    return {
        "PASS": EXIT_PASS,
        "FAIL": EXIT_FAIL,
        "NOT ESTABLISHED": EXIT_NOT_ESTABLISHED,
        "NOT MEASURED": EXIT_NOT_ESTABLISHED,
    }[res.verdict]


def qif_writer(tree, state: dict) -> Writer:
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
            raise RuntimeError(
                f"the QIF document qifreport wrote is not valid against {xsd} "
                f"(line {first.line}: {first.message}); nothing written"
            )
        state.update(
            valid=True,
            validated_with=["lxml"],
            message=f"valid against the QIF 3.0 schemas in {xsd}",
        )

    return write


def _stage(prof: Profiler | None, name: str):
    """``prof.stage(name)``, or a no-op context without a profiler."""
    return prof.stage(name) if prof is not None else contextlib.nullcontext()


@contextlib.contextmanager
def progress_bar(
    desc: str, *, enabled: bool = True, total: int | None = None, unit: str = "it"
) -> Iterator[Any]:
    """A tqdm progress bar on stderr for the ``with`` block, or None (no bar).

    The bar is drawn only when ``enabled`` and stderr is a terminal: in a file or a pipe its
    carriage returns would leave the bar's text on the line of whatever is written next.
    When the block ends (normally or not) the bar's line is ended by a newline, its final
    count left on it, so whatever follows (the summary on stdout, an error on stderr)
    starts on a line of its own, never after the bar on the line the carriage return went
    back to. Log records of the block are written above the bar (``tqdm.write``), not
    after its text.

    Parameters
    ----------
    desc : the bar's label.  enabled : False: no bar (``--quiet``).
    total : the number of iterations, when known.  unit : what one iteration is.

    Yields
    ------
    tqdm or None
        The bar (``update(n)`` per iteration), or None when there is none.
    """
    if not enabled or not sys.stderr.isatty():
        yield None
        return
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(desc=desc, total=total, unit=unit, file=sys.stderr, leave=True)
    try:
        with logging_redirect_tqdm(tqdm_class=tqdm):
            yield bar
    finally:
        bar.close()


#: the reports a run may write under its base name (:meth:`InspectJob.output_paths`)
REPORT_SUFFIXES = (".qif", ".pdf", ".html", ".json")


def stale_siblings(job: InspectJob) -> list[Path]:
    """The reports under the job's base name that it will not write and that exist (an
    earlier run's PDF beside this run's QIF would read as this run's): refused without
    ``force``, removed once this run's outputs are published with it."""
    outputs = set(job.output_paths().values())
    siblings = (job.out / f"{job.base.name}{s}" for s in REPORT_SUFFIXES)
    return [p for p in siblings if p not in outputs and p.is_file()]


def remove_stale(paths: list[Path]) -> None:
    """Remove an earlier run's reports (:func:`stale_siblings`) once this run's are
    published with ``--force``: the set under the name is this run's alone."""
    for path in paths:
        path.unlink(missing_ok=True)
        log.warning("removed %s, an earlier run's report this run does not write", path)


def check_job(job: InspectJob) -> None:
    """Refuse before any work: bad options, a missing input, an output that exists (without
    ``force``) or a directory that cannot be written."""
    job.check()
    for name in ("nominal", "scan"):
        require_file(getattr(job, name), name)
    plan = plan_path(job, job.out)
    if plan is not None and plan.exists() and not job.force:
        from qifreport.qif.plan import plan_qpid, read_qpid

        if read_qpid(plan) != plan_qpid(sha256(job.nominal)):
            raise InputError(
                f"output exists: {plan} is not the plan of {job.nominal.name} by this "
                "qifreport (use --force to overwrite)"
            )
    for path in stale_siblings(job):
        if not job.force:
            raise InputError(
                f"output exists: {path}, an earlier run's, would stand beside this run's "
                "outputs as if it were one of them (use --force to replace the set)"
            )
    for path in job.output_paths().values():
        if path.exists() and not job.force:
            raise InputError(f"output exists: {path} (use --force to overwrite)")
        if path.is_dir():
            raise InputError(f"output path is a directory: {path}")
        parent = path.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"output directory not writable: {parent}")


def resampled_runs(
    res: InspectionResult,
    params: InspectionParams,
    part: Part,
    drawing: Drawing,
    seeds: int,
    bar=None,
    prepared=None,
) -> None:
    """Inspect ``seeds`` resamplings of the scan and keep only the persistent regions of
    ``res`` (:mod:`qifreport.metrology.acceptance.repeatability`; ``res`` is changed in place).

    Resampling ``k`` keeps each point of the scan with probability
    :data:`qifreport.metrology.acceptance.repeatability.KEEP_FRACTION` (seed ``k``). It starts from
    ``res``'s pose: the scan already moved into the nominal frame, no pose search
    (``prealign="never"``).
    """
    t0 = time.perf_counter()
    p = replace(params, prealign="never")
    if res.restraint is not None:  # the scan is held already: each resampling as it is
        p = replace(p, fixture="free", rigid_only=True)
    runs = []
    for k in range(seeds):
        if bar is not None:
            bar.set_description_str(f"resampling {k + 1}/{seeds}")
        keep = resample_mask(len(res.P), k, KEEP_FRACTION)
        inputs = part_inputs(part, drawing, basis=res.basis, prepared=prepared)
        progress = None if bar is None else bar.update
        runs.append(inspect(res.V, res.F, res.P[keep], p, inputs, progress=progress))
    seconds = time.perf_counter() - t0
    apply_repeatability(res, runs, KEEP_FRACTION, seconds=seconds)
    diagonal = bounding_diagonal(res.V)
    by_key = [{q.spec.key: q.value for q in r.characteristics} for r in runs]
    for i, c in enumerate(res.characteristics):
        values = [v.get(c.spec.key) for v in by_key]
        res.characteristics[i] = registration_term(c, values, params.decision_rule, diagonal)
    res.timings["repeatability"] = seconds


def part_inputs(part: Part, drawing: Drawing, **more) -> InspectionInputs:
    """The inspection's inputs of the part read and its drawing (:class:`InspectionInputs`):
    its B-rep faces and corner normals, solidity, zones, unscored PMI items and
    characteristic plan, with ``more`` (its prepared state, bending basis, restraint)."""
    return InspectionInputs(
        zones=drawing.zones,
        face_id=part.face_id,
        not_evaluated=drawing.not_evaluated,
        solid=part.is_solid,
        brep_normals=part.brep_normals,
        plan=drawing.plan,
        **more,
    )


def zones_with_coverage(
    zones: list[ToleranceZone] | None, rules: tuple[tuple[str, float], ...]
) -> list[ToleranceZone] | None:
    """The zones with the ``--min-coverage TOL=FRACTION`` rules applied: ``TOL`` is a zone's
    key (``T2``), its name, or its STEP id (``#1452``). InputError for a rule that selects no
    zone (naming the zones there are)."""
    if not rules:
        return zones
    zones = list(zones or [])
    for sel, frac in rules:
        hits = [
            i
            for i, z in enumerate(zones)
            if sel in (z.key, z.name) or (z.step_id is not None and sel == f"#{z.step_id}")
        ]
        if not hits:
            names = ", ".join(f"{z.key} ({z.name})" for z in zones) or "none"
            raise InputError(
                f"--min-coverage {sel}={frac:g}: no tolerance {sel!r}; there are {names}"
            )
        for i in hits:
            zones[i] = replace(zones[i], min_coverage=frac)
    return zones


def staged(bar, desc: str):
    """The ``progress(k)`` of a stage that counts iterations: the first names the stage on
    the bar (``desc``), each advances it (None without a bar)."""
    if bar is None:
        return None
    bar.set_description_str("seating the scan (pose search, rigid fit), judging the free state")

    def progress(k: int) -> None:
        if bar.desc != desc:
            bar.set_description_str(desc)
        bar.update(k)

    return progress


def inspect_state(
    P: np.ndarray,
    state: PartState,
    job: InspectJob,
    *,
    bar=None,
    prof: Profiler | None = None,
    executor=None,
    stray: StrayPoints | None = None,
) -> InspectionResult:
    """Inspect the scan points ``P`` (mm) against a prepared part, with the job's options
    (the repeatability runs included); ``executor``: where side work of the inspection runs
    beside its main line (:func:`qifreport.schedule.inspect_beside`), ``stray``: the stray
    points :func:`scan_input` left out of ``P`` (None: the inspection looks for them)."""
    o = job.options
    part, drawing = state.part, state.drawing
    # the condition the part is judged in, and who stated it: the operator's, else the
    # drawing's (judge_as_held applies it)
    held = o.restraint_condition(drawing)
    params = replace(o.inspection_params(), restraint=held)
    if held.condition == CLAMPS:
        params = replace(params, fixture="restrained")
    inputs = replace(
        part_inputs(
            part,
            drawing,
            prepared=state.prepared,
            restraint=state.restraint,
            fixture_load=state.fixture_load,
        ),
        # the --min-coverage rules apply to this inspection's zones
        zones=zones_with_coverage(drawing.zones, o.zone_min_coverage),
        scan_units=o.scan_units,
        stray=stray,
    )
    res = inspect_beside(
        part.V,
        part.F,
        P,
        params,
        inputs,
        executor=executor,
        progress=staged(bar, "virtual fixturing"),
    )
    res.drawing_warnings = list(drawing.warnings)
    if o.seeds > 1:
        with _stage(prof, f"repeatability ({o.seeds} resamplings)"):
            resampled_runs(res, params, part, drawing, o.seeds, bar, prepared=state.prepared)
    return res


def traceability(
    res: InspectionResult, part: Part, job: InspectJob, started: datetime, finished: datetime
) -> dict:
    """Who and what the inspection ``res`` is of and by (the JSON summary's
    ``traceability``, the report header's and the QIF's fields): the part number and
    revision (the operator's, else the STEP product's), serial number, people, the
    instrument and the part's temperature (the scanner profile the inspection used), when it
    ran (ISO 8601, UTC)."""
    o = job.options
    product = part.info.get("product") or {}
    number = o.part_number or product.get("number")
    revision = o.revision or product.get("revision")
    source = "operator" if o.part_number else ("step" if number else None)
    profile = res.params.scanner
    instrument = profile.name + (f" ({profile.model})" if profile.model else "")
    return {
        "part_number": number,
        "revision": revision,
        "part_number_source": source,
        "serial": job.serial,
        "operator": o.operator,
        "organization": o.organization,
        "author": o.author,
        "instrument": instrument,
        "temperature_C": profile.temperature,
        "started": started.isoformat(timespec="seconds"),
        "finished": finished.isoformat(timespec="seconds"),
    }


def _provenance(
    res: InspectionResult,
    part: Part,
    drawing: Drawing,
    job: InspectJob,
    digests: dict[str, str],
    started: datetime,
    finished: datetime,
):
    """The QIF and report header of one inspection
    (:class:`qifreport.qif.writer.Provenance`): the inputs and their SHA-256 ``digests``,
    the part's datums and STEP ids, the job's people and serial number, when it ran."""
    from qifreport.qif.writer import Provenance

    o = job.options
    return Provenance(
        part_name=job.nominal.stem,
        nominal_path=str(job.nominal),
        scan_path=str(job.scan),
        nominal_sha256=digests["nominal"],
        scan_sha256=digests["scan"],
        started=started,
        finished=finished,
        datums=drawing.datums,
        nominal_info=part.info,
        face_step_ids=part.face_step_ids,
        author=o.author,
        organization=o.organization,
        operator=o.operator,
        serial_number=job.serial,
        plan=plan_source(part, drawing, job, digests["nominal"]),
        trace=traceability(res, part, job, started, finished),
    )


def _json_writer(
    res: InspectionResult,
    part: Part,
    job: InspectJob,
    digests: dict[str, str],
    scan_report: ThinningReport | None,
    qif_state: dict | None,
    times: tuple[datetime, datetime],
) -> Writer:
    """The writer of the JSON summary (:func:`summary_document` with the QIF's
    ``qif_state``, filled by the QIF writer, which runs first)."""
    doc = summary_document(res, part, job, digests, scan_report, times)

    def write_json(p: Path) -> None:  # runs after the QIF writer: its state is known
        if qif_state is not None:
            doc["qif"] = qif_state
        p.write_text(json.dumps(finite(doc), indent=2, default=json_default, allow_nan=False))

    return write_json


def summary_document(
    res: InspectionResult,
    part: Part,
    job: InspectJob,
    digests: dict[str, str],
    scan_report: ThinningReport | None,
    times: tuple[datetime, datetime],
) -> dict:
    """The JSON summary (``schemas/summary-1.schema.json``) but its ``qif`` block: the
    inspection's :meth:`~qifreport.metrology.results.InspectionResult.to_dict` with its
    :func:`traceability` (``times``: started, finished), the software, the nominal, the
    inputs and their ``digests`` and the ``scan_report``."""
    doc = res.to_dict()
    doc = {"schema": SUMMARY_SCHEMA_VERSION, **doc}
    doc["traceability"] = traceability(res, part, job, *times)
    doc["software"] = {
        "name": "qifreport",
        "version": __version__,
        "sparse_solver": default_backend(),
    }
    doc["nominal"] = part.info
    doc["inputs"] = {
        "nominal": {"path": str(job.nominal), "sha256": digests["nominal"]},
        "scan": {"path": str(job.scan), "sha256": digests["scan"]},
    }
    if scan_report is not None:
        doc["scan_input"] = scan_report.to_dict()
    return doc


def output_writers(
    res: InspectionResult,
    part: Part,
    drawing: Drawing,
    job: InspectJob,
    paths: dict[str, Path],
    digests: dict[str, str],
    started: datetime,
    finished: datetime,
    *,
    scan_report: ThinningReport | None = None,
) -> tuple[list[tuple[Path, Writer]], dict | None]:
    """The writers ``[(path, write(tmp))]`` of one inspection's outputs, in writing order
    (the QIF first: the JSON summary reports its validation), and the QIF's state block.

    ``job`` gives the names recorded in the outputs (``nominal``, ``scan``), the header
    fields (options ``author``, ``organization``, ``operator``; ``serial``) and the choices
    (``no_qif``, ``no_pdf``, ``html``, ``json``, ``page``); ``paths`` is
    ``job.output_paths()``;
    ``scan_report`` (:func:`scan_input`) is the JSON summary's ``scan_input`` block.
    """
    o = job.options
    outputs: list = []
    qif_state = None
    prov = None
    if not (o.no_qif and o.no_pdf) or o.html:
        prov = _provenance(res, part, drawing, job, digests, started, finished)
    if not o.no_qif:
        from qifreport.qif.writer import build_qif

        qif_state = {"path": str(paths["qif"])}
        outputs.append((paths["qif"], qif_writer(build_qif(res, prov), qif_state)))
        plan = plan_output(part, drawing, job, paths["qif"].parent, digests["nominal"])
        if plan is not None:
            outputs.append(plan)
    if not o.no_pdf:
        from .reports.pdf import write_pdf

        qif_name = paths["qif"].name if "qif" in paths else ""
        outputs.append(
            (paths["pdf"], lambda p: write_pdf(p, res, prov, page=o.page, qif_name=qif_name))
        )
    if o.html:
        from .reports.html import write_html

        outputs.append((paths["html"], lambda p: write_html(p, res, prov, face_id=part.face_id)))
    if job.json:
        outputs.append(
            (
                paths["json"],
                _json_writer(res, part, job, digests, scan_report, qif_state, (started, finished)),
            )
        )
    if "mesh" in paths:
        outputs.append(
            (
                paths["mesh"],
                lambda p: write_ply_with_scalar(
                    p, res.V_registered, part.F, "deviation", res.deviation
                ),
            )
        )
    return outputs, qif_state


def plan_path(job: InspectJob, out_dir: Path) -> Path | None:
    """Where the part's QIF plan goes beside the results (``<nominal stem>_plan.qif``), None
    when there is none: a mesh nominal (no PMI) or no QIF asked for."""
    from qifreport.qif.plan import plan_file_name
    from qifreport.step.reader import STEP_SUFFIXES

    if job.options.no_qif or job.nominal.suffix.lower() not in STEP_SUFFIXES:
        return None
    return out_dir / plan_file_name(job.nominal.stem)


def plan_output(
    part: Part, drawing: Drawing, job: InspectJob, out_dir: Path, nominal_sha256: str
) -> tuple[Path, Writer] | None:
    """The writer of the part's QIF plan (:mod:`qifreport.qif.plan`), which the results
    document names: None for a mesh nominal, or when the plan of this STEP file by this
    version is there already (same QPId: every scan of a batch shares it)."""
    from qifreport.qif.plan import build_plan, plan_qpid, read_qpid

    path = plan_path(job, out_dir)
    src = plan_source(part, drawing, job, nominal_sha256)
    if path is None or src is None:
        return None
    if path.is_file() and read_qpid(path) == plan_qpid(nominal_sha256):
        return None
    return path, qif_writer(build_plan(src), {})


def plan_source(part: Part, drawing: Drawing, job: InspectJob, nominal_sha256: str):
    """The part's plan (:class:`qifreport.qif.plan.PlanSource`): its drawing's zones,
    characteristics and datums; None for a part without a drawing to refer to (a mesh
    nominal)."""
    from qifreport.qif.plan import PlanSource

    if part.face_step_ids is None or drawing.plan is None:
        return None
    return PlanSource(
        part_name=job.nominal.stem,
        nominal_path=str(job.nominal),
        nominal_sha256=nominal_sha256,
        zones=drawing.zones,
        plan=drawing.plan,
        datums=drawing.datums,
        face_step_ids=part.face_step_ids,
    )


def scan_input(
    scan: Scan, part: Part, scan_units: str | None = None
) -> tuple[np.ndarray, ThinningReport, StrayPoints]:
    """The points (m, 3) mm an inspection uses of a scan read against a part: its extent
    checked against the part's (other units, another part: ``InputError`` naming the unit,
    ``scan_units`` the one the user declared, for the hint), thinned to the part's mesh grid
    when far denser (:mod:`qifreport.registration.thinning`), then without its stray points
    (:mod:`qifreport.registration.outliers`), with the two reports (logged, one INFO line
    each). Give the stray points to the inspection
    (:attr:`~qifreport.metrology.inspection.InspectionInputs.stray`)."""
    # before the thinning: a scan in metres would fall into one cell of the part's grid
    check_units(part.V, scan.points, scan_units)
    P, report = thin_scan(
        scan.points, nominal_spacing(part.V, part.F), points_read=scan.points_read
    )
    log.info("%s: %s", scan.name, report.describe())
    P, stray = without_stray(P)
    log.info("%s: %s", scan.name, stray.describe())
    return P, report, stray


@dataclass
class JobOutcome:
    """What :func:`run_job` did.

    Attributes
    ----------
    result : the inspection.  paths : the files written, by kind.
    qif : the QIF's validation block (None without a QIF).  cache : how the part was obtained.
    inspected : the inspection and what its outputs were made of (:func:`inspect_job`).
    """

    result: InspectionResult
    paths: dict[str, Path]
    qif: dict | None
    cache: CacheOutcome
    inspected: Inspected | None = None

    def summary(self, job: InspectJob) -> dict:
        """The JSON summary of ``job`` (what ``<stem>.json`` holds), JSON-ready."""
        i = self.inspected
        doc = summary_document(
            i.result, i.state.part, job, i.digests, i.scan_report, (i.started, i.finished)
        )
        if self.qif is not None:
            doc["qif"] = self.qif
        return finite(doc)

    @property
    def exit_code(self) -> int:
        return exit_code(self.result)


def run_job(job: InspectJob, *, progress: bool = True, prof: Profiler | None = None) -> JobOutcome:
    """Inspect one scan and write its outputs atomically (all or none).

    Parameters
    ----------
    job : the files, options and outputs.  progress : a progress bar on stderr when it
        is a terminal (:func:`progress_bar`).
    prof : a started :class:`~qifreport.profile.Profiler` to time the stages, or None.

    Raises
    ------
    qifreport.errors.InputError
        Bad input (nothing written).
    """
    check_job(job)
    try:
        with output_lock(job.out):
            return _run_locked(job, progress, prof)
    except BlockingIOError:
        raise InputError(
            f"another qifreport run is writing into {job.out}: wait for it or choose another --out"
        ) from None


@dataclass
class Inspected:
    """One inspection done, before any output is written (:func:`inspect_job`).

    Attributes
    ----------
    result : the inspection.  state : the part's prepared state (its part and drawing).
    digests : the inputs' SHA-256 (``nominal``, ``scan``).
    started, finished : when it ran (UTC).  scan_report : how the scan was read and thinned.
    cache : how the part was obtained.
    """

    result: InspectionResult
    state: PartState
    digests: dict[str, str]
    started: datetime
    finished: datetime
    scan_report: ThinningReport | None
    cache: CacheOutcome

    def writers(
        self, job: InspectJob, paths: dict[str, Path] | None = None
    ) -> tuple[list[tuple[Path, Writer]], dict | None]:
        """:func:`output_writers` of this inspection for ``job``'s outputs (``paths``:
        ``job.output_paths()`` unless given)."""
        return output_writers(
            self.result,
            self.state.part,
            self.state.drawing,
            job,
            job.output_paths() if paths is None else paths,
            self.digests,
            self.started,
            self.finished,
            scan_report=self.scan_report,
        )


def _run_locked(job: InspectJob, progress: bool, prof: Profiler | None) -> JobOutcome:
    for tmp in remove_stale_temps(list(job.output_paths().values())):
        log.warning("removed a temporary file an interrupted run left: %s", tmp)
    # one command, one scan: a second CPU judges the free state beside the fixture, measures
    # the trim edges beside a judgement and renders the reports beside the QIF (a batch's
    # processes fill the CPUs already)
    beside = None if job.options.one_process else fork_executor()
    done = inspect_job(job, progress=progress, prof=prof, beside=beside)
    paths = job.output_paths()
    outputs, qif_state = done.writers(job, paths)
    stale = stale_siblings(job)
    with _stage(prof, "write outputs"):  # all outputs or none
        reports = [paths[k] for k in ("pdf", "html") if k in paths]
        atomic_write_many(outputs, executor=beside, beside=reports)
    remove_stale(stale)
    if prof is not None and beside is not None:
        prof.children.extend(beside.peaks)
    return JobOutcome(done.result, paths, qif_state, done.cache, done)


def inspect_job(
    job: InspectJob,
    *,
    progress: bool = True,
    prof: Profiler | None = None,
    beside: Any = None,
) -> Inspected:
    """Read ``job``'s scan, prepare its part (through the cache) and inspect: everything
    :func:`run_job` does but write. ``beside``: a :func:`~qifreport.forked.fork_executor`
    for the work a second CPU does beside the main one (None: one process)."""
    o = job.options
    started = datetime.now(timezone.utc)
    with _stage(prof, "load scan"):  # first: a bad scan is reported before any heavy work
        scan: dict = {"read": read_scan(job.scan, units=o.scan_units)}
    nominal_options, params = o.nominal_options(job.nominal), o.inspection_params()

    def nominal_read(part: Part) -> None:
        # the scan is thinned to the nominal's grid as soon as the mesh is known: the points
        # read are let go before the preparation of a new part
        with _stage(prof, "thin scan"):
            scan["P"], scan["report"], scan["stray"] = scan_input(
                scan.pop("read"), part, o.scan_units
            )

    # one bar for the whole inspection, named after its stage (preparing a new part is the
    # long one; then the seat, the free state, the fixture's iterations)
    with progress_bar("reading the part (a new one is prepared once)", enabled=progress) as bar:
        with _stage(prof, "prepare part (cache)"):
            # the free state is judged first: a part that conforms needs no bending basis,
            # so a new entry leaves it out and the first fixtured inspection stores it
            state, cache = part_state(
                job.nominal,
                nominal_options,
                params,
                o.cache_dir,
                lazy_basis=not o.always_fixture,
                on_nominal=nominal_read,
            )
        log.info("%s", cache.describe())
        t_inspect = time.perf_counter()
        res = inspect_state(
            scan["P"],
            state,
            job,
            bar=bar,
            prof=prof,
            executor=beside,
            stray=scan["stray"],
        )
    if prof is not None:
        prof.add_stages(t_inspect, res.timings, prefix="inspect: ")
    if res.fit is not None:
        store_basis(state, cache, res.basis, nominal_options, params, o.cache_dir)
    return Inspected(
        result=res,
        state=state,
        digests={"nominal": state.nominal_sha256, "scan": sha256(job.scan)},
        started=started,
        finished=datetime.now(timezone.utc),
        scan_report=scan["report"],
        cache=cache,
    )
