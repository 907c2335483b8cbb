"""One inspection, end to end on arrays: rigid alignment, virtual fixturing, deviation, verdict.

This is the library entry point. :func:`inspect` takes the nominal ``(V, F)`` and the scan
``P`` in mm and returns an :class:`~qifreport.metrology.results.InspectionResult`: the
registered nominal, the signed deviation field, its statistics and the acceptance decision
of the paper's Section 10 (area criterion and region criterion). It seats the scan
(:func:`seat_rigidly`: pose search, rigid fit) and judges it as the inspection's fixture
policy asks (:func:`judge_as_held`), in the condition the drawing or the operator states
(:class:`~qifreport.metrology.params.RestraintCondition`): the free state only; a virtual
restraint, the free state first and the virtual fixture (:func:`fixture_step`) when the
free state does not stand (:func:`free_state_stands`); or held at its clamps. Each judgement is
:func:`qifreport.metrology.judgement.judge`'s.

Everything runs here, one step after the other; each step is a public function, so a
caller with other processes (the command line, :mod:`qifreport.schedule`) can run some of
them elsewhere and get the same numbers.

Frames: the scan is moved into the nominal (CAD) frame once, by the rigid stage
(paper Section 3); everything reported (registered nominal, region centroids) is in the
nominal frame.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
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
from qifreport.metrology.gdt.pmi_plan import CharacteristicPlan
from qifreport.metrology.restraint.held import hold_scan, hold_too_far
from qifreport.registration.deformable.bending_basis import BendingBasis
from qifreport.registration.deformable.methods import METHODS, deform, method_spec
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import rigid_icp
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import bounding_diagonal, median_edge_length, vertex_normals
from qifreport.registration.normals import one_skin_normals
from qifreport.registration.outliers import StrayPoints, without_stray
from qifreport.registration.pose.prealign import seat_scan
from qifreport.registration.restraint.fixture_load import (
    DEFAULT_MAX_FORCE,
    HOLD_SHARE,
    FixtureLoad,
    LoadModel,
    fixture_load,
)
from qifreport.registration.restraint.restrained import RestraintBasis

from .judgement import judge
from .params import CLAMPS, FREE, InspectionParams
from .prepared import PreparedPart, prepare_part
from .results import (
    FREE_STATE_CONFORMS,
    FREE_STATE_LOCAL_DEFECTS,
    FREE_STATE_UNCERTAIN,
    RESTRAINED,
    InspectionResult,
    ZoneResult,
)
from .stages.context import JudgeContext, Registered
from .stages.rim_seat import seat_on_rim

__all__ = [
    "FREE_STATE_CONFORMS",
    "FREE_STATE_LOCAL_DEFECTS",
    "FREE_STATE_UNCERTAIN",
    "RESTRAINED",
    "InspectionInputs",
    "InspectionParams",
    "InspectionResult",
    "JudgeRun",
    "ZoneResult",
    "check_units",
    "checked_part",
    "default_zones",
    "fixture_and_judge",
    "fixture_step",
    "free_deviation",
    "free_state_stands",
    "free_state_zones",
    "hold_misfit",
    "inspect",
    "inspection_context",
    "judged_in_modes",
    "judge_as_held",
    "lay_zone_bands",
    "seat_rigidly",
    "surface_points",
    "with_fixture_load",
    "with_free_state",
    "with_stray",
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


@dataclass(frozen=True)
class InspectionInputs:
    """What an inspection may be given besides the nominal mesh, the scan and the
    parameters (:func:`inspect`): the part's B-rep faces and drawing, its clamps, the state
    prepared for it to reuse across its scans, and the scan's declared unit. Every field is
    optional: the default is a mesh nominal with one general zone.

    Attributes
    ----------
    zones : tolerance zones (:func:`qifreport.metrology.acceptance.bands.zones_from_pmi`);
        default one general zone of half-width ``params.tolerance``
        (:func:`default_zones`). Zones that cover no triangle are dropped.
    face_id, not_evaluated, solid, brep_normals, plan : the part's B-rep faces, PMI items
        not scored, solidity, exact corner normals and drawing characteristics, as
        :class:`~qifreport.metrology.stages.context.JudgeContext` holds them.
    restraint : the part's clamps and their elastic responses
        (:func:`qifreport.registration.restraint.restrained.restraint_basis` on this mesh),
        for ``params.fixture == "restrained"``: the rigidly seated scan is held at its
        clamps and judged as held (no virtual fixture, no free-state shortcut: the drawing
        says how the part is inspected).
    prepared : the nominal's scan-independent state
        (:func:`qifreport.metrology.prepared.prepare_part` with these ``params``), to reuse
        across scans of one part: operators, unscored bands, hygiene, bending basis (unless
        ``basis`` is given) and the pose search's model. ``ValueError`` if it was prepared
        for another mesh or other settings.
    basis : the nominal's GB-CICP bending basis
        (:func:`qifreport.registration.deformable.bending_basis.bending_basis`), to reuse it across
        scans of one part; computed when needed if omitted.
    scan_units : the unit the user declared for the scan file (for the units hint only).
    stray : the stray points the caller left out of the scan already
        (:func:`qifreport.registration.outliers.without_stray`, e.g. before starting its
        normals); None: :func:`inspect` leaves them out itself (:func:`surface_points`).
    fixture_load : the part's elastic model for the virtual fixture's load
        (:func:`qifreport.registration.restraint.fixture_load.load_model` on this mesh), or
        why there is none (a sentence naming what is needed); None: none given. A fixtured
        result carries the load (:func:`with_fixture_load`).
    """

    zones: list[ToleranceZone] | None = None
    face_id: np.ndarray | None = None
    not_evaluated: list[NotEvaluated] | None = None
    solid: bool = False
    brep_normals: np.ndarray | None = None
    plan: CharacteristicPlan | None = None
    restraint: RestraintBasis | None = None
    prepared: PreparedPart | None = None
    basis: BendingBasis | None = None
    scan_units: str | None = None
    fixture_load: LoadModel | str | None = None
    stray: StrayPoints | None = None


def surface_points(P: np.ndarray, inputs: InspectionInputs) -> tuple[np.ndarray, StrayPoints]:
    """The scan points ``P`` (m, 3) mm an inspection judges, those in a surface patch, and
    the stray ones left out (:mod:`qifreport.registration.outliers`): ``inputs.stray`` when
    the caller left them out already, else found here."""
    if inputs.stray is not None:
        return P, inputs.stray
    return without_stray(P)


def inspect(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    inputs: InspectionInputs | None = None,
    *,
    progress: Callable[[int], Any] | None = None,
) -> InspectionResult:
    """Inspect the scan ``P`` against the nominal ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points, mm, in any placement: a scan not already in the nominal frame
        is seated first by the pose search (``params.prealign``).
    params : :class:`InspectionParams`.
    inputs : the part's zones, B-rep, drawing, clamps and prepared state
        (:class:`InspectionInputs`); default: none.
    progress : optional callable ``progress(k)`` advanced once per iteration of the virtual
        fixture (``params.method``).

    Raises
    ------
    InputError
        Wrong units, or a scan that does not overlap the nominal after rigid alignment;
        :class:`qifreport.registration.pose.prealign.PoseNotEstablished` when no pose can be
        established.
    """
    inputs = InspectionInputs() if inputs is None else inputs
    timings: dict[str, float] = {}
    prepared, basis = checked_part(V, F, P, params, inputs, timings)
    P, stray = surface_points(P, inputs)
    reg = seat_rigidly(V, F, P, params, prepared, timings)
    run = inspection_context(reg, params, inputs, prepared, basis, timings, progress)
    return with_stray(judge_as_held(run, inputs.restraint), stray)


def with_stray(res: InspectionResult, stray: StrayPoints) -> InspectionResult:
    """The result with the stray points left out of its scan recorded (they bear on its
    verdict: :attr:`~qifreport.metrology.results.InspectionResult.stray`)."""
    res.stray = stray
    return res


@dataclass(frozen=True)
class JudgeRun:
    """What the judgements of one seated scan share (:func:`judge_as_held`'s inputs).

    Attributes
    ----------
    reg : the seated scan.  ctx : the judgements' context.  params : the parameters.
    zones : the zones as given, before those covering no triangle were dropped (the
        tightest sets the fixture's guard).
    timings : seconds per stage, added to.
    progress : :func:`inspect`'s.
    judge : how the free state and the fixtured part are judged:
        :func:`~qifreport.metrology.judgement.judge`, or a caller's function with its
        signature that gives it side work started elsewhere (the trim edges).
    """

    reg: Registered
    ctx: JudgeContext
    params: InspectionParams
    zones: list[ToleranceZone]
    timings: dict[str, float]
    progress: Callable[[int], Any] | None = None
    judge: Callable[..., InspectionResult] = judge


def inspection_context(
    reg: Registered,
    params: InspectionParams,
    inputs: InspectionInputs,
    prepared: PreparedPart,
    basis: BendingBasis | None,
    timings: dict[str, float],
    progress: Callable[[int], Any] | None = None,
) -> JudgeRun:
    """The judgements' shared inputs for the seated scan ``reg``: the zones (``inputs``' or
    :func:`default_zones`) laid on the nominal, the part's ``prepared`` state and bending
    ``basis`` (:func:`checked_part`), its B-rep and drawing (:class:`JudgeRun`)."""
    zones = default_zones(params) if inputs.zones is None else inputs.zones
    ctx = JudgeContext(
        prepared=prepared,
        bands=lay_zone_bands(reg.F, len(reg.V), inputs.face_id, zones),
        energy=prepared.energy,
        face_id=inputs.face_id,
        not_evaluated=inputs.not_evaluated,
        solid=inputs.solid,
        basis=basis,
        brep_normals=inputs.brep_normals,
        plan=inputs.plan,
        fixture_load=inputs.fixture_load,
    )
    return JudgeRun(reg, ctx, params, zones, timings, progress)


def judge_as_held(run: JudgeRun, restraint: RestraintBasis | None = None) -> InspectionResult:
    """The seated scan judged in the condition its parameters state
    (:attr:`~qifreport.metrology.params.InspectionParams.held_condition`, recorded in the
    result's ``params``): the free state only (:data:`~qifreport.metrology.params.FREE`),
    held at its clamps (``restraint``, :data:`~qifreport.metrology.params.CLAMPS`), or
    virtually restrained (:data:`~qifreport.metrology.params.VIRTUAL`): always fixtured, or
    in its free state first and fixtured only when that does not stand
    (:func:`free_state_stands`)."""
    reg, ctx, params, timings = run.reg, run.ctx, run.params, run.timings
    condition = params.held_condition.condition
    if condition == FREE:
        res = judge(reg, None, params, timings, ctx)
        res.fixture_decision = "rigid only"
        return res
    if condition == CLAMPS:
        if restraint is None:
            raise ValueError("a restrained inspection needs the part's restraint basis")
        if len(restraint.points) != len(reg.V):
            raise ValueError("the restraint basis was built for another mesh of the part")
        return _restrained(run, restraint)
    if params.always_fixture:
        return fixture_and_judge(run, ctx.basis)
    # ISO 10579 / Y14.5: restraint is there to bring a compliant part to its drawing shape;
    # the free state (no force) is one of the states a fixture may hold it in. When it
    # conforms on its own, no restraint is needed and none is simulated: a virtual fixture
    # can then only add its own error (a stiff part moved by it).
    t0 = time.perf_counter()
    free = run.judge(reg, None, params, dict(timings), ctx, check_part=False)
    decided = free_state_stands(free)
    if decided is not None:
        return decided
    timings["free state"] = time.perf_counter() - t0  # then the fixtured judgement's
    return fixture_and_judge(run, ctx.basis, free=free)


def checked_part(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    inputs: InspectionInputs,
    timings: dict[str, float],
) -> tuple[PreparedPart, BendingBasis | None]:
    """The inspection's method and units checked, and the part's prepared state
    (``inputs.prepared``, checked against ``(V, F)`` and ``params``, or made) with the
    bending basis to use; ``timings``: added to ("operators")."""
    if params.method not in METHODS:
        raise ValueError(f"unknown method {params.method!r} (one of {', '.join(METHODS)})")
    t0 = time.perf_counter()
    check_units(V, P, inputs.scan_units)
    prepared, basis = inputs.prepared, inputs.basis
    if prepared is None:
        prepared = prepare_part(V, F, params, basis=False, model=False)
    else:
        prepared.check(V, F, params)
        if basis is None:
            basis = prepared.basis
    timings["operators"] = time.perf_counter() - t0
    return prepared, basis


def seat_rigidly(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    prepared: PreparedPart,
    timings: dict[str, float],
) -> Registered:
    """The scan ``P`` (m, 3) seated on the nominal ``(V, F)``: the pose search, the rigid
    fit, the overlap check, and the seated scan's normals and sheets
    (:class:`~qifreport.metrology.stages.context.Registered`; its covered area is measured
    when first asked for, with the seated normals).

    The normals are fitted on one skin at a length of the part and signed per connected
    sheet along them (:func:`seated_normals`); each sheet's side is the scan's own where a
    wall's two skins show it, else a vote against the nominal's normals when the
    inspection asks. ``timings``: seconds per stage, added to. Raises :class:`InputError`
    when the seated scan does not overlap the nominal."""
    t0 = time.perf_counter()
    seat = seat_scan(V, F, P, mode=params.prealign, model=prepared.model)
    timings["prealign"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree = prepared.model.tree if prepared.model is not None else cKDTree(V)
    rigid = rigid_icp(V, prepared.ops.normals, P, R0=seat.R, t0=seat.t, tree=tree)
    rigid, on_rim = seat_on_rim(V, F, prepared.ops.normals, P, rigid, params.tolerance or 0.5)
    Pm = rigid.apply(P)
    timings["rigid"] = time.perf_counter() - t0
    diag = bounding_diagonal(V)
    d_near, near = tree.query(Pm, workers=-1)
    overlap = float(np.mean(d_near < 0.02 * diag))
    if overlap < 0.3 or rigid.inlier_fraction < 0.3:
        raise InputError(
            f"scan does not overlap the nominal: after rigid alignment only "
            f"{100 * overlap:.0f} % of the points lie within {0.02 * diag:.3g} mm of it"
        )
    t0 = time.perf_counter()
    Ns, sheets = seated_normals(Pm, V, F, prepared.ops.normals, near)
    timings["scan normals"] = time.perf_counter() - t0
    return Registered(
        V=V,
        F=F,
        P=Pm,
        rigid=rigid,
        seat=seat,
        scan_normals=Ns,
        sheets=sheets,
        diag=diag,
        rim_seat=on_rim,
    )


def seated_normals(
    P: np.ndarray, V: np.ndarray, F: np.ndarray, normals: np.ndarray, near: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The seated scan's normals (m, 3) fitted on one skin within one median edge of the
    nominal (the prior each point's nearest nominal vertex's normal) and signed per sheet
    along them, with the sheet labels
    (:func:`~qifreport.registration.normals.one_skin_normals`): a length of the part, so
    that a sparser scan of the same surface gets the same normals and the same sheets.

    Each sheet's side is the scan's own where it sees a wall's other skin, else its first
    point's prior's: a side the caller chooses again by a vote of the whole sheet
    (:func:`~qifreport.registration.deformable.result.orient_scan_normals`), so no earlier
    estimate of the scan's normals is needed.

    Parameters
    ----------
    P : (m, 3) the seated scan, mm.  V : (n, 3) the nominal, mm.  F : (f, 3) its triangles.
    normals : (n, 3) its unit vertex normals.  near : (m,) each point's nearest vertex.
    """
    prior = normals[near]
    return one_skin_normals(P, prior, prior, median_edge_length(V, F))


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


def free_state_stands(free: InspectionResult) -> InspectionResult | None:
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


def fixture_and_judge(
    run: JudgeRun, basis: BendingBasis | None, free: InspectionResult | None = None
) -> InspectionResult:
    """The virtual fixture (in ``basis``) and the judgement of the part as it holds it
    (``run.judge``), after the free state's judgement ``free`` that did not stand (None:
    ``always_fixture``, not judged), with the load a physical fixture would need
    (:func:`with_fixture_load`)."""
    fit = fixture_step(run, basis, run.progress)
    res = run.judge(
        run.reg, fit, run.params, run.timings, run.ctx, free_deviation=free_deviation(free)
    )
    return with_fixture_load(with_free_state(res, free), run, free)


def with_fixture_load(
    res: InspectionResult, run: JudgeRun, free: InspectionResult | None = None
) -> InspectionResult:
    """The fixtured judgement ``res`` with the load a physical fixture would need to hold
    the part in its virtual fixture's shape
    (:func:`~qifreport.registration.restraint.fixture_load.fixture_load` on the part's
    elastic model ``run.ctx.fixture_load``), checked against ``params.max_restraint_force``
    (default :data:`~qifreport.registration.restraint.fixture_load.DEFAULT_MAX_FORCE`), the
    material's yield strength and the part's compliant modes (:func:`judged_in_modes`):
    beyond any, a PASS is not established (:meth:`InspectionResult.trust_warnings`).
    Without a model the load is reported as not established and the verdict stands (no
    model, no force to bound). ``free``: the free state's judgement, when it was made."""
    if res.fit is None:
        return res
    t0 = time.perf_counter()
    lm = run.ctx.fixture_load
    if not isinstance(lm, LoadModel):
        res.fixture_load = FixtureLoad.not_established(
            lm or "no elastic model of the part was given (--material, a sheet's --thickness)"
        )
        return res
    limit = run.params.max_restraint_force
    source = "--max-restraint-force"
    if limit is None:
        limit, source = DEFAULT_MAX_FORCE, "default: none stated"
    misfit, of = hold_misfit(run.ctx.bands.zones)
    try:
        load = fixture_load(lm, run.reg.V, res.fit.V - run.reg.V, misfit, of)
    except ValueError as e:  # a model the fitted field cannot be solved on
        res.fixture_load = FixtureLoad.not_established(str(e))
        return res
    res.fixture_load = load.bounded(limit, source)
    run.timings["fixture load"] = time.perf_counter() - t0
    if res.passed and len(load.departure):
        t0 = time.perf_counter()
        load.beyond_modes = judged_in_modes(res, load, run, free)
        run.timings["compliant modes"] = time.perf_counter() - t0
    return res


def judged_in_modes(
    res: InspectionResult, load: FixtureLoad, run: JudgeRun, free: InspectionResult | None = None
) -> str:
    """Why the passing fixtured judgement ``res`` rests on a correction outside the part's
    compliant modes (empty: it does not).

    The virtual fixture's smooth field follows whatever its prior allows: the part's
    flexure, and also a dent or a bump wide enough for its bending basis. A fixture removes
    the flexure, which lies in the part's lowest elastic modes; a plastic dent lies outside
    them (the paper's Section 11). The part is judged again in the modal shape, the fitted
    nominal moved along its normals by the remainder outside those modes
    (:attr:`FixtureLoad.departure`); when that judgement does not pass, which of the two
    shapes the part is held in decides the verdict, and the data do not say: the PASS is
    not established, the failing reading named. A remainder within
    :data:`~qifreport.registration.restraint.fixture_load.HOLD_SHARE` of the tightest zone
    held cannot move a reading by more than a gauge's error: not judged again. ``free``:
    the free state's judgement, whose deviation the free-state zones take."""
    fit = res.fit
    normals = vertex_normals(fit.V, run.reg.F)
    along = np.einsum("ij,ij->i", load.departure, normals)
    largest = float(np.abs(along).max())
    if largest <= load.misfit_allowed:  # the hold's misfit (:func:`hold_misfit`)
        return ""
    modal = run.judge(
        run.reg,
        replace(fit, V=fit.V + along[:, None] * normals),
        run.params,
        {},
        run.ctx,
        free_deviation=free_deviation(free),
    )
    if modal.passed:
        return ""
    failed = modal.decided_by()
    return (
        f"the virtual fixture's correction departs by up to {largest:.3g} mm from the part's "
        f"{load.modes} compliant modes (its lowest elastic modes): held in them, it fails "
        f"({failed[0] if failed else 'a criterion'}); a dent or bump the fixture absorbed, "
        "or a restraint not stated: state the restraint (--clamps) to decide"
    )


def hold_misfit(zones: list[ToleranceZone]) -> tuple[float, str]:
    """The root-mean-square misfit, mm, the virtual fixture's load is measured within
    (:func:`~qifreport.registration.restraint.fixture_load.least_energy_hold`), and what it
    is a share of: :data:`~qifreport.registration.restraint.fixture_load.HOLD_SHARE` of
    the tightest of the ``zones`` judged as held (not in the free state), or of the default
    general band where none is."""
    held = [z for z in zones if not z.free_state]
    if not held:
        width = 2.0 * DEFAULT_GENERAL_TOLERANCE
        return HOLD_SHARE * width, f"{100 * HOLD_SHARE:g} % of the default band, {width:g} mm"
    tightest = min(held, key=lambda z: z.width)
    return HOLD_SHARE * tightest.width, (
        f"{100 * HOLD_SHARE:g} % of the tightest zone held, {tightest.key} {tightest.width:g} mm"
    )


def free_state_zones(ctx: JudgeContext) -> bool:
    """Whether a zone of the part is judged in its free state (a held part's too)."""
    return any(z.free_state for z in ctx.bands.zones)


def free_deviation(free: InspectionResult | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The free state's vertex deviation and its variance, measured once (None: not
    judged), for the fixtured judgement's free-state zones."""
    return None if free is None else (free.deviation, free.deviation_variance)


def with_free_state(res: InspectionResult, free: InspectionResult | None) -> InspectionResult:
    """The fixtured judgement ``res`` with why it was fixtured and the free state's verdict
    (``free``: its judgement that did not stand; None: ``always_fixture``)."""
    res.fixture_decision = "always" if free is None else "free state does not conform"
    if free is not None:
        res.free_state = free.verdict
        res.free_state_decided_by = free.decided_by()
    return res


def fixture_step(
    run: JudgeRun,
    basis: BendingBasis | None,
    progress: Callable[[int], Any] | None,
    solver: SPDSolver | None = None,
) -> DeformResult:
    """The virtual fixture (``params.method``) of ``run``'s seated scan in ``basis`` (None:
    built by the fixture when it needs one), its time a stage (``run.timings[method]``).

    ``progress(k)``: called between two of its iterations (it may raise to give the fixture
    up); ``solver``: GB-CICP's factorisation, one that built ``basis``
    (:func:`~qifreport.registration.deformable.bending_basis.part_solver`); a new one if None."""
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


def _restrained(run: JudgeRun, restraint: RestraintBasis) -> InspectionResult:
    """Hold the rigidly seated scan at its clamps
    (:func:`qifreport.metrology.restraint.held.hold_scan`)
    and judge it as held; the free-state zones are judged on the free state in the held
    seat, and the hold's uncertainty enters each deviation's. With
    ``params.judge_free_state`` the free state is judged too, in its own best fit, for what
    the outputs say it gave."""
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
    )
    far = hold_too_far(held, bounding_diagonal(reg.V))
    if far is not None:
        raise InputError(far)
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
    if params.judge_free_state:
        # what the free state gives, in its own best fit, for the outputs (it decides
        # nothing)
        t0 = time.perf_counter()
        free = run.judge(reg, None, params, {}, ctx, check_part=False)
        timings["free state"] = time.perf_counter() - t0
        res.free_state = free.verdict
        res.free_state_decided_by = free.decided_by()
    return res
