"""Trim-edge deviation: where the scan's edge lies against the open rim of the nominal.

A normal deviation cannot see an error *along* the surface: a sheet trimmed 2 mm too long, or
a whole part 2 % too large, lies on its nominal surface everywhere and passes a profile
check; the rim vertices, where the difference shows, are left unscored
(:mod:`qifreport.metrology.deviation.hygiene`). This module measures the rim directly.

For every open-boundary vertex ``v`` of the (registered) nominal it builds a local frame: the
rim tangent ``t`` (from the boundary edges, oriented by the triangles' winding), the surface
normal ``n`` and the *outward in-plane normal* ``b = t x n`` (in the tangent plane, pointing
away from the material). The scan's edge is estimated in a strip about each rim vertex, where
the points' outward projections end (:mod:`~qifreport.metrology.deviation.rim_strips`). The
strip's size is a length of the part, 2.5 median edges of the nominal, not of the scan: the
reading does not change with the scan's density (a strip holds the outermost rows of a scan
as sparse as the nominal's own vertices; a sparser scan's strips hold too few points, and
those rim vertices are not seen).

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

Closed solids (a STEP part's tessellation) have no open boundary. Their trim edges are the sharp
creases between a large face and a thin side wall, and ``trim_edges="auto"`` (the default) then
measures those (:func:`~qifreport.metrology.deviation.rim.crease_frames`): the mesh is cut along
its creases (dihedral angle above ``crease_angle``, 60 degrees) into smooth patches, and each
patch's rim is measured as above with three changes: the frame uses the patch's own normal (not
the average across the crease), a frame is kept only where its patch extends a full strip depth
inward (the large face beside a side wall, not the 2 mm side wall itself), and only scan points
whose PCA normal lies within 45 degrees of the patch's normal and within ``radius / 4`` of its
tangent plane enter the strip (not the side wall's points, nor the far skin's). A one-sided scan
sees the upper skin's rims only, so about half the rim length is "not seen". A mesh with neither
an open boundary nor a sharp crease (a smooth closed surface) returns ``status == "no rim"``
with empty arrays and measures nothing.

The scale of the part is estimated from these deviations by
:mod:`qifreport.metrology.deviation.size`.

All lengths are mm; ``V`` (n, 3), ``F`` (f, 3), ``P`` (m, 3).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.deviation.edge_statistics import EdgeDeviation, rim_segments
from qifreport.metrology.deviation.rim import crease_frames, rim_frames
from qifreport.metrology.deviation.rim_strips import rim_strips
from qifreport.registration.mesh import median_edge_length

__all__ = [
    "edge_deviation",
]

log = logging.getLogger(__name__)

#: the strip's half-width along the rim, depth and normal window, in median nominal edges
_STRIP_EDGES = 2.5


def _checked(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    tolerance: float,
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
    if tree is None and len(P):
        tree = cKDTree(P)
    if radius is None:
        radius = _STRIP_EDGES * median_edge_length(V, F)
    radius = float(radius)
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    if trim_edges not in ("auto", "rim", "crease"):
        raise ValueError(f"trim_edges must be 'auto', 'rim' or 'crease', got {trim_edges!r}")
    return P, tree, tolerance, radius


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
        2.5 median edge lengths of the nominal.
    max_gap : half-width of the coarse pass's window along the outward normal, mm: a scan
        edge more than this inside the nominal rim is "not seen", one more than this
        outside is not found. Default ``2.5 x radius``.
    min_points : fewest strip points for a seen vertex.
    corner_angle : degrees; rim vertices at corners are not measured
        (:func:`~qifreport.metrology.deviation.rim.rim_frames`).
    trim_edges : ``"rim"`` (the open boundary only), ``"crease"`` (the rims of the smooth
        patches between sharp creases, :func:`~qifreport.metrology.deviation.rim.crease_frames`:
        the trim edges of a closed solid) or ``"auto"`` (default): the open boundary if there
        is one, else the creases.
    crease_angle : degrees, the creases of ``"crease"`` mode
        (:func:`~qifreport.metrology.deviation.rim.split_at_creases`).
    tree : ``cKDTree(P)`` when at hand (used when every point of ``P`` is finite).

    Returns
    -------
    :class:`~qifreport.metrology.deviation.edge_statistics.EdgeDeviation`.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    P, tree, tolerance, radius = _checked(V, F, P, tolerance, radius, trim_edges, tree)
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
    e, n2, ok = rim_strips(P, tree, rim, measured, radius, max_gap, min_points)
    dev[measured[ok]] = e[ok]
    cnt[measured] = n2
    status = "measured" if ok.any() else "not seen"
    out = EdgeDeviation(status, rim, dev, cnt, tolerance, radius, max_gap)
    out.segments = rim_segments(rim, dev, tolerance)
    _log_summary(out, tolerance)
    return out


def _log_summary(out: EdgeDeviation, tolerance: float) -> None:
    """Log a measured rim's length, seen share, median deviation and the segments beyond
    ``tolerance`` (mm)."""
    log.info(
        "edge deviation: rim %.0f mm, seen %.0f %%, median %+.3f mm, %d segment(s) beyond %.3g mm",
        out.rim_length,
        100 * out.seen_fraction,
        out.statistics()["median"],
        len(out.segments),
        tolerance,
    )
