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

from .nearest import TrackedNearest

__all__ = [
    "MAD_SCALE",
    "TUKEY_C",
    "converged_rigid_fit",
    "kabsch",
    "point_to_plane_step",
    "pose_conditioning",
    "rigid_icp",
    "RigidResult",
    "robust_scale",
    "tukey_rho",
    "tukey_weights",
]

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
    a_bar = (w @ A) / sw
    b_bar = (w @ B) / sw
    # sum_i w_i (a_i - a_bar)(b_i - b_bar)^T, as one product (no centred copies)
    H = (A * w[:, None]).T @ B - sw * np.outer(a_bar, b_bar)
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
    R, dt = _rodrigues(x[:3]), x[3:]
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


def _rigid_step(
    X: np.ndarray,
    V: np.ndarray,
    idx: np.ndarray,
    n: np.ndarray,
    r: np.ndarray,
    w: np.ndarray,
    step: str,
) -> tuple[np.ndarray, np.ndarray]:
    """One pose update of :func:`rigid_icp` for the posed scan points ``X`` (m, 3) mm,
    their nearest vertices ``idx`` (m,) of ``V`` with normals ``n`` (m, 3), signed
    point-to-plane residuals ``r`` (m,) mm and weights ``w`` (m,): the weighted Kabsch fit
    to the tangent-plane projections (``step="kabsch"``) or a Gauss-Newton point-to-plane
    step. Returns the incremental rotation (3, 3) and translation (3,) mm."""
    targets = X - r[:, None] * n
    if step == "kabsch":
        return kabsch(X, targets, w)
    return point_to_plane_step(X, np.take(V, idx, axis=0), n, w)


