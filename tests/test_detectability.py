"""Defect detectability (paper Eqs. 18-19): the metric on arrays, and one cell end to end."""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.simulate.detectability import Detectability, detectability


def _grid(half: int = 100, spacing: float = 1.0) -> np.ndarray:
    """A flat (2 half + 1)^2 vertex grid in the z = 0 plane, centred at the origin, mm."""
    g = np.arange(-half, half + 1) * spacing
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def _bump_field(V, x0, a=0.9, sigma=7.0, noise=0.02, seed=0):
    """A Gaussian bump (Eq. 16 width convention) plus background noise beyond 60 mm only, so
    the peak and the background quantile are known exactly."""
    r = np.linalg.norm(V - x0, axis=1)
    e = a * np.exp(-(r**2) / sigma**2)
    far = r > 60.0
    e[far] += noise * np.random.default_rng(seed).standard_normal(int(far.sum()))
    return e, r


def test_known_bump_gives_exact_peak_background_and_location():
    V = _grid()
    x0 = np.array([10.0, -5.0, 0.0])  # on a vertex
    e, r = _bump_field(V, x0)
    d = detectability(e, V, x0, None, a=0.9)
    assert isinstance(d, Detectability)
    b = np.percentile(np.abs(e[r > 60.0]), 95)
    assert d.a_hat == pytest.approx(0.9, abs=1e-12)
    assert d.recovery == pytest.approx(1.0, abs=1e-12)
    assert d.background == pytest.approx(b, rel=1e-12)
    assert d.rho == pytest.approx(0.9 / b, rel=1e-12)
    assert d.localisation_mm == 0.0
    assert d.n_defect == int((r <= 12.0).sum())
    assert d.n_background == int((r > 60.0).sum())
    assert d.separable


def test_sunk_defect_off_vertex_and_partial_recovery():
    V = _grid()
    x0 = np.array([0.3, 0.4, 0.0])  # between vertices: nearest vertex (origin) is 0.5 mm away
    e, _ = _bump_field(V, x0, a=-0.6)  # a sink: |e| is scored
    d = detectability(0.5 * e, V, x0, None, a=-0.6)  # half the amplitude survives the fit
    peak = 0.6 * np.exp(-0.25 / 49.0)
    assert d.a_hat == pytest.approx(0.5 * peak, rel=1e-12)
    assert d.recovery == pytest.approx(0.5 * peak / 0.6, rel=1e-12)
    assert d.localisation_mm == pytest.approx(0.5, abs=1e-12)


def test_radii_are_fixed_and_inclusive_as_defined():
    V = _grid()
    x0 = np.zeros(3)
    e, r = _bump_field(V, x0, a=0.3, sigma=3.0)
    # a larger spike exactly at R_d belongs to D (r <= R_d) and becomes the peak
    at_rd = np.flatnonzero(np.isclose(r, 12.0))[0]
    e[at_rd] = 0.5
    # a huge spike exactly at R_b is not background (r > R_b)
    at_rb = np.flatnonzero(np.isclose(r, 60.0))[0]
    e[at_rb] = 100.0
    d = detectability(e, V, x0, None, a=0.3)
    assert d.a_hat == 0.5 and d.localisation_mm == pytest.approx(12.0)
    assert d.background == pytest.approx(np.percentile(np.abs(e[r > 60.0]), 95))
    assert d.background < 1.0
    # other radii are honoured
    d2 = detectability(e, V, x0, None, a=0.3, R_d=5.0, R_b=80.0)
    assert d2.a_hat == pytest.approx(0.3) and d2.n_defect == int((r <= 5.0).sum())
    assert d2.n_background == int((r > 80.0).sum())


