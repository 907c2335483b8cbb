"""Candidate starts of the pose search (steps 3-5 of :mod:`qifreport.registration.pose.prealign`).

Three kinds of start, all poses scan -> model (``P_model = P @ R.T + t``, mm):

* ``descriptor``: descriptor matches (:func:`mutual_matches`, :func:`knn_matches`) between
  the model's and the scan's keypoints, both scan-normal signs, and RANSAC on compatible
  triplets (:func:`ransac_triplets`), the hypotheses re-scored on a scan sample
  (:func:`descriptor_hypotheses`);
* ``pca``: the proper signed axis permutations (:func:`axis_hypotheses`) mapping the scan's
  principal axes onto the model's, centroid-aligned;
* ``random``: uniformly random rotations (:func:`random_rotations`), centroid-aligned.

:func:`initial_starts` assembles them in that order.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from qifreport.registration.icp import kabsch
from qifreport.registration.pose.descriptors import (
    DescriptorSet,
    bilateral_filter,
    joint_normalize,
    range_bandwidths,
)
from qifreport.registration.pose.fit import PoseFit, score_pose
from qifreport.registration.pose.geometry import pose_distance, principal_axes
from qifreport.registration.pose.model import PrealignParams, PreparedModel, PreparedScan

__all__ = [
    "Hypothesis",
    "Start",
    "axis_hypotheses",
    "descriptor_hypotheses",
    "initial_starts",
    "knn_matches",
    "mutual_matches",
    "ransac_triplets",
    "random_rotations",
]

#: a descriptor hypothesis: its fit on the scan sample, ``R``, ``t`` and its RANSAC inliers
Hypothesis = tuple[PoseFit, np.ndarray, np.ndarray, int]
#: a start of the ICP: ``R``, ``t`` and its kind (``descriptor``, ``pca`` or ``random``)
Start = tuple[np.ndarray, np.ndarray, str]


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


def random_rotations(n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n`` uniformly random rotations (3, 3) drawn from ``rng`` (none when ``n <= 0``)."""
    if n <= 0:
        return []
    return list(Rotation.random(n, random_state=rng).as_matrix())


def descriptor_hypotheses(
    model: PreparedModel,
    scan: PreparedScan,
    S: np.ndarray,
    tau: float,
    p: PrealignParams,
    rng: np.random.Generator,
) -> tuple[list[Hypothesis], int]:
    """RANSAC pose hypotheses from descriptor matches, scored on the scan sample ``S``.

    Range bandwidths from the model's fields and the scan's noise, the model's (memoised)
    and the scan's descriptors, heavy tails compressed (``asinh(f / (3 eta_f))``) and jointly
    normalised; the ``salient`` keypoints of each side matched (:func:`mutual_matches` when
    ``match_k == 0``, else :func:`knn_matches`) for both signs of the scan normals, and the
    best 20 RANSAC hypotheses (:func:`ransac_triplets`) of each sign scored by
    :func:`~qifreport.registration.pose.fit.score_pose`.

    Parameters
    ----------
    model, scan : the prepared sides.  S : (k, 3) scan sample the hypotheses are scored on.
    tau : gate, mm.  p : settings.  rng : generator of the RANSAC draws.

    Returns
    -------
    hypotheses : ``(fit, R, t, ransac_inliers)``, lowest cost first.
    matches : descriptor matches over both signs.
    """
    sig_r = range_bandwidths(model.fields, scan.eta_fields, c=p.range_c, r0=p.range_r0)
    dm = model.descriptors(sig_r)
    scales = np.asarray(p.scales) * model.h
    DS = bilateral_filter(scan.balls, scan.fields, scan.area, scales, sig_r)
    ds = DescriptorSet(scan.balls.sources, scan.P[scan.balls.sources], DS, scales, sig_r)
    comp = np.repeat(np.maximum(3.0 * scan.eta_fields, 1e-12), len(p.scales))

    hyps: list[Hypothesis] = []
    n_matches = 0
    L = len(p.scales)
    for side in (ds, ds.flipped()):
        im, js = np.arange(len(dm.D)), np.arange(len(side.D))
        if p.salient < 1.0:  # drop the flattest keypoints (no curvature to match on)
            cm, cs = dm.D[:, 3 * L :].mean(axis=1), side.D[:, 3 * L :].mean(axis=1)
            thr = np.quantile(np.concatenate([cm, cs]), 1.0 - p.salient)
            im, js = np.flatnonzero(cm >= thr), np.flatnonzero(cs >= thr)
        A, B, _, _ = joint_normalize(np.arcsinh(dm.D[im] / comp), np.arcsinh(side.D[js] / comp))
        pairs = mutual_matches(A, B, p.ratio) if p.match_k == 0 else knn_matches(A, B, p.match_k)
        n_matches += len(pairs)
        for R, t, cnt in ransac_triplets(
            side.X[js[pairs[:, 1]]], dm.X[im[pairs[:, 0]]], tau, p.ransac_iters, rng
        )[:20]:
            hyps.append((score_pose(model, S, R, t, tau), R, t, cnt))
    hyps.sort(key=lambda h: h[0].cost)
    return hyps, n_matches


def initial_starts(
    model: PreparedModel,
    P: np.ndarray,
    hyps: list[Hypothesis],
    p: PrealignParams,
    rng: np.random.Generator,
) -> list[Start]:
    """Every start of the search: descriptor, then principal-axis, then random.

    Parameters
    ----------
    model : the prepared nominal (its principal frame and centroid).
    P : (m, 3) the scan, mm (its principal frame and centroid).
    hyps : :func:`descriptor_hypotheses`, best first; the first ``descriptor_starts`` are kept.
    p : settings.  rng : generator of the random rotations.

    Returns
    -------
    ``(R, t, kind)`` per start; the principal-axis and random rotations are centroid-aligned.
    """
    starts: list[Start] = [(h[1], h[2], "descriptor") for h in hyps[: p.descriptor_starts]]
    cs, Us = principal_axes(P)
    for M in axis_hypotheses(p.axis_permutations):
        R = model.axes @ M @ Us.T
        starts.append((R, model.centroid - R @ cs, "pca"))
    for R in random_rotations(p.random_restarts, rng):
        starts.append((R, model.centroid - R @ cs, "random"))
    return starts
