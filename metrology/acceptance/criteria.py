"""Conformance decision: the area criterion and the region criterion (paper Sections 7.2, 10).

A scored nominal vertex is *in tolerance* when ``|dev| <= tau`` (its tolerance band, mm).
A surface conforms when both criteria hold:

* **Area criterion** -- at least ``min_fraction`` (95 %, following the seed study) of the
  scored area is in tolerance. Areas are the barycentric vertex areas of the nominal.
* **Region criterion** -- no connected out-of-tolerance region is larger than
  ``max_region_area``. Out-of-tolerance vertices are grouped into connected components
  over the *mesh edges*, so regions follow the surface and not Euclidean proximity (two
  sides of a thin wall never merge).

The region criterion exists because the area criterion alone admits localized defects: a
0.90 mm dent covering 144 mm^2 moves the in-tolerance share by a fraction of a percent and
passes a 95 % rule comfortably (Section 10). :data:`DEFAULT_MAX_REGION_AREA` is 25 mm^2,
a 5 mm x 5 mm patch: that dent fails it by a factor of almost six, while a single-vertex
noise excursion on a 1-2 mm mesh, whose vertex area is about 1-4 mm^2, does not. The
value is a default, to be stated with each report, not a universal constant.

Unscored vertices (NaN deviation: not observed by the scan) are never out of tolerance and
never in it; they contribute to neither the scored area nor any region, and they break
connectivity, so two defects separated by an unobserved strip are two regions.

The coverage ceiling, a registration check that needs no ground truth, is in
:mod:`qifreport.metrology.acceptance.scan_area`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse.csgraph import connected_components

from qifreport.metrology.acceptance.decision import PROOF_COVERAGE, decide
from qifreport.metrology.acceptance.point_regions import SurfacePoints
from qifreport.metrology.acceptance.statistics import json_float
from qifreport.registration.mesh import adjacency, vertex_areas

__all__ = [
    "DEFAULT_MAX_REGION_AREA",
    "Acceptance",
    "evaluate",
    "find_regions",
    "Region",
    "region_reasons",
]

log = logging.getLogger(__name__)

#: mm^2; a 5 mm x 5 mm patch (see the module docstring)
DEFAULT_MAX_REGION_AREA = 25.0
#: relative slack on the area criterion absorbing floating-point summation error only
_AREA_RTOL = 1e-12
#: at most this many offending regions are spelled out in ``Acceptance.reasons``
_MAX_REASONS = 5


@dataclass
class Region:
    """A connected out-of-tolerance region of the nominal surface.

    Attributes
    ----------
    vertices : (k,) int64 nominal vertex indices.
    area : float, mm^2, sum of the vertex areas.
    peak : float, mm, the signed deviation of largest magnitude in the region.
    peak_vertex : int, the vertex where ``peak`` occurs.
    centroid : (3,) float, mm, vertex-area-weighted centroid.
    sign : int, ``+1`` if the peak is proud (material above nominal), ``-1`` if sunk.
    peak_location : (3,) mm where ``peak`` occurs; None: at ``peak_vertex``.
    sampling : ``"nominal"`` (found on the vertices' deviation) or ``"scan points"`` (on the
        points, :mod:`qifreport.metrology.acceptance.point_regions`: ``vertices`` are then the
        nominal
        vertices nearest to its points, the area, peak and centroid the points' own).
    """

    vertices: np.ndarray
    area: float
    peak: float
    peak_vertex: int
    centroid: np.ndarray
    sign: int
    peak_location: np.ndarray | None = None
    sampling: str = "nominal"

    def peak_at(self, V: np.ndarray) -> np.ndarray:
        """(3,) mm: where the peak is, on the nominal ``V`` when it was found there."""
        return V[self.peak_vertex] if self.peak_location is None else self.peak_location

    def to_dict(self) -> dict:
        """JSON-ready dict (the vertex list is summarised as ``n_vertices``)."""
        return {
            "n_vertices": int(len(self.vertices)),
            "area": json_float(self.area),
            "peak": json_float(self.peak),
            "peak_vertex": int(self.peak_vertex),
            "centroid": [float(c) for c in self.centroid],
            "sign": int(self.sign),
            "sampling": self.sampling,
        } | ({} if self.peak_location is None else {"peak_location": _vec(self.peak_location)})


def _vec(x) -> list[float]:
    return [float(c) for c in x]


def _per_vertex(x, n: int, name: str) -> np.ndarray:
    """A scalar broadcast to (n,), or an (n,) array, as float64."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise ValueError(f"{name} must be a scalar or shape ({n},), got {a.shape}")
    return a


def _tolerance_array(tolerance, n: int) -> np.ndarray:
    tol = _per_vertex(tolerance, n, "tolerance")
    if np.any(np.isnan(tol)) or np.any(tol < 0):
        raise ValueError("tolerance must be non-negative and not NaN")
    return tol


def _areas(V: np.ndarray, F: np.ndarray, area: np.ndarray | None) -> np.ndarray:
    if area is None:
        return vertex_areas(V, F)
    area = np.asarray(area, dtype=np.float64)
    if area.shape != (len(V),):
        raise ValueError(f"area must have shape ({len(V)},), got {area.shape}")
    return area


def _center_array(center, n: int) -> np.ndarray:
    c = _per_vertex(center, n, "center")
    if not np.all(np.isfinite(c)):
        raise ValueError("center must be finite")
    return c


def _prepare(V, F, dev, tolerance, area, center=0.0):
    """Checked arrays for :func:`find_regions` and :func:`evaluate`.

    Returns ``V, F, dev, tol, A, c``: the band half-width, vertex areas and band centre per
    vertex.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    dev = np.asarray(dev, dtype=np.float64).ravel()
    if dev.shape != (n,):
        raise ValueError(f"dev must have shape ({n},), got {dev.shape}")
    return (V, F, dev, _tolerance_array(tolerance, n), _areas(V, F, area), _center_array(center, n))


def find_regions(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    tolerance,
    area: np.ndarray | None = None,
    center=0.0,
) -> list[Region]:
    """Connected out-of-tolerance regions of the deviation field on the nominal mesh.

    A vertex is out of tolerance when ``|dev - center| > tolerance`` (NaN, unscored, never
    is); the band is ``[center - tolerance, center + tolerance]``, so an unequally disposed
    or unilateral zone is a shifted centre.
    Out-of-tolerance vertices joined by a mesh edge belong to the same region
    (``scipy.sparse.csgraph.connected_components`` on the vertex adjacency restricted to
    them). Consequences of this choice:

    * Proud and sunk vertices that touch form **one** region (sign = that of its peak): a
      dent with a raised rim, or an S-shaped warp, is one finding for an inspector.
    * Connectivity is that of the triangulation: two vertices touching only diagonally
      across a quad are one region if that quad's diagonal is a mesh edge, and two regions
      otherwise.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  dev : (n,) signed deviation, mm, NaN unscored.
    tolerance : scalar or (n,) per-vertex tolerance band, mm (``|dev| <= tol`` passes).
    area : (n,) vertex areas, mm^2; default :func:`qifreport.registration.mesh.vertex_areas`.
    center : scalar or (n,) band centre, mm (0: a symmetric band).

    Returns
    -------
    list of :class:`Region`, largest area first (ties: larger ``|peak|`` first).
    """
    V, F, dev, tol, A, c = _prepare(V, F, dev, tolerance, area, center)
    return _regions(V, adjacency(F, len(V)), dev, tol, A, c)


def _regions(V, adj, dev, tol, A, c) -> list[Region]:
    """:func:`find_regions` on checked per-vertex arrays and the mesh's vertex adjacency
    ``adj`` (n, n)."""
    with np.errstate(invalid="ignore"):
        out = np.abs(dev - c) > tol  # NaN compares False: unscored is never out
    idx = np.flatnonzero(out)
    if len(idx) == 0:
        return []
    sub = adj[idx][:, idx]
    n_comp, label = connected_components(sub, directed=False)
    order = np.argsort(label, kind="stable")
    starts = np.flatnonzero(np.r_[True, label[order][1:] != label[order][:-1]])
    groups = np.split(idx[order], starts[1:])
    regions = []
    for verts in groups:
        a = A[verts]
        total = float(a.sum())
        j = int(np.argmax(np.abs(dev[verts])))
        peak = float(dev[verts[j]])
        if total > 0:
            centroid = (a[:, None] * V[verts]).sum(axis=0) / total
        else:
            centroid = V[verts].mean(axis=0)
        regions.append(
            Region(
                vertices=np.sort(verts).astype(np.int64),
                area=total,
                peak=peak,
                peak_vertex=int(verts[j]),
                centroid=centroid,
                sign=1 if peak > 0 else -1,
            )
        )
    regions.sort(key=lambda r: (-r.area, -abs(r.peak)))
    log.debug("find_regions: %d out-of-tolerance vertices in %d regions", len(idx), n_comp)
    return regions


@dataclass
class Acceptance:
    """Conformance decision for one surface.

    Attributes
    ----------
    tolerance : scalar tolerance band, mm, or the (n,) per-vertex array.
    min_fraction : required in-tolerance share of the scored area (0.95).
    max_region_area : largest admissible out-of-tolerance region, mm^2.
    scored_area : area of the scored (non-NaN) vertices, mm^2.
    nominal_area : area of the whole nominal, mm^2.
    coverage : ``scored_area / nominal_area``.
    in_tolerance_fraction : area-weighted in-tolerance share of the scored vertices.
    area_ok : ``in_tolerance_fraction >= min_fraction``.
    regions : out-of-tolerance regions, largest first.
    largest_region_area : mm^2, 0 if there is no region.
    region_ok : ``largest_region_area <= max_region_area``.
    passed : ``area_ok and region_ok and scored_area > 0``: the measured values themselves
        meet the criteria (the simple reading).
    reasons : human-readable reasons for a failure (empty when passed).
    decision_rule : how :attr:`decision` weighs the measurement uncertainty
        (:mod:`qifreport.metrology.acceptance.decision`); ``"simple"`` without one.
    proven_in : the criteria hold with every band reduced by its vertex's expanded
        uncertainty at the proofs' coverage factor
        (:data:`qifreport.metrology.acceptance.decision.PROOF_COVERAGE`; conformance proven, ISO
        14253-1); ``passed`` without an uncertainty.
    proven_out : they fail with every band enlarged by it (non-conformance proven).
    uncertainty_mm : the median and the largest expanded uncertainty of the scored
        vertices, mm (NaN without one).
    uncertain_reasons : why neither is proven (empty when one is).
    nominal_decision : the decision on the nominal's vertices alone, without the scan
        points' regions (None: judged without points); ``"PASS"`` where :attr:`decision`
        is not means only defects narrower than the mesh decide it.
    """

    tolerance: float | np.ndarray
    min_fraction: float
    max_region_area: float
    scored_area: float
    nominal_area: float
    coverage: float
    in_tolerance_fraction: float
    area_ok: bool
    regions: list[Region] = field(default_factory=list)
    largest_region_area: float = 0.0
    region_ok: bool = True
    passed: bool = False
    reasons: list[str] = field(default_factory=list)
    decision_rule: str = "simple"
    proven_in: bool | None = None
    proven_out: bool | None = None
    uncertainty_mm: tuple[float, float] = (math.nan, math.nan)
    uncertain_reasons: list[str] = field(default_factory=list)
    nominal_decision: str | None = None

    @property
    def decision(self) -> str:
        """``"PASS"``, ``"FAIL"`` or ``"UNCERTAIN"`` under :attr:`decision_rule`
        (:func:`qifreport.metrology.acceptance.decision.decide`); a surface with nothing scored
        fails."""
        if not self.scored_area > 0:
            return "FAIL"
        proven_in = self.passed if self.proven_in is None else self.proven_in
        proven_out = (not self.passed) if self.proven_out is None else self.proven_out
        return decide(self.decision_rule, self.passed, proven_in, proven_out)

    def to_dict(self) -> dict:
        """JSON-ready dict; NaN becomes ``None``.

        ``tolerance`` is a float when it is uniform, else ``None``; ``tolerance_min`` and
        ``tolerance_max`` give its range in both cases.
        """
        tol = np.atleast_1d(np.asarray(self.tolerance, dtype=np.float64))
        uniform = len(tol) > 0 and bool(np.all(tol == tol[0]))
        return {
            "tolerance": float(tol[0]) if uniform else None,
            "tolerance_min": json_float(tol.min()) if len(tol) else None,
            "tolerance_max": json_float(tol.max()) if len(tol) else None,
            "min_fraction": float(self.min_fraction),
            "max_region_area": float(self.max_region_area),
            "scored_area": json_float(self.scored_area),
            "nominal_area": json_float(self.nominal_area),
            "coverage": json_float(self.coverage),
            "in_tolerance_fraction": json_float(self.in_tolerance_fraction),
            "area_ok": bool(self.area_ok),
            "regions": [r.to_dict() for r in self.regions],
            "n_regions": len(self.regions),
            "largest_region_area": json_float(self.largest_region_area),
            "region_ok": bool(self.region_ok),
            "passed": bool(self.passed),
            "reasons": list(self.reasons),
            "decision_rule": self.decision_rule,
            "decision": self.decision,
            "proven_in": None if self.proven_in is None else bool(self.proven_in),
            "proven_out": None if self.proven_out is None else bool(self.proven_out),
            "uncertainty_median_mm": json_float(self.uncertainty_mm[0]),
            "uncertainty_max_mm": json_float(self.uncertainty_mm[1]),
            "uncertain_reasons": list(self.uncertain_reasons),
        }


def region_reasons(regions: list[Region], max_region_area: float) -> list[str]:
    """The failure reasons of the regions larger than ``max_region_area`` (mm^2): one line
    each for the first few (regions are largest first), then a count of the rest."""
    big = [r for r in regions if r.area > max_region_area]
    out = []
    for r in big[:_MAX_REASONS]:
        x, y, z = r.centroid
        kind = "proud" if r.sign > 0 else "sunk"
        on = ", on the scan points" if r.sampling == "scan points" else ""
        out.append(
            f"region of {r.area:.1f} mm^2 at ({x:.1f}, {y:.1f}, {z:.1f}) exceeds "
            f"{max_region_area:.1f} mm^2 (peak {r.peak:+.3f} mm, {kind}{on})"
        )
    if len(big) > _MAX_REASONS:
        out.append(f"... and {len(big) - _MAX_REASONS} more regions above the limit")
    return out


def evaluate(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    tolerance,
    area: np.ndarray | None = None,
    min_fraction: float = 0.95,
    max_region_area: float = DEFAULT_MAX_REGION_AREA,
    center=0.0,
    uncertainty=None,
    decision_rule: str = "simple",
    points: SurfacePoints | None = None,
) -> Acceptance:
    """Decide conformance by the area criterion AND the region criterion.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  dev : (n,) signed deviation, mm, NaN unscored.
    tolerance : scalar or (n,) per-vertex band, mm.
    area : (n,) vertex areas, mm^2; default :func:`qifreport.registration.mesh.vertex_areas`.
    min_fraction : required in-tolerance share of the scored area; the comparison is
        ``>=`` (exactly 95 % passes), with a 1e-12 relative slack for summation round-off.
    max_region_area : mm^2; a region passes if its area is ``<=`` this.
    center : scalar or (n,) band centre, mm: in tolerance is ``|dev - center| <= tolerance``.
    uncertainty : scalar or (n,) expanded uncertainty ``U`` (k = 2) of each vertex's
        deviation, mm (:func:`qifreport.metrology.acceptance.decision.vertex_uncertainty`);
        the proofs scale it to :data:`qifreport.metrology.acceptance.decision.PROOF_COVERAGE`;
        None: not known (the decision is the simple one whatever ``decision_rule``).
    decision_rule : one of :data:`qifreport.metrology.acceptance.decision.DECISION_RULES`.
    points : the scan points of the surface
        (:mod:`qifreport.metrology.acceptance.point_regions`): the region criterion is also
        judged on them, with their own uncertainties, so a defect narrower than the mesh is
        not averaged away; a region found on both samplings is reported once, as the larger.

    Returns
    -------
    Acceptance. With no scored vertex the part is not passed (nothing was inspected).
    """
    V, F, dev, tol, A, c = _prepare(V, F, dev, tolerance, area, center)
    scored = ~np.isnan(dev)
    scored_area, nominal_area = float(A[scored].sum()), float(A.sum())
    adj = adjacency(F, len(V))  # one adjacency for the measured values and both guard bands
    U, u_stats = _proof_band(uncertainty, scored, scored_area)

    def criteria(band: np.ndarray, widen: float) -> tuple:
        return _criteria(V, adj, dev, band, A, c, scored_area, min_fraction, points, widen)

    # the band reduced first: its scan points out of tolerance hold those of the measured
    # and the enlarged band, whose point regions then reuse its links
    reduced = None if U is None else criteria(tol - U, -1.0)
    frac, area_ok, regions, largest, largest_v = criteria(tol, 0.0)
    region_ok = bool(largest <= max_region_area)
    passed = bool(area_ok and region_ok and scored_area > 0)
    passed_v = bool(area_ok and largest_v <= max_region_area and scored_area > 0)
    proven_in, proven_out, proven_in_v, proven_out_v, uncertain = _proofs(
        criteria, tol, U, reduced, u_stats, max_region_area, passed_v
    )
    rule = decision_rule if uncertainty is not None else "simple"
    nominal = None if points is None else decide(rule, passed_v, proven_in_v, proven_out_v)
    return Acceptance(
        tolerance=float(tolerance) if np.ndim(tolerance) == 0 else np.asarray(tolerance, float),
        min_fraction=float(min_fraction),
        max_region_area=float(max_region_area),
        scored_area=scored_area,
        nominal_area=nominal_area,
        coverage=scored_area / nominal_area if nominal_area > 0 else math.nan,
        in_tolerance_fraction=frac,
        area_ok=area_ok,
        regions=regions,
        largest_region_area=float(largest),
        region_ok=region_ok,
        passed=passed,
        reasons=_reasons(scored_area, frac, area_ok, min_fraction, regions, max_region_area),
        decision_rule=rule,
        proven_in=proven_in,
        proven_out=proven_out,
        uncertainty_mm=u_stats,
        uncertain_reasons=uncertain,
        nominal_decision=nominal,
    )


def _proofs(
    criteria: Callable[[np.ndarray, float], tuple],
    tol: np.ndarray,
    U: np.ndarray | None,
    reduced: tuple | None,
    u_stats: tuple[float, float],
    max_region_area: float,
    passed_v: bool,
) -> tuple[bool | None, bool | None, bool, bool, list[str]]:
    """Conformance and non-conformance proven against the band reduced (``reduced``, its
    :func:`_criteria`) and enlarged (``tol + U``, judged here by ``criteria(band, widen)``)
    by the uncertainty ``U``: ``(proven_in, proven_out, proven_in_v, proven_out_v,
    uncertain_reasons)``, the ``_v`` on the vertices alone. Without ``U``: nothing proven
    (None), the vertices' verdict ``passed_v`` taken as it is."""
    if U is None:
        return None, None, passed_v, not passed_v, []
    proven_in, proven_in_v = _within(reduced, max_region_area)
    conforms_out, conforms_out_v = _within(criteria(tol + U, 1.0), max_region_area)
    proven_out, proven_out_v = not conforms_out, not conforms_out_v
    uncertain: list[str] = []
    if not proven_in and not proven_out:
        uncertain = _uncertain_reasons(reduced, u_stats, max_region_area)
    return proven_in, proven_out, proven_in_v, proven_out_v, uncertain


def _proof_band(
    uncertainty, scored: np.ndarray, scored_area: float
) -> tuple[np.ndarray | None, tuple[float, float]]:
    """The proofs' widening of the band per vertex (n,), mm: the expanded uncertainty
    scaled to :data:`PROOF_COVERAGE` (NaN: 0), and the uncertainty's median and largest
    over the scored vertices; (None, NaNs) without an uncertainty or a scored vertex."""
    if uncertainty is None or scored_area <= 0:
        return None, (math.nan, math.nan)
    U = np.nan_to_num(_per_vertex(uncertainty, len(scored), "uncertainty"), nan=0.0)
    Us = U[scored]
    u_stats = (float(np.median(Us)), float(Us.max()))
    return U * (0.5 * PROOF_COVERAGE), u_stats  # the proofs' band (decision.py)


def _within(criteria: tuple, max_region_area: float) -> tuple[bool, bool]:
    """Whether a band's criteria (:func:`_criteria`) pass, with the scan points' regions
    and on the vertices alone."""
    _, area_ok, _, largest, largest_v = criteria
    return (
        bool(area_ok and largest <= max_region_area),
        bool(area_ok and largest_v <= max_region_area),
    )


def _reasons(
    scored_area: float,
    frac: float,
    area_ok: bool,
    min_fraction: float,
    regions: list[Region],
    max_region_area: float,
) -> list[str]:
    """Why the part does not pass on its measured values (empty: it does)."""
    if scored_area <= 0:
        return ["no scored vertex: the scan observed none of the nominal surface"]
    reasons: list[str] = []
    if not area_ok:
        reasons.append(
            f"in-tolerance area {100 * frac:.1f} % of the scored area is below "
            f"{100 * min_fraction:.1f} %"
        )
    return reasons + region_reasons(regions, max_region_area)


def _uncertain_reasons(
    reduced: tuple, u_stats: tuple[float, float], max_region_area: float
) -> list[str]:
    """Why neither conformance nor non-conformance is proven: what fails the band reduced
    by the uncertainty (``reduced``: its :func:`_criteria`)."""
    frac_in, area_in, _, largest_in, _ = reduced
    why_in = []
    if not area_in:
        why_in.append(f"{100 * frac_in:.1f} % of the scored area in tolerance")
    if largest_in > max_region_area:
        why_in.append(f"a region of {largest_in:.1f} mm^2")
    return [
        f"within the measurement uncertainty of the zone limit (U median "
        f"{u_stats[0]:.4f} mm, max {u_stats[1]:.4f} mm; proofs at k = "
        f"{PROOF_COVERAGE:g}): {r}"
        for r in why_in
    ]


def _criteria(V, adj, dev, tol, A, c, scored_area, min_fraction, points=None, widen=0.0):
    """The area criterion and the regions with the per-vertex band ``tol`` (the measured
    band, or one reduced or enlarged by the uncertainty; a band reduced below 0 holds no
    vertex), and with ``points`` the regions of the scan points with their band widened
    by ``widen`` x their uncertainty: (in-tolerance share of the scored area, area
    criterion met, regions largest first, the largest one's area in mm^2 or 0, the largest
    one's of the vertices alone)."""
    with np.errstate(invalid="ignore"):
        inside = ~np.isnan(dev) & (np.abs(dev - c) <= tol)
    frac = float(A[inside].sum()) / scored_area if scored_area > 0 else math.nan
    area_ok = bool(scored_area > 0 and frac >= min_fraction * (1.0 - _AREA_RTOL))
    regions = _regions(V, adj, dev, np.maximum(tol, 0.0), A, c)
    largest_v = regions[0].area if regions else 0.0
    if points is not None:
        regions = _merge(regions, points.regions(widen, Region))
    return frac, area_ok, regions, regions[0].area if regions else 0.0, largest_v


def _merge(on_vertices: list[Region], on_points: list[Region]) -> list[Region]:
    """One list of the regions of both samplings, largest first: a region of the points
    that shares nominal vertices with regions of the vertices replaces them when it is
    larger than each, and is dropped otherwise (one finding, reported once, with the
    larger peak of the two)."""
    if not on_points:
        return on_vertices
    owner: dict[int, int] = {}
    for i, r in enumerate(on_vertices):
        for v in r.vertices.tolist():
            owner[v] = i
    dropped: set[int] = set()
    kept = []
    on_vertices = list(on_vertices)
    for r in on_points:
        hit = {owner[v] for v in r.vertices.tolist() if v in owner}
        if hit and max(on_vertices[i].area for i in hit) >= r.area:
            # the vertices' region stands for the finding, with the points' peak when it
            # is the larger (the vertices' fit averages a narrow peak away)
            i = max(hit, key=lambda i: on_vertices[i].area)
            if abs(r.peak) > abs(on_vertices[i].peak):
                on_vertices[i] = replace(
                    on_vertices[i],
                    peak=r.peak,
                    peak_vertex=r.peak_vertex,
                    peak_location=r.peak_location,
                    sign=r.sign,
                )
            continue
        dropped |= hit
        kept.append(r)
    out = [r for i, r in enumerate(on_vertices) if i not in dropped] + kept
    out.sort(key=lambda r: (-r.area, -abs(r.peak)))
    return out