def test_nan_and_unscored_vertices_are_ignored():
    V = _grid()
    x0 = np.zeros(3)
    e, r = _bump_field(V, x0)
    centre = int(np.argmin(r))
    e[centre] = np.nan  # the peak vertex was not scored
    far = np.flatnonzero(r > 60.0)
    e[far[:50]] = np.nan
    d = detectability(e, V, x0, None, a=0.9)
    assert d.a_hat == pytest.approx(0.9 * np.exp(-1.0 / 49.0))  # a neighbour 1 mm away
    assert d.localisation_mm == pytest.approx(1.0)
    assert d.n_defect == int((r <= 12.0).sum()) - 1
    assert d.n_background == len(far) - 50
    assert np.isfinite(d.background)
    # an explicit scored mask removes vertices the same way; its NaNs still count as unscored
    scored = np.ones(len(V), dtype=bool)
    scored[r <= 1.5] = False
    d2 = detectability(e, V, x0, scored, a=0.9)
    assert d2.localisation_mm > 1.5
    assert d2.n_defect == int((r <= 12.0).sum()) - int((r <= 1.5).sum())


def test_empty_sets_give_nan_not_an_exception():
    V = _grid(half=30)
    e = np.zeros(len(V))
    # B empty: on a 60 x 60 mm grid no vertex lies beyond 60 mm of the centre (corners: 42 mm)
    d = detectability(e + 0.1, V, np.zeros(3), None, a=0.5)
    assert d.n_background == 0 and np.isnan(d.background) and np.isnan(d.rho)
    assert d.a_hat == pytest.approx(0.1) and not d.separable
    # D empty: the centre is far from every scored vertex
    d = detectability(e + 0.1, V, np.array([500.0, 0.0, 0.0]), None, a=0.5)
    assert d.n_defect == 0 and np.isnan(d.a_hat) and np.isnan(d.recovery)
    assert np.isnan(d.localisation_mm) and np.isnan(d.rho)
    # all NaN: both empty
    d = detectability(np.full(len(V), np.nan), V, np.zeros(3), None, a=0.5)
    assert d.n_defect == d.n_background == 0 and np.isnan(d.rho)
    # a perfectly quiet background: rho is infinite, not an error
    V = _grid()
    e, r = _bump_field(V, np.zeros(3), noise=0.0)
    e[r > 60.0] = 0.0
    assert detectability(e, V, np.zeros(3), None, a=0.9).rho == np.inf


def test_bad_inputs_raise():
    V = _grid(half=5)
    e = np.zeros(len(V))
    with pytest.raises(ValueError):
        detectability(e[:-1], V, np.zeros(3), None, a=1.0)
    with pytest.raises(ValueError):
        detectability(e, V, np.zeros(2), None, a=1.0)
    with pytest.raises(ValueError):
        detectability(e, V, np.zeros(3), np.ones(3, dtype=bool), a=1.0)
    with pytest.raises(ValueError):
        detectability(e, V, np.zeros(3), None, a=0.0)
    with pytest.raises(ValueError):
        detectability(e, V, np.zeros(3), None, a=1.0, R_d=20.0, R_b=10.0)


@pytest.mark.slow
def test_mid_grid_cell_end_to_end_multi_pass_detects(shell):
    """Table 3's mid-grid cell (a = 0.9 mm, sigma = 7 mm, analytic free state, 0.03 mm noise)
    through the real pipeline: the product's default multi-pass scheme keeps the defect
    separable (paper: rho 11.8, 92 % recovered) and puts its peak near the true centre."""
    from qifreport.metrology.inspection import InspectionParams, inspect
    from qifreport.registration.deformable.gbcicp import GBCICPParams
    from qifreport.registration.mesh import bounding_diagonal
    from qifreport.simulate.cases import make_case
    from qifreport.simulate.scanner import ScanSpec

    V, F = shell
    spec = ScanSpec(noise=0.03, seed=0, dropout_radius=0.03 * bounding_diagonal(V))
    case = make_case(
        V, F, generator="analytic", amplitude=0.02, defect=(0.9, 7.0), spec=spec, seed=0
    )
    res = inspect(V, F, case.P, InspectionParams(gbcicp=GBCICPParams()))
    assert res.fit.passes >= 2 and not res.fit.fallback
    d = detectability(res.deviation, V, V[case.defect_vertex], None, a=0.9)
    assert d.n_defect > 100 and d.n_background > 1000
    assert d.rho >= 3.0
    assert d.recovery >= 0.5
    assert d.localisation_mm < 3.0
