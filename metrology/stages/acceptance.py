"""The acceptance stage: area, region and coverage criteria on the whole part and on each
tolerance zone (:func:`acceptance_stage`, :func:`zone_result`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse.csgraph import connected_components

from qifreport.metrology.acceptance.bands import BandField, ToleranceZone, zone_vertex_areas
from qifreport.metrology.acceptance.coverage import (
    Coverage,
    plausible_uncertainty,
    zone_coverage,
)
from qifreport.metrology.acceptance.criteria import Acceptance, evaluate
from qifreport.metrology.acceptance.point_regions import ScanSamples, SurfacePoints
from qifreport.metrology.acceptance.scan_area import coverage_ceiling_ok
from qifreport.metrology.acceptance.statistics import DeviationStats, deviation_statistics
from qifreport.metrology.deviation.detectable import Detectable
from qifreport.metrology.deviation.residual_fit import ball_radius
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.params import InspectionParams
from qifreport.metrology.results import ZoneResult
from qifreport.registration.mesh import adjacency, bounding_diagonal

from .context import JudgeContext, Registered
from .deviation import Deviations
from .held import HeldNominal
from .readings import Readings
from .scoring import Scores

__all__ = [
    "MIN_HOLE_VERTICES",
    "Decisions",
    "Measured",
    "acceptance_stage",
    "read_across",
    "zone_result",
]

#: the fewest vertices, joined by mesh edges, that make a hole in the scan
MIN_HOLE_VERTICES = 3


@dataclass(frozen=True)
class Measured:
    """The measuring stages' outputs the decisions read (:func:`acceptance_stage`)."""

    nominal: HeldNominal
    deviations: Deviations
    scores: Scores
    readings: Readings


@dataclass(frozen=True)
class Decisions:
    """The tolerance decisions on the readings (:func:`acceptance_stage`).

    Attributes
    ----------
    vertex_stats : area-weighted statistics of the judged deviation.
    point_stats : statistics of the scan points' deviation.
    acceptance : area and region criteria on the whole part.
    zones : each zone's result.
    coverage : the whole part's measured coverage.
    coverage_ceiling_ok : coverage does not exceed scan area / nominal area.
    detectable : the whole part's detectable dent
        (:func:`~qifreport.metrology.stages.detectable.detectable_stage`; None before it).
    """

    vertex_stats: DeviationStats
    point_stats: DeviationStats
    acceptance: Acceptance
    zones: list[ZoneResult]
    coverage: Coverage
    coverage_ceiling_ok: bool
    detectable: Detectable | None = None


def acceptance_stage(
    reg: Registered, m: Measured, ctx: JudgeContext, params: InspectionParams
) -> Decisions:
    """The area, region and coverage criteria on the whole part and on each zone
    (:class:`Decisions`), from the measuring stages' outputs ``m``.

    Beside a drawing's own tolerances, qifreport's default band is no requirement: it is
    judged where it was measured and its unmeasured patches are reported (each PMI zone
    keeps its rules).
    """
    V, F, bands, area = reg.V, reg.F, ctx.bands, ctx.prepared.ops.area
    deviations, scores, readings = m.deviations, m.scores, m.readings
    general_half, dev_all = ctx.general_half, readings.deviation
    vstats = deviation_statistics(dev_all, weights=area, threshold=general_half)
    # the scan points' statistics are over the points that judge something: not a spike
    spiked = np.where(scores.samples.spike, np.nan, deviations.point)
    pstats = deviation_statistics(spiked, threshold=general_half)
    points = _surface_points(
        scores.samples,
        scores.points_ok,
        bands.half_width,
        readings.point_center,
        readings.point_uncertainty,
    )
    acc = _acceptance(V, F, dev_all, bands, area, readings.uncertainty, points, params)
    advisory = any(z.source == "default" for z in bands.zones) and any(
        z.faces is not None for z in bands.zones
    )
    across = read_across(reg, m.nominal.V)
    zones = [
        zone_result(i, reg, m, ctx, params, advisory=advisory, across=across)
        for i in range(len(bands.zones))
    ]
    excluded, n_points = deviations.excluded, int(scores.points_ok.sum())
    whole = _coverage(
        V,
        F,
        dev_all,
        bands,
        area,
        excluded,
        params.min_coverage,
        params,
        advisory,
        n_points,
        across,
    )
    whole = plausible_uncertainty(whole, acc.uncertainty_mm[1], bounding_diagonal(V))
    # the ceiling catches a deformable fit that met points of other features; a B-rep's free
    # state is rigid and scores each vertex from its own faces' points only, while the
    # scan-area estimate merges the two skins of a wall thinner than a point neighbourhood
    # (NIST CTC 03, 1.9 mm walls: 65 % "scanned" against 94 % scored)
    ceiling = m.nominal.to_creases or coverage_ceiling_ok(
        acc.coverage, reg.scan_area, acc.nominal_area
    )
    return Decisions(
        vertex_stats=vstats,
        point_stats=pstats,
        acceptance=acc,
        zones=zones,
        coverage=whole,
        coverage_ceiling_ok=ceiling,
    )