def _small_step(dR: np.ndarray, dt: np.ndarray, tol: float, diag: float) -> bool:
    """Whether the update ``(dR, dt)`` turns less than ``tol`` radians and moves less than
    ``tol`` model diagonals (``diag`` mm): the ICP has converged."""
    angle = np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))
    return bool(angle < tol and np.linalg.norm(dt) < tol * diag)


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
    P : (m, 3) scan points, mm.  R0, t0 : the scan's initial pose (default identity).
    max_iter : iteration cap.  tol : convergence on the pose update (radians, and
        translation relative to the model diagonal).  tree : ``cKDTree(V)``, optional.
    max_distance : scan points farther than this from every model vertex get zero weight
        (mm; default 5 % of the model diagonal): points off the modelled surface.
    step : ``"kabsch"`` (default): the paper's weighted Kabsch fit to the tangent-plane
        projections; ``"plane"``: Gauss-Newton point-to-plane (a few iterations). On a
        compliant part a converged fit slides along it (the thin shell at 2 % compliance:
        23 mm and 11 degrees off); 60 Kabsch steps stay within ~3 mm, which the non-rigid
        stage absorbs: a compromise, not a measurement (the datum frame fixes the pose).

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
    # the scan moves a fraction of the mesh spacing per step: the tree is asked again only
    # for the points whose nearest vertex may have changed (the same answers, exactly)
    nearest = TrackedNearest(tree, V)
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` is reported after the loop
        X = P @ R.T
        X += t  # in place: the same sums, without a second (m, 3) temporary
        dist, idx = nearest.query(X)
        n = np.take(N, idx, axis=0)  # (np.take: qifreport.registration.arrays)
        r = np.einsum("ij,ij->i", X - np.take(V, idx, axis=0), n)  # signed point-to-plane
        near = dist < max_distance
        if near.sum() < 6:
            break
        scale = max(robust_scale(r[near]), 1e-9 * diag)
        w = tukey_weights(r, scale) * near
        history.append(float(np.sqrt(np.sum(w * r**2) / max(w.sum(), 1e-300))))
        dR, dt = _rigid_step(X, V, idx, n, r, w, step)
        R, t = dR @ R, dR @ t + dt
        if _small_step(dR, dt, tol, diag):
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


def _rodrigues(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``omega`` (radians)."""
    theta = float(np.linalg.norm(omega))
    if theta == 0.0:
        return np.eye(3)
    k = omega / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def tukey_rho(r: np.ndarray, scale: float) -> np.ndarray:
    """Tukey biweight loss ``c^2/6 (1 - (1 - u^2)^3)``, ``u = |r| / c``, ``c = 4.685 scale``
    (saturates at ``c^2 / 6`` beyond ``c``); its IRLS weight is :func:`tukey_weights`."""
    c = TUKEY_C * scale
    u = np.minimum(np.abs(r) / c, 1.0)
    return c**2 / 6.0 * (1.0 - (1.0 - u**2) ** 3)


@dataclass
class _BlendedCost:
    """The robust rigid cost of :func:`converged_rigid_fit`, evaluated at a pose.

    Attributes
    ----------
    V : (n, 3) model vertices, mm.  N : (n, 3) unit vertex normals.
    P : (m, 3) scan points, mm.  tree : ``cKDTree(V)``.
    k : vertices blended per point.  diag : model diagonal, mm.
    scale : fixed Tukey scale, mm.  max_distance : farther points cost ``outside``, mm.
    outside : the saturated Tukey loss at ``scale``, mm^2.
    on_edge : (n,) bool, vertices on an open boundary.
    """

    V: np.ndarray
    N: np.ndarray
    P: np.ndarray
    tree: cKDTree
    k: int
    diag: float
    scale: float
    max_distance: float
    outside: float
    on_edge: np.ndarray

    def __call__(self, R: np.ndarray, t: np.ndarray) -> tuple:
        """The cost of the pose ``(R, t)`` (scan -> model, mm) and what its step needs.

        Returns
        -------
        E : the cost, mm^2.  X : (m, 3) posed scan points, mm.
        n : (m, 3) blended unit normals.  r : (m,) blended point-to-plane residuals, mm.
        u : (m, 3) unit tangential offset directions.  b : (m,) tangential offsets beyond
            an open boundary, mm (0 elsewhere).  near : (m,) bool, points within
            ``max_distance`` of the model.
        """
        V, N, diag, scale = self.V, self.N, self.diag, self.scale
        X = self.P @ R.T + t
        d, idx = self.tree.query(X, k=self.k, workers=-1)
        d, idx = d.reshape(len(X), -1), idx.reshape(len(X), -1)
        wk = 1.0 / np.maximum(d, 1e-9 * diag) ** 2
        wk /= wk.sum(axis=1, keepdims=True)
        Nk = N[idx]
        n = np.einsum("ik,ikj->ij", wk, Nk)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        r = np.einsum("ik,ik->i", wk, np.einsum("ikj,ikj->ik", X[:, None, :] - V[idx], Nk))
        # beyond an open boundary: the tangential offset from the nearest (boundary) vertex
        D = X - V[idx[:, 0]]
        tang = D - np.einsum("ij,ij->i", D, n)[:, None] * n
        b = np.linalg.norm(tang, axis=1)
        u = tang / np.maximum(b, 1e-300)[:, None]
        b = np.where(self.on_edge[idx[:, 0]], b, 0.0)
        near = d[:, 0] < self.max_distance
        E = float(np.sum(np.where(near, tukey_rho(r, scale) + tukey_rho(b, scale), self.outside)))
        return E, X, n, r, u, b, near


def _normal_equations(
    X: np.ndarray,
    n: np.ndarray,
    r: np.ndarray,
    u: np.ndarray,
    b: np.ndarray,
    w: np.ndarray,
    wb: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gauss-Newton system of one rigid step about the centroid of ``X`` (m, 3) mm:
    the residuals ``r`` along the normals ``n`` weighted by ``w``, the boundary offsets
    ``b`` along ``u`` by ``wb`` (all (m,) or (m, 3)).

    Returns
    -------
    c : (3,) centroid, mm.  A : (6, 6) normal matrix.  g : (6,) right-hand side (rotation
        vector, radians, then translation, mm).
    """
    c = X.mean(axis=0)
    J = np.hstack([np.cross(X - c, n), n])
    Jb = np.hstack([np.cross(X - c, u), u])
    A = (J * w[:, None]).T @ J + (Jb * wb[:, None]).T @ Jb
    g = -(J * w[:, None]).T @ r - (Jb * wb[:, None]).T @ b
    return c, A, g


def _damped_step(
    evaluate: _BlendedCost,
    A: np.ndarray,
    g: np.ndarray,
    c: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    E: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray, tuple, float] | None:
    """A Levenberg-Marquardt step from the pose ``(R, t)`` of cost ``E`` (mm^2): the
    damping ``lam`` grows fourfold until the step does not increase the cost (at most 30
    times). Returns the new pose, its evaluation and the damping that made it, or None when
    no damping decreases the cost."""
    for _ in range(30):
        x = np.linalg.solve(A + lam * np.diag(np.diag(A)) + 1e-12 * np.trace(A) * np.eye(6), g)
        dR = _rodrigues(x[:3])
        R2, t2 = dR @ R, dR @ t + (c - dR @ c + x[3:])
        trial = evaluate(R2, t2)
        if trial[0] <= E:
            return R2, t2, trial, lam
        lam *= 4.0
    return None


def _blended_cost(
    V: np.ndarray,
    N: np.ndarray,
    P: np.ndarray,
    boundary: np.ndarray | None,
    scale: float | None,
    max_distance: float | None,
    k: int,
    tree: cKDTree | None,
) -> _BlendedCost:
    """The cost of :func:`converged_rigid_fit` (arguments as there), its defaults resolved
    from the model diagonal."""
    tree = tree or cKDTree(V)
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    scale = 0.01 * diag if scale is None else float(scale)
    max_distance = 0.05 * diag if max_distance is None else float(max_distance)
    return _BlendedCost(
        V=V,
        N=N,
        P=P,
        tree=tree,
        k=k,
        diag=diag,
        scale=scale,
        max_distance=max_distance,
        outside=float(tukey_rho(np.array([np.inf]), scale)[0]),
        on_edge=np.zeros(len(V), dtype=bool) if boundary is None else np.asarray(boundary, bool),
    )


def _minimise(
    evaluate: _BlendedCost, R0: np.ndarray, t0: np.ndarray, max_iter: int, rtol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, bool, list[float]]:
    """Levenberg-Marquardt on the cost ``evaluate`` from the pose ``(R0, t0)`` (scan ->
    model, mm): at most ``max_iter`` accepted steps, until the relative decrease falls below
    ``rtol`` or no damping decreases the cost.

    Returns
    -------
    R, t : the pose.  r : (m,) its blended residuals, mm.  near : (m,) bool, the points
        within the cost's ``max_distance``.  it : steps taken.  converged : whether a
        minimum was reached.  history : the weighted RMS residual (mm) at each step.
    """
    scale = evaluate.scale
    R = np.asarray(R0, dtype=float)
    t = np.asarray(t0, dtype=float)
    E, X, n, r, u, b, near = evaluate(R, t)
    lam, history, converged, it = 1e-4, [], False, 0
    for it in range(1, max_iter + 1):  # noqa: B007 - reported
        w = tukey_weights(r, scale) * near
        wb = tukey_weights(b, scale) * near * (b > 0)
        history.append(float(np.sqrt(np.sum(w * r**2) / max(w.sum(), 1e-300))))
        c, A, g = _normal_equations(X, n, r, u, b, w, wb)
        if np.trace(A) <= 0:
            break
        step = _damped_step(evaluate, A, g, c, R, t, E, lam)
        if step is None:  # no damping decreases E: at the minimum to numerical precision
            converged = True
            break
        R2, t2, trial, lam = step
        lam = max(lam / 4.0, 1e-8)
        decrease = (E - trial[0]) / max(E, 1e-300)
        R, t = R2, t2
        E, X, n, r, u, b, near = trial
        if decrease < rtol:
            converged = True
            break
    return R, t, r, near, it, converged, history


def converged_rigid_fit(
    V: np.ndarray,
    N: np.ndarray,
    P: np.ndarray,
    R0: np.ndarray,
    t0: np.ndarray,
    *,
    boundary: np.ndarray | None = None,
    scale: float | None = None,
    max_distance: float | None = None,
    k: int = 4,
    max_iter: int = 100,
    rtol: float = 1e-10,
    tree: cKDTree | None = None,
) -> RigidResult:
    """Rigid pose that *minimises* a fixed robust point-to-plane cost (Levenberg-Marquardt).

    :func:`rigid_icp` stops after a fixed number of Kabsch steps, which on a deformed smooth
    part leaves the pose wherever it was along a shallow valley of near-equal poses: from two
    starts 3 degrees apart it ends 1-3 degrees apart. This function minimises one well-defined
    cost to convergence, so every start in the basin ends at the same pose:

    ``E(R, t) = sum_i rho(r_i) + rho(b_i)`` over the scan points within ``max_distance`` of
    the model, Tukey ``rho`` (:func:`tukey_rho`) at a *fixed* ``scale`` (an adaptive scale
    would shrink onto the best-fitting patch of a deformed part and move the minimum with
    it). ``r_i`` is the point-to-plane residual against the inverse-square-distance blend of
    the ``k`` nearest vertices' tangent planes (continuous in the pose, so the Gauss-Newton
    steps do not jump between vertex planes). ``b_i`` is the *tangential* offset of a point
    whose nearest vertex lies on an open ``boundary``: a tangent plane extends beyond the
    edge of the part, so without it a point that slid off the edge costs nothing and an open
    sheet slides freely along itself (the cap-like thin shell: 11 degrees from the truth and
    1-2 degrees between starts; with it 3 degrees and < 0.15 degrees). Steps are damped
    (Levenberg-Marquardt) and accepted only when ``E`` decreases; it stops when the relative
    decrease falls below ``rtol``.

    Parameters
    ----------
    V : (n, 3) model vertices, mm.  N : (n, 3) unit vertex normals.
    P : (m, 3) scan points, mm.  R0, t0 : start pose (scan -> model).
    boundary : (n,) bool, vertices on an open boundary
        (:func:`qifreport.registration.mesh.boundary_vertices`); None: a closed mesh.
    scale : Tukey scale, mm (default 1 % of the model diagonal: deformation residuals of a
        few mm keep their weight).  max_distance : mm (default 5 % of the diagonal).
    k : vertices blended per point.  max_iter : accepted steps at most.
    rtol : relative decrease of ``E`` below which the minimum is reached.
    tree : optional prebuilt ``cKDTree(V)``.

    Returns
    -------
    RigidResult (``scale`` the fixed scale; ``history`` the RMS residual per accepted step).
    """
    evaluate = _blended_cost(V, N, P, boundary, scale, max_distance, k, tree)
    scale = evaluate.scale
    R, t, r, near, it, converged, history = _minimise(evaluate, R0, t0, max_iter, rtol)
    w = tukey_weights(r, scale) * near
    rms = float(np.sqrt(np.sum(w * r**2) / max(w.sum(), 1e-300)))
    log.debug("converged rigid fit: %d steps, rms %.4f mm", it, rms)
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


def pose_conditioning(
    V: np.ndarray,
    N: np.ndarray,
    X: np.ndarray,
    tree: cKDTree | None = None,
    boundary: np.ndarray | None = None,
) -> tuple[float, np.ndarray]:
    """How well the surface seen by the scan fixes a rigid pose.

    Eigen-analysis of the information matrix ``J^T J / m`` of the posed scan ``X``: one
    point-to-plane row per point, plus, for points whose nearest vertex lies on an open
    ``boundary``, a row along the outward tangent (an edge pins the slide across it), with
    rotations scaled by half the model diagonal so the six directions are in mm. The ratio of
    the smallest to the largest eigenvalue is near 0 when the seen surface can slide along
    itself (a sphere-like cap seen without its rim, a cylinder, a plane) and a rigid fit
    cannot pin that direction down (Gelfand et al., "Geometrically stable sampling for the
    ICP algorithm").

    Parameters
    ----------
    V, N : (n, 3) model vertices (mm) and unit normals.  X : (m, 3) posed scan points, mm.
    boundary : (n,) bool, open-boundary vertices, or None.

    Returns
    -------
    ratio : smallest / largest eigenvalue.  weakest : (6,) the least constrained direction
        ``(rotation, translation)``.
    """
    tree = tree or cKDTree(V)
    _, idx = tree.query(X, workers=-1)
    n = N[idx]
    half = 0.5 * float(np.linalg.norm(V.max(0) - V.min(0)))
    c = X.mean(axis=0)
    J = np.hstack([np.cross(X - c, n) / half, n])
    if boundary is not None and np.any(boundary[idx]):
        e = np.flatnonzero(boundary[idx])
        D = X[e] - V[idx[e]]
        tang = D - np.einsum("ij,ij->i", D, n[e])[:, None] * n[e]
        keep = np.linalg.norm(tang, axis=1) > 0
        u = tang[keep] / np.linalg.norm(tang[keep], axis=1)[:, None]
        J = np.vstack([J, np.hstack([np.cross(X[e[keep]] - c, u) / half, u])])
    ev, evec = np.linalg.eigh(J.T @ J / len(X))
    return float(ev[0] / max(ev[-1], 1e-300)), evec[:, 0]
