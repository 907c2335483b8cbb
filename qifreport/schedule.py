"""The inspection on two processes: the command's side work beside its main line.

The library's :func:`qifreport.metrology.inspection.inspect` makes every step in this
process, one after the other. A command with a second CPU (a forked child,
:mod:`qifreport.forked`) makes some of them beside the rest, from the library's public
steps: :func:`inspect_beside` judges the free state beside the virtual fixture, which is
given up once the free state stands, and measures the trim edges beside each judgement made
here (:func:`judge_beside`).

The outcome is the sequential one: every decision is the library's
(:func:`~qifreport.metrology.inspection.free_state_stands`,
:func:`~qifreport.metrology.inspection.with_free_state`); only the time differs.
"""

from __future__ import annotations

import functools
import time
from dataclasses import replace

import numpy as np

from qifreport.metrology.acceptance.bands import ToleranceZone
from qifreport.metrology.inspection import (
    InspectionInputs,
    InspectionParams,
    InspectionResult,
    JudgeRun,
    checked_part,
    fixture_step,
    free_deviation,
    free_state_stands,
    free_state_zones,
    inspection_context,
    judge_as_held,
    seat_rigidly,
    surface_points,
    with_fixture_load,
    with_free_state,
    with_stray,
)
from qifreport.metrology.judgement import judge
from qifreport.metrology.params import VIRTUAL
from qifreport.metrology.stages.context import JudgeContext, Registered
from qifreport.metrology.stages.held import held_nominal
from qifreport.metrology.stages.trim_edges import measures_size, trim_edge_stage
from qifreport.registration.deformable.bending_basis import bending_basis, part_solver
from qifreport.registration.deformable.methods import method_spec
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import RigidResult

__all__ = [
    "FIXTURE_LIKELY",
    "fixture_likely",
    "inspect_beside",
    "judge_beside",
]


def inspect_beside(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    inputs: InspectionInputs | None = None,
    *,
    executor=None,
    progress=None,
) -> InspectionResult:
    """:func:`qifreport.metrology.inspection.inspect` (same arguments, same result) with
    side work on ``executor``.

    Parameters
    ----------
    V, F, P, params, inputs, progress : as :func:`~qifreport.metrology.inspection.inspect`'s.
    executor : an object whose ``submit(fn, *args, **kwargs)`` returns a future (with
        ``result()`` and ``cancel()``, and ``done()`` to give up the fixture early), e.g. a
        :class:`concurrent.futures.Executor` or the command line's forked child
        (:class:`qifreport.forked.ForkExecutor`). Given to it: the free-state judgement
        (beside the virtual fixture, which is given up once the free state stands) and the
        trim edges of the judgements made here. Default: everything here, in the library's
        order.
    """
    inputs = InspectionInputs() if inputs is None else inputs
    timings: dict[str, float] = {}
    prepared, basis = checked_part(V, F, P, params, inputs, timings)
    P, stray = surface_points(P, inputs)
    reg = seat_rigidly(V, F, P, params, prepared, timings)
    run = inspection_context(reg, params, inputs, prepared, basis, timings, progress)
    if executor is None:
        return with_stray(judge_as_held(run, inputs.restraint), stray)
    run = replace(run, judge=functools.partial(judge_beside, executor))
    if _held_as_asked(params) or not fixture_likely(reg.rigid, run.zones):
        return with_stray(judge_as_held(run, inputs.restraint), stray)
    return with_stray(_free_state_beside_fixture(run, executor), stray)


def judge_beside(
    executor,
    reg: Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    timings: dict[str, float],
    ctx: JudgeContext,
    **options,
) -> InspectionResult:
    """:func:`~qifreport.metrology.judgement.judge` (its arguments and ``options``) with the
    trim edges measured on ``executor`` beside its other stages."""
    nominal = held_nominal(reg, fit, ctx, params, restrained=options.get("free") is not None)
    trim = None
    if measures_size(fit):
        reg.scan_tree  # noqa: B018 - built once, before a child would build its own
        trim = executor.submit(trim_edge_stage, reg, nominal, ctx, params)
    return judge(reg, fit, params, timings, ctx, nominal=nominal, trim_edges=trim, **options)


def _held_as_asked(params: InspectionParams) -> bool:
    """Whether the inspection's fixture policy leaves no free-state shortcut: the free state
    only, restrained at its clamps, or always fixtured."""
    return params.held_condition.condition != VIRTUAL or params.always_fixture


#: the rigid seat's robust residual scale, in units of the tightest zone's half-width, from
#: which the virtual fixture is started beside the free state's judgement. Measured: the
#: compliant sample parts seat at 0.6-1.9 and the fandisk of ``bench/fandisk_command.py``
#: (bent and twisted, its free state fails) at 0.19; the NIST machined parts' perfect
#: scans at 0.02-0.18 (0.02-0.08 for five of the seven)
FIXTURE_LIKELY = 0.1


def fixture_likely(rigid: RigidResult, zones: list[ToleranceZone]) -> bool:
    """Whether the rigid seat leaves the part far enough from its drawing shape that its
    free state may well not conform: its robust residual scale reaches a tenth of the
    tightest zone's half-width.

    Only the schedule depends on it, never the result: whether the fixture starts beside
    the free state's judgement or after it, if it does not stand. A wrong guess costs time,
    not a verdict: a fixture started for a free state that stands wastes the CPU it took (a
    stiff part's bending basis, a large cost), and one not started for a free state that
    fails waits for the judgement (a small one); hence a low bar. A seat well inside the
    tightest zone (a stiff part) is judged in its free state first, here, its trim edges
    beside it."""
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
        if done is not None and done() and free_state_stands(self.pending.result()):
            raise _FreeStateStood


def _free_state_beside_fixture(run: JudgeRun, executor) -> InspectionResult:
    """The free state judged on ``executor`` beside the virtual fixture, which is given up
    (between two of its steps, or of the bending basis's) once the free state stands; the
    outcome is the sequential one (:func:`~qifreport.metrology.inspection.judge_as_held`).

    The decisions it makes are the library's
    (:func:`~qifreport.metrology.inspection.free_state_stands`,
    :func:`~qifreport.metrology.inspection.with_free_state`), as in the sequential
    schedule."""
    reg, ctx, params, timings, basis = run.reg, run.ctx, run.params, run.timings, run.ctx.basis
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

        fit = fixture_step(run, basis, watched, solver)
        # the free-state zones take its deviation; else the fixtured judgement goes first
        free = _take(pending, timings) if free_state_zones(ctx) else None
        res = run.judge(reg, fit, params, timings, ctx, free_deviation=free_deviation(free))
        free = _take(pending, timings) if free is None else free
        return with_fixture_load(with_free_state(res, free), run, free)
    except _FreeStateStood:  # its fixture_decision is set (free_state_stands)
        free = pending.result()
        # taken when it was done already (between two fixture steps), or waited for
        timings.setdefault("free state (waited)", 0.0)
        # the stages this process ran beside it: their sum is the inspection's wall time
        free.timings = dict(timings)
        return free
    finally:
        pending.cancel()


def _take(pending, timings: dict[str, float]) -> InspectionResult:
    """The pending free-state judgement's result (the time waited for it is a stage);
    :class:`_FreeStateStood` when it stands."""
    t0 = time.perf_counter()
    free = pending.result()
    timings["free state (waited)"] = time.perf_counter() - t0
    if free_state_stands(free) is not None:
        raise _FreeStateStood
    return free
