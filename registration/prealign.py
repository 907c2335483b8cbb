"""Pose-free pre-registration of a scan onto the nominal (paper Section 5.1, Algorithm 1).

A scanner's frame bears no relation to the CAD frame. :func:`prealign` recovers the rigid
transform that carries the scan ``P`` into the model frame from any initial placement, and
refuses (:class:`PoseNotEstablished`) when it cannot establish one.

Pipeline
--------
1. Curvature fields ``H, K, S, C`` on the mesh (cotangent mean-curvature normal, angle
   defect) and on the scan (local quadric fits, :mod:`qifreport.registration.curvature`), brought to
   one resolution by a small area-weighted average (:func:`qifreport.registration.descriptors.presmooth`).
2. Geodesic bilateral filtering at ``L`` scales ``rho h`` (``h`` the model's mean edge
   length) at farthest-point keypoints of each side (Dijkstra balls of ``3 sigma_s``); range
   bandwidth ``max(r0 spread, c eta)`` from the scan noise ``eta`` measured in each field's
   units (:mod:`qifreport.registration.descriptors`).
3. Heavy tails compressed (``asinh(f / (3 eta_f))``), joint z-score over model and scan.
   Matching keeps the ``salient`` half of the keypoints (by filtered curvedness: flat
   patches all look alike) and pairs each scan keypoint with its ``match_k`` nearest model
   descriptors (``match_k = 0``: the paper's mutual nearest neighbours with Lowe's ratio
   test). The global sign of the scan normals cannot be known from points alone, so both
   signs are matched.
4. RANSAC on triplets (:func:`ransac_triplets`): compatibility-guided draws (pairwise
   distances must agree within the gate), Kabsch fit, inlier count under the absolute gate
   ``tau = gate * diagonal``; the best distinct hypotheses are re-scored on a sample of *all*
   scan points by the MSAC cost (:func:`score_pose`).
5. Restarts as in the paper's Section 8.4.2: principal-axis hypotheses (the 24 proper
   signed permutations mapping the scan's PCA axes onto the model's; the first four are the
   paper's sign combinations) and ``random_restarts`` uniformly random rotations, all
   centroid-aligned. Every start is screened by a few ICP iterations; the best
   ``screen_keep`` and the descriptor hypotheses go on.
6. Each surviving start is refined by trimmed point-to-point ICP on a sample of the scan;
   the converged poses are grouped into *basins* (poses that place the scan within
   ``basin * tau`` RMS of each other). The best basin -- and any rival within the ambiguity
   margin -- gets :func:`refine_pose`: point-to-point ICP on all vertices, then the robust
   rigid ICP of the foundation (:func:`qifreport.registration.icp.rigid_icp`) on all scan points.

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
``P_model = P @ R.T + t`` (as :class:`qifreport.registration.icp.RigidResult`); the posed nominal of
the paper's Algorithm 1, ``V0 = R' V + t'``, is :meth:`PrealignResult.model_pose`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from qifreport.errors import InputError

from .curvature import mesh_curvatures, scan_curvatures
from .descriptors import (
    SCALES,
    DescriptorSet,
    GeodesicBalls,
    bilateral_filter,
    farthest_points,
    field_noise,
    geodesic_balls,
    joint_normalize,
    knn_graph,
    mesh_graph,
    presmooth,
    range_bandwidths,
)
from .icp import RigidResult, converged_rigid_fit, kabsch, pose_conditioning, rigid_icp
from .mesh import (
    boundary_vertices,
    bounding_diagonal,
    edges,
    vertex_areas,
    vertex_normals,
    wall_thickness,
)
from .pointcloud import validate_scan

log = logging.getLogger(__name__)


# below this ratio of the smallest to the largest eigenvalue of the information matrix the seen
# surface slides along itself (measured at the accepted poses, bench/prealign.py: fandisk
# 0.046, housing 0.020, thin shell 0.0075 with its rim rows; the shell's surface alone 3e-5)
WEAK_CONDITIONING = 1e-3


class PoseNotEstablished(InputError):
    """The scan could not be seated on the nominal (no overlap, no agreement, no match)."""


@dataclass
class PrealignParams:
    """Settings of :func:`prealign` (lengths relative to the model unless stated).

    Attributes
    ----------
    scales : spatial scales ``rho_l`` in mean edge lengths (paper: 1.5, 2.4, 3.8, 6.0).
    model_keypoints, scan_keypoints : farthest-point keypoints per side.
    scan_k : neighbourhood size of the scan's quadric fits.
    scan_max_points : the scan's curvature and descriptors use a random subset of at most
        this many points (scoring and refinement use all of them).
    presmooth : sigma of the resolution-matching average, in mean edge lengths.
    range_c, range_r0 : ``sigma_r = max(range_r0 * spread_model, range_c * eta)`` per field.
    salient : fraction of keypoints (union of both sides, by mean filtered curvedness) kept
        for matching; 1.0 keeps all.
    match_k : 0 -> the paper's mutual nearest neighbours with Lowe's ratio test; k > 0 -> each
        scan keypoint's k nearest model descriptors (more correct pairs, more outliers; the
        compatibility-guided RANSAC copes).
    ratio : Lowe ratio (nearest / second-nearest descriptor distance).
    gate : RANSAC and scoring gate ``tau`` as a fraction of the model diagonal.
    ransac_iters : guided triplets drawn per normal sign.
    descriptor_starts : best RANSAC hypotheses (after re-scoring) passed on as ICP starts.
    sample_points : scan points used by hypothesis scoring and the coarse ICP.
    axis_permutations : all 24 proper signed axis permutations (True) or only the paper's
        four sign combinations of the ordered PCA axes (False).
    random_restarts : uniformly random rotations (paper Section 8.4.2 uses 16).
    screen_iters, screen_points, screen_keep : every start first gets ``screen_iters``
        coarse-ICP iterations on ``screen_points`` scan points; the ``screen_keep`` with the
        lowest cost (all, if there are no more) go on to the full coarse ICP and vote.
    icp_iters, icp_trim : coarse point-to-point ICP iterations and kept fraction.
    continue_starts : the best coarse results (cost within 3x the best) get ``2 icp_iters``
        more iterations before the basins are formed.
    coarse_vertices : model vertices (farthest-point sample) the coarse ICP matches against.
    basin : two poses lie in the same basin when they place the scan sample within
        ``basin * tau`` (RMS) of each other. Above 1 because the coarse ICP stops after
        ``icp_iters`` while a deformed smooth part can still be sliding slowly along a shallow
        valley (measured: coarse poses 5-8 mm apart on the 205 mm shell).
    final_basins : at most this many basins get the final robust refinement.
    min_inlier_fraction : scan fraction within ``tau`` required to accept.
    min_agreement : starts that must reach the winning basin.
    ambiguity_margin : relative MSAC-cost margin under which a rival basin is a tie.
    refuse_thin_wall : refuse the pose (:class:`PoseNotEstablished`) when most of the scan
        lies on a wall thinner than the gate (:func:`qifreport.registration.mesh.wall_thickness`): a
        one-sided scan of a thin solid fits the other skin, shifted by the wall, about as well
        -- measured on the demo panel (1.8 mm wall, 2.8 mm free-state deflection) at the
        paper's pose: the inner skin fits *better* (rms 0.43 against 0.62 mm) and the outer
        skin's tolerance got no data. Which side was scanned is not in the points.
    """

    scales: tuple[float, ...] = SCALES
    model_keypoints: int = 2000
    scan_keypoints: int = 1000
    scan_k: int = 20
    scan_max_points: int = 15000
    presmooth: float = 1.0
    range_c: float = 3.0
    range_r0: float = 0.5
    salient: float = 0.5
    match_k: int = 3
    ratio: float = 0.9
    gate: float = 0.02
    ransac_iters: int = 4000
    descriptor_starts: int = 4
    sample_points: int = 1000
    axis_permutations: bool = True
    random_restarts: int = 72
    screen_iters: int = 10
    screen_points: int = 300
    screen_keep: int = 40
    icp_iters: int = 40
    icp_trim: float = 0.9
    continue_starts: int = 10
    coarse_vertices: int = 6000
    basin: float = 2.0
    final_basins: int = 2
    min_inlier_fraction: float = 0.6
    min_agreement: int = 2
    ambiguity_margin: float = 0.1
    refuse_thin_wall: bool = True


@dataclass
class PreparedModel:
    """Everything about the nominal that does not depend on the scan (cache it per part).

    Attributes
    ----------
    V, F : the mesh (mm).  N : (n, 3) unit vertex normals.  tree : ``cKDTree(V)``.
    diag : bounding diagonal, mm.  h : mean edge length, mm.
    area : (n,) vertex areas, mm^2.  fields : (n, 4) resolution-matched ``[H, K, S, C]``.
    balls : geodesic neighbourhoods of the keypoints.  centroid, axes : area-weighted PCA
    frame (columns largest to smallest).  Vc, coarse_tree : the vertex sample of the coarse
    ICP and its tree.  params : the settings used.  boundary : (n,) bool, vertices on an
    open boundary (the rigid refinement's edge term).
    """

    V: np.ndarray
    F: np.ndarray
    N: np.ndarray
    tree: cKDTree
    diag: float
    h: float
    area: np.ndarray
    fields: np.ndarray
    balls: GeodesicBalls
    centroid: np.ndarray
    axes: np.ndarray
    Vc: np.ndarray
    coarse_tree: cKDTree
    params: PrealignParams
    boundary: np.ndarray | None = None
    _descriptors: dict = field(default_factory=dict, repr=False)

    def descriptors(self, sigma_r: np.ndarray) -> DescriptorSet:
        """Model descriptors for the range bandwidths ``sigma_r`` (memoised)."""
        key = tuple(np.round(np.log(np.asarray(sigma_r)), 3))
        if key not in self._descriptors:
            scales = np.asarray(self.params.scales) * self.h
            D = bilateral_filter(self.balls, self.fields, self.area, scales, sigma_r)
            k = self.balls.sources
            self._descriptors[key] = DescriptorSet(k, self.V[k], D, scales, np.asarray(sigma_r))
        return self._descriptors[key]


@dataclass
class Candidate:
    """One basin of the pose search.

    Attributes
    ----------
    R, t : pose (scan -> model), t in mm.  inlier_fraction : scan fraction within the gate.
    rms : residual, mm (coarse: trimmed point-to-point RMS on the sample; final: the robust
        point-to-plane RMS of :func:`rigid_icp`).  support : starts that converged here.
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
            amb += (f"; pose weakly constrained (conditioning {self.conditioning:.1e}: the "
                    "surface can slide along itself; normal deviations are unaffected)")
        return (
            f"pose by {self.method}: {self.inlier_fraction:.1%} of scan within "
            f"{self.gate:.2f} mm, rms {self.rms:.3f} mm, {self.restart_agreement}/"
            f"{self.n_starts} starts agree ({self.n_screened} screened), {self.matches} "
            f"matches / {self.ransac_inliers} "
            f"RANSAC inliers, {self.seconds:.1f} s{amb}"
        )


# ---------------------------------------------------------------------------------------
# geometry helpers


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (degrees) of the rotation ``R``."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def pose_distance(
    R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray, at: np.ndarray
) -> tuple[float, float]:
    """Rotation difference (degrees) and displacement of the point ``at`` (mm) between poses."""
    return rotation_angle_deg(R1 @ R2.T), float(np.linalg.norm((R1 - R2) @ at + t1 - t2))


