"""Free-state generators: prescribed, exactly known deformations of a nominal mesh.

Three generators (paper Sections 1.2 and 4.3):

* :func:`biharmonic_deformation` -- the paper's ground truth: the minimiser of the bending
  energy ``d^T Q d`` (``Q = L M^-1 L`` or the Hessian energy) subject to prescribed normal
  displacements at clamp handles chosen automatically from the part's principal (PCA)
  bounding rectangle (Section 7.1). Three sign patterns give the canonical modes: bend,
  twist and saddle.
* :func:`analytic_deformation` -- a closed-form smooth normal field that minimises no energy,
  so a method whose prior is ``Q`` gains no advantage from matching its own generator.
* :func:`elastic_deformation` -- physics: the lowest elastic vibration modes of the part as a
  thin-walled solid (quadratic tetrahedra of the nominal thickened, scikit-fem), mixed at
  bounded energy (weights ``1/omega``): the generator the paper's Section 1.2 describes and
  its Section 11 asks the comparison to be re-run with.

All displacements are (n, 3) arrays in mm.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import scipy.sparse.linalg as spla

from qifreport.registration.deformable.handles import Handles, clamp_handles, pca_frame
from qifreport.registration.mesh import (
    bending_operator,
    vertex_areas,
    vertex_normals,
)

__all__ = [
    "elastic_deformation",
    "MODES",
    "analytic_deformation",
    "biharmonic_deformation",
    "clamp_handles",
    "Deformation",
    "handle_signs",
    "pca_frame",
]

log = logging.getLogger(__name__)

#: Sign pattern ``s_c`` of each canonical mode, per handle kind, in the order
#: :func:`clamp_handles` returns the groups of that kind:
#: corners counter-clockwise in (u1, u2) starting at (-u1, -u2); edge midpoints at
#: +u1, +u2, -u1, -u2. The anchor (centroid) handle is held at zero displacement in every mode.
#:
#: * ``bend``: all four corners move the same way along their normals. Without the anchor
#:   a uniform corner motion would be reproduced exactly by a rigid translation (a zero-energy
#:   mode of ``Q``); the fixed anchor is what makes the part bow.
#: * ``twist``: corners alternate +1, -1, +1, -1 around the boundary, so opposite corners
#:   move together and adjacent ones oppositely (displacement ~ xi1 * xi2, anticlastic with
#:   its principal axes along the rectangle's diagonals).
#: * ``saddle``: edge midpoints +1 at the +-u1 ends, -1 at the +-u2 ends
#:   (displacement ~ xi1^2 - xi2^2): anticlastic as well, rotated 45 degrees from the twist.
MODES: Mapping[str, Mapping[str, tuple[int, ...]]] = MappingProxyType(
    {
        "bend": MappingProxyType({"corner": (1, 1, 1, 1)}),
        "twist": MappingProxyType({"corner": (1, -1, 1, -1)}),
        "saddle": MappingProxyType({"edge": (1, -1, 1, -1)}),
    }
)

_DEFAULT_MODES: Mapping[str, float] = MappingProxyType({"bend": 1.0})

# Fixed coefficients of the default analytic field (seed=None).
_ANALYTIC_DEFAULT = np.array([0.60, 0.35, -0.25, 0.20, 0.15])


def handle_signs(handles: Handles, modes: Mapping[str, float]) -> np.ndarray:
    """Per-group sign ``s_c`` (k,): the weighted sum of the requested :data:`MODES`.

    Anchor groups get 0. Raises ``ValueError`` for an unknown mode or one whose handle kind
    is missing from ``handles`` (e.g. ``saddle`` without edge handles).
    """
    s = np.zeros(len(handles.groups))
    kinds = np.array(handles.kind)
    for name, weight in modes.items():
        if name not in MODES:
            raise ValueError(f"unknown deformation mode {name!r} (one of {sorted(MODES)})")
        for kind, pattern in MODES[name].items():
            where = np.flatnonzero(kinds == kind)
            if len(where) != len(pattern):
                raise ValueError(f"mode {name!r} needs {len(pattern)} {kind} handles")
            s[where] += weight * np.asarray(pattern, dtype=float)
    return s


@dataclass
class Deformation:
    """A prescribed free state: ``V_free = V + d``.

    Attributes
    ----------
    d : (n, 3) displacement, mm.
    handles : the handles used (only the kinds the requested modes need, plus the anchor).
    g : (h, 3) prescribed displacement of ``handles.indices`` (same order), mm.
    signs : (k,) per-group sign ``s_c`` (weighted sum of the modes; 0 for the anchor).
    """

    d: np.ndarray
    handles: Handles
    g: np.ndarray
    signs: np.ndarray = field(default_factory=lambda: np.zeros(0))


def biharmonic_deformation(
    V: np.ndarray,
    F: np.ndarray,
    amplitude: float,
    modes: Mapping[str, float] = _DEFAULT_MODES,
    energy: str = "laplacian",
    handle_radius: float | None = None,
    clamp_motion: str = "rigid",
) -> Deformation:
    """Minimise the bending energy ``d^T Q d`` subject to ``d_H = g`` (paper Eq. 2-3).

    Handle motion is ``g_c = amplitude * s_c * n_c`` with ``n_c`` the unit mean normal of
    each handle group (the clamp translates its patch rigidly) and ``s_c`` from
    :func:`handle_signs`; the anchor is held at zero.
    The free block is factorised once (``splu``) and solved for the 3 coordinates at once.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    amplitude : handle displacement ``a`` (mm), e.g. ``0.02 * bounding_diagonal(V)``.
    modes : mode name -> weight, e.g. ``{"bend": 1.0, "twist": 0.5}`` (default bend only).
        Only handle kinds some requested mode uses are constrained (corners for bend and
        twist, edge midpoints for saddle), so e.g. a pure saddle leaves the corners free.
    energy : ``"laplacian"`` (``L M^-1 L``) or ``"hessian"``, see
        :func:`qifreport.registration.mesh.bending_operator`.
    handle_radius : clamp group radius, mm (default 1.5 % of the bounding diagonal).
    clamp_motion : ``"rigid"`` -- each clamp translates its patch along the patch's mean
        normal; ``"normal"`` -- each handle vertex moves along its own normal, which crushes
        a patch that straddles a crease (a non-physical free state no smooth fit follows:
        the registration-failure case of the trust tests).

    Returns
    -------
    Deformation with ``d`` (n, 3) mm; ``d`` equals ``g`` on the handles to round-off.
    Where groups overlap, the later group (the anchor last) sets the constraint.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    unknown = set(modes) - set(MODES)
    if unknown:
        raise ValueError(f"unknown deformation mode(s) {sorted(unknown)} (one of {sorted(MODES)})")
    need = {kind for name in modes for kind in MODES[name]}
    all_handles = clamp_handles(V, F, handle_radius, include_edges="edge" in need)
    keep = [k for k, kind in enumerate(all_handles.kind) if kind in need or kind == "anchor"]
    handles = Handles(
        groups=[all_handles.groups[k] for k in keep],
        centers=all_handles.centers[keep],
        kind=[all_handles.kind[k] for k in keep],
    )
    signs = handle_signs(handles, modes)

    ops = bending_operator(V, F, energy)
    n = len(V)
    # each clamp moves its contact patch as one rigid piece, along the patch's mean normal:
    # per-vertex normals would shear a patch that straddles a crease (on the fandisk's
    # corners they differ by up to 57 degrees) and tear the part at the clamp
    s_vertex = np.zeros(n)
    n_vertex = np.zeros((n, 3))
    for group, s in zip(handles.groups, signs, strict=True):
        s_vertex[group] = s
        if clamp_motion == "normal":
            n_vertex[group] = ops.normals[group]
        elif clamp_motion == "rigid":
            nc = ops.normals[group].sum(axis=0)
            n_vertex[group] = nc / max(float(np.linalg.norm(nc)), 1e-300)
        else:
            raise ValueError(f"unknown clamp motion {clamp_motion!r} (rigid or normal)")
    h = handles.indices
    g = amplitude * s_vertex[h, None] * n_vertex[h]

    free = np.ones(n, dtype=bool)
    free[h] = False
    Q = ops.Q.tocsc()
    Qff = Q[free][:, free].tocsc()
    Qfh = Q[free][:, h]
    d = np.zeros((n, 3))
    d[h] = g
    if free.any():
        lu = spla.splu(Qff, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
        d[free] = lu.solve(np.ascontiguousarray(-(Qfh @ g)))
    if not np.isfinite(d).all():
        raise ValueError("bending system is singular: a mesh component carries no handle")
    log.debug(
        "biharmonic %s: %d handles, max |d| %.3f mm",
        dict(modes),
        len(h),
        np.linalg.norm(d, axis=1).max(),
    )
    return Deformation(d=d, handles=handles, g=g, signs=signs)


def analytic_deformation(
    V: np.ndarray,
    F: np.ndarray,
    amplitude: float,
    seed: int | None = None,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """A closed-form smooth normal displacement that shares no prior with any method.

    With ``(xi1, xi2)`` the two in-plane principal coordinates (:func:`pca_frame`, area
    weighted) each mapped to [-1, 1] over the part,

        f = c1 xi1^2 + c2 xi1 xi2 + c3 sin(pi xi2 / 2) xi1 + c4 cos(pi xi1) xi2^2 + c5 xi2^3

    and ``d = s f n`` along the unit vertex normals ``n``, with ``s`` chosen so that
    ``max |d| == amplitude`` exactly. Nothing is subtracted (not zero-mean, no rigid part
    removed), and ``f`` minimises no energy: it is not in the span of any method's prior.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    amplitude : peak displacement norm, mm.
    seed : ``None`` -> fixed default coefficients; otherwise ``c1..c5`` are drawn from
        ``np.random.default_rng(seed)`` uniformly in [-1, 1].
    direction : (3,) if given, displace every vertex along this one unit vector instead of
        its own normal. Use it for a *solid* thin part (a STEP nominal with both skins):
        along the vertex normals the two skins would move apart, changing the thickness;
        along the mid-plane normal the wall bends as a plate does.

    Returns
    -------
    d : (n, 3) displacement, mm.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if seed is None:
        coef = _ANALYTIC_DEFAULT
    else:
        coef = np.random.default_rng(seed).uniform(-1.0, 1.0, 5)
    c, U = pca_frame(V, vertex_areas(V, F))
    xi = (V - c) @ U[:, :2]
    lo, hi = xi.min(axis=0), xi.max(axis=0)
    xi = 2.0 * (xi - lo) / np.maximum(hi - lo, 1e-300) - 1.0
    x1, x2 = xi[:, 0], xi[:, 1]
    f = (
        coef[0] * x1**2
        + coef[1] * x1 * x2
        + coef[2] * np.sin(np.pi * x2 / 2.0) * x1
        + coef[3] * np.cos(np.pi * x1) * x2**2
        + coef[4] * x2**3
    )
    if direction is None:
        d = f[:, None] * vertex_normals(V, F)
    else:
        u = np.asarray(direction, dtype=np.float64)
        d = f[:, None] * (u / np.linalg.norm(u))[None, :]
    peak = np.linalg.norm(d, axis=1).max()
    if peak <= 0:
        raise ValueError("analytic field vanishes on this mesh")
    return d * (amplitude / peak)


def elastic_deformation(
    V: np.ndarray,
    F: np.ndarray,
    a: float,
    *,
    seed: int = 0,
    thickness: float = 2.0,
    n_modes: int = 6,
    model_triangles: int = 3000,
) -> np.ndarray:
    """A free state made of the part's lowest elastic modes (Sections 1.2 and 11).

    The nominal, decimated to about ``model_triangles`` triangles and thickened to a wall of
    ``thickness`` mm (:func:`qifreport.registration.restraint.sheet_solid.sheet_solid`; ABS,
    quadratic
    tetrahedra), gives its ``n_modes`` lowest non-rigid modes; their mix with coefficients
    ``N(0, 1) / omega`` (equal energy per unit of each mode) is evaluated at ``V`` and scaled
    to a peak displacement ``a``.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    a : peak displacement, mm.  seed : the coefficients' seed.

    Returns
    -------
    (n, 3) displacement, mm.
    """
    from qifreport.registration.restraint.elastic import MATERIALS, elastic_model, elastic_modes
    from qifreport.registration.restraint.sheet_solid import sheet_solid
    from qifreport.restraint import sheet_model_mesh

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    U, G = sheet_model_mesh(V, F, model_triangles)
    solid = sheet_solid(U, G, vertex_normals(U, G), thickness)
    model = elastic_model(solid.X, solid.T, MATERIALS["abs"])
    omega2, modes = elastic_modes(model, n_modes)
    u = np.asarray(model.probes(V) @ modes)  # (3n, k)
    u = u.reshape(3, len(V), -1).transpose(1, 0, 2)
    peak = np.linalg.norm(u, axis=1).max(axis=0)  # each mode's own peak, mm
    rng = np.random.default_rng(seed)
    c = rng.normal(size=len(omega2)) / np.sqrt(omega2 / omega2[0]) / peak
    d = u @ c
    d *= a / np.linalg.norm(d, axis=1).max()
    log.info(
        "elastic free state: %d modes of a %.1f mm wall (%d tetrahedra), peak %.3f mm",
        len(omega2),
        thickness,
        len(solid.T),
        a,
    )
    return d
