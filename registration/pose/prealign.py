"""Pose-free pre-registration of a scan onto the nominal (paper Section 5.1, Algorithm 1).

A scanner's frame bears no relation to the CAD frame. :func:`prealign` recovers the rigid
transform that carries the scan ``P`` into the model frame from any initial placement, and
refuses (:class:`PoseNotEstablished`) when it cannot establish one.

Pipeline
--------
1. Curvature fields ``H, K, S, C`` on the mesh (cotangent mean-curvature normal, angle
   defect) and on the scan (local quadric fits, :mod:`qifreport.registration.pose.curvature`),
   brought to one resolution by a small area-weighted average
   (:func:`qifreport.registration.pose.descriptors.presmooth`); the model side once per part
   (:func:`~qifreport.registration.pose.model.prepare_model`).
2. Geodesic bilateral filtering at ``L`` scales ``rho h`` (``h`` the model's mean edge
   length) at farthest-point keypoints of each side (Dijkstra balls of ``3 sigma_s``); range
   bandwidth ``max(r0 spread, c eta)`` from the scan noise ``eta`` measured in each field's
   units (:mod:`qifreport.registration.pose.descriptors`).
3. Heavy tails compressed (``asinh(f / (3 eta_f))``), joint z-score over model and scan.
   Matching keeps the ``salient`` half of the keypoints (by filtered curvedness: flat
   patches all look alike) and pairs each scan keypoint with its ``match_k`` nearest model
   descriptors (``match_k = 0``: the paper's mutual nearest neighbours with Lowe's ratio
   test). The global sign of the scan normals cannot be known from points alone, so both
   signs are matched.
4. RANSAC on triplets (:func:`~qifreport.registration.pose.starts.ransac_triplets`):
   compatibility-guided draws (pairwise distances must agree within the gate), Kabsch fit,
   inlier count under the absolute gate ``tau = gate * diagonal``; the best distinct
   hypotheses are re-scored on a sample of *all* scan points by the MSAC cost
   (:func:`~qifreport.registration.pose.fit.score_pose`).
5. Restarts as in the paper's Section 8.4.2: principal-axis hypotheses (the 24 proper
   signed permutations mapping the scan's PCA axes onto the model's; the first four are the
   paper's sign combinations) and ``random_restarts`` uniformly random rotations, all
   centroid-aligned. Every start is screened by a few ICP iterations; the best
   ``screen_keep`` and the descriptor hypotheses go on.
6. Each surviving start is refined by trimmed point-to-point ICP on a sample of the scan;
   the converged poses are grouped into *basins* (poses that place the scan within
   ``basin * tau`` RMS of each other). The best basin -- and any rival within the ambiguity
   margin -- gets :func:`~qifreport.registration.pose.fit.refine_pose`: point-to-point ICP on
   all vertices, then the robust rigid fit of the foundation
   (:func:`qifreport.registration.icp.converged_rigid_fit`) on all scan points
   (:mod:`qifreport.registration.pose.basins`).

Acceptance rule
---------------
Basins are ranked by the MSAC cost ``mean(min(d, tau)^2) / tau^2`` of all scan points after
the final refinement (it rewards overlap and closeness together; an inlier fraction alone
saturates on a smooth part under a loose gate). The winner is accepted when

* at least ``min_inlier_fraction`` of the scan lies within ``tau`` of the model (the scan
  overlaps the part), and
* at least ``min_agreement`` independent starts converged into its basin (restart
  agreement, paper Section 8.4.2: "several distinct starts converge to the same basin").

Otherwise :class:`PoseNotEstablished` is raised with the numbers. When another basin's cost
is within ``ambiguity_margin`` (relative) of the winner's, the part is symmetric or nearly so
*for this scan*: the result is returned with ``ambiguous = True`` and the rival among
``candidates``, and a warning is logged; it is the caller's decision whether to trust it
(a datum reference frame resolves it).

Conventions: all lengths in mm. ``R, t`` map scan points into the model frame,
``P_model = P @ R.T + t`` (as :class:`qifreport.registration.icp.RigidResult`); the posed
nominal of the paper's Algorithm 1, ``V0 = R' V + t'``, is :meth:`PrealignResult.model_pose`.

Modules
-------
This module is the search's entry points (:func:`seat_scan`, :func:`prealign`,
:func:`already_in_frame`), its acceptance rule and its confidence report
(:class:`PrealignResult`). The steps live in

* :mod:`qifreport.registration.pose.model` -- settings, the prepared model and scan sides;
* :mod:`qifreport.registration.pose.starts` -- descriptor matching, RANSAC on triplets,
  principal-axis and random starts;
* :mod:`qifreport.registration.pose.fit` -- the MSAC score, the point-to-point ICP and the
  converged refinement;
* :mod:`qifreport.registration.pose.basins` -- screening, coarse ICP, basin grouping, the final
  refinement and merge;
* :mod:`qifreport.registration.pose.geometry` -- rotation angles, pose distances, principal
  axes.

The names other code imports from here (:class:`PreparedModel`, :func:`prepare_model`,
:class:`PrealignParams`, :func:`refine_pose`, :func:`score_pose`, :func:`pose_distance`, ...)
are re-exported (``__all__``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from qifreport.errors import InputError
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.icp import RigidResult, pose_conditioning, rigid_icp
from qifreport.registration.mesh import bounding_diagonal, vertex_normals, wall_thickness
from qifreport.registration.pointcloud import validate_scan
from qifreport.registration.pose.basins import (
    Candidate,
    coarse_fits,
    group_basins,
    refine_basins,
    screen_starts,
)
from qifreport.registration.pose.fit import PoseFit, refine_pose, score_pose
from qifreport.registration.pose.geometry import pose_distance, rotation_angle_deg
from qifreport.registration.pose.model import (
    PrealignParams,
    PreparedModel,
    PreparedScan,
    prepare_model,
    prepare_scan,
)
from qifreport.registration.pose.starts import descriptor_hypotheses, initial_starts

__all__ = [
    # defined here
    "WEAK_CONDITIONING",
    "PoseNotEstablished",
    "PrealignResult",
    "already_in_frame",
    "prealign",
    "seat_scan",
    # re-exported from the step modules
    "Candidate",
    "PoseFit",
    "PrealignParams",
    "PreparedModel",
    "pose_distance",
    "prepare_model",
    "refine_pose",
    "score_pose",
]

log = logging.getLogger(__name__)


# below this ratio of the smallest to the largest eigenvalue of the information matrix the seen
# surface slides along itself (measured at the accepted poses, bench/prealign.py: fandisk
# 0.046, housing 0.020, thin shell 0.0075 with its rim rows; the shell's surface alone 3e-5)
WEAK_CONDITIONING = 1e-3


class PoseNotEstablished(InputError):
    """The scan could not be seated on the nominal (no overlap, no agreement, no match)."""


@dataclass
class PrealignResult:
    """Outcome of :func:`prealign`.

    Attributes
    ----------
    R : (3, 3) rotation.  t : (3,) translation, mm: ``P_model = P @ R.T + t``.
    rms : robust point-to-plane residual of the final rigid ICP, mm.
    inliers : scan points within ``gate`` of the model after refinement.
    inlier_fraction : ``inliers / len(P)``.
    restart_agreement : starts that converged into the winning basin (of ``n_starts``).
    n_starts : starts that went through the coarse ICP and voted (descriptor hypotheses and
        the screened principal-axis / random starts).
    n_screened : starts screened (descriptor + principal-axis + random).
    matches : mutual descriptor matches surviving the ratio test (both signs).
    ransac_inliers : matches consistent with the best RANSAC hypothesis.
    ambiguous : a rival basin fits as well (symmetry); see ``candidates``.
    candidates : the basins, best first.
    gate : ``tau`` in mm.  noise : estimated scan range noise, mm.
    seconds : wall time.  method : ``"descriptor"`` when a descriptor hypothesis reached the
        winning basin, ``"restart"`` when only principal-axis / random starts did,
        ``"identity"`` when the scan was already in the model frame.
    rigid : the final :class:`RigidResult`.
    conditioning : smallest / largest eigenvalue of the point-to-plane information matrix
        at the pose (:func:`qifreport.registration.icp.pose_conditioning`); below
        :data:`WEAK_CONDITIONING` the seen surface can slide along itself (a cap, a
        cylinder) and the rigid pose is fixed only to within that slide.
    wall : median wall thickness under the seated scan, mm (``inf``: an open sheet or a
        wall thicker than the gate).
    """

    R: np.ndarray
    t: np.ndarray
    rms: float
    inliers: int
    inlier_fraction: float
    restart_agreement: int
    n_starts: int
    n_screened: int
    matches: int
    ransac_inliers: int
    ambiguous: bool
    candidates: list[Candidate]
    gate: float
    noise: float
    seconds: float
    method: str
    rigid: RigidResult | None = None
    conditioning: float = float("nan")
    wall: float = float("inf")

    @property
    def weakly_constrained(self) -> bool:
        """The seen surface can slide along itself (see ``conditioning``)."""
        return bool(self.conditioning < WEAK_CONDITIONING)

    def apply(self, P: np.ndarray) -> np.ndarray:
        """Map scan points (m, 3) into the model frame."""
        return P @ self.R.T + self.t

    def model_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R', t')`` posing the nominal on the scan: ``V0 = V @ R'.T + t'`` (Algorithm 1)."""
        return self.R.T, -self.R.T @ self.t

    def summary(self) -> str:
        """One line: inliers, residual, agreement, ambiguity."""
        amb = "; AMBIGUOUS (rival pose fits as well)" if self.ambiguous else ""
        if self.weakly_constrained:
            amb += (
                f"; pose weakly constrained (conditioning {self.conditioning:.1e}: the "
                "surface can slide along itself; normal deviations are unaffected)"
            )
        return (
            f"pose by {self.method}: {self.inlier_fraction:.1%} of scan within "
            f"{self.gate:.2f} mm, rms {self.rms:.3f} mm, {self.restart_agreement}/"
            f"{self.n_starts} starts agree ({self.n_screened} screened), {self.matches} "
            f"matches / {self.ransac_inliers} "
            f"RANSAC inliers, {self.seconds:.1f} s{amb}"
        )


