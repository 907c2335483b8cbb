"""The resolution stage: the scan's noise and the registration's residual scatter against
each zone's width (:func:`residual_scatter`)."""

from __future__ import annotations

import numpy as np

from qifreport.metrology.acceptance.resolution import Resolution, resolution
from qifreport.metrology.results import ZoneResult
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import robust_scale

from .context import Registered
from .deviation import Deviations
from .readings import Readings
from .scoring import Scores

__all__ = ["residual_scatter"]


def residual_scatter(
    reg: Registered,
    fit: DeformResult | None,
    deviations: Deviations,
    scores: Scores,
    readings: Readings,
    zones: list[ZoneResult],
    *,
    restrained: bool = False,
) -> Resolution:
    """The measurement's resolution against each zone's width (:func:`resolution`): the
    scan's noise and the registration's residual scatter, mm.

    The scatter is the fixture's residual scale, or the rigid fit's; a scan held otherwise
    (``restrained``) has the part's form in its deviations, not a scatter: its scatter is
    about the measured deviation field (each point against its nearest scored vertex's
    value: a conforming panel with 0.23 mm of form the clamps leave was "not established"
    when the form itself was taken for scatter)."""
    if fit is not None:
        residual_scale = fit.scale
    elif restrained:
        pvert = scores.samples.vertex
        near = np.where(pvert >= 0, readings.deviation[np.maximum(pvert, 0)], np.nan)
        about = deviations.point - near
        residual_scale = (
            robust_scale(about[np.isfinite(about)]) if np.isfinite(about).any() else 0.0
        )
    else:
        residual_scale = reg.rigid.scale
    return resolution(
        scores.noise,
        residual_scale,
        [(z.zone.key, float(z.zone.upper - z.zone.lower)) for z in zones],
    )