def zone_result(
    i: int,
    reg: Registered,
    m: Measured,
    ctx: JudgeContext,
    params: InspectionParams,
    *,
    advisory: bool = False,
    across: np.ndarray | None = None,
) -> ZoneResult:
    """The result of zone ``i`` of ``ctx.bands``: its deviation (the free state's for a
    free-state zone of a held part; in its datum frame when located), statistics, area and
    region criteria (on its scan points too, unless the free state's), and measured
    coverage (``advisory``: its gaps reported, not failed, for qifreport's default band
    beside a drawing's zones; ``across``: the vertices read across a hole in the scan,
    :func:`read_across`)."""
    V, F, normals = reg.V, reg.F, ctx.prepared.ops.normals
    deviations, scores, readings = m.deviations, m.scores, m.readings
    z, mask = ctx.bands.zones[i], ctx.bands.tri_masks[i]
    az = zone_vertex_areas(V, F, mask)
    use_free = z.free_state and deviations.free is not None
    dz = np.where(az > 0, deviations.free if use_free else deviations.vertex, np.nan)
    frame = readings.zone_frames.get(i)
    located = i in readings.located
    zU = scores.free_uncertainty if use_free else readings.uncertainty
    zcenter, zpU = z.center, 0.0
    if located:
        shift = frame.normal_shift(V, normals)
        dz = dz + shift
        zcenter = z.center - shift
        zpU = frame.shift_uncertainty(V, normals)
        own_U = scores.free_uncertainty if use_free else scores.uncertainty
        zU = np.hypot(own_U, zpU)
    points, n_points = None, None
    if not use_free:
        on_zone = scores.points_ok & mask[np.maximum(deviations.face, 0)]
        points = _surface_points(scores.samples, on_zone, z.half_width, zcenter, zpU)
        n_points = int(on_zone.sum())
    zacc = _acceptance(V, F[mask], dz, z, az, zU, points, params)
    zstats = deviation_statistics(dz, weights=az, threshold=z.half_width)
    min_coverage = params.min_coverage if z.min_coverage is None else z.min_coverage
    advisory = advisory and z.source == "default"
    excluded = deviations.excluded
    zcov = _coverage(
        V, F[mask], dz, z, az, excluded, min_coverage, params, advisory, n_points, across
    )
    zcov = plausible_uncertainty(zcov, zacc.uncertainty_mm[1], bounding_diagonal(V))
    if z.datums and not located:
        zcov = _frame_required(zcov, z, frame)
    return ZoneResult(
        zone=z,
        stats=zstats,
        acceptance=zacc,
        fixtured=m.nominal.held and not use_free,
        deviation=dz,
        coverage=zcov,
        reading=_zone_reading(z, frame, located),
        judged=not (z.source == "default" and ctx.drawing_decides),
    )


def _acceptance(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    band: BandField | ToleranceZone,
    area: np.ndarray,
    uncertainty: np.ndarray,
    points: SurfacePoints | None,
    params: InspectionParams,
) -> Acceptance:
    """:func:`evaluate` of the surface ``F`` against ``band``'s half-width and centre, by
    the inspection's criteria and decision rule."""
    return evaluate(
        V,
        F,
        dev,
        band.half_width,
        area=area,
        min_fraction=params.min_fraction,
        max_region_area=params.max_region_area,
        center=band.center,
        uncertainty=uncertainty,
        decision_rule=params.decision_rule,
        points=points,
    )


