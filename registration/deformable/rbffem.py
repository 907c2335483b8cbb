"""RBF-FEM: clamp-driven multiquadric interpolation, the paper's seed method (Section 6.1).

After the rigid alignment to ``V0``, each clamp ``c`` is compared with the scan: its target
``t_c`` is the (coordinate-wise) median of the scan points within ``target_radius`` of
``V0[c]``, or the nearest scan point when that ball is empty, and its estimated displacement
is ``g_c = t_c - V0[c]``. A multiquadric centred at each clamp,

    phi_c(x) = sqrt(|x - V0[c]|^2 + eps_c^2),   eps_c = min_{c' != c} |V0[c] - V0[c']|,

interpolates them: ``Phi_CC W = G`` (k x k, dense), and ``V = V0 + Phi_VC W`` (Jaramillo et
al., Eqs. 4-5). The deformation lives in the span of the few clamp functions, so it is only
as good as the clamp displacements -- which a free-state scan measures worst (the clamp
regions are where the scan has dropouts).

Default clamps (``clamps=None``): the vertex nearest the centre (mean position) of each
``"corner"`` handle group of :func:`qifreport.registration.deformable.handles.clamp_handles` -- the
corners
of the part's principal (PCA) bounding rectangle, the generator's driving handles -- plus
the ``"anchor"`` (the vertex nearest the centroid), which the generator holds fixed: without
it four corner displacements alone cannot express a bend about the middle.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from qifreport.registration.arrays import unique_sorted
from qifreport.registration.deformable.result import (
    DeformResult,
    coverage_radius,
    finish,
    scan_matcher,
)
from qifreport.registration.mesh import MeshOperators
from qifreport.registration.normals import pca_normals

__all__ = [
    "clamp_targets",
    "default_clamps",
    "multiquadric",
    "rbffem",
    "RBFFEMParams",
]

log = logging.getLogger(__name__)


@dataclass
class RBFFEMParams:
    """Parameters of :func:`rbffem` (lengths in mm).

    Attributes
    ----------
    target_radius : radius of the scan neighbourhood whose median is a clamp's target, mm.
        Default two coverage radii (about three scan spacings: a few tens of points, enough
        for a median that rejects the range noise, small against the part).
    anchor : with the default clamps, also drive the anchor (centroid) handle.
    coverage_radius : radius of the final coverage test, mm (default as GB-CICP).
    scan_normal_k : neighbours of the PCA scan normals when they are not given.
    """

    target_radius: float | None = None
    anchor: bool = True
    coverage_radius: float | None = None
    scan_normal_k: int = 12


def default_clamps(V0: np.ndarray, F: np.ndarray, anchor: bool = True) -> np.ndarray:
    """Clamp vertex indices (k,): nearest the centre of each corner handle group (and the
    anchor's) of :func:`qifreport.registration.deformable.handles.clamp_handles`."""
    from qifreport.registration.deformable.handles import clamp_handles

    h = clamp_handles(V0, F)
    kinds = ("corner", "anchor") if anchor else ("corner",)
    centres = np.array(
        [V0[g].mean(axis=0) for g, k in zip(h.groups, h.kind, strict=True) if k in kinds]
    )
    _, idx = cKDTree(V0).query(centres)
    return unique_sorted(np.asarray(idx, dtype=np.int64))


def clamp_targets(
    V0: np.ndarray, clamps: np.ndarray, P: np.ndarray, radius: float, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Targets ``t_c`` (k, 3) of the clamps and whether each fell back to the nearest point.

    ``t_c`` is the coordinate-wise median of the scan points within ``radius`` (mm) of
    ``V0[c]``; the nearest scan point when there is none.
    """
    tree = tree or cKDTree(P)
    T = np.empty((len(clamps), 3))
    fallback = np.zeros(len(clamps), dtype=bool)
    for k, (c, near) in enumerate(
        zip(clamps, tree.query_ball_point(V0[clamps], radius), strict=True)
    ):
        if near:
            T[k] = np.median(P[near], axis=0)
        else:
            fallback[k] = True
            T[k] = P[tree.query(V0[c])[1]]
    return T, fallback


def multiquadric(X: np.ndarray, C: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """``sqrt(|x - c|^2 + eps_c^2)`` (len(X), len(C)), mm."""
    d2 = np.sum((X[:, None, :] - C[None, :, :]) ** 2, axis=2)
    return np.sqrt(d2 + eps[None, :] ** 2)


def rbffem(
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    params: RBFFEMParams | None = None,
    scan_normals: np.ndarray | None = None,
    scan_sheets: np.ndarray | None = None,
    clamps: np.ndarray | None = None,
    progress: Callable[[int], Any] | None = None,
) -> DeformResult:
    """Drive the rigidly aligned nominal ``V0`` by the scan's clamp displacements.

    Parameters
    ----------
    V0 : (n, 3) nominal vertices in the scan's frame after rigid alignment, mm.
    F : (f, 3) triangles.  ops : operators of the nominal (normals for the final match).
    P : (m, 3) scan points, mm.
    params : :class:`RBFFEMParams`.
    scan_normals, scan_sheets : used only by the final coverage match.
    clamps : (k,) clamp vertex indices; default :func:`default_clamps`.
    progress : optional ``progress(1)`` (called once: the method is not iterative).

    Returns
    -------
    DeformResult with ``method="rbffem"``; ``history[0]`` holds the clamps, their targets
    ``t``, displacements ``g`` (k, 3), mm, and which targets fell back to the nearest point.
    """
    t0 = time.perf_counter()
    p = _resolve(params or RBFFEMParams(), V0, F, P)
    C = default_clamps(V0, F, p.anchor) if clamps is None else np.asarray(clamps, np.int64)
    if len(C) == 0:
        raise ValueError("RBF-FEM needs at least one clamp")
    tree = cKDTree(P)
    T, fell = clamp_targets(V0, C, P, p.target_radius, tree)
    G = T - V0[C]
    Xc = V0[C]
    if len(C) == 1:
        V = V0 + G[0]  # one clamp: a translation
    else:
        D = np.sqrt(np.sum((Xc[:, None] - Xc[None]) ** 2, axis=2))
        np.fill_diagonal(D, np.inf)
        eps = D.min(axis=1)
        Phi = multiquadric(Xc, Xc, eps)
        try:
            W = np.linalg.solve(Phi, G)
        except np.linalg.LinAlgError:  # coincident clamps
            W = np.linalg.lstsq(Phi, G, rcond=None)[0]
        V = V0 + multiquadric(V0, Xc, eps) @ W
    if fell.any():
        log.info(
            "RBF-FEM: %d of %d clamps had no scan point within %.2f mm (nearest point used)",
            int(fell.sum()),
            len(C),
            p.target_radius,
        )
    if progress is not None:
        progress(1)
    Ns = scan_normals if scan_normals is not None else pca_normals(P, p.scan_normal_k)
    matcher = scan_matcher(V0, F, ops, P, Ns, scan_sheets, radius=p.coverage_radius)
    history = [dict(clamps=C, t=T, g=G, fallback=fell)]
    return finish("rbffem", V0, V, matcher, p, 1, time.perf_counter() - t0, history)


def _resolve(p: RBFFEMParams, V0: np.ndarray, F: np.ndarray, P: np.ndarray) -> RBFFEMParams:
    """Fill in the size-dependent defaults."""
    q = RBFFEMParams(**vars(p))
    if q.coverage_radius is None:
        q.coverage_radius = coverage_radius(V0, F, P)
    if q.target_radius is None:
        q.target_radius = 2.0 * q.coverage_radius
    return q
