"""The part's elastic model (:mod:`qifreport.registration.restraint.elastic`, issue 21 item 1)
against
closed forms, on real gmsh tetrahedral meshes of real OCP solids
(:func:`qifreport.step.gmsh_mesh.gmsh_solid_mesh`).

* A steel cantilever strip (200 x 10 x 2 mm) under its own weight: tip deflection
  ``q L^4 / (8 E I) = 3 rho g L^4 / (2 E t^2)`` within 3 % (Euler-Bernoulli; the 3-D
  clamped root adds about t / L), halving the element size changes it < 2 %, and the
  clamp's reaction equals the weight.
* A simply supported square steel plate (100 x 100 x 2 mm) under its own weight (one
  quarter with symmetry planes): centre deflection ``0.00406 q a^4 / D`` (Navier's series,
  Timoshenko & Woinowsky-Krieger Table 8) within 3 %, converged < 2 %.
* Linear tetrahedra lock in bending (the reason the model is quadratic): they read the
  cantilever at under half its deflection on the same mesh.
* The same cantilever as a mesh nominal, its mid-surface thickened into one layer of
  tetrahedra (:mod:`qifreport.registration.restraint.sheet_solid`): within 3 %, converged < 2 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.registration.linalg import BACKEND_ENV, have_cholmod
from qifreport.registration.restraint.elastic import GRAVITY, MATERIALS, elastic_model, material

STEEL = MATERIALS["steel"]


def box(x0, x1, y0, y1, z0, z1, h: float):
    """A box solid made by OCP (through cadquery) and filled by gmsh: (X, T)."""
    import cadquery as cq

    from qifreport.step.gmsh_mesh import gmsh_solid_mesh

    solid = cq.Solid.makeBox(x1 - x0, y1 - y0, z1 - z0, pnt=cq.Vector(x0, y0, z0))
    m = gmsh_solid_mesh(solid.wrapped, h)
    return m.X, m.T


def on(X: np.ndarray, axis: int, value: float) -> np.ndarray:
    return np.flatnonzero(np.abs(X[:, axis] - value) < 1e-6)


def cantilever(h: float, order: int = 2) -> tuple[float, float, float]:
    """(tip deflection mm, closed form mm, clamp reaction / weight)."""
    L, b, t = 200.0, 10.0, 2.0
    X, T = box(0.0, L, -b / 2, b / 2, -t / 2, t / 2, h)
    model = elastic_model(X, T, STEEL, order=order)
    root = on(X, 0, 0.0)
    fixed = np.array([(v, a) for v in root for a in range(3)])
    sol = model.solve(fixed, load=model.gravity())
    tip = -float(sol.u[on(X, 0, L), 2].mean())
    exact = 3.0 * STEEL.density * GRAVITY * L**4 / (2.0 * STEEL.E * t**2)
    weight = STEEL.density * GRAVITY * L * b * t
    return tip, exact, float(sol.reaction[:, 2].sum()) / weight


def quarter_plate(h: float) -> tuple[float, float]:
    """(centre deflection mm, Navier's closed form mm) of the simply supported plate."""
    a, t = 100.0, 2.0
    X, T = box(0.0, a / 2, 0.0, a / 2, -t / 2, t / 2, h)
    model = elastic_model(X, T, STEEL)
    fixed = [(v, 2) for v in np.r_[on(X, 0, a / 2), on(X, 1, a / 2)]]  # the supported edges
    fixed += [(v, 0) for v in on(X, 0, 0.0)] + [(v, 1) for v in on(X, 1, 0.0)]  # symmetry
    sol = model.solve(np.array(fixed), load=model.gravity())
    centre = -float(sol.u[:, 2].min())
    D = STEEL.E * t**3 / (12.0 * (1.0 - STEEL.nu**2))
    q = STEEL.density * GRAVITY * t
    return centre, 0.00406235 * q * a**4 / D


def test_cantilever_tip_deflection_and_convergence():
    coarse, exact, _ = cantilever(5.0)
    fine, _, reaction = cantilever(2.5)
    assert fine == pytest.approx(exact, rel=0.03)
    assert abs(fine - coarse) / fine < 0.02
    assert reaction == pytest.approx(1.0, rel=1e-6)


def test_simply_supported_plate_under_gravity():
    coarse, exact = quarter_plate(5.0)
    fine, _ = quarter_plate(2.5)
    assert fine == pytest.approx(exact, rel=0.03)
    assert abs(fine - coarse) / fine < 0.02


def test_linear_tetrahedra_lock():
    locked, exact, _ = cantilever(5.0, order=1)
    assert locked < 0.5 * exact


def test_materials_and_refusals():
    assert material("Aluminum") is MATERIALS["aluminium"]
    custom = material("E=9500, nu=0.35, density=1.36e-9")
    assert (custom.E, custom.nu, custom.density) == (9500.0, 0.35, 1.36e-9)
    for bad in ("unobtainium", "E=-1,nu=0.3", "E=200000,nu=0.5", "E=1e5", "E=abc,nu=0.3"):
        with pytest.raises(ValueError):
            material(bad)
    X, T = box(0.0, 10.0, 0.0, 10.0, 0.0, 1.0, 2.0)
    model = elastic_model(X, T, STEEL)
    with pytest.raises(ValueError, match="rigid motion"):
        model.solve(np.array([(0, 2)]), load=model.gravity())


def sheet_cantilever(h: float) -> tuple[float, float]:
    """The cantilever strip as a mesh nominal (a mid-surface grid) thickened to 2 mm
    (:func:`qifreport.registration.restraint.sheet_solid.sheet_solid`): (tip deflection, closed
    form)."""
    from qifreport.registration.restraint.sheet_solid import sheet_solid
    from tests.test_metrology import grid_mesh

    L, b, t = 200.0, 10.0, 2.0
    nx, ny = int(round(L / h)) + 1, int(round(b / h)) + 1
    V, F = grid_mesh(nx, ny, h)
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    sheet = sheet_solid(V, F, N, t)
    model = elastic_model(sheet.X, sheet.T, STEEL)
    root = on(sheet.X, 0, 0.0)
    sol = model.solve(np.array([(v, a) for v in root for a in range(3)]), load=model.gravity())
    mid = sheet.mid_surface(sol.u)
    tip = -float(mid[on(V, 0, L), 2].mean())
    return tip, 3.0 * STEEL.density * GRAVITY * L**4 / (2.0 * STEEL.E * t**2)


def test_a_sheet_thickened_into_one_layer_bends_right():
    """One layer of quadratic tetrahedra through the thickness: within 3 % of the closed
    form, converged < 2 %, and the split conforming (no gap between prisms: a
    non-conforming split would read the strip far softer)."""
    coarse, exact = sheet_cantilever(5.0)
    fine, _ = sheet_cantilever(2.5)
    assert fine == pytest.approx(exact, rel=0.03)
    assert abs(fine - coarse) / fine < 0.02


def test_a_pad_pushing_a_plate_needs_the_closed_form_force():
    """A 6 mm pad pushing the simply supported plate's centre down by 0.05 mm (one quarter,
    symmetry planes) needs ``P = w D / (0.0116 a^2)`` (Timoshenko & Woinowsky-Krieger,
    Table 23: central load on a simply supported square plate), within 3 % (measured
    +1.2 %: the pad spreads the load a little); the pad moves
    exactly 0.05 mm along its (non-axis) direction when tilted, and a pad alone cannot hold
    the plate's rigid motions."""
    from qifreport.registration.restraint.elastic import Pad

    a, t, w = 100.0, 2.0, 0.05
    X, T = box(0.0, a / 2, 0.0, a / 2, -t / 2, t / 2, 2.5)
    model = elastic_model(X, T, STEEL)
    fixed = [(v, 2) for v in np.r_[on(X, 0, a / 2), on(X, 1, a / 2)]]
    fixed += [(v, 0) for v in on(X, 0, 0.0)] + [(v, 1) for v in on(X, 1, 0.0)]
    top = on(X, 2, t / 2)
    pad = top[np.linalg.norm(X[top, :2], axis=1) <= 3.0]
    assert len(pad) >= 3
    sol = model.solve(np.array(fixed), pads=[Pad(pad, (0.0, 0.0, 1.0), -w)])
    assert np.allclose(sol.u[pad, 2], -w, atol=1e-12)
    D = STEEL.E * t**3 / (12.0 * (1.0 - STEEL.nu**2))
    P = -4.0 * float(sol.pad_forces[0])  # the whole plate's load, N
    assert P == pytest.approx(w * D / (0.0116 * a**2), rel=0.03)
    with pytest.raises(ValueError, match="rigid motion"):
        model.solve(pads=[Pad(pad, (0.0, 0.0, 1.0), -w)])
    d = np.array([0.0, 0.6, -0.8])  # the same pad along a tilted direction
    tilted = model.solve(np.array(fixed), pads=[Pad(pad, d, 0.01)])
    assert np.allclose(tilted.u[pad] @ d, 0.01, atol=1e-12)


def test_the_sample_panel_step_solid_fills_with_tetrahedra():
    """The sample panel's STEP solid (read by the product's reader) filled by gmsh: the
    tetrahedra's volume is the B-rep's (OCP's volume integral) within 0.5 % (measured
    +0.14 % at 10 mm), none degenerate, and its elastic model builds and sags under its own
    weight on three of its corners."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    from qifreport.step.gmsh_mesh import gmsh_solid_mesh
    from qifreport.step.reader import read_step
    from tests.conftest import ROOT

    part = read_step(ROOT / "samples" / "panel.step", pmi=False)
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(part.shape, props)
    m = gmsh_solid_mesh(part.shape, 10.0)
    a, b, c, d = (m.X[m.T[:, i]] for i in range(4))
    vol = np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0
    assert vol.sum() == pytest.approx(props.Mass(), rel=0.005)
    assert vol.min() > 1e-6 * vol.mean()
    model = elastic_model(m.X, m.T, MATERIALS["aluminium"])
    lo = m.X.min(axis=0)
    corners = [np.argmin(np.linalg.norm(m.X - q, axis=1)) for q in (lo, m.X.max(axis=0))]
    corners.append(np.argmin(np.linalg.norm(m.X - [m.X[:, 0].max(), lo[1], lo[2]], axis=1)))
    fixed = [(v, a) for v in corners for a in range(3)]
    sol = model.solve(np.array(fixed), load=model.gravity())
    assert np.isfinite(sol.u).all() and 0.0 < np.abs(sol.u).max() < 10.0


@pytest.mark.parametrize("backend", ["superlu", *(["cholmod"] if have_cholmod() else [])])
def test_the_clamp_responses_solve_the_saddle_problem_and_the_stiffness_is_scikit_fem_s(
    backend, monkeypatch
):
    """The clamps' unit responses (one factorisation of the augmented, positive-definite
    stiffness in a nested-dissection order, with SuperLU or CHOLMOD, and the constraints'
    Schur complement) equal the model's direct saddle-point solve (``ElasticModel.solve``:
    SuperLU with pivoting, one drive at a time) to 1e-8 of the largest displacement and
    force; the stiffness equals scikit-fem's own ``linear_elasticity`` assembly to 1e-12;
    the elastic modes carry a fixed sign."""
    from skfem import asm
    from skfem.models.elasticity import linear_elasticity

    from qifreport.registration.restraint.elastic import Pad, elastic_modes

    X, T = box(0.0, 40.0, 0.0, 10.0, 0.0, 4.0, 3.0)
    model = elastic_model(X, T, STEEL)
    K = asm(linear_elasticity(*STEEL.lame), model._basis).tocsr()
    assert abs(model.K - K).max() <= 1e-12 * abs(K).max()

    def near(axis: int, value: float, r: float, c: tuple[float, float]) -> np.ndarray:
        face = on(X, axis, value)
        other = [a for a in range(3) if a != axis]
        return face[np.linalg.norm(X[face][:, other] - c, axis=1) <= r]

    pads = [
        Pad(near(0, 0.0, 2.5, (5.0, 2.0)), (1.0, 0.0, 0.0)),  # rigid: x and two tilts
        Pad(near(2, 0.0, 3.0, (8.0, 5.0)), (0.0, 0.0, 1.0)),  # rigid: z and two tilts
        Pad(near(1, 0.0, 2.5, (20.0, 2.0)), (0.0, 1.0, 0.0), mean=True),
        Pad(near(2, 0.0, 3.0, (34.0, 5.0)), (0.0, 0.0, 1.0), mean=True),
    ]
    assert all(len(p.vertices) >= 3 for p in pads)
    load = model.gravity()
    monkeypatch.setenv(BACKEND_ENV, backend)
    D, G = model.pad_responses(pads, load)
    assert D.shape == (model.n_dofs, 5) and G.shape == (4, 5)
    for j in range(5):
        for k, p in enumerate(pads):
            p.value = float(k == j)
        sol = model.solve(pads=pads, load=load if j == 4 else None)
        assert np.abs(sol.dofs - D[:, j]).max() <= 1e-8 * np.abs(D).max()
        assert np.abs(sol.pad_forces - G[:, j]).max() <= 1e-8 * np.abs(G).max()

    _, modes = elastic_modes(model, 3)
    big = np.argmax(np.abs(modes), axis=0)
    assert np.all(modes[big, np.arange(3)] > 0)