def _batch_kabsch(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kabsch fits of (b, k, 3) point sets ``A`` onto ``B``: R (b, 3, 3), t (b, 3)."""
    a = A.mean(axis=1)
    b = B.mean(axis=1)
    H = np.einsum("bki,bkj->bij", A - a[:, None], B - b[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("bji,bkj->bik", Vt, U)))
    d[d == 0] = 1.0
    D = np.zeros((len(A), 3, 3))
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.einsum("bji,bjk,blk->bil", Vt, D, U)
    t = b - np.einsum("bij,bj->bi", R, a)
    return R, t


def _pca(X: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroid and principal axes (columns, largest first, right-handed)."""
    w = np.ones(len(X)) if w is None else w
    w = w / w.sum()
    c = w @ X
    C = ((X - c) * w[:, None]).T @ (X - c)
    _, U = np.linalg.eigh(C)
    U = U[:, ::-1].copy()
    U[:, 2] = np.cross(U[:, 0], U[:, 1])
    return c, U


def axis_hypotheses(all_permutations: bool = True) -> list[np.ndarray]:
    """Proper signed permutation matrices: 4 sign flips of the identity order, then the rest.

    With ``all_permutations`` the 24 rotations of the cube (every way to map ordered axes onto
    ordered axes), the paper's four principal-axis hypotheses first.
    """
    out: list[np.ndarray] = []
    for s in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        out.append(np.diag(np.asarray(s, dtype=float)))
    if all_permutations:
        from itertools import permutations, product

        for perm in permutations(range(3)):
            for sg in product((1.0, -1.0), repeat=3):
                M = np.zeros((3, 3))
                M[np.arange(3), perm] = sg
                if np.linalg.det(M) > 0 and not any(np.allclose(M, X) for X in out):
                    out.append(M)
    return out


# ---------------------------------------------------------------------------------------
# model and scan preparation


def mean_edge_length(V: np.ndarray, F: np.ndarray) -> float:
    """Mean edge length ``h`` (mm), the unit of the descriptor scales."""
    E = edges(F)
    return float(np.mean(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)))


