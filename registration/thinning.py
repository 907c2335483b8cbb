"""Voxel thinning of a scan far denser than the nominal can resolve.

The inspection compares the scan with a triangle mesh: the nominal's resolution, not the
scanner's, sets how much detail a deviation map can hold. A scan many times denser than the
nominal's mesh costs time and memory in every stage (normals, nearest neighbours, the
virtual fixture) and adds nothing the mesh can show, so it is thinned to a grid that follows
the nominal.

The rule (:func:`nominal_spacing`, :func:`thin_scan`):

* **grid** ``h = min(mean nominal edge / 4, diagonal / 300)`` mm: four cells along a mean
  edge. The second term keeps a coarse nominal (a few large triangles) from thinning a
  scan to nothing: it is what a STEP nominal tessellated at its default maximum edge
  (diagonal / 60) gives.
* **thin above a stated density**: when the scan has on average at least
  :data:`MIN_POINTS_PER_VOXEL` (T = 1.5) points per occupied cell of ``h``, every occupied
  cell of a grid finer by ``sqrt(T)`` keeps one point. On a surface that finer grid has
  about T times the cells, so a scan just past the threshold keeps about the points it had
  and a denser one keeps about T per cell of ``h``: the points used, and the cost, never
  fall as a scan gets denser (no cliff), and they stop growing. The bundled samples (1.1-1.3
  points per cell) are not thinned, so their results do not change.
* **the kept point is a measured one**: the point of the cell nearest the centroid of the
  cell's points (ties: the first in file order). Not the centroid itself, which would
  average the range noise away (the measurement-resolution check, :mod:`metrology.resolution`,
  would then credit the scan with a precision it does not have) and cut corners at creases.

Cost: one sort of 64-bit cell keys to count the cells, a second on the finer grid when the
scan is thinned, O(m log m), numpy only, and a few hundred MB beyond the points themselves
on 10 M points (``bench/big_scan.py``).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "CELLS_PER_EDGE",
    "DIAGONAL_CELLS",
    "MIN_POINTS_PER_VOXEL",
    "ThinningReport",
    "nominal_spacing",
    "thin_scan",
]

log = logging.getLogger(__name__)

#: grid cells along a mean nominal edge
CELLS_PER_EDGE = 4.0
#: the grid is never coarser than the nominal's bounding diagonal over this
DIAGONAL_CELLS = 300.0
#: thin only when the scan has at least this many points per occupied cell, on average
MIN_POINTS_PER_VOXEL = 1.5


@dataclass(frozen=True)
class ThinningReport:
    """What became of the points a scan file held.

    Attributes
    ----------
    points_read : valid points in the file.
    duplicates_removed : exact duplicates removed on reading
        (:func:`qifreport.registration.pointcloud.unique_points`).
    points_used : points given to the inspection.
    voxel_mm : the thinning grid's cell size, mm; None when the scan was not thinned.
    grid_mm : the cell size the rule derived from the nominal, mm (None: no rule applied).
    points_per_voxel : mean points per occupied cell of that grid, before thinning (the
        density the rule judged; None: no rule applied).
    """

    points_read: int
    duplicates_removed: int
    points_used: int
    voxel_mm: float | None = None
    grid_mm: float | None = None
    points_per_voxel: float | None = None

    @property
    def thinned(self) -> bool:
        """Whether the scan was thinned."""
        return self.voxel_mm is not None

    def to_dict(self) -> dict:
        """The JSON summary's ``scan_input`` block."""
        return asdict(self)

    def describe(self) -> str:
        """One line for the log."""
        text = f"{self.points_read} points read"
        if self.duplicates_removed:
            text += f", {self.duplicates_removed} exact duplicates removed"
        if self.thinned:
            text += (
                f", thinned to {self.points_used} on a {self.voxel_mm:.3g} mm grid "
                f"({self.points_per_voxel:.1f} points per {self.grid_mm:.3g} mm cell)"
            )
        else:
            text += f", {self.points_used} used"
            if self.grid_mm is not None:
                text += (
                    f" (not thinned: {self.points_per_voxel:.1f} points per "
                    f"{self.grid_mm:.3g} mm cell, < {MIN_POINTS_PER_VOXEL:g})"
                )
        return text


