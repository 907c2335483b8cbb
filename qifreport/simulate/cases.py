"""Test cases with exact ground truth: nominal -> free state (+ defect) -> virtual scan.

A :class:`Case` is the paper's dataset sample (Section 7): the nominal mesh, the deformed
free state (the truth), and the scan of it, plus what only the generator knows (the
generator vertex of each scan point, the defect centre). Registration sees only
``V``, ``F`` and ``P``; the rest is for scoring.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from qifreport.registration.mesh import bounding_diagonal, vertex_normals

from .defects import gaussian_bump
from .deform import (
    analytic_deformation,
    biharmonic_deformation,
    clamp_handles,
    elastic_deformation,
    pca_frame,
)
from .scanner import ScanSpec, SimulatedScan, virtual_scan

__all__ = [
    "Case",
    "defect_site",
    "inspection_error",
    "make_case",
]


@dataclass
class Case:
    """One generated inspection case (mm).

    Attributes
    ----------
    V, F : nominal mesh.  V_true : (n, 3) free state without the defect (the compliance the
        registration must remove).  V_scanned : (n, 3) the surface actually scanned
        (free state + defect).  scan : the virtual scan of ``V_scanned``.
    clamp_centers : (k, 3) clamp positions on the free state.
    defect_vertex : index of the vertex at the defect centre, or -1.
    defect : (amplitude, sigma) of the injected bump, mm, or None.
    """

    V: np.ndarray
    F: np.ndarray
    V_true: np.ndarray
    V_scanned: np.ndarray
    scan: SimulatedScan
    clamp_centers: np.ndarray
    defect_vertex: int
    defect: tuple[float, float] | None

    @property
    def P(self) -> np.ndarray:
        return self.scan.P

    def measured_vertices(self) -> np.ndarray:
        """Indices of the vertices the scanner measured (generator vertices of the points)."""
        return np.unique(self.scan.vertex)


def defect_site(V: np.ndarray, offset: float = 0.35) -> int:
    """Vertex at ``offset`` of the half-extent along +u1 and +u2 from the PCA centroid."""
    c, U = pca_frame(V)
    X = (V - c) @ U
    half = np.abs(X).max(axis=0)
    goal = np.array([offset * half[0], offset * half[1]])
    return int(np.argmin(np.linalg.norm(X[:, :2] - goal, axis=1)))


def make_case(
    V: np.ndarray,
    F: np.ndarray,
    generator: str = "analytic",
    amplitude: float = 0.02,
    modes: Mapping[str, float] | None = None,
    defect: tuple[float, float] | None = None,
    defect_vertex: int | None = None,
    spec: ScanSpec | None = None,
    seed: int = 0,
    clamp_motion: str = "rigid",
) -> Case:
    """Deform, optionally add a Gaussian bump, and scan.

    Parameters
    ----------
    V, F : nominal mesh (mm).
    generator : ``"analytic"`` (closed form, shares no prior), ``"biharmonic"`` (paper Eq. 2)
        or ``"elastic"`` (the part's lowest elastic modes as a 2 mm ABS wall, the paper's
        Section 1.2 design; :func:`elastic_deformation`).
    amplitude : deformation amplitude as a fraction of the bounding diagonal (0.02 = 2 %).
    modes : biharmonic sign patterns and their weights (default bend 1.0 + twist 0.5).
    defect : ``(a, sigma)`` of a Gaussian bump along the free-state normal (mm), or None.
    defect_vertex : centre vertex of the bump (default :func:`defect_site`).
    spec : virtual scanner settings (default :class:`ScanSpec` with ``seed`` and clamp
        dropout disks of 3 % of the diagonal); clamp
        centres are filled in from the handles when the spec has none.
    clamp_motion : biharmonic handles move ``"rigid"`` (each clamp's patch as one piece) or
        along each vertex's own ``"normal"`` (see :func:`biharmonic_deformation`).
    seed : seed of the analytic coefficients (``None`` keeps the fixed default field) and the
        scanner.
    """
    diag = bounding_diagonal(V)
    a = amplitude * diag
    handles = clamp_handles(V, F)
    if generator == "analytic":
        d = analytic_deformation(V, F, a)
    elif generator == "biharmonic":
        d = biharmonic_deformation(
            V, F, a, modes=dict(modes or {"bend": 1.0, "twist": 0.5}), clamp_motion=clamp_motion
        ).d
    elif generator == "elastic":
        d = elastic_deformation(V, F, a, seed=0 if seed is None else seed)
    else:
        raise ValueError(f"unknown generator {generator!r}")
    V_true = V + d
    V_scanned = V_true
    dv = -1
    if defect is not None:
        dv = defect_site(V) if defect_vertex is None else int(defect_vertex)
        N_true = vertex_normals(V_true, F)
        V_scanned = V_true + gaussian_bump(V_true, N_true, V_true[dv], defect[0], defect[1])
    corner = np.array([k == "corner" for k in handles.kind])
    clamp_centers = np.array([V_true[g].mean(axis=0) for g in handles.groups])[corner]
    spec = spec or ScanSpec(seed=seed, dropout_radius=0.03 * diag)
    if spec.clamp_centers is None:
        spec = ScanSpec(**{**vars(spec), "clamp_centers": clamp_centers})
    scan = virtual_scan(V_scanned, F, spec)
    return Case(V, F, V_true, V_scanned, scan, clamp_centers, dv, defect)


def inspection_error(V_hat: np.ndarray, V_true: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Per-vertex inspection deviation ``|(V_hat - V_true) . n_true|`` (paper Section 7.2), mm."""
    N = vertex_normals(V_true, F)
    return np.abs(np.einsum("ij,ij->i", V_hat - V_true, N))
