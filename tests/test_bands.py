"""Tolerance zones: bands from PMI, tightest-zone rule, per-zone criteria."""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.acceptance.bands import (
    DEFAULT_GENERAL_TOLERANCE,
    ToleranceZone,
    lay_bands,
    profile_band,
    symmetric_zone,
    zone_vertex_areas,
    zones_from_pmi,
)
from qifreport.metrology.acceptance.criteria import evaluate
from qifreport.step.pmi import PMI, DatumRef, Dimension, GeometricTolerance


def _grid(n=21, h=1.0):
    """A flat n x n vertex grid (mm) split in two B-rep 'faces' at x = 10."""
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h, indexing="ij")
    V = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    cx = V[F].mean(axis=1)[:, 0]
    face_id = (cx > 10).astype(np.int64)
    return V, F, face_id


def _tol(step_id, value, faces, typ="surface_profile", uz=None, mods=(), datums=()):
    return GeometricTolerance(
        step_id=step_id,
        name=f"t{step_id}",
        type=typ,
        value=value,
        value_text=f"{value} MM",
        zone_form=None,
        modifiers=list(mods),
        unequal_displacement=uz,
        max_value=None,
        unit_basis=None,
        datums=[DatumRef(lab, i + 1, []) for i, lab in enumerate(datums)],
        face_step_ids=list(faces),
        problems=[] if value is not None else ["no magnitude"],
    )


def _pmi(tols, dims=()):
    return PMI(
        schema="AP242",
        length_unit="mm",
        length_scale=1.0,
        tolerances=list(tols),
        dimensions=list(dims),
        datums=[],
        problems=[],
    )


def test_profile_band_bilateral_unequal_unilateral():
    assert profile_band(1.0, None) == (-0.5, 0.5)
    assert profile_band(1.0, 0.2) == pytest.approx((-0.8, 0.2))
    assert profile_band(0.6, 0.6) == pytest.approx((0.0, 0.6))  # all outside the material
    assert profile_band(0.6, 0.0) == pytest.approx((-0.6, 0.0))  # all inside
    with pytest.raises(ValueError):
        profile_band(0.5, 0.7)
    with pytest.raises(ValueError):
        profile_band(0.0, None)


def test_zones_from_pmi_sources_and_skips():
    # STEP face #100 -> face 0, #200 -> face 1
    fidx = {100: 0, 200: 1}
    pmi = _pmi(
        [
            _tol(11, 1.0, [100, 200], datums=("A", "B", "C")),
            _tol(12, 0.4, [200], uz=0.1),
            _tol(13, None, [100]),  # value not established
            _tol(14, 0.05, [100], typ="flatness"),  # feature tolerance
            _tol(15, 0.3, [999]),  # faces unknown
        ],
        dims=[
            Dimension(
                step_id=20,
                name="d",
                kind="size",
                type="diameter",
                unit="mm",
                nominal=10.0,
                lower=-0.1,
                upper=0.1,
                lower_limit=None,
                upper_limit=None,
                fit=None,
                qualifiers=[],
                face_step_ids=[100],
                problems=[],
            )
        ],
    )
    zones, skipped = zones_from_pmi(pmi, fidx, general=None)
    assert [z.key for z in zones] == ["T1", "T2", "general"]
    assert zones[0].datums == ["A", "B", "C"] and zones[0].source == "pmi"
    assert (zones[1].lower, zones[1].upper) == pytest.approx((-0.3, 0.1))
    assert zones[-1].source == "default" and zones[-1].half_width == DEFAULT_GENERAL_TOLERANCE
    reasons = {s.step_id: s.reason for s in skipped}
    # the flatness (14) and the dimension (20) are feature characteristics (issue 22)
    assert set(reasons) == {13, 15}
    assert "could not be established" in reasons[13]
    from qifreport.metrology.gdt.pmi_plan import specs_from_pmi

    plan = specs_from_pmi(pmi, fidx)
    assert [(s.key, s.step_id) for s in plan.specs] == [("G1", 14), ("D1", 20)]
    assert plan.specs[1].lower_limit == pytest.approx(9.9)
    zones2, _ = zones_from_pmi(pmi, fidx, general=0.2)
    assert zones2[-1].source == "general" and zones2[-1].half_width == 0.2


