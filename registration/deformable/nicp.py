"""Optimal-step non-rigid ICP (Amberg et al. 2007), the paper's NICP baseline (Section 6.3).

Every nominal vertex ``i`` carries its own affine transform ``X_i`` (4 x 3, acting on the
homogeneous vertex ``[v_i 1]``); stacked, ``X`` is (4n, 3). With ``D`` the (n, 4n) matrix
placing ``[v_i 1]`` in the columns of vertex ``i``, the deformed vertices are ``D X`` and each
step minimises

    E(X) = || W_D (D X - U) ||^2 + alpha^2 || (M_inc (x) G) X ||^2,

``M_inc`` the node-arc incidence matrix of the mesh edges, ``G = diag(1, 1, 1, gamma)``,
``U`` the targets and ``W_D`` the robust gate weights. The normal equations

    (alpha^2 (M_inc (x) G)^T (M_inc (x) G) + D^T W_D D) X = D^T W_D U

are a sparse SPD system in 4n unknowns, three right-hand sides. ``(M_inc (x) G)^T (M_inc (x) G)
= L_graph (x) G^2`` is assembled once; its pattern together with the 4 x 4 diagonal blocks
of ``D^T W_D D`` is fixed, so per iteration only the values are refilled (a vector operation).
The matrix is factorised once per stiffness level (CHOLMOD reusing its symbolic analysis when
installed, else SuperLU in a block nested-dissection order); the further iterations of a
level, where only a few gate weights differ, solve the exact system by conjugate gradients
preconditioned with that factor (a few CG iterations on the fandisk, far cheaper than a
SuperLU factorisation of its 115,640 unknowns).

Choices stated:

* **Targets** ``U``: the nearest scan point of each vertex, found by
  :class:`qifreport.registration.deformable.result.ScanMatcher` (Amberg's closest point);
  ``targets="plane"`` uses the matcher's point-to-plane targets instead (the vertex projected
  onto the tangent plane of its nearest scan point, as GB-CICP).
* **Gate** ``W_D``: binary as in Amberg -- weight 1, or 0 when the vertex is not covered
  (matched point farther than the coverage radius tangentially), when the normal
  compatibility ``|n . n_scan|`` (with the *current* deformed vertex normals) is below
  ``normal_gate``, or when the normal residual exceeds the distance gate
  ``max(gate_k x robust scale, gate_floor)``.
* **Units**: the vertices are centred on their centroid and divided by the bounding
  diagonal before the affines are formed (``gamma = 1`` then balances the linear and
  translational parts on a part of unit size, as in Amberg's normalised setting).
* **Stiffness as a length**: for a smooth field the cheapest way for the affines to follow
  a displacement ``u`` is mostly through their translations, and the stiffness term then
  approximates a membrane energy ``alpha^2 gamma^2 sqrt(3) a ||grad u||^2`` per data term of
  a vertex of area ``a`` -- a smoothing length ``l = alpha gamma sqrt(sqrt(3) a)`` (gain of a
  mode of wavenumber k: ``1 / (1 + (k l)^2)``). The default schedule is therefore given as
  lengths (mm), from near-rigid to the coverage radius, turned into ``alpha`` with the mean
  normalised vertex area, so it does not depend on the mesh resolution.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from qifreport.registration.deformable.result import (
    DeformResult,
    Match,
    ScanMatcher,
    coverage_radius,
    finish,
    scan_matcher,
)
from qifreport.registration.icp import robust_scale
from qifreport.registration.linalg import SPDSolver, default_backend
from qifreport.registration.mesh import (
    MeshOperators,
    adjacency,
    bounding_diagonal,
    edges,
    vertex_normals,
)
from qifreport.registration.normals import pca_normals
from qifreport.registration.ordering import nested_dissection

__all__ = [
    "nicp",
    "NICPParams",
]

log = logging.getLogger(__name__)


@dataclass
class NICPParams:
    """Parameters of :func:`nicp` (lengths in mm).

    Attributes
    ----------
    alpha_start, alpha_end : stiffness ``alpha`` of the first and last level (dimensionless,
        on the diagonal-normalised part). Default: from ``band_start`` / ``band_end``.
    band_start : smoothing length of the first level, mm. Default 25 % of the bounding
        diagonal (near-rigid: a bend over the whole part is followed only partly).
    band_end : smoothing length of the last level, mm. Default one coverage radius (the
        resolution of the correspondences; GB-CICP's default band limit too).
    levels : number of stiffness levels, geometric from ``alpha_start`` to ``alpha_end``.
    inner_iter : at most this many correspondence/solve iterations per level.
    tol : end a level early when no vertex with data moved more than ``tol`` mm in an
        iteration (the vertices no data reaches -- the far side of a solid -- are an
        extrapolation that keeps shifting as a few gate weights at the edge of the scanned
        region flip; measured on the fandisk, they move up to ~0.8 mm per iteration at the
        last level while the fitted surface has settled).
    gamma : weight of the translational against the linear part of the affines (Amberg: 1).
    normal_gate : zero weight where ``|n . n_scan| < normal_gate``.
    gate_k : distance gate: zero weight where ``|r| > max(gate_k x robust scale, gate_floor)``.
    gate_floor : floor of the distance gate, mm. Default 1.5 coverage radii (the rigid pose
        leaves residuals of several robust scales where the compliance is largest; the
        floor keeps them in while the stiff levels bring them closer).
    coverage_radius : tangential matching radius, mm. Default 1.5 x max(median edge,
        median scan spacing), as GB-CICP.
    update_normals : recompute the vertex normals of the deformed mesh for the normal gate
        every iteration (Amberg); False: the nominal normals throughout.
    scan_normal_k : neighbours of the PCA scan normals when they are not given.
    cg_rtol : relative residual of the conjugate-gradient solves (see :func:`nicp`).
    targets : ``"point"`` -- the matched scan point itself (Amberg's closest point; it pins
        the tangential position) -- or ``"plane"`` -- the vertex projected on the matched
        point's PCA tangent plane, as GB-CICP. Measured on the fandisk (a = 2 %): with
        plane targets the low-stiffness levels let the surface creep tangentially from
        iteration to iteration (the data do not resist it and the affine stiffness
        relaxes by it), so point targets are the default.
    """

    alpha_start: float | None = None
    alpha_end: float | None = None
    band_start: float | None = None
    band_end: float | None = None
    levels: int = 8
    inner_iter: int = 4
    tol: float = 1e-2
    gamma: float = 1.0
    normal_gate: float = 0.5
    gate_k: float = 3.0
    gate_floor: float | None = None
    coverage_radius: float | None = None
    update_normals: bool = True
    scan_normal_k: int = 12
    cg_rtol: float = 1e-8
    targets: str = "point"


class _AffineSystem:
    """The NICP normal equations on a fixed sparsity pattern (values refilled per solve).

    Parameters
    ----------
    H : (n, 4) homogeneous normalised vertices ``[v 1]``.
    E : (e, 2) mesh edges.  gamma : translational weight of ``G``.
    """

    def __init__(self, H: np.ndarray, E: np.ndarray, gamma: float):
        n = len(H)
        self.n = n
        N = 4 * n
        deg = np.bincount(E.ravel(), minlength=n).astype(float)
        Lg = sp.coo_matrix(
            (
                np.r_[deg, -np.ones(2 * len(E))],
                (np.r_[np.arange(n), E[:, 0], E[:, 1]], np.r_[np.arange(n), E[:, 1], E[:, 0]]),
            ),
            shape=(n, n),
        ).tocsr()
        K = sp.kron(Lg, sp.diags([1.0, 1.0, 1.0, gamma**2])).tocoo()
        keep = K.data != 0
        Kr, Kc, Kv = K.row[keep], K.col[keep], K.data[keep]
        blk = 4 * np.arange(n)[:, None, None]
        Br = np.broadcast_to(blk + np.arange(4)[None, :, None], (n, 4, 4)).ravel()
        Bc = np.broadcast_to(blk + np.arange(4)[None, None, :], (n, 4, 4)).ravel()
        S = sp.csc_matrix(
            (np.ones(len(Kr) + len(Br)), (np.r_[Kr, Br], np.r_[Kc, Bc])), shape=(N, N)
        )
        S.sum_duplicates()
        S.sort_indices()
        self.indices, self.indptr = S.indices, S.indptr
        cols = np.repeat(np.arange(N, dtype=np.int64), np.diff(S.indptr))
        keys = cols * N + S.indices.astype(np.int64)

        def pos(r, c):
            return np.searchsorted(keys, c.astype(np.int64) * N + r.astype(np.int64))

        self.K_vals = np.zeros(len(keys))
        np.add.at(self.K_vals, pos(Kr, Kc), Kv)
        self.pos_B = pos(Br, Bc)
        self.pos_I = pos(np.arange(N), np.arange(N))
        self.HH = (H[:, :, None] * H[:, None, :]).reshape(n, 16)
        self.H = H
        self.X_id = np.tile(np.vstack([np.eye(3), np.zeros((1, 3))]), (n, 1))

    def matrix(self, alpha: float, w: np.ndarray, eps: float) -> sp.csc_matrix:
        """``alpha^2 L (x) G^2 + D^T diag(w) D + eps I`` on the fixed pattern."""
        vals = alpha**2 * self.K_vals
        vals[self.pos_B] += (w[:, None] * self.HH).ravel()
        vals[self.pos_I] += eps
        N = 4 * self.n
        return sp.csc_matrix((vals, self.indices, self.indptr), shape=(N, N))

    def rhs(self, w: np.ndarray, U: np.ndarray, eps: float) -> np.ndarray:
        """``D^T diag(w) U + eps X_id`` (4n, 3): the tiny ``eps`` keeps a vertex set that no
        data reaches at its rigid pose instead of leaving the system singular."""
        B = (w[:, None, None] * self.H[:, :, None] * U[:, None, :]).reshape(4 * self.n, 3)
        return B + eps * self.X_id

    def apply(self, X: np.ndarray) -> np.ndarray:
        """``D X``: the deformed normalised vertices (n, 3)."""
        return np.einsum("ia,iac->ic", self.H, X.reshape(self.n, 4, 3))


def _block_order(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """SuperLU's fill-reducing order of the 4n NICP unknowns: a nested dissection of the
    vertices (:func:`qifreport.registration.ordering.nested_dissection` on the mesh's vertex
    graph), each vertex's four unknowns kept together. On the 28,910-vertex fandisk this
    factors in about half the time of SuperLU's own MMD order on the scalar pattern, at the
    same fill. (CHOLMOD, when installed, orders by itself.)"""
    perm = nested_dissection(V, adjacency(F, len(V)), leaf=64)
    return (4 * perm[:, None] + np.arange(4)).ravel()


def _pcg(
    A: sp.csc_matrix,
    B: np.ndarray,
    solve: Callable[[np.ndarray], np.ndarray],
    X0: np.ndarray,
    rtol: float,
    max_iter: int = 50,
) -> tuple[np.ndarray, int]:
    """Solve ``A X = B`` (k right-hand sides) by conjugate gradients preconditioned with the
    factor ``solve`` of a nearby matrix (the same level's, a few gate weights different).

    Returns the solution and the largest iteration count over the columns.
    """
    X0 = np.asarray(X0)
    R = B - A @ X0
    X = X0.copy()
    Z = solve(R)
    Pd = Z.copy()
    rz = np.einsum("ij,ij->j", R, Z)
    bnorm = np.maximum(np.linalg.norm(B, axis=0), 1e-300)
    for it in range(1, max_iter + 1):
        if (np.linalg.norm(R, axis=0) <= rtol * bnorm).all():
            return X, it - 1
        AP = A @ Pd
        a = rz / np.maximum(np.einsum("ij,ij->j", Pd, AP), 1e-300)
        X += a * Pd
        R -= a * AP
        Z = solve(R)
        rz_new = np.einsum("ij,ij->j", R, Z)
        Pd = Z + (rz_new / np.maximum(rz, 1e-300)) * Pd
        rz = rz_new
    log.warning("NICP: preconditioned CG stopped at %d iterations", max_iter)
    return X, max_iter


def _matchers(
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    Ns: np.ndarray,
    scan_sheets: np.ndarray | None,
    p: NICPParams,
) -> tuple[ScanMatcher, ScanMatcher]:
    """The iterations' scan matcher (its vertex normals may be updated as the mesh deforms)
    and the final one, on the nominal's normals (arguments as :func:`nicp`)."""
    match = scan_matcher(
        V0, F, ops, P, Ns, scan_sheets, radius=p.coverage_radius, gate=p.normal_gate
    )
    final = ScanMatcher(
        match.P,
        match.Ns,
        ops.normals,
        match.radius,
        signed=match.signed,
        gate=match.gate,
        tree=match.tree,
    )
    return match, final


def _gate_weights(m: Match, p: NICPParams) -> tuple[np.ndarray, float]:
    """The data weights (n,) of one iteration, 1 where the vertex is covered, its normal
    compatible and its residual within the gate, else 0; and the gate (mm): ``gate_k``
    robust scales, at least ``gate_floor``."""
    ok = m.covered & (m.compat >= p.normal_gate)
    scale = robust_scale(m.r[ok]) if ok.any() else 0.0
    gate = max(p.gate_k * scale, p.gate_floor)
    w = (ok & (np.abs(m.r) <= gate)).astype(float)
    return w, gate


@dataclass
class _LevelSolve:
    """The solves of the NICP systems: one factorisation per stiffness level, reused.

    Attributes
    ----------
    solver : the sparse SPD solver.
    cg_rtol : relative residual of the preconditioned CG.
    X : (4n, 3) the latest solution (the affine transforms, normalised part).
    alpha : the stiffness of the current factor (None before the first).
    w : (n,) the data weights of the current factor.
    solve : the current factor's solve.
    """

    solver: SPDSolver
    cg_rtol: float
    X: np.ndarray
    alpha: float | None = None
    w: np.ndarray | None = None
    solve: Callable[[np.ndarray], np.ndarray] | None = None

    def __call__(self, A: sp.csc_matrix, b: np.ndarray, alpha: float, w: np.ndarray) -> int:
        """Solve ``A X = b`` (4n, 3) into :attr:`X` for the stiffness ``alpha`` and the data
        weights ``w`` (n,); returns the CG iterations (0 for a direct solve)."""
        if alpha != self.alpha:  # one factorisation per level
            self.solve = self.solver.factor(A)
            self.alpha, self.w = alpha, w
            self.X = self.solve(b)
            return 0
        if np.array_equal(w, self.w):  # same matrix: the factor is exact
            self.X = self.solve(b)
            return 0
        # a few gate weights changed: CG preconditioned by the level's factor
        self.X, n_cg = _pcg(A, b, self.solve, self.X, self.cg_rtol)
        return n_cg


def _iteration_record(
    level: int,
    alpha: float,
    m: Match,
    w: np.ndarray,
    gate: float,
    n_cg: int,
    V: np.ndarray,
    V_new: np.ndarray,
) -> dict:
    """One iteration's entry of the NICP history: the step from ``V`` to ``V_new`` (n, 3)
    mm with the match ``m`` and data weights ``w`` (n,) that made it (keys as in
    :func:`nicp`'s Returns)."""
    used = w > 0
    step = np.abs(V_new - V)
    delta = float(step.max())
    delta_data = float(step[used].max()) if used.any() else delta
    rms = float(np.sqrt(np.mean(m.r[used] ** 2))) if used.any() else float("nan")
    return dict(
        level=level,
        alpha=float(alpha),
        rms=rms,
        delta=delta,
        delta_data=delta_data,
        used=float(used.mean()),
        gate=gate,
        cg=n_cg,
    )


def nicp(
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    params: NICPParams | None = None,
    scan_normals: np.ndarray | None = None,
    scan_sheets: np.ndarray | None = None,
    progress: Callable[[int], Any] | None = None,
) -> DeformResult:
    """Optimal-step non-rigid ICP of the rigidly aligned nominal ``V0`` onto the scan ``P``.

    Parameters
    ----------
    V0 : (n, 3) nominal vertices in the scan's frame after rigid alignment, mm.
    F : (f, 3) triangles.  ops : operators of the nominal (its ``normals``).
    P : (m, 3) scan points, mm.
    params : :class:`NICPParams` (defaults resolved from the part size and mesh).
    scan_normals : (m, 3) PCA scan normals (computed when None).
    scan_sheets : (m,) sheet labels of consistently oriented ``scan_normals``: when given,
        the signed normal compatibility is used (see :func:`scan_matcher`).
    progress : optional ``progress(1)`` per iteration.

    Returns
    -------
    DeformResult with ``method="nicp"``; ``history`` has one record per iteration: level,
    ``alpha``, ``rms`` of the gated normal residuals (mm), the largest vertex step ``delta``
    and the largest step of a vertex with data ``delta_data`` (mm), the fraction ``used`` of
    vertices with data, the distance ``gate`` (mm) and the CG iterations ``cg``.
    """
    t0 = time.perf_counter()
    p = _resolve(params or NICPParams(), V0, F, ops, P)
    Ns = scan_normals if scan_normals is not None else pca_normals(P, p.scan_normal_k)
    match, final = _matchers(V0, F, ops, P, Ns, scan_sheets, p)
    c = V0.mean(axis=0)
    s = bounding_diagonal(V0)
    H = np.c_[(V0 - c) / s, np.ones(len(V0))]
    system = _AffineSystem(H, edges(F), p.gamma)
    # CHOLMOD's analysis is reused across the levels (the pattern is fixed); SuperLU gets a
    # block nested-dissection order
    superlu = default_backend() == "superlu"
    solver = SPDSolver(order=_block_order(V0, F) if superlu else None)
    alphas = np.geomspace(p.alpha_start, p.alpha_end, p.levels)
    eps = 1e-9 * max(min(p.alpha_end, 1.0), 1e-6) ** 2

    V = V0.copy()
    history: list[dict] = []
    level_solve = _LevelSolve(solver, p.cg_rtol, system.X_id)
    for level, alpha in enumerate(alphas):
        for _ in range(p.inner_iter):
            if p.update_normals:
                match.N = vertex_normals(V, F)
            m = match(V)
            w, gate = _gate_weights(m, p)
            A = system.matrix(alpha, w, eps)
            U = m.target if p.targets == "plane" else match.P[m.j]
            b = system.rhs(w, (U - c) / s, eps)
            n_cg = level_solve(A, b, alpha, w)
            V_new = c + s * system.apply(np.asarray(level_solve.X))
            record = _iteration_record(level, alpha, m, w, gate, n_cg, V, V_new)
            V = V_new
            history.append(record)
            if progress is not None:
                progress(1)
            if record["delta_data"] < p.tol:
                break
    log.debug("NICP: %d iterations over %d levels", len(history), p.levels)
    return finish("nicp", V0, V, final, p, len(history), time.perf_counter() - t0, history)


def _resolve(
    p: NICPParams, V0: np.ndarray, F: np.ndarray, ops: MeshOperators, P: np.ndarray
) -> NICPParams:
    """Fill in the size-dependent defaults."""
    q = NICPParams(**vars(p))
    diag = bounding_diagonal(V0)
    if q.coverage_radius is None:
        q.coverage_radius = coverage_radius(V0, F, P)
    if q.gate_floor is None:
        q.gate_floor = 1.5 * q.coverage_radius
    if q.band_start is None:
        q.band_start = 0.25 * diag
    if q.band_end is None:
        q.band_end = q.coverage_radius
    # membrane length l = alpha gamma sqrt(sqrt(3) a) on the normalised part (module doc)
    a = float(np.mean(ops.area)) / diag**2
    per_alpha = max(q.gamma, 1e-12) * np.sqrt(np.sqrt(3.0) * a) * diag  # mm per unit alpha
    if q.alpha_start is None:
        q.alpha_start = float(q.band_start / per_alpha)
    if q.alpha_end is None:
        q.alpha_end = float(q.band_end / per_alpha)
    q.levels = max(int(q.levels), 1)
    if q.targets not in ("point", "plane"):
        raise ValueError(f"unknown NICP targets {q.targets!r} (point or plane)")
    return q