def prepare_model(
    V: np.ndarray, F: np.ndarray, params: PrealignParams | None = None, seed: int = 0
) -> PreparedModel:
    """Curvature fields, keypoints and geodesic neighbourhoods of the nominal (scan-free).

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  params : settings.  seed : keypoint seed.
    """
    p = params or PrealignParams()
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    diag = bounding_diagonal(V)
    h = mean_edge_length(V, F)
    area = vertex_areas(V, F)
    tree = cKDTree(V)
    raw = mesh_curvatures(V, F)
    planar = 1e-3 / diag
    fields = presmooth(V, raw.H, raw.K, area, p.presmooth * h, planar, tree=tree).stack()
    kp = farthest_points(V, p.model_keypoints, seed=seed)
    balls = geodesic_balls(mesh_graph(V, F), kp, 3.0 * max(p.scales) * h)
    c, U = _pca(V, area)
    Vc = V[farthest_points(V, p.coarse_vertices, seed=seed)]
    log.debug("model: %d vertices, h %.3f mm, %d keypoints, %d ball entries",
              len(V), h, len(kp), len(balls.rows))
    return PreparedModel(
        V=V, F=F, N=vertex_normals(V, F), tree=tree, diag=diag, h=h, area=area,
        fields=fields, balls=balls, centroid=c, axes=U, Vc=Vc, coarse_tree=cKDTree(Vc),
        params=p, boundary=boundary_vertices(F, len(V)),
    )