def test_tightest_zone_governs_shared_vertices_and_general_fills_gaps():
    V, F, fid = _grid()
    wide = ToleranceZone("T1", "wide", "surface_profile", 1.0, -0.5, 0.5, np.array([0]), "pmi")
    tight = ToleranceZone("T2", "tight", "surface_profile", 0.2, -0.1, 0.1, np.array([1]), "pmi")
    bands = lay_bands(F, len(V), fid, [wide, tight, symmetric_zone(0.3, "general")])
    # the general zone covers no triangle here
    assert not bands.tri_masks[2].any()
    x = V[:, 0]
    assert np.all(bands.half_width[x < 10 - 1e-9] == 0.5)
    assert np.all(bands.half_width[x > 10 + 1e-9] == 0.1)
    assert np.all(bands.half_width[np.isclose(x, 10)] == 0.1)  # shared boundary: tightest
    # a partly covered part: the rest takes the general band
    bands = lay_bands(F, len(V), fid, [tight, symmetric_zone(0.3, "general")])
    assert np.all(bands.half_width[x < 10 - 1e-9] == 0.3)
    assert np.all(bands.governing[x < 10 - 1e-9] == 1)


def test_per_zone_criteria_fail_only_the_offending_surface():
    """A 0.3 mm warp on face 1 fails the tight zone there but not the wide one on face 0."""
    V, F, fid = _grid()
    dev = np.where(V[:, 0] > 12, 0.3, 0.0)
    zones = [
        ToleranceZone("T1", "wide", "surface_profile", 1.0, -0.5, 0.5, np.array([0]), "pmi"),
        ToleranceZone("T2", "tight", "surface_profile", 0.4, -0.2, 0.2, np.array([1]), "pmi"),
    ]
    bands = lay_bands(F, len(V), fid, zones)
    res = {}
    for z, m in zip(bands.zones, bands.tri_masks, strict=True):
        az = zone_vertex_areas(V, F, m)
        dz = np.where(az > 0, dev, np.nan)
        res[z.key] = evaluate(V, F[m], dz, z.half_width, area=az, center=z.center)
    assert res["T1"].passed
    assert not res["T2"].passed
    assert res["T2"].scored_area == pytest.approx(200.0)  # face 1 is 10 x 20 mm
    # an unequal zone [-0.1, +0.3] accepts the same +0.3 warp
    uz = ToleranceZone("T2", "uz", "surface_profile", 0.4, -0.1, 0.3, np.array([1]), "pmi")
    m = lay_bands(F, len(V), fid, [uz]).tri_masks[0]
    az = zone_vertex_areas(V, F, m)
    acc = evaluate(V, F[m], np.where(az > 0, dev, np.nan), uz.half_width, area=az, center=uz.center)
    assert acc.passed and acc.in_tolerance_fraction == pytest.approx(1.0)
    # ... and rejects a -0.3 sink of the same size
    acc = evaluate(
        V, F[m], np.where(az > 0, -dev, np.nan), uz.half_width, area=az, center=uz.center
    )
    assert not acc.passed


def test_zone_vertex_areas_partition_the_total():
    from qifreport.registration.mesh import vertex_areas

    V, F, fid = _grid()
    a0 = zone_vertex_areas(V, F, fid == 0)
    a1 = zone_vertex_areas(V, F, fid == 1)
    np.testing.assert_allclose(a0 + a1, vertex_areas(V, F), rtol=1e-12, atol=1e-12)
    assert a0.sum() == pytest.approx(200.0) and a1.sum() == pytest.approx(200.0)
