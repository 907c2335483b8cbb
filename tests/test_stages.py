"""The inspection as a library user runs it step by step: the seat, then the judgement's
stages one by one (:mod:`qifreport.metrology.stages`), give the numbers of
:func:`~qifreport.metrology.judgement.judge` and of
:func:`~qifreport.metrology.inspection.inspect`, and :func:`judge` given the held nominal and
the trim edges measured already (as the command's schedule gives them) is unchanged."""

from __future__ import annotations

import numpy as np

from qifreport.metrology.inspection import (
    InspectionInputs,
    InspectionParams,
    checked_part,
    inspect,
    inspection_context,
    seat_rigidly,
)
from qifreport.metrology.judgement import judge
from qifreport.metrology.stages.acceptance import Measured, acceptance_stage
from qifreport.metrology.stages.characteristics import characteristics_stage
from qifreport.metrology.stages.detectable import detectable_stage
from qifreport.metrology.stages.deviation import deviation_stage
from qifreport.metrology.stages.held import held_nominal
from qifreport.metrology.stages.readings import located_readings
from qifreport.metrology.stages.scoring import scoring_stage
from qifreport.metrology.stages.trim_edges import trim_edge_stage
from qifreport.simulate.shapes import thin_shell
from tests.test_determinism import flatten
from tests.test_forked import shell_scan


def same(a, b) -> list[str]:
    """The access paths where two results' numbers differ (none: bit-identical)."""
    x, y = flatten(a), flatten(b)
    assert x.keys() == y.keys()
    return [k for k in x if not np.array_equal(x[k], y[k], equal_nan=True)]


def test_the_stages_one_by_one_give_the_judgement_and_the_inspection():
    V, F = thin_shell(spacing=3.0)
    P = shell_scan(V, F, 0.5)
    params = InspectionParams(tolerance=0.3, prealign="never", rigid_only=True)
    inputs = InspectionInputs()
    timings: dict[str, float] = {}
    prepared, basis = checked_part(V, F, P, params, inputs, timings)
    reg = seat_rigidly(V, F, P, params, prepared, timings)
    ctx = inspection_context(reg, params, inputs, prepared, basis, timings).ctx
    res = judge(reg, None, params, {}, ctx)

    nominal = held_nominal(reg, None, ctx, params)
    deviations = deviation_stage(reg, nominal, ctx)
    scores = scoring_stage(reg, nominal, deviations, ctx, params, {})
    characteristics = characteristics_stage(reg, nominal, deviations, scores, ctx, params, {})
    readings = located_readings(reg, scores, characteristics, ctx)
    edges, size = trim_edge_stage(reg, nominal, ctx, params)
    measured = Measured(nominal, deviations, scores, readings)
    decisions = acceptance_stage(reg, measured, ctx, params)
    decisions = detectable_stage(reg, None, measured, decisions, ctx, params)
    assert np.array_equal(readings.deviation, res.deviation, equal_nan=True)
    assert np.array_equal(deviations.point, res.point_deviation, equal_nan=True)
    assert not same(decisions.acceptance, res.acceptance)
    assert not same(decisions.zones, res.zones)
    assert not same((edges, size), (res.edges, res.size))

    # the steps started elsewhere, handed in as values: the same judgement
    given = judge(reg, None, params, {}, ctx, nominal=nominal, trim_edges=(edges, size))
    assert not same(given, res)
    whole = inspect(V, F, P, params)
    assert whole.fixture_decision == "rigid only"
    # a clean scan: no stray point left out, so the same points judged, the same numbers
    assert whole.stray is not None and whole.stray.count == 0
    whole.stray = None
    assert not same(whole, res)
