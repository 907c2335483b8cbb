"""The readings stage: the judged deviation read in the located zones' datum frames
(:func:`located_readings`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.metrology.gdt.frames import DatumFrameResult

from .characteristics import Characteristics
from .context import JudgeContext, Registered
from .scoring import Scores

__all__ = ["Readings", "located_readings"]


@dataclass(frozen=True)
class Readings:
    """The deviations read where the located zones lie (:func:`located_readings`).

    Attributes
    ----------
    deviation : (n,) the judged deviation, each located zone's vertices in its frame, mm.
    uncertainty : (n,) its expanded uncertainty, the frame's combined in, mm.
    point_center : the scan points' band centre: scalar or (n,) per vertex, mm.
    point_uncertainty : 0.0, or (n,) the frames' expanded uncertainty per vertex, mm.
    zone_frames : as :attr:`Characteristics.zone_frames`.
    located : the established ones among them.
    """

    deviation: np.ndarray
    uncertainty: np.ndarray
    point_center: float | np.ndarray
    point_uncertainty: float | np.ndarray
    zone_frames: dict[int, DatumFrameResult | None]
    located: dict[int, DatumFrameResult]


def located_readings(
    reg: Registered, scores: Scores, characteristics: Characteristics, ctx: JudgeContext
) -> Readings:
    """The judged deviation read in the located zones' frames (:class:`Readings`): each
    vertex governed by a zone whose datum frame is established takes its reading in that
    frame, and the frame's uncertainty with it; the scan points judge against their
    vertex's band moved the other way."""
    zone_frames = characteristics.zone_frames
    located = {i: f for i, f in zone_frames.items() if f is not None and f.established}
    dev_all, U = scores.deviation, scores.uncertainty
    point_center: float | np.ndarray = ctx.bands.center
    point_U: float | np.ndarray = 0.0
    if located:
        V, normals, governing = reg.V, ctx.prepared.ops.normals, ctx.bands.governing
        dev_all, U = dev_all.copy(), U.copy()
        point_center = np.broadcast_to(ctx.bands.center, (len(V),)).astype(np.float64).copy()
        point_U = np.zeros(len(V))
        for i, f in located.items():
            gv = governing == i
            shift = f.normal_shift(V[gv], normals[gv])
            dev_all[gv] = dev_all[gv] + shift
            point_center[gv] -= shift
            point_U[gv] = f.shift_uncertainty(V[gv], normals[gv])
            U[gv] = np.hypot(U[gv], f.shift_uncertainty(V[gv], normals[gv]))
    return Readings(
        deviation=dev_all,
        uncertainty=U,
        point_center=point_center,
        point_uncertainty=point_U,
        zone_frames=zone_frames,
        located=located,
    )
