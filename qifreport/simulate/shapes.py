"""Test geometries: the doubly curved thin shell (paper Section 8.3.1), the fandisk (7.1),
a housing, a formed hat bracket with a bead (a STEP solid, for the fixture benchmark) and a
smooth organic closed surface (a bumpy sphere).

The meshes are plain arrays ``V`` (n, 3) float64 in mm and ``F`` (f, 3) int64.
"""

from __future__ import annotations

import logging

import igl
import numpy as np
import trimesh

from qifreport.registration.mesh import bounding_diagonal, load_mesh, weld

__all__ = [
    "bumpy_sphere",
    "fandisk",
    "HAT_CLAMPS",
    "hat_bracket",
    "hat_profile",
    "rim_clamps",
    "grid_triangles",
    "housing",
    "shell_height",
    "thin_shell",
]

log = logging.getLogger(__name__)

# Height field of the thin shell, w(x, y) in mm over x, y in mm. Two unequal radii make it
# doubly curved (mean curvature ~ (1/R1 + 1/R2) / 2 ~ 5e-3 /mm, as the paper's host shell);
# the saddle and cubic terms break the symmetry of a plain elliptic bowl so that no in-plane
# flip or rotation maps the surface onto itself (registration cannot be fooled by symmetry).
_SHELL_R1 = 220.0  # mm, radius along x
_SHELL_R2 = 180.0  # mm, radius along y
_SHELL_SADDLE = 8.0e-4  # 1/mm, coefficient of x*y
_SHELL_CUBIC = 5.0e-6  # 1/mm^2, coefficient of x^3 (curvature grows along +x)


def shell_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Height ``w(x, y)`` (mm) of :func:`thin_shell` at in-plane coordinates ``x, y`` (mm)."""
    return (
        x**2 / (2.0 * _SHELL_R1)
        + y**2 / (2.0 * _SHELL_R2)
        + _SHELL_SADDLE * x * y
        + _SHELL_CUBIC * x**3
    )


def grid_triangles(nx: int, ny: int) -> np.ndarray:
    """Triangles (2 (nx-1)(ny-1), 3) of a regular ``nx`` by ``ny`` vertex grid.

    Vertex ``(i, j)`` has index ``j * nx + i``. The quad diagonal alternates in a
    checkerboard pattern so the triangulation has no preferred direction, and every
    triangle is counter-clockwise in the (x, y) plane (normals towards +z).
    """
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="xy")
    i, j = i.ravel(), j.ravel()
    v00 = j * nx + i
    v10 = v00 + 1
    v01 = v00 + nx
    v11 = v01 + 1
    even = (i + j) % 2 == 0
    # even quads: diagonal v00-v11; odd quads: diagonal v10-v01
    t1 = np.where(even[:, None], np.c_[v00, v10, v11], np.c_[v00, v10, v01])
    t2 = np.where(even[:, None], np.c_[v00, v11, v01], np.c_[v10, v11, v01])
    return np.concatenate([t1, t2]).astype(np.int64)


def thin_shell(
    length: float = 170.0, width: float = 110.0, spacing: float = 1.5
) -> tuple[np.ndarray, np.ndarray]:
    """A gently, doubly curved open thin shell: the graph ``z = w(x, y)`` over a rectangle.

    The part of the paper's defect study (Section 8.3.1): single-sided (no back face), smooth,
    with median absolute mean curvature about 5e-3 /mm (radius ~200 mm) and a total rise of
    about 25-30 mm for the default size. The height field is :func:`shell_height`.

    Parameters
    ----------
    length, width : rectangle extent along x and y (mm), centred at the origin.
    spacing : target grid pitch (mm); the actual pitch is adjusted so the grid spans the
        rectangle exactly. The default gives 114 x 74 = 8436 vertices.

    Returns
    -------
    V : (n, 3) float64, mm.  F : (f, 3) int64, oriented so the normals point to +z.
    """
    if length <= 0 or width <= 0 or spacing <= 0:
        raise ValueError("length, width and spacing must be positive")
    nx = max(2, int(round(length / spacing)) + 1)
    ny = max(2, int(round(width / spacing)) + 1)
    x, y = np.meshgrid(
        np.linspace(-length / 2, length / 2, nx), np.linspace(-width / 2, width / 2, ny)
    )
    x, y = x.ravel(), y.ravel()
    V = np.column_stack([x, y, shell_height(x, y)]).astype(np.float64)
    F = grid_triangles(nx, ny)
    log.debug("thin shell: %d vertices, %d triangles", len(V), len(F))
    return V, F


def fandisk(
    path: str, diagonal: float = 100.0, subdivide: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """The fandisk CAD mesh, centred, scaled and midpoint-subdivided (paper Section 7.1).

    Parameters
    ----------
    path : the ``fandisk.off`` file (read with :func:`qifreport.registration.mesh.load_mesh`).
    diagonal : bounding-box diagonal (mm) after scaling.
    subdivide : number of ``igl.upsample`` passes; each splits every triangle into four
        without moving vertices, so sharp creases stay sharp (7229 -> 28910 vertices once).

    Returns
    -------
    V : (n, 3) float64, mm, bounding-box centre at the origin.  F : (f, 3) int64.
    """
    V, F = load_mesh(path)
    V = V - 0.5 * (V.min(axis=0) + V.max(axis=0))
    V = V * (diagonal / bounding_diagonal(V))
    if subdivide > 0:
        V, F = igl.upsample(np.ascontiguousarray(V), np.ascontiguousarray(F), subdivide)
    return np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)


def bumpy_sphere(radius: float = 40.0, subdivisions: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A smooth organic closed surface: an icosphere of ``radius`` mm (10,242 vertices at 5
    subdivisions, edges about 1.5 mm) displaced along its normals by three low-frequency
    Gaussian bumps (+4, -3 and +2.5 mm over 0.6, 0.5 and 0.7 rad).

    Returns
    -------
    V : (n, 3) float64, mm, centred on the origin.  F : (f, 3) int64, outward.
    """
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    u = np.asarray(m.vertices, dtype=np.float64)
    u /= np.linalg.norm(u, axis=1)[:, None]
    r = np.full(len(u), float(radius))
    for centre, amplitude, width in (
        ((0.0, 0.0, 1.0), 4.0, 0.6),
        ((1.0, 0.0, 0.0), -3.0, 0.5),
        ((0.0, -0.6, -0.8), 2.5, 0.7),
    ):
        angle = np.arccos(np.clip(u @ np.asarray(centre), -1.0, 1.0))
        r += amplitude * np.exp(-0.5 * (angle / width) ** 2)
    return u * r[:, None], np.asarray(m.faces, dtype=np.int64)


