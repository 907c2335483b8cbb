"""Run-chart primitives of the trend report: axis steps and ticks, the data-to-page
transform of a plot, and the marks and lines drawn in it.

The ticks are chosen from the page space (:func:`nice_step`, :func:`seq_ticks`), so a chart
reads the same for 3 scans and for 2000; :class:`ChartGeometry` maps a scan's sequence
number and a value (mm, or % for a pass rate) to the page.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .kit import INK, MUTED, Box, draw_text

if TYPE_CHECKING:
    from reportlab.pdfgen.canvas import Canvas

__all__ = [
    "nice_step",
    "decimals",
    "seq_ticks",
    "ChartGeometry",
    "draw_marker",
    "draw_polyline",
    "draw_y_title",
    "draw_frame",
]


def nice_step(raw: float, mantissas: tuple[float, ...] = (1.0, 2.0, 2.5, 5.0)) -> float:
    """The smallest ``m * 10**k`` (m in ``mantissas``) not below ``raw`` (> 0)."""
    e = 10.0 ** math.floor(math.log10(raw))
    for m in (*mantissas, 10.0):
        if m * e >= raw * (1 - 1e-9):
            return m * e
    return 10.0 * e


def decimals(step: float) -> int:
    """Decimals that print every multiple of ``step`` exactly (at most 4)."""
    for d in range(5):
        if abs(round(step, d) - step) < 1e-9 * max(step, 1e-12):
            return d
    return 4


def seq_ticks(n: int, width: float, min_gap: float = 42.0) -> list[int]:
    """Sequence numbers to label on an axis of ``n`` scans ``width`` points wide.

    Multiples of a step of 1, 2 or 5 times a power of ten, at least ``min_gap`` points apart,
    and scan 1 when it does not crowd the first multiple.
    """
    if n <= 1:
        return [1]
    step = max(1, int(nice_step(max(n / max(width / min_gap, 1.0), 1.0), (1.0, 2.0, 5.0))))
    ticks = list(range(step, n + 1, step))
    if not ticks or ticks[0] - 1 >= 0.5 * step:
        ticks.insert(0, 1)
    return ticks


@dataclass
class ChartGeometry:
    """A plot area and its data-to-page transform (points, origin at the page's bottom-left).

    Attributes
    ----------
    key : the characteristic's key (``"pass rate"`` for the pass-rate chart).
    plot : the frame of the plot.
    n_scans : scans on the x axis; scan ``s`` sits at ``(s - 0.5) / n_scans`` of the width.
    y_low : page y of the value ``bottom`` (above the strip of marks along the bottom).
    top : value at the top of the frame (mm, or % for the pass-rate chart).
    bottom : value at ``y_low`` (0 for the run charts).
    """

    key: str
    plot: Box
    n_scans: int
    y_low: float
    top: float
    bottom: float = 0.0

    def x(self, seq: float | np.ndarray) -> float | np.ndarray:
        """Page x of scan sequence number ``seq`` (1-based)."""
        return (
            self.plot.x + (np.asarray(seq, dtype=float) - 0.5) / max(self.n_scans, 1) * self.plot.w
        )

    def y(self, value: float | np.ndarray) -> float | np.ndarray:
        """Page y of ``value``, clipped to the frame's top and to ``bottom``."""
        v = np.clip(np.asarray(value, dtype=float), self.bottom, self.top)
        return self.y_low + (v - self.bottom) / (self.top - self.bottom) * (
            self.plot.top - self.y_low
        )


# ------------------------------------------------------------------------------ drawing


def draw_marker(
    c: Canvas,
    kind: str,
    x: float,
    y: float,
    size: float,
    color: tuple[float, float, float],
    weight: float | None = None,
) -> None:
    """A legend or data mark: ``dot``, ``cross``, ``tri`` (pointing up) or ``tick`` (a
    vertical stroke ``weight`` points wide)."""
    c.setFillColorRGB(*color)
    c.setStrokeColorRGB(*color)
    if kind == "dot":
        c.circle(x, y, size, stroke=0, fill=1)
    elif kind == "cross":
        c.setLineWidth(max(0.5, size * 0.45))
        c.line(x - size, y - size, x + size, y + size)
        c.line(x - size, y + size, x + size, y - size)
    elif kind == "tri":
        p = c.beginPath()
        p.moveTo(x - size, y - size * 0.8)
        p.lineTo(x + size, y - size * 0.8)
        p.lineTo(x, y + size * 0.9)
        p.close()
        c.drawPath(p, stroke=0, fill=1)
    elif kind == "tick":
        c.setLineWidth(weight if weight is not None else max(0.4, size * 0.4))
        c.line(x, y - size, x, y + size)


def draw_polyline(c: Canvas, xs: np.ndarray, ys: np.ndarray, ok: np.ndarray) -> None:
    """One path through the points ``ok``, broken where ``ok`` is False."""
    path = c.beginPath()
    pen = False
    for x, y, good in zip(xs, ys, ok, strict=True):
        if not good:
            pen = False
        elif pen:
            path.lineTo(float(x), float(y))
        else:
            path.moveTo(float(x), float(y))
            pen = True
    c.drawPath(path, stroke=1, fill=0)


def draw_y_title(c: Canvas, x: float, pa: Box, title: str) -> None:
    """``title`` written upwards at ``x``, centred on the plot ``pa``."""
    c.saveState()
    c.translate(x, pa.y + pa.h / 2)
    c.rotate(90)
    draw_text(c, 0, 0, title, 6.0, False, MUTED, "c")
    c.restoreState()


def draw_frame(c: Canvas, geo: ChartGeometry, label: Callable[[int], str]) -> None:
    """Frame of a plot and its sequence ticks (:func:`seq_ticks`), labelled below the frame
    with ``label(position)`` (1-based batch position)."""
    pa = geo.plot
    c.setStrokeColorRGB(*INK)
    c.setLineWidth(0.5)
    c.rect(pa.x, pa.y, pa.w, pa.h, stroke=1, fill=0)
    for pos in seq_ticks(geo.n_scans, pa.w):
        x = float(geo.x(pos))
        c.line(x, pa.y, x, pa.y - 2.0)
        draw_text(c, x, pa.y - 8.2, label(pos), 6.0, False, INK, "c")
