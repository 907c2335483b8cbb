"""Repeatability over resamplings of the scan: which out-of-tolerance regions persist.

The paper (Section 9.2) recommends that "any part whose decision turns on a single region be
run under several resampling seeds, with only regions appearing in all runs treated as
findings". ``qifreport --seeds N`` (N >= 2) does this:

* **Runs.** The inspection of the full scan is the *reported* run. It is repeated on ``N``
  random resamplings of the scan, seed ``k = 0 .. N-1``: each scan point is kept
  independently with probability :data:`KEEP_FRACTION` (0.8; :func:`resample_mask`). The
  resampled runs start from the reported run's pose (the scan already moved into the nominal
  frame, no pose search): like the paper's replication study (Section 9.1: part, nominal,
  pose and parameters held fixed, only the resampling varied) they test the sensitivity of
  the fit and of the deviation to the sampling, not the pose search's choice of basin (a
  symmetric part could otherwise land in another basin and make a real defect look
  transient).
* **Persistence.** A region of the reported run is *persistent* when, in every resampled
  run, an out-of-tolerance region of the same surface (whole part, or the same tolerance
  zone) overlaps it with the same sign: some vertex of the region is out of tolerance in
  that run, on the same side of the band as in the reported run (:func:`region_hits`).
  Every out-of-tolerance vertex belongs to exactly one region of its run (singletons
  included), so "a vertex of the region is out on the same side in run k" and "a region of
  run k shares a same-signed vertex with it" are the same test. Signs are taken per vertex
  (``dev - centre``), not per region, so a dent with a raised rim whose peak flips sign
  between runs is still matched by its sunk and its proud parts.
* **Decision.** The region criterion of the whole part and of each tolerance zone is
  re-judged on the persistent regions only (:func:`restrict_acceptance`); the area
  criterion, the statistics and every other figure are the reported run's, unchanged. So
  ``--seeds`` can only remove findings of the region criterion: an area-criterion FAIL stays
  a FAIL. A resampled run whose own registration cannot be trusted (its
  ``trust_warnings``) adds a warning to the result, so a part that would pass only thanks to
  the resamplings is reported NOT ESTABLISHED, never PASS.
* **Spread.** The area-weighted deviation RMS and maximum |deviation| of every run (the
  reported one first) and their spread, taken as the paper does (Section 9.1: "about
  0.02 mm taken as the half-range") as the half-range ``(max - min) / 2`` over the
  ``N + 1`` runs, mm.

Why the full scan's run is the reported one (rather than seed 0's): the reported figures
then describe the whole measurement the QIF traceability names by its SHA-256, not 80 % of
it; the findings are a subset of what the default run reports (resampling can only drop a
region, never add one); and ``--seeds 1`` (the default) is exactly the run without
resampling. The price is one inspection more than ``N``.

The functions work on plain arrays (vertex indices, signed out-of-tolerance maps);
:func:`apply` is the glue that reads them from
:class:`qifreport.metrology.results.InspectionResult` objects (duck-typed, to keep this module
free of the inspection module).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from qifreport.metrology.acceptance.criteria import Acceptance, Region, region_reasons
from qifreport.metrology.acceptance.statistics import json_float

__all__ = [
    "KEEP_FRACTION",
    "WHOLE_PART",
    "apply",
    "DroppedRegion",
    "persistent_regions",
    "region_hits",
    "region_sign_map",
    "Repeatability",
    "resample_mask",
    "restrict_acceptance",
    "signed_out",
    "spread",
    "surface_persistence",
    "SurfacePersistence",
]

log = logging.getLogger(__name__)

#: probability with which each scan point is kept in a resampling
KEEP_FRACTION = 0.8
#: the surface key of the whole part (tolerance zones use their own keys)
WHOLE_PART = "part"


def resample_mask(m: int, seed: int, keep: float = KEEP_FRACTION) -> np.ndarray:
    """Points kept by resampling ``seed``: (m,) bool, each point kept with probability ``keep``.

    Deterministic: ``numpy.random.default_rng(seed)``, one uniform draw per point.
    """
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    return np.random.default_rng(int(seed)).random(int(m)) < keep


def signed_out(dev: np.ndarray, tolerance, center=0.0) -> np.ndarray:
    """Signed out-of-tolerance map of a deviation field.

    Parameters
    ----------
    dev : (n,) signed deviation, mm, NaN unscored.
    tolerance : scalar or (n,) band half-width, mm.  center : scalar or (n,) band centre, mm.

    Returns
    -------
    (n,) int8: +1 proud beyond the band (``dev - center > tolerance``), -1 sunk beyond it,
    0 inside the band or unscored -- the vertices
    :func:`qifreport.metrology.acceptance.criteria.find_regions` groups into regions.
    """
    d = np.asarray(dev, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    tol = np.asarray(tolerance, dtype=np.float64)
    out = np.zeros(d.shape, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        out[d > tol] = 1
        out[d < -tol] = -1
    return out


def region_sign_map(n: int, regions: Sequence[Region]) -> np.ndarray:
    """(n,) int8 map with each region's vertices set to its (peak) sign, 0 elsewhere: the
    coarser stand-in for :func:`signed_out` when a surface's deviation is not at hand."""
    out = np.zeros(int(n), dtype=np.int8)
    for r in regions:
        out[np.asarray(r.vertices, dtype=np.int64)] = np.int8(r.sign)
    return out