def nominal_spacing(V: np.ndarray, F: np.ndarray) -> float:
    """The thinning grid's cell size for a nominal mesh, mm (module docstring).

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) int triangles.

    Returns
    -------
    h : ``min(mean edge / CELLS_PER_EDGE, diagonal / DIAGONAL_CELLS)``, mm (each edge
        counted once per triangle side).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    edges = np.linalg.norm(V[F[:, [1, 2, 0]]] - V[F], axis=2)
    diagonal = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    return min(float(edges.mean()) / CELLS_PER_EDGE, diagonal / DIAGONAL_CELLS)


def thin_scan(
    P: np.ndarray,
    spacing: float,
    *,
    min_per_voxel: float = MIN_POINTS_PER_VOXEL,
    points_read: int | None = None,
) -> tuple[np.ndarray, ThinningReport]:
    """Keep one point per cell of a grid ``spacing / sqrt(min_per_voxel)``, when the scan
    has at least ``min_per_voxel`` points per occupied cell of ``spacing``.

    Parameters
    ----------
    P : (m, 3) float64 scan points, mm (finite, already de-duplicated).
    spacing : the grid's cell size, mm (:func:`nominal_spacing`).
    min_per_voxel : thin only when the mean number of points per occupied cell of
        ``spacing`` is at least this (at most 1: always thin, on ``spacing`` itself).
    points_read : the points the file held before de-duplication (default ``m``), for the
        report.

    Returns
    -------
    P_thin : (k, 3) the kept points, in their original order (``P`` itself when not thinned).
    report : :class:`ThinningReport`.
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    m = len(P)
    read = m if points_read is None else int(points_read)
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"thinning grid spacing must be a positive length, got {spacing}")
    if m == 0:
        return P, ThinningReport(read, read - m, m)
    order, starts = _cells(P, spacing)
    per_cell = m / len(starts)
    if per_cell < min_per_voxel:
        report = ThinningReport(read, read - m, m, None, float(spacing), per_cell)
        return P, report
    # one point per cell of a grid finer by sqrt(min_per_voxel): on a surface, about
    # min_per_voxel times the cells of the nominal's grid, so a scan just past the
    # threshold keeps about the points it had (no cliff in the cost of a denser scan), and
    # the densest keep about min_per_voxel points per cell of the nominal's grid
    voxel = float(spacing) / np.sqrt(max(min_per_voxel, 1.0))
    if voxel != spacing:
        order, starts = _cells(P, voxel)
    keep = _one_per_cell(P, order, starts)
    report = ThinningReport(read, read - m, len(keep), voxel, float(spacing), per_cell)
    return P[keep], report


def _cells(P: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The points' order by cell of a ``spacing`` grid, and where each occupied cell's
    points start in that order (each int64)."""
    order, ks = _sorted_cells(P, spacing)
    new_cell = np.r_[True, ks[1:] != ks[:-1]]
    del ks
    return order, np.flatnonzero(new_cell)


def _one_per_cell(P: np.ndarray, order: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """The index (sorted) of the point kept in each cell: the one nearest the centroid of
    the cell's points (ties: the first in file order)."""
    m = len(P)
    counts = np.diff(np.r_[starts, m])
    cell = np.repeat(np.arange(len(starts)), counts)  # the cell of each sorted point
    d2 = np.zeros(m)
    for j in range(3):
        x = P[order, j]
        centre = np.add.reduceat(x, starts) / counts
        x -= centre[cell]
        d2 += x * x
    del x
    nearest = d2 == np.minimum.reduceat(d2, starts)[cell]
    del d2, cell
    # the first point (in file order) of each cell among those nearest its centroid
    keep = np.minimum.reduceat(np.where(nearest, order, m), starts)
    keep.sort()
    return keep


def _sorted_cells(P: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The points' order by grid cell, and the sorted cell keys (each (m,) int64).

    When the keys leave room for the point index in 63 bits (any scan of a part: 2^39 cells
    for 16 M points), key and index are packed into one integer and sorted by value, which
    numpy does several times faster than an argsort.
    """
    key = _cell_keys(P, spacing)
    m = len(P)
    bits = max(1, (m - 1).bit_length())
    if int(key.max()) < 2 ** (63 - bits):
        key <<= bits
        key |= np.arange(m, dtype=np.int64)
        key.sort()
        order = key & ((1 << bits) - 1)
        key >>= bits
        return order, key
    order = np.argsort(key)
    return order, key[order]


def _cell_keys(P: np.ndarray, spacing: float) -> np.ndarray:
    """One int64 key (m,) per point naming its grid cell (equal keys: same cell).

    Cell indices from the scan's minimum corner, combined as ``i + ni (j + nj k)``; when the
    grid is too fine for that to fit 63 bits (far outliers), the indices are ranked per axis
    and combined two at a time (exact, one more sort per axis).
    """
    lo = np.array([P[:, j].min() for j in range(3)])  # per column: faster than axis=0
    hi = np.array([P[:, j].max() for j in range(3)])
    n = [int(v) + 1 for v in np.floor((hi - lo) / spacing)]
    buf = np.empty(len(P))
    if float(n[0]) * n[1] * n[2] < 2**62:
        key = np.zeros(len(P), dtype=np.int64)
        for j, stride in enumerate((1, n[0], n[0] * n[1])):
            np.subtract(P[:, j], lo[j], out=buf)
            buf /= spacing
            ijk = buf.astype(np.int64)  # >= 0: truncation is the floor
            ijk *= stride
            key += ijk
        return key
    ranks = []
    for j in range(3):  # float floors (exact below 2^53 cells), ranked per axis
        np.subtract(P[:, j], lo[j], out=buf)
        buf /= spacing
        u, r = np.unique(np.floor(buf), return_inverse=True)
        ranks.append((r.astype(np.int64), len(u)))
    (r0, _), (r1, n1), (r2, _) = ranks
    u01, r01 = np.unique(r0 * n1 + r1, return_inverse=True)  # < m^2: fits
    return r01.astype(np.int64) + len(u01) * r2  # < m^2: fits
