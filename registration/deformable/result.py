"""What every deformable (virtual-fixture) method shares: its result and its scan matching.

All four methods of the paper's Section 6 (GB-CICP, NICP, CPD, RBF-FEM) take the same
inputs -- the rigidly aligned nominal ``V0`` (n, 3) mm, its triangles ``F``, its operators,
the scan ``P`` (m, 3) mm in the same frame -- and return a :class:`DeformResult` on the
nominal vertex set (paper Section 6.5), so that the metrology downstream does not depend on
the method. :class:`ScanMatcher` gives the nearest-scan-point, point-to-plane
correspondences with their coverage test; every method's result is finished with it, so
``residual`` and ``covered`` mean the same thing for all of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from qifreport.registration.icp import robust_scale
from qifreport.registration.mesh import MeshOperators, median_edge_length
from qifreport.registration.nearest import workers_for
from qifreport.registration.normals import SIDE_KNOWN, orient_normals_consistent, pca_normals
from qifreport.registration.scan import median_spacing

__all__ = [
    "coverage_radius",
    "DeformResult",
    "finish",
    "Match",
    "orient_scan_normals",
    "scan_matcher",
    "ScanMatcher",
]


@dataclass
class DeformResult:
    """Outcome of a deformable registration.

    Attributes
    ----------
    V : (n, 3) registered (virtually fixtured) nominal, mm.
    e : (n, 3) displacement from the rigid base ``V0``, mm.
    residual : (n,) signed normal residual from each vertex to the scan (along the vertex
        normal), mm; NaN where the vertex is not covered.
    covered : (n,) vertices with a scan point within the coverage radius.
    flagged : (n,) vertices flagged as out-of-band (defect candidates).
    held_out : (n,) vertices whose measurement was withheld in the refit.
    weights : (n,) final data weights.
    scale : final robust residual scale, mm.
    passes : passes run.  fallback : the flagged-fraction guard fired.
    flagged_fraction : flagged / covered vertices after the first pass (GB-CICP: the flags its
        guard counts, those above ``guard_floor``).
    guard_fraction, guard_pass : the flagged fraction that fired the guard and the pass that
        flagged it (NaN, 0 when it did not fire): a refit can flag more than the first pass.
    iterations : total iterations.  seconds : wall time.
    params : the parameters actually used (a dataclass; defaults resolved).
    history : per-iteration record.
    method : ``"gbcicp"``, ``"nicp"``, ``"cpd"`` or ``"rbffem"``.
    basis : GB-CICP's bending basis
    (:class:`qifreport.registration.deformable.bending_basis.BendingBasis`), per-part
        state to reuse for further scans of the part; None for the other methods.
    """

    V: np.ndarray
    e: np.ndarray
    residual: np.ndarray
    covered: np.ndarray
    flagged: np.ndarray
    held_out: np.ndarray
    weights: np.ndarray
    scale: float
    passes: int
    fallback: bool
    flagged_fraction: float
    iterations: int
    seconds: float
    params: Any
    history: list[dict] = field(default_factory=list)
    guard_fraction: float = float("nan")
    guard_pass: int = 0
    method: str = "gbcicp"
    basis: Any = None

    @property
    def max_displacement(self) -> float:
        """The largest displacement the fit applied to a vertex, mm (0 for an empty mesh)."""
        return float(np.linalg.norm(self.e, axis=1).max()) if len(self.e) else 0.0


@dataclass
class Match:
    """Correspondences of the nominal vertices to the scan.

    Attributes
    ----------
    target : (n, 3) point-to-plane targets (the vertex projected on the matched scan
        point's tangent plane), mm.
    r : (n,) signed normal residual (along the vertex's side of the scan normal), mm.
    covered : (n,) the matched point lies within the coverage radius tangentially (and,
        when signed, faces the same way as the vertex).
    compat : (n,) ``n . n_scan`` (signed) or ``|n . n_scan|``.
    j : (n,) index of the matched scan point.
    """

    target: np.ndarray
    r: np.ndarray
    covered: np.ndarray
    compat: np.ndarray
    j: np.ndarray


class ScanMatcher:
    """Vertex -> nearest-scan-point correspondences with point-to-plane targets.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  scan_normals : (m, 3) unit scan normals.
    normals : (n, 3) unit vertex normals of the nominal.
    radius : coverage radius, mm (tangential distance to the matched point).
    signed : the scan normals are oriented (outward); a vertex is covered only when its
        normal agrees with the matched measurement's (``n . n_scan >= gate``).
    tree : optional ``cKDTree(P)``.
    max_distance : vertices with no scan point within this distance (mm) are not matched
        (not covered, zero residual, target = the vertex itself); bounding the search
        makes it several times faster.
    """

    def __init__(
        self,
        P: np.ndarray,
        scan_normals: np.ndarray,
        normals: np.ndarray,
        radius: float,
        signed: bool = False,
        gate: float = 0.0,
        tree: cKDTree | None = None,
        max_distance: float = np.inf,
    ):
        self.P = P
        self.Ns = scan_normals
        self.N = normals
        self.radius = radius
        self.signed = signed
        self.gate = gate
        self.max_distance = max_distance
        # without compact nodes the tree answers these queries (many from vertices far from
        # any scan point: the unseen side of the part) several times faster
        self.tree = tree if tree is not None else cKDTree(P, compact_nodes=False)

    def __call__(self, X: np.ndarray, rows: np.ndarray | None = None) -> Match:
        """Match the vertices ``X`` (n, 3) mm; with ``rows`` (k,), ``X`` (k, 3) holds the
        positions of those vertices only (their normals are ``normals[rows]``)."""
        N = self.N if rows is None else np.take(self.N, rows, axis=0)
        dist, j = self.tree.query(
            X, workers=workers_for(len(X)), distance_upper_bound=self.max_distance
        )
        found = np.isfinite(dist)
        j = np.where(found, j, 0)
        # rows gathered by np.take (qifreport.registration.arrays)
        diff = np.where(found[:, None], np.take(self.P, j, axis=0) - X, 0.0)
        ns = np.take(self.Ns, j, axis=0)
        c = np.einsum("ij,ij->i", ns, N)
        s = np.sign(c)
        s[s == 0] = 1.0
        ns = ns * s[:, None]  # point-to-plane along the scan normal, turned like the vertex's
        r = np.einsum("ij,ij->i", diff, ns)
        tang = np.linalg.norm(diff - r[:, None] * ns, axis=1)
        covered = (tang < self.radius) & found
        if self.signed:
            covered &= c >= self.gate
        return Match(
            target=X + r[:, None] * ns,
            r=r,
            covered=covered,
            compat=c if self.signed else np.abs(c),
            j=j,
        )


def finish(
    method: str,
    V0: np.ndarray,
    V: np.ndarray,
    matcher: ScanMatcher,
    params: Any,
    iterations: int,
    seconds: float,
    history: list[dict] | None = None,
) -> DeformResult:
    """Wrap a method's registered vertices ``V`` (n, 3) mm as a :class:`DeformResult`.

    For methods without a defect-flagging scheme (NICP, CPD, RBF-FEM): nothing flagged or
    held out; ``residual``, ``covered`` and ``scale`` from one final match.
    """
    m = matcher(V)
    n = len(V)
    scale = robust_scale(m.r[m.covered]) if m.covered.any() else 0.0
    return DeformResult(
        V=V,
        e=V - V0,
        residual=np.where(m.covered, m.r, np.nan),
        covered=m.covered,
        flagged=np.zeros(n, dtype=bool),
        held_out=np.zeros(n, dtype=bool),
        weights=m.covered.astype(float),
        scale=float(scale),
        passes=1,
        fallback=False,
        flagged_fraction=0.0,
        iterations=int(iterations),
        seconds=float(seconds),
        params=params,
        history=list(history or []),
        method=method,
    )


def orient_scan_normals(
    P: np.ndarray,
    Ns: np.ndarray,
    V: np.ndarray,
    N: np.ndarray,
    k: int = 10,
    sheets: np.ndarray | None = None,
) -> np.ndarray:
    """Outward scan normals: consistent per connected sheet of the scan, each sheet's side
    chosen by a vote of its points against the nearest vertex normal of the posed nominal,
    unless the scan showed it (a wall's two skins, label
    :data:`qifreport.registration.normals.SIDE_KNOWN`).

    A vote rather than a per-point test, because where the free-state deflection exceeds
    half the wall of a thin solid the nearest nominal vertex lies on the other skin.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  Ns : (m, 3) unit scan normals.
    V, N : (n, 3) posed nominal vertices (mm) and their unit normals.
    k : neighbours of the propagation graph.
    sheets : (m,) sheet label of each point when ``Ns`` is already consistent within each
        sheet (:func:`qifreport.registration.normals.orient_normals_consistent`): only the
        vote is made, so one propagation serves several nominals.
    """

    if sheets is None:
        Ns, sheets = orient_normals_consistent(P, Ns, k=k)
    _, near = cKDTree(V).query(P, workers=-1)
    agree = np.einsum("ij,ij->i", Ns, N[near])
    open_ = sheets != SIDE_KNOWN  # the scan's own evidence stands
    votes = np.bincount(sheets[open_], weights=np.sign(agree[open_]))
    flip = np.zeros(len(P), dtype=bool)
    flip[open_] = votes[sheets[open_]] < 0
    out = Ns.copy()
    out[flip] = -out[flip]
    return out


def coverage_radius(V0: np.ndarray, F: np.ndarray, P: np.ndarray) -> float:
    """The shared coverage radius: 1.5 x max(median edge length, median scan spacing), mm."""
    return 1.5 * max(median_edge_length(V0, F), median_spacing(P))


def scan_matcher(
    V0: np.ndarray,
    F: np.ndarray,
    ops: MeshOperators,
    P: np.ndarray,
    scan_normals: np.ndarray | None,
    scan_sheets: np.ndarray | None,
    radius: float | None = None,
    gate: float = 0.5,
    k: int = 12,
) -> ScanMatcher:
    """The :class:`ScanMatcher` with which the baselines (NICP, CPD, RBF-FEM) are finished.

    As :func:`qifreport.registration.deformable.gbcicp.gbcicp` builds its own: coverage radius
    :func:`coverage_radius` unless given; the unsigned compatibility ``|n . n_scan|`` unless
    ``scan_sheets`` is given, when the scan normals are oriented per sheet by a vote against
    the nominal (:func:`orient_scan_normals`) and a vertex facing away
    from its matched measurement (``n . n_scan < gate``) is not covered.

    Parameters
    ----------
    V0 : (n, 3) rigidly aligned nominal, mm.  F : (f, 3).  ops : its operators (normals).
    P : (m, 3) scan, mm.  scan_normals : (m, 3) PCA normals or None (computed, ``k``
    neighbours).  scan_sheets : (m,) sheet labels of consistently oriented normals, or None.
    """
    Ns = scan_normals if scan_normals is not None else pca_normals(P, k)
    r = coverage_radius(V0, F, P) if radius is None else float(radius)
    if scan_sheets is not None:
        Ns = orient_scan_normals(P, Ns, V0, ops.normals, sheets=scan_sheets)
        return ScanMatcher(P, Ns, ops.normals, r, signed=True, gate=gate)
    return ScanMatcher(P, Ns, ops.normals, r, signed=False)