def region_hits(
    regions: Sequence[np.ndarray], ref: np.ndarray, runs: Sequence[np.ndarray]
) -> np.ndarray:
    """Which resampled runs find each region of the reported run.

    Parameters
    ----------
    regions : the reported run's regions, each a (k_i,) array of vertex indices.
    ref : (n,) int8 signed out-of-tolerance map of the reported run (:func:`signed_out`).
    runs : one (n,) int8 signed map per resampled run (same nominal vertices).

    Returns
    -------
    (len(regions), len(runs)) bool: ``hits[i, k]`` when some vertex ``v`` of region ``i`` is
    out of tolerance in run ``k`` on the same side as in the reported run
    (``runs[k][v] == ref[v] != 0``).
    """
    ref = np.asarray(ref)
    hits = np.zeros((len(regions), len(runs)), dtype=bool)
    for i, verts in enumerate(regions):
        v = np.asarray(verts, dtype=np.int64)
        s = ref[v]
        v, s = v[s != 0], s[s != 0]
        for k, run in enumerate(runs):
            hits[i, k] = bool(np.any(np.asarray(run)[v] == s))
    return hits


def persistent_regions(
    regions: Sequence[np.ndarray], ref: np.ndarray, runs: Sequence[np.ndarray]
) -> np.ndarray:
    """(len(regions),) bool: the region is found in every run (:func:`region_hits`); with no
    run every region persists."""
    return region_hits(regions, ref, runs).all(axis=1)


def spread(values) -> float:
    """Half-range ``(max - min) / 2`` of the finite values (mm; the paper's spread, Section
    9.1), NaN when there are none."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(0.5 * (x.max() - x.min())) if len(x) else math.nan


def restrict_acceptance(acc: Acceptance, keep: np.ndarray) -> Acceptance:
    """The acceptance re-judged on the regions ``acc.regions[keep]`` only.

    The region criterion (largest region, ``region_ok``) and ``passed`` are recomputed and the
    region reasons rewritten; the area criterion, coverage and every other field are kept, so
    a part failing the area criterion still fails. Under a decision rule the persistent
    regions decide too: passing on them proves conformance, and non-conformance stays proven
    only when they fail.

    Parameters
    ----------
    acc : the acceptance of the reported run.  keep : (len(acc.regions),) bool.
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.shape != (len(acc.regions),):
        raise ValueError(f"keep must have shape ({len(acc.regions)},), got {keep.shape}")
    regions = [r for r, k in zip(acc.regions, keep, strict=True) if k]
    largest = regions[0].area if regions else 0.0  # still largest first
    region_ok = bool(largest <= acc.max_region_area)
    passed = bool(acc.area_ok and region_ok and acc.scored_area > 0)
    reasons = [
        s for s in acc.reasons if not (s.startswith("region of ") or s.startswith("... and "))
    ]
    reasons += region_reasons(regions, acc.max_region_area)
    return replace(
        acc,
        regions=regions,
        largest_region_area=float(largest),
        region_ok=region_ok,
        passed=passed,
        reasons=reasons,
        # the persistence of the regions stands in for the guard band on them: a region
        # that does not persist proves nothing, and the persistent ones decide
        proven_in=None if acc.proven_in is None else bool(acc.proven_in or passed),
        proven_out=None if acc.proven_out is None else bool(acc.proven_out and not passed),
        uncertain_reasons=[] if passed else list(acc.uncertain_reasons),
    )


