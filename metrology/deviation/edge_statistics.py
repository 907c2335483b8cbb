"""The trim-edge deviation's result: its statistics, its out-of-tolerance rim segments.

:class:`EdgeDeviation` holds the edge deviation of every rim vertex
(:func:`qifreport.metrology.deviation.edges.edge_deviation`) with its length-weighted
statistics, JSON summary and one-line findings; :func:`rim_segments` groups the rim
vertices beyond a tolerance into connected stretches (:class:`EdgeSegment`).

All lengths are mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from qifreport.metrology.acceptance.statistics import json_float
from qifreport.metrology.deviation.part_class import PartClass
from qifreport.metrology.deviation.rim import RimFrames

__all__ = [
    "EdgeDeviation",
    "EdgeSegment",
    "rim_segments",
]


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
    rim : :class:`~qifreport.metrology.deviation.rim.RimFrames` of the nominal the deviations
        refer to.
    deviation : (k,) signed in-plane distance from the nominal edge to the scan's edge
        along the outward normal, mm (+ = scan material beyond the edge); NaN where not seen.
    points : (k,) scan points in each vertex's final strip.
    tolerance : the edge tolerance, mm: a seen vertex with ``|deviation| > tolerance`` is
        out of tolerance.
    radius : strip half-width along the rim, strip depth and normal window, mm.
    max_gap : the wide window of the coarse pass, mm (a scan edge farther inside the nominal
        rim than this is "not seen").
    segments : connected rim stretches out of tolerance, longest first.
    part : the part's class (:func:`~qifreport.metrology.deviation.part_class.part_class`):
        on a solid the trim edges and the size read from them are reported, not judged;
        None: not classified (judged).
    """

    status: str
    rim: RimFrames
    deviation: np.ndarray
    points: np.ndarray
    tolerance: float
    radius: float
    max_gap: float
    segments: list[EdgeSegment] = field(default_factory=list)
    part: PartClass | None = None

    @property
    def judged(self) -> bool:
        """Whether the trim edges (and the size read from them) take part in the verdict:
        not on a solid (:attr:`part`)."""
        return self.part is None or self.part.judges_trim_edges

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

    @property
    def spacing(self) -> float:
        """The scan's point spacing at the rim, mm: ``sqrt(area / points)`` of the seen
        strips (``2 radius`` along the rim by ``radius`` deep), their median; NaN when
        nothing was seen. The sampling leaves each edge's position uncertain by about this
        much (the true edge lies between the outermost points and the next, unsampled ones)."""
        n = self.points[self.seen]
        n = n[n > 0]
        if len(n) == 0:
            return float("nan")
        return float(self.radius * np.sqrt(2.0 / np.median(n)))

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
            "spacing_mm": json_float(self.spacing),
            "statistics_mm": {k: json_float(v) for k, v in self.statistics().items()},
            "out_of_tolerance_length_mm": json_float(self.out_of_tolerance_length),
            "part_class": None if self.part is None else self.part.to_dict(),
            "judged": self.judged,
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
            f"P05/P95 {s['p05']:+.2f}/{s['p95']:+.2f} mm (point spacing {self.spacing:.2f} mm)"
            + ("" if self.judged else f"; reported, not judged: {self.part.describe()}")
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


def rim_segments(rim: RimFrames, values: np.ndarray, tolerance: float) -> list[EdgeSegment]:
    """Connected stretches of the rim where ``|values| > tolerance``, longest first.

    Parameters
    ----------
    rim : :class:`~qifreport.metrology.deviation.rim.RimFrames`.  values : (k,) per rim vertex,
        mm (NaN: not seen, never out).
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
