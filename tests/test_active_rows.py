"""Minimum-zone programmes solved on their active rows give the whole programme's optimum."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from qifreport.metrology.gdt.active_rows import FEASIBILITY, linprog_active
from qifreport.metrology.gdt.form import cylindricity, flatness


def chebyshev_rows(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    m, k = A.shape
    ones = np.ones((m, 1))
    return np.r_[np.zeros(k), 1.0], np.vstack([np.c_[A, -ones], np.c_[-A, -ones]]), np.r_[b, -b]


@pytest.mark.parametrize("seed", range(4))
def test_a_chebyshev_fit_on_its_active_rows_is_the_whole_programme_s(seed):
    """40,000 points of a wavy, noisy, tilted plane (so that the rows tightest at the start
    lie at one edge): the optimum of the reduced programme is the full one's to 1e-9 mm,
    and its solution satisfies every one of the 80,000 rows (the 64 tightest rows alone
    leave the programme unbounded)."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-50, 50, (40_000, 2))
    w = 0.01 * np.sin(uv[:, 0] / 7) + 0.003 * rng.standard_normal(len(uv)) + 0.002 * uv[:, 1]
    A = np.c_[uv, np.ones(len(uv))]
    c, A_ub, b_ub = chebyshev_rows(A, w)
    bounds = [(None, None)] * 4
    whole = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    got = linprog_active(c, A_ub, b_ub, bounds)
    assert got.status == 0
    assert got.fun == pytest.approx(whole.fun, abs=1e-9)
    assert (A_ub @ got.x - b_ub).max() <= FEASIBILITY * (1 + np.abs(b_ub).max())
    first = np.argpartition(-(A_ub @ np.zeros(4) - b_ub), 64)[:64]
    once = linprog(c, A_ub=A_ub[first], b_ub=b_ub[first], bounds=bounds, method="highs")
    assert once.status == 3  # unbounded: all 64 rows along one edge


def test_form_readings_equal_the_whole_programme_s(monkeypatch):
    """Flatness and cylindricity of 30,000 noisy points read the same on the active rows as
    on every row (to 1e-9 mm)."""
    import qifreport.metrology.gdt.form as form

    rng = np.random.default_rng(7)
    P = np.c_[rng.uniform(0, 80, (30_000, 2)), 0.002 * rng.standard_normal(30_000)]
    P[:, 2] += 1e-4 * P[:, 0]
    th, z = rng.uniform(0, 2 * np.pi, 30_000), rng.uniform(0, 40, 30_000)
    r = 10 + 0.003 * rng.standard_normal(30_000) + 0.002 * np.cos(3 * th)
    C = np.c_[r * np.cos(th), r * np.sin(th), z]

    def readings():
        return (
            flatness(P).minimum_zone,
            cylindricity(C, np.zeros(3), np.eye(3)[2], 10.0).minimum_zone,
        )

    active = readings()
    monkeypatch.setattr(
        form,
        "linprog_active",
        lambda c, A, b, bounds: linprog(c, A_ub=A, b_ub=b, bounds=bounds, method="highs"),
    )
    whole = readings()
    assert active == pytest.approx(whole, abs=1e-9)
    assert 0.005 < active[0] < 0.03 and 0.005 < active[1] < 0.03