@dataclass
class DroppedRegion:
    """A region of the reported run not found in every resampled run (not a finding).

    Attributes
    ----------
    area : mm^2.  peak : signed peak deviation, mm.  sign : +1 proud, -1 sunk.
    centroid : (3,) mm, nominal frame.  runs_found : resampled runs that found it.
    """

    area: float
    peak: float
    sign: int
    centroid: np.ndarray
    runs_found: int

    def to_dict(self) -> dict:
        return {
            "area": json_float(self.area),
            "peak": json_float(self.peak),
            "sign": int(self.sign),
            "centroid": [float(c) for c in self.centroid],
            "runs_found": int(self.runs_found),
        }


@dataclass
class SurfacePersistence:
    """Persistence of the regions of one surface (the whole part or one tolerance zone).

    Attributes
    ----------
    key : :data:`WHOLE_PART` or the zone's key.
    runs_found : (m,) int, resampled runs that found each region of the reported run.
    persistent : (m,) bool, found in every run.
    dropped : the regions that are not persistent, largest first.
    """

    key: str
    runs_found: np.ndarray
    persistent: np.ndarray
    dropped: list[DroppedRegion] = field(default_factory=list)

    @property
    def n_regions(self) -> int:
        return int(len(self.persistent))

    @property
    def n_persistent(self) -> int:
        return int(np.count_nonzero(self.persistent))

    def to_dict(self) -> dict:
        return {
            "key": self.key,
            "regions": self.n_regions,
            "persistent": self.n_persistent,
            "dropped": [d.to_dict() for d in self.dropped],
        }


def surface_persistence(
    key: str, acc: Acceptance, ref: np.ndarray, runs: Sequence[np.ndarray]
) -> SurfacePersistence:
    """Persistence of the regions of ``acc`` (the reported run's) against the signed maps
    ``runs`` of the resampled runs (:func:`region_hits`)."""
    hits = region_hits([r.vertices for r in acc.regions], ref, runs)
    found = hits.sum(axis=1).astype(np.int64)
    keep = hits.all(axis=1)
    dropped = [
        DroppedRegion(
            area=r.area,
            peak=r.peak,
            sign=r.sign,
            centroid=np.asarray(r.centroid, dtype=float),
            runs_found=int(f),
        )
        for r, f, k in zip(acc.regions, found, keep, strict=True)
        if not k
    ]
    return SurfacePersistence(key=key, runs_found=found, persistent=keep, dropped=dropped)


@dataclass
class Repeatability:
    """The resampling study of one inspection (``qifreport --seeds N``).

    Attributes
    ----------
    seeds : resampled runs ``N`` (seeds 0 .. N-1).
    keep_fraction : probability of keeping each scan point.
    surfaces : persistence of the whole part's regions (first) and of each zone's.
    rms, max_abs : (N + 1,) area-weighted deviation RMS and max |deviation| of each run, mm,
        the reported (full-scan) run first.
    warnings : trust warnings of the resampled runs, one line each.
    seconds : wall time of the resampled runs.
    """

    seeds: int
    keep_fraction: float
    surfaces: list[SurfacePersistence]
    rms: np.ndarray
    max_abs: np.ndarray
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def part(self) -> SurfacePersistence:
        """The whole part's persistence."""
        return self.surfaces[0]

    @property
    def n_regions(self) -> int:
        """Out-of-tolerance regions of the whole part in the reported run."""
        return self.part.n_regions

    @property
    def n_persistent(self) -> int:
        """Of those, the regions found in every resampled run (the findings)."""
        return self.part.n_persistent

    @property
    def rms_spread(self) -> float:
        """Spread (half-range) of the deviation RMS over the runs, mm."""
        return spread(self.rms)

    @property
    def max_spread(self) -> float:
        """Spread (half-range) of the maximum |deviation| over the runs, mm."""
        return spread(self.max_abs)

    def describe(self) -> str:
        """One line: ``Repeatability over N resamplings: regions persistent k of m; ...``."""
        pct = f"{100 * self.keep_fraction:g} %"
        zones = sum(len(s.dropped) for s in self.surfaces[1:])
        tail = f"; {zones} zone region(s) not persistent" if zones else ""
        return (
            f"Repeatability over {self.seeds} resamplings ({pct} of the scan points each): "
            f"regions persistent {self.n_persistent} of {self.n_regions}; RMS spread "
            f"+/-{self.rms_spread:.4f} mm, max spread +/-{self.max_spread:.4f} mm "
            f"(half-ranges over {self.seeds + 1} runs){tail}"
        )

    def to_dict(self) -> dict:
        """JSON-ready dict (the summary's ``repeatability`` object)."""
        return {
            "seeds": int(self.seeds),
            "keep_fraction": float(self.keep_fraction),
            "reported_run": "full scan",
            "regions": self.n_regions,
            "persistent_regions": self.n_persistent,
            "rms_mm": [json_float(x) for x in self.rms],
            "max_abs_mm": [json_float(x) for x in self.max_abs],
            "rms_spread_mm": json_float(self.rms_spread),
            "max_spread_mm": json_float(self.max_spread),
            "surfaces": [s.to_dict() for s in self.surfaces],
            "warnings": list(self.warnings),
            "seconds": float(self.seconds),
        }