def housing(
    length: float = 150.0,
    width: float = 90.0,
    height: float = 40.0,
    power: float = 4.0,
    n: int = 48,
) -> tuple[np.ndarray, np.ndarray]:
    """A smooth housing-like cover: the upper half of a superellipsoid, open underneath.

    ``|x/a|^p + |y/b|^p + |z/c|^p = 1`` (``a = length/2``, ``b = width/2``, ``c = height``,
    ``p = power``: boxy faces joined by large fillets, no sharp edge), meshed as a projected
    cube grid (``n`` cells per cube edge), cut at ``z = 0``, then tapered in plan
    (``y *= 1 + 0.15 x/a``) and sloped (``z *= 1 + 0.12 x/a``) so no rotation maps it onto
    itself (its mirror symmetry ``y -> -y`` is not a rigid motion). Outward normals.

    Returns
    -------
    V : (n, 3) float64, mm.  F : (f, 3) int64.
    """
    a, b, c = length / 2, width / 2, height
    u = np.linspace(-1.0, 1.0, n + 1)
    Vs, Fs, off = [], [], 0
    for axis in range(3):
        others = [k for k in range(3) if k != axis]
        for sign in (-1.0, 1.0):
            g1, g2 = np.meshgrid(u, u)
            X = np.zeros((g1.size, 3))
            X[:, axis] = sign
            X[:, others[0]] = g1.ravel()
            X[:, others[1]] = g2.ravel()
            T = grid_triangles(n + 1, n + 1)
            normal = np.cross(np.eye(3)[others[0]], np.eye(3)[others[1]])
            if normal @ (sign * np.eye(3)[axis]) < 0:
                T = T[:, ::-1]
            Vs.append(X)
            Fs.append(T + off)
            off += len(X)
    V, F = weld(np.concatenate(Vs), np.concatenate(Fs))
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    r = (
        np.abs(d[:, 0] / a) ** power + np.abs(d[:, 1] / b) ** power + np.abs(d[:, 2] / c) ** power
    ) ** (-1.0 / power)
    V = d * r[:, None]
    F = F[V[F][:, :, 2].min(axis=1) >= -1e-9]
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    x = V[:, 0] / a
    V[:, 1] *= 1.0 + 0.15 * x
    V[:, 2] *= 1.0 + 0.12 * x
    return V.astype(np.float64), F.astype(np.int64)