def _coverage(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    band: BandField | ToleranceZone,
    area: np.ndarray,
    excluded: np.ndarray,
    min_coverage: float,
    params: InspectionParams,
    advisory: bool,
    points: int | None,
    across: np.ndarray | None = None,
) -> Coverage:
    """:func:`zone_coverage` of the surface ``F`` in ``band`` with the inspection's region
    and gap limits (``advisory``: its gaps reported only), its ``points`` scan points
    (None: no density rule) and the vertices read ``across`` a hole in the scan."""
    return zone_coverage(
        V,
        F,
        dev,
        area,
        excluded,
        center=band.center,
        half_width=band.half_width,
        min_coverage=min_coverage,
        max_region_area=params.max_region_area,
        max_gap_area=params.max_gap_area,
        advisory_gaps=advisory,
        points=points,
        read_across=across,
    )


def read_across(reg: Registered, V: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices of the held nominal ``V`` (n, 3) mm with no point of the
    seated scan within half the deviation's first ball
    (:func:`~qifreport.metrology.deviation.residual_fit.ball_radius`, at least 2.5 point
    spacings), in groups of at least :data:`MIN_HOLE_VERTICES` joined by mesh edges: a
    vertex scored there is read across a hole in the scan, from its rim (a lone one is a
    sparse spot of a randomly sampled scan, not a hole)."""
    tree = reg.scan_tree
    r = 0.5 * ball_radius(V, reg.F, reg.P, tree)
    far = ~np.isfinite(tree.query(V, distance_upper_bound=r)[0])
    idx = np.flatnonzero(far)
    if not len(idx):
        return far
    _, label = connected_components(adjacency(reg.F, len(V))[idx][:, idx], directed=False)
    far[idx] = np.bincount(label)[label] >= MIN_HOLE_VERTICES
    return far


def _frame_required(cov: Coverage, z: ToleranceZone, frame: DatumFrameResult | None) -> Coverage:
    """``cov``, not measured: the zone references datums whose frame was not established
    (ASME Y14.5, ISO 1101: a datum-referenced zone is located by its frame; read best fit
    it would judge another requirement). The reason names the frame and what it lacked."""
    lacked = "; ".join(frame.problems) if frame is not None and frame.problems else ""
    why = (
        f"datum frame |{'|'.join(z.datums)}| not established"
        + (f" ({lacked})" if lacked else " (its datums are not defined on the part)")
        + ": a datum-referenced tolerance is measured in its frame or not at all"
    )
    return replace(cov, measured=False, reasons=[*cov.reasons, why])


def _zone_reading(z: ToleranceZone, frame: DatumFrameResult | None, located: bool) -> str:
    """How a zone's deviation was read: best fit, or in its datum frame (``located``: the
    frame established), or a composite lower segment at its own placement."""
    if located:
        labels = "|".join(frame.labels)
        if z.composite == "lower":
            return "composite lower segment: zone placed at its minimax position" + (
                f", orientation in |{labels}|" if frame.labels else ""
            )
        reading = f"datum frame |{labels}|"
        if frame.free:
            reading += " (best fit: " + ", ".join(frame.free) + ")"
        return reading
    if frame is not None:
        return "best fit (datum frame not established: " + "; ".join(frame.problems) + ")"
    return "best fit"


def _surface_points(
    samples: ScanSamples, sel: np.ndarray, half_width, center, extra_U=0.0
) -> SurfacePoints:
    """The points ``sel`` (m,) bool of ``samples`` with the band of their nearest vertex
    (``half_width``, ``center``, ``extra_U``: scalars or (n,) per vertex, mm)."""
    idx = np.flatnonzero(sel)
    v = samples.vertex[idx]

    def per_point(x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return np.full(len(idx), float(x)) if x.ndim == 0 else x[v]

    return SurfacePoints(
        samples=samples,
        index=idx,
        tolerance=per_point(half_width),
        center=per_point(center),
        extra_U=per_point(extra_U),
    )
