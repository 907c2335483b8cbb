"""The judgement of one registered scan: deviations, tolerances, characteristics, verdict.

:func:`judge` takes the scan seated on the nominal (:class:`Registered`) and, when the part
is fixtured, the virtual fixture's fit, and measures and decides everything the result
reports (:class:`~qifreport.metrology.results.InspectionResult`): the vertices' and the scan
points' deviations, each tolerance zone's area and region criteria with the uncertainty,
coverage, the trim edges and the size, added material, the drawing's feature
characteristics in their datum frames. :func:`~qifreport.metrology.inspection.inspect`
decides which judgements an inspection makes (the free state, the fixtured part).

What one inspection's judgements share (the prepared part, its zones, its drawing) is a
:class:`JudgeContext`. :func:`judge` runs the stages of :mod:`qifreport.metrology.stages`
in order, each a public function with a typed output a library user can run and look at one
by one, then :func:`check_same_part` and :func:`assemble_result`. It runs them all here, in
this process; a caller with other processes may start the trim edges
(:func:`~qifreport.metrology.stages.trim_edges.trim_edge_stage`) elsewhere and give
:func:`judge` their pending result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from qifreport.errors import InputError
from qifreport.metrology.acceptance.added import AddedMaterial
from qifreport.metrology.acceptance.resolution import Resolution
from qifreport.metrology.deviation.edge_statistics import EdgeDeviation
from qifreport.metrology.deviation.size import SizeEstimate
from qifreport.metrology.stages.acceptance import Decisions, Measured, acceptance_stage
from qifreport.metrology.stages.added import added_stage
from qifreport.metrology.stages.characteristics import Characteristics, characteristics_stage
from qifreport.metrology.stages.context import JudgeContext, Registered
from qifreport.metrology.stages.detectable import detectable_stage
from qifreport.metrology.stages.deviation import Deviations, deviation_stage
from qifreport.metrology.stages.held import HeldNominal, held_nominal
from qifreport.metrology.stages.readings import Readings, located_readings
from qifreport.metrology.stages.resolution import residual_scatter
from qifreport.metrology.stages.scoring import Scores, scoring_stage
from qifreport.metrology.stages.trim_edges import measures_size, trim_edge_stage
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import RigidResult

from .params import InspectionParams
from .results import InspectionResult

__all__ = [
    "FAR_DIAGONAL",
    "FAR_HALF_WIDTHS",
    "MAX_FAR_SHARE",
    "Stages",
    "assemble_result",
    "check_same_part",
    "judge",
    "resolved",
]

#: a scan point this far from the fixtured nominal (in general half-widths, at least
#: :data:`FAR_DIAGONAL` of the diagonal) is explained by no defect or compliance
FAR_HALF_WIDTHS = 10.0
FAR_DIAGONAL = 0.01
#: share of such points above which, with a poor rigid fit or a fixture guard that fired,
#: the scan is not of this part
MAX_FAR_SHARE = 0.10


def check_same_part(
    point_dev: np.ndarray, half_width: float, diagonal: float, rigid: RigidResult, fit
) -> None:
    """Refuse a scan that is not of this part (:class:`InputError`: "scan does not match
    the nominal").

    After the virtual fixture a scan of the part lies within defects' reach of the nominal
    everywhere. The scan is refused when more than :data:`MAX_FAR_SHARE` of its points lie
    farther than ``max(FAR_HALF_WIDTHS * half_width, FAR_DIAGONAL * diagonal)`` from the
    fixtured nominal *and* the registration itself says so: fewer than 90 % rigid inliers, or
    the two-pass guard fired. Stray points (a fixture or the table in view) trip it too: the
    message says so, crop them.

    Parameters
    ----------
    point_dev : (m,) data-referenced deviation of each scan point, mm.
    half_width : the general zone's half-width, mm.  diagonal : the nominal's, mm.
    rigid : the rigid alignment.  fit : the virtual fixture's result, or None.
    """
    far_mm = max(FAR_HALF_WIDTHS * half_width, FAR_DIAGONAL * diagonal)
    d = np.abs(np.asarray(point_dev, dtype=np.float64))
    share = float(np.mean(~(d <= far_mm)))  # NaN (no correspondence) counts as far
    suspect = rigid.inlier_fraction < 0.9 or (fit is not None and fit.fallback)
    if share > MAX_FAR_SHARE and suspect:
        raise InputError(
            f"scan does not match the nominal: {100 * share:.1f} % of its points lie more than "
            f"{far_mm:.3g} mm from the fixtured part (rigid inliers "
            f"{100 * rigid.inlier_fraction:.0f} %): another part, or foreign objects in the scan"
        )


@dataclass(frozen=True)
class Stages:
    """Every stage's output of one judgement, for :func:`assemble_result`."""

    nominal: HeldNominal
    deviations: Deviations
    scores: Scores
    characteristics: Characteristics
    readings: Readings
    decisions: Decisions
    added: AddedMaterial
    resolution: Resolution
    edges: EdgeDeviation | None = None
    size: SizeEstimate | None = None


def assemble_result(
    reg: Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    ctx: JudgeContext,
    timings: dict[str, float],
    s: Stages,
) -> InspectionResult:
    """The :class:`InspectionResult` of one judgement from its stages' outputs."""
    d, decisions, near_crease = s.deviations, s.decisions, s.deviations.near_crease
    area = ctx.prepared.ops.area
    return InspectionResult(
        V=reg.V,
        F=reg.F,
        V_registered=s.nominal.V,
        P=reg.P,
        deviation=s.readings.deviation,
        deviation_variance=s.scores.variance,
        solid=ctx.solid,
        point_deviation=d.point,
        vertex_stats=decisions.vertex_stats,
        point_stats=decisions.point_stats,
        acceptance=decisions.acceptance,
        rigid=reg.rigid,
        fit=fit,
        params=params,
        scan_area=reg.scan_area,
        coverage_ceiling_ok=decisions.coverage_ceiling_ok,
        timings=timings,
        zones=decisions.zones,
        not_evaluated=list(ctx.not_evaluated or []),
        bands=ctx.bands,
        energy=ctx.energy,
        edge_excluded_area=float(area[near_crease].sum()) if near_crease is not None else 0.0,
        prealign=reg.seat,
        rim_seat=None if reg.rim_seat is None else reg.rim_seat.to_dict(),
        added=s.added,
        hygiene=d.hygiene,
        basis=s.nominal.basis,
        resolution=s.resolution,
        excluded=d.excluded,
        coverage=decisions.coverage,
        edges=s.edges,
        size=s.size,
        characteristics=s.characteristics.results,
        frames=s.characteristics.frames,
        spikes=s.scores.samples.spike,
        detectable=decisions.detectable,
    )


def judge(
    reg: Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    timings: dict[str, float],
    ctx: JudgeContext,
    *,
    check_part: bool = True,
    free_deviation: tuple[np.ndarray, np.ndarray] | None = None,
    free: Registered | None = None,
    model_uncertainty: tuple[np.ndarray, np.ndarray] | None = None,
    nominal: HeldNominal | None = None,
    trim_edges: Any = None,
) -> InspectionResult:
    """Judge the rigidly seated scan ``reg`` against the nominal as the fixture ``fit``
    holds it (``None``: the free state, the nominal where the rigid alignment put it): the
    stages of :mod:`qifreport.metrology.stages` in order.

    Parameters
    ----------
    reg : the seated scan.  fit : the virtual fixture's result, or None.
    params : the inspection's parameters.  ctx : what the inspection's judgements share.
    timings : seconds per stage, added to.
    check_part : refuse a scan that is not of this part (:func:`check_same_part`).
    free_deviation : the free state's (n,) vertex deviation, mm, and its variance, mm^2,
        when it was judged already (the zones with the free-state modifier take them
        instead of measuring again).
    free : the free state's registration when ``reg`` holds the scan otherwise
        (restrained): the free-state zones are judged on it.
    model_uncertainty : expanded uncertainties (mm, (n,) per vertex and (m,) per scan point)
        the hold adds, combined in quadrature with the scanner's.
    nominal : the nominal as held
        (:func:`~qifreport.metrology.stages.held.held_nominal` of these inputs), when the
        caller made it already; default: made here.
    trim_edges : the trim edges and the size
        (:func:`~qifreport.metrology.stages.trim_edges.trim_edge_stage` of these inputs)
        when the caller started them already: the value, or a pending result (anything
        with ``result()``, :func:`resolved`); default: measured here. Not read when the
        fixture reads no size (:func:`~qifreport.metrology.stages.trim_edges.measures_size`).
    """
    t0 = time.perf_counter()
    if nominal is None:
        nominal = held_nominal(reg, fit, ctx, params, restrained=free is not None)
    deviations = deviation_stage(reg, nominal, ctx, free_deviation=free_deviation, free=free)
    timings["deviation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    scores = scoring_stage(reg, nominal, deviations, ctx, params, timings, model_uncertainty)
    characteristics = characteristics_stage(reg, nominal, deviations, scores, ctx, params, timings)
    readings = located_readings(reg, scores, characteristics, ctx)
    if check_part:
        check_same_part(deviations.point, ctx.general_half, reg.diag, reg.rigid, fit)
    edges = size = None
    if measures_size(fit):
        t_edges = time.perf_counter()
        edges, size = (
            trim_edge_stage(reg, nominal, ctx, params)
            if trim_edges is None
            else resolved(trim_edges)
        )
        timings["edges"] = time.perf_counter() - t_edges
    measured = Measured(nominal, deviations, scores, readings)
    decisions = acceptance_stage(reg, measured, ctx, params)
    decisions = detectable_stage(reg, fit, measured, decisions, ctx, params, timings)
    added = added_stage(reg, deviations, scores, ctx, params)
    timings["metrology"] = time.perf_counter() - t0
    scatter = residual_scatter(
        reg, fit, deviations, scores, readings, decisions.zones, restrained=free is not None
    )
    stages = (nominal, deviations, scores, characteristics, readings, decisions, added, scatter)
    return assemble_result(reg, fit, params, ctx, timings, Stages(*stages, edges, size))


def resolved(value: Any) -> Any:
    """``value.result()`` for a pending result (a future, a call made elsewhere), else
    ``value`` itself."""
    result = getattr(value, "result", None)
    return result() if callable(result) else value
