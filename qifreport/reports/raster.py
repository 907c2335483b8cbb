"""Rasterizing the coloured deviation map for a set of views: VTK offscreen (through EGL,
no display needed) and, when VTK cannot render, matplotlib's Agg (painter's algorithm on the
projected triangles). Both return the pictures and a distance buffer per view (mm in front of
the part's nearest point, inf on background)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .views import Projection, face_normals_areas

__all__ = ["Scene", "render_mpl", "render_vtk", "vertex_zbuffer"]


@dataclass
class Scene:
    """The coloured deviation map to draw.

    Attributes
    ----------
    V : (n, 3) vertices, mm.  F : (f, 3) triangles.  rgb : (n, 3) uint8 vertex colours.
    outline : (s, 2, 3) segments of the band edge, mm, drawn in ``outline_rgb`` (0..1).
    """

    V: np.ndarray
    F: np.ndarray
    rgb: np.ndarray
    outline: np.ndarray
    outline_rgb: tuple[float, float, float]


def render_vtk(scene: Scene, projs: list[Projection]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Render ``scene`` in every view of ``projs`` with VTK offscreen; returns (images,
    distance buffers)."""
    V, F, rgb, outline = scene.V, scene.F, scene.rgb, scene.outline
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL factories)
    from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow

    ren = vtkRenderer()
    ren.SetBackground(1.0, 1.0, 1.0)
    ren.AddActor(_surface_actor(V, F, rgb))
    if len(outline):
        width = max(1.5, max(pj.w for pj in projs) / 500.0)
        ren.AddActor(_outline_actor(outline, scene.outline_rgb, width))

    win = vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(8)
    win.AddRenderer(ren)
    cam = ren.GetActiveCamera()
    cam.ParallelProjectionOn()
    diag = float(np.linalg.norm(np.ptp(V, axis=0))) or 1.0
    images, depths = [], []
    try:
        for pj in projs:
            img, zmm = _grab(win, cam, pj, diag)
            images.append(img)
            depths.append(zmm)
    finally:
        win.Finalize()
    return images, depths


def _polydata(points: np.ndarray, cells: np.ndarray, lines: bool):
    """A ``vtkPolyData`` of ``points`` (m, 3) and ``cells`` (c, k): lines or polygons."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    pd = vtkPolyData()
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    pd.SetPoints(pts)
    ca = vtkCellArray()
    k = cells.shape[1]
    offsets = np.arange(0, k * len(cells) + 1, k, dtype=np.int64)
    ca.SetData(
        numpy_to_vtkIdTypeArray(offsets, deep=True),
        numpy_to_vtkIdTypeArray(np.ascontiguousarray(cells.ravel(), dtype=np.int64), deep=True),
    )
    if lines:
        pd.SetLines(ca)
    else:
        pd.SetPolys(ca)
    return pd


def _surface_actor(V: np.ndarray, F: np.ndarray, rgb: np.ndarray):
    """The surface, coloured per vertex (Gouraud), pushed back behind coincident lines."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkUnsignedCharArray
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    surf = _polydata(V, F, lines=False)
    colors = numpy_to_vtk(
        np.ascontiguousarray(rgb), deep=True, array_type=vtkUnsignedCharArray().GetDataType()
    )
    colors.SetName("rgb")
    surf.GetPointData().SetScalars(colors)
    mapper = vtkPolyDataMapper()
    mapper.SetInputData(surf)
    mapper.SetColorModeToDirectScalars()
    mapper.SetScalarModeToUsePointData()
    mapper.SetResolveCoincidentTopologyToPolygonOffset()
    mapper.SetRelativeCoincidentTopologyPolygonOffsetParameters(1.5, 1.5)
    actor = vtkActor()
    actor.SetMapper(mapper)
    prop = actor.GetProperty()
    prop.SetAmbient(0.35)
    prop.SetDiffuse(0.65)
    prop.SetSpecular(0.0)
    prop.SetInterpolationToGouraud()
    return actor


def _outline_actor(outline: np.ndarray, rgb: tuple[float, float, float], width: float):
    """The band edge's segments (s, 2, 3), unlit lines ``width`` pixels wide."""
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    segs = outline.reshape(-1, 3)
    lines = _polydata(segs, np.arange(len(segs)).reshape(-1, 2), lines=True)
    lmapper = vtkPolyDataMapper()
    lmapper.SetInputData(lines)
    lmapper.ScalarVisibilityOff()
    lactor = vtkActor()
    lactor.SetMapper(lmapper)
    lp = lactor.GetProperty()
    lp.SetColor(*rgb)
    lp.SetLighting(False)
    lp.SetLineWidth(width)
    return lactor


