"""What the measurement can see: the dent a surface's region criterion is sure to catch.

A deviation is not read point by point. Each vertex's value is a linear fit of the scan
points' residuals inside a ball about it
(:func:`~qifreport.metrology.deviation.residual_fit.residual_referenced`, about 1.5 mesh
edges), so a dent narrower than a few balls reads shallower than it is; and a virtual
fixture follows whatever its band limit allows, so it absorbs the part of a dent it did
not hold out. Both are linear in the dent once the fixture's weights and hold-outs are
fixed, so they are probed, not assumed:

* **The critical dent.** A dent ``d(x) = a exp(-|x - x0|^2 / sigma^2)`` (the paper's
  Eq. 16) is out of a band of half-width ``t`` over a disk of area ``pi sigma^2 ln(a / t)``.
  The region criterion's limit ``A`` (mm^2) names its own width, ``sigma_A = sqrt(A / pi)``,
  and the dent of that width whose region is exactly ``A`` is ``a = e t``.
* **The probe.** That dent is laid at the surface's most interior measured vertex; the
  fixture's last pass (:class:`FixtureProbe`: its final weights, its first pass's flags
  and hold-outs, replayed on the dent) takes what it would absorb, and the deviation's
  ball fit reads the rest on the scan's own points. What the product reads of a failing
  region of the limit's size is :attr:`Detectable.read_area_mm2`.
* **The decision.** A region criterion is established only where the product can tell a
  failing region from a passing one: a surface whose largest region is within the area the
  probe lost (``A - read``) of the limit is not proven in (NOT ESTABLISHED, like a reading
  within its uncertainty, ISO 14253-1); a surface on which the critical dent reads no region
  at all has a region criterion below what this scan and mesh can detect.
* **The detectable dent** stated per surface: the shallowest dent of width ``sigma_A``
  read beyond the band, ``(t + U) / g`` (``g`` the read share of its peak, ``U`` the
  surface's median expanded uncertainty).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.criteria import Acceptance
from qifreport.metrology.acceptance.statistics import json_float
from qifreport.metrology.deviation.residual_fit import residual_referenced
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import MeshOperators

__all__ = [
    "Detectable",
    "FixtureProbe",
    "critical_depth",
    "detectable_dent",
    "interior_vertex",
    "with_detectable",
]

#: rounds a probed hold-out may grow (the fixture's own grow until they settle)
HOLDOUT_ROUNDS = 3


def critical_depth(half_width: float, max_region_area: float, sigma: float) -> float:
    """Depth, mm, of the dent of width ``sigma`` (mm, Eq. 16) whose out-of-band disk is
    exactly ``max_region_area`` (mm^2) for a band of half-width ``half_width`` (mm)."""
    return half_width * math.exp(max_region_area / (math.pi * sigma**2))


@dataclass(frozen=True)
class FixtureProbe:
    """The virtual fixture's last pass as a linear map, for replaying a probe dent.

    Attributes
    ----------
    V0 : (n, 3) the posed nominal the fixture started from, mm.
    ops : the nominal's operators (bending ``Q``, mass ``M``, vertex areas).
    weights : (n,) the final data weights; a held-out covered vertex carries the median
        weight (the probe's own hold-outs decide where data is withheld).
    covered : (n,) bool vertices with a matched scan point.
    band_limit, band_limit_refit : the first pass's and the refits' smoothing lengths, mm.
    threshold : the first pass's flag threshold (``flag_k`` robust scales), mm.
    holdout_radius : the radius withheld around a flagged vertex, mm.
    refits : whether the fixture refitted (its band-limited scheme ran).
    """

    V0: np.ndarray
    ops: MeshOperators
    weights: np.ndarray
    covered: np.ndarray
    band_limit: float
    band_limit_refit: float
    threshold: float
    holdout_radius: float
    refits: bool

    @classmethod
    def of(cls, fit: DeformResult, ops: MeshOperators) -> FixtureProbe | None:
        """The probe of a GB-CICP ``fit`` with the band-limit parametrisation (None for
        another method or parametrisation: their absorption is not probed)."""
        p = fit.params
        if fit.method != "gbcicp" or getattr(p, "lambda0", None) is not None:
            return None
        first = [h["scale"] for h in fit.history if h.get("pass_no") == 1]
        w = np.asarray(fit.weights, dtype=np.float64).copy()
        cov = np.asarray(fit.covered, dtype=bool)
        pos = cov & (w > 0)
        w[cov & (w <= 0)] = float(np.median(w[pos])) if pos.any() else 1.0
        return cls(
            V0=fit.V - fit.e,
            ops=ops,
            weights=w,
            covered=cov,
            band_limit=float(p.band_limit),
            band_limit_refit=float(p.band_limit_refit),
            threshold=p.flag_k * (first[-1] if first else fit.scale),
            holdout_radius=float(p.coverage_radius * p.holdout_factor),
            refits=fit.passes > 1 and not fit.fallback,
        )

    def _fitted(self, solver: SPDSolver, lam: float, w: np.ndarray, d: np.ndarray) -> np.ndarray:
        Aw = self.ops.area * w
        eps = 1e-9 * self.band_limit**4 * self.ops.M
        return solver.factor((sp.diags(Aw) + lam * self.ops.Q + eps).tocsc())(Aw * d)

    def absorbed(self, d: np.ndarray) -> np.ndarray:
        """(n,) the part of the normal dent ``d`` (n,) mm the fixture follows, mm: its
        first pass at the band limit, then, where that leaves the dent beyond the flag
        threshold, the refit with the flagged vertices' surroundings withheld, grown while
        a withheld vertex stays beyond it."""
        solver = SPDSolver(points=self.V0)
        h = self._fitted(solver, self.band_limit**4, self.weights, d)
        flagged = self.covered & (np.abs(d - h) > self.threshold)
        if not (self.refits and flagged.any()):
            return h
        tree = cKDTree(self.V0)
        hold = np.zeros(len(d), dtype=bool)
        seeds = flagged
        for _ in range(HOLDOUT_ROUNDS):
            grown = hold.copy()
            for near in tree.query_ball_point(self.V0[seeds], self.holdout_radius):
                grown[near] = True
            if (grown == hold).all():
                break
            hold = grown
            h = self._fitted(solver, self.band_limit_refit**4, self.weights * ~hold, d)
            seeds = hold & (np.abs(d - h) > self.threshold)
        return h


@dataclass(frozen=True)
class Detectable:
    """What one surface's region criterion can see (module docstring); lengths in mm,
    areas in mm^2.

    Attributes
    ----------
    sigma_mm : the probed dent's width, ``sqrt(limit / pi)`` (Eq. 16 convention).
    depth_mm : its depth, the critical one (its true out-of-band region is the limit).
    read_peak_mm : the largest deviation the product reads of it.
    read_area_mm2 : the out-of-band area it reads of it.
    limit_mm2 : the region criterion's limit.
    smallest_depth_mm : the shallowest dent of width ``sigma_mm`` read beyond the band
        (``(t + U) / g``; inf when the dent reads nothing).
    absorbed_by : what reads it short: the deviation's ball fit, and the virtual fixture
        when one held the part.
    site : (3,) where it was probed, mm.
    """

    sigma_mm: float
    depth_mm: float
    read_peak_mm: float
    read_area_mm2: float
    limit_mm2: float
    smallest_depth_mm: float
    absorbed_by: str
    site: tuple[float, float, float]

    @property
    def lost_area_mm2(self) -> float:
        """The area of a failing region of the limit's size the product does not read."""
        return max(self.limit_mm2 - self.read_area_mm2, 0.0)

    def doubt(self, largest: float) -> str:
        """Why a surface whose largest out-of-band region reads ``largest`` mm^2 is not
        proven to meet its region criterion (empty: it is)."""
        if largest > self.limit_mm2:
            return ""
        size = (
            f"a dent of sigma {self.sigma_mm:.2g} mm and {self.depth_mm:.3g} mm whose region "
            f"is the {self.limit_mm2:g} mm^2 limit"
        )
        if self.read_area_mm2 <= 0.0:
            return (
                f"region criterion below what this scan and mesh detect: {size} reads no "
                f"region (read peak {self.read_peak_mm:.3g} mm; {self.absorbed_by})"
            )
        # a region read as large as the critical dent's may be the critical dent or a
        # deeper one (the mesh's vertex areas read both the same): not proven in
        if largest >= self.limit_mm2 - self.lost_area_mm2 - 1e-9 and largest > 0:
            return (
                f"a region of {largest:.1f} mm^2 cannot be told from a failing one: {size} "
                f"reads as {self.read_area_mm2:.1f} mm^2 ({self.absorbed_by})"
            )
        return ""

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN and inf become None)."""
        return {
            "sigma_mm": json_float(self.sigma_mm),
            "critical_depth_mm": json_float(self.depth_mm),
            "read_peak_mm": json_float(self.read_peak_mm),
            "read_area_mm2": json_float(self.read_area_mm2),
            "limit_mm2": json_float(self.limit_mm2),
            "lost_area_mm2": json_float(self.lost_area_mm2),
            "smallest_depth_mm": json_float(self.smallest_depth_mm),
            "absorbed_by": self.absorbed_by,
            "site_mm": [json_float(x) for x in self.site],
        }

    def line(self) -> str:
        """One line for the console and the report."""
        return (
            f"detects a dent of sigma {self.sigma_mm:.2g} mm from {self.smallest_depth_mm:.3g} "
            f"mm deep; a failing {self.limit_mm2:g} mm^2 region reads "
            f"{self.read_area_mm2:.1f} mm^2"
        )


def interior_vertex(V: np.ndarray, scored: np.ndarray) -> int | None:
    """The scored vertex farthest from every unscored one (``scored`` (n,) bool): a
    surface's most interior measured vertex. None when nothing is scored."""
    idx = np.flatnonzero(scored)
    if not len(idx):
        return None
    rest = np.flatnonzero(~scored)
    if not len(rest):
        return int(idx[0])
    dist, _ = cKDTree(V[rest]).query(V[idx])
    return int(idx[int(np.argmax(dist))])


