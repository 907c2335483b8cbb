"""One inspection, end to end on arrays: rigid alignment, virtual fixturing, deviation, verdict.

This is the library entry point the command line calls. :func:`inspect` takes the nominal
``(V, F)`` and the scan ``P`` in mm and returns an
:class:`~qifreport.metrology.results.InspectionResult`: the registered nominal, the signed
deviation field, its statistics and the acceptance decision of the paper's Section 10 (area
criterion and region criterion). It seats the scan (pose search, rigid fit) and schedules
the rest: the free state's judgement, the virtual fixture when the free state does not
stand (beside each other, given a second process), or the restrained hold the drawing asks
for. Each judgement is :func:`qifreport.metrology.judgement.judge`'s.

Frames: the scan is moved into the nominal (CAD) frame once, by the rigid stage
(paper Section 3); everything reported (registered nominal, region centroids) is in the
nominal frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from qifreport.errors import InputError
from qifreport.metrology.acceptance.bands import (
    DEFAULT_GENERAL_TOLERANCE,
    BandField,
    NotEvaluated,
    ToleranceZone,
    lay_bands,
    symmetric_zone,
)
from qifreport.metrology.acceptance.criteria import scan_area
from qifreport.metrology.gdt.characteristics import CharacteristicPlan
from qifreport.metrology.restraint.held import hold_scan
from qifreport.registration.deformable.bending_basis import BendingBasis, bending_basis, part_solver
from qifreport.registration.deformable.methods import METHODS, deform, method_spec
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import RigidResult, rigid_icp
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import bounding_diagonal
from qifreport.registration.normals import oriented_normals
from qifreport.registration.pose.prealign import seat_scan
from qifreport.registration.restraint.restrained import RestraintBasis

from .deferred import submit
from .judgement import JudgeContext, Registered, judge
from .params import InspectionParams, method_label
from .prepared import PreparedPart, prepare_part
from .results import (
    FREE_STATE_CONFORMS,
    FREE_STATE_LOCAL_DEFECTS,
    FREE_STATE_UNCERTAIN,
    RESTRAINED,
    InspectionResult,
    ZoneResult,
)

__all__ = [
    "FREE_STATE_CONFORMS",
    "FREE_STATE_LOCAL_DEFECTS",
    "FREE_STATE_UNCERTAIN",
    "RESTRAINED",
    "InspectionParams",
    "InspectionResult",
    "ScanMeasures",
    "ZoneResult",
    "check_units",
    "default_zones",
    "inspect",
    "judge_as_held",
    "lay_zone_bands",
    "method_label",
    "seat_rigidly",
    "start_scan_measures",
]

log = logging.getLogger(__name__)

#: scan-to-nominal extent ratios that betray a unit mix-up, and the unit behind each
_UNIT_FACTORS = {1 / 25.4: "in", 0.001: "m", 0.1: "cm", 25.4: "in", 1000.0: "m", 10.0: "cm"}


def check_units(V: np.ndarray, P: np.ndarray, scan_units: str | None = None) -> None:
    """Reject a scan whose extent betrays other units (or another part) than the nominal's.

    ``scan_units`` is what the user declared (``--scan-units``; None: the format's unit), for
    the hint. The overlap check needs the rigid pose and is made in :func:`inspect`.
    Raises :class:`InputError` with a one-line message.
    """
    dv, dp = bounding_diagonal(V), bounding_diagonal(P)
    if dv <= 0:
        raise InputError("the nominal mesh has zero extent")
    ratio = dp / dv
    if not 0.2 <= ratio <= 5.0:
        best = min(_UNIT_FACTORS, key=lambda r: abs(np.log(ratio / r)))
        hint = ""
        if abs(np.log(ratio / best)) < 0.4:
            unit = _UNIT_FACTORS[best]
            if best < 1:  # the scan is too small: its numbers are in a larger unit
                hint = (
                    f"; the scan looks {1 / best:g}x too small: in {unit}? use --scan-units {unit}"
                    if unit in ("in", "m")
                    else f"; the scan looks {1 / best:g}x too small (in {unit}?)"
                )
            elif scan_units not in (None, "mm"):
                hint = (
                    f"; the scan looks {best:g}x too large: it is in mm already? drop "
                    f"--scan-units {scan_units}"
                )
            else:
                hint = (
                    f"; the scan looks {best:g}x too large: is the nominal in {unit}? "
                    "(nominals are read in mm)"
                )
        raise InputError(
            f"scan extent {dp:.4g} mm vs nominal extent {dv:.4g} mm (ratio {ratio:.3g}): "
            f"wrong units or wrong part{hint}"
        )


@dataclass
class ScanMeasures:
    """The scan's own normals and the area it covers, under way (:func:`start_scan_measures`).

    Attributes
    ----------
    P : (m, 3) the scan points they are measured on, mm (the very array later inspected).
    normals : pending ``(Ns, sheets)`` of
        :func:`~qifreport.registration.normals.oriented_normals` (``result()``).
    area : pending covered area, mm^2, of
    :func:`~qifreport.metrology.acceptance.criteria.scan_area`;
        None: not started yet (:func:`inspect` starts it).
    """

    P: np.ndarray
    normals: Any
    area: Any = None

    def cancel(self) -> None:
        """Stop whatever of them is still running (a result taken already is kept)."""
        self.normals.cancel()
        if self.area is not None:
            self.area.cancel()


def start_scan_measures(
    P: np.ndarray, params: InspectionParams, executor=None, *, area: bool = True
) -> ScanMeasures:
    """Start measuring the scan's own normals and covered area (for :func:`inspect`).

    The normals (oriented consistently per connected sheet once; the inspection only chooses
    each sheet's side against its nominal) and the area do not depend on where the scan
    lies: they are measured on the points as read and turned with the scan. So they can run
    before the scan is seated, even while the part is still being prepared: on ``executor``
    (as :func:`inspect`'s) beside it, else when their results are asked for.

    Parameters
    ----------
    P : (m, 3) the scan points the inspection will be given, mm.
    params : the inspection's parameters (the normals' neighbourhood).
    executor : where they run; default: in this process, when asked for.
    area : start the area too (else :func:`inspect` starts it).
    """
    normals = submit(executor, oriented_normals, P, params.gbcicp.scan_normal_k)
    pending = submit(executor, scan_area, P) if area else None
    return ScanMeasures(P=P, normals=normals, area=pending)


def inspect(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    progress=None,
    *,
    face_id: np.ndarray | None = None,
    zones: list[ToleranceZone] | None = None,
    not_evaluated: list[NotEvaluated] | None = None,
    scan_units: str | None = None,
    basis: BendingBasis | None = None,
    prepared: PreparedPart | None = None,
    solid: bool = False,
    brep_normals: np.ndarray | None = None,
    restraint: RestraintBasis | None = None,
    plan: CharacteristicPlan | None = None,
    executor=None,
    measures: ScanMeasures | None = None,
) -> InspectionResult:
    """Inspect the scan ``P`` against the nominal ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points, mm, in any placement: a scan not already in the nominal frame
        is seated first by the pose search (``params.prealign``).
    params : :class:`InspectionParams`.
    progress : optional callable ``progress(k)`` advanced once per iteration of the virtual
        fixture (``params.method``).
    zones : tolerance zones (:func:`qifreport.metrology.acceptance.bands.zones_from_pmi`); default
    one general
        zone of half-width ``params.tolerance``. Zones that cover no triangle are dropped.
    face_id, not_evaluated, solid, brep_normals, plan : the part's B-rep faces, PMI items not
        scored, solidity, exact corner normals and drawing characteristics, as
        :class:`~qifreport.metrology.judgement.JudgeContext` holds them.
    scan_units : the unit the user declared for the scan file (for the units hint only).
    basis : the nominal's GB-CICP bending basis
        (:func:`qifreport.registration.deformable.gbcicp.bending_basis`), to reuse it across scans
        of one part;
        computed when needed if omitted.
    prepared : the nominal's scan-independent state
        (:func:`qifreport.metrology.prepared.prepare_part` with these ``params``), to reuse across
        scans of one part: operators, unscored bands, hygiene, bending basis (unless ``basis`` is
        given) and the pose search's model. ``ValueError`` if it was prepared for another mesh or
        other settings.
    restraint : the part's clamps and their elastic responses
        (:func:`qifreport.registration.restraint.restrained.restraint_basis` on this mesh), for
        ``params.fixture == "restrained"``: the rigidly seated scan is held at its clamps
        and judged as held (no virtual fixture, no free-state shortcut: the drawing says
        how the part is inspected).
    executor : an object whose ``submit(fn, *args, **kwargs)`` returns a future (with
        ``result()`` and ``cancel()``, and ``done()`` to give up the fixture early), e.g. a
        :class:`concurrent.futures.Executor` or the command line's forked child
        (:class:`qifreport.forked.ForkExecutor`). Given to it: the scan's normals and area
        (beside the pose), the free-state judgement (beside the virtual fixture, which is
        given up once the free state stands) and the fixtured part's trim edges. The
        outcome is the sequential one. Default: sequential.
    measures : the scan's normals and area started already on these very points
        (:func:`start_scan_measures`, e.g. beside the part's preparation); default: started
        here, on ``executor``. The inspection takes them, or stops them when it fails.

    Raises
    ------
    InputError
        Wrong units, or a scan that does not overlap the nominal after rigid alignment;
        :class:`qifreport.registration.pose.prealign.PoseNotEstablished` when no pose can be
        established.
    """
    timings: dict[str, float] = {}
    prepared, basis = _checked_part(V, F, P, params, scan_units, prepared, basis, timings, measures)
    reg = seat_rigidly(V, F, P, params, prepared, timings, measures=measures, executor=executor)
    zones = default_zones(params) if zones is None else zones
    ctx = JudgeContext(
        prepared=prepared,
        bands=lay_zone_bands(F, len(V), face_id, zones),
        energy=prepared.energy,
        face_id=face_id,
        not_evaluated=not_evaluated,
        solid=solid,
        basis=basis,
        brep_normals=brep_normals,
        plan=plan,
    )
    return judge_as_held(reg, ctx, params, zones, timings, progress, restraint, executor)


def judge_as_held(
    reg: Registered,
    ctx: JudgeContext,
    params: InspectionParams,
    zones: list[ToleranceZone],
    timings: dict[str, float],
    progress=None,
    restraint: RestraintBasis | None = None,
    executor=None,
) -> InspectionResult:
    """The seated scan judged as the inspection's fixture policy asks (:func:`inspect`):
    rigidly only, held at its clamps (``restraint``), always fixtured, or in its free state
    first and fixtured only when that does not stand (:func:`_free_state_stands`).

    ``zones``: the zones as given, before those covering no triangle were dropped (the
    tightest sets the fixture's guard); ``timings``: seconds per stage, added to;
    ``executor``: as :func:`inspect`'s (:func:`_free_state_beside_fixture`)."""
    run = _Run(reg, ctx, params, zones, timings, progress, executor)
    if params.rigid_only:
        res = judge(reg, None, params, timings, ctx)
        res.fixture_decision = "rigid only"
        return res
    if params.fixture == "restrained":
        if restraint is None:
            raise ValueError("a restrained inspection needs the part's restraint basis")
        if len(restraint.points) != len(reg.V):
            raise ValueError("the restraint basis was built for another mesh of the part")
        return _restrained(run, restraint)
    if params.always_fixture:
        return _fixture_and_judge(run, ctx.basis)
    # ISO 10579 / Y14.5: restraint is there to bring a compliant part to its drawing shape;
    # the free state (no force) is one of the states a fixture may hold it in. When it
    # conforms on its own, no restraint is needed and none is simulated: a virtual fixture
    # can then only add its own error (a stiff part moved by it).
    t0 = time.perf_counter()
    if executor is not None and _fixture_likely(reg.rigid, zones):
        return _free_state_beside_fixture(run, ctx.basis)
    # a seat well inside the tightest zone (a stiff part): its free state will most likely
    # stand, so no fixture is started beside it (its work would be wasted, and would take a
    # core from the judgement); judged here, its own steps beside it
    free = judge(reg, None, params, dict(timings), ctx, check_part=False, executor=executor)
    decided = _free_state_stands(free)
    if decided is not None:
        return decided
    timings["free state"] = time.perf_counter() - t0  # then the fixtured judgement's
    return _fixture_and_judge(run, ctx.basis, free=free)


@dataclass(frozen=True)
class _Run:
    """What the judgements of one seated scan share (:func:`judge_as_held`'s inputs):
    ``timings`` is added to; ``progress`` and ``executor`` are :func:`inspect`'s."""

    reg: Registered
    ctx: JudgeContext
    params: InspectionParams
    zones: list[ToleranceZone]
    timings: dict[str, float]
    progress: Any = None
    executor: Any = None


def _checked_part(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    scan_units: str | None,
    prepared: PreparedPart | None,
    basis: BendingBasis | None,
    timings: dict[str, float],
    measures: ScanMeasures | None = None,
) -> tuple[PreparedPart, BendingBasis | None]:
    """The inspection's method and units checked, and the part's prepared state (made, or
    checked against ``(V, F)`` and ``params``) with the bending basis to use; ``timings``:
    added to ("operators"). ``measures`` (:func:`start_scan_measures`) are stopped when a
    check fails."""
    if measures is not None and measures.P is not P:
        measures.cancel()
        raise ValueError("the scan measures were started on other points than these")
    try:
        if params.method not in METHODS:
            raise ValueError(f"unknown method {params.method!r} (one of {', '.join(METHODS)})")
        t0 = time.perf_counter()
        check_units(V, P, scan_units)
        if prepared is None:
            prepared = prepare_part(V, F, params, basis=False, model=False)
        else:
            prepared.check(V, F, params)
            if basis is None:
                basis = prepared.basis
        timings["operators"] = time.perf_counter() - t0
    except BaseException:
        if measures is not None:
            measures.cancel()
        raise
    return prepared, basis


def seat_rigidly(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    prepared: PreparedPart,
    timings: dict[str, float],
    *,
    measures: ScanMeasures | None = None,
    executor=None,
) -> Registered:
    """The scan ``P`` (m, 3) seated on the nominal ``(V, F)``: the pose search, the rigid
    fit, the overlap check, and the scan's normals (turned with it) and covered area
    (:class:`~qifreport.metrology.judgement.Registered`).

    ``measures``: the scan's normals and area started already (:func:`start_scan_measures`);
    default: started here on ``executor``; either is stopped when the seat fails.
    ``timings``: seconds per stage, added to. Raises :class:`InputError` when the seated
    scan does not overlap the nominal."""
    if measures is None:
        measures = start_scan_measures(P, params, executor)
    elif measures.area is None:
        measures.area = submit(executor, scan_area, P)
    normals, area = measures.normals, measures.area
    try:
        t0 = time.perf_counter()
        seat = seat_scan(V, F, P, mode=params.prealign, model=prepared.model)
        timings["prealign"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tree = prepared.model.tree if prepared.model is not None else cKDTree(V)
        rigid = rigid_icp(V, prepared.ops.normals, P, R0=seat.R, t0=seat.t, tree=tree)
        Pm = rigid.apply(P)
        timings["rigid"] = time.perf_counter() - t0
        diag = bounding_diagonal(V)
        d_near, _ = tree.query(Pm, workers=-1)
        overlap = float(np.mean(d_near < 0.02 * diag))
        if overlap < 0.3 or rigid.inlier_fraction < 0.3:
            raise InputError(
                f"scan does not overlap the nominal: after rigid alignment only "
                f"{100 * overlap:.0f} % of the points lie within {0.02 * diag:.3g} mm of it"
            )
        t0 = time.perf_counter()
        Ns, sheets = normals.result()
        Ns = Ns @ rigid.R.T
        area_mm2 = area.result()
        timings["scan normals, area"] = time.perf_counter() - t0
    finally:
        normals.cancel()
        area.cancel()
    reg = Registered(
        V=V, F=F, P=Pm, rigid=rigid, seat=seat, scan_normals=Ns, sheets=sheets, diag=diag
    )
    reg.scan_area = area_mm2  # the cached property, known already
    return reg


def default_zones(params: InspectionParams) -> list[ToleranceZone]:
    """The one general zone of an inspection without a drawing's zones: half-width
    ``params.tolerance``, mm, or qifreport's default band when none is given."""
    tol = params.tolerance
    if tol is None:
        return [symmetric_zone(DEFAULT_GENERAL_TOLERANCE, "default")]
    return [symmetric_zone(tol, "general")]


def lay_zone_bands(
    F: np.ndarray, n: int, face_id: np.ndarray | None, zones: list[ToleranceZone]
) -> BandField:
    """The zones laid on the mesh (:func:`~qifreport.metrology.acceptance.bands.lay_bands`), those
    that cover no triangle dropped."""
    bands = lay_bands(F, n, face_id, zones)
    keep = [i for i, m in enumerate(bands.tri_masks) if m.any()]
    if len(keep) < len(zones):
        dropped = [zones[i].key for i in range(len(zones)) if i not in keep]
        log.info("zones covering no triangle dropped: %s", ", ".join(dropped))
        bands = lay_bands(F, n, face_id, [zones[i] for i in keep])
    return bands


#: the rigid seat's robust residual scale, in units of the tightest zone's half-width, from
#: which the virtual fixture is started beside the free state's judgement. Measured: the
#: compliant sample parts seat at 0.6-1.9 and the fandisk of ``bench/fandisk_command.py``
#: (bent and twisted, its free state fails) at 0.19; the NIST machined parts' perfect
#: scans at 0.02-0.18 (0.02-0.08 for five of the seven)
FIXTURE_LIKELY = 0.1


def _fixture_likely(rigid: RigidResult, zones: list[ToleranceZone]) -> bool:
    """Whether the rigid seat leaves the part far enough from its drawing shape that its
    free state may well not conform: its robust residual scale reaches a tenth of the
    tightest zone's half-width.

    Only the schedule depends on it, never the result: whether the fixture starts beside
    the free state's judgement or after it, if it does not stand. A wrong guess costs time,
    not a verdict: a fixture started for a free state that stands wastes the CPU it took (a
    stiff part's bending basis, a large cost), and one not started for a free state that
    fails waits for the judgement (a small one); hence a low bar."""
    tightest = min(z.half_width for z in zones)
    return rigid.scale >= FIXTURE_LIKELY * tightest


def _modal(params: InspectionParams) -> bool:
    """Whether the inspection's virtual fixture iterates in the part's bending basis
    (GB-CICP's modal solver)."""
    g = params.gbcicp
    return (
        method_spec(params.method).uses_bending_basis and g.solver == "modal" and g.lambda0 is None
    )


class _FreeStateStood(Exception):
    """The free state, judged beside the virtual fixture, stands: the fixture is given up."""


class _StoodCheck:
    """Called between two steps of the virtual fixture: raises :class:`_FreeStateStood`
    when the free-state judgement beside it is done and stands."""

    def __init__(self, pending) -> None:
        self.pending = pending

    def __call__(self) -> None:
        done = getattr(self.pending, "done", None)
        if done is not None and done() and _free_state_stands(self.pending.result()):
            raise _FreeStateStood


def _free_state_stands(free: InspectionResult) -> InspectionResult | None:
    """The free-state judgement ``free`` as the inspection's result when it decides it:
    nothing of it proven out of tolerance with the registration trusted (PASS; NOT
    MEASURED where the scan has holes; NOT ESTABLISHED on a zone limit within the
    uncertainty: a fixture cannot decide what the measurement cannot), or only defects
    narrower than the mesh failed (which no fixture can remove). None: it does not."""
    if free.passed and free.established:  # its stages are the inspection's
        free.fixture_decision = FREE_STATE_UNCERTAIN if free.uncertain() else FREE_STATE_CONFORMS
        return free
    if free.established and free.fails_only_narrower_than_mesh():
        free.fixture_decision = FREE_STATE_LOCAL_DEFECTS
        return free
    return None


def _fixture_and_judge(
    run: _Run, basis: BendingBasis | None, free: InspectionResult | None = None
) -> InspectionResult:
    """The virtual fixture (in ``basis``) and the judgement of the part as it holds it
    (``run.executor``: for the trim edges), after the free state's judgement ``free`` that
    did not stand (None: ``always_fixture``, not judged)."""
    fit = _timed_fixture(run, basis, run.progress)
    res = judge(
        run.reg,
        fit,
        run.params,
        run.timings,
        run.ctx,
        free_deviation=_deviation(free),
        executor=run.executor,
    )
    return _with_free_state(res, free)


def _free_state_beside_fixture(run: _Run, basis: BendingBasis | None) -> InspectionResult:
    """The schedule with a second process: the free state judged on ``run.executor``
    beside the virtual fixture, which is given up (between two of its steps, or of the
    bending basis's) once the free state stands; the outcome is the sequential one
    (:func:`inspect`).

    The only function whose steps depend on the executor: the decisions it makes are
    :func:`_free_state_stands`' and :func:`_with_free_state`'s, as in the sequential
    schedule."""
    reg, ctx, params, timings, executor = run.reg, run.ctx, run.params, run.timings, run.executor
    pending = executor.submit(judge, reg, None, params, dict(timings), ctx, check_part=False)
    stood = _StoodCheck(pending)
    # one factorisation for the basis and the fixture: their matrices share a pattern, so
    # the symbolic analysis is made once (and never again for the part: the basis keeps its
    # fill-reducing order)
    solver = part_solver(reg.V, basis)
    try:
        if basis is None and _modal(params):
            # a new part's bending basis (a fixture's costliest step), built here and given
            # up between two of its solves once the free state stands
            t_basis = time.perf_counter()
            basis = bending_basis(ctx.prepared.ops, params.gbcicp.modes, solver=solver, check=stood)
            timings["bending basis"] = time.perf_counter() - t_basis

        def watched(k: int) -> None:  # between two fixture iterations, likewise
            stood()
            if run.progress is not None:
                run.progress(k)

        fit = _timed_fixture(run, basis, watched, solver)
        # the free-state zones take its deviation; else the fixtured judgement goes first
        free = _take(pending, timings) if _free_state_zones(ctx) else None
        res = judge(
            reg, fit, params, timings, ctx, free_deviation=_deviation(free), executor=executor
        )
        return _with_free_state(res, _take(pending, timings) if free is None else free)
    except _FreeStateStood:  # its fixture_decision is set (_free_state_stands)
        free = pending.result()
        # taken when it was done already (between two fixture steps), or waited for
        timings.setdefault("free state (waited)", 0.0)
        # the stages this process ran beside it: their sum is the inspection's wall time
        free.timings = dict(timings)
        return free
    finally:
        pending.cancel()


def _free_state_zones(ctx: JudgeContext) -> bool:
    """Whether a zone of the part is judged in its free state (a held part's too)."""
    return any(z.free_state for z in ctx.bands.zones)


def _deviation(free: InspectionResult | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The free state's vertex deviation and its variance, measured once (None: not
    judged)."""
    return None if free is None else (free.deviation, free.deviation_variance)


def _with_free_state(res: InspectionResult, free: InspectionResult | None) -> InspectionResult:
    """The fixtured judgement ``res`` with why it was fixtured and the free state's verdict
    (``free``: its judgement that did not stand; None: ``always_fixture``)."""
    res.fixture_decision = "always" if free is None else "free state does not conform"
    if free is not None:
        res.free_state = free.verdict
        res.free_state_decided_by = free.decided_by()
    return res


def _take(pending, timings: dict[str, float]) -> InspectionResult:
    """The pending free-state judgement's result (the time waited for it is a stage);
    :class:`_FreeStateStood` when it stands."""
    t0 = time.perf_counter()
    free = pending.result()
    timings["free state (waited)"] = time.perf_counter() - t0
    if _free_state_stands(free) is not None:
        raise _FreeStateStood
    return free


def _timed_fixture(
    run: _Run, basis: BendingBasis | None, progress, solver: SPDSolver | None = None
) -> DeformResult:
    """:func:`_virtual_fixture` of ``run``'s seated scan, its time a stage
    (``run.timings[params.method]``)."""
    t0 = time.perf_counter()
    params = run.params
    fit = _virtual_fixture(run.reg, params, run.ctx.prepared, run.zones, basis, progress, solver)
    run.timings[params.method] = time.perf_counter() - t0
    return fit


def _virtual_fixture(
    reg: Registered,
    params: InspectionParams,
    prepared: PreparedPart,
    zones: list[ToleranceZone],
    basis: BendingBasis | None,
    progress,
    solver: SPDSolver | None = None,
) -> DeformResult:
    """The free virtual fixture (``params.method``) on the rigidly seated scan (``solver``:
    GB-CICP's factorisation, one that built the bending basis; a new one if None)."""
    near_crease, near_rim = prepared.near_crease, prepared.near_rim
    flaggable = ~near_rim if near_crease is None else ~(near_rim | near_crease)
    # the two-pass guard counts no residual under a quarter of the tightest half-width
    tightest = min(z.half_width for z in zones)
    gb = replace(params.gbcicp, guard_floor=max(params.gbcicp.guard_floor, 0.25 * tightest))
    return deform(
        params.method,
        reg.V,
        reg.F,
        prepared.ops,
        reg.P,
        gb if method_spec(params.method).params_field is not None else None,
        scan_normals=reg.scan_normals,
        scan_sheets=reg.sheets,
        progress=progress,
        basis=basis,
        flaggable=flaggable,
        solver=solver,
    )


def _restrained(run: _Run, restraint: RestraintBasis) -> InspectionResult:
    """Hold the rigidly seated scan at its clamps
    (:func:`qifreport.metrology.restraint.held.hold_scan`)
    and judge it as held; the free-state zones are judged on the free state in the held
    seat, and the hold's uncertainty enters each deviation's."""
    reg, ctx, params, timings = run.reg, run.ctx, run.params, run.timings
    prepared = ctx.prepared

    def free_fit() -> np.ndarray:
        return _virtual_fixture(reg, params, prepared, run.zones, ctx.basis, run.progress).V

    held = hold_scan(
        reg.V,
        reg.F,
        reg.P,
        reg.scan_normals,
        reg.sheets,
        restraint,
        normals=prepared.ops.normals,
        free_fit=free_fit,
        face_id=ctx.face_id,
        brep_normals=ctx.brep_normals,
        tree=prepared.model.tree if prepared.model is not None else None,
        normal_k=params.gbcicp.scan_normal_k,
    )
    if "free fit" in held.seconds:
        timings[params.method] = held.seconds.pop("free fit")
    timings.update(held.seconds)
    res = judge(
        replace(reg, P=held.P, scan_normals=held.normals, sheets=held.sheets),
        None,
        params,
        timings,
        ctx,
        free=replace(reg, P=held.P_free),
        model_uncertainty=(held.u_vertex, held.u_point),
    )
    res.restraint = held.restraint
    res.fixture_decision = RESTRAINED
    return res
