"""The scoring stage: the judged deviation field, the scan points that judge it, the scan's
noise and the uncertainties (:func:`scoring_stage`)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from qifreport.metrology.acceptance.added import attached_to_surface
from qifreport.metrology.acceptance.decision import vertex_uncertainty
from qifreport.metrology.acceptance.point_regions import ScanSamples, scan_samples
from qifreport.metrology.acceptance.resolution import range_noise
from qifreport.metrology.deviation.surface import point_faces
from qifreport.metrology.params import InspectionParams

from .context import JudgeContext, Registered
from .deviation import Deviations
from .held import HeldNominal

__all__ = ["Scores", "scoring_stage"]


@dataclass(frozen=True)
class Scores:
    """The judged deviation field and what decides on it (:func:`scoring_stage`).

    Attributes
    ----------
    deviation : (n,) the judged vertex deviation, mm: the held state's, the free state's
        on the free-state zones' vertices.  variance : (n,) its variance, mm^2.
    free_vertices : (n,) bool the vertices governed by a free-state zone; None: the free
        state not measured.
    labels : (m,) B-rep face of each scan point (-1: none); None: a mesh nominal.
    samples : the scan points' local values and uncertainties.
    points_ok : (m,) bool the points that judge the surface (nearest vertex scored there,
        not added material, not a spike).
    noise : the scan's range noise, mm.
    uncertainty : (n,) expanded uncertainty of ``deviation``, mm, the instrument's surface
        term included (what the surfaces' decisions use).
    free_uncertainty : (n,) that of the free state's deviation, mm; None: not measured.
    own_uncertainty, own_free_uncertainty : the same without the instrument's term: the
        measurement's own, which a characteristic's budget starts from before adding the
        instrument term of its kind (:mod:`qifreport.metrology.gdt.budgets`).
    """

    deviation: np.ndarray
    variance: np.ndarray
    free_vertices: np.ndarray | None
    labels: np.ndarray | None
    samples: ScanSamples
    points_ok: np.ndarray
    noise: float
    uncertainty: np.ndarray
    free_uncertainty: np.ndarray | None
    own_uncertainty: np.ndarray
    own_free_uncertainty: np.ndarray | None


def scoring_stage(
    reg: Registered,
    nominal: HeldNominal,
    deviations: Deviations,
    ctx: JudgeContext,
    params: InspectionParams,
    timings: dict[str, float],
    model_uncertainty: tuple[np.ndarray, np.ndarray] | None = None,
) -> Scores:
    """The judged deviation field, the scan points that judge the surface with their local
    values, the scan's noise, and the expanded uncertainties (:class:`Scores`).

    Parameters
    ----------
    reg, nominal, deviations : the earlier stages'.  ctx : the judgement's context.
    params : the inspection's parameters (the instrument's surface term, mm:
        :attr:`~qifreport.metrology.params.InspectionParams.surface_uncertainty`).
    timings : seconds per stage, added to ("scan points", "resolution").
    model_uncertainty : expanded uncertainties the hold adds, mm, (n,) per vertex and (m,)
        per scan point, combined in quadrature with the scanner's; None: none.
    """
    d = deviations
    dev_all, var_all = d.vertex.copy(), d.variance.copy()
    free_v = None
    if d.free is not None:
        free_v = np.isin(
            ctx.bands.governing, [i for i, z in enumerate(ctx.bands.zones) if z.free_state]
        )
        dev_all[free_v] = d.free[free_v]
        var_all[free_v] = d.free_variance[free_v]
    # a STEP nominal's scan points grouped by their B-rep face: a thin wall's two skins are
    # kept apart in the noise estimate and in the points' own values
    plabel = None if ctx.face_id is None else point_faces(d.face, ctx.face_id)
    instrument = params.surface_uncertainty
    sys_vertices: float | np.ndarray = instrument
    sys_points: float | np.ndarray = instrument
    own_vertices: float | np.ndarray = 0.0
    if model_uncertainty is not None:
        sys_vertices = np.hypot(instrument, model_uncertainty[0])
        sys_points = np.hypot(instrument, model_uncertainty[1])
        own_vertices = model_uncertainty[0]
    t_pts = time.perf_counter()
    samples = scan_samples(
        nominal.V,
        reg.F,
        reg.P,
        d.point,
        d.closest,
        d.face,
        plabel,
        systematic=sys_points,
        tree=reg.scan_tree,
    )
    points_ok = _points_judging(samples, dev_all, free_v, ctx.general_half)
    timings["scan points"] = time.perf_counter() - t_pts
    t_noise = time.perf_counter()
    noise = range_noise(reg.P, labels=plabel)
    timings["resolution"] = time.perf_counter() - t_noise
    return Scores(
        deviation=dev_all,
        variance=var_all,
        free_vertices=free_v,
        labels=plabel,
        samples=samples,
        points_ok=points_ok,
        noise=noise,
        # the expanded uncertainty of each vertex's deviation, for the decision rule
        uncertainty=vertex_uncertainty(var_all, sys_vertices),
        free_uncertainty=None
        if d.free_variance is None
        else vertex_uncertainty(d.free_variance, instrument),
        own_uncertainty=vertex_uncertainty(var_all, own_vertices),
        own_free_uncertainty=None
        if d.free_variance is None
        else vertex_uncertainty(d.free_variance),
    )


def _points_judging(
    samples: ScanSamples, dev_all: np.ndarray, free_v: np.ndarray | None, general_half: float
) -> np.ndarray:
    """(m,) bool: the scan points that judge the surface. A point judges a surface where
    its nearest vertex is scored there (the same crease and rim bands), unless it is a
    spike or proud material standing apart from the part; the free-state zones of a held
    judgement are the free state's (no points)."""
    pvert = samples.vertex
    dev_pts = np.where(pvert >= 0, dev_all[np.maximum(pvert, 0)], np.nan)
    if free_v is not None:
        dev_pts[free_v[np.maximum(pvert, 0)]] = np.nan
    # a spike (a stray point near the surface, a burr of one point) judges nothing
    pts_ok = (pvert >= 0) & np.isfinite(dev_pts) & ~samples.spike
    # a point standing proud beyond the whole part's band is material the nominal does not
    # have: where it is continuous with the part's surface (a bump, flash, a rib) its
    # surface judges it; standing apart (an object in the scan) it is added material,
    # judged by its own policy (:mod:`qifreport.metrology.acceptance.added`)
    with np.errstate(invalid="ignore"):
        proud = pts_ok & (samples.value > general_half)
    apart = proud & ~attached_to_surface(samples.P, proud, pts_ok & ~proud, samples.spacing)
    return pts_ok & ~apart
