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
  failing region from a passing one: a failing region of the limit's size reads as
  ``A x read share``, and a surface whose largest region reads at least that is not proven
  in (NOT ESTABLISHED, like a reading within its uncertainty, ISO 14253-1).
* **Below detection.** A surface on which the critical dent reads no region at all has a
  region criterion below what this scan and mesh detect: it is not proven in (NOT
  ESTABLISHED, never PASS), the reason stated in every output. The scan points read a
  dent of the limit's size where the scan is dense enough; a sparse scan, or a fixture
  that absorbs the dent, leaves it unread.
* **The detectable dent** stated per surface: the shallowest dent of width ``sigma_A``
  read beyond the band, ``(t + U) / g`` (``g`` the read share of its peak, ``U`` the
  surface's median expanded uncertainty).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.criteria import Acceptance
from qifreport.metrology.acceptance.point_regions import DEFAULT_K, point_areas
from qifreport.metrology.acceptance.statistics import json_float
from qifreport.metrology.deviation.residual_fit import ResidualReader, ball_radius
from qifreport.registration.arrays import LabelIndex, unique_sorted
from qifreport.registration.deformable.gbcicp import MASS_REGULARISATION, holdout
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import MeshOperators, median_edge_length
from qifreport.registration.nearest import farthest_from
from qifreport.registration.scan import median_spacing

__all__ = [
    "Detectable",
    "FixtureProbe",
    "ScanReading",
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
    cache : the first pass's factorisation, once made.
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
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, fit: DeformResult, ops: MeshOperators) -> FixtureProbe | None:
        """The probe of a band-limited fit (GB-CICP's parameters: a band limit and a refit
        band limit, no ``lambda0``); None for another method or parametrisation, whose
        absorption is not probed."""
        p = fit.params
        if getattr(p, "band_limit_refit", None) is None or getattr(p, "lambda0", None) is not None:
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

    def _factor(self, solver: SPDSolver, lam: float, w: np.ndarray):
        """The solve of ``(A W + lam Q + eps) x = b`` for the weights ``w`` (n,)."""
        Aw = self.ops.area * w
        eps = MASS_REGULARISATION * self.band_limit**4 * self.ops.M
        return solver.factor((sp.diags(Aw) + lam * self.ops.Q + eps).tocsc())

    def _first(self) -> tuple[SPDSolver, object]:
        """The solver and the first pass's factorisation, made once per probe."""
        if "first" not in self.cache:
            solver = SPDSolver(points=self.V0)
            self.cache["first"] = (solver, self._factor(solver, self.band_limit**4, self.weights))
        return self.cache["first"]

    def absorbed(self, d: np.ndarray) -> np.ndarray:
        """(n,) the part of the normal dent ``d`` (n,) mm the fixture follows, mm: its
        first pass at the band limit, then, where that leaves the dent beyond the flag
        threshold, the refit with the flagged vertices' surroundings withheld, grown while
        a withheld vertex stays beyond it."""
        solver, first = self._first()
        h = first(self.ops.area * self.weights * d)
        flagged = self.covered & (np.abs(d - h) > self.threshold)
        if not (self.refits and flagged.any()):
            return h
        hold = np.zeros(len(d), dtype=bool)
        seeds = flagged
        for _ in range(HOLDOUT_ROUNDS):
            grown = hold | holdout(self.V0, seeds, self.holdout_radius)
            if (grown == hold).all():
                break
            hold = grown
            w = self.weights * ~hold
            h = self._factor(solver, self.band_limit_refit**4, w)(self.ops.area * w * d)
            seeds = hold & (np.abs(d - h) > self.threshold)
        return h


@dataclass(frozen=True)
class Detectable:
    """What one surface's region criterion can see (module docstring); lengths in mm,
    areas in mm^2.

    Attributes
    ----------
    sigma_mm : the probed dent's width (Eq. 16 convention).
    depth_mm : its depth, the critical one (its out-of-band disk is the limit's area).
    read_peak_mm : the largest deviation the product reads of it.
    true_area_mm2 : its out-of-band area on the surface (the limit, less what of the disk
        lies off the surface).
    read_area_mm2 : the out-of-band area the product reads of it.
    limit_mm2 : the region criterion's limit.
    smallest_depth_mm : the shallowest dent of width ``sigma_mm`` read beyond the band
        (``(t + U) / g``, ``g`` the read share of the peak; inf when it reads nothing).
    absorbed_by : what reads it short: the deviation's reading, and the virtual fixture
        when one held the part.
    site : (3,) where it was probed, mm.
    """

    sigma_mm: float
    depth_mm: float
    read_peak_mm: float
    true_area_mm2: float
    read_area_mm2: float
    limit_mm2: float
    smallest_depth_mm: float
    absorbed_by: str
    site: tuple[float, float, float]

    @property
    def read_share(self) -> float:
        """The share of a region's area the product reads (at most 1; NaN: no region)."""
        if not self.true_area_mm2 > 0:
            return math.nan
        return min(self.read_area_mm2 / self.true_area_mm2, 1.0)

    @property
    def passing_below_mm2(self) -> float:
        """The largest region read that proves the region criterion: a failing region of
        the limit's size reads as ``limit x read share``."""
        share = self.read_share
        return self.limit_mm2 if not math.isfinite(share) else self.limit_mm2 * share

    @property
    def below_detection(self) -> bool:
        """The critical dent reads no region at all: the region criterion is below what
        this scan and mesh detect on the surface."""
        return self.read_share == 0.0

    def blind(self) -> str:
        """The statement of a region criterion below detection (empty: it is not)."""
        if not self.below_detection:
            return ""
        return (
            f"region criterion below what this scan and mesh detect: a dent of sigma "
            f"{self.sigma_mm:.2g} mm and {self.depth_mm:.3g} mm deep, whose region is the "
            f"{self.limit_mm2:g} mm^2 limit, reads no region (read peak "
            f"{self.read_peak_mm:.3g} mm; {self.absorbed_by})"
        )

    def doubt(self, largest: float) -> str:
        """Why a surface whose largest out-of-band region reads ``largest`` mm^2 is not
        proven to meet its region criterion (empty: it is, or no region was read)."""
        share = self.read_share
        if not (0.0 < largest <= self.limit_mm2) or not (math.isfinite(share) and share > 0):
            return ""
        # a region read as large as a failing one's reading may be that one: not proven in
        # (the mesh's vertex areas read neighbouring depths alike)
        if largest >= self.passing_below_mm2 - 1e-9:
            return (
                f"a region of {largest:.1f} mm^2 cannot be told from a failing one: a dent of "
                f"sigma {self.sigma_mm:.2g} mm and {self.depth_mm:.3g} mm deep reads "
                f"{100 * share:.0f} % of its region's area ({self.absorbed_by}), so a "
                f"{self.limit_mm2:g} mm^2 region reads as {self.passing_below_mm2:.1f} mm^2"
            )
        return ""

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN and inf become None)."""
        return {
            "sigma_mm": json_float(self.sigma_mm),
            "critical_depth_mm": json_float(self.depth_mm),
            "read_peak_mm": json_float(self.read_peak_mm),
            "true_area_mm2": json_float(self.true_area_mm2),
            "read_area_mm2": json_float(self.read_area_mm2),
            "read_share": json_float(self.read_share),
            "limit_mm2": json_float(self.limit_mm2),
            "passing_below_mm2": json_float(self.passing_below_mm2),
            "smallest_depth_mm": json_float(self.smallest_depth_mm),
            "absorbed_by": self.absorbed_by,
            "site_mm": [json_float(x) for x in self.site],
        }

    def line(self) -> str:
        """One line for the console and the report."""
        share = self.read_share
        read = "n/a" if not math.isfinite(share) else f"{100 * share:.0f} %"
        return (
            f"detects a dent of sigma {self.sigma_mm:.2g} mm from {self.smallest_depth_mm:.3g} "
            f"mm deep; a region's area read at {read}"
        )


def interior_vertex(
    V: np.ndarray, scored: np.ndarray, border: np.ndarray | None = None
) -> int | None:
    """The scored vertex farthest from every unscored one and every ``border`` vertex
    (``scored``, ``border`` (n,) bool; the border: the mesh's open boundary, the B-rep's
    face edges): a surface's most interior measured vertex. None when nothing is
    scored."""
    idx = np.flatnonzero(scored)
    if not len(idx):
        return None
    rest = np.flatnonzero(~scored if border is None else ~scored | border)
    if not len(rest):
        return int(idx[0])
    return int(idx[farthest_from(V[idx], V[rest])])


@dataclass(frozen=True)
class ScanReading:
    """How the scan is read, for a probe (mm).

    Attributes
    ----------
    tree : ``cKDTree(P)``.  spacing : the scan's median point spacing (the one the point
        regions take their areas from).
    ball : the deviation's first ball radius
        (:func:`~qifreport.metrology.deviation.residual_fit.ball_radius`).
    edge : the mesh's median edge length.
    labels : (f,) each triangle's face (a B-rep face, or a smooth patch; zeros: one).
    point_label : (m,) each point's face (its closest triangle's; -1: none, not read).
    vertex_tree : ``cKDTree(V)`` of the nominal read.  corners : the triangles' corners
        (``F.ravel()``, corner ``c`` of triangle ``c // 3``) indexed by vertex. With them a
        probe's patch and dent centres are found about the probe, not over the whole mesh
        (None: over the whole mesh).
    """

    tree: cKDTree
    spacing: float
    ball: float
    edge: float
    labels: np.ndarray
    point_label: np.ndarray
    vertex_tree: cKDTree | None = field(default=None, compare=False, repr=False)
    corners: LabelIndex | None = field(default=None, compare=False, repr=False)

    @classmethod
    def of(
        cls,
        V: np.ndarray,
        F: np.ndarray,
        P: np.ndarray,
        tree: cKDTree | None = None,
        labels: np.ndarray | None = None,
        point_label: np.ndarray | None = None,
        spacing: float | None = None,
    ) -> ScanReading:
        """The reading of the scan ``P`` (m, 3) on ``(V, F)``; one face when ``labels``
        (f,) and ``point_label`` (m,) are not given; ``spacing``: the point regions' own
        (:attr:`~qifreport.metrology.acceptance.point_regions.ScanSamples.spacing`), else
        measured here."""
        tree = cKDTree(P) if tree is None else tree
        one = labels is None or point_label is None
        if spacing is None:
            spacing = max(median_spacing(P, tree) if len(P) > 1 else 0.0, 1e-9)
        return cls(
            tree=tree,
            spacing=spacing,
            ball=ball_radius(V, F, P, tree),
            edge=median_edge_length(V, F),
            labels=np.zeros(len(F), dtype=np.int64) if one else np.asarray(labels, np.int64),
            point_label=np.zeros(len(P), np.int64) if one else np.asarray(point_label, np.int64),
            vertex_tree=cKDTree(V),
            corners=LabelIndex(F),
        )

    def patch_vertices(
        self, V: np.ndarray, F: np.ndarray, x0: np.ndarray, reach: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The vertices of ``V`` (n, 3) mm within ``reach`` mm of ``x0``, as an (n,) bool,
        and the triangles of ``F`` (f, 3, the reading's own) with all three corners among
        them, ascending: :attr:`vertex_tree`'s candidates a hair wider, each measured as
        over all of ``V``, and only the triangles about them tested (a ``V`` the tree was
        not made of: a pass over all of it)."""
        if self.vertex_tree is None or not np.array_equal(self.vertex_tree.data, V):
            vin = np.linalg.norm(V - x0, axis=1) <= reach
            return vin, np.flatnonzero(vin[F].all(axis=1))
        vin = np.zeros(len(V), dtype=bool)
        cand = np.asarray(
            self.vertex_tree.query_ball_point(x0, reach * (1.0 + 1e-9) + 1e-9), dtype=np.int64
        )
        vin[cand] = np.linalg.norm(V[cand] - x0, axis=1) <= reach
        faces = unique_sorted(self.corners.of(np.flatnonzero(vin)) // 3)
        return vin, faces[vin[F[faces]].all(axis=1)]

    def first_face(self, F: np.ndarray, v: int) -> int | None:
        """The lowest-numbered triangle of ``F`` (f, 3, the reading's own) with corner
        ``v`` (None: none)."""
        if self.corners is None:
            hit = np.flatnonzero((F == v).any(axis=1))
            return int(hit[0]) if len(hit) else None
        at = self.corners.of([v])
        return int(at[0] // 3) if len(at) else None


@dataclass(frozen=True)
class _Patch:
    """The surface about a probe site: its vertices and triangles within reach, and the
    scan points there (mm); ``reader`` reads the vertices from the points' residuals (its
    ball pairs kept for the next dent)."""

    V: np.ndarray
    F: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    vertex: np.ndarray
    P: np.ndarray
    neighbours: np.ndarray
    on_surface: np.ndarray
    tree: cKDTree

    labels: np.ndarray
    point_label: np.ndarray
    reader: ResidualReader | None

    @classmethod
    def about(cls, V, F, P, normals, area, x0, reach, scan: ScanReading) -> _Patch:
        vin, keep = scan.patch_vertices(V, F, x0, reach)
        Fs = F[keep]
        vertex = np.flatnonzero(vin)
        remap = np.full(len(V), -1, dtype=np.int64)
        remap[vertex] = np.arange(len(vertex))
        pin = _points_within(P, x0, reach, scan)
        Pn = P[pin]
        Vs, Fp, Ns = V[vertex], remap[Fs], normals[vertex]
        tree = cKDTree(Vs)
        k = min(DEFAULT_K, len(Pn))
        nb = cKDTree(Pn).query(Pn, k=k)[1].reshape(len(Pn), -1) if k else np.empty((0, 1), int)
        As = area[vertex]
        on = As[tree.query(Pn)[1]] > 0 if len(Pn) else np.zeros(0, dtype=bool)
        labels, point_label = scan.labels[keep], scan.point_label[pin]
        reader = None
        if len(Fp):
            reader = ResidualReader(
                Vs, Fp, Pn, Ns, point_label, labels, radius=scan.ball, robust=False
            )
        return cls(Vs, Fp, Ns, As, vertex, Pn, nb, on, tree, labels, point_label, reader)


def _points_within(P: np.ndarray, x0: np.ndarray, reach: float, scan: ScanReading) -> np.ndarray:
    """The ids (ascending) of the points of ``P`` (m, 3) mm within ``reach`` mm of ``x0``
    and on a face of ``scan``; the candidates from ``scan.tree`` (of ``P``), a hair
    wider, each then measured as a point of the whole scan would be."""
    if scan.tree.n == len(P):
        cand = scan.tree.query_ball_point(x0, reach * (1.0 + 1e-9) + 1e-9)
        cand = np.sort(np.asarray(cand, dtype=np.int64))
    else:
        cand = np.arange(len(P))
    near = np.linalg.norm(P[cand] - x0, axis=1) <= reach
    return cand[near & (scan.point_label[cand] >= 0)]


def detectable_dent(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    normals: np.ndarray,
    area: np.ndarray,
    site: int,
    band: tuple[float, float, float],
    fixture: FixtureProbe | None = None,
    sigma: float | None = None,
    scan: ScanReading | None = None,
) -> Detectable:
    """The critical dent of one surface, probed at vertex ``site`` (module docstring).

    Parameters
    ----------
    V : (n, 3) the held nominal, mm.  F : (f, 3).  P : (m, 3) the scan's points, mm.
    normals : (n, 3) unit vertex normals.  area : (n,) vertex areas of the surface, mm^2
        (0 off it).
    band : the band's half-width (mm), the region limit (mm^2) and the surface's median
        expanded uncertainty (mm).
    fixture : the virtual fixture's last pass (None: the part is judged as seated or held
        by its clamps, and only the reading reads the dent short).
    sigma : the dent's width, mm (Eq. 16); default the limit's own, ``sqrt(A / pi)``.
    scan : how the scan is read (its tree, spacing, ball and face labels); made here when
        not given.

    The area read is the larger of the vertices' (each a ball fit) and the scan points'
    (each the median of its :data:`~qifreport.metrology.acceptance.point_regions.DEFAULT_K`
    nearest, with the area it stands for), as the region criterion judges both. The dent
    is proud: continuous with the surface, its points are judged in the surface's regions
    however far they stand (``metrology/stages/scoring.py``).
    """
    half_width, limit, uncertainty = band
    sigma = math.sqrt(limit / math.pi) if sigma is None else float(sigma)
    a = critical_depth(half_width, limit, sigma)
    x0 = V[site]
    scan = ScanReading.of(V, F, P) if scan is None else scan
    patch = _Patch.about(V, F, P, normals, area, x0, 3.0 * sigma + 4.0 * scan.edge, scan)
    h = None
    if fixture is not None:
        h = fixture.absorbed(a * np.exp(-np.sum((V - x0) ** 2, axis=1) / sigma**2))
        h = h[patch.vertex]
    peak, share, true_area = math.inf, math.inf, 0.0
    # the dent centred on the vertex and between vertices: a region's area on the mesh
    # depends on where the dent falls among the vertices, and the least read counts
    for c in _centres(V, F, site, scan.first_face(F, site)):
        d = a * np.exp(-np.sum((patch.P - c) ** 2, axis=1) / sigma**2)
        r = d if h is None else d - h[patch.tree.query(patch.P - (c - x0))[1]]
        p, on_vertices = _read(patch, r, half_width, scan)
        on_points = _read_points(patch, r, half_width, scan)
        inside = d > half_width
        on_share = float(np.mean(patch.on_surface[inside])) if inside.any() else 0.0
        t_area = limit * on_share
        peak = min(peak, p)
        if t_area > 0 and max(on_vertices, on_points) / t_area < share:
            share, true_area = max(on_vertices, on_points) / t_area, t_area
    g = peak / a if a > 0 else 0.0
    return Detectable(
        sigma_mm=sigma,
        depth_mm=a,
        read_peak_mm=peak,
        true_area_mm2=true_area,
        read_area_mm2=share * true_area if true_area > 0 else 0.0,
        limit_mm2=float(limit),
        smallest_depth_mm=(half_width + uncertainty) / g if g > 0 else math.inf,
        absorbed_by="the deviation's reading"
        if fixture is None
        else "the virtual fixture and the deviation's reading",
        site=tuple(float(x) for x in x0),
    )


def _read(
    patch: _Patch, r: np.ndarray, half_width: float, scan: ScanReading
) -> tuple[float, float]:
    """The largest vertex reading (mm) and the area read beyond ``half_width`` (mm^2)
    of the patch's points with residuals ``r`` (k,) mm, each vertex a ball fit of the
    points on its own faces."""
    if not len(patch.F):
        return 0.0, 0.0
    read = patch.reader(r)
    on = np.isfinite(read) & (patch.area > 0)
    if not on.any():
        return 0.0, 0.0
    return float(np.max(read[on])), float(patch.area[on & (read > half_width)].sum())


def _read_points(patch: _Patch, r: np.ndarray, half_width: float, scan: ScanReading) -> float:
    """The area (mm^2) the patch's points with residuals ``r`` (k,) mm read beyond
    ``half_width``."""
    if not len(r):
        return 0.0
    med = np.median(r[patch.neighbours], axis=1)
    out = patch.P[(med > half_width) & patch.on_surface]
    return float(point_areas(scan.tree, out, scan.spacing).sum()) if len(out) else 0.0


def with_detectable(acc: Acceptance, det: Detectable | None) -> Acceptance:
    """``acc`` not proven in when its region criterion cannot tell its largest region
    from a failing one (:meth:`Detectable.doubt`), or is below what the scan and mesh
    detect (:meth:`Detectable.blind`: a failing region would read as none); unchanged
    otherwise."""
    if det is None or acc.proven_in is False:
        return acc
    why = det.doubt(acc.largest_region_area) or det.blind()
    if not why:
        return acc
    return replace(acc, proven_in=False, uncertain_reasons=[*acc.uncertain_reasons, why])


def _centres(V: np.ndarray, F: np.ndarray, site: int, face: int | None) -> list[np.ndarray]:
    """Dent centres about vertex ``site``: the vertex, the midpoint of one of its edges and
    the centroid of its triangle ``face`` (mm; None: the vertex alone)."""
    if face is None:
        return [V[site]]
    tri = F[face]
    other = tri[tri != site][0]
    return [V[site], 0.5 * (V[site] + V[other]), V[tri].mean(axis=0)]