def rim_clamps(
    V: np.ndarray, N: np.ndarray, inset: float = 6.0, limit: float | None = None
) -> tuple[list, np.ndarray]:
    """A sheet's fixture at its rim: four corner clamps along the normal (``A1``-``A4``,
    force ``limit`` N each) and two pins in the sheet's plane at the middle of the short
    sides (``B1`` restraining x and y, ``C1`` y), each at the vertex of ``V`` (n, 3) mm
    nearest its spot ``inset`` mm inside the xy bounding box.

    Returns
    -------
    clamps : list of :class:`qifreport.registration.restraint.clamps.Clamp`.
    normals : (6, 3) the unit normals ``N`` (n, 3) at them.
    """
    from qifreport.registration.restraint.clamps import Clamp

    lo, hi = V[:, :2].min(axis=0) + inset, V[:, :2].max(axis=0) - inset
    spots = [
        ("A1", (lo[0], lo[1]), "n"),
        ("A2", (hi[0], lo[1]), "n"),
        ("A3", (lo[0], hi[1]), "n"),
        ("A4", (hi[0], hi[1]), "n"),
        ("B1", (lo[0], 0.5 * (lo[1] + hi[1])), "xy"),
        ("C1", (hi[0], 0.5 * (lo[1] + hi[1])), "y"),
    ]
    clamps, normals = [], []
    for name, xy, d in spots:
        v = int(np.argmin(np.linalg.norm(V[:, :2] - np.asarray(xy), axis=1)))
        clamps.append(Clamp(name, tuple(float(x) for x in V[v]), d, limit if d == "n" else None))
        normals.append(N[v])
    return clamps, np.array(normals)


# The hat bracket: a formed sheet-metal channel (mid-line of its section in the xz plane, mm)
# with a raised bead along its top, flanges at z = 0 (their undersides), extruded along y.
HAT_WALL = 1.2  # mm, sheet thickness
HAT_LENGTH = 180.0  # mm, along y
_HAT_MIDLINE = (
    (-60.0, 0.0),
    (-40.0, 0.0),
    (-30.0, 28.0),
    (-9.0, 28.0),
    (-5.0, 31.0),
    (5.0, 31.0),
    (9.0, 28.0),
    (30.0, 28.0),
    (40.0, 0.0),
    (60.0, 0.0),
)

#: The bracket's fixture (CSV rows as in ``samples/panel_clamps.csv``): four clamp faces on
#: the flange undersides along the normal (force limit in N set by the caller), a locator on
#: the end face along y and two on the left flange's edge along x.
HAT_CLAMPS = (
    ("A1", (-50.0, -80.0, 0.0), "n"),
    ("A2", (50.0, -80.0, 0.0), "n"),
    ("A3", (-50.0, 80.0, 0.0), "n"),
    ("A4", (50.0, 80.0, 0.0), "n"),
    ("B1", (-19.0, -90.0, 28.0 + HAT_WALL / 2), "y"),
    ("C1", (-60.0, -60.0, HAT_WALL / 2), "x"),
    ("C2", (-60.0, 60.0, HAT_WALL / 2), "x"),
)


def hat_profile(wall: float = HAT_WALL) -> np.ndarray:
    """The closed section of the hat bracket (k, 2) in the xz plane, mm: the mid-line
    offset by +/- ``wall`` / 2 (mitred corners), lifted so the flange undersides are z = 0."""
    M = np.array(_HAT_MIDLINE, dtype=np.float64) + [0.0, wall / 2]
    seg = np.diff(M, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    nrm = np.c_[-seg[:, 1], seg[:, 0]]  # left normals of the segments
    off = np.empty_like(M)
    off[0], off[-1] = nrm[0], nrm[-1]
    mid = nrm[:-1] + nrm[1:]
    off[1:-1] = mid / np.einsum("ij,ij->i", mid, nrm[1:])[:, None]  # mitre: 1/cos(half angle)
    upper, lower = M + off * wall / 2, M - off * wall / 2
    return np.vstack([upper, lower[::-1]])


def hat_bracket(wall: float = HAT_WALL, length: float = HAT_LENGTH):
    """The hat bracket as one valid OCP solid (mm; flange undersides at z = 0, y along its
    length, centred): 120 mm wide over the flanges, 31 mm high at the bead.

    Returns
    -------
    OCP ``TopoDS_Shape`` (a solid).
    """
    import cadquery as cq
    from OCP.BRepCheck import BRepCheck_Analyzer

    pts = [tuple(map(float, p)) for p in hat_profile(wall)]
    body = cq.Workplane("XZ").polyline(pts).close().extrude(length / 2, both=True)
    solids = body.solids().vals()
    if len(solids) != 1 or not BRepCheck_Analyzer(solids[0].wrapped).IsValid():
        raise RuntimeError("the hat bracket is not one valid solid")
    return solids[0].wrapped
