"""One inspection, end to end on arrays: rigid alignment, virtual fixturing, deviation, verdict.

This is the library entry point the CLI (and later the QIF writer) calls. It takes the
nominal ``(V, F)`` and the scan ``P`` in mm, and returns an :class:`InspectionResult` with the
registered nominal, the signed deviation field, its statistics and the acceptance decision
of the paper's Section 10 (area criterion and region criterion).

Frames: the scan is moved into the nominal (CAD) frame once, by the rigid stage
(paper Section 3); everything reported (registered nominal, region centroids) is in the
nominal frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from registration.errors import InputError
from registration.gbcicp import GBCICPParams, GBCICPResult, gbcicp
from registration.icp import RigidResult, rigid_icp
from registration.mesh import bending_operator, bounding_diagonal, vertex_normals

from .acceptance import (
    DEFAULT_MAX_REGION_AREA,
    Acceptance,
    coverage_ceiling_ok,
    evaluate,
    scan_area,
)
from .deviation import data_referenced, nominal_referenced
from .statistics import DeviationStats, deviation_statistics

log = logging.getLogger(__name__)

#: Scan-to-nominal size ratios that betray a unit mismatch, and what they mean.
_UNIT_RATIOS = {25.4: "inch vs mm", 1 / 25.4: "mm vs inch", 1000.0: "m vs mm",
                0.001: "mm vs m", 10.0: "cm vs mm", 0.1: "mm vs cm"}


@dataclass
class InspectionParams:
    """Parameters of :func:`inspect` (lengths in mm).

    Attributes
    ----------
    tolerance : half-width of the profile band: a vertex is in tolerance if ``|dev| <= tol``.
    min_fraction : area criterion, fraction of the scored area that must be in tolerance.
    max_region_area : region criterion, largest admissible connected out-of-tolerance
        region (mm^2).
    energy : bending energy, ``"hessian"`` (default; natural boundary conditions) or
        ``"laplacian"`` (the paper's ``L M^-1 L``).
    rigid_only : skip the virtual fixture (the fixtureless rigid baseline).
    gbcicp : parameters of the non-rigid stage.
    """

    tolerance: float
    min_fraction: float = 0.95
    max_region_area: float = DEFAULT_MAX_REGION_AREA
    energy: str = "hessian"
    rigid_only: bool = False
    gbcicp: GBCICPParams = field(default_factory=GBCICPParams)


@dataclass
class InspectionResult:
    """Everything one inspection measured (arrays in the nominal frame, mm).

    Attributes
    ----------
    V, F : the nominal mesh.  V_registered : (n, 3) nominal after virtual fixturing.
    P : (m, 3) scan points moved into the nominal frame.
    deviation : (n,) signed nominal-referenced deviation per vertex, NaN where unscored.
    point_deviation : (m,) signed data-referenced deviation of every scan point.
    vertex_stats : area-weighted statistics of ``deviation``.
    point_stats : statistics of ``point_deviation``.
    acceptance : area and region criteria and the verdict.
    rigid : the rigid alignment.  fit : the GB-CICP result (None with ``rigid_only``).
    scan_area : estimated area covered by the scan, mm^2.
    coverage_ceiling_ok : coverage does not exceed scan area / nominal area (over-fit check).
    timings : seconds per stage.
    """

    V: np.ndarray
    F: np.ndarray
    V_registered: np.ndarray
    P: np.ndarray
    deviation: np.ndarray
    point_deviation: np.ndarray
    vertex_stats: DeviationStats
    point_stats: DeviationStats
    acceptance: Acceptance
    rigid: RigidResult
    fit: GBCICPResult | None
    params: InspectionParams
    scan_area: float
    coverage_ceiling_ok: bool
    timings: dict[str, float]

    @property
    def passed(self) -> bool:
        return bool(self.acceptance.passed)

    def to_dict(self) -> dict:
        """JSON-ready summary: verdict, statistics, regions, registration and parameters."""
        fit = self.fit
        p = asdict(self.params)
        if fit is not None:
            p["gbcicp"] = asdict(fit.params)
        return {
            "verdict": "PASS" if self.passed else "FAIL",
            "acceptance": self.acceptance.to_dict(),
            "vertex_deviation": self.vertex_stats.to_dict(),
            "point_deviation": self.point_stats.to_dict(),
            "coverage": {
                "scored_area_mm2": self.acceptance.scored_area,
                "nominal_area_mm2": self.acceptance.nominal_area,
                "coverage": self.acceptance.coverage,
                "scan_area_mm2": self.scan_area,
                "ceiling_ok": self.coverage_ceiling_ok,
            },
            "registration": {
                "rigid": {
                    "R": self.rigid.R.tolist(),
                    "t_mm": self.rigid.t.tolist(),
                    "rms_mm": self.rigid.rms,
                    "inlier_fraction": self.rigid.inlier_fraction,
                    "iterations": self.rigid.iterations,
                },
                "gbcicp": None if fit is None else {
                    "iterations": fit.iterations,
                    "passes": fit.passes,
                    "fallback": fit.fallback,
                    "flagged_fraction": fit.flagged_fraction,
                    "residual_scale_mm": fit.scale,
                    "max_displacement_mm": float(np.linalg.norm(fit.e, axis=1).max()),
                },
            },
            "parameters": p,
            "mesh": {"vertices": len(self.V), "triangles": len(self.F), "scan_points": len(self.P)},
            "timings_s": self.timings,
        }


def check_units(V: np.ndarray, P: np.ndarray) -> None:
    """Reject a scan whose extent betrays other units (or another part) than the nominal's.

    The overlap check needs the rigid pose and is made in :func:`inspect`.
    Raises :class:`InputError` with a one-line message.
    """
    dv, dp = bounding_diagonal(V), bounding_diagonal(P)
    if dv <= 0:
        raise InputError("the nominal mesh has zero extent")
    ratio = dp / dv
    if not 0.2 <= ratio <= 5.0:
        best = min(_UNIT_RATIOS, key=lambda r: abs(np.log(ratio / r)))
        hint = f" (units differ: {_UNIT_RATIOS[best]}?)" if abs(np.log(ratio / best)) < 0.4 else ""
        raise InputError(
            f"scan extent {dp:.4g} vs nominal extent {dv:.4g} (ratio {ratio:.3g}): "
            f"wrong units or wrong part{hint}"
        )


def inspect(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    progress=None,
) -> InspectionResult:
    """Inspect the scan ``P`` against the nominal ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points, mm, roughly in the nominal frame (an arbitrary placement needs
        the pre-registration stage first).
    params : :class:`InspectionParams`.
    progress : optional callable ``progress(k)`` advanced once per GB-CICP iteration.

    Raises
    ------
    InputError
        Wrong units, or a scan that does not overlap the nominal after rigid alignment.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    check_units(V, P)
    ops = bending_operator(V, F, params.energy)
    timings["operators"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    tree = cKDTree(V)
    rigid = rigid_icp(V, ops.normals, P, tree=tree)
    Pm = rigid.apply(P)
    timings["rigid"] = time.perf_counter() - t0
    diag = bounding_diagonal(V)
    d_near, _ = tree.query(Pm, workers=-1)
    overlap = float(np.mean(d_near < 0.02 * diag))
    if overlap < 0.3 or rigid.inlier_fraction < 0.3:
        raise InputError(
            f"scan does not overlap the nominal: after rigid alignment only {100 * overlap:.0f} % "
            f"of the points lie within {0.02 * diag:.3g} mm of it"
        )

    fit = None
    V_reg = V
    t0 = time.perf_counter()
    if not params.rigid_only:
        fit = gbcicp(V, F, ops, Pm, params.gbcicp, progress=progress)
        V_reg = fit.V
    timings["gbcicp"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    N_reg = vertex_normals(V_reg, F)
    dev = nominal_referenced(V_reg, F, Pm, normals=N_reg)
    pdev = data_referenced(V_reg, F, Pm)
    area = ops.area  # barycentric vertex areas of the nominal, mm^2
    vstats = deviation_statistics(dev, weights=area, threshold=params.tolerance)
    pstats = deviation_statistics(pdev, threshold=params.tolerance)
    acc = evaluate(
        V, F, dev, params.tolerance, area=area, min_fraction=params.min_fraction,
        max_region_area=params.max_region_area,
    )
    s_area = scan_area(Pm)
    ceiling = coverage_ceiling_ok(acc.coverage, s_area, acc.nominal_area)
    timings["metrology"] = time.perf_counter() - t0
    return InspectionResult(
        V=V, F=F, V_registered=V_reg, P=Pm, deviation=dev, point_deviation=pdev,
        vertex_stats=vstats, point_stats=pstats, acceptance=acc, rigid=rigid, fit=fit,
        params=params, scan_area=s_area, coverage_ceiling_ok=ceiling, timings=timings,
    )
