"""Datum reference frames on measured points (metrology/gdt/datums.py; issue 22): 3-2-1 planes,
a plane with a hole pattern, the free motions of an incomplete frame, and the simulators
(tangent planes, inscribed and circumscribed cylinders) against closed forms and the
minimum-zone flatness of metrology/gdt/form.py."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qifreport.metrology.gdt.datums import (
    DatumFeature,
    datum_frame,
    nominal_feature,
    simulate_datum,
)
from qifreport.metrology.gdt.form import flatness

RNG = np.random.default_rng(5459)

#: the measured part: turned 0.8 deg about an oblique axis and moved (mm)
M_R = Rotation.from_rotvec(np.radians(0.8) * np.array([0.3, -0.5, 0.81]) / 1.0).as_matrix()
M_T = np.array([0.6, -0.4, 0.25])


def _moved(P):
    return P @ M_R.T + M_T


def _plane_points(origin, u, v, su, sv, n=400, form=0.0):
    """Points of a plane patch (origin, in-plane unit u, v, sizes), a smooth waviness of
    peak ``form`` mm along its normal."""
    a, b = RNG.uniform(0, su, n), RNG.uniform(0, sv, n)
    w = form * np.sin(a / su * 3.1) * np.cos(b / sv * 2.3)
    normal = np.cross(u, v)
    return origin + np.outer(a, u) + np.outer(b, v) + np.outer(w, normal)


X, Y, Z = np.eye(3)
A = DatumFeature("A", "plane", np.zeros(3), -Z)  # the bottom
B = DatumFeature("B", "plane", np.zeros(3), -X)  # the left side
C = DatumFeature("C", "plane", np.zeros(3), -Y)  # the front


def _block(form):
    return [
        _plane_points(np.zeros(3), X, Y, 100, 60, form=form),
        _plane_points(np.zeros(3), Y, Z, 60, 20, form=form),
        _plane_points(np.zeros(3), X, Z, 100, 20, form=form),
    ]


def test_a_3_2_1_frame_undoes_the_parts_placement():
    pts = [_moved(P) for P in _block(form=0.0)]
    drf = datum_frame([A, B, C], pts)
    assert drf.free == []
    # the frame is the placement's inverse: the part's corner back at the origin
    corner = drf.apply(_moved(np.zeros((1, 3))))[0]
    assert np.linalg.norm(corner) < 1e-9
    assert np.abs(drf.R @ M_R - np.eye(3)).max() < 1e-9


def test_the_primary_rocks_to_the_minimum_zone_and_the_others_keep_square():
    """With 20 um of waviness the primary simulator touches the high points and lies as
    close to the farthest as a plane outside the material can: the points' spread above
    it is the feature's minimum-zone flatness. The secondary and tertiary simulators stay
    perpendicular to it and touch their own high points."""
    raw = _block(form=0.02)
    pts = [_moved(P) for P in raw]
    drf = datum_frame([A, B, C], pts)
    a, b, c = (drf.apply(P) for P in pts)
    assert a[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    assert a[:, 2].max() == pytest.approx(flatness(pts[0]).minimum_zone, abs=1e-7)
    assert b[:, 0].min() == pytest.approx(0.0, abs=1e-9)
    assert c[:, 1].min() == pytest.approx(0.0, abs=1e-9)
    sa, sb, sc = drf.simulators
    assert abs(sa.direction @ sb.direction) < 1e-9
    assert abs(sc.direction @ sa.direction) < 1e-9 and abs(sc.direction @ sb.direction) < 1e-9
    # a least-squares plane would cut through the waviness: half the points below it
    assert sa.form == pytest.approx(flatness(pts[0]).minimum_zone, abs=1e-7)


def _cylinder_points(centre, axis, radius, length, lobes=0, amp=0.0, n=600):
    Rm = Rotation.align_vectors([axis], [[0, 0, 1.0]])[0].as_matrix()
    t, z = RNG.uniform(0, 2 * np.pi, n), RNG.uniform(0, length, n)
    r = radius + amp * np.cos(lobes * t)
    return centre + np.c_[r * np.cos(t), r * np.sin(t), z] @ Rm.T


@pytest.mark.parametrize("internal", [True, False])
def test_a_hole_is_simulated_inscribed_and_a_pin_circumscribed(internal):
    f = DatumFeature("D", "cylinder", np.array([10.0, 5, 0]), Z, 6.0, internal)
    P = _cylinder_points(np.array([10.3, 4.8, 0]), Z, 6.0, 15.0, lobes=3, amp=0.01)
    sim = simulate_datum(P, f)
    # three lobes of 10 um: the largest inscribed circle is R - A, the smallest
    # circumscribed R + A, both about the true centre
    assert sim.radius == pytest.approx(6.0 - 0.01 if internal else 6.0 + 0.01, abs=2e-4)
    d = sim.origin - np.array([10.3, 4.8, 0])
    assert np.linalg.norm(d - (d @ sim.direction) * sim.direction) < 1e-3


def test_a_plane_and_a_hole_pattern_locate_and_clock_the_part():
    """A|B|C with B and C holes square to A: B fixes the position in A's plane, C the
    rotation about A's normal (Y14.5's pattern as a tertiary)."""
    hb = DatumFeature("B", "cylinder", np.array([30.0, 30, 0]), Z, 5.0, True)
    hc = DatumFeature("C", "cylinder", np.array([80.0, 30, 0]), Z, 4.0, True)
    raw = [
        _plane_points(np.zeros(3), X, Y, 100, 60),
        _cylinder_points(hb.origin, Z, 5.0, 20.0),
        _cylinder_points(hc.origin, Z, 4.0, 20.0),
    ]
    drf = datum_frame([A, hb, hc], [_moved(P) for P in raw])
    assert drf.free == []
    # the nominal hole centres come back where they were drawn
    back = drf.apply(_moved(np.array([[30.0, 30, 7], [80.0, 30, 3]])))
    assert np.abs(back - [[30.0, 30, 7], [80.0, 30, 3]]).max() < 1e-6


def test_an_incomplete_frame_says_what_it_leaves_free():
    drf = datum_frame([A], [_moved(_block(0.0)[0])])
    assert sorted(drf.free) == sorted(
        ["translation along x", "translation along y", "rotation about z"]
    )
    drf = datum_frame([A, B], [_moved(P) for P in _block(0.0)[:2]])
    assert drf.free == ["translation along y"]


def test_nominal_features_from_mesh_vertices():
    # a plane patch with its outward normal
    V = _plane_points(np.array([0, 0, 5.0]), X, Y, 10, 10, n=50)
    f = nominal_feature("A", V, np.tile(Z, (50, 1)))
    assert f.kind == "plane" and f.direction @ Z == pytest.approx(1.0)
    assert (f.origin - [0, 0, 5.0]) @ Z == pytest.approx(0.0, abs=1e-12)
    # a hole (outward normals point at the axis) and a pin
    axis = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    P = _cylinder_points(np.array([3.0, -2, 1]), axis, 4.0, 12.0, n=200)
    proj = (P - [3.0, -2, 1]) - np.outer((P - [3.0, -2, 1]) @ axis, axis)
    radial = proj / np.linalg.norm(proj, axis=1, keepdims=True)
    for sign, internal in ((-1.0, True), (1.0, False)):
        f = nominal_feature("B", P, sign * radial)
        assert f.kind == "cylinder" and f.internal is internal
        assert f.radius == pytest.approx(4.0, abs=1e-9)
        assert abs(abs(f.direction @ axis) - 1) < 1e-12
    with pytest.raises(ValueError, match="neither a plane nor a cylinder"):
        nominal_feature("S", P, RNG.normal(size=P.shape))
