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
    ScanReading,
    detectable_dent,
    interior_vertex,
    with_detectable,
)
from qifreport.metrology.params import InspectionParams
from qifreport.metrology.results import ZoneResult
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.mesh import boundary_vertices, label_boundary_vertices

from .acceptance import Decisions, Measured
from .context import JudgeContext, Registered
from .held import HeldNominal

__all__ = ["WIDTHS", "detectable_stage"]

#: the probed dent widths, in units of the region limit's own width ``sqrt(A / pi)``: the
#: binding one (the least read share) is kept
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
    surfaces; a free-state zone, a seated or a clamped part are read short by the reading
    alone. Its seconds go to ``timings["detectable"]``."""
    t0 = time.perf_counter()
    held = m.nominal
    probe = None
    if fit is not None and held.held:
        probe = FixtureProbe.of(fit, ctx.prepared.ops)
    labels = point_label = None
    if ctx.face_id is not None:
        labels = np.asarray(ctx.face_id, dtype=np.int64)
        face = m.deviations.face
        point_label = np.where(face >= 0, labels[np.maximum(face, 0)], -1)
    spacing = m.scores.samples.spacing
    scan = ScanReading.of(held.V, reg.F, reg.P, reg.scan_tree, labels, point_label, spacing)
    prober = _Prober(reg, held, scan, params, _border(reg.F, ctx))
    acc = decisions.acceptance
    whole = prober(ctx.prepared.ops.area, m.readings.deviation, ctx.general_half, probe, acc)
    zones = []
    for i, zr in enumerate(decisions.zones):
        if zr.deviation is None:
            zones.append(zr)
            continue
        az = zone_vertex_areas(reg.V, reg.F, ctx.bands.tri_masks[i])
        fixture = probe if zr.fixtured else None
        det = prober(az, zr.deviation, zr.zone.half_width, fixture, zr.acceptance)
        zones.append(zr if det is None else _guarded(zr, det))
    if timings is not None:
        timings["detectable"] = time.perf_counter() - t0
    return replace(decisions, acceptance=with_detectable(acc, whole), zones=zones, detectable=whole)


def _border(F: np.ndarray, ctx: JudgeContext) -> np.ndarray:
    """(n,) bool: the vertices on the mesh's open boundary or on a B-rep face's edge."""
    n = len(ctx.prepared.ops.area)
    border = boundary_vertices(F, n)
    if ctx.face_id is not None:
        border |= label_boundary_vertices(F, ctx.face_id, n)
    return border


def _guarded(zr: ZoneResult, det: Detectable) -> ZoneResult:
    """The zone result ``zr`` with its detectable dent ``det`` and its region guard."""
    return replace(zr, acceptance=with_detectable(zr.acceptance, det), detectable=det)


class _Prober:
    """The binding detectable dent of a surface over :data:`WIDTHS`, one probe per site,
    band and fixture (the whole part and a zone over all of it share theirs)."""

    def __init__(
        self,
        reg: Registered,
        held: HeldNominal,
        scan: ScanReading,
        params: InspectionParams,
        border: np.ndarray,
    ):
        self.reg, self.V, self.normals = reg, held.V, held.normals
        self.scan, self.border = scan, border
        self.limit = params.max_region_area
        self.seen: dict[tuple, Detectable] = {}

    def __call__(self, area, dev, half_width, fixture, acc) -> Detectable | None:
        """The binding dent of the surface ``area`` > 0 scored in ``dev``, or None
        (nothing scored, or no band to probe)."""
        t = float(np.min(half_width)) if np.ndim(half_width) else float(half_width)
        if not (math.isfinite(t) and t > 0):
            return None
        site = interior_vertex(self.V, np.isfinite(dev) & (area > 0), self.border)
        if site is None:
            return None
        u = float(acc.uncertainty_mm[0]) if math.isfinite(acc.uncertainty_mm[0]) else 0.0
        key = (site, t, round(u, 6), fixture is not None, float(area.sum()))
        if key not in self.seen:
            sigma_a = math.sqrt(self.limit / math.pi)
            found = [
                detectable_dent(
                    self.V,
                    self.reg.F,
                    self.reg.P,
                    self.normals,
                    area,
                    site,
                    (t, self.limit, u),
                    fixture,
                    sigma=k * sigma_a,
                    scan=self.scan,
                )
                for k in WIDTHS
            ]
            self.seen[key] = min(found, key=_share)
        return self.seen[key]


def _share(d: Detectable) -> float:
    """The read share of a probed dent, the binding one the least (no region: last)."""
    share = d.read_share
    return share if math.isfinite(share) else math.inf
