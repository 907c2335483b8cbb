"""Measured or not: how much of a toleranced surface the scan actually scored.

A tolerance can only be said to hold on a surface that was measured. Each toleranced
surface (a zone, or the whole part) gets a coverage decision before its area and region
criteria count:

* **Coverage rule** -- the scored area must be at least ``min_coverage`` of the zone's own
  area (default :data:`DEFAULT_MIN_COVERAGE`, 70 %). The zone's area is all of it: the bands
  left unscored by design (near sharp creases and open rims) count as not measured, so the
  rule is "at least 70 % of this surface was looked at", whatever the reason for the rest.
* **Gap rules** -- an *unmeasured patch* is a connected set of vertices neither scored nor in a
  band left out by design (connected over the mesh edges of the zone's triangles, as the
  out-of-tolerance regions are). A patch larger than the region criterion's limit
  (``max_region_area``, 25 mm^2) could hide a whole failing region, so:

  - no patch may exceed ``max_gap_area`` (default :data:`GAP_AREA_FACTOR` x
    ``max_region_area`` = 100 mm^2, a 11 mm disk: scans routinely lose patches that size at
    clamp pads and reflections);
  - a patch *together with the out-of-tolerance vertices it touches* may not exceed
    ``max_region_area`` when the deviation around it leaves the inner three quarters of the
    band (``|dev - centre| > half-width / 4``, :data:`HIDING_EXCESS`, on a scored vertex
    bordering it, or an out-of-tolerance vertex in it): a defect is smooth, and a dent cut
    out of the scan leaves its shoulders around the hole. A dent cut out of the scan is not
    a conforming dent; a clamp hole on conforming material is. The vertices read *across* a
    hole in the scan (scored, with no scan point within the deviation's first ball: their
    reading is the wider ball's extrapolation from the hole's rim, ``read_across``) count
    as part of the patch here: a dent's core cut out of the scan is read from its shoulders
    and so under the band. Measured on the shell: a 1 mm dent whose core (its points within
    5.6 mm) was cut out leaves a 51 mm^2 patch with 0.15 mm (29 % of the half-band) around
    it, a conforming scan cut the same way 0.01 mm (2 %).
  Beside a drawing's own tolerances, qifreport's *default* band (no requirement of the
  drawing, a screen for gross errors on the faces it does not tolerance) takes the first gap
  rule as a warning only (``advisory_gaps``): it is judged where it was measured, and the
  drawing's tolerances keep every rule on their own surfaces.
* **Scan density** -- a region of the region criterion's area (``max_region_area``) must
  hold the :data:`~qifreport.metrology.acceptance.point_regions.DEFAULT_K` points of one
  point's median (:mod:`qifreport.metrology.acceptance.point_regions`), else a failing
  region of that size is not seen on the points: the surface's points per mm^2 of its
  scored area must reach ``DEFAULT_K / max_region_area`` (0.36 for 25 mm^2;
  :func:`min_scan_density`). Below it the surface is NOT MEASURED, "scan too sparse". The
  rule is stated by the drawing's region size, not by the scan's spacing. (Each vertex's
  own reading needs points within its ball, about 1.5 mesh edges: a vertex without them
  is unscored, and the coverage rule counts it.)
* **Excluded share** -- the bands left out by design are reported per zone; when they exceed
  :data:`MAX_EXCLUDED_SHARE` of a zone's area the zone's result says so in a warning (the
  coverage rule then decides: 70 % cannot be reached with more than 30 % excluded).

A zone that fails the coverage, gap or density rule is **NOT MEASURED**: its criteria are still
computed and reported on what was scored, but it neither passes nor fails on them, and a
part with a required zone not measured is never PASS (:mod:`qifreport.metrology.inspection`).

Areas are the barycentric vertex areas of the nominal restricted to the zone's triangles
(:func:`qifreport.metrology.acceptance.bands.zone_vertex_areas`), mm^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from qifreport.metrology.acceptance.point_regions import DEFAULT_K
from qifreport.metrology.acceptance.statistics import json_float
from qifreport.registration.mesh import adjacency, label_boundary_vertices

__all__ = [
    "DEFAULT_MIN_COVERAGE",
    "GAP_AREA_FACTOR",
    "HIDING_EXCESS",
    "MAX_EXCLUDED_SHARE",
    "Coverage",
    "min_scan_density",
    "plausible_uncertainty",
    "unmeasured_patches",
    "unseen_neighbour_edges",
    "zone_coverage",
]

#: least scored share of a toleranced surface's area for its tolerance to be measured
DEFAULT_MIN_COVERAGE = 0.70
#: the default largest unmeasured patch, in units of the region criterion's area
GAP_AREA_FACTOR = 4.0
#: the deviation around an unmeasured patch, in half-bands, beyond which the patch could
#: hide a failing region (the second gap rule)
HIDING_EXCESS = 0.25
#: share of a zone's area left out by design (crease and rim bands) above which the
#: result warns
MAX_EXCLUDED_SHARE = 0.30


@dataclass
class Coverage:
    """Whether one toleranced surface was measured.

    Attributes
    ----------
    area : the surface's area, mm^2.
    scored_area : area of its scored vertices, mm^2.
    excluded_area : area left unscored by design (crease and rim bands), mm^2.
    unmeasured_area : area neither scored nor excluded (the scan did not see it), mm^2.
    coverage : ``scored_area / area`` (NaN for an empty surface).
    min_coverage : the coverage rule's threshold (fraction).
    largest_gap_area : mm^2, the largest connected unmeasured patch (0 if none).
    largest_gap_centroid : (3,) its area-weighted centroid, mm, or None.
    max_gap_area : the gap rule's limit, mm^2.
    measured : every rule holds.
    reasons : one line per rule that failed (empty when measured).
    warnings : other notes (a large excluded share).
    density : the surface's scan points per mm^2 of its scored area (NaN: not counted).
    min_density : the density rule's least points per mm^2 (:func:`min_scan_density`).
    """

    area: float
    scored_area: float
    excluded_area: float
    unmeasured_area: float
    coverage: float
    min_coverage: float
    largest_gap_area: float
    max_gap_area: float
    largest_gap_centroid: np.ndarray | None = None
    measured: bool = False
    reasons: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    density: float = math.nan
    min_density: float = math.nan

    @property
    def excluded_share(self) -> float:
        return self.excluded_area / self.area if self.area > 0 else math.nan

    def to_dict(self) -> dict:
        c = self.largest_gap_centroid
        return {
            "measured": bool(self.measured),
            "area_mm2": json_float(self.area),
            "scored_area_mm2": json_float(self.scored_area),
            "excluded_area_mm2": json_float(self.excluded_area),
            "unmeasured_area_mm2": json_float(self.unmeasured_area),
            "coverage": json_float(self.coverage),
            "min_coverage": float(self.min_coverage),
            "excluded_share": json_float(self.excluded_share),
            "largest_gap_area_mm2": json_float(self.largest_gap_area),
            "largest_gap_centroid_mm": None if c is None else [float(x) for x in c],
            "max_gap_area_mm2": float(self.max_gap_area),
            "reasons": list(self.reasons),
            "warnings": list(self.warnings),
            "points_per_mm2": json_float(self.density),
            "min_points_per_mm2": json_float(self.min_density),
        }


def min_scan_density(max_region_area: float) -> float:
    """The least scan points per mm^2 a toleranced surface needs for its region criterion
    (module docstring): the :data:`DEFAULT_K` points of one point's median within one region
    of ``max_region_area`` mm^2."""
    return DEFAULT_K / float(max_region_area)


def unmeasured_patches(
    V: np.ndarray,
    F: np.ndarray,
    gap: np.ndarray,
    area: np.ndarray,
    adj: sp.csr_matrix | None = None,
) -> list[tuple[float, np.ndarray]]:
    """Connected patches of the vertices flagged ``gap`` over the edges of ``F``.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) triangles (the zone's).  gap : (n,) bool.
    area : (n,) vertex areas, mm^2.
    adj : the vertex adjacency of ``F`` (:func:`qifreport.registration.mesh.adjacency`), if
        the caller has it.

    Returns
    -------
    ``[(area_mm2, centroid (3,))]``, largest first.
    """
    idx = np.flatnonzero(gap)
    if len(idx) == 0:
        return []
    adj = adjacency(F, len(V)) if adj is None else adj
    sub = adj[idx][:, idx]
    _, label = connected_components(sub, directed=False)
    a = area[idx]
    tot = np.bincount(label, weights=a)
    cen = np.stack([np.bincount(label, weights=a * V[idx, k]) for k in range(3)], axis=1)
    out = []
    for k in np.argsort(-tot, kind="stable"):
        w = tot[k]
        c = cen[k] / w if w > 0 else V[idx[label == k]].mean(axis=0)
        out.append((float(w), c))
    return out


def zone_coverage(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    area: np.ndarray,
    excluded: np.ndarray,
    center=0.0,
    half_width=0.5,
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    max_region_area: float = 25.0,
    max_gap_area: float | None = None,
    advisory_gaps: bool = False,
    points: int | None = None,
    read_across: np.ndarray | None = None,
) -> Coverage:
    """The coverage, gap and density rules on one toleranced surface (module docstring).

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) the surface's triangles.
    dev : (n,) deviation, mm; NaN where unscored.
    area : (n,) vertex areas of the surface (0 off it), mm^2.
    excluded : (n,) bool, vertices left unscored by design (crease and rim bands).
    center, half_width : the band (scalars or (n,)), mm: in tolerance is
        ``|dev - center| <= half_width``.
    min_coverage : fraction in [0, 1].  max_region_area : the region criterion's limit, mm^2.
    max_gap_area : mm^2 (default ``GAP_AREA_FACTOR * max_region_area``).
    advisory_gaps : a patch larger than ``max_gap_area`` is a warning, not a reason: for a
        band that is no drawing requirement (qifreport's default band beside a drawing's
        tolerances), judged where it was measured. The coverage rule and the second gap
        rule (a patch that could hide a failing region) still decide.
    points : the scan points judging the surface (None: no density rule, e.g. a free state).
    read_across : (n,) bool, the scored vertices read across a hole in the scan (no point
        within the deviation's first ball): part of a patch for the second gap rule.

    Returns
    -------
    Coverage
    """
    n = len(V)
    if max_gap_area is None:
        max_gap_area = GAP_AREA_FACTOR * max_region_area
    c, h = (np.broadcast_to(np.asarray(x, dtype=np.float64), (n,)) for x in (center, half_width))
    on = area > 0
    scored = on & np.isfinite(dev)
    excl = on & ~scored & excluded
    gap = on & ~scored & ~excluded
    with np.errstate(invalid="ignore"):
        excess = np.where(scored, np.abs(dev - c) / h, 0.0)
    out = scored & (excess > 1.0)
    total, s_area, e_area, u_area = (float(area[x].sum()) for x in (on, scored, excl, gap))
    cov = s_area / total if total > 0 else math.nan
    adj = adjacency(F, n)
    patches = unmeasured_patches(V, F, gap, area, adj)
    g_area, g_cen = patches[0] if patches else (0.0, None)
    reasons = _coverage_rule(total, cov, e_area, min_coverage)
    hiding = gap if read_across is None else gap | (scored & read_across)
    limits = (max_gap_area, max_region_area)
    gap_reasons, warnings = _gap_rules(
        adj, V, (gap, hiding), out, excess, area, patches, limits, advisory_gaps
    )
    density = points / s_area if points is not None and s_area > 0 else math.nan
    reasons += gap_reasons + _density_rule(density, max_region_area)
    warnings += _excluded_share_warning(total, e_area)
    return Coverage(
        area=total,
        scored_area=s_area,
        excluded_area=e_area,
        unmeasured_area=u_area,
        coverage=cov,
        min_coverage=float(min_coverage),
        largest_gap_area=g_area,
        max_gap_area=float(max_gap_area),
        largest_gap_centroid=g_cen,
        measured=not reasons,
        reasons=reasons,
        warnings=warnings,
        density=density,
        min_density=min_scan_density(max_region_area),
    )


def _excluded_share_warning(total: float, e_area: float) -> list[str]:
    """The warning of a surface of ``total`` mm^2 with ``e_area`` mm^2 in the bands left
    unscored by design beyond :data:`MAX_EXCLUDED_SHARE`, or none."""
    if not (total > 0 and e_area / total > MAX_EXCLUDED_SHARE):
        return []
    return [
        f"{100 * e_area / total:.1f} % of the surface lies in the bands left unscored near "
        f"sharp creases and open rims (more than {100 * MAX_EXCLUDED_SHARE:.0f} %)"
    ]


def _density_rule(density: float, max_region_area: float) -> list[str]:
    """The density rule on a surface scanned at ``density`` points per mm^2 (NaN: not
    counted) with the region criterion's ``max_region_area``, mm^2: its reason, or none."""
    least = min_scan_density(max_region_area)
    if not density < least:
        return []
    return [
        f"scan too sparse: {density:.2f} points/mm^2 on the scored surface < {least:.2f} "
        f"(the {DEFAULT_K} points of one point's median within a {max_region_area:g} mm^2 "
        "region of the region criterion)"
    ]


def _coverage_rule(total: float, cov: float, e_area: float, min_coverage: float) -> list[str]:
    """The coverage rule on a surface of ``total`` mm^2 scored over the share ``cov``
    (``e_area`` mm^2 left out by design): its reason, or none."""
    if total > 0 and cov >= min_coverage * (1 - 1e-12):
        return []
    return [
        f"scored {100 * (cov if total > 0 else 0.0):.1f} % of the surface, below the "
        f"{100 * min_coverage:.0f} % needed to measure it"
        + (f" ({100 * e_area / total:.1f} % left out near creases and rims)" if e_area else "")
    ]


def _gap_rules(
    adj,
    V: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray],
    out: np.ndarray,
    excess: np.ndarray,
    area: np.ndarray,
    patches: list[tuple[float, np.ndarray]],
    limits: tuple[float, float],
    advisory_gaps: bool,
) -> tuple[list[str], list[str]]:
    """The two gap rules (module docstring) on the unmeasured ``patches`` (largest first)
    of a surface: its reasons and warnings. The largest patch beyond ``max_gap_area``, mm^2,
    is a reason (a warning with ``advisory_gaps``); else, or with ``advisory_gaps``, a patch
    that with the out-of-tolerance area it touches could hide a failing region
    (:func:`_hiding_patch`) is. ``gaps``: the unmeasured vertices, and those with the
    vertices read across a hole (the second rule's patches); ``limits``: ``max_gap_area``
    and ``max_region_area``, mm^2."""
    gap, hiding = gaps
    max_gap_area, max_region_area = limits
    g_area, g_cen = patches[0] if patches else (0.0, None)
    reasons: list[str] = []
    warnings: list[str] = []
    if g_area > max_gap_area:
        x, y, z = g_cen
        text = (
            f"an unmeasured patch of {g_area:.1f} mm^2 at ({x:.1f}, {y:.1f}, {z:.1f}) is larger "
            f"than the {max_gap_area:g} mm^2 allowed"
        )
        if advisory_gaps:
            warnings.append(f"{text} (a default band, no drawing requirement: reported only)")
        else:
            reasons.append(text)
    if g_area <= max_gap_area or advisory_gaps:
        hidden = _hiding_patch(adj, V, hiding, out, excess, area, max_region_area)
        if hidden is not None:
            a, cen, peak = hidden
            x, y, z = cen
            reasons.append(
                f"an unmeasured patch at ({x:.1f}, {y:.1f}, {z:.1f}) with the out-of-tolerance "
                f"area it touches covers {a:.1f} mm^2, more than the {max_region_area:g} mm^2 "
                f"of a failing region, and the deviation around it reaches {100 * peak:.0f} % "
                "of the half-band: it could hide one"
            )
    return reasons, warnings


