"""The added-material stage: scan points standing proud of the nominal beyond the whole
part's band (:func:`added_stage`)."""

from __future__ import annotations

import numpy as np

from qifreport.metrology.acceptance.added import AddedMaterial, added_material
from qifreport.metrology.params import InspectionParams

from .context import JudgeContext, Registered
from .deviation import Deviations
from .scoring import Scores

__all__ = ["added_stage"]


def added_stage(
    reg: Registered,
    deviations: Deviations,
    scores: Scores,
    ctx: JudgeContext,
    params: InspectionParams,
) -> AddedMaterial:
    """The added material (:func:`added_material`): scan points standing proud of the
    nominal beyond the whole part's band; points beyond its rim are not proud of it, nor
    is a spike (a point alone off its neighbourhood: no surface patch of material)."""
    pdev_in = np.where(deviations.beyond_rim | scores.samples.spike, np.nan, deviations.point)
    return added_material(
        reg.P,
        pdev_in,
        ctx.general_half,
        reg.scan_area,
        params.max_region_area,
        fail_on=params.fail_on_added_material,
        tree=scores.samples.tree,
    )
