"""Nominal-referenced deviation: each nominal vertex against a plane fitted to the scan near it.

:func:`nominal_referenced` scores every *nominal vertex*: the signed distance, along the
vertex normal, from the vertex to a plane fitted to the scan points near it (paper
Sections 8.4.5, 10). It is structurally blind to added material: no nominal normal passes
through a feature that the nominal does not contain (paper Section 8.4.5). On a curved
surface the plane reads the sag of the points inside its ball as deviation (``r^2 / 4R``),
so the inspection scores vertices with the fit of the points' own distances to the nominal
instead (:mod:`qifreport.metrology.deviation.residual_fit`); this measure remains for the
noise-floor study (:mod:`qifreport.simulate.ladder`). Vertices the scan did not
observe are left unscored (NaN) rather than given a spurious value.

Unscored vertices: a vertex is unscored (NaN) when fewer than ``min_points`` scan points are
in its neighbourhood, and -- unless ``max_centroid_offset`` is None -- when the centroid of
those points lies more than ``max_centroid_offset * radius`` from the normal line of the
vertex. The second rule rejects vertices *beyond the edge of the scan*, whose few points sit
in a sliver on one side and would be scored by extrapolating a plane fitted to the sliver
(errors of tenths of a mm to several mm at 0.02 mm noise); a vertex right on a straight scan
edge (half-disk neighbourhood, offset ``4 / (3 pi) = 0.42`` of the radius) stays scored, the
corner of a scan (quarter disk, 0.60) does not.

The neighbourhood is a ball: a deviation larger than ``radius`` cannot be measured and leaves
the vertex unscored (NaN), not out of tolerance. Pass ``max_distance`` to use a cylinder
instead -- points within ``radius`` of the normal line and within ``max_distance`` along it
-- so that deep dents and large form errors are still scored; keep ``max_distance`` below the
wall thickness of a closed part, or the opposite wall enters the fit.

Signs and arrays as in :mod:`qifreport.metrology.deviation.closest` (positive: material
proud of the nominal surface; ``V`` (n, 3) mm, ``F`` (f, 3), ``P`` (m, 3) mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.closest import as_mesh, as_points
from qifreport.metrology.deviation.pooled import pooled_variance
from qifreport.registration.mesh import median_edge_length, vertex_normals
from qifreport.registration.nearest import ball_pairs

__all__ = [
    "nominal_referenced",
]


#: below |n_vertex . n_plane| = cos(75 deg) the fitted plane counts as near-parallel
_MIN_PLANE_COS = 0.26


#: second / smallest covariance eigenvalue below this: the points are (nearly) collinear
_MIN_SPREAD_RATIO = 10.0


#: with oriented scan normals, a point belongs to a vertex's surface only within 60 degrees
_MIN_FACING_COS = 0.5


def nominal_referenced(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    normals: np.ndarray | None = None,
    radius: float | None = None,
    min_points: int = 4,
    *,
    max_centroid_offset: float | None = 0.5,
    max_distance: float | None = None,
    scan_normals: np.ndarray | None = None,
    variance: bool = False,
    tree: cKDTree | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Signed deviation (n,) mm of every nominal vertex along its normal to the local scan.

    For vertex ``v`` with unit normal ``n``, the scan points within ``radius`` of ``v`` are
    fitted with a plane (centroid ``c`` and the PCA normal ``m``, the eigenvector of the
    smallest eigenvalue of their covariance). The deviation is the signed position ``t`` of
    the intersection of the line ``v + t n`` with that plane,
    ``t = ((c - v) . m) / (n . m)``. Where the plane is near-parallel to the normal
    (``|n . m| < 0.26``, i.e. more than 75 degrees of tilt) or the points are nearly
    collinear (second covariance eigenvalue < 10 x the smallest: the plane could rotate
    freely about their line), it falls back to ``t = (c - v) . n``. Which vertices are left
    unscored, and the ball or cylinder neighbourhood: module docstring.

    Parameters
    ----------
    V : (n, 3) float, mm.  F : (f, 3) int.  P : (m, 3) float scan points, mm.
    normals : (n, 3) unit outward vertex normals; default
        :func:`qifreport.registration.mesh.vertex_normals`.
    radius : neighbourhood radius, mm; default 1.5 x the median edge length.
    min_points : a vertex with fewer scan points than this in its neighbourhood is unscored.
    max_centroid_offset : fraction of ``radius`` (module docstring); None disables the rule.
    max_distance : mm; if given, the neighbourhood is the cylinder of the module docstring.
    scan_normals : (m, 3) scan normals *oriented* outward (e.g. by
        :func:`qifreport.registration.deformable.result.orient_scan_normals`); if given, a
        vertex only uses points whose normal is within 60 degrees of its own (``n_point .
        n_vertex > 0.5``). This keeps the back skin and the edge faces of a thin wall, closer
        to the front's measurements than ``radius``, from being scored against them.
    variance : also return each deviation's variance (see Returns).
    tree : ``cKDTree(P)`` when at hand (built here otherwise).

    Returns
    -------
    dev : (n,) float, mm. Positive = the scan lies on the +normal side (proud of nominal);
        NaN where the vertex is unscored (not observed by the scan).
    var : (n,) float, mm^2, only with ``variance``: the variance of ``dev`` from the scatter
        of the points about their plane, ``s^2 (1 + sum_k (c . e_k)^2 / lambda_k) / (N
        cos^2)`` (``N`` points, centroid ``c``, in-plane principal directions ``e_k`` and
        spreads ``lambda_k``, the plane's tilt ``cos`` to the vertex normal; ``s^2 / N`` for
        the centroid fallback), ``s^2`` the points' scatter about the plane pooled with the
        part's median (:func:`qifreport.metrology.acceptance.decision.vertex_uncertainty`);
        NaN where unscored.
    """
    V, F = as_mesh(V, F)
    P = as_points(P)
    finite = np.isfinite(P).all(axis=1)
    P = P[finite]
    Ns = None if scan_normals is None else np.asarray(scan_normals, dtype=np.float64)[finite]
    n = len(V)
    dev = np.full(n, np.nan)
    h = np.full(n, np.nan)
    if len(P) == 0:
        return (dev, h) if variance else dev
    N = vertex_normals(V, F) if normals is None else np.asarray(normals, dtype=np.float64)
    if radius is None:
        radius = 1.5 * median_edge_length(V, F)
    radius = float(radius)
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    min_points = max(int(min_points), 1)
    vrt, Q = _neighbourhoods(V, N, P, Ns, radius, max_distance, min_points, tree)
    if len(vrt) == 0:
        return (dev, h) if variance else dev
    fit = _LocalPlanes.fitted(vrt, Q, N)
    t, enough = fit.deviation(min_points, max_centroid_offset, radius)
    dev[fit.vid[enough]] = t[enough]
    return (dev, fit.variance(enough, n)) if variance else dev


