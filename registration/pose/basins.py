"""From starts to ranked basins: steps 5-6 of :mod:`qifreport.registration.pose.prealign`.

Every start (:mod:`qifreport.registration.pose.starts`) is screened by a few point-to-point
ICP iterations on a small scan sample (:func:`screen_starts`); the survivors get the coarse
ICP on the full sample, the most promising of them more iterations (:func:`coarse_fits`).
The converged poses are grouped into *basins* -- poses that place the scan sample within
``basin * tau`` RMS of each other (:func:`group_basins`) -- and the best basin and its close
rivals get the converged refinement on all scan points, after which basins the refinement
brought together are merged (:func:`refine_basins`). Ranking is by the MSAC cost of
:func:`qifreport.registration.pose.fit.score_pose`. Poses map scan points into the model
frame, ``P_model = P @ R.T + t``; lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.registration.icp import RigidResult
from qifreport.registration.pose.fit import PoseFit, point_icp, refine_pose, score_pose
from qifreport.registration.pose.geometry import scan_displacement
from qifreport.registration.pose.model import PrealignParams, PreparedModel
from qifreport.registration.pose.starts import Start

__all__ = [
    "Candidate",
    "CoarseFit",
    "coarse_fits",
    "group_basins",
    "refine_basins",
    "screen_starts",
]

#: a start after the coarse ICP: its fit on the scan sample, ``R``, ``t`` and its kind
CoarseFit = tuple[PoseFit, np.ndarray, np.ndarray, str]


@dataclass
class Candidate:
    """One basin of the pose search.

    Attributes
    ----------
    R, t : pose (scan -> model), t in mm.  inlier_fraction : scan fraction within the gate.
    rms : residual, mm (coarse: trimmed point-to-point RMS on the sample; final: the robust
        point-to-plane RMS of :func:`~qifreport.registration.icp.rigid_icp`).
    support : starts that converged here.
    sources : kinds of those starts (``descriptor``, ``pca``, ``random``).  final : whether
    it got the robust refinement on all points.  cost : MSAC cost
    ``mean(min(d, tau)^2) / tau^2`` of the scan against the model (the ranking score).
    """

    R: np.ndarray
    t: np.ndarray
    inlier_fraction: float
    rms: float
    support: int
    sources: list[str]
    final: bool = False
    cost: float = 1.0


def screen_starts(
    model: PreparedModel, S: np.ndarray, starts: list[Start], tau: float, p: PrealignParams
) -> list[Start]:
    """The starts that go on to the coarse ICP.

    When there are more than ``screen_keep``, each start gets ``screen_iters`` point-to-point
    iterations on the first ``screen_points`` of the sample ``S``; the ``screen_keep``
    principal-axis / random starts of lowest cost and every descriptor start go on, in their
    original order, from their screened poses. Otherwise ``starts`` is returned unchanged.

    Parameters
    ----------
    model : the prepared nominal.  S : (k, 3) scan sample, mm.  starts : ``(R, t, kind)``.
    tau : gate, mm.  p : settings.
    """
    if p.screen_keep < len(starts):
        S0 = S[: p.screen_points]
        screened = []
        for R0, t0, src in starts:
            R, t, _ = point_icp(model, S0, R0, t0, p.screen_iters, p.icp_trim)
            screened.append((score_pose(model, S0, R, t, tau).cost, R, t, src))
        rest = [k for k in range(len(starts)) if starts[k][2] != "descriptor"]
        keep = sorted(rest, key=lambda k: screened[k][0])[: p.screen_keep]
        keep += [k for k in range(len(starts)) if starts[k][2] == "descriptor"]
        starts = [screened[k][1:] for k in sorted(keep)]
    return starts


def coarse_fits(
    model: PreparedModel, S: np.ndarray, starts: list[Start], tau: float, p: PrealignParams
) -> list[CoarseFit]:
    """Coarse point-to-point ICP of the sample ``S`` from every start, lowest cost first.

    Each start gets ``icp_iters`` iterations; then the best ``continue_starts`` (while their
    cost is within 3x the best, plus 1e-3) get ``2 icp_iters`` more: on a smooth part the
    ones still sliding along the shallow valley get the iterations they need to reach (or
    not) the best basin.

    Parameters
    ----------
    model : the prepared nominal.  S : (k, 3) scan sample, mm.  starts : ``(R, t, kind)``.
    tau : gate, mm.  p : settings.

    Returns
    -------
    ``(fit, R, t, kind)`` per start, sorted by ``fit.cost``.
    """
    coarse = []
    for R0, t0, src in starts:
        R, t, _ = point_icp(model, S, R0, t0, p.icp_iters, p.icp_trim)
        coarse.append((score_pose(model, S, R, t, tau), R, t, src))
    coarse.sort(key=lambda c: c[0].cost)
    for k, (fit, R, t, src) in enumerate(coarse[: p.continue_starts]):
        if fit.cost > 3.0 * coarse[0][0].cost + 1e-3:
            break
        R, t, _ = point_icp(model, S, R, t, 2 * p.icp_iters, p.icp_trim)
        coarse[k] = (score_pose(model, S, R, t, tau), R, t, src)
    coarse.sort(key=lambda c: c[0].cost)
    return coarse


def group_basins(
    coarse: list[CoarseFit], S: np.ndarray, tau: float, p: PrealignParams
) -> list[Candidate]:
    """Group the coarse poses into basins, in cost order.

    A pose joins the first basin whose representative places the sample ``S`` within
    ``basin * tau`` (RMS) of it (:func:`~qifreport.registration.pose.geometry.scan_displacement`),
    else it founds a new basin; the founder (the lowest-cost member) is the representative.

    Parameters
    ----------
    coarse : :func:`coarse_fits`, lowest cost first.  S : (k, 3) scan sample, mm.
    tau : gate, mm.  p : settings.
    """
    basins: list[Candidate] = []
    for fit, R, t, src in coarse:
        for b in basins:
            if scan_displacement(R, t, b.R, b.t, S) <= p.basin * tau:
                b.support += 1
                b.sources.append(src)
                break
        else:
            basins.append(Candidate(R, t, fit.frac, fit.rms, 1, [src], cost=fit.cost))
    return basins


def refine_basins(
    model: PreparedModel,
    P: np.ndarray,
    S: np.ndarray,
    basins: list[Candidate],
    tau: float,
    p: PrealignParams,
    seed: int,
) -> tuple[list[Candidate], list[Candidate], RigidResult | None]:
    """Robust refinement of the best basin and of the rivals whose coarse cost is close.

    At most ``final_basins`` basins, the best and those within ``1 + 2 ambiguity_margin`` of
    its coarse cost (plus 1e-3), get :func:`~qifreport.registration.pose.fit.refine_pose` on
    all scan points ``P`` and are re-scored there (``final = True``; the basins are updated
    in place). Refined basins that the refinement brought within ``basin * tau`` of the best
    are merged into it (their support and sources added to the best's).

    Parameters
    ----------
    model : the prepared nominal.  P : (m, 3) the scan, mm.  S : (k, 3) scan sample, mm.
    basins : :func:`group_basins`, best first.  tau : gate, mm.  p : settings.
    seed : seed of the refinement's sample.

    Returns
    -------
    finals : the refined basins that remain after merging, lowest cost first.
    others : the basins that were not refined, in their order.
    rigid : the final :class:`~qifreport.registration.icp.RigidResult` of ``finals[0]``.
    """
    top = basins[0].cost
    rigid_by_basin: dict[int, RigidResult] = {}
    for k, b in enumerate(basins[: p.final_basins]):
        if k > 0 and b.cost > top * (1.0 + 2.0 * p.ambiguity_margin) + 1e-3:
            break
        r = refine_pose(model, P, b.R, b.t, seed=seed)
        fit = score_pose(model, P, r.R, r.t, tau)
        b.R, b.t, b.final = r.R, r.t, True
        b.inlier_fraction, b.cost, b.rms = fit.frac, fit.cost, r.rms
        rigid_by_basin[id(b)] = r
    finals = sorted((b for b in basins if b.final), key=lambda b: b.cost)
    others = [b for b in basins if not b.final]
    best = finals[0]
    for b in finals[1:]:  # refinement may bring two coarse basins together
        if scan_displacement(b.R, b.t, best.R, best.t, S) <= p.basin * tau:
            best.support += b.support
            best.sources += b.sources
            b.support = 0
    finals = [best] + [b for b in finals[1:] if b.support > 0]
    return finals, others, rigid_by_basin.get(id(best))
