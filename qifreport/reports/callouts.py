"""Deviation callouts of the map views: the signed deviation printed at a few points.

As on a commercial inspection report, the deviation maps carry labels with the signed
deviation (mm, the page's 3 decimals, :func:`~qifreport.reports.kit.fmt_smm`) and a leader
line to the point it was measured at:

* the **worst point of every numbered region** (the regions the maps number, the first
  ``n_listed`` of the region table): the region's ``peak`` where it occurs, printed beside
  the region's number (one label: the number in its circle, the value after it);
* **points of interest**: the part's largest proud (``max``) and largest sunk (``min``)
  scored deviation, each unless it lies in a numbered region (whose label already gives
  the region's worst value), and with two or more tolerances the extreme (largest
  ``|dev|``) of each tolerance's surface (``T2 max``), unless it is one of the points
  already called out.

Every value is the one the QIF and JSON reports hold: a region's ``peak`` (QIF
``region_<k>_peak_mm``) and the deviation at a vertex (the whole part's and each tolerance's
``max_pos``/``min_neg``). A point is called out once, in the first view (A, B, C) that shows
it and has room for the label, and not at all when no view shows it; at most
:data:`MAX_PER_VIEW` values per view, regions first, so the page stays legible.

:class:`LabelPlacer` finds the room: a label goes beside its point, around it at growing
distances, never over another label, over a point another label names, or out of the
picture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from qifreport.metrology.acceptance.criteria import Region
from qifreport.metrology.inspection import InspectionResult

from .kit import Box, fmt_smm

__all__ = ["MAX_PER_VIEW", "Callout", "LabelPlacer", "callouts", "leader_end"]

#: at most this many deviation values are printed on one view
MAX_PER_VIEW = 6
#: a tolerance's key is cut to this many characters in its callout
_KEY_CHARS = 8


@dataclass(frozen=True)
class Callout:
    """A signed deviation to print on the maps at a point.

    Attributes
    ----------
    key : unique name of the point (``"region 1"``, ``"max"``, ``"min"``, ``"zone T2"``),
        as passed to :func:`~qifreport.reports.render.render_views` (``points``).
    value : the signed deviation, mm.
    position : (3,) the point on the registered nominal, mm (for a region found on the
        scan points, the region's vertex nearest its peak point).
    region : the number of the region whose worst point it is (1 = the first of the region
        table), or None for a point of interest.
    tag : what the value is, printed before it (``"max"``, ``"T2 min"``; empty for a
        region's worst point: its number says it).
    vertex : the nominal vertex it is measured at, or None (a region found on the scan
        points peaks at a point).
    """

    key: str
    value: float
    position: np.ndarray
    region: int | None = None
    tag: str = ""
    vertex: int | None = None

    @property
    def text(self) -> str:
        """The value as printed (``"+0.896"``), after its tag when it has one."""
        return f"{self.tag} {fmt_smm(self.value)}" if self.tag else fmt_smm(self.value)


def callouts(res: InspectionResult, n_listed: int) -> list[Callout]:
    """The points to call out on the maps of ``res``, most important first.

    Parameters
    ----------
    res : the inspection result.
    n_listed : how many regions the maps number (the rows of the region table).

    Returns
    -------
    list of :class:`Callout`
        The worst point of each numbered region (in region order), then the part's largest
        proud and largest sunk scored deviation (unless in a numbered region), then each
        tolerance's extreme when there are two or more (unless already called out).
    """
    V = np.asarray(res.V_registered, dtype=float)
    dev = np.asarray(res.deviation, dtype=float)
    regions = list(res.acceptance.regions)[: max(int(n_listed), 0)]
    out = [
        Callout(
            key=f"region {k}",
            value=float(r.peak),
            position=_on_surface(r, V),
            region=k,
            vertex=int(r.peak_vertex) if r.peak_location is None else None,
        )
        for k, r in enumerate(regions, start=1)
    ]
    in_region = np.zeros(len(V), dtype=bool)
    for r in regions:
        in_region[np.asarray(r.vertices, dtype=np.int64)] = True
    scored = np.isfinite(dev)
    if scored.any():
        for tag, pick in (("max", np.argmax), ("min", np.argmin)):
            v = int(pick(np.where(scored, dev, -np.inf if tag == "max" else np.inf)))
            if not in_region[v] and (dev[v] > 0 if tag == "max" else dev[v] < 0):
                out.append(Callout(tag, float(dev[v]), V[v].copy(), tag=tag, vertex=v))
    if len(res.zones) >= 2:
        out += _zone_extremes(res, V, dev, in_region, {c.vertex for c in out})
    return out


def _on_surface(region: Region, V: np.ndarray) -> np.ndarray:
    """(3,) mm: where a region's worst point is on the registered nominal ``V``: its peak
    vertex, or for a region found on the scan points the region's vertex nearest its peak
    point (the point itself lies off the surface by its deviation: a sunk one would be
    hidden behind the surface in every view)."""
    if region.peak_location is None:
        return V[int(region.peak_vertex)].copy()
    idx = np.asarray(region.vertices, dtype=np.int64)
    p = np.asarray(region.peak_location, dtype=float)
    if len(idx) == 0:
        return p.copy()
    return V[idx[np.argmin(np.linalg.norm(V[idx] - p, axis=1))]].copy()


def _zone_extremes(
    res: InspectionResult, V: np.ndarray, dev: np.ndarray, in_region: np.ndarray, taken: set
) -> list[Callout]:
    """Each tolerance's largest ``|dev|`` on its own surface, where the map shows that same
    value (a surface judged in another state than the map is left out), not in a numbered
    region and not at a vertex already called out."""
    out = []
    for z in res.zones:
        if z.deviation is None:
            continue
        zd = np.asarray(z.deviation, dtype=float)
        if not np.isfinite(zd).any():
            continue
        v = int(np.nanargmax(np.abs(zd)))
        if in_region[v] or v in taken or zd[v] != dev[v]:
            continue
        taken.add(v)
        tag = f"{z.zone.key[:_KEY_CHARS]} {'max' if zd[v] > 0 else 'min'}"
        out.append(Callout(f"zone {z.zone.key}", float(zd[v]), V[v].copy(), tag=tag, vertex=v))
    return out


# ------------------------------------------------------------------------------- placing


class LabelPlacer:
    """Room for labels on one map picture: each beside its point, none over another.

    Parameters
    ----------
    box : the picture on the page (points).
    anchors : (x, y) page points that labels must leave uncovered (every point a label
        of this picture names, and the clamps).
    """

    #: gaps tried between a label and its point (beyond the region's extent), points
    GAPS = (3.0, 10.0, 18.0, 28.0, 40.0)
    #: directions tried, degrees counter-clockwise from +x (diagonals first)
    ANGLES = (45, 135, -45, -135, 90, -90, 0, 180, 22, 158, -22, -158)

    def __init__(self, box: Box, anchors: list[tuple[float, float]]):
        self.box = box
        self.anchors = list(anchors)
        self.placed: list[tuple[float, float, float, float]] = []  # x0, y0, x1, y1
        self.leaders: list[tuple[float, float, float, float]] = []  # ax, ay, ex, ey

    def reserve(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Keep labels off the rectangle ``(x0, y0)``-``(x1, y1)`` (points), e.g. a clamp's
        mark and name."""
        self.placed.append((x0, y0, x1, y1))

    def place(
        self, ax: float, ay: float, w: float, h: float, extent: float = 0.0
    ) -> tuple[float, float] | None:
        """The centre of a ``w`` x ``h`` label (points) for the point ``(ax, ay)``, or None
        when there is no room; the label is then reserved.

        The label is tried beyond ``extent`` (how far the region it names reaches from the
        point, capped at 40 pt) and then close to the point, at each gap in every direction,
        its near edge at the gap's distance. Its leader line may cross no other label, and
        it may cover no other label's leader.
        """
        ext = min(extent, 40.0)
        for base in (ext, 0.0) if ext > 0 else (0.0,):
            for gap in self.GAPS:
                for ang in self.ANGLES:
                    c, s = math.cos(math.radians(ang)), math.sin(math.radians(ang))
                    reach = base + gap + abs(c) * w / 2 + abs(s) * h / 2
                    px, py = ax + reach * c, ay + reach * s
                    rect = (px - w / 2, py - h / 2, px + w / 2, py + h / 2)
                    leader = (ax, ay, *leader_end(ax, ay, px, py, w, h))
                    if self._free(rect, leader):
                        self.placed.append(rect)
                        self.leaders.append(leader)
                        return px, py
        return None

    def _free(self, rect: tuple, leader: tuple) -> bool:
        b = self.box
        x0, y0, x1, y1 = rect
        if x0 < b.x + 1 or x1 > b.x + b.w - 1 or y0 < b.y + 1 or y1 > b.top - 1:
            return False
        if any(
            x0 < q[2] + 1.5 and q[0] < x1 + 1.5 and y0 < q[3] + 1.5 and q[1] < y1 + 1.5
            for q in self.placed
        ):
            return False
        if any(x0 - 1 < qx < x1 + 1 and y0 - 1 < qy < y1 + 1 for qx, qy in self.anchors):
            return False
        if any(_crosses(seg, rect, 1.0) for seg in self.leaders):
            return False
        return not any(_crosses(leader, q, 0.5) for q in self.placed)


def _crosses(seg: tuple, rect: tuple, pad: float) -> bool:
    """Whether the segment ``(ax, ay, bx, by)`` meets the rectangle ``(x0, y0, x1, y1)``
    grown by ``pad`` (points; Liang-Barsky clipping)."""
    ax, ay, bx, by = seg
    x0, y0, x1, y1 = rect[0] - pad, rect[1] - pad, rect[2] + pad, rect[3] + pad
    t0, t1 = 0.0, 1.0
    for p, q in (
        (-(bx - ax), ax - x0),
        (bx - ax, x1 - ax),
        (-(by - ay), ay - y0),
        (by - ay, y1 - ay),
    ):
        if abs(p) < 1e-12:
            if q < 0:
                return False
            continue
        t = q / p
        if p < 0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
        if t0 > t1:
            return False
    return True


def leader_end(ax: float, ay: float, cx: float, cy: float, w: float, h: float) -> tuple:
    """Where the leader from the point ``(ax, ay)`` meets the edge of the ``w`` x ``h``
    label centred at ``(cx, cy)`` (points)."""
    dx, dy = ax - cx, ay - cy
    t = min(
        (w / 2) / abs(dx) if abs(dx) > 1e-9 else math.inf,
        (h / 2) / abs(dy) if abs(dy) > 1e-9 else math.inf,
    )
    return cx + dx * min(t, 1.0), cy + dy * min(t, 1.0)
