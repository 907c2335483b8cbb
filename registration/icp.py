"""Robust rigid ICP of a partial scan onto the nominal mesh (paper Section 5.2).

Each *scan point* is matched to the model (never the reverse), so unscanned regions of the
model exert no pull. Outliers are suppressed with a Tukey biweight on a robust scale
``sigma = 1.4826 median |d|``; each step is a weighted Kabsch fit with a reflection guard.
The target of a scan point is its projection onto the tangent plane of the nearest model
vertex (point-to-plane), which removes the tangential quantisation of a coarse mesh.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)

TUKEY_C = 4.685
MAD_SCALE = 1.4826


def kabsch(
    A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares rotation and translation taking ``A`` onto ``B``.

    Minimises ``sum_i w_i |R a_i + t - b_i|^2`` (paper Eq. 8) with the determinant guard
    ``diag(1, 1, det(V U^T))`` so that ``R`` is a proper rotation, never a reflection.

    Parameters
    ----------
    A, B : (k, 3) corresponding points, mm.
    w : (k,) non-negative weights (default all ones).

    Returns
    -------
    R : (3, 3) rotation, ``det(R) = +1``.  t : (3,) translation, mm.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    w = np.ones(len(A)) if w is None else np.asarray(w, dtype=float)
    sw = w.sum()
    if sw <= 0:
        return np.eye(3), np.zeros(3)
    a_bar = (w[:, None] * A).sum(axis=0) / sw
    b_bar = (w[:, None] * B).sum(axis=0) / sw
    H = ((A - a_bar) * w[:, None]).T @ (B - b_bar)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, b_bar - R @ a_bar


def point_to_plane_step(
    X: np.ndarray, T: np.ndarray, N: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One weighted Gauss-Newton step of point-to-plane alignment of ``X`` onto planes ``(T, N)``.

    Minimises ``sum_i w_i ((R x_i + t - t_i) . n_i)^2`` linearised in the rotation
    (``R ~ I + [omega]x``), then re-orthonormalises ``R`` exactly (Rodrigues).

    Returns
    -------
    R : (3, 3) rotation.  t : (3,) translation, mm.
    """
    c = X.mean(axis=0)
    Xc = X - c
    J = np.hstack([np.cross(Xc, N), N])  # (k, 6): d r / d(omega, t)
    r = np.einsum("ij,ij->i", X - T, N)
    A = (J * w[:, None]).T @ J
    b = -(J * w[:, None]).T @ r
    try:
        x = np.linalg.solve(A + 1e-12 * np.trace(A) * np.eye(6), b)
    except np.linalg.LinAlgError:
        return np.eye(3), np.zeros(3)
    omega, dt = x[:3], x[3:]
    theta = float(np.linalg.norm(omega))
    if theta > 0:
        k = omega / theta
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
    else:
        R = np.eye(3)
    # rotation about the centroid c, then the translation
    return R, c - R @ c + dt


def tukey_weights(d: np.ndarray, scale: float) -> np.ndarray:
    """Tukey biweight ``(1 - (d / (4.685 s))^2)^2`` for ``|d| < 4.685 s``, else 0."""
    if scale <= 0:
        return (np.abs(d) == 0).astype(float)
    u = np.abs(d) / (TUKEY_C * scale)
    return np.where(u < 1.0, (1.0 - u**2) ** 2, 0.0)


def robust_scale(d: np.ndarray) -> float:
    """Robust scale ``1.4826 median |d|`` (mm)."""
    return float(MAD_SCALE * np.median(np.abs(d))) if len(d) else 0.0


