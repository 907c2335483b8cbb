"""Scan point clouds: loading, validation and local PCA normals.

A scan ``P`` is an (m, 3) float64 array of points in mm, as an optically tracked scanner
delivers it: unordered, partial, noisy, already merged from all views (paper Section 4.1).
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from .errors import InputError

log = logging.getLogger(__name__)

SCAN_SUFFIXES = (".ply", ".xyz", ".txt", ".csv", ".npy", ".stl", ".obj", ".off")
MIN_POINTS = 100


def load_scan(path: str | Path) -> np.ndarray:
    """Read a scan point cloud.

    PLY (points, or the vertices of a mesh), STL/OBJ/OFF (vertices), XYZ/TXT/CSV (first three
    columns of each row), NPY ((m, 3) array). Units are taken as mm.

    Raises
    ------
    InputError
        Missing or unreadable file, fewer than ``MIN_POINTS`` points, or non-finite
        coordinates; the message is one line naming the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"scan not found: {path}")
    suffix = path.suffix.lower()
    if suffix not in SCAN_SUFFIXES:
        raise InputError(f"unsupported scan format {path.suffix!r} (use PLY, XYZ, CSV or NPY)")
    try:
        if suffix == ".npy":
            P = np.load(path, allow_pickle=False)
        elif suffix in (".xyz", ".txt", ".csv"):
            delim = "," if suffix == ".csv" else None
            with warnings.catch_warnings():  # an empty file is reported below, once
                warnings.simplefilter("ignore", UserWarning)
                P = np.loadtxt(path, delimiter=delim, usecols=(0, 1, 2), ndmin=2, comments="#")
        else:
            geom = trimesh.load(str(path), process=False)
            if isinstance(geom, trimesh.Scene):
                geom = geom.to_geometry() if geom.geometry else None
            P = np.asarray(getattr(geom, "vertices", np.empty((0, 3))))
    except InputError:
        raise
    except Exception as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot read scan {path.name}: {why}") from None
    return validate_scan(P, path.name)


def validate_scan(P: np.ndarray, name: str = "scan") -> np.ndarray:
    """Check an (m, 3) point array; return it as contiguous float64 or raise :class:`InputError`."""
    P = np.asarray(P)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"{name}: expected (m, 3) points, got shape {P.shape}")
    P = np.ascontiguousarray(P, dtype=np.float64)
    if len(P) == 0:
        raise InputError(f"{name}: the scan is empty (no points)")
    bad = ~np.isfinite(P).all(axis=1)
    if bad.any():
        raise InputError(f"{name}: {int(bad.sum())} of {len(P)} points have NaN/inf coordinates")
    if len(P) < MIN_POINTS:
        raise InputError(f"{name}: only {len(P)} points (at least {MIN_POINTS} needed)")
    return P


def pca_normals(P: np.ndarray, k: int = 12, tree: cKDTree | None = None) -> np.ndarray:
    """Unit normals (m, 3) of the scan from the PCA of each point's ``k`` nearest neighbours.

    The sign is arbitrary (a one-sided scan has no inside); use ``|n . n_scan|``.
    """
    tree = tree or cKDTree(P)
    k = min(k, len(P))
    _, idx = tree.query(P, k=k, workers=-1)
    X = P[idx] - P[idx].mean(axis=1, keepdims=True)
    C = np.einsum("mki,mkj->mij", X, X)
    _, vecs = np.linalg.eigh(C)
    return vecs[:, :, 0]


def median_spacing(P: np.ndarray, tree: cKDTree | None = None) -> float:
    """Median nearest-neighbour distance (mm) of the scan points."""
    tree = tree or cKDTree(P)
    d, _ = tree.query(P, k=2, workers=-1)
    return float(np.median(d[:, 1]))


def orient_normals_consistent(
    P: np.ndarray, Ns: np.ndarray, k: int = 10, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Give unsigned normals (m, 3) one consistent side per connected sheet of the scan.

    The sign is propagated along a minimum spanning tree of the k-NN graph weighted by
    ``1 - |n_i . n_j|`` (Hoppe et al. 1992): each point takes the side of its parent, and the
    tree crosses creases where the normals turn least. The overall side of each connected
    component is still arbitrary: the caller chooses it (e.g. by a vote against a posed
    nominal, :func:`registration.gbcicp.gbcicp`).

    Returns
    -------
    normals : (m, 3) unit normals, consistently signed within each component.
    labels : (m,) int component label of each point.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import (
        breadth_first_order,
        connected_components,
        minimum_spanning_tree,
    )

    m = len(P)
    tree = tree or cKDTree(P)
    k = min(k, m - 1)
    _, nb = tree.query(P, k=k + 1, workers=-1)
    i = np.repeat(np.arange(m), k)
    j = nb[:, 1:].ravel()
    w = 1.0 - np.abs(np.einsum("ij,ij->i", Ns[i], Ns[j])) + 1e-6
    G = coo_matrix((w, (i, j)), shape=(m, m)).tocsr()
    G = G.maximum(G.T)
    T = minimum_spanning_tree(G)
    T = T.maximum(T.T)
    n_comp, labels = connected_components(T, directed=False)
    # parent of every point in a breadth-first tree of its component (roots: themselves)
    pred = np.arange(m)
    for c in range(n_comp):
        root = int(np.flatnonzero(labels == c)[0])
        order, p = breadth_first_order(T, root, directed=False)
        pred[order[1:]] = p[order[1:]]
    # a point's side relative to its root is the product of the edge signs along its tree
    # path: pointer doubling, log2(depth) vectorised steps
    flip = np.where(np.einsum("ij,ij->i", Ns, Ns[pred]) < 0, -1.0, 1.0)
    up = pred.copy()
    while np.any(up != up[up]):
        flip *= flip[up]
        up = up[up]
    flip *= flip[up]  # the roots' own sign, +1
    return Ns * flip[:, None], labels
