"""The views of the deviation map: which directions show the part best
(:func:`choose_views`), and the parallel projection of a view onto a picture
(:class:`Projection`, :func:`project_view`, :func:`picture_points`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Projection",
    "ViewSpec",
    "camera_frame",
    "choose_views",
    "face_normals_areas",
    "picture_points",
    "project_view",
    "view_from_direction",
    "view_margins",
]

#: camera names of the world axes (the side the camera is on)
_AXIS_NAMES = {
    (2, 1): "top (+z)",
    (2, -1): "bottom (-z)",
    (1, -1): "front (-y)",
    (1, 1): "back (+y)",
    (0, 1): "right (+x)",
    (0, -1): "left (-x)",
}


@dataclass
class ViewSpec:
    """A camera direction.

    Attributes
    ----------
    name : e.g. ``"top (+z)"`` or ``"oblique (+x-y+z)"``.
    direction : (3,) unit vector from the part toward the camera (world frame).
    up : (3,) unit vector that is up on the picture.
    """

    name: str
    direction: np.ndarray
    up: np.ndarray


def face_normals_areas(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (f, 3) and areas (f,), mm^2, of the triangles F of V."""
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a2 = np.linalg.norm(c, axis=1)
    n = c / np.where(a2 > 0, a2, 1.0)[:, None]
    return n, 0.5 * a2