def _grab(win, cam, pj: Projection, diag: float) -> tuple[np.ndarray, np.ndarray]:
    """Render one view and read back its picture (h, w, 3) uint8 and its distance buffer
    (h, w), mm in front of the part's nearest point (inf on background); ``diag`` is the
    part's diagonal, mm."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkFloatArray, vtkUnsignedCharArray

    win.SetSize(pj.w, pj.h)
    focal = pj.cx * pj.r + pj.cy * pj.u + pj.depth_max * pj.d
    pos = focal + 2.0 * diag * pj.d
    cam.SetFocalPoint(*focal)
    cam.SetPosition(*pos)
    cam.SetViewUp(*pj.u)
    cam.SetParallelScale(0.5 * pj.h / pj.k)
    near, far = 0.5 * diag, 4.0 * diag
    cam.SetClippingRange(near, far)
    win.Render()
    pix = vtkUnsignedCharArray()
    win.GetPixelData(0, 0, pj.w - 1, pj.h - 1, 0, pix, 0)
    img = vtk_to_numpy(pix).reshape(pj.h, pj.w, -1)[::-1, :, :3].copy()
    zb = vtkFloatArray()
    win.GetZbufferData(0, 0, pj.w - 1, pj.h - 1, zb)
    z = vtk_to_numpy(zb).reshape(pj.h, pj.w)[::-1].astype(np.float64)
    # window depth (parallel projection: linear) -> mm in front of the nearest point
    dist_cam = near + z * (far - near)
    zmm = np.where(z < 1.0, dist_cam - 2.0 * diag, np.inf)
    return img, zmm


def render_mpl(scene: Scene, projs: list[Projection]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Fallback: painter's algorithm with matplotlib Agg; returns (images, distance buffers)."""
    V, F, rgb, outline = scene.V, scene.F, scene.rgb, scene.outline
    # the Agg canvas directly (no pyplot): the process's matplotlib backend is left alone
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    fn, _ = face_normals_areas(V, F)
    base = rgb[F].astype(float).mean(axis=1) / 255.0
    images, depths = [], []
    for pj in projs:
        px = pj.pixels(V)
        dist = pj.distance(V)
        shade = 0.35 + 0.65 * np.abs(fn @ pj.d)
        fc = np.clip(base * shade[:, None], 0, 1)
        order = np.argsort(-dist[F].mean(axis=1), kind="stable")  # far first
        fig = Figure(figsize=(pj.w / 100.0, pj.h / 100.0), dpi=100)
        canvas = FigureCanvasAgg(fig)
        ax = fig.add_axes((0, 0, 1, 1))
        ax.set_xlim(0, pj.w)
        ax.set_ylim(pj.h, 0)
        ax.axis("off")
        pc = PolyCollection(
            px[F[order]], facecolors=fc[order], edgecolors="none", antialiased=False
        )
        ax.add_collection(pc)
        # vertex z-buffer with cells of about one projected edge, depth tolerance one edge
        e = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)
        edge = float(np.median(e)) if len(e) else 1.0
        cell = int(np.clip(round(edge * pj.k), 3, 24))
        zbuf = vertex_zbuffer(px, dist, pj.w, pj.h, cell=cell)
        if len(outline):
            a, b = outline[:, 0], outline[:, 1]
            pa, pb = pj.pixels(a), pj.pixels(b)
            mid = 0.5 * (a + b)
            pm = pj.pixels(mid)
            ix = np.clip(np.round(pm[:, 0]).astype(int), 0, pj.w - 1)
            iy = np.clip(np.round(pm[:, 1]).astype(int), 0, pj.h - 1)
            vis = pj.distance(mid) <= zbuf[iy, ix] + max(edge, 3.0 / pj.k)
            segs = np.stack([pa[vis], pb[vis]], axis=1)
            ax.add_collection(LineCollection(segs, colors=[scene.outline_rgb], linewidths=1.2))
        canvas.draw()
        img = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
        images.append(img)
        depths.append(zbuf)
    return images, depths


def vertex_zbuffer(px: np.ndarray, dist: np.ndarray, w: int, h: int, cell: int = 3) -> np.ndarray:
    """Approximate per-pixel nearest distance (mm) from the vertices alone: the nearest
    vertex in each ``cell`` x ``cell`` block; inf where no vertex projects."""
    gw, gh = (w + cell - 1) // cell, (h + cell - 1) // cell
    gx = np.clip((px[:, 0] // cell).astype(int), 0, gw - 1)
    gy = np.clip((px[:, 1] // cell).astype(int), 0, gh - 1)
    g = np.full((gh, gw), np.inf)
    np.minimum.at(g, (gy, gx), dist)
    return np.repeat(np.repeat(g, cell, axis=0), cell, axis=1)[:h, :w]
