"""The region criterion on the scan points: defects smaller than the nominal's mesh.

The deviation field of :mod:`qifreport.metrology.deviation.residual_fit` lives on the
nominal's vertices, each fitted to the scan points within about 1.5 mesh edges. A defect
narrower than that ball is averaged away: on NIST CTC 01 (4 mm edges, a 6 mm ball) a 0.5 mm
bump of sigma 3 mm read 0.19 mm against a +/-0.25 mm zone and PASSed, although 39 mm^2 of
the face stood more than 0.25 mm proud, beyond the 25 mm^2 region limit. A profile tolerance
bounds every point of the surface, so the region criterion is also judged where the scan
samples the surface more finely than the mesh: on the scan points themselves.

Each point's value is the median of the signed surface distances (+ outside the material)
of its ``k`` nearest points on the same B-rep face (noise falls to about 0.42 sigma for
``k = 9``, a burr of one point does not count), its expanded uncertainty ``U`` that of such
a median (``2 sqrt(pi / 2) s / sqrt(k)``, ``s`` the robust scatter of the face's points
about their medians), combined in quadrature with a scanner's stated uncertainty. A
point counts for a surface only where the nominal vertex nearest to it is scored there:
the crease and rim bands, and whatever the vertex measure leaves unscored, are left out
on the points too. Out-of-tolerance points closer than ``link`` point spacings form a
region, its area the sum of its points' areas from the local point density, as
:mod:`qifreport.metrology.acceptance.added` does for proud material.

A surface's points are thousands of simultaneous measurements, and neighbouring medians
share their points: with the k = 2 band of one measurement (2.3 % one-sided), a face on its
zone limit showed clusters of 10 chance exceedances (150 mm^2 on NIST CTC 02's T2 at 3.6 mm
spacing). A region is therefore *proven* out of (or into) the zone on the points with the
coverage factor :data:`qifreport.metrology.acceptance.decision.PROOF_COVERAGE` = 4 (3e-5 one-sided
per
point), as on the vertices: none then on CTC 02's on-limit faces, while a 0.5 mm defect
against a 0.25 mm zone is proven with a margin of twenty such ``U`` at 10 um noise.

A point that disagrees with its neighbourhood's median by more than :data:`SPIKE_SIGMAS`
times the face's robust scatter (and :data:`SPIKE_FLOOR` mm), with fewer than
:data:`MIN_SPIKE_PATCH` such points linked within :data:`LINK` spacings, is a **spike**: a
stray point closer to the surface than the scan's own outlier model reaches
(:mod:`qifreport.registration.outliers`), or a single-point burr. It judges nothing (a
feature's form read on the points would take its height whole); a defect, seen by several
points together, is kept.

Each region is returned as a :class:`qifreport.metrology.acceptance.criteria.Region` on the nominal
vertices nearest to its points (for the views and the repeatability map), with the
points' own area, peak, peak location and centroid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.decision import PROOF_COVERAGE
from qifreport.registration.arrays import unique_sorted
from qifreport.registration.nearest import workers_for
from qifreport.registration.scan import median_spacing

__all__ = ["ScanSamples", "SurfacePoints", "linked_groups", "point_areas", "scan_samples"]

#: neighbours in each point's median
DEFAULT_K = 9
#: two out-of-tolerance points belong to one region when closer than this many spacings
LINK = 3.0
#: a point this many robust scatters of its face from its neighbourhood's median is a spike
#: candidate (module docstring)
SPIKE_SIGMAS = 6.0
#: and at least this far from it, mm (an exact scan's scatter is a few micrometres)
SPIKE_FLOOR = 0.02
#: the fewest candidates linked within :data:`LINK` spacings that are material, not spikes
MIN_SPIKE_PATCH = 4


@dataclass
class ScanSamples:
    """The scan points as a second sampling of the nominal surface (mm, mm^2).

    Attributes
    ----------
    P : (m, 3) points in the nominal frame.
    value : (m,) median signed surface distance of each point's neighbourhood (NaN: none).
    U : (m,) its expanded uncertainty (k = 2).
    vertex : (m,) the nominal vertex nearest to each point's closest point (-1: none).
    spacing : the scan's median point spacing.
    tree : a k-d tree of ``P`` (the points' areas, the added-material pass).
    spike : (m,) bool, the points that disagree alone with their neighbourhood (module
        docstring): they judge nothing.
    """

    P: np.ndarray
    value: np.ndarray
    U: np.ndarray
    vertex: np.ndarray
    spacing: float
    tree: cKDTree
    spike: np.ndarray
    _area: np.ndarray | None = None
    #: the links of the last point set grouped: (distance, its points, the pairs as
    #: positions in it, each scan point's position in it or -1)
    _links: tuple | None = None

    def area(self, idx: np.ndarray) -> np.ndarray:
        """(len(idx),) area of the points ``idx``, mm^2 (:func:`point_areas`), each
        computed once."""
        if self._area is None:
            self._area = np.full(len(self.P), np.nan)
        todo = idx[np.isnan(self._area[idx])]
        if len(todo):
            self._area[todo] = point_areas(self.tree, self.P[todo], self.spacing)
        return self._area[idx]

    def groups(self, sel: np.ndarray, distance: float) -> np.ndarray:
        """(len(sel),) the connected group of each point ``sel`` (distinct indices of
        ``P``): :func:`linked_groups` of ``P[sel]``. The region criterion groups nested
        sets of points (the band reduced, as measured, enlarged); the pairs of a set found
        before are reused for its subsets (the graph they induce is the same, and so are
        the groups and their numbers)."""
        sel = np.asarray(sel, dtype=np.int64)
        if self._links is not None and self._links[0] == distance:
            _, members, a, b, where = self._links
            pos = where[sel]
            if (pos >= 0).all():
                local = np.full(len(members), -1, dtype=np.int64)
                local[pos] = np.arange(len(sel))
                a, b = local[a], local[b]
                keep = (a >= 0) & (b >= 0)
                return _components(len(sel), a[keep], b[keep])
        pairs = cKDTree(self.P[sel]).query_pairs(distance, output_type="ndarray")
        where = np.full(len(self.P), -1, dtype=np.int64)
        where[sel] = np.arange(len(sel))
        self._links = (distance, sel, pairs[:, 0], pairs[:, 1], where)
        return _components(len(sel), pairs[:, 0], pairs[:, 1])


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) the connected component of each of ``n`` nodes joined by the pairs ``(a, b)``."""
    G = sp.coo_matrix((np.ones(len(a)), (a, b)), (n, n))
    return connected_components(G, directed=False)[1]


def point_areas(tree: cKDTree, Q: np.ndarray, spacing: float) -> np.ndarray:
    """(q,) the area, mm^2, each point of ``Q`` (q, 3) stands for: a disk of 2.5 ``spacing``
    (mm) shared among the scan points of ``tree`` in it (a grazing strip and an overlap of
    two views are not sampled like the scan on average)."""
    r = 2.5 * spacing
    n = tree.query_ball_point(Q, r, return_length=True, workers=-1)
    return np.pi * r * r / np.maximum(n, 1)


def linked_groups(Q: np.ndarray, distance: float) -> np.ndarray:
    """(q,) the connected group of each point of ``Q`` (q, 3): points closer than
    ``distance`` (mm) are linked."""
    pairs = cKDTree(Q).query_pairs(distance, output_type="ndarray")
    return _components(len(Q), pairs[:, 0], pairs[:, 1])


@dataclass
class SurfacePoints:
    """The scan points of one judged surface and their band.

    Attributes
    ----------
    samples : the inspection's :class:`ScanSamples`.
    index : (k,) the points of the surface.
    tolerance : (k,) half-width of each point's band, mm.  center : (k,) its centre, mm.
    extra_U : (k,) an expanded uncertainty of where the band lies (a datum frame's), mm,
        combined in quadrature with the points' own; 0 without.
    """

    samples: ScanSamples
    index: np.ndarray
    tolerance: np.ndarray
    center: np.ndarray
    extra_U: np.ndarray | float = 0.0

    def regions(self, widen: float, region_type) -> list:
        """Connected regions of points out of the band widened by ``widen`` x their
        expanded uncertainty at :data:`PROOF_COVERAGE` (0: the measured values; -1: the
        band reduced, for proving conformance; +1: enlarged, for proving non-conformance),
        as ``region_type`` (the acceptance's ``Region``), largest first."""
        s = self.samples
        idx = self.index
        val = s.value[idx]
        k = 0.5 * PROOF_COVERAGE * widen
        tol = np.maximum(self.tolerance + k * np.hypot(s.U[idx], self.extra_U), 0.0)
        with np.errstate(invalid="ignore"):
            out = np.abs(val - self.center) > tol
        sel = idx[out]
        if len(sel) == 0:
            return []
        Q = s.P[sel]
        label = s.groups(sel, LINK * s.spacing)
        a = s.area(sel)
        d = val[out]
        c = self.center[out]
        regions = []
        order = np.argsort(label, kind="stable")
        starts = np.flatnonzero(np.r_[True, np.diff(label[order]) != 0])
        for members in np.split(order, starts[1:]):
            am = a[members]
            total = float(am.sum())
            j = members[int(np.argmax(np.abs(d[members] - c[members])))]
            verts = unique_sorted(s.vertex[sel[members]])
            regions.append(
                region_type(
                    vertices=verts[verts >= 0].astype(np.int64),
                    area=total,
                    peak=float(d[j]),
                    peak_vertex=int(s.vertex[sel[j]]),
                    centroid=(am[:, None] * Q[members]).sum(axis=0) / max(total, 1e-300),
                    sign=1 if d[j] > 0 else -1,
                    peak_location=Q[j].copy(),
                    sampling="scan points",
                )
            )
        regions.sort(key=lambda r: (-r.area, -abs(r.peak)))
        return regions


def scan_samples(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    residual: np.ndarray,
    C: np.ndarray,
    cface: np.ndarray,
    point_label: np.ndarray | None,
    *,
    k: int = DEFAULT_K,
    systematic: float | np.ndarray = 0.0,
    tree: cKDTree | None = None,
) -> ScanSamples:
    """The scan points' local values and uncertainties (:class:`ScanSamples`).

    Parameters
    ----------
    V : (n, 3) registered nominal, mm.  F : (f, 3).  P : (m, 3) scan points, mm.
    residual : (m,) signed distance of each point to the nominal surface, mm (NaN: none).
    C : (m, 3) closest points on the nominal, mm.  cface : (m,) their triangles (-1: none).
    point_label : (m,) B-rep face of each point (-1: none); None: one surface (a mesh
        nominal).
    k : points in each median.
    systematic : a scanner's stated expanded uncertainty, mm, added in quadrature (or one
        per point (m,): a restrained hold's model uncertainty besides).
    tree : ``cKDTree(P)`` when at hand (kept as the samples' tree).
    """
    P = np.asarray(P, dtype=np.float64)
    r = np.asarray(residual, dtype=np.float64)
    cface = np.asarray(cface, dtype=np.int64)
    m = len(P)
    label = np.zeros(m, dtype=np.int64) if point_label is None else np.asarray(point_label)
    ok = (cface >= 0) & np.isfinite(r) & (label >= 0)
    value = np.full(m, np.nan)
    var = np.full(m, np.nan)
    # the nearest corner of each point's closest triangle
    vertex = np.full(m, -1, dtype=np.int64)
    t = F[np.maximum(cface, 0)]
    d2 = ((V[t] - C[:, None, :]) ** 2).sum(axis=2)
    vertex[ok] = t[ok, np.argmin(d2[ok], axis=1)]
    candidate = np.zeros(m, dtype=bool)
    order = np.argsort(label[ok], kind="stable")
    ids = np.flatnonzero(ok)[order]
    lab = label[ids]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]]) if len(ids) else np.empty(0, int)
    for group in np.split(ids, starts[1:]) if len(ids) else []:
        kk = min(int(k), len(group))
        if kk < 3:
            continue
        _, nb = cKDTree(P[group]).query(P[group], k=kk, workers=workers_for(len(group)))
        med = np.median(r[group][nb], axis=1)
        s = 1.4826 * np.median(np.abs(r[group] - med)) * np.sqrt(kk / (kk - 1.0))
        value[group] = med
        var[group] = 0.5 * np.pi * s * s / kk
        candidate[group] = np.abs(r[group] - med) > max(SPIKE_SIGMAS * s, SPIKE_FLOOR)
    tree = cKDTree(P) if tree is None else tree
    spacing = max(median_spacing(P, tree, probes=5000) if m > 1 else 0.0, 1e-9)
    U = np.sqrt(4.0 * var + np.asarray(systematic, dtype=np.float64) ** 2)
    spike = np.zeros(m, dtype=bool)
    cand = np.flatnonzero(candidate)
    if len(cand):
        groups = linked_groups(P[cand], LINK * spacing)
        spike[cand] = np.bincount(groups)[groups] < MIN_SPIKE_PATCH
    return ScanSamples(
        P=P, value=value, U=U, vertex=vertex, spacing=spacing, tree=tree, spike=spike
    )