@dataclass
class RigidResult:
    """Outcome of :func:`rigid_icp`. The transform maps scan points into the model frame.

    Attributes
    ----------
    R : (3, 3) rotation.  t : (3,) translation, mm: ``P_model = P @ R.T + t``.
    rms : weighted point-to-plane residual at convergence, mm.
    scale : final robust scale, mm.
    inlier_fraction : fraction of scan points with non-zero Tukey weight.
    iterations : iterations run.  converged : whether the pose update fell below tolerance.
    history : residual RMS per iteration, mm.
    """

    R: np.ndarray
    t: np.ndarray
    rms: float
    scale: float
    inlier_fraction: float
    iterations: int
    converged: bool
    history: list[float] = field(default_factory=list)

    def apply(self, P: np.ndarray) -> np.ndarray:
        """Map scan points (m, 3) into the model frame."""
        return P @ self.R.T + self.t


def rigid_icp(
    V: np.ndarray,
    N: np.ndarray,
    P: np.ndarray,
    R0: np.ndarray | None = None,
    t0: np.ndarray | None = None,
    max_iter: int = 60,
    tol: float = 1e-6,
    max_distance: float | None = None,
    tree: cKDTree | None = None,
    step: str = "kabsch",
) -> RigidResult:
    """Robust partial-overlap rigid ICP of the scan ``P`` onto the model ``(V, N)``.

    Parameters
    ----------
    V : (n, 3) model vertices, mm.  N : (n, 3) unit vertex normals.
    P : (m, 3) scan points, mm.
    R0, t0 : initial pose of the scan in the model frame (default identity).
    max_iter : iteration cap.  tol : convergence on the pose update (radians, and
        translation relative to the model diagonal).
    max_distance : scan points farther than this from every model vertex get zero weight
        (mm; default 5 % of the model diagonal): points off the modelled surface.
    tree : optional prebuilt ``cKDTree(V)``.
    step : ``"kabsch"`` (default): the paper's weighted Kabsch fit to the tangent-plane
        projections; ``"plane"``: Gauss-Newton point-to-plane step (converges in a few
        iterations). Measured on the thin-shell benchmark with 2 % compliance: a converged
        rigid fit of a deformed smooth shell *slides* along it (point-to-plane: 23 mm and
        11 degrees from the true placement) because sliding lets the bent part fit better;
        the Kabsch step stays within ~3 mm in 60 iterations, which the non-rigid stage then
        absorbs. A rigid pose of a compliant part is a compromise, not a measurement: the
        datum reference frame (STEP PMI) is what fixes it for reporting.

    Returns
    -------
    RigidResult
    """
    tree = tree or cKDTree(V)
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    max_distance = 0.05 * diag if max_distance is None else max_distance
    R = np.eye(3) if R0 is None else np.asarray(R0, dtype=float)
    t = np.zeros(3) if t0 is None else np.asarray(t0, dtype=float)
    history: list[float] = []
    converged = False
    scale = 0.0
    w = np.zeros(len(P))
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` is reported after the loop
        X = P @ R.T + t
        dist, idx = tree.query(X, workers=-1)
        n = N[idx]
        r = np.einsum("ij,ij->i", X - V[idx], n)  # signed point-to-plane residual
        near = dist < max_distance
        if near.sum() < 6:
            break
        scale = max(robust_scale(r[near]), 1e-9 * diag)
        w = tukey_weights(r, scale) * near
        history.append(float(np.sqrt(np.sum(w * r**2) / max(w.sum(), 1e-300))))
        targets = X - r[:, None] * n
        if step == "kabsch":
            dR, dt = kabsch(X, targets, w)

        else:
            dR, dt = point_to_plane_step(X, V[idx], n, w)
        R, t = dR @ R, dR @ t + dt
        angle = np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))
        if angle < tol and np.linalg.norm(dt) < tol * diag:
            converged = True
            break
    rms = history[-1] if history else float("nan")
    log.debug("rigid ICP: %d iterations, rms %.4f mm, scale %.4f mm", it, rms, scale)
    return RigidResult(
        R=R,
        t=t,
        rms=rms,
        scale=scale,
        inlier_fraction=float((w > 0).mean()) if len(w) else 0.0,
        iterations=it,
        converged=converged,
        history=history,
    )
