"""The scan as the product speaks of it: the points measured on one part, and where from.

:class:`Scan` is what :func:`qifreport.registration.pointcloud.read_scan` returns for a file
(PLY, STL, OBJ, OFF, XYZ/TXT/CSV, NPY, E57): the distinct points in mm, the unit the file
was in, the file, how many points it held. The simulator's scan
(:class:`qifreport.simulate.scanner.SimulatedScan`) is one of these plus its truth.

The density a scan is described by is derived from its spacing (:attr:`Scan.spacing`, the
median distance from a point to its nearest neighbour): a scan sampling a surface on a
square grid of pitch ``s`` has ``1 / s^2`` points per mm^2 (:attr:`Scan.density`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "SPACING_PROBES",
    "Scan",
    "median_spacing",
]

#: how many points (about) :attr:`Scan.spacing` measures at: every ``m // SPACING_PROBES``-th
SPACING_PROBES = 20_000


@dataclass
class Scan:
    """A scan point cloud, in mm, and its provenance.

    Attributes
    ----------
    points : (m, 3) float64 distinct finite points, mm.
    normals : (m, 3) unit surface normals given with the points, or None (the file readers
        keep none: the inspection estimates its own from the points).
    units : the length unit of the numbers in the file before their conversion to mm
        (``"mm"``, ``"in"``, ``"m"``: :data:`qifreport.registration.pointcloud.SCAN_UNITS`).
    source : the file read, None for points made in memory.
    points_read : the valid points in the file before exact duplicates were removed
        (``>= m``); None when made: ``m``.
    format : the format read (``"ply"``, ``"stl"``, ``"obj"``, ``"off"``, ``"text"``,
        ``"npy"``, ``"e57"``), ``"memory"`` for points made in memory, ``"simulated"`` for the
        virtual scanner's.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    units: str = "mm"
    source: Path | None = None
    points_read: int | None = None
    format: str = "memory"

    def __post_init__(self) -> None:
        if self.points_read is None:
            self.points_read = len(self.points)

    @property
    def n(self) -> int:
        """The number of points ``m``."""
        return len(self.points)

    @property
    def name(self) -> str:
        """What messages call the scan: its file's name, ``"scan"`` without one."""
        return "scan" if self.source is None else Path(self.source).name

    @cached_property
    def spacing(self) -> float:
        """The median nearest-neighbour distance of the points, mm, measured at about
        :data:`SPACING_PROBES` of them (:func:`median_spacing`)."""
        return median_spacing(self.points, probes=SPACING_PROBES)

    @property
    def density(self) -> float:
        """Points per mm^2 of surface, ``1 / spacing^2``: exact for a square grid of pitch
        ``spacing``; points on a hexagonal grid of that pitch are ``2 / sqrt(3)`` (1.15)
        times denser. Where merged views overlap the spacing is smaller than each view's,
        and the density counts the points of every view."""
        return 1.0 / self.spacing**2


def median_spacing(P: np.ndarray, tree: cKDTree | None = None, probes: int | None = None) -> float:
    """Median nearest-neighbour distance (mm) of the scan points ``P`` (m, 3) (``tree``: a
    k-d tree of them to reuse); with ``probes``, measured at about that many of them (every
    ``m // probes``-th) instead of all."""
    tree = tree or cKDTree(P)
    Q = P if probes is None else P[:: max(len(P) // probes, 1)]
    d, _ = tree.query(Q, k=2, workers=-1)
    return float(np.median(d[:, 1]))