# ---------------------------------------------------------------------------------------
# public API


def already_in_frame(
    V: np.ndarray,
    P: np.ndarray,
    *,
    F: np.ndarray | None = None,
    fraction: float = 0.6,
    gate: float = 0.02,
    max_motion_deg: float = 10.0,
    max_motion_frac: float = 0.05,
    sample: int = 3000,
    seed: int = 0,
    tree: cKDTree | None = None,
    normals: np.ndarray | None = None,
) -> bool:
    """Cheap test: does the scan already lie on the nominal, in the model frame?

    A plain rigid ICP (:func:`qifreport.registration.icp.rigid_icp`) from the identity on a
    sample of the scan; the scan is in frame when, after it, more than ``fraction`` of the sampled
    points lie within ``gate * diagonal`` of the model vertices *and* the ICP moved the scan
    by less than ``max_motion_deg`` degrees and ``max_motion_frac * diagonal`` mm (the
    identity was already in the right basin). A quick pre-check returns ``False`` when fewer
    than a third of the points are within 5 % of the diagonal before any ICP.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  P : (m, 3) scan, mm.
    F : (f, 3) faces, for vertex normals (point-to-plane targets); without it the ICP uses
        normals of the vertex cloud's PCA.
    tree, normals : ``cKDTree(V)`` and the (n, 3) vertex normals, when already at hand
        (a :class:`PreparedModel`'s).
    """
    V = np.asarray(V, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    diag = bounding_diagonal(V)
    rng = np.random.default_rng(seed)
    S = P[rng.choice(len(P), size=min(sample, len(P)), replace=False)]
    tree = cKDTree(V) if tree is None else tree
    d0, _ = tree.query(S, distance_upper_bound=0.05 * diag, workers=-1)
    if np.isfinite(d0).mean() < 1.0 / 3.0:
        return False
    if normals is not None:
        N = normals
    elif F is not None:
        N = vertex_normals(V, np.asarray(F, dtype=np.int64))
    else:
        from qifreport.registration.normals import pca_normals

        N = pca_normals(V, tree=tree)
    r = rigid_icp(V, N, S, tree=tree)
    d, _ = tree.query(r.apply(S), distance_upper_bound=gate * diag, workers=-1)
    inside = float(np.isfinite(d).mean())
    moved_deg = rotation_angle_deg(r.R)
    moved = float(np.linalg.norm((r.R - np.eye(3)) @ S.mean(axis=0) + r.t))
    ok = inside > fraction and moved_deg < max_motion_deg and moved < max_motion_frac * diag
    log.debug(
        "already_in_frame: %.1f%% within gate, moved %.2f deg / %.2f mm -> %s",
        100 * inside,
        moved_deg,
        moved,
        ok,
    )
    return bool(ok)


def _model_of(
    V: np.ndarray, F: np.ndarray, p: PrealignParams, seed: int, model: PreparedModel | None
) -> PreparedModel:
    """The prepared model of the nominal ``(V, F)``: ``model`` when given (ValueError when
    it was prepared for another mesh), else prepared here with the settings ``p``."""
    if model is None:
        return prepare_model(V, F, p, seed=seed)
    if np.shape(V) != model.V.shape:
        raise ValueError("model was prepared for another mesh (vertex count differs)")
    return model


def _descriptor_step(
    model: PreparedModel,
    scan: PreparedScan,
    S: np.ndarray,
    tau: float,
    p: PrealignParams,
    rng: np.random.Generator,
) -> tuple[list, int, int]:
    """Steps 1-4 of the search on the prepared sides: the descriptor matches and the RANSAC
    hypotheses scored on the scan sample ``S`` (s, 3) mm under the gate ``tau`` (mm).

    Returns
    -------
    hyps : the hypotheses, best first.  n_matches : descriptor matches.
    best_ransac : inliers of the best hypothesis (0 without one).
    """
    hyps, n_matches = descriptor_hypotheses(model, scan, S, tau, p, rng)
    log.debug(
        "descriptor matches %d, %d RANSAC hypotheses; best sample cost %.3f",
        n_matches,
        len(hyps),
        hyps[0][0].cost if hyps else 1.0,
    )
    best_ransac = hyps[0][3] if hyps else 0
    return hyps, n_matches, best_ransac


def _search_basins(
    model: PreparedModel,
    P: np.ndarray,
    S: np.ndarray,
    hyps: list,
    tau: float,
    p: PrealignParams,
    rng: np.random.Generator,
    seed: int,
) -> tuple[int, int, list[Candidate], list[Candidate], RigidResult | None]:
    """Steps 5 and 6 of the search: the starts (the descriptor hypotheses ``hyps``,
    principal-axis and random rotations), screened and refined on the scan sample ``S``
    (s, 3) mm, grouped into basins under the gate ``tau`` (mm); the best basin and its close
    rivals refined on all scan points ``P`` (m, 3) mm.

    Returns
    -------
    n_starts : starts kept by the screening.
    n_screened : starts screened.
    finals, others : the refined basins (best first) and the rest.
    rigid : the robust rigid fit of the best basin (None when none was refined).
    """
    # starts: descriptor hypotheses, principal-axis hypotheses, random rotations
    starts = initial_starts(model, P, hyps, p, rng)
    # screening: a few iterations on a small sample, the most promising starts go on
    n_screened = len(starts)
    starts = screen_starts(model, S, starts, tau, p)
    coarse = coarse_fits(model, S, starts, tau, p)
    # group into basins: poses that place the scan within the gate of each other
    basins = group_basins(coarse, S, tau, p)
    # robust refinement of the best basin and of rivals whose coarse cost is close
    finals, others, rigid = refine_basins(model, P, S, basins, tau, p, seed)
    return len(starts), n_screened, finals, others, rigid


def _check_accepted(
    best: Candidate,
    n_points: int,
    n_starts: int,
    tau: float,
    p: PrealignParams,
    n_matches: int,
    best_ransac: int,
) -> None:
    """The acceptance rule: raise :class:`PoseNotEstablished` unless the best basin seats
    ``min_inlier_fraction`` of the ``n_points`` scan points within the gate ``tau`` (mm)
    and ``min_agreement`` of the ``n_starts`` starts reach it. ``n_matches`` and
    ``best_ransac`` (descriptor matches, inliers of the best RANSAC hypothesis) go into
    the message."""
    if best.inlier_fraction < p.min_inlier_fraction:
        raise PoseNotEstablished(
            f"no pose seats the scan on the nominal: best {best.inlier_fraction:.1%} of "
            f"{n_points} scan points within {tau:.2f} mm (need {p.min_inlier_fraction:.0%}), "
            f"rms {best.rms:.3f} mm, {n_matches} descriptor matches, best RANSAC "
            f"{best_ransac} inliers; the scan does not overlap this part"
        )
    if best.support < p.min_agreement:
        raise PoseNotEstablished(
            f"pose not confirmed: only {best.support} of {n_starts} starts reach the best "
            f"basin ({best.inlier_fraction:.1%} within {tau:.2f} mm, rms {best.rms:.3f} mm; "
            f"need {p.min_agreement}); the restarts disagree"
        )


def _scanned_wall(
    model: PreparedModel,
    S: np.ndarray,
    best: Candidate,
    tau: float,
    p: PrealignParams,
    rival: Candidate | None = None,
) -> float:
    """The median wall thickness (mm) of the model where the posed scan sample ``S``
    (s, 3) mm lands; with ``p.refuse_thin_wall``, :class:`PoseNotEstablished` when it is
    thinner than the gate ``tau`` (mm): a one-sided scan then fits either skin. ``rival``:
    a basin that fits about as well as ``best``, named in the message (a near-symmetric
    part: the gate cannot tell the two apart either)."""
    at = unique_sorted(model.tree.query(S @ best.R.T + best.t)[1])
    th = wall_thickness(model.V, model.N, at, radius=tau, tree=model.tree)
    wall = float(np.median(th))
    if p.refuse_thin_wall and wall < tau:
        also = ""
        if rival is not None:
            dd, dt = pose_distance(rival.R, rival.t, best.R, best.t, S.mean(axis=0))
            also = (
                f", and a pose {dd:.0f} deg / {dt:.1f} mm away fits as well (a near-symmetric part)"
            )
        raise PoseNotEstablished(
            f"the scan lies on a {wall:.2f} mm wall (median), thinner than the "
            f"{tau:.2f} mm pose gate: a one-sided scan fits either skin{also}, and the search "
            "cannot tell which pose is the part's; deliver the scan in the part frame "
            "(--prealign never)"
        )
    return wall


def _warn_ambiguous(b: Candidate, best: Candidate, S: np.ndarray, tau: float) -> None:
    """Log that the rival basin ``b`` fits the scan sample ``S`` (s, 3) mm about as well
    as ``best`` (its rotation, deg, and translation, mm, from the winner; gate ``tau`` mm)."""
    dd, dt = pose_distance(b.R, b.t, best.R, best.t, S.mean(axis=0))
    log.warning(
        "ambiguous pose: a rival basin %.1f deg / %.1f mm away fits as well "
        "(%.1f%% vs %.1f%% within %.2f mm, rms %.3f vs %.3f mm): symmetric part?",
        dd,
        dt,
        100 * b.inlier_fraction,
        100 * best.inlier_fraction,
        tau,
        b.rms,
        best.rms,
    )


def prealign(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    *,
    seed: int = 0,
    params: PrealignParams | None = None,
    model: PreparedModel | None = None,
) -> PrealignResult:
    """Seat the nominal on a scan in an arbitrary pose (paper Algorithm 1 plus restarts).

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points in the scanner frame, mm.
    seed : seed of keypoint sampling, RANSAC and the random restarts.
    params : settings (:class:`PrealignParams`).
    model : :func:`prepare_model` of ``(V, F)``, to reuse across scans of one part (the model
        side is the costlier half); its ``params`` are used unless ``params`` is
        given (the model-side settings -- scales, keypoints -- are always the model's).

    Returns
    -------
    PrealignResult (pose scan -> model; see the module docstring for the acceptance rule).

    Raises
    ------
    PoseNotEstablished
        No basin reaches ``min_inlier_fraction`` of the scan within the gate, or fewer than
        ``min_agreement`` starts agree on the winning basin.
    InputError
        Invalid scan array.
    """
    t_start = time.perf_counter()
    p = params or (model.params if model is not None else PrealignParams())
    P = validate_scan(P)
    model = _model_of(V, F, p, seed, model)
    rng = np.random.default_rng(seed)
    tau = p.gate * model.diag
    scan = prepare_scan(P, model, seed)
    S = P[rng.choice(len(P), size=min(p.sample_points, len(P)), replace=False)]
    hyps, n_matches, best_ransac = _descriptor_step(model, scan, S, tau, p, rng)
    n_starts, n_screened, finals, others, rigid = _search_basins(
        model, P, S, hyps, tau, p, rng, seed
    )
    best = finals[0]
    rivals = [b for b in finals[1:] if b.cost <= best.cost * (1.0 + p.ambiguity_margin) + 1e-3]
    seconds = time.perf_counter() - t_start
    inliers = int(round(best.inlier_fraction * len(P)))
    _check_accepted(best, len(P), n_starts, tau, p, n_matches, best_ransac)
    wall = _scanned_wall(model, S, best, tau, p, rivals[0] if rivals else None)
    if rivals:
        _warn_ambiguous(rivals[0], best, S, tau)
    method = "descriptor" if "descriptor" in best.sources else "restart"
    res = PrealignResult(
        R=best.R,
        t=best.t,
        rms=best.rms,
        inliers=inliers,
        inlier_fraction=best.inlier_fraction,
        restart_agreement=best.support,
        n_starts=n_starts,
        n_screened=n_screened,
        matches=n_matches,
        ransac_inliers=best_ransac,
        ambiguous=bool(rivals),
        candidates=finals + others,
        gate=tau,
        noise=scan.noise,
        seconds=seconds,
        method=method,
        rigid=rigid,
        conditioning=pose_conditioning(
            model.V, model.N, S @ best.R.T + best.t, tree=model.tree, boundary=model.boundary
        )[0],
        wall=wall,
    )
    log.info("%s", res.summary())
    return res


def seat_scan(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    *,
    mode: str = "auto",
    seed: int = 0,
    params: PrealignParams | None = None,
    model: PreparedModel | None = None,
) -> PrealignResult:
    """Bring the scan into the part frame as the CLI needs it.

    Parameters
    ----------
    V, F : nominal mesh (mm).  P : (m, 3) scan (mm).
    mode : ``"auto"`` -- identity when :func:`already_in_frame`, else :func:`prealign`;
        ``"always"`` -- always :func:`prealign`; ``"never"`` -- identity (the user vouches
        that scan and nominal share a frame).
    seed, params, model : passed to :func:`prealign`.

    Returns
    -------
    PrealignResult; for the identity ``method == "identity"``, ``R = I``, ``t = 0`` and the
    fit of the scan as delivered (``rms``: RMS nearest-vertex distance of the points within
    the gate, mm); the rigid refinement is left to the caller.

    Raises
    ------
    PoseNotEstablished, InputError
        As :func:`prealign`; ``ValueError`` for an unknown ``mode``.
    """
    if mode not in ("auto", "always", "never"):
        raise ValueError(f"unknown prealignment mode {mode!r} (auto, always or never)")
    t0 = time.perf_counter()
    P = validate_scan(P)
    tree = normals = None
    if model is not None and model.V.shape == np.shape(V):
        tree, normals = model.tree, model.N
    if mode == "always" or (
        mode == "auto" and not already_in_frame(V, P, F=F, seed=seed, tree=tree, normals=normals)
    ):
        return prealign(V, F, P, seed=seed, params=params, model=model)
    p = params or (model.params if model is not None else PrealignParams())
    diag = bounding_diagonal(V)
    tau = p.gate * diag
    d, _ = (cKDTree(V) if tree is None else tree).query(P, distance_upper_bound=tau, workers=-1)
    inl = np.isfinite(d)
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return PrealignResult(
        R=np.eye(3),
        t=np.zeros(3),
        rms=rms,
        inliers=int(inl.sum()),
        inlier_fraction=float(inl.mean()),
        restart_agreement=0,
        n_starts=0,
        n_screened=0,
        matches=0,
        ransac_inliers=0,
        ambiguous=False,
        candidates=[],
        gate=tau,
        noise=0.0,
        seconds=time.perf_counter() - t0,
        method="identity",
    )
