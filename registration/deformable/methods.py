"""The deformable methods behind ``qifreport --method``, one call signature for all.

``deform(method, V0, F, ops, P, ...)`` runs GB-CICP (the product's default, paper Section
6.4) or one of the paper's baselines -- NICP (Amberg optimal step, 6.3), CPD (coherent point
drift, 6.2), RBF-FEM (clamp-driven multiquadric RBF, 6.1) -- and returns a
:class:`qifreport.registration.deformable.result.DeformResult` on the nominal vertex set.

Each method is one :class:`MethodSpec` of :data:`METHODS`: its label, implementation,
parameters, QIF description and capabilities. The layers above ask a method's capabilities
(:func:`method_spec`), never compare its name.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.mesh import MeshOperators

__all__ = [
    "METHODS",
    "MethodSpec",
    "deform",
    "method_function",
    "method_label",
    "method_spec",
]


@dataclass(frozen=True)
class MethodSpec:
    """One deformable method: its names, where it is implemented, and what it can do (the
    inspection asks these capabilities, never the method's name).

    Attributes
    ----------
    name : its ``--method`` name (``"gbcicp"``).
    label : its display name (``"GB-CICP"``).
    function : ``"module:function"`` implementing it, imported on first use (the call
        signature of :func:`deform`).
    params_class : ``"module:Class"`` of its parameter dataclass.
    qif_algorithm : the ``Description`` of its virtual-fixture algorithm in a QIF results
        document.
    params_field : the :class:`qifreport.metrology.params.InspectionParams` field holding its
        parameters (also the key its resolved parameters and its fit are recorded under in
        the JSON summary); None: it runs with its defaults, resolved from the part.
    flags_defects : it flags defect candidates (the multi-pass scheme with the two-pass
        guard) among the vertices it is allowed to (``flaggable``).
    uses_bending_basis : it iterates in the part's bending basis, factorised by an
        :class:`~qifreport.registration.linalg.SPDSolver` (with its modal solver and no
        fixed stiffness): the basis is built once per part.
    band_limited : its fit is band-limited (band limits l1, l2, a start length and a
        coverage radius among its parameters, reported as such).
    moves_along_normals_only : it moves the nominal along its normals only, never along the
        surface, so the trim edges of the fitted nominal still measure the part's size.
    driven_by_clamps : it is driven by clamp vertices (``clamps``).
    """

    name: str
    label: str
    function: str
    params_class: str
    qif_algorithm: str
    params_field: str | None = None
    flags_defects: bool = False
    uses_bending_basis: bool = False
    band_limited: bool = False
    moves_along_normals_only: bool = False
    driven_by_clamps: bool = False

    @property
    def module(self) -> str:
        """The module implementing it."""
        return self.function.partition(":")[0]

    def params_type(self) -> type:
        """Its parameter dataclass (:attr:`params_class`), imported now."""
        module, _, name = self.params_class.partition(":")
        return getattr(importlib.import_module(module), name)


_R = "qifreport.registration.deformable"
#: the deformable methods by ``--method`` name: GB-CICP (the product's default, paper
#: Section 6.4) and the paper's baselines
METHODS: dict[str, MethodSpec] = {
    m.name: m
    for m in (
        MethodSpec(
            "gbcicp",
            label="GB-CICP",
            function=f"{_R}.gbcicp:gbcicp",
            params_class=f"{_R}.gbcicp:GBCICPParams",
            qif_algorithm="GB-CICP: deformation of the nominal onto the free-state scan under a "
            "bending-energy prior (paper Sections 4-5)",
            params_field="gbcicp",
            flags_defects=True,
            uses_bending_basis=True,
            band_limited=True,
            moves_along_normals_only=True,
        ),
        MethodSpec(
            "nicp",
            label="NICP",
            function=f"{_R}.nicp:nicp",
            params_class=f"{_R}.nicp:NICPParams",
            qif_algorithm="NICP: optimal-step non-rigid ICP, deformation of the nominal onto the "
            "free-state scan under a per-vertex affine stiffness prior (paper baseline, "
            "Section 6.3)",
        ),
        MethodSpec(
            "cpd",
            label="CPD",
            function=f"{_R}.cpd:cpd",
            params_class=f"{_R}.cpd:CPDParams",
            qif_algorithm="CPD: coherent point drift, a Gaussian-mixture deformation of the "
            "nominal onto the free-state scan with motion coherence (paper baseline, Section "
            "6.2)",
        ),
        MethodSpec(
            "rbffem",
            label="RBF-FEM",
            function=f"{_R}.rbffem:rbffem",
            params_class=f"{_R}.rbffem:RBFFEMParams",
            qif_algorithm="RBF-FEM: deformation of the nominal driven by its clamps with "
            "multiquadric radial basis functions (paper baseline, Section 6.1)",
            driven_by_clamps=True,
        ),
    )
}


def method_spec(method: str) -> MethodSpec:
    """The registered method ``method``; for a name that is none (a fit recorded by another
    program), a spec with no capability, its label the name in capitals and its QIF
    description the name."""
    spec = METHODS.get(method)
    return spec if spec is not None else MethodSpec(method, method.upper(), "", "", method)


def method_label(method: str) -> str:
    """Display name of a deformable method (``"gbcicp"`` -> ``"GB-CICP"``)."""
    return method_spec(method).label


def method_function(method: str) -> Callable[..., DeformResult]:
    """The function implementing ``method`` (ValueError unless one of :data:`METHODS`)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    module, _, name = METHODS[method].function.partition(":")
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
    basis : the part's :class:`qifreport.registration.deformable.bending_basis.BendingBasis`
        (GB-CICP's per-part precomputation, reused across scans); ignored by the other methods.
    flaggable : (n,) bool, vertices GB-CICP may flag as defect candidates (its multi-pass
        scheme); ignored by the other methods, which flag nothing.
    solver : the :class:`qifreport.registration.linalg.SPDSolver` GB-CICP factorises with (one
        that factorised the part's bending basis keeps its symbolic analysis: the matrices
        share their pattern); ignored by the other methods.
    """
    fn = method_function(method)
    spec = METHODS[method]
    kw: dict[str, Any] = dict(
        params=params, scan_normals=scan_normals, scan_sheets=scan_sheets, progress=progress
    )
    if spec.driven_by_clamps:
        kw["clamps"] = clamps
    if spec.uses_bending_basis:
        kw.update(basis=basis, solver=solver)
    if spec.flags_defects:
        kw["flaggable"] = flaggable
    return fn(V0, F, ops, P, **kw)
