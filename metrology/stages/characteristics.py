"""The characteristics stage: the drawing's feature characteristics measured on the judged
surface and the zones' datum frames (:func:`characteristics_stage`)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from trimesh.triangles import points_to_barycentric

from qifreport.metrology.gdt.characteristic_types import CharacteristicResult
from qifreport.metrology.gdt.characteristics import frame_of, measure_characteristics
from qifreport.metrology.gdt.composite import composite_zone_frame
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.gdt.measured_surface import MeasuredSurface
from qifreport.metrology.params import InspectionParams

from .context import JudgeContext, Registered
from .deviation import Deviations
from .held import HeldNominal
from .scoring import Scores

__all__ = ["Characteristics", "characteristics_stage"]


@dataclass(frozen=True)
class Characteristics:
    """The drawing's characteristics measured (:func:`characteristics_stage`).

    Attributes
    ----------
    results : the feature characteristics, measured on the judged surface.
    frames : the datum reference frames established.
    zone_frames : the frame of each zone (by index in ``bands.zones``) that names datums,
        or a composite lower segment's own placement (None: not established at all).
    """

    results: list[CharacteristicResult]
    frames: list[DatumFrameResult]
    zone_frames: dict[int, DatumFrameResult | None]


def characteristics_stage(
    reg: Registered,
    nominal: HeldNominal,
    deviations: Deviations,
    scores: Scores,
    ctx: JudgeContext,
    params: InspectionParams,
    timings: dict[str, float],
) -> Characteristics:
    """The drawing's feature characteristics measured on the judged surface, and the frames
    of the profiles that name datums (Y14.5-2018 11.2.1) or are a composite's lower
    segment (:class:`Characteristics`; nothing without a plan, a B-rep nominal and its
    corner normals). ``timings``: seconds per stage, added to ("characteristics")."""
    plan, face_id, corners = ctx.plan, ctx.face_id, ctx.brep_normals
    if plan is None or face_id is None or corners is None:
        return Characteristics(results=[], frames=[], zone_frames={})
    t_feat = time.perf_counter()
    V, F, d = reg.V, reg.F, deviations
    surf = _measured_surface(
        V,
        F,
        nominal.V,
        face_id,
        corners,
        scores.deviation,
        scores.own_uncertainty,
        reg.P,
        d.closest,
        d.face,
        d.point,
        # a spike lies on no feature (a feature's form read on the points takes it whole)
        None if scores.labels is None else np.where(scores.samples.spike, -1, scores.labels),
        scores.samples.vertex,
        scores.points_ok,
        scores.noise,
    )
    free_surf = None
    if d.free is not None and scores.own_free_uncertainty is not None:
        free_surf = _measured_surface(
            V, F, V, face_id, corners, d.free, scores.own_free_uncertainty, *_no_points()
        )
    cache: dict = {}
    zone_frames: dict[int, DatumFrameResult | None] = {}
    for i, z in enumerate(ctx.bands.zones):
        if z.datums:
            use_free = z.free_state and free_surf is not None
            zone_frames[i] = frame_of(z.datums, plan.datums, free_surf if use_free else surf, cache)
        if z.composite == "lower":  # its own placement, in its frame's orientation
            zone_frames[i] = composite_zone_frame(
                zone_frames.get(i),
                V,
                ctx.prepared.ops.normals,
                scores.deviation - z.center,
                ctx.bands.governing == i,
                z.half_width,
            )
    feats, frames_used = measure_characteristics(
        plan.specs,
        plan.datums,
        surf,
        params.decision_rule,
        free_surface=free_surf,
        frames=cache,
        scanner=params.scanner,
    )
    timings["characteristics"] = time.perf_counter() - t_feat
    return Characteristics(results=feats or [], frames=frames_used or [], zone_frames=zone_frames)


def _measured_surface(
    V,
    F,
    V_reg,
    face_id,
    corner_normals,
    dev,
    U,
    P,
    C,
    cface,
    pdev,
    plabel,
    pvert,
    pok=None,
    noise=0.0,
) -> MeasuredSurface:
    """The judged surface for the feature characteristics: the vertices' deviations, and
    the scan points carried back through the fixture's displacement at their closest
    point (:class:`~qifreport.metrology.gdt.measured_surface.MeasuredSurface`). A point's
    expanded uncertainty is its nearest vertex's, and never below twice the scan's range
    noise ``noise`` (mm): one point is not the average a vertex's fit is."""
    if len(P):
        bary = points_to_barycentric(V_reg[F[cface]], C)
        u = np.einsum("ij,ijk->ik", bary, (V_reg - V)[F[cface]])
        P0 = P - u
        PU = np.where(pvert >= 0, U[np.maximum(pvert, 0)], np.nan)
        PU = np.where(np.isfinite(PU), PU, np.nanmedian(U) if np.isfinite(U).any() else 0.0)
        PU = np.maximum(PU, 2.0 * noise if np.isfinite(noise) else 0.0)
    else:
        P0, PU = P, np.empty(0)
    return MeasuredSurface(
        V,
        F,
        face_id,
        corner_normals,
        dev.copy(),
        U,
        P0,
        np.asarray(plabel),
        np.asarray(pdev),
        PU,
        None if pok is None else np.asarray(pok, dtype=bool),
        None if pok is None else np.asarray(pvert, dtype=np.int64),
        read_on_points=not len(P) or np.array_equal(V_reg, V),
    )


def _no_points() -> tuple:
    """Empty scan-point arrays for a surface measured on its vertices only."""
    e = np.empty(0)
    return (
        np.empty((0, 3)),
        np.empty((0, 3)),
        e.astype(np.int64),
        e,
        e.astype(np.int64),
        e.astype(np.int64),
    )
