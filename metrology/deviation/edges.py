"""Trim-edge deviation: where the scan's edge lies against the open rim of the nominal.

A normal deviation cannot see an error *along* the surface: a sheet trimmed 2 mm too long, or
a whole part 2 % too large, lies on its nominal surface everywhere and passes a profile
check; the rim vertices, where the difference shows, are left unscored
(:mod:`qifreport.metrology.deviation.hygiene`). This module measures the rim directly.

For every open-boundary vertex ``v`` of the (registered) nominal it builds a local frame:
the rim tangent ``t`` (from the boundary edges, oriented by the triangles' winding), the
surface normal ``n`` and the *outward in-plane normal* ``b = t x n`` (in the tangent plane,
pointing away from the material). The scan points in a strip about ``v`` -- within
``radius`` of it along ``t``, within ``radius`` of its tangent plane along ``n`` -- are
projected on ``b``; ``u = (p - v) . b`` is how far beyond the nominal edge a point lies.
The scan's edge is then estimated in three passes:

1. a coarse edge ``e0``, the 95th percentile of ``u`` over a wide window
   ``[-max_gap, +max_gap]``;
2. twice: a strip of depth ``D = radius`` behind the current estimate, ``u in [e - D,
   e + D / 2]`` (stray points farther out are ignored), and
   ``e = a + (Q_q - a) (N + 1) / ((N - 1) q + 1)`` with ``a = e - D`` the strip's inner end,
   ``Q_q`` the ``q = 0.9`` quantile of the strip's ``N`` values of ``u``.

The correction in step 2 is unbiased for points spread uniformly over ``[a, e]``: numpy's
``q`` quantile of ``N`` such points is the order statistic of rank ``(N - 1) q + 1``, whose
expected position is that rank over ``N + 1`` of the way from ``a`` to ``e`` (``q`` for
many points). It removes the inset of a plain maximum or quantile (about half a point
spacing, plus the noise of the single outermost point), whatever the scan density.
Measured: points spread at random over a plate (8 per mm^2, 0.02 mm noise), within
0.02 mm of the true edge (median per side, 0.07 mm standard deviation per rim vertex); on
the simulated shell (3 views, 0.02 mm noise) within 0.01 mm of the true edge of the
scanned surface (median), 0.21 mm standard deviation per rim vertex. A scanner's regular
pixel grid leaves a resolution limit: the true edge lies anywhere within one pixel pitch
beyond the outermost row, so with one grid aligned with the edge the estimate can be off
by up to half a pitch along a whole side (0.3 mm at the virtual scanner's 1.05 mm pitch,
0.15 mm at 0.35 mm); several views at different angles average this out.

The *edge deviation* of ``v`` is that estimate, in mm: positive where the scan's material
reaches beyond the nominal edge (trimmed long, part too large), negative where it stops
short. A vertex is *seen* when the strip holds at least ``min_points`` points, spread on
both sides of ``v`` along the rim (each side at least 20 %), and the coarse edge lies
within ``max_gap`` of the nominal edge; otherwise its deviation is NaN (not measured: the
scan does not reach the rim there, e.g. a clamp's shadow or an unscanned strip). Two
more rules keep the boundary of a dropout hole that cuts the rim from passing for the trim
edge: the two halves of the strip (either side of ``v`` along the rim) must agree on the
edge within ``0.4 radius``, and the strip must hold at least half the median seen strip's
points. Rim vertices near a corner of the rim (the outward normals of the rim within
``1.5 radius`` turn by more than ``corner_angle``) are not measured: there the strip is
not straight.

Closed solids (a STEP part's tessellation) have no open boundary. Their trim edges are the
sharp creases between a large face and a thin side wall, and ``trim_edges="auto"`` (the
default) then measures those (:func:`crease_frames`): the mesh is cut along its creases
(dihedral angle above ``crease_angle``, 60 degrees) into smooth patches, and each patch's
rim is measured as above with three changes: the frame uses the patch's own normal (not
the average across the crease), a frame is kept only where its patch extends a full strip
depth inward (the large face beside a side wall, not the 2 mm side wall itself), and only
scan points whose PCA normal lies within 45 degrees of the patch's normal and within
``radius / 4`` of its tangent plane enter the strip (not the side wall's points, nor the
far skin's). A one-sided scan sees the upper skin's rims only, so about half the rim
length is "not seen". A mesh with neither an open boundary nor a sharp crease (a smooth
closed surface) returns ``status == "no rim"`` with empty arrays and measures nothing.

The scale of the part is estimated from these deviations by
:mod:`qifreport.metrology.deviation.size`.

All lengths are mm; ``V`` (n, 3), ``F`` (f, 3), ``P`` (m, 3).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.statistics import json_float
from qifreport.metrology.deviation.signed import closest_points
from qifreport.metrology.groups import sort_within_groups
from qifreport.registration.mesh import (
    edge_uses,
    face_normals,
    median_edge_length,
    vertex_normals,
)
from qifreport.registration.nearest import ball_pairs
from qifreport.registration.normals import pca_normals

__all__ = [
    "DEFAULT_QUANTILE",
    "EdgeDeviation",
    "EdgeSegment",
    "RimFrames",
    "crease_frames",
    "edge_deviation",
    "rim_frames",
    "rim_segments",
    "scan_spacing",
    "split_at_creases",
]

log = logging.getLogger(__name__)

#: quantile of the outward projections in the strip (the density-corrected edge estimate)
DEFAULT_QUANTILE = 0.9
#: quantile of the coarse first pass over the wide window
_COARSE_QUANTILE = 0.95
#: each side of a rim vertex (along the rim) must hold this share of the strip's points
_MIN_SIDE_SHARE = 0.2
#: the edge estimates of the strip's two halves (centres ``radius`` apart) may differ by this
#: much x ``radius`` (a slope of 0.4, 22 degrees); more: the scan's edge is not the trim edge
_MAX_SLANT = 0.4
#: a seen strip holds at least this share of the median seen strip's points
_MIN_COUNT_SHARE = 0.5
#: crease mode: a scan point belongs to a patch's surface within 45 degrees of its normal
#: (a point on a right-angled crease, half its PCA neighbours on each face, tilts by 45)
_MIN_FACING_COS = float(np.cos(np.deg2rad(45.0)))
#: crease mode: the normal window, as a fraction of ``radius`` (the patch on the far side of
#: a thin wall lies one wall thickness away)
_CREASE_WINDOW = 0.25
#: rim vertices measured at once (bounds the temporary (point, vertex) pairs)
_CHUNK_VERTICES = 2000
#: scan points sampled for the spacing estimate
_SPACING_SAMPLE = 20_000


@dataclass
class RimFrames:
    """The open rim of a mesh and a local frame at each of its vertices.

    Attributes
    ----------
    vertices : (k,) int64, the rim (open-boundary) vertices, indices into ``V``.
    position : (k, 3) their positions, mm.
    edges : (e, 2) int64, the open boundary edges as pairs of *positions* in ``vertices``.
    tangent : (k, 3) unit rim tangents, along the boundary's direction of travel.
    normal : (k, 3) unit surface normals (vertex normals).
    outward : (k, 3) unit outward in-plane normals ``tangent x normal``: in the tangent
        plane, pointing away from the material.
    length : (k,) rim length attributed to each vertex (half its boundary edges), mm.
    loop : (k,) int, connected piece of the rim (outer rim, each hole) of each vertex.
    corner : (k,) bool, vertex at a corner of the rim (not measured).
    patch : (k,) int, the smooth patch the frame belongs to (crease mode: a vertex on a crease
        appears once per patch meeting there; open rims: all 0).
    mode : ``"rim"`` (open boundary) or ``"crease"`` (sharp creases of a closed mesh).
    """

    vertices: np.ndarray
    position: np.ndarray
    edges: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    outward: np.ndarray
    length: np.ndarray
    loop: np.ndarray
    corner: np.ndarray
    patch: np.ndarray | None = None
    mode: str = "rim"

    def __post_init__(self) -> None:
        if self.patch is None:
            self.patch = np.zeros(len(self.vertices), dtype=np.int64)

    @property
    def empty(self) -> bool:
        """True when the mesh has no open boundary."""
        return len(self.vertices) == 0


@dataclass
class EdgeSegment:
    """A connected stretch of the rim whose edge deviation is beyond the edge tolerance.

    Attributes
    ----------
    vertices : (j,) int64, its rim vertices (indices into ``V``).
    length : rim length, mm.
    peak : the signed deviation of largest magnitude, mm.
    mean : the mean signed deviation, mm.
    centroid : (3,) the mean position of its vertices, mm.
    """

    vertices: np.ndarray
    length: float
    peak: float
    mean: float
    centroid: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready summary (no vertex list: ``n_vertices``)."""
        return {
            "n_vertices": len(self.vertices),
            "length_mm": json_float(self.length),
            "peak_mm": json_float(self.peak),
            "mean_mm": json_float(self.mean),
            "centroid": [json_float(c) for c in self.centroid],
        }


