"""What a clamp set holds, stated before it holds anything: the sample shell's rim set (four
normals and three in-plane directions) over-constrains it; six normals of the same shallow
shell hold its in-plane slides only through their surface's tilt and are refused, the slides
named; five directions leave a motion free; six well spread directions locate the part."""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.registration.mesh import load_mesh, vertex_normals
from qifreport.registration.restraint.clamp_set import WEAKEST_HOLD, classify_clamp_set
from qifreport.simulate.shapes import rim_clamps
from tests.conftest import ROOT

NOMINAL = ROOT / "samples" / "shell_nominal.ply"


@pytest.fixture(scope="module")
def shell():
    V, F = load_mesh(NOMINAL)
    return V, F, vertex_normals(V, F)


def _classify(V, N, spots):
    """Spots ``(x, y, directions)``: each at the vertex nearest (x, y), along its normal
    (``n``) or the axes named."""
    P, D = [], []
    for x, y, d in spots:
        v = int(np.argmin(np.linalg.norm(V[:, :2] - (x, y), axis=1)))
        for a in d:
            P.append(V[v])
            D.append(N[v] if a == "n" else np.eye(3)["xyz".index(a)])
    return classify_clamp_set(np.array(P), np.array(D), V, 5.0)


def test_the_rim_set_over_constrains_the_shell_and_places_it_firmly(shell):
    V, _, N = shell
    clamps, normals = rim_clamps(V, N, inset=6.0)
    P = np.array([c.position for c, n in zip(clamps, normals, strict=True) for _ in c.axes(n)])
    D = np.array([e for c, n in zip(clamps, normals, strict=True) for e in c.axes(n)])
    cs = classify_clamp_set(P, D, V, 5.0)
    assert (cs.kind, cs.directions, cs.rank, cs.removes_flex) == ("over-constrained", 7, 6, True)
    assert 0.5 < cs.weakest and cs.refusal() is None and cs.weak == ()
    assert "bends the part to its clamps" in cs.describe()


def test_six_normals_of_a_shallow_shell_are_refused_naming_the_slides(shell):
    V, _, N = shell
    xs, ys = (-79.0, 0.0, 79.0), (-49.0, 49.0)
    cs = _classify(V, N, [(x, y, "n") for x in xs[::2] for y in ys] + [(0, y, "n") for y in ys])
    assert cs.rank == 6 and cs.kind == "kinematic"
    assert cs.weakest < WEAKEST_HOLD / 3  # 0.02: a 0.1 mm misreading moves it ~5 mm
    assert cs.ill_conditioned and set(cs.weak) == {"a slide along x", "a slide along y"}
    why = cs.refusal()
    assert why.startswith("the clamps hold a slide along") and "too weakly" in why


def test_five_directions_leave_a_motion_free_and_six_spread_ones_locate(shell):
    V, _, N = shell
    five = _classify(V, N, [(-79, -49, "n"), (79, -49, "n"), (-79, 49, "n"), (-79, 0, "xy")])
    assert five.rank == 5 and five.kind == "under-constrained"
    assert "leave 1 rigid motion(s) of the part free" in five.refusal()
    six = _classify(
        V, N, [(-79, -49, "n"), (79, -49, "n"), (-79, 49, "n"), (-79, 0, "xy"), (79, 0, "y")]
    )
    assert (six.kind, six.rank, six.removes_flex, six.refusal()) == ("kinematic", 6, False, None)
    assert "removes no flex; the part is judged in its free shape, located" in six.describe()
