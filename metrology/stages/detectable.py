"""The detectability stage: each surface's critical dent probed, its region criterion not
proven where the product cannot tell a failing region from a passing one
(:mod:`qifreport.metrology.deviation.detectable`)."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from qifreport.metrology.acceptance.bands import zone_vertex_areas
from qifreport.metrology.deviation.detectable import (
    Detectable,
    FixtureProbe,
    detectable_dent,
    interior_vertex,
    with_detectable,
)
from qifreport.metrology.params import InspectionParams
from qifreport.metrology.results import ZoneResult
from qifreport.registration.deformable.result import DeformResult

from .acceptance import Decisions, Measured
from .context import JudgeContext, Registered

__all__ = ["WIDTHS", "detectable_stage"]

#: the probed dent widths, in units of the region limit's own width ``sqrt(A / pi)``: the
#: binding one (the larger area read short) is kept
WIDTHS = (1.0, 1.5)


def detectable_stage(
    reg: Registered,
    fit: DeformResult | None,
    m: Measured,
    decisions: Decisions,
    ctx: JudgeContext,
    params: InspectionParams,
    timings: dict[str, float] | None = None,
) -> Decisions:
    """``decisions`` with each surface's detectable dent and its region criterion guarded
    by it (:func:`~qifreport.metrology.deviation.detectable.with_detectable`): the whole
    part's, and every zone's. The virtual fixture's absorption is probed on the fixtured
    surfaces; a free-state zone, a seated or a clamped part are read short by the ball fit
    alone. Its seconds go to ``timings["detectable"]``."""
    t0 = time.perf_counter()
    held = m.nominal
    probe = None
    if fit is not None and held.held:
        probe = FixtureProbe.of(fit, ctx.prepared.ops)
    dev = m.readings.deviation
    area = ctx.prepared.ops.area
    acc = decisions.acceptance
    u = _median_u(acc.uncertainty_mm)
    whole = _probe(reg, held.V, held.normals, area, dev, ctx.general_half, params, probe, u)
    acc = with_detectable(acc, whole)
    zones = [_zone(zr, i, reg, held, ctx, params, probe) for i, zr in enumerate(decisions.zones)]
    if timings is not None:
        timings["detectable"] = time.perf_counter() - t0
    return replace(decisions, acceptance=acc, zones=zones, detectable=whole)


def _zone(
    zr: ZoneResult,
    i: int,
    reg: Registered,
    held,
    ctx: JudgeContext,
    params: InspectionParams,
    probe: FixtureProbe | None,
) -> ZoneResult:
    """The zone result ``zr`` (zone ``i``) with its detectable dent and guard."""
    if zr.deviation is None or not np.isfinite(zr.deviation).any():
        return zr
    az = zone_vertex_areas(reg.V, reg.F, ctx.bands.tri_masks[i])
    det = _probe(
        reg,
        held.V,
        held.normals,
        az,
        zr.deviation,
        zr.zone.half_width,
        params,
        probe if zr.fixtured else None,
        _median_u(zr.acceptance.uncertainty_mm),
    )
    if det is None:
        return zr
    return replace(zr, acceptance=with_detectable(zr.acceptance, det), detectable=det)


def _probe(
    reg: Registered,
    V: np.ndarray,
    normals: np.ndarray,
    area: np.ndarray,
    dev: np.ndarray,
    half_width,
    params: InspectionParams,
    probe: FixtureProbe | None,
    uncertainty: float,
) -> Detectable | None:
    """The binding detectable dent over :data:`WIDTHS` of the surface ``area`` > 0 scored
    in ``dev``, or None (nothing scored, or no single band to probe)."""
    t = float(np.min(half_width)) if np.ndim(half_width) else float(half_width)
    if not (math.isfinite(t) and t > 0):
        return None
    site = interior_vertex(V, np.isfinite(dev) & (area > 0))
    if site is None:
        return None
    limit = params.max_region_area
    sigma_a = math.sqrt(limit / math.pi)
    found = [
        detectable_dent(
            V, reg.F, reg.P, normals, area, site, t, limit, uncertainty, probe, sigma=k * sigma_a
        )
        for k in WIDTHS
    ]
    return max(found, key=lambda d: d.lost_area_mm2)


def _median_u(u: tuple[float, float]) -> float:
    """The median expanded uncertainty of a surface, mm (0 when not known)."""
    return float(u[0]) if math.isfinite(u[0]) else 0.0