def _vertex_normals_areas(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fn, fa = face_normals_areas(V, F)
    N = np.zeros_like(V)
    A = np.zeros(len(V))
    for k in range(3):
        np.add.at(N, F[:, k], fn * fa[:, None])
        np.add.at(A, F[:, k], fa / 3.0)
    N /= np.maximum(np.linalg.norm(N, axis=1), 1e-300)[:, None]
    return N, A


def _is_open(F: np.ndarray) -> bool:
    """Whether the mesh has boundary edges (an open sheet, seen from both sides)."""
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key = e[:, 0].astype(np.int64) * (int(F.max()) + 1) + e[:, 1]
    _, counts = np.unique(key, return_counts=True)
    return bool(np.any(counts == 1))


def _principal_frame(V: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, 3) rows = principal axes (largest variance first), snapped to the world axes
    when every axis lies within 20 degrees of one (CAD parts are usually axis-aligned)."""
    c = (w[:, None] * V).sum(0) / w.sum()
    X = V - c
    C = (w[:, None] * X).T @ X / w.sum()
    _, vecs = np.linalg.eigh(C)
    R = vecs[:, ::-1].T
    idx = np.argmax(np.abs(R), axis=1)
    if len(set(idx.tolist())) == 3 and np.all(
        np.abs(R[np.arange(3), idx]) > math.cos(math.radians(20))
    ):
        return np.eye(3)[idx]
    return R


def _view_name(d: np.ndarray) -> str:
    k = int(np.argmax(np.abs(d)))
    if abs(d[k]) > math.cos(math.radians(10)):
        return _AXIS_NAMES[(k, 1 if d[k] > 0 else -1)]
    parts = "".join(f"{'+' if d[i] > 0 else '-'}{'xyz'[i]}" for i in range(3) if abs(d[i]) > 0.2)
    return f"oblique ({parts})"


def _up_for(d: np.ndarray) -> np.ndarray:
    """Picture-up vector: world +z projected, or +y for views along z."""
    ref = np.array([0.0, 1.0, 0.0]) if abs(d[2]) > 0.9 else np.array([0.0, 0.0, 1.0])
    u = ref - (ref @ d) * d
    return u / np.linalg.norm(u)


def view_from_direction(direction, name: str | None = None) -> ViewSpec:
    """A :class:`ViewSpec` for a camera on the side ``direction`` (from the part)."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    return ViewSpec(name=name or _view_name(d), direction=d, up=_up_for(d))


def choose_views(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    regions: Sequence = (),
    n_views: int = 3,
) -> list[ViewSpec]:
    """Two or three camera directions that together show the most scored surface.

    Candidates are the 14 directions of the principal frame's cube faces (axis views) and
    corners (oblique views); the frame is snapped to the world axes for axis-aligned parts.
    Views are at least 50 degrees apart. A vertex seen from direction ``d`` is shown with
    weight ``n . d`` (its projected area; for an open sheet, whose back is the same surface,
    0.85 ``|n . d|`` from behind). Greedy choice: each next view
    maximises the gain in shown scored area, counting the vertices of out-of-tolerance
    regions five times, so views that show the regions win. Unless one of the first two is
    already oblique, the third is the most informative corner (oblique) direction, which
    gives the depth cue the axis views lack. When a view would add less than 2 % (an open
    sheet is seen whole from one side), the oblique view showing the most is taken.

    Parameters
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) triangles.  dev : (n,) deviation, NaN unscored.
    regions : out-of-tolerance regions (objects with ``vertices``).
    n_views : number of views (1 to 3).

    Returns
    -------
    list of :class:`ViewSpec`, the most informative first.
    """
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    N, A = _vertex_normals_areas(V, F)
    w = A * np.isfinite(dev)
    if not w.sum() > 0:
        w = A.copy()
    for r in regions:
        w[np.asarray(r.vertices, dtype=np.int64)] *= 5.0
    R = _principal_frame(V, np.maximum(A, 1e-12))
    cands = []
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            for k in (-1, 0, 1):
                if i or j or k:
                    v = i * R[0] + j * R[1] + k * R[2]
                    cands.append(v / np.linalg.norm(v))
    D = np.array(cands)
    corner = np.sum(np.abs(D @ R.T) > 0.5, axis=1) == 3
    face = np.sum(np.abs(D @ R.T) > 0.99, axis=1) == 1
    proj = N @ D.T  # (n, 26 candidates; edges are never chosen)
    if _is_open(F):  # both sides show the surface; its front (normal side) slightly better
        proj = np.maximum(proj, 0.0) + 0.85 * np.maximum(-proj, 0.0)
    else:
        proj = np.maximum(proj, 0.0)
    best = np.zeros(len(V))
    chosen: list[int] = []
    shown = (w[:, None] * proj).sum(axis=0)
    for step in range(max(1, min(int(n_views), 3))):
        gain = (w[:, None] * (np.maximum(proj, best[:, None]) - best[:, None])).sum(axis=0)
        # edge directions (neither face-on nor a clear oblique) are not used, nor any
        # direction within 50 degrees of a chosen one (nearly the same picture)
        ok = face | corner
        if chosen:
            ok &= np.all(D @ D[chosen].T < math.cos(math.radians(50)), axis=1)
        if step == 2 and not corner[chosen].any():
            ok &= corner  # the third view is oblique: the depth cue axis views lack
        if not ok.any():
            break
        if step > 0 and gain[ok].max() < 0.02 * shown.max():
            # nothing new to show (an open sheet seen whole from the first view): an
            # oblique view showing the most, for the shape
            ok &= corner if (ok & corner).any() else ok
            score = shown
        else:
            # near ties go to the view showing more in all, then to face views (cleaner)
            score = (gain + 0.01 * shown) * np.where(face, 1.02, 1.0)
        k = int(np.argmax(np.where(ok, score, -np.inf)))
        chosen.append(k)
        best = np.maximum(best, proj[:, k])
    return [view_from_direction(D[k]) for k in chosen]


def camera_frame(view: ViewSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors ``(right, up, toward the camera)`` of a view's picture (world frame)."""
    d = np.asarray(view.direction, dtype=float)
    d = d / np.linalg.norm(d)
    u = np.asarray(view.up, dtype=float)
    u = u - (u @ d) * d
    u = u / np.linalg.norm(u)
    r = np.cross(u, d)
    return r, u, d


@dataclass
class Projection:
    """Parallel projection of one view onto a ``w x h`` picture."""

    r: np.ndarray
    u: np.ndarray
    d: np.ndarray
    cx: float
    cy: float
    k: float  # pixels per mm
    w: int
    h: int
    depth_max: float  # largest V . d (nearest to the camera)

    def pixels(self, X: np.ndarray) -> np.ndarray:
        """(m, 2) pixel coordinates (origin top-left) of points X (m, 3)."""
        x = self.w / 2 + (X @ self.r - self.cx) * self.k
        y = self.h / 2 - (X @ self.u - self.cy) * self.k
        return np.c_[x, y]

    def distance(self, X: np.ndarray) -> np.ndarray:
        """Distance (mm) in front of the nearest point of the part (0 = nearest)."""
        return self.depth_max - X @ self.d


def project_view(
    V: np.ndarray, view: ViewSpec, w: int, h: int, margin: tuple[float, float, float, float]
) -> Projection:
    """Fit the part into the picture inside the margins ``(left, right, top, bottom)``
    (fractions of the picture's width and height)."""
    ml, mr, mt, mb = margin
    r, u, d = camera_frame(view)
    x, y = V @ r, V @ u
    x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
    span_x = max(x1 - x0, 1e-9)
    span_y = max(y1 - y0, 1e-9)
    k = min(w * (1 - ml - mr) / span_x, h * (1 - mt - mb) / span_y)
    # the centre of the free area maps to the centre of the part's extent
    cx = 0.5 * (x0 + x1) - (w * (ml - mr) / 2) / k
    cy = 0.5 * (y0 + y1) + (h * (mt - mb) / 2) / k
    return Projection(
        r=r,
        u=u,
        d=d,
        cx=float(cx),
        cy=float(cy),
        k=float(k),
        w=int(w),
        h=int(h),
        depth_max=float((V @ d).max()),
    )


def view_margins(margin, n: int) -> np.ndarray:
    """(n, 4) margins ``(left, right, top, bottom)`` of ``n`` views from one number, one
    tuple for all views or one tuple per view."""
    m = np.asarray(margin, dtype=float)
    if m.ndim == 0:
        return np.full((n, 4), float(m))
    return np.tile(m, (n, 1)) if m.ndim == 1 else m[:n]


def picture_points(
    V: np.ndarray,
    view: ViewSpec,
    size: tuple[int, int],
    X: np.ndarray,
    margin: float | Sequence[float] = 0.04,
) -> np.ndarray:
    """Where points fall in the picture :func:`render_views` draws of ``V`` from ``view``.

    Parameters
    ----------
    V : (n, 3) vertices of the registered nominal, mm (they fix the picture's scale).
    view : the camera direction.  size : picture ``(width, height)``, pixels.
    X : (m, 3) points, mm.  margin : as :func:`render_views` (one view's).

    Returns
    -------
    (m, 2) pixel coordinates, origin at the top-left corner (no visibility test).
    """
    V = np.asarray(V, dtype=np.float64)
    pj = project_view(V, view, int(size[0]), int(size[1]), tuple(view_margins(margin, 1)[0]))
    return pj.pixels(np.asarray(X, dtype=np.float64).reshape(-1, 3))