@dataclass
class _ScanSide:
    P: np.ndarray
    tree: cKDTree
    fields: np.ndarray
    area: np.ndarray
    eta_fields: np.ndarray
    noise: float
    balls: GeodesicBalls


def _prepare_scan(P: np.ndarray, model: PreparedModel, seed: int) -> _ScanSide:
    p = model.params
    if len(P) > p.scan_max_points:
        rng = np.random.default_rng(seed + 1)
        P = P[np.sort(rng.choice(len(P), size=p.scan_max_points, replace=False))]
    tree = cKDTree(P)
    sc = scan_curvatures(P, k=p.scan_k, tree=tree)
    area = sc.spacing**2
    eta = field_noise(sc.stack(), P, tree=tree)
    fields = presmooth(P, sc.H, sc.K, area, p.presmooth * model.h, 1e-3 / model.diag,
                       tree=tree).stack()
    kp = farthest_points(P, p.scan_keypoints, seed=seed)
    balls = geodesic_balls(knn_graph(P, tree=tree), kp, 3.0 * max(p.scales) * model.h)
    return _ScanSide(P, tree, fields, area, eta, sc.noise, balls)


# ---------------------------------------------------------------------------------------
# matching and RANSAC


def mutual_matches(A: np.ndarray, B: np.ndarray, ratio: float) -> np.ndarray:
    """Mutual nearest neighbours between descriptor rows of ``A`` and ``B`` with Lowe's test.

    Returns
    -------
    (k, 2) int pairs ``(i in A, j in B)``: ``A_i`` is ``B_j``'s nearest neighbour and vice
    versa, and ``B_j``'s nearest distance is below ``ratio`` times its second nearest.
    """
    if len(A) < 2 or len(B) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    dB, iB = cKDTree(A).query(B, k=2, workers=-1)
    _, iA = cKDTree(B).query(A, k=1, workers=-1)
    j = np.arange(len(B))
    ok = (iA[iB[:, 0]] == j) & (dB[:, 0] < ratio * dB[:, 1])
    return np.column_stack([iB[ok, 0], j[ok]]).astype(np.int64)


def knn_matches(A: np.ndarray, B: np.ndarray, k: int) -> np.ndarray:
    """Each row of ``B``'s ``k`` nearest rows of ``A`` in descriptor space: (len(B) k, 2)."""
    if len(A) == 0 or len(B) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    k = min(k, len(A))
    _, i = cKDTree(A).query(B, k=k, workers=-1)
    i = i.reshape(len(B), k)
    return np.column_stack([i.ravel(), np.repeat(np.arange(len(B)), k)]).astype(np.int64)


