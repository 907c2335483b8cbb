"""A part's compliant modes: what of a fitted displacement a fixture can bend the part into.

A fixture removes a compliant part's flexure, which lies in the part's lowest elastic modes;
a plastic dent or bump lies outside them (the paper's Section 11: "confining the admissible
deformation to the compliant, physically realizable modes of the part"). The compliant
modes are the lowest free elastic modes whose frequency lies within :data:`MODE_DECADE` of
the softest one's (:func:`compliant_modes`); a fitted field's remainder outside them and the
rigid motions (:func:`beyond_modes`) is what a fixture that bends only them would leave; and
the narrowest Gaussian bump they take more than half of (:func:`absorbed_width`) is what a
fixture conforming to the part cannot tell from its flexure.

Fields are normal displacements at the held surface nodes of the part's elastic model
(:mod:`qifreport.registration.restraint.fixture_load`), carried to the nominal's vertices by
:func:`back_to_nominal`. Units: mm.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from qifreport.registration.mesh import barycentric
from qifreport.registration.restraint.elastic import ElasticModel, elastic_modes

__all__ = [
    "BUMP_SIGMAS",
    "MODE_DECADE",
    "absorbed_width",
    "back_to_nominal",
    "beyond_modes",
    "compliant_modes",
    "rigid_normals",
]

#: the part's compliant modes: its lowest elastic modes whose frequency is within this
#: factor of the softest one's (a modal stiffness within its square, a hundredfold: what
#: the force that bends the softest mode by a millimetre bends them by at least a
#: hundredth of one), at most :data:`MODES_COMPUTED` of them
MODE_DECADE = 10.0
MODES_COMPUTED = 24

#: the Gaussian bump widths (sigma, mm) :func:`absorbed_width` tries, and the sites it
#: tries them at (held nodes spread over the part)
BUMP_SIGMAS = (1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 30.0, 50.0, 80.0)
BUMP_SITES = 8


def compliant_modes(model: ElasticModel, nodes: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m, k) the normal displacement at the surface ``nodes`` (m,) of ``model``, along their
    unit ``normals`` (m, 3), of the part's compliant modes (:data:`MODE_DECADE`), each
    column of unit norm."""
    omega2, phi = elastic_modes(model, MODES_COMPUTED)
    keep = omega2 <= MODE_DECADE**2 * max(float(omega2[0]), 1e-300)
    u = phi[:, keep][model.vertex_dofs[nodes]]  # (m, 3, k)
    A = np.einsum("mjk,mj->mk", u, normals)
    return A / np.maximum(np.linalg.norm(A, axis=0), 1e-300)


def back_to_nominal(
    X: np.ndarray, faces: np.ndarray, nodes: np.ndarray, V: np.ndarray
) -> sp.csr_matrix:
    """(n, m) sparse: a field at the ``nodes`` (m,) of a model with vertices ``X`` (N, 3) mm
    and boundary triangles ``faces`` (b, 3) to its value at the nominal's vertices ``V``
    (n, 3) mm: linear on the boundary triangle closest to each vertex, over its corners
    among ``nodes`` (renormalised; a zero row where none is)."""
    import igl

    _, tri, C = igl.point_mesh_squared_distance(V, X, faces)
    tri = np.asarray(tri, dtype=np.int64)
    w = np.clip(barycentric(X, faces, tri, C), 0.0, None)
    col = np.full(len(X), -1, dtype=np.int64)
    col[nodes] = np.arange(len(nodes))
    corner = col[faces[tri]]  # (n, 3)
    w = np.where(corner >= 0, w, 0.0)
    total = w.sum(axis=1, keepdims=True)
    w = np.divide(w, total, out=np.zeros_like(w), where=total > 1e-9)
    keep = (corner >= 0) & (w > 0)
    rows = np.repeat(np.arange(len(V)), 3).reshape(-1, 3)
    return sp.csr_matrix((w[keep], (rows[keep], corner[keep])), shape=(len(V), len(nodes)))


def rigid_normals(X: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m, 6) the normal displacement at nodes ``X`` (m, 3) mm, along their unit
    ``normals``, of the six rigid motions, unit columns."""
    c = X - X.mean(axis=0)
    scale = max(float(np.abs(c).max()), 1e-12)
    rigid = np.hstack([normals, np.cross(c / scale, normals)])
    return rigid / np.maximum(np.linalg.norm(rigid, axis=0), 1e-300)


def beyond_modes(
    X: np.ndarray,
    normals: np.ndarray,
    modes: np.ndarray | None,
    back: sp.csr_matrix,
    target: np.ndarray,
) -> np.ndarray:
    """(n, 3) mm at the nominal's vertices: the normal displacements ``target`` (m,) mm at
    the nodes ``X`` (m, 3) mm (unit ``normals``) fitted by least squares with the rigid
    motions and the compliant ``modes`` (m, k), the fit less ``target`` (what a fixture that
    bends only those modes leaves of the fitted shape, with the opposite sign), carried
    back along the nodes' normals by ``back`` (n, m) (:func:`back_to_nominal`)."""
    A = rigid_normals(X, normals)
    if modes is not None:
        A = np.hstack([A, modes])
    coef, *_ = np.linalg.lstsq(A, target, rcond=1e-10)
    rest = A @ coef - target
    return np.asarray(back @ (rest[:, None] * normals))


def absorbed_width(X: np.ndarray, normals: np.ndarray, modes: np.ndarray | None) -> float | None:
    """The narrowest Gaussian bump (sigma, mm, of :data:`BUMP_SIGMAS`) of which the part's
    compliant modes take more than half: at the median of :data:`BUMP_SITES` nodes spread
    over the part (farthest-point order), the bump's height left outside the rigid motions
    and ``modes`` at its centre is below half. ``X`` (m, 3) mm the nodes, ``normals`` (m, 3)
    theirs, ``modes`` (m, k). None: no width tried is taken so."""
    A = rigid_normals(X, normals)
    if modes is not None:
        A = np.hstack([A, modes])
    Q, _ = np.linalg.qr(A)
    sites = [0]
    dist = np.linalg.norm(X - X[0], axis=1)
    for _ in range(min(BUMP_SITES, len(X)) - 1):
        sites.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(X - X[sites[-1]], axis=1))
    for sigma in BUMP_SIGMAS:
        left = []
        for j in sites:
            r2 = np.sum((X - X[j]) ** 2, axis=1)
            # a bump of the wall: both skins move along the site's normal
            t = np.exp(-r2 / (2 * sigma**2)) * (normals @ normals[j])
            left.append(abs(t[j] - Q[j] @ (Q.T @ t)))
        if np.median(left) < 0.5:
            return sigma
    return None