def _hiding_patch(A, V, gap, out, excess, area, max_region_area):
    """The largest patch that could hide a failing region (second gap rule), as
    ``(area_mm2, centroid, peak_excess)``, or None.

    Components of ``gap | out`` over the vertex adjacency ``A`` that hold a gap vertex; each one's
    area (the patch, the out-of-tolerance vertices joined to it and the ring of vertices
    bordering it, which are read from one side of the hole) and the largest ``excess``
    (``|dev - centre| / half-width``) on it and on that ring.
    """
    sel = gap | out
    idx = np.flatnonzero(sel)
    if not gap.any():
        return None
    _, label = connected_components(A[idx][:, idx], directed=False)
    k = label.max() + 1
    tot = np.bincount(label, weights=area[idx], minlength=k)
    has_gap = np.bincount(label, weights=gap[idx].astype(float), minlength=k) > 0
    # bordering scored vertices: the neighbours of each component's vertices
    rows = A[idx].tocoo()
    ring = ~sel[rows.col]
    pairs = np.unique(np.stack([label[rows.row[ring]], rows.col[ring]]), axis=1)
    tot += np.bincount(pairs[0], weights=area[pairs[1]], minlength=k)
    nb_excess = excess[rows.col]
    peak = np.zeros(k)
    np.maximum.at(peak, label[rows.row], nb_excess)
    np.maximum.at(peak, label, excess[idx])
    bad = has_gap & (tot > max_region_area) & (peak > HIDING_EXCESS)
    if not bad.any():
        return None
    j = int(np.argmax(np.where(bad, tot, -1.0)))
    m = label == j
    w = area[idx][m]
    cen = (w[:, None] * V[idx][m]).sum(axis=0) / max(float(w.sum()), 1e-300)
    return float(tot[j]), cen, float(peak[j])


