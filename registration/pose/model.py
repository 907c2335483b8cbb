"""The pose search's two prepared sides: the nominal (scan-free, cached per part) and the scan.

:func:`prepare_model` computes everything about the nominal that does not depend on the scan
-- resolution-matched curvature fields ``[H, K, S, C]``, farthest-point keypoints and their
geodesic neighbourhoods, the area-weighted principal frame, the coarse-ICP vertex sample --
into a :class:`PreparedModel`, which memoises its descriptors per range bandwidth.
:func:`prepare_scan` does the same for one scan (:class:`PreparedScan`). The settings of the
whole search are :class:`PrealignParams` (steps 1-2 of :mod:`qifreport.registration.pose.prealign`).
All lengths in mm.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from qifreport.registration.mesh import (
    boundary_vertices,
    bounding_diagonal,
    edges,
    vertex_areas,
    vertex_normals,
)
from qifreport.registration.pose.curvature import mesh_curvatures, scan_curvatures
from qifreport.registration.pose.descriptors import (
    SCALES,
    DescriptorSet,
    GeodesicBalls,
    bilateral_filter,
    farthest_points,
    field_noise,
    geodesic_balls,
    knn_graph,
    mesh_graph,
    presmooth,
)
from qifreport.registration.pose.geometry import principal_axes

__all__ = [
    "PrealignParams",
    "PreparedModel",
    "PreparedScan",
    "mean_edge_length",
    "prepare_model",
    "prepare_scan",
]

log = logging.getLogger(__name__)


@dataclass
class PrealignParams:
    """Settings of the pose search (lengths relative to the model unless stated).

    Used by :func:`qifreport.registration.pose.prealign.prealign` and :func:`prepare_model`.

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
    refuse_thin_wall : refuse the pose
        (:class:`~qifreport.registration.pose.prealign.PoseNotEstablished`) when most of the scan
        lies on a wall thinner than the gate
        (:func:`qifreport.registration.mesh.wall_thickness`): a one-sided scan of a thin solid
        fits the other skin, shifted by the wall, about as well -- measured on the demo panel
        (1.8 mm wall, 2.8 mm free-state deflection) at the paper's pose: the inner skin fits
        *better* (rms 0.43 against 0.62 mm) and the outer skin's tolerance got no data. Which
        side was scanned is not in the points.
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
    # one farthest-point sequence: its first samples are the keypoints, and its first
    # ``coarse_vertices`` the coarse model (a shorter run from the same seed is its prefix;
    # a sample of every vertex is all of them, in order)
    n = len(V)
    fps = farthest_points(V, min(max(p.model_keypoints, p.coarse_vertices), n - 1), seed, tree)

    def sample(k: int) -> np.ndarray:
        return fps[:k] if k < n else np.arange(n, dtype=np.int64)

    kp = sample(p.model_keypoints)
    balls = geodesic_balls(mesh_graph(V, F), kp, 3.0 * max(p.scales) * h, tree=tree)
    c, U = principal_axes(V, area)
    Vc = V[sample(p.coarse_vertices)]
    log.debug(
        "model: %d vertices, h %.3f mm, %d keypoints, %d ball entries",
        len(V),
        h,
        len(kp),
        len(balls.rows),
    )
    return PreparedModel(
        V=V,
        F=F,
        N=vertex_normals(V, F),
        tree=tree,
        diag=diag,
        h=h,
        area=area,
        fields=fields,
        balls=balls,
        centroid=c,
        axes=U,
        Vc=Vc,
        coarse_tree=cKDTree(Vc),
        params=p,
        boundary=boundary_vertices(F, len(V)),
    )


@dataclass
class PreparedScan:
    """The scan side of the pose search (one scan, in its own frame).

    Attributes
    ----------
    P : (k, 3) the points the descriptors use (at most ``scan_max_points``, mm).
    tree : ``cKDTree(P)``.  fields : (k, 4) resolution-matched ``[H, K, S, C]``.
    area : (k,) per-point areas (squared local spacing), mm^2.
    eta_fields : (4,) noise of each field in its own units.  noise : range noise, mm.
    balls : geodesic neighbourhoods of the keypoints (on the k-nearest-neighbour graph).
    """

    P: np.ndarray
    tree: cKDTree
    fields: np.ndarray
    area: np.ndarray
    eta_fields: np.ndarray
    noise: float
    balls: GeodesicBalls


def prepare_scan(P: np.ndarray, model: PreparedModel, seed: int) -> PreparedScan:
    """Curvature fields, noise, keypoints and geodesic neighbourhoods of a scan.

    Parameters
    ----------
    P : (m, 3) validated scan points, mm (a seeded random subset of ``scan_max_points`` is
        used when there are more).
    model : the prepared nominal (its ``params``, mean edge length and diagonal set the
        scales).
    seed : seed of the subset (``seed + 1``) and of the keypoints.
    """
    p = model.params
    if len(P) > p.scan_max_points:
        rng = np.random.default_rng(seed + 1)
        P = P[np.sort(rng.choice(len(P), size=p.scan_max_points, replace=False))]
    tree = cKDTree(P)
    sc = scan_curvatures(P, k=p.scan_k, tree=tree)
    area = sc.spacing**2
    eta = field_noise(sc.stack(), P, tree=tree)
    fields = presmooth(
        P, sc.H, sc.K, area, p.presmooth * model.h, 1e-3 / model.diag, tree=tree
    ).stack()
    kp = farthest_points(P, p.scan_keypoints, seed=seed, tree=tree)
    balls = geodesic_balls(knn_graph(P, tree=tree), kp, 3.0 * max(p.scales) * model.h, tree=tree)
    return PreparedScan(P, tree, fields, area, eta, sc.noise, balls)