def _surface_map(dev, tolerance, center, acc: Acceptance, n: int) -> np.ndarray:
    """Signed out-of-tolerance map of one surface of one run (region signs as fallback)."""
    if dev is None:
        return region_sign_map(n, acc.regions)
    return signed_out(dev, tolerance, center)


def apply(
    res: Any, runs: Sequence[Any], keep_fraction: float = KEEP_FRACTION, seconds: float = 0.0
) -> Repeatability:
    """Judge the reported result ``res`` on its persistent regions only, in place.

    Parameters
    ----------
    res : the reported run (:class:`qifreport.metrology.results.InspectionResult` of the full
        scan). Its ``acceptance`` and each zone's ``acceptance`` are replaced by
        :func:`restrict_acceptance` of their persistent regions, and ``res.repeatability`` is set
        (so its trust warnings include the resampled runs').
    runs : the resampled runs' results, seed 0 first (same nominal and zones).
    keep_fraction : the resampling's keep probability (reported).
    seconds : wall time of the resampled runs (reported).

    Returns
    -------
    :class:`Repeatability`, also stored as ``res.repeatability``.
    """
    n = len(res.V)

    def part_map(r) -> np.ndarray:
        b = r.bands
        if b is None:
            return region_sign_map(n, r.acceptance.regions)
        return signed_out(r.deviation, b.half_width, b.center)

    surfaces = [
        surface_persistence(WHOLE_PART, res.acceptance, part_map(res), [part_map(r) for r in runs])
    ]
    new_part = restrict_acceptance(res.acceptance, surfaces[0].persistent)
    for z in res.zones:
        key = z.zone.key
        ref = _surface_map(z.deviation, z.zone.half_width, z.zone.center, z.acceptance, n)
        maps = []
        for r in runs:
            rz = next((q for q in r.zones if q.zone.key == key), None)
            maps.append(
                np.zeros(n, dtype=np.int8)
                if rz is None
                else _surface_map(
                    rz.deviation, rz.zone.half_width, rz.zone.center, rz.acceptance, n
                )
            )
        sp = surface_persistence(key, z.acceptance, ref, maps)
        surfaces.append(sp)
        z.acceptance = restrict_acceptance(z.acceptance, sp.persistent)
    res.acceptance = new_part
    warnings = [f"resampling seed {k}: {w}" for k, r in enumerate(runs) for w in r.trust_warnings()]
    rep = Repeatability(
        seeds=len(runs),
        keep_fraction=float(keep_fraction),
        surfaces=surfaces,
        rms=np.array([res.vertex_stats.rms] + [r.vertex_stats.rms for r in runs], dtype=float),
        max_abs=np.array(
            [res.vertex_stats.max_abs] + [r.vertex_stats.max_abs for r in runs], dtype=float
        ),
        warnings=warnings,
        seconds=float(seconds),
    )
    for s in surfaces:
        for d in s.dropped:
            log.info(
                "%s: region of %.1f mm^2 (peak %+.3f mm) found in %d of %d resamplings: "
                "not a finding",
                s.key,
                d.area,
                d.peak,
                d.runs_found,
                len(runs),
            )
    res.repeatability = rep
    return rep