@dataclass
class EdgeDeviation:
    """Trim-edge deviation of a scan against the open rim of the (registered) nominal.

    Attributes
    ----------
    status : ``"measured"``, ``"not seen"`` (a rim, but the scan reaches it nowhere) or
        ``"no rim"`` (no open boundary and no trim crease; nothing is measured).
    rim : :class:`RimFrames` of the nominal the deviations refer to.
    deviation : (k,) signed in-plane distance from the nominal edge to the scan's edge
        along the outward normal, mm (+ = scan material beyond the edge); NaN where not seen.
    points : (k,) scan points in each vertex's final strip.
    tolerance : the edge tolerance, mm: a seen vertex with ``|deviation| > tolerance`` is
        out of tolerance.
    radius : strip half-width along the rim, strip depth and normal window, mm.
    max_gap : the wide window of the coarse pass, mm (a scan edge farther inside the nominal
        rim than this is "not seen").
    segments : connected rim stretches out of tolerance, longest first.
    """

    status: str
    rim: RimFrames
    deviation: np.ndarray
    points: np.ndarray
    tolerance: float
    radius: float
    max_gap: float
    segments: list[EdgeSegment] = field(default_factory=list)

    @property
    def seen(self) -> np.ndarray:
        """(k,) bool, rim vertices whose edge deviation was measured."""
        return np.isfinite(self.deviation)

    @property
    def rim_length(self) -> float:
        """Total length of the open rim, mm."""
        return float(self.rim.length.sum())

    @property
    def seen_fraction(self) -> float:
        """Share of the rim length where the edge deviation was measured (0 without rim)."""
        total = self.rim_length
        return float(self.rim.length[self.seen].sum() / total) if total > 0 else 0.0

    def statistics(self) -> dict[str, float]:
        """Median, P05, P95, min and max of the seen deviations (length weighted), mm.

        NaN when nothing was seen.
        """
        d = self.deviation[self.seen]
        if len(d) == 0:
            return {k: float("nan") for k in ("median", "p05", "p95", "min", "max")}
        w = self.rim.length[self.seen]
        return {
            "median": _weighted_quantile(d, w, 0.5),
            "p05": _weighted_quantile(d, w, 0.05),
            "p95": _weighted_quantile(d, w, 0.95),
            "min": float(d.min()),
            "max": float(d.max()),
        }

    @property
    def out_of_tolerance_length(self) -> float:
        """Rim length (mm) of the seen vertices with ``|deviation| > tolerance``."""
        bad = self.seen & (np.abs(np.nan_to_num(self.deviation)) > self.tolerance)
        return float(self.rim.length[bad].sum())

    def to_dict(self, per_vertex: bool = False) -> dict:
        """JSON-ready summary (NaN -> None).

        Parameters
        ----------
        per_vertex : also list the rim vertices and their deviations (None where not seen).
        """
        out = {
            "status": self.status,
            "mode": self.rim.mode,
            "rim_vertices": len(self.rim.vertices),
            "rim_length_mm": json_float(self.rim_length),
            "seen_fraction": json_float(self.seen_fraction),
            "tolerance_mm": json_float(self.tolerance),
            "radius_mm": json_float(self.radius),
            "max_gap_mm": json_float(self.max_gap),
            "statistics_mm": {k: json_float(v) for k, v in self.statistics().items()},
            "out_of_tolerance_length_mm": json_float(self.out_of_tolerance_length),
            "n_segments": len(self.segments),
            "segments": [s.to_dict() for s in self.segments[:50]],
        }
        if per_vertex:
            out["vertices"] = [int(v) for v in self.rim.vertices]
            out["deviation_mm"] = [json_float(d) for d in self.deviation]
        return out

    def reasons(self) -> list[str]:
        """One-line findings, for a report or a log."""
        if self.status == "no rim":
            return [
                "trim edges not measured: the nominal has no open rim and no sharp crease "
                "(nothing bounds its surfaces)"
            ]
        if self.status == "not seen":
            return [
                f"trim edges not measured: the scan reaches the {self.rim_length:.0f} mm rim "
                "nowhere"
            ]
        s = self.statistics()
        what = "rim" if self.rim.mode == "rim" else "trim creases"
        out = [
            f"trim edge seen over {100 * self.seen_fraction:.0f} % of the "
            f"{self.rim_length:.0f} mm {what}: median {s['median']:+.2f} mm, "
            f"P05/P95 {s['p05']:+.2f}/{s['p95']:+.2f} mm"
        ]
        if self.segments:
            worst = max(self.segments, key=lambda g: abs(g.peak))
            out.append(
                f"{len(self.segments)} rim segment(s), {self.out_of_tolerance_length:.0f} mm, "
                f"beyond the +/-{self.tolerance:.2g} mm edge tolerance; peak "
                f"{worst.peak:+.2f} mm"
            )
        return out