def ransac_triplets(
    Xs: np.ndarray, Xm: np.ndarray, tau: float, iters: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """RANSAC over matched pairs ``Xs[i] <-> Xm[i]`` (scan -> model), minimal triplets.

    Two pairs are *compatible* when their scan and model separations agree within ``tau``
    (a rigid motion preserves distances) and are at least ``2 tau`` (well-conditioned).
    Triplets are drawn guided by compatibility: a random seed pair, a second pair among
    those compatible with it, a third among those compatible with both, so a triplet is
    rigidly consistent by construction (with 5 % correct matches about one guided triplet
    in a hundred is all-correct, against one in 8000 for uniform draws). Each gets a Kabsch
    fit (paper Eq. 8) and the count of pairs with ``|R x_s + t - x_m| <= tau`` (the absolute
    gate); the best hypotheses are re-fitted on their inliers.

    Returns
    -------
    List of ``(R, t, inlier_count)``, best first, mutually distinct (more than 5 degrees or
    ``2 tau`` apart), at most 50.
    """
    n = len(Xs)
    if n < 3:
        return []
    Xs32, Xm32 = Xs.astype(np.float32), Xm.astype(np.float32)
    Ds = np.linalg.norm(Xs32[:, None] - Xs32[None], axis=2)
    Dm = np.linalg.norm(Xm32[:, None] - Xm32[None], axis=2)
    C = (np.abs(Ds - Dm) <= tau) & (Ds >= 2.0 * tau)
    del Ds, Dm
    deg = C.sum(axis=1)
    seeds = np.flatnonzero(deg >= 2)
    if len(seeds) == 0:
        return []
    per_seed = 8
    n_seeds = max(1, iters // per_seed)
    trip = []
    for a in rng.choice(seeds, size=min(n_seeds, len(seeds)), replace=False):
        nb = np.flatnonzero(C[a])
        for b in rng.choice(nb, size=min(per_seed, len(nb)), replace=False):
            common = nb[C[b, nb]]
            if len(common):
                trip.append((a, b, common[rng.integers(len(common))]))
    if not trip:
        return []
    idx = np.asarray(trip, dtype=np.int64)
    A = Xs[idx]
    area = np.linalg.norm(np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0]), axis=1)
    idx = idx[area >= 2.0 * tau**2]
    if len(idx) == 0:
        return []
    R, t = _batch_kabsch(Xs[idx], Xm[idx])
    counts = np.zeros(len(idx), dtype=np.int64)
    step = max(1, 2_000_000 // max(n, 1))
    for s in range(0, len(idx), step):
        Y = np.einsum("bij,nj->bni", R[s : s + step], Xs) + t[s : s + step, None, :]
        counts[s : s + step] = (np.linalg.norm(Y - Xm[None], axis=2) <= tau).sum(axis=1)
    order = np.argsort(-counts)
    out: list[tuple[np.ndarray, np.ndarray, int]] = []
    ctr = Xs.mean(axis=0)
    for o in order[:200]:
        inl = np.linalg.norm(Xs @ R[o].T + t[o] - Xm, axis=1) <= tau
        Rr, tr = kabsch(Xs[inl], Xm[inl])
        cnt = int((np.linalg.norm(Xs @ Rr.T + tr - Xm, axis=1) <= tau).sum())
        if cnt < counts[o]:
            Rr, tr, cnt = R[o], t[o], int(counts[o])
        if all(
            (lambda d: d[0] > 5.0 or d[1] > 2.0 * tau)(pose_distance(Rr, tr, R2, t2, ctr))
            for R2, t2, _ in out
        ):
            out.append((Rr, tr, cnt))
        if len(out) >= 50:
            break
    out.sort(key=lambda x: -x[2])
    return out


# ---------------------------------------------------------------------------------------
# scoring and coarse ICP


@dataclass
class PoseFit:
    """How well a pose seats scan points on the model.

    Attributes
    ----------
    cost : MSAC cost ``mean(min(d, tau)^2) / tau^2`` in [0, 1] (lower is better), ``d`` the
        distance of each posed point to the nearest model vertex, mm.
    frac : fraction of points with ``d <= tau``.  rms : RMS of those ``d``, mm.
    """

    cost: float
    frac: float
    rms: float


def score_pose(model: PreparedModel, S: np.ndarray, R: np.ndarray, t: np.ndarray, tau: float
               ) -> PoseFit:
    """Fit of the posed scan points ``S`` to the model vertices under the gate ``tau`` (mm).

    The ranking score is the MSAC (truncated quadratic) cost ``mean(min(d, tau)^2) / tau^2``,
    which rewards both overlap and closeness, so a saturated inlier fraction (a smooth part
    under a loose gate) does not make every sliding pose a tie.
    """
    workers = 1 if len(S) < 5000 else -1
    d, _ = model.tree.query(S @ R.T + t, distance_upper_bound=tau, workers=workers)
    inl = np.isfinite(d)
    frac = float(inl.mean())
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    cost = float(np.mean(np.where(inl, np.minimum(d, tau), tau) ** 2) / tau**2)
    return PoseFit(cost, frac, rms)


def scan_displacement(
    R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray, S: np.ndarray
) -> float:
    """RMS distance (mm) between the points ``S`` placed by pose 1 and by pose 2."""
    D = S @ (R1 - R2).T + (t1 - t2)
    return float(np.sqrt(np.mean(np.sum(D * D, axis=1))))


def point_icp(
    model: PreparedModel,
    S: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    iters: int = 50,
    trim: float = 0.9,
    fine: bool = False,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Trimmed point-to-point ICP of the scan sample ``S`` onto the model vertices.

    Each iteration matches every sample point to its nearest vertex (of the coarse vertex
    sample, or of all vertices when ``fine``), keeps the ``trim`` fraction of closest pairs
    and applies the Kabsch fit; stops when the update is below 0.005 degrees and ``5e-5``
    diagonals (``fine``: 0.001 degrees and ``1e-5`` diagonals).

    Returns
    -------
    R, t (scan -> model) and the iterations run.
    """
    tree, X = (model.tree, model.V) if fine else (model.coarse_tree, model.Vc)
    tol = (1e-5 if fine else 5e-5) * model.diag
    tol_deg = 0.001 if fine else 0.005
    it = 0
    for it in range(1, iters + 1):  # noqa: B007 - reported
        Y = S @ R.T + t
        d, i = tree.query(Y)  # single thread: thread start-up costs more than the query
        keep = d <= np.quantile(d, trim)
        dR, dt = kabsch(Y[keep], X[i[keep]])
        R, t = dR @ R, dR @ t + dt
        if rotation_angle_deg(dR) < tol_deg and np.linalg.norm(dt) < tol:
            break
    return R, t, it


def refine_pose(
    model: PreparedModel,
    P: np.ndarray,
    R0: np.ndarray,
    t0: np.ndarray,
    *,
    sample: int = 3000,
    seed: int = 0,
) -> RigidResult:
    """The refinement every accepted basin gets (paper Algorithm 1 step 12, then Section 5.2).

    Trimmed point-to-point ICP (:func:`point_icp`, 90 % of pairs, up to 100 iterations) of a
    ``sample`` of the scan onto *all* model vertices, then the robust point-to-plane fit
    minimised to convergence on all scan points (:func:`qifreport.registration.icp.converged_rigid_fit`:
    Tukey at a fixed scale, damped Gauss-Newton, with the edge term at the model's open
    boundary). The foundation's :func:`qifreport.registration.icp.rigid_icp` stops after a fixed number
    of Kabsch steps, which on a deformed smooth part leaves the pose anywhere along a shallow
    valley (refinements from the truth perturbed by 3 degrees ended within 1 degree of each
    other only 10-20 % of the time); a minimiser ends at one pose from every start in the
    basin. The inspection then runs ``rigid_icp`` from this pose as from any scan delivered
    in the part frame. Deterministic for a given start, so running it from the ground-truth
    placement gives the reference pose a benchmark compares against.

    Returns
    -------
    RigidResult of the final stage (pose scan -> model).
    """
    rng = np.random.default_rng(seed)
    S = P[rng.choice(len(P), size=min(sample, len(P)), replace=False)]
    R, t, _ = point_icp(model, S, R0, t0, iters=100, trim=model.params.icp_trim, fine=True)
    return converged_rigid_fit(model.V, model.N, P, R, t, boundary=model.boundary,
                               tree=model.tree)


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

    A plain rigid ICP (:func:`qifreport.registration.icp.rigid_icp`) from the identity on a sample of
    the scan; the scan is in frame when, after it, more than ``fraction`` of the sampled
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
        from .pointcloud import pca_normals

        N = pca_normals(V, tree=tree)
    r = rigid_icp(V, N, S, tree=tree)
    d, _ = tree.query(r.apply(S), distance_upper_bound=gate * diag, workers=-1)
    inside = float(np.isfinite(d).mean())
    moved_deg = rotation_angle_deg(r.R)
    moved = float(np.linalg.norm((r.R - np.eye(3)) @ S.mean(axis=0) + r.t))
    ok = inside > fraction and moved_deg < max_motion_deg and moved < max_motion_frac * diag
    log.debug("already_in_frame: %.1f%% within gate, moved %.2f deg / %.2f mm -> %s",
              100 * inside, moved_deg, moved, ok)
    return bool(ok)


def _random_rotations(n: int, rng: np.random.Generator) -> list[np.ndarray]:
    if n <= 0:
        return []
    return list(Rotation.random(n, random_state=rng).as_matrix())


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
        side costs ~2 s on a 29k-vertex mesh); its ``params`` are used unless ``params`` is
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
    if model is None:
        model = prepare_model(V, F, p, seed=seed)
    elif np.shape(V) != model.V.shape:
        raise ValueError("model was prepared for another mesh (vertex count differs)")
    rng = np.random.default_rng(seed)
    tau = p.gate * model.diag
    scan = _prepare_scan(P, model, seed)
    sig_r = range_bandwidths(model.fields, scan.eta_fields, c=p.range_c, r0=p.range_r0)
    dm = model.descriptors(sig_r)
    scales = np.asarray(p.scales) * model.h
    DS = bilateral_filter(scan.balls, scan.fields, scan.area, scales, sig_r)
    ds = DescriptorSet(scan.balls.sources, scan.P[scan.balls.sources], DS, scales, sig_r)
    comp = np.repeat(np.maximum(3.0 * scan.eta_fields, 1e-12), len(p.scales))

    S = P[rng.choice(len(P), size=min(p.sample_points, len(P)), replace=False)]
    hyps: list[tuple[PoseFit, np.ndarray, np.ndarray, int]] = []
    n_matches = 0
    L = len(p.scales)
    for side in (ds, ds.flipped()):
        im, js = np.arange(len(dm.D)), np.arange(len(side.D))
        if p.salient < 1.0:  # drop the flattest keypoints (no curvature to match on)
            cm, cs = dm.D[:, 3 * L :].mean(axis=1), side.D[:, 3 * L :].mean(axis=1)
            thr = np.quantile(np.concatenate([cm, cs]), 1.0 - p.salient)
            im, js = np.flatnonzero(cm >= thr), np.flatnonzero(cs >= thr)
        A, B, _, _ = joint_normalize(
            np.arcsinh(dm.D[im] / comp), np.arcsinh(side.D[js] / comp)
        )
        pairs = mutual_matches(A, B, p.ratio) if p.match_k == 0 else knn_matches(A, B, p.match_k)
        n_matches += len(pairs)
        for R, t, cnt in ransac_triplets(
            side.X[js[pairs[:, 1]]], dm.X[im[pairs[:, 0]]], tau, p.ransac_iters, rng
        )[:20]:
            hyps.append((score_pose(model, S, R, t, tau), R, t, cnt))
    hyps.sort(key=lambda h: h[0].cost)
    log.debug("descriptor matches %d, %d RANSAC hypotheses; best sample cost %.3f",
              n_matches, len(hyps), hyps[0][0].cost if hyps else 1.0)
    best_ransac = hyps[0][3] if hyps else 0

    # starts: descriptor hypotheses, principal-axis hypotheses, random rotations
    starts: list[tuple[np.ndarray, np.ndarray, str]] = [
        (h[1], h[2], "descriptor") for h in hyps[: p.descriptor_starts]
    ]
    cs, Us = _pca(P)
    for M in axis_hypotheses(p.axis_permutations):
        R = model.axes @ M @ Us.T
        starts.append((R, model.centroid - R @ cs, "pca"))
    for R in _random_rotations(p.random_restarts, rng):
        starts.append((R, model.centroid - R @ cs, "random"))

    # screening: a few iterations on a small sample, the most promising starts go on
    n_screened = len(starts)
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
    coarse = []
    for R0, t0, src in starts:
        R, t, _ = point_icp(model, S, R0, t0, p.icp_iters, p.icp_trim)
        coarse.append((score_pose(model, S, R, t, tau), R, t, src))
    coarse.sort(key=lambda c: c[0].cost)
    # the most promising starts continue: on a smooth part the ones still sliding along the
    # shallow valley get the iterations they need to reach (or not) the best basin
    for k, (fit, R, t, src) in enumerate(coarse[: p.continue_starts]):
        if fit.cost > 3.0 * coarse[0][0].cost + 1e-3:
            break
        R, t, _ = point_icp(model, S, R, t, 2 * p.icp_iters, p.icp_trim)
        coarse[k] = (score_pose(model, S, R, t, tau), R, t, src)
    coarse.sort(key=lambda c: c[0].cost)

    # group into basins: poses that place the scan within the gate of each other
    basins: list[Candidate] = []
    for fit, R, t, src in coarse:
        for b in basins:
            if scan_displacement(R, t, b.R, b.t, S) <= p.basin * tau:
                b.support += 1
                b.sources.append(src)
                break
        else:
            basins.append(Candidate(R, t, fit.frac, fit.rms, 1, [src], cost=fit.cost))

    # robust refinement of the best basin and of rivals whose coarse cost is close
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
    rivals = [b for b in finals[1:] if b.cost <= best.cost * (1.0 + p.ambiguity_margin) + 1e-3]
    seconds = time.perf_counter() - t_start
    inliers = int(round(best.inlier_fraction * len(P)))
    if best.inlier_fraction < p.min_inlier_fraction:
        raise PoseNotEstablished(
            f"no pose seats the scan on the nominal: best {best.inlier_fraction:.1%} of "
            f"{len(P)} scan points within {tau:.2f} mm (need {p.min_inlier_fraction:.0%}), "
            f"rms {best.rms:.3f} mm, {n_matches} descriptor matches, best RANSAC "
            f"{best_ransac} inliers; the scan does not overlap this part"
        )
    if best.support < p.min_agreement:
        raise PoseNotEstablished(
            f"pose not confirmed: only {best.support} of {len(starts)} starts reach the best "
            f"basin ({best.inlier_fraction:.1%} within {tau:.2f} mm, rms {best.rms:.3f} mm; "
            f"need {p.min_agreement}); the restarts disagree"
        )
    at = np.unique(model.tree.query(S @ best.R.T + best.t)[1])
    th = wall_thickness(model.V, model.N, at, radius=tau, tree=model.tree)
    wall = float(np.median(th))
    if p.refuse_thin_wall and wall < tau:
        raise PoseNotEstablished(
            f"the scan lies on a {wall:.2f} mm wall (median), thinner than the "
            f"{tau:.2f} mm pose gate: a one-sided scan fits either skin and the search cannot "
            "tell which side was scanned; deliver the scan in the part frame (--prealign "
            "never)"
        )
    if rivals:
        b = rivals[0]
        dd, dt = pose_distance(b.R, b.t, best.R, best.t, S.mean(axis=0))
        log.warning(
            "ambiguous pose: a rival basin %.1f deg / %.1f mm away fits as well "
            "(%.1f%% vs %.1f%% within %.2f mm, rms %.3f vs %.3f mm): symmetric part?",
            dd, dt, 100 * b.inlier_fraction, 100 * best.inlier_fraction, tau, b.rms, best.rms,
        )
    method = "descriptor" if "descriptor" in best.sources else "restart"
    res = PrealignResult(
        R=best.R, t=best.t, rms=best.rms, inliers=inliers,
        inlier_fraction=best.inlier_fraction, restart_agreement=best.support,
        n_starts=len(starts), n_screened=n_screened, matches=n_matches, ransac_inliers=best_ransac,
        ambiguous=bool(rivals), candidates=finals + others, gate=tau, noise=scan.noise,
        seconds=seconds, method=method, rigid=rigid_by_basin.get(id(best)),
        conditioning=pose_conditioning(model.V, model.N, S @ best.R.T + best.t,
                                       tree=model.tree, boundary=model.boundary)[0],
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
    if mode == "always" or (mode == "auto" and not already_in_frame(
            V, P, F=F, seed=seed, tree=tree, normals=normals)):
        return prealign(V, F, P, seed=seed, params=params, model=model)
    p = params or (model.params if model is not None else PrealignParams())
    diag = bounding_diagonal(V)
    tau = p.gate * diag
    d, _ = (cKDTree(V) if tree is None else tree).query(P, distance_upper_bound=tau,
                                                          workers=-1)
    inl = np.isfinite(d)
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
    return PrealignResult(
        R=np.eye(3), t=np.zeros(3), rms=rms, inliers=int(inl.sum()),
        inlier_fraction=float(inl.mean()), restart_agreement=0, n_starts=0, n_screened=0,
        matches=0, ransac_inliers=0, ambiguous=False, candidates=[], gate=tau, noise=0.0,
        seconds=time.perf_counter() - t0, method="identity",
    )
