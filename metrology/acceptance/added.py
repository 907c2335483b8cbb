"""Added material: what the data-referenced pass sees and a profile check cannot (paper
Sections 8.4.5 and 11).

A feature standing proud of the surface (a boss, a rib, flash) occupies space the nominal does
not model: no nominal vertex points at it and no nominal normal passes through it, so the
nominal-referenced deviation (one value per nominal vertex) barely moves -- on the paper's
engine cover 3075 mm^2 of added material changed its RMS from 0.1979 to 0.1970 mm. The
*data-referenced* deviation (one value per scan point: its signed distance along the normal
of the registered nominal, + = outside the material) carries it in its upper tail: the
99.9th signed percentile moved 5x and the share beyond +5 mm 9.6x (Table 4), while the
negative tail, the control, did not move.

This module turns that tail into a finding: the scan points beyond ``+threshold``, grouped
into connected regions *of the scan* (points closer than a few scan spacings), each with an
area (the sum of its points' areas, each from the local point density within 2.5 median
spacings), peak and centroid. The part can be failed on
them (``fail_on`` in :func:`added_material`), otherwise they are reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.point_regions import linked_groups, point_areas
from qifreport.metrology.acceptance.statistics import json_float
from qifreport.registration.scan import median_spacing

__all__ = [
    "LINK",
    "added_material",
    "AddedMaterial",
    "AddedRegion",
    "attached_to_surface",
]

#: two points are linked when closer than this many median scan spacings
LINK = 3.0


@dataclass
class AddedRegion:
    """A connected group of scan points standing proud of the registered nominal.

    Attributes
    ----------
    n_points : scan points in the region.  area : estimated area, mm^2.
    peak : largest signed deviation, mm.  centroid : (3,) mean position, mm (nominal frame).
    """

    n_points: int
    area: float
    peak: float
    centroid: np.ndarray

    def to_dict(self) -> dict:
        return {
            "n_points": int(self.n_points),
            "area": float(self.area),
            "peak": float(self.peak),
            "centroid": [float(c) for c in self.centroid],
        }


@dataclass
class AddedMaterial:
    """The data-referenced pass over the scan (mm, mm^2).

    Attributes
    ----------
    threshold : the stated threshold, mm (the whole-part tail threshold).
    mean_signed : mean signed data-referenced deviation, mm.
    p99_signed, p999_signed : 99th / 99.9th percentiles of the *signed* deviation, mm.
    max_signed, min_signed : extremes, mm.
    frac_above, frac_below : shares of scan points beyond ``+threshold`` / ``-threshold``.
    area_per_point : scan area / scored scan points, mm^2 (the scan's average; region areas
        use the local density).
    max_region_area : the limit a region is judged against, mm^2.
    fail_on : whether a region above the limit fails the part.
    regions : the regions beyond ``+threshold``, largest first.
    """

    threshold: float
    mean_signed: float
    p99_signed: float
    p999_signed: float
    max_signed: float
    min_signed: float
    frac_above: float
    frac_below: float
    area_per_point: float
    max_region_area: float
    fail_on: bool
    regions: list[AddedRegion] = field(default_factory=list)

    @property
    def largest_area(self) -> float:
        return self.regions[0].area if self.regions else 0.0

    @property
    def found(self) -> bool:
        """A region larger than ``max_region_area`` stands proud of the nominal."""
        return self.largest_area > self.max_region_area

    @property
    def passed(self) -> bool:
        return not (self.fail_on and self.found)

    def describe(self) -> str:
        """One line for the report."""
        if not self.regions:
            return f"no scan region beyond +{self.threshold:g} mm"
        r = self.regions[0]
        c = r.centroid
        return (
            f"{len(self.regions)} scan region(s) beyond +{self.threshold:g} mm; largest "
            f"{r.area:.1f} mm^2 (limit {self.max_region_area:g}), peak {r.peak:+.3f} mm at "
            f"({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f})"
        )

    def to_dict(self) -> dict:
        return {
            "threshold_mm": json_float(self.threshold),
            "mean_signed_mm": json_float(self.mean_signed),
            "p99_signed_mm": json_float(self.p99_signed),
            "p999_signed_mm": json_float(self.p999_signed),
            "max_signed_mm": json_float(self.max_signed),
            "min_signed_mm": json_float(self.min_signed),
            "frac_above": json_float(self.frac_above),
            "frac_below": json_float(self.frac_below),
            "area_per_point_mm2": json_float(self.area_per_point),
            "max_region_area_mm2": json_float(self.max_region_area),
            "fail_on": bool(self.fail_on),
            "found": bool(self.found),
            "passed": bool(self.passed),
            "n_regions": len(self.regions),
            "regions": [r.to_dict() for r in self.regions[:50]],
        }


def added_material(
    P: np.ndarray,
    dev: np.ndarray,
    threshold: float,
    scan_area: float,
    max_region_area: float,
    *,
    fail_on: bool = False,
    link: float = LINK,
    tree: cKDTree | None = None,
) -> AddedMaterial:
    """Tail statistics and proud regions of the data-referenced deviation.

    Parameters
    ----------
    P : (m, 3) scan points in the nominal frame, mm.
    dev : (m,) signed data-referenced deviation, mm (+ outside the material; NaN unscored).
    threshold : mm; points with ``dev > threshold`` are proud.
    scan_area : estimated area the scan covers, mm^2 (for the area per point).
    max_region_area : mm^2, the region limit (the product's region criterion).
    fail_on : a region above the limit fails the part.
    link : two proud points are connected when closer than ``link`` times the median
        nearest-neighbour spacing of the scan.
    tree : optional ``cKDTree(P)``.

    Returns
    -------
    AddedMaterial
    """
    P = np.asarray(P, dtype=float)
    dev = np.asarray(dev, dtype=float)
    ok = np.isfinite(dev)
    d = dev[ok]
    m = len(P)
    area_per_point = float(scan_area) / max(int(ok.sum()), 1)
    nan = float("nan")
    out = AddedMaterial(
        threshold=float(threshold),
        mean_signed=float(d.mean()) if len(d) else nan,
        p99_signed=float(np.percentile(d, 99.0)) if len(d) else nan,
        p999_signed=float(np.percentile(d, 99.9)) if len(d) else nan,
        max_signed=float(d.max()) if len(d) else nan,
        min_signed=float(d.min()) if len(d) else nan,
        frac_above=float(np.mean(d > threshold)) if len(d) else nan,
        frac_below=float(np.mean(d < -threshold)) if len(d) else nan,
        area_per_point=area_per_point,
        max_region_area=float(max_region_area),
        fail_on=bool(fail_on),
    )
    proud = np.flatnonzero(ok & (dev > threshold))
    if len(proud) == 0 or m < 2:
        return out
    tree = tree or cKDTree(P)
    spacing = max(median_spacing(P, tree, probes=5000), 1e-12)
    Q = P[proud]
    # each proud point's area from the local density (a rib, an overlap of two views and a
    # sparse grazing strip are not sampled like the scan on average)
    a_local = point_areas(tree, Q, spacing)
    labels = linked_groups(Q, link * spacing)
    regions = []
    for k in np.unique(labels):
        members = np.flatnonzero(labels == k)
        dk = dev[proud[members]]
        regions.append(
            AddedRegion(
                n_points=len(members),
                area=float(a_local[members].sum()),
                peak=float(dk.max()),
                centroid=Q[members].mean(axis=0),
            )
        )
    out.regions = sorted(regions, key=lambda r: -r.area)
    return out


def attached_to_surface(
    P: np.ndarray, proud: np.ndarray, surface: np.ndarray, spacing: float
) -> np.ndarray:
    """(m,) bool: the proud points that are the part's own material, continuous with its
    surface: each connected group of ``proud`` points (linked within :data:`LINK` scan
    spacings) with a ``surface`` point within that distance of one of its points. A
    group standing apart (an object in the scan that does not touch the part) is not.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  proud, surface : (m,) bool, disjoint.
    spacing : the scan's median point spacing, mm.
    """
    out = np.zeros(len(P), dtype=bool)
    idx = np.flatnonzero(proud)
    if len(idx) == 0 or not surface.any():
        return out
    link = LINK * spacing
    labels = linked_groups(P[idx], link)
    # the nearest surface point of each proud point, if one lies within the link
    d, _ = cKDTree(P[surface]).query(P[idx], distance_upper_bound=link, workers=-1)
    touches = np.isfinite(d)
    out[idx] = np.isin(labels, np.unique(labels[touches]))
    return out
