"""Stray points: scan points that belong to no measured surface.

A real scan holds points that are not on the part: reflections, dust, a spark of the
fixture, the scanner's ghosts. They lie alone, away from any surface the scanner swept.
The outlier model (:func:`stray_points`) needs no registration, so the seat, the rigid fit
and the virtual fixture are spared them too:

* two points are **linked** when each is among the other's :data:`LINK_NEIGHBOURS` nearest
  (mutual neighbours: a sparse strip of a grazing view links within itself, while a point
  off a surface has surface points as its nearest but is none of theirs), at most
  :data:`LINK_SPACINGS` median point spacings apart;
* a **surface patch** is a connected set of linked points sampled like a surface: at
  least :data:`MIN_PATCH_POINTS` points whose median link is at most
  :data:`PATCH_LINK_SPACINGS` median spacings (a scanned surface links at about 2, a
  cloud of stray points dense enough to link at 9-16): measured material (a rib, a flash,
  a clamp in the scan: what the inspection judges as added material or as deviation);
* every other point is **stray**: counted, reported, and given to no stage.

A stray point closer to a surface than the link distance joins that surface's patch: the
measured surface's own robust reading of its points (the features' form filter, the
vertices' robust local fit) is what keeps it from deciding.

A scan with more than :data:`STRAY_LIMIT` of its points stray is not a scan of one part
seen clearly: the model is stated up to that share, and the inspection's verdict above it
is NOT ESTABLISHED with the share named (:attr:`StrayPoints.over_limit`).

Lengths mm; ``P`` (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "LINK_NEIGHBOURS",
    "LINK_SPACINGS",
    "MIN_PATCH_POINTS",
    "PARTITION_LINKS",
    "PATCH_LINK_SPACINGS",
    "STRAY_LIMIT",
    "StrayPoints",
    "median_link",
    "stray_points",
    "without_stray",
]

#: nearest neighbours a point is linked to (within :data:`LINK_SPACINGS`)
LINK_NEIGHBOURS = 8
#: the longest link, in median point spacings: a scan's density falls tenfold and more
#: on grazing views and at the edge of a view (a simulated two-view scan: strips 1.2-5 mm
#: from the rest at a 0.24 mm median spacing) and stays one surface
LINK_SPACINGS = 25.0
#: the fewest points of a surface patch: fewer are stray (at the sample scans' 0.38 mm
#: spacing, about 1.5 mm^2 of surface)
MIN_PATCH_POINTS = 10
#: the longest median link of a surface patch, in median point spacings
PATCH_LINK_SPACINGS = 5.0
#: the largest share of stray points the outlier model is stated for: up to it, stray points
#: never change a verdict; above it, the verdict is not established
STRAY_LIMIT = 0.02


@dataclass(frozen=True)
class StrayPoints:
    """The stray points of a scan (:func:`stray_points`).

    Attributes
    ----------
    mask : (m,) bool, the stray points.
    spacing : the scan's median point spacing, mm.
    link : the longest link between two points of one surface patch, mm.
    min_patch : the fewest points of a surface patch.
    limit : the largest stray share the model is stated for (:data:`STRAY_LIMIT`).
    """

    mask: np.ndarray
    spacing: float
    link: float
    min_patch: int = MIN_PATCH_POINTS
    limit: float = STRAY_LIMIT

    @property
    def count(self) -> int:
        """How many points are stray."""
        return int(self.mask.sum())

    @property
    def share(self) -> float:
        """The stray points' share of the scan's points."""
        return self.count / max(len(self.mask), 1)

    @property
    def over_limit(self) -> bool:
        """More of the scan is stray than the outlier model is stated for."""
        return self.share > self.limit

    def describe(self) -> str:
        """One line: how many points were stray and what the model is."""
        return (
            f"{self.count} stray point(s), {100 * self.share:.2f} % of the scan, left out "
            f"(in no surface patch of {self.min_patch}+ points linked within "
            f"{self.link:.2g} mm whose median link is at most "
            f"{PATCH_LINK_SPACINGS * self.spacing:.2g} mm; the model holds up to "
            f"{100 * self.limit:g} %)"
        )

    def refusal(self) -> str | None:
        """Why the verdict is not established (None: within the model's limit)."""
        if not self.over_limit:
            return None
        return (
            f"the scan holds {100 * self.share:.1f} % stray points ({self.count}, in no "
            f"surface patch), more than the {100 * self.limit:g} % the outlier model is "
            "stated for"
        )

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {
            "count": self.count,
            "share": self.share,
            "spacing_mm": self.spacing,
            "link_mm": self.link,
            "min_patch_points": self.min_patch,
            "limit": self.limit,
        }


def stray_points(
    P: np.ndarray,
    *,
    neighbours: int = LINK_NEIGHBOURS,
    link_spacings: float = LINK_SPACINGS,
    min_patch: int = MIN_PATCH_POINTS,
    tree: cKDTree | None = None,
) -> StrayPoints:
    """The points of ``P`` (m, 3) mm in no surface patch (module docstring).

    Parameters
    ----------
    P : (m, 3) scan points, mm, in any placement.
    neighbours : nearest neighbours each point is linked to.
    link_spacings : the longest link, in median nearest-neighbour spacings.
    min_patch : the fewest points of a surface patch.
    tree : ``cKDTree(P)``, when the caller has it.
    """
    P = np.asarray(P, dtype=np.float64)
    m = len(P)
    if m <= min_patch:
        return StrayPoints(np.zeros(m, dtype=bool), 0.0, 0.0, min_patch)
    tree = cKDTree(P) if tree is None else tree
    k = min(neighbours + 1, m)
    d, j = tree.query(P, k=k, workers=-1)
    spacing = float(np.median(d[:, 1]))
    link = link_spacings * max(spacing, 1e-12)
    near = (d[:, 1:] <= link) & (j[:, 1:] < m)
    rows = np.repeat(np.arange(m), k - 1)[near.ravel()]
    cols = j[:, 1:][near]
    directed = coo_matrix((d[:, 1:][near], (rows, cols)), shape=(m, m)).tocsr()
    mutual = directed.multiply(directed.T > 0).tocoo()
    n, label = connected_components(mutual, directed=False)
    size = np.bincount(label, minlength=n)
    surface = (size >= min_patch) & (median_link(mutual, label, n) <= PATCH_LINK_SPACINGS * spacing)
    return StrayPoints(~surface[label], spacing, link, min_patch)


def median_link(links: coo_matrix, label: np.ndarray, n: int) -> np.ndarray:
    """(n,) the median length of each component's links (a sparse COO matrix of link
    lengths, mm; ``inf`` for a component without one): the upper median, the element at
    ``count // 2`` of the sorted lengths. A component with many links (a scan's surface is
    a few) is selected by :func:`numpy.partition`, the rest by one sort."""
    group, data = label[links.row], links.data
    count = np.bincount(group, minlength=n)
    out = np.full(n, np.inf)
    big = np.flatnonzero(count >= PARTITION_LINKS)
    for g in big:
        x = data[group == g]
        out[g] = np.partition(x, count[g] // 2)[count[g] // 2]
    if len(big):
        rest = count[group] < PARTITION_LINKS
        group, data = group[rest], data[rest]
        count = np.bincount(group, minlength=n)
    order = np.lexsort((data, group))
    group, length = group[order], data[order]
    mid = np.searchsorted(group, np.arange(n)) + count // 2
    has = count > 0
    out[has] = length[mid[has]]
    return out


#: links from which a component's median is selected on its own (:func:`median_link`)
PARTITION_LINKS = 10_000


def without_stray(P: np.ndarray, **options) -> tuple[np.ndarray, StrayPoints]:
    """The points of ``P`` (m, 3) mm in a surface patch, and the stray ones
    (:func:`stray_points` with ``options``)."""
    stray = stray_points(P, **options)
    if not stray.count:
        return np.asarray(P, dtype=np.float64), stray
    return np.asarray(P, dtype=np.float64)[~stray.mask], stray
