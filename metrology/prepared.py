"""Everything an inspection needs from the nominal alone, computed once per part.

A production line inspects every molding off the press against one nominal. The work that
depends only on the nominal -- the bending operators, the unscored crease and rim bands, the
mesh hygiene, the GB-CICP bending basis (the costliest: an eigen-decomposition) and the
pose search's curvature descriptors -- is done once by :func:`prepare_part` and handed to
every :func:`qifreport.metrology.inspection.inspect` of the part (``prepared=``). The per-part cache
(:mod:`qifreport.cache`) stores it on disk; the batch runner (:mod:`qifreport.batch`) ships it to
each worker once.

A :class:`PreparedPart` remembers the settings it was built with (:func:`part_settings`);
:meth:`PreparedPart.check` refuses an inspection whose parameters would have built it
differently, so a prepared state can never silently stand in for another.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from qifreport.metrology.deviation.hygiene import MeshHygiene, mesh_hygiene
from qifreport.metrology.deviation.unscored import unscored_bands
from qifreport.registration.deformable.bending_basis import BendingBasis, bending_basis
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import MeshOperators, bending_operator, boundary_vertices
from qifreport.registration.pose.prealign import PreparedModel, prepare_model

from .params import InspectionParams

__all__ = [
    "part_settings",
    "prepare_part",
    "PreparedPart",
]

log = logging.getLogger(__name__)


def part_settings(params: InspectionParams) -> dict:
    """The inspection parameters that change the prepared state (JSON-able).

    Parameters
    ----------
    params : :class:`qifreport.metrology.params.InspectionParams`.
    """
    return {
        "energy": params.energy,
        "edge_band": params.edge_band,
        "boundary_band": params.boundary_band,
        "crease_angle": params.crease_angle,
        "modes": int(params.gbcicp.modes),
    }


@dataclass
class PreparedPart:
    """The scan-independent state of one nominal (mm throughout).

    Attributes
    ----------
    V : (n, 3) nominal vertices.  F : (f, 3) triangles.
    energy : the bending energy resolved from ``settings["energy"]`` (``"hessian"`` for an
        open sheet, ``"laplacian"`` for a closed solid under ``"auto"``).
    ops : cotangent Laplacian, mass, bending operator, vertex normals and areas.
    boundary : (n,) bool, vertices on an open boundary.
    near_crease : (n,) bool within the edge band of a sharp crease (None: band 0).
    near_rim : (n,) bool within the rim band.  rim_band : its width, mm.
    hygiene : defects of the nominal mesh (rim band not yet filled in).
    basis : GB-CICP's bending basis (None when not built: ``basis=False``).
    model : the pose search's model side (None when not built: ``model=False``).
    settings : :func:`part_settings` of the parameters it was built with.
    timings : seconds per preparation step.
    """

    V: np.ndarray
    F: np.ndarray
    energy: str
    ops: MeshOperators
    boundary: np.ndarray
    near_crease: np.ndarray | None
    near_rim: np.ndarray
    rim_band: float
    hygiene: MeshHygiene
    basis: BendingBasis | None
    model: PreparedModel | None
    settings: dict
    timings: dict = field(default_factory=dict)

    def check(self, V: np.ndarray, F: np.ndarray, params: InspectionParams) -> None:
        """Raise ``ValueError`` unless this state was prepared for ``(V, F)`` and ``params``."""
        if (
            self.V.shape != np.shape(V)
            or self.F.shape != np.shape(F)
            or not (np.array_equal(self.F, F) and np.allclose(self.V, V, rtol=0, atol=1e-9))
        ):
            raise ValueError("prepared state belongs to another nominal mesh")
        want = part_settings(params)
        if want != self.settings:
            diff = {
                k: (self.settings.get(k), v) for k, v in want.items() if self.settings.get(k) != v
            }
            raise ValueError(f"prepared state built with other settings: {diff}")


def prepare_part(
    V: np.ndarray,
    F: np.ndarray,
    params: InspectionParams,
    *,
    basis: bool = True,
    model: bool = True,
) -> PreparedPart:
    """Compute the scan-independent state of the nominal ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.
    params : :class:`qifreport.metrology.params.InspectionParams` (its :func:`part_settings`).
    basis : build GB-CICP's bending basis (``params.gbcicp.modes`` modes; the costliest
        step, seconds on tens of thousands of vertices).
    model : build the pose search's model (curvature fields, keypoints, geodesic balls),
        used when a scan arrives in an arbitrary placement.
    """

    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    boundary = boundary_vertices(F, len(V))
    energy = params.energy
    if energy == "auto":
        energy = "hessian" if boundary.any() else "laplacian"
    ops = bending_operator(V, F, energy)
    timings["operators"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    near_crease, near_rim, rim_band = unscored_bands(V, F, boundary, params)
    hygiene = mesh_hygiene(V, F)
    timings["bands"] = time.perf_counter() - t0
    b = None
    if basis:
        b = bending_basis(ops, params.gbcicp.modes, solver=SPDSolver(points=V))
        timings["basis"] = b.seconds
    m = None
    if model:
        t0 = time.perf_counter()
        m = prepare_model(V, F)
        timings["prealign_model"] = time.perf_counter() - t0
    log.info(
        "prepared %d vertices: %s", len(V), ", ".join(f"{k} {v:.2f} s" for k, v in timings.items())
    )
    return PreparedPart(
        V=V,
        F=F,
        energy=energy,
        ops=ops,
        boundary=boundary,
        near_crease=near_crease,
        near_rim=near_rim,
        rim_band=rim_band,
        hygiene=hygiene,
        basis=b,
        model=m,
        settings=part_settings(params),
        timings=timings,
    )