def unseen_neighbour_edges(F: np.ndarray, face_id: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices on a B-rep face boundary left unscored beside scored ones.

    The face-aware measure scores a vertex shared by several B-rep faces only when every one
    of them was seen
    (:func:`~qifreport.metrology.deviation.residual_fit.residual_referenced`): along the
    edge of a seen face with an unseen one its boundary vertices stay unscored, by design, not
    for want of data on the seen face. They count as excluded (as the crease band of a mesh
    nominal does), not as an unmeasured patch of the seen face; boundary vertices with no
    scored neighbour stay part of whatever unseen patch they lie in.

    Parameters
    ----------
    F : (f, 3) triangles.  face_id : (f,) B-rep face of each triangle.
    dev : (n,) deviation, mm, NaN where unscored.
    """
    n = len(dev)
    scored = np.isfinite(dev)
    beside = (adjacency(F, n) @ scored.astype(np.int64)) > 0
    return label_boundary_vertices(F, face_id, n) & ~scored & beside


def plausible_uncertainty(cov: Coverage, u_max: float, diagonal: float) -> Coverage:
    """``cov``, not measured when the surface's largest expanded uncertainty ``u_max`` (mm,
    :attr:`~qifreport.metrology.acceptance.criteria.Acceptance.uncertainty_mm`) is wider
    than the part's ``diagonal`` (mm): no deviation of the part's surface is larger than
    the part, so such a U is a fit extrapolated far beyond its points (a sparse scan), not
    a measurement; the reason names both numbers."""
    if not (math.isfinite(u_max) and u_max > diagonal):
        return cov
    why = (
        f"implausible uncertainty: U max {u_max:.4g} mm exceeds the part's {diagonal:.4g} mm "
        "diagonal (a fit extrapolated beyond its scan points)"
    )
    return replace(cov, measured=False, reasons=[*cov.reasons, why])
