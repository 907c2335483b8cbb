"""The deformable methods behind ``qifreport --method``, one call signature for all.

``deform(method, V0, F, ops, P, ...)`` runs GB-CICP (the product's default, paper Section
6.4) or one of the paper's baselines -- NICP (Amberg optimal step, 6.3), CPD (coherent point
drift, 6.2), RBF-FEM (clamp-driven multiquadric RBF, 6.1) -- and returns a
:class:`qifreport.registration.deformable.DeformResult` on the nominal vertex set.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import numpy as np

from .deformable import DeformResult
from .mesh import MeshOperators

__all__ = [
    "METHODS",
    "deform",
    "method_function",
]

#: method name -> (module, function); imported on first use
METHODS: dict[str, tuple[str, str]] = {
    "gbcicp": ("qifreport.registration.gbcicp", "gbcicp"),
    "nicp": ("qifreport.registration.nicp", "nicp"),
    "cpd": ("qifreport.registration.cpd", "cpd"),
    "rbffem": ("qifreport.registration.rbffem", "rbffem"),
}


def method_function(method: str) -> Callable[..., DeformResult]:
    """The function implementing ``method`` (one of :data:`METHODS`)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    module, name = METHODS[method]
    return getattr(importlib.import_module(module), name)


def deform(
    method: str,
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    params: Any = None,
    scan_normals: np.ndarray | None = None,
    scan_sheets: np.ndarray | None = None,
    clamps: np.ndarray | None = None,
    progress: Callable[[int], Any] | None = None,
    basis: Any = None,
    flaggable: np.ndarray | None = None,
    solver: Any = None,
) -> DeformResult:
    """Register the rigidly aligned nominal ``V0`` (n, 3) mm onto the scan ``P`` (m, 3) mm.

    Parameters
    ----------
    method : ``"gbcicp"``, ``"nicp"``, ``"cpd"`` or ``"rbffem"``.
    F : (f, 3) triangles.  ops : operators of the nominal (normals, areas, bending).
    params : the method's own parameter dataclass (defaults when None).
    scan_normals, scan_sheets : PCA scan normals (m, 3), consistently oriented per sheet,
        and their sheet labels
        (see :func:`qifreport.registration.normals.orient_normals_consistent`).
    clamps : (k,) vertex indices of the clamps (RBF-FEM's driving points; default: the
        corners of the part's principal rectangle). Ignored by the other methods.
    progress : optional ``progress(n_iterations)`` callback.
    basis : the part's :class:`qifreport.registration.gbcicp.BendingBasis` (GB-CICP's per-part
        precomputation, reused across scans); ignored by the other methods.
    flaggable : (n,) bool, vertices GB-CICP may flag as defect candidates (its multi-pass
        scheme); ignored by the other methods, which flag nothing.
    solver : the :class:`qifreport.registration.linalg.SPDSolver` GB-CICP factorises with (one
        that factorised the part's bending basis keeps its symbolic analysis: the matrices
        share their pattern); ignored by the other methods.
    """
    fn = method_function(method)
    kw: dict[str, Any] = dict(
        params=params, scan_normals=scan_normals, scan_sheets=scan_sheets, progress=progress
    )
    if method == "rbffem":
        kw["clamps"] = clamps
    if method == "gbcicp":
        kw["basis"] = basis
        kw["flaggable"] = flaggable
        kw["solver"] = solver
    return fn(V0, F, ops, P, **kw)
