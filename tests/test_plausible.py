"""Physically implausible readings are not measured, never judged (a metrologist signs no
8 km diameter and no 767 mm uncertainty): on FTC 06's real part and drawing, through the
measurement a report runs.

* D9, the 15.875 mm hole diameter, read on its perfect surface: PASS; the same hole with a
  sixth of each of its four holes scored, those vertices on a 100 m circle (a nearly
  straight arc, as a sparse scan of a hole's edge gives): too little of the circumference
  for a size, NOT_MEASURED; read regardless, the fitted diameter is 200 m, beyond the
  part's 405 mm diagonal: NOT_MEASURED, the reason naming both numbers;
* the same holes with a 10 m vertex uncertainty (a scan too sparse to know them): D9's
  value is right but its U is wider than the part, and G9 (their position): both
  NOT_MEASURED;
* the judging function itself: a reading at the bound is judged, just beyond it is not; an
  angle dimension outside 0..180 deg, a size <= 0, a non-finite value are not measured.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    judge,
)
from qifreport.metrology.gdt.characteristics import measure_characteristics
from qifreport.metrology.gdt.dimensions import measure_dimension
from qifreport.metrology.gdt.measured_surface import MeasuredSurface
from qifreport.registration.mesh import bounding_diagonal
from tests.test_characteristics import exact_surface

D9_FACES = [25, 26]  # one of D9's four holes (the one G9 is drawn on)


@pytest.fixture(scope="module")
def ftc06(nist_nominal):
    return nist_nominal("nist_ftc_06_asme1_ap242-e1.stp")


def _spec(drawing, key: str):
    return next(s for s in drawing.plan.specs if s.key == key)


def _on_big_circle(surf: MeasuredSurface, faces, R: float) -> tuple[np.ndarray, np.ndarray]:
    """The own vertices of a hole's ``faces`` within 30 deg of one direction across its
    axis, and their deviations (along the normal, mm) putting them on a circle of radius
    ``R`` mm through the nominal wall there (a nearly straight arc)."""
    v = surf.own_vertices(faces)
    cyl = surf.nominal(faces)
    a = cyl.direction
    d = np.cross(a, [1.0, 0.0, 0.0])
    d /= np.linalg.norm(d)
    X = surf.V[v] - cyl.origin
    z = X @ a
    Q = X - np.outer(z, a)
    u = Q / np.linalg.norm(Q, axis=1)[:, None]
    keep = u @ d > np.cos(np.radians(30.0))
    C = -(R - cyl.radius) * d  # the big circle's centre, across the axis
    uc = u @ C
    rho = uc + np.sqrt(uc**2 - C @ C + R**2)  # where each vertex's ray meets it
    T = cyl.origin + np.outer(z, a) + rho[:, None] * u
    dev = np.einsum("ij,ij->i", T - surf.V[v], surf.N[v])
    return v, np.where(keep, dev, np.nan)


def test_a_huge_fitted_diameter_is_not_measured(ftc06, monkeypatch):
    part, drawing = ftc06
    spec = _spec(drawing, "D9")
    assert spec.dim_type == "diameter" and spec.nominal == pytest.approx(15.875)
    diagonal = bounding_diagonal(part.V)
    assert diagonal == pytest.approx(404.7, abs=0.1)
    perfect = measure_dimension(spec, exact_surface(part, np.zeros(len(part.V))), "iso14253")
    assert perfect.status == "PASS" and perfect.value == pytest.approx(15.875, abs=1e-3)
    dev = np.zeros(len(part.V))
    surf = exact_surface(part, dev)
    for hole in surf.features(spec.faces):
        v, d = _on_big_circle(surf, hole, 1e5)
        dev[v] = d
    sparse = exact_surface(part, dev)
    (got,), _ = measure_characteristics([spec], drawing.plan.datums, sparse, "iso14253")
    # 60 deg of each hole seen: too little of its circumference to give a size at all
    assert got.status == "NOT_MEASURED" and got.value is None
    assert "unseen (at most 180)" in got.reason and "circumference" in got.reason, got.reason
    # read regardless, the fit goes astray and the plausibility bound refuses it
    from qifreport.metrology.gdt import dimensions

    with monkeypatch.context() as m:
        m.setattr(dimensions, "max_unseen_arc", lambda feat: 360.0)
        got = measure_dimension(spec, sparse, "iso14253")
    assert got.value == pytest.approx(2e5, rel=1e-3), got.reading  # the fit did go astray
    assert got.status == "NOT_MEASURED"
    assert got.reason.startswith("implausible reading: diameter 200000 mm"), got.reason
    assert "the part's 404.7 mm diagonal" in got.reason


def test_an_uncertainty_wider_than_the_part_is_not_measured(ftc06):
    part, drawing = ftc06
    specs = [_spec(drawing, "D9"), _spec(drawing, "G9")]
    perfect = exact_surface(part, np.zeros(len(part.V)))
    res, _ = measure_characteristics(specs, drawing.plan.datums, perfect, "iso14253")
    assert [r.status for r in res] == ["PASS", "PASS"], [r.reason for r in res]
    sparse = exact_surface(part, np.zeros(len(part.V)))
    for hole in sparse.features(specs[0].faces):
        sparse.U[sparse.own_vertices(hole)] = 1e4  # mm: a scan that does not know them
    res, _ = measure_characteristics(specs, drawing.plan.datums, sparse, "iso14253")
    for r in res:
        assert r.status == "NOT_MEASURED", (r.spec.key, r.status, r.uncertainty)
        assert r.reason.startswith("implausible reading:"), r.reason
        assert "uncertainty U" in r.reason and "404.7 mm diagonal" in r.reason, r.reason
    assert res[0].value == pytest.approx(15.875, abs=1e-3)  # the value itself is right


@pytest.mark.parametrize(
    ("value", "U", "status"),
    [
        (15.9, 0.01, "PASS"),
        (15.875 + 100.0, 0.01, "FAIL"),  # far out, still a part's size: judged
        (15.875 + 100.0, 100.0, "INDETERMINATE"),
        (15.875 + 101.0, 0.01, "NOT_MEASURED"),  # farther from nominal than the part
        (15.9, 100.5, "NOT_MEASURED"),
        (0.0, 0.01, "NOT_MEASURED"),  # no size
        (float("nan"), 0.01, "NOT_MEASURED"),
        (15.9, float("inf"), "NOT_MEASURED"),
    ],
)
def test_the_judgement_bounds(ftc06, value, U, status):
    """A part 100 mm across: a diameter of nominal 15.875 judged or not measured."""
    spec = _spec(ftc06[1], "D9")
    res = CharacteristicResult(spec, value=value, uncertainty=U)
    judge(res, "iso14253", spec.lower_limit, spec.upper_limit, 100.0)
    assert res.status == status, res.reason
    if status == "NOT_MEASURED":
        assert res.reason.startswith("implausible reading: diameter"), res.reason


@pytest.mark.parametrize(("value", "status"), [(90.2, "PASS"), (181.0, "NOT_MEASURED")])
def test_an_angle_is_bounded_by_its_range(ftc06, value, status):
    from dataclasses import replace

    spec = replace(
        _spec(ftc06[1], "D9"),
        dim_type="angle",
        unit="deg",
        nominal=90.0,
        lower_limit=89.5,
        upper_limit=90.5,
    )
    res = CharacteristicResult(spec, value=value, uncertainty=0.05)
    judge(res, "iso14253", spec.lower_limit, spec.upper_limit, 1000.0)
    assert res.status == status, res.reason
    if status == "NOT_MEASURED":
        assert "181 deg" in res.reason and "0..180 deg" in res.reason, res.reason