def _weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    o = np.argsort(x)
    x, w = x[o], w[o]
    c = np.cumsum(w)
    if c[-1] <= 0:
        return float(np.quantile(x, q))
    return float(np.interp(q * c[-1], c - 0.5 * w, x))


def scan_spacing(P: np.ndarray, tree: cKDTree | None = None) -> float:
    """Median nearest-neighbour distance of the scan points (mm), from a fixed subsample.

    Parameters
    ----------
    P : (m, 3) scan points, mm.
    tree : ``cKDTree(P)`` when at hand (``P`` then all finite).
    """
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    if tree is None:
        P = P[np.isfinite(P).all(axis=1)]
    if len(P) < 2:
        return float("nan")
    step = max(1, len(P) // _SPACING_SAMPLE)
    d, _ = (cKDTree(P) if tree is None else tree).query(P[::step], k=2, workers=-1)
    return float(np.median(d[:, 1]))


def _directed_boundary(F: np.ndarray) -> np.ndarray:
    """(e, 2) open boundary edges, directed as their one triangle traverses them."""
    _, count, of = edge_uses(F)
    out = []
    for k in range(3):
        sel = count[of[:, k]] == 1
        out.append(np.c_[F[sel, k], F[sel, (k + 1) % 3]])
    return np.concatenate(out).astype(np.int64)


def rim_frames(
    V: np.ndarray,
    F: np.ndarray,
    normals: np.ndarray | None = None,
    radius: float | None = None,
    corner_angle: float = 30.0,
) -> RimFrames:
    """The open rim of ``(V, F)`` and its local frames (see :class:`RimFrames`).

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int, consistently wound (outward normals).
    normals : (n, 3) unit vertex normals; default
        :func:`qifreport.registration.mesh.vertex_normals`.
    radius : neighbourhood of the corner test, mm; default 2 median edge lengths.
    corner_angle : a rim vertex is a corner when the outward normals of the rim vertices of
        its loop within ``radius`` turn by more than this, degrees.

    Returns
    -------
    :class:`RimFrames`, empty (``k = 0``) for a mesh without an open boundary.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    D = _directed_boundary(F)
    if len(D) == 0:
        z3 = np.zeros((0, 3))
        z = np.zeros(0, dtype=np.int64)
        return RimFrames(
            z, z3, np.zeros((0, 2), np.int64), z3, z3, z3, np.zeros(0), z, z.astype(bool)
        )
    verts, pos = np.unique(D, return_inverse=True)
    pos = pos.reshape(D.shape)
    k = len(verts)
    vec = V[D[:, 1]] - V[D[:, 0]]
    elen = np.linalg.norm(vec, axis=1)
    unit = vec / np.maximum(elen, 1e-300)[:, None]
    T = np.zeros((k, 3))
    np.add.at(T, pos[:, 0], unit)
    np.add.at(T, pos[:, 1], unit)
    length = np.zeros(k)
    np.add.at(length, pos[:, 0], 0.5 * elen)
    np.add.at(length, pos[:, 1], 0.5 * elen)
    N = (vertex_normals(V, F) if normals is None else np.asarray(normals, np.float64))[verts]
    T = T - np.einsum("ij,ij->i", T, N)[:, None] * N
    tn = np.linalg.norm(T, axis=1)
    degenerate = tn < 1e-9
    T = T / np.maximum(tn, 1e-300)[:, None]
    B = np.cross(T, N)
    B = B / np.maximum(np.linalg.norm(B, axis=1), 1e-300)[:, None]
    A = sp.coo_matrix((np.ones(len(pos)), (pos[:, 0], pos[:, 1])), shape=(k, k))
    _, loop = connected_components(A, directed=False)
    # corners: the outward normal turns by more than corner_angle within radius (same loop)
    r = 2.0 * median_edge_length(V, F) if radius is None else float(radius)
    pairs = cKDTree(V[verts]).query_pairs(r, output_type="ndarray")
    corner = degenerate.copy()
    if len(pairs):
        same = loop[pairs[:, 0]] == loop[pairs[:, 1]]
        pairs = pairs[same]
        turn = np.einsum("ij,ij->i", B[pairs[:, 0]], B[pairs[:, 1]]) < np.cos(
            np.deg2rad(corner_angle)
        )
        corner[pairs[turn].ravel()] = True
    return RimFrames(
        vertices=verts.astype(np.int64),
        position=V[verts],
        edges=pos.astype(np.int64),
        tangent=T,
        normal=N,
        outward=B,
        length=length,
        loop=loop.astype(np.int64),
        corner=corner,
    )


def _order_gain(n: np.ndarray, q: float) -> np.ndarray:
    """``(e - a) / (Q_q - a)`` in expectation for ``n`` i.i.d. uniform points on ``[a, e]``.

    numpy's linear quantile of ``n`` points sits at order ``(n - 1) q + 1``, whose expected
    position is that order over ``n + 1``; ``1 / q`` is the limit for many points.
    """
    n = np.asarray(n, dtype=np.float64)
    return np.where(n > 1, (n + 1.0) / np.maximum((n - 1.0) * q + 1.0, 1e-300), np.nan)


def split_at_creases(
    V: np.ndarray, F: np.ndarray, crease_angle: float = 60.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cut the mesh along its sharp creases into smooth patches with their own vertices.

    Two triangles sharing an edge stay in one patch when their normals differ by at most
    ``crease_angle`` degrees; non-manifold edges are cut too. Each patch gets its own copy
    of the vertices it uses, so a crease becomes an open boundary of both patches.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int, consistently wound.  crease_angle : degrees.

    Returns
    -------
    V2 : (n2, 3) the vertices, one copy per patch using it.  F2 : (f, 3) the triangles on
    them.  source : (n2,) index in ``V`` of each copy.  patch : (f,) patch of each triangle.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nf = len(F)
    _, count, of = edge_uses(F)
    fn = face_normals(V, F)
    slot_edge = of.ravel()
    slot_face = np.repeat(np.arange(nf), 3)
    manifold = count[slot_edge] == 2
    order = np.argsort(slot_edge[manifold], kind="stable")
    faces = slot_face[manifold][order].reshape(-1, 2)  # the two triangles of each edge
    smooth = np.einsum("ij,ij->i", fn[faces[:, 0]], fn[faces[:, 1]]) >= np.cos(
        np.deg2rad(crease_angle)
    )
    a, b = faces[smooth, 0], faces[smooth, 1]
    A = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(nf, nf))
    _, patch = connected_components(A, directed=False)
    key = patch[:, None].astype(np.int64) * len(V) + F
    uniq, inv = np.unique(key.ravel(), return_inverse=True)
    source = uniq % len(V)
    return V[source], inv.reshape(F.shape).astype(np.int64), source, patch.astype(np.int64)


def crease_frames(
    V: np.ndarray,
    F: np.ndarray,
    radius: float,
    crease_angle: float = 60.0,
    corner_angle: float = 30.0,
) -> RimFrames:
    """Trim edges of a closed mesh: the rims of its smooth patches (:func:`split_at_creases`).

    Each frame uses its own patch's normal (not the average across the crease) and points
    out of that patch, across the crease. A frame is kept only where its patch extends a
    full strip depth ``radius`` inward (the point ``radius`` inside the rim lies on the
    patch): the large face beside a thin side wall keeps its frames, the side wall (and the
    bottom skin's narrow strips) does not.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  radius : the strip depth, mm.
    crease_angle, corner_angle : degrees (:func:`split_at_creases`, :func:`rim_frames`).

    Returns
    -------
    :class:`RimFrames` with ``mode == "crease"``; ``vertices`` index ``V`` (a crease vertex
    may appear once per patch).
    """
    V2, F2, source, patch_f = split_at_creases(V, F, crease_angle)
    rf = rim_frames(V2, F2, radius=1.5 * radius, corner_angle=corner_angle)
    if rf.empty:
        return RimFrames(**{**vars(rf), "mode": "crease"})
    # the patch of each rim copy: that of any triangle using it
    vpatch = np.zeros(len(V2), dtype=np.int64)
    vpatch[F2.ravel()] = np.repeat(patch_f, 3)
    pv = vpatch[rf.vertices]
    probe = V2[rf.vertices] - radius * rf.outward
    _, face, dist = closest_points(V2, F2, probe)
    wide = (patch_f[np.maximum(face, 0)] == pv) & (np.abs(dist) <= 0.02 * radius) & (face >= 0)
    keep = np.flatnonzero(wide)
    pos = -np.ones(len(rf.vertices), dtype=np.int64)
    pos[keep] = np.arange(len(keep))
    e = rf.edges[(pos[rf.edges] >= 0).all(axis=1)]
    return RimFrames(
        vertices=source[rf.vertices[keep]],
        position=rf.position[keep],
        edges=pos[e],
        tangent=rf.tangent[keep],
        normal=rf.normal[keep],
        outward=rf.outward[keep],
        length=rf.length[keep],
        loop=rf.loop[keep],
        corner=rf.corner[keep],
        patch=pv[keep],
        mode="crease",
    )


def _group_quantile(group: np.ndarray, x: np.ndarray, q: float, k: int) -> np.ndarray:
    """Per group (0..k-1) the ``q`` quantile (linear interpolation) of ``x``; NaN if empty."""
    out = np.full(k, np.nan)
    if len(x) == 0:
        return out
    order = sort_within_groups(group, x)
    xs = x[order]
    cnt = np.bincount(group, minlength=k)
    start = np.cumsum(cnt) - cnt
    has = cnt > 0
    posf = (cnt[has] - 1) * q
    lo = np.floor(posf).astype(np.int64)
    hi = np.minimum(lo + 1, cnt[has] - 1)
    frac = posf - lo
    s = start[has]
    out[has] = xs[s + lo] * (1.0 - frac) + xs[s + hi] * frac
    return out


def rim_segments(rim: RimFrames, values: np.ndarray, tolerance: float) -> list[EdgeSegment]:
    """Connected stretches of the rim where ``|values| > tolerance``, longest first.

    Parameters
    ----------
    rim : :class:`RimFrames`.  values : (k,) per rim vertex, mm (NaN: not seen, never out).
    tolerance : mm.
    """
    values = np.asarray(values, dtype=np.float64)
    bad = np.isfinite(values) & (np.abs(np.nan_to_num(values)) > tolerance)
    if not bad.any():
        return []
    k = len(rim.vertices)
    e = rim.edges[bad[rim.edges[:, 0]] & bad[rim.edges[:, 1]]]
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(k, k))
    _, lab = connected_components(A, directed=False)
    out = []
    for g in np.unique(lab[bad]):
        m = np.flatnonzero(bad & (lab == g))
        vals = values[m]
        centroid = rim.position[m].mean(axis=0)
        out.append(
            EdgeSegment(
                vertices=rim.vertices[m],
                length=float(rim.length[m].sum()),
                peak=float(vals[np.argmax(np.abs(vals))]),
                mean=float(vals.mean()),
                centroid=np.asarray(centroid, dtype=np.float64),
            )
        )
    out.sort(key=lambda g: -g.length)
    return out


def _strip_edges(
    P: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    T: np.ndarray,
    N: np.ndarray,
    B: np.ndarray,
    radius: float,
    window: float,
    max_gap: float,
    min_points: int,
    quantile: float,
    crease: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scan's edge along ``B`` at each rim point ``X`` (j, 3) (module docstring).

    Returns the edge estimate (NaN: too few points), the final strip's point count, the
    share of them on the ``+T`` side, and the disagreement of the strip's two halves, mm.
    """
    km = len(X)
    e = np.full(km, np.nan)
    n2 = np.zeros(km, dtype=np.int64)
    share = np.zeros(km)
    slant = np.full(km, np.inf)
    reach = float(np.sqrt(radius**2 + max_gap**2 + window**2))
    # every (rim point, scan point) pair within reach, as flat arrays from one dual-tree
    # search (their order does not matter: each rim point's values are sorted or counted)
    grp, idx = ball_pairs(X, tree, reach)
    if len(grp) == 0:
        return e, n2, share, slant
    # rows gathered by np.take (qifreport.registration.arrays)
    Q = np.take(P, idx, axis=0) - np.take(X, grp, axis=0)
    along = np.einsum("ij,ij->i", Q, np.take(T, grp, axis=0))
    u = np.einsum("ij,ij->i", Q, np.take(B, grp, axis=0))
    z = np.einsum("ij,ij->i", Q, np.take(N, grp, axis=0))
    keep = (np.abs(along) <= radius) & (np.abs(z) <= window) & (np.abs(u) <= max_gap)
    if crease and keep.any():
        # only points of the patch's own surface: not the side wall or the next face
        cand, back = np.unique(idx[keep], return_inverse=True)
        Ns = pca_normals(P[cand])
        facing = np.abs(np.einsum("ij,ij->i", Ns[back], N[grp[keep]])) >= _MIN_FACING_COS
        keep[np.flatnonzero(keep)[~facing]] = False
    grp, along, u = grp[keep], along[keep], u[keep]

    # pass 1: coarse edge over the wide window
    n1 = np.bincount(grp, minlength=km)
    e = _group_quantile(grp, u, _COARSE_QUANTILE, km)
    e[n1 < min_points] = np.nan
    # pass 2 (twice): density-corrected quantile in a strip of depth `radius` behind it
    for _ in range(2):
        lo = e - radius
        sel = np.isfinite(e[grp]) & (u >= lo[grp]) & (u <= (e + 0.5 * radius)[grp])
        g2, a2, u2 = grp[sel], along[sel], u[sel]
        n2 = np.bincount(g2, minlength=km)
        qv = _group_quantile(g2, u2, quantile, km)
        e = lo + (qv - lo) * _order_gain(n2, quantile)
        e[n2 < min_points] = np.nan
    plus = a2 > 0
    share = np.divide(
        np.bincount(g2, weights=plus.astype(float), minlength=km),
        n2,
        out=np.zeros(km),
        where=n2 > 0,
    )
    # the scan's edge must run along the rim: the two halves of the strip agree (a dropout
    # hole's boundary crossing the rim gives a slanted "edge")
    halves = []
    for m in (~plus, plus):
        qh = _group_quantile(g2[m], u2[m], quantile, km)
        halves.append(lo + (qh - lo) * _order_gain(np.bincount(g2[m], minlength=km), quantile))
    slant = np.abs(halves[1] - halves[0])
    return e, n2, share, np.where(np.isfinite(slant), slant, np.inf)


def _checked(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    tolerance: float,
    quantile: float,
    radius: float | None,
    trim_edges: str,
    tree: cKDTree | None,
) -> tuple[np.ndarray, cKDTree | None, float, float]:
    """:func:`edge_deviation`'s inputs checked: the finite scan points (m', 3), their tree
    (None: no points), the tolerance and the strip radius, mm (its default)."""
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(P).all(axis=1)
    if not finite.all():
        P, tree = P[finite], None
    tolerance = float(tolerance)
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"edge tolerance must be positive, got {tolerance}")
    if not 0.5 <= quantile < 1.0:
        raise ValueError(f"quantile must lie in [0.5, 1), got {quantile}")
    if tree is None and len(P):
        tree = cKDTree(P)
    if radius is None:
        spacing = scan_spacing(P, tree) if tree is not None else float("nan")
        radius = max(2.0 * median_edge_length(V, F), 6.0 * np.nan_to_num(spacing))
    radius = float(radius)
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    if trim_edges not in ("auto", "rim", "crease"):
        raise ValueError(f"trim_edges must be 'auto', 'rim' or 'crease', got {trim_edges!r}")
    return P, tree, tolerance, radius


def _rim_strips(
    P: np.ndarray,
    tree: cKDTree,
    rim: RimFrames,
    measured: np.ndarray,
    radius: float,
    max_gap: float,
    min_points: int,
    quantile: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scan's edge in the strip of each ``measured`` rim vertex (k,), mm along its
    outward direction, the strip's points (k,), and whether the edge is seen (k,) bool:
    enough points, on both halves of the strip and agreeing (no dropout hole's boundary
    crossing the rim), and not a strip a hole cut (:func:`_strip_edges`)."""
    window = _CREASE_WINDOW * radius if rim.mode == "crease" else radius
    parts = []
    for c0 in range(0, len(measured), _CHUNK_VERTICES):
        sl = measured[c0 : c0 + _CHUNK_VERTICES]
        parts.append(
            _strip_edges(
                P,
                tree,
                rim.position[sl],
                rim.tangent[sl],
                rim.normal[sl],
                rim.outward[sl],
                radius,
                window,
                max_gap,
                min_points,
                quantile,
                crease=rim.mode == "crease",
            )
        )
    e, n2, share, slant = (np.concatenate(x) for x in zip(*parts, strict=True))
    ok = (
        np.isfinite(e)
        & (n2 >= min_points)
        & (share >= _MIN_SIDE_SHARE)
        & (share <= 1.0 - _MIN_SIDE_SHARE)
        & (slant <= _MAX_SLANT * radius)
    )
    if ok.any():  # a strip cut by a dropout hole holds fewer points than a full one
        ok &= n2 >= _MIN_COUNT_SHARE * np.median(n2[ok])
    return e, n2, ok


def edge_deviation(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    tolerance: float,
    *,
    normals: np.ndarray | None = None,
    radius: float | None = None,
    max_gap: float | None = None,
    min_points: int = 10,
    quantile: float = DEFAULT_QUANTILE,
    corner_angle: float = 30.0,
    trim_edges: str = "auto",
    crease_angle: float = 60.0,
    tree: cKDTree | None = None,
) -> EdgeDeviation:
    """Trim-edge deviation of the scan ``P`` at every open-rim vertex of ``(V, F)``.

    The method is in the module docstring. Pass the *registered* nominal (after the virtual
    fixture) and the scan in the nominal frame, so that the rim is where the fixture put it.

    Parameters
    ----------
    V : (n, 3) float, nominal vertices, mm.  F : (f, 3) int, consistently wound.
    P : (m, 3) float, scan points in the frame of ``V``, mm.
    tolerance : edge tolerance, mm (e.g. the general profile zone's half-width).
    normals : (n, 3) unit vertex normals of ``V``; default
        :func:`qifreport.registration.mesh.vertex_normals`.
    radius : strip half-width along the rim, strip depth and normal window, mm; default
        ``max(2 x median edge length, 6 x scan spacing)`` (:func:`scan_spacing`).
    max_gap : half-width of the coarse pass's window along the outward normal, mm: a scan
        edge more than this inside the nominal rim is "not seen", one more than this
        outside is not found. Default ``2.5 x radius``.
    min_points : fewest strip points for a seen vertex.
    quantile : ``q`` of the density-corrected estimate (module docstring).
    corner_angle : degrees; rim vertices at corners are not measured (:func:`rim_frames`).
    trim_edges : ``"rim"`` (the open boundary only), ``"crease"`` (the rims of the smooth
        patches between sharp creases, :func:`crease_frames`: the trim edges of a closed
        solid) or ``"auto"`` (default): the open boundary if there is one, else the creases.
    crease_angle : degrees, the creases of ``"crease"`` mode (:func:`split_at_creases`).
    tree : ``cKDTree(P)`` when at hand (used when every point of ``P`` is finite).

    Returns
    -------
    :class:`EdgeDeviation`.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    P, tree, tolerance, radius = _checked(V, F, P, tolerance, quantile, radius, trim_edges, tree)
    max_gap = 2.5 * radius if max_gap is None else float(max_gap)
    rim = rim_frames(V, F, normals=normals, radius=1.5 * radius, corner_angle=corner_angle)
    if trim_edges == "crease" or (trim_edges == "auto" and rim.empty):
        rim = crease_frames(V, F, radius, crease_angle=crease_angle, corner_angle=corner_angle)
    k = len(rim.vertices)
    dev = np.full(k, np.nan)
    cnt = np.zeros(k, dtype=np.int64)
    if rim.empty:
        log.info("edge deviation: the nominal has no open rim and no trim crease")
        return EdgeDeviation("no rim", rim, dev, cnt, tolerance, radius, max_gap)
    measured = np.flatnonzero(~rim.corner)
    if len(P) == 0 or len(measured) == 0:
        return EdgeDeviation("not seen", rim, dev, cnt, tolerance, radius, max_gap)
    e, n2, ok = _rim_strips(P, tree, rim, measured, radius, max_gap, min_points, quantile)
    dev[measured[ok]] = e[ok]
    cnt[measured] = n2
    status = "measured" if ok.any() else "not seen"
    out = EdgeDeviation(status, rim, dev, cnt, tolerance, radius, max_gap)
    out.segments = rim_segments(rim, dev, tolerance)
    log.info(
        "edge deviation: rim %.0f mm, seen %.0f %%, median %+.3f mm, %d segment(s) beyond %.3g mm",
        out.rim_length,
        100 * out.seen_fraction,
        out.statistics()["median"],
        len(out.segments),
        tolerance,
    )
    return out