def detectable_dent(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    normals: np.ndarray,
    area: np.ndarray,
    site: int,
    half_width: float,
    max_region_area: float,
    uncertainty: float = 0.0,
    fixture: FixtureProbe | None = None,
    sigma: float | None = None,
) -> Detectable:
    """The critical dent of one surface, probed at vertex ``site`` (module docstring).

    Parameters
    ----------
    V : (n, 3) the held nominal, mm.  F : (f, 3).  P : (m, 3) the scan's points, mm.
    normals : (n, 3) unit vertex normals.  area : (n,) vertex areas of the surface, mm^2
        (0 off it).
    half_width : the band's half-width, mm.  max_region_area : the region limit, mm^2.
    uncertainty : the surface's median expanded uncertainty, mm.
    fixture : the virtual fixture's last pass (None: the part is judged as seated or held
        by its clamps, and only the ball fit reads the dent short).
    sigma : the dent's width, mm (Eq. 16); default the limit's own, ``sqrt(A / pi)``.
    """
    sigma = math.sqrt(max_region_area / math.pi) if sigma is None else float(sigma)
    a = critical_depth(half_width, max_region_area, sigma)
    x0 = V[site]
    reach = 3.0 * sigma + 4.0 * _edge(V, F)
    near_p = np.flatnonzero(np.linalg.norm(P - x0, axis=1) <= reach)
    Pn = P[near_p]
    by = "the deviation's ball fit"
    absorbed = None
    if fixture is not None:
        h = fixture.absorbed(a * np.exp(-np.sum((V - x0) ** 2, axis=1) / sigma**2))
        tree = cKDTree(V)
        by = "the virtual fixture and the deviation's ball fit"

        def absorbed(shift):
            return h[tree.query(Pn - shift)[1]]

    peak, read_area = math.inf, math.inf
    # the dent centred on the vertex and between vertices: a region's area on the mesh
    # depends on where the dent falls among the vertices, and the least read counts
    for c in _centres(V, F, site):
        r = a * np.exp(-np.sum((Pn - c) ** 2, axis=1) / sigma**2)
        if absorbed is not None:
            r = r - absorbed(c - x0)
        read = _ball_read(V, F, Pn, r, normals)
        on = np.isfinite(read) & (area > 0)
        peak = min(peak, float(np.max(read[on])) if on.any() else 0.0)
        read_area = min(read_area, float(area[on & (read > half_width)].sum()))
    g = peak / a if a > 0 else 0.0
    smallest = (half_width + uncertainty) / g if g > 0 else math.inf
    return Detectable(
        sigma_mm=sigma,
        depth_mm=a,
        read_peak_mm=peak,
        read_area_mm2=read_area,
        limit_mm2=float(max_region_area),
        smallest_depth_mm=smallest,
        absorbed_by=by,
        site=tuple(float(x) for x in x0),
    )