def _neighbourhoods(
    V: np.ndarray,
    N: np.ndarray,
    P: np.ndarray,
    Ns: np.ndarray | None,
    radius: float,
    max_distance: float | None,
    min_points: int,
    tree: cKDTree | None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nominal_referenced`'s (vertex, point) pairs: each pair's vertex (k,) and the
    point in local coordinates about it (k, 3), mm, vertex by vertex (each one's points
    ascending), only points facing the vertex's side (``Ns``), within the ball or the
    cylinder (``max_distance``)."""
    reach = radius if max_distance is None else float(np.hypot(radius, max_distance))
    # every (vertex, point) pair within reach, in the order of a ball query per vertex
    # (vertex by vertex, each one's points ascending: the same sums below) without its list
    # of lists (costly Python objects on a large part)
    vrt, idx = ball_pairs(V, cKDTree(P) if tree is None else tree, reach, min_points)
    if len(vrt) == 0:
        return vrt, np.empty((0, 3))
    vrt, idx = np.divmod(np.sort(vrt * len(P) + idx), len(P))
    # rows gathered by np.take (qifreport.registration.arrays)
    if Ns is not None:  # only points of a surface facing the vertex's side
        Ni, Nv = np.take(Ns, idx, axis=0), np.take(N, vrt, axis=0)
        facing = np.einsum("ij,ij->i", Ni, Nv) > _MIN_FACING_COS
        del Ni, Nv
        idx, vrt = idx[facing], vrt[facing]
    Q = np.take(P, idx, axis=0)
    Q -= np.take(V, vrt, axis=0)  # local coordinates about the vertex: well conditioned
    if max_distance is not None:  # cylinder about the normal line
        along = np.einsum("ij,ij->i", Q, np.take(N, vrt, axis=0))
        lateral2 = np.einsum("ij,ij->i", Q, Q) - along**2
        keep = (np.abs(along) <= max_distance) & (lateral2 <= radius**2)
        Q, vrt = Q[keep], vrt[keep]
    return vrt, Q


@dataclass(frozen=True)
class _LocalPlanes:
    """The plane fitted to each vertex's neighbourhood (:func:`nominal_referenced`): ``k``
    vertices with points, coordinates about the vertex, mm.

    Attributes
    ----------
    vid : (k,) the vertices.  counts : (k,) their points.  c : (k, 3) centroids.
    evals, evecs : (k, 3), (k, 3, 3) the points' covariance, ascending.
    nv : (k, 3) vertex normals.  cos : (k,) the plane normal's cosine to the vertex normal.
    c_m : (k,) the centroid along the plane normal.
    ok : (k,) bool the plane defines the deviation (tilt and spread, else the centroid).
    """

    vid: np.ndarray
    counts: np.ndarray
    c: np.ndarray
    evals: np.ndarray
    evecs: np.ndarray
    nv: np.ndarray
    cos: np.ndarray
    c_m: np.ndarray
    ok: np.ndarray

    @classmethod
    def fitted(cls, vrt: np.ndarray, Q: np.ndarray, N: np.ndarray) -> _LocalPlanes:
        """The planes of the pairs ``vrt`` (k,), ``Q`` (k, 3) (:func:`_neighbourhoods`);
        ``N`` (n, 3) unit vertex normals."""
        vid, row, counts = np.unique(vrt, return_inverse=True, return_counts=True)

        def _sum(w: np.ndarray) -> np.ndarray:
            return np.bincount(row, weights=w, minlength=len(vid))

        c = np.stack([_sum(Q[:, a]) for a in range(3)], axis=1) / counts[:, None]
        R = Q - np.take(c, row, axis=0)
        cov = np.empty((len(vid), 3, 3))
        for a in range(3):
            for b in range(a, 3):
                cov[:, a, b] = cov[:, b, a] = _sum(R[:, a] * R[:, b]) / counts
        evals, evecs = np.linalg.eigh(cov)
        m_plane = evecs[:, :, 0]  # eigenvector of the smallest eigenvalue
        nv = N[vid]
        cos = np.einsum("ij,ij->i", nv, m_plane)
        # the plane's tilt is only defined if the points spread in two directions well
        # above the scatter about the plane (a collinear sliver can be rotated freely
        # about its line)
        planar = evals[:, 1] > _MIN_SPREAD_RATIO * np.maximum(evals[:, 0], 1e-300)
        return cls(
            vid=vid,
            counts=counts,
            c=c,
            evals=evals,
            evecs=evecs,
            nv=nv,
            cos=cos,
            c_m=np.einsum("ij,ij->i", c, m_plane),
            ok=(np.abs(cos) >= _MIN_PLANE_COS) & planar,
        )

    def deviation(
        self, min_points: int, max_centroid_offset: float | None, radius: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """(k,) each vertex's deviation, mm: where its normal line meets the plane, or the
        centroid's offset along it (the plane too tilted, or the points collinear); and
        (k,) bool whether it is scored: ``min_points`` points, their centroid within
        ``max_centroid_offset x radius`` of the normal line (None: no such rule)."""
        t = np.einsum("ij,ij->i", self.c, self.nv)  # fallback: centroid offset along normal
        t[self.ok] = self.c_m[self.ok] / self.cos[self.ok]
        enough = self.counts >= min_points
        if max_centroid_offset is not None:
            c_n = np.einsum("ij,ij->i", self.c, self.nv)
            offset = np.linalg.norm(self.c - c_n[:, None] * self.nv, axis=1)  # to normal line
            enough &= offset <= float(max_centroid_offset) * radius
        return t, enough

    def variance(self, enough: np.ndarray, n: int) -> np.ndarray:
        """(n,) the variance of each scored (``enough`` (k,)) vertex's deviation, mm^2
        (:func:`nominal_referenced`'s Returns); NaN elsewhere."""
        # the plane's height at the vertex: its offset (variance 1/N) and its two slopes
        # (variance 1 / (N lambda_k)) times the centroid's in-plane distance, then along n
        vid, counts, ok, cos = self.vid, self.counts, self.ok, self.cos
        lev = np.ones(len(vid))
        for k in (1, 2):
            ck = np.einsum("ij,ij->i", self.c, self.evecs[:, :, k])
            lev += ck**2 / np.maximum(self.evals[:, k], 1e-300)
        hv = 1.0 / counts
        hv[ok] = lev[ok] / (counts[ok] * cos[ok] ** 2)
        h = np.full(n, np.nan)
        h[vid[enough]] = hv[enough]
        sse = np.zeros(n)
        dof = np.zeros(n)
        sse[vid] = self.evals[:, 0] * counts  # the points' squared distances to their plane
        dof[vid] = counts - 3.0
        return pooled_variance(h, sse, dof)
