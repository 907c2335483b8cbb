"""Non-rigid coherent point drift (Myronenko & Song 2010), the paper's CPD baseline (6.2).

The rigidly aligned nominal vertices ``Y`` are the centroids of a Gaussian mixture, the scan
points ``X`` its data; EM alternates the posteriors ``P`` (M, N) of the correspondences,
with a uniform outlier component of weight ``w``, and the displacement field
``v(y) = sum_i G(y, y_i) W_i`` regularised by motion coherence, ``G`` a Gaussian kernel of
width ``beta``. The M-step solves

    (G + lambda sigma^2 diag(P 1)^-1) W = diag(P 1)^-1 P X - Y,

here in its symmetric positive-definite form (a Cholesky factorisation)

    (D^1/2 G D^1/2 + lambda sigma^2 I) Z = D^-1/2 P X - D^1/2 Y,   W = D^1/2 Z,   D = diag(P 1).

The correspondence matrix is dense, so the mixture is fitted on decimated sets (farthest-point
sampling of the nominal vertices and of the scan, seeded); the continuous warp
``v -> v + sum_i exp(-|v - y_i|^2 / (2 beta^2)) W_i`` is then evaluated at *every* nominal
vertex, in chunks of bounded memory, so the estimate is CPD's own field on the nominal
vertex set (paper Section 6.2).

Coordinates are in mm throughout (both sets share the rigid frame, so they are not
normalised separately as in Myronenko's reference code -- that would change the relative
pose); they are centred on the source centroid for numerical range only.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from qifreport.registration.deformable.result import (
    DeformResult,
    coverage_radius,
    finish,
    scan_matcher,
)
from qifreport.registration.mesh import MeshOperators, bounding_diagonal
from qifreport.registration.normals import pca_normals

__all__ = [
    "cpd",
    "cpd_em",
    "cpd_warp",
    "CPDFit",
    "CPDParams",
    "gaussian_kernel",
    "resolve_params",
    "sample_points",
]

log = logging.getLogger(__name__)


@dataclass
class CPDParams:
    """Parameters of :func:`cpd` (lengths in mm).

    Attributes
    ----------
    beta : width of the motion-coherence kernel, mm. Default 10 % of the bounding diagonal
        (Myronenko's ``beta = 2`` in unit-variance coordinates would be ~60 % of the
        diagonal here, too stiff to follow a bend over the part; 10 % follows a bend and a
        twist while still coupling a few centimetres of surface on a 100 mm part).
    lam : regularisation weight ``lambda`` (Myronenko's default 2).
    w : weight of the uniform outlier component (0 <= w < 1); 0.1 for the noise and for
        scan points near surfaces the decimated source does not sample.
    n_source, n_scan : decimated sizes of the nominal vertex set and of the scan.
    sampling : ``"fps"`` (farthest-point, evenly spread) or ``"random"``; both seeded.
    max_iter : EM iteration cap (Myronenko: 150).
    tol : stop when the relative change of the EM objective falls below ``tol``
        (Myronenko: 1e-5).
    sigma2 : initial mixture variance, mm^2. Default Myronenko's
        ``sum |x_n - y_m|^2 / (3 M N)``.
    seed : seed of the decimation.
    chunk : kernel entries per block when the warp is evaluated at all vertices (bounds
        memory: 4e6 entries = 32 MB).
    coverage_radius : radius of the final coverage test, mm (default as GB-CICP).
    scan_normal_k : neighbours of the PCA scan normals when they are not given.
    """

    beta: float | None = None
    lam: float = 2.0
    w: float = 0.1
    n_source: int = 1500
    n_scan: int = 1500
    sampling: str = "fps"
    max_iter: int = 150
    tol: float = 1e-5
    sigma2: float | None = None
    seed: int = 0
    chunk: int = 4_000_000
    coverage_radius: float | None = None
    scan_normal_k: int = 12


@dataclass
class CPDFit:
    """The EM result on the decimated sets.

    Attributes
    ----------
    Y : (M, 3) source centroids (kernel centres), mm.  W : (M, 3) kernel coefficients, mm.
    TY : (M, 3) the moved centroids ``Y + G W`` at the last M-step, mm.
    sigma2 : final mixture variance, mm^2.  iterations : EM iterations run.
    history : per iteration, ``sigma2`` and the objective.
    """

    Y: np.ndarray
    W: np.ndarray
    TY: np.ndarray
    sigma2: float
    iterations: int
    history: list[dict]


def sample_points(X: np.ndarray, k: int, method: str = "fps", seed: int = 0) -> np.ndarray:
    """Indices (min(k, len(X)),) of a seeded subsample: farthest-point or uniform random."""
    n = len(X)
    rng = np.random.default_rng(seed)
    if k >= n:
        return np.arange(n)
    if method == "random":
        return np.sort(rng.choice(n, size=k, replace=False))
    if method != "fps":
        raise ValueError(f"unknown sampling {method!r} (fps or random)")
    idx = np.empty(k, dtype=np.int64)
    idx[0] = rng.integers(n)
    d = np.sum((X - X[idx[0]]) ** 2, axis=1)
    for i in range(1, k):
        idx[i] = int(np.argmax(d))
        np.minimum(d, np.sum((X - X[idx[i]]) ** 2, axis=1), out=d)
    return idx


def _sqdist(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Squared distances (len(A), len(B)) by ``|a|^2 + |b|^2 - 2 a.b`` (one matrix product;
    the callers centre the coordinates so the cancellation stays at rounding level)."""
    d2 = np.sum(A**2, axis=1)[:, None] + np.sum(B**2, axis=1)[None, :] - 2.0 * (A @ B.T)
    return np.maximum(d2, 0.0)


def gaussian_kernel(A: np.ndarray, B: np.ndarray, beta: float) -> np.ndarray:
    """``exp(-|a - b|^2 / (2 beta^2))`` (len(A), len(B))."""
    return np.exp(-_sqdist(A, B) / (2.0 * beta**2))


def cpd_em(
    X: np.ndarray,
    Y: np.ndarray,
    beta: float,
    lam: float = 2.0,
    w: float = 0.1,
    sigma2: float | None = None,
    max_iter: int = 150,
    tol: float = 1e-5,
    callback: Callable[[int], Any] | None = None,
) -> CPDFit:
    """Non-rigid CPD EM of the centroids ``Y`` (M, 3) onto the data ``X`` (N, 3), mm.

    The E-step, M-step and variance update are Myronenko & Song's (2010, Fig. 4), as in
    ``pycpd.DeformableRegistration`` (``alpha`` there is ``lam`` here); the M-step is solved
    in the symmetric form of the module docstring. Stops after ``max_iter`` iterations or
    when the relative change of the objective
    ``Np D / 2 log sigma^2 + lam / 2 tr(W^T G W)`` is below ``tol``.
    """
    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    N, D = X.shape
    M = len(Y)
    c0 = Y.mean(axis=0)
    Xc, Yc = X - c0, Y - c0
    G = gaussian_kernel(Yc, Yc, beta)
    if sigma2 is None:
        sigma2 = float(np.sum(_sqdist(Xc, Yc))) / (D * M * N)
    W = np.zeros((M, D))
    TY = Yc.copy()
    xx = np.sum(Xc**2, axis=1)
    history: list[dict] = []
    L_old = np.inf
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        # E-step
        Pm = np.exp(-_sqdist(TY, Xc) / (2.0 * sigma2))
        c = (2.0 * np.pi * sigma2) ** (D / 2.0) * w / (1.0 - w) * M / N
        den = Pm.sum(axis=0)
        den[den == 0] = np.finfo(float).eps
        Pm /= den + c
        Pt1 = Pm.sum(axis=0)
        P1 = Pm.sum(axis=1)
        Np = float(P1.sum())
        PX = Pm @ Xc
        # M-step (symmetric positive-definite form)
        d = np.sqrt(P1)
        safe = np.where(d > 0, d, 1.0)
        rhs = np.where(d[:, None] > 0, PX / safe[:, None], 0.0) - d[:, None] * Yc
        A = d[:, None] * G * d[None, :]
        A[np.diag_indices(M)] += lam * sigma2
        Z = sla.cho_solve(
            sla.cho_factor(A, lower=True, check_finite=False), rhs, check_finite=False
        )
        W = d[:, None] * Z
        TY = Yc + G @ W
        # variance
        s2 = (xx @ Pt1 - 2.0 * np.sum(TY * PX) + np.sum(TY**2, axis=1) @ P1) / (Np * D)
        sigma2 = float(s2) if s2 > 0 else 1e-10
        L = Np * D / 2.0 * np.log(sigma2) + lam / 2.0 * float(np.sum(W * (G @ W)))
        history.append(dict(sigma2=sigma2, objective=L))
        if callback is not None:
            callback(1)
        if np.isfinite(L_old) and abs(L - L_old) <= tol * abs(L):
            break
        L_old = L
    return CPDFit(Y=Y, W=W, TY=TY + c0, sigma2=sigma2, iterations=it, history=history)


def cpd_warp(
    V: np.ndarray, Y: np.ndarray, W: np.ndarray, beta: float, chunk: int = 4_000_000
) -> np.ndarray:
    """The CPD warp ``v + sum_i exp(-|v - y_i|^2 / (2 beta^2)) W_i`` at the points ``V``.

    Parameters
    ----------
    V : (n, 3) points, mm.  Y : (M, 3) kernel centres, mm.  W : (M, 3) coefficients, mm.
    beta : kernel width, mm.  chunk : kernel entries per block (memory bound).

    Returns
    -------
    (n, 3) warped points, mm.
    """
    V = np.asarray(V, dtype=np.float64)
    c0 = Y.mean(axis=0)
    Yc = Y - c0
    out = np.empty_like(V)
    step = max(1, int(chunk) // max(len(Y), 1))
    for a in range(0, len(V), step):
        out[a : a + step] = V[a : a + step] + gaussian_kernel(V[a : a + step] - c0, Yc, beta) @ W
    return out


def cpd(
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    params: CPDParams | None = None,
    scan_normals: np.ndarray | None = None,
    scan_sheets: np.ndarray | None = None,
    progress: Callable[[int], Any] | None = None,
) -> DeformResult:
    """Non-rigid CPD of the rigidly aligned nominal ``V0`` onto the scan ``P``.

    Parameters
    ----------
    V0 : (n, 3) nominal vertices in the scan's frame after rigid alignment, mm.
    F : (f, 3) triangles.  ops : operators of the nominal (normals for the final match).
    P : (m, 3) scan points, mm.
    params : :class:`CPDParams` (defaults resolved from the part size).
    scan_normals, scan_sheets : used only by the final coverage match
        (:func:`qifreport.registration.deformable.result.scan_matcher`); CPD itself ignores normals.
    progress : optional ``progress(1)`` per EM iteration.

    Returns
    -------
    DeformResult with ``method="cpd"``; ``history`` holds ``sigma2`` and the objective per
    EM iteration, and the first record also the decimated indices (``source``, ``scan``),
    the kernel coefficients ``W`` and the EM's moved centroids ``TY``.
    """
    t0 = time.perf_counter()
    p = resolve_params(params or CPDParams(), V0, F, P)
    src = sample_points(V0, p.n_source, p.sampling, p.seed)
    dst = sample_points(P, p.n_scan, p.sampling, p.seed + 1)
    fit = cpd_em(
        P[dst], V0[src], p.beta, p.lam, p.w, p.sigma2, p.max_iter, p.tol, callback=progress
    )
    V = cpd_warp(V0, fit.Y, fit.W, p.beta, p.chunk)
    Ns = scan_normals if scan_normals is not None else pca_normals(P, p.scan_normal_k)
    matcher = scan_matcher(V0, F, ops, P, Ns, scan_sheets, radius=p.coverage_radius)
    history = [dict(h) for h in fit.history]
    if history:
        history[0].update(source=src, scan=dst, W=fit.W, TY=fit.TY)
    log.debug("CPD: %d EM iterations, sigma2 %.3g mm^2", fit.iterations, fit.sigma2)
    return finish("cpd", V0, V, matcher, p, fit.iterations, time.perf_counter() - t0, history)


def resolve_params(p: CPDParams, V0: np.ndarray, F: np.ndarray, P: np.ndarray) -> CPDParams:
    """The settings :func:`cpd` actually runs with: ``p`` with its size-dependent defaults.

    Parameters
    ----------
    p : the requested settings (not modified).
    V0 : (n, 3) nominal vertices in the scan's frame, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points, mm.

    Returns
    -------
    A copy of ``p`` with ``beta`` (10 % of the bounding diagonal of ``V0``) and
    ``coverage_radius`` (:func:`qifreport.registration.deformable.result.coverage_radius`) filled in
    where they are None.

    Raises
    ------
    ValueError
        The outlier weight ``w`` is not in [0, 1).
    """
    q = CPDParams(**vars(p))
    if q.beta is None:
        q.beta = 0.1 * bounding_diagonal(V0)
    if q.coverage_radius is None:
        q.coverage_radius = coverage_radius(V0, F, P)
    if not 0.0 <= q.w < 1.0:
        raise ValueError(f"CPD outlier weight w must be in [0, 1), got {q.w}")
    return q