def with_detectable(acc: Acceptance, det: Detectable | None) -> Acceptance:
    """``acc`` not proven in when its region criterion cannot tell its largest region
    from a failing one (:meth:`Detectable.doubt`); unchanged otherwise."""
    if det is None or acc.proven_in is False:
        return acc
    why = det.doubt(acc.largest_region_area)
    if not why:
        return acc
    return replace(acc, proven_in=False, uncertain_reasons=[*acc.uncertain_reasons, why])


def _centres(V: np.ndarray, F: np.ndarray, site: int) -> list[np.ndarray]:
    """Dent centres about vertex ``site``: the vertex, the midpoint of one of its edges and
    the centroid of one of its triangles (mm)."""
    tri = F[np.flatnonzero((F == site).any(axis=1))[:1]]
    if not len(tri):
        return [V[site]]
    other = tri[0][tri[0] != site][0]
    return [V[site], 0.5 * (V[site] + V[other]), V[tri[0]].mean(axis=0)]


def _edge(V: np.ndarray, F: np.ndarray) -> float:
    """The mesh's median edge length, mm."""
    e = np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1)
    return float(np.median(e)) if len(e) else 0.0


def _ball_read(
    V: np.ndarray, F: np.ndarray, P: np.ndarray, r: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """(n,) the deviation the ball fit reads from the points ``P`` (k, 3) mm whose
    residuals are ``r`` (k,) mm, one smooth surface (no B-rep face split), NaN unread."""
    labels = np.zeros(len(F), dtype=np.int64)
    return residual_referenced(
        V, F, P, r, normals, np.zeros(len(P), dtype=np.int64), labels, variance=False
    )
