"""The virtual fixture's load on a part's elastic model (registration.restraint.fixture_load)."""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.registration.restraint.elastic import MATERIALS, elastic_model, material
from qifreport.registration.restraint.fixture_load import (
    FixtureLoad,
    fixture_load,
    load_model,
    without_rigid_motion,
)


def _plate(L: float, W: float, t: float, nx: int, ny: int):
    """A one-layer box of tetrahedra (six per hexahedron) and its surface triangles."""
    xs, ys, zs = (
        np.linspace(-L / 2, L / 2, nx + 1),
        np.linspace(-W / 2, W / 2, ny + 1),
        [-t / 2, t / 2],
    )
    X = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(len(X)).reshape(nx + 1, ny + 1, 2)
    T = []
    for i in range(nx):
        for j in range(ny):
            c = [idx[i + a, j + b, k] for a in (0, 1) for b in (0, 1) for k in (0, 1)]
            for p, q in ((4, 6), (6, 2), (2, 3), (3, 1), (1, 5), (5, 4)):
                T.append([c[0], c[p], c[q], c[7]])
    from qifreport.registration.restraint.fixture_load import boundary_faces

    F, n = boundary_faces(X, np.array(T))
    wound = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    flip = np.einsum("ij,ij->i", wound, n) < 0  # outward winding, as a nominal's
    F[flip] = F[flip][:, ::-1]
    return X, np.array(T), F


@pytest.fixture(scope="module")
def steel_plate():
    X, T, F = _plate(100.0, 20.0, 2.0, 20, 4)
    return X, F, load_model(elastic_model(X, T, MATERIALS["steel"]), X, F, "plate")


def test_bending_matches_plate_theory(steel_plate):
    """w = kappa x^2 / 2 on a 100 x 20 x 2 mm steel plate: the energy lies between the
    beam's (E I) and the plate's (D, no anticlastic curvature), within 5 % of the plate's;
    the surface stress within 10 % of E kappa t / 2 / (1 - nu^2)'s von Mises."""
    X, F, lm = steel_plate
    kappa, mat = 1e-3, MATERIALS["steel"]
    d = np.zeros_like(X)
    d[:, 2] = kappa * X[:, 0] ** 2 / 2
    load = fixture_load(lm, X, d)
    E, nu, t, L, W = mat.E, mat.nu, 2.0, 100.0, 20.0
    plate = 0.5 * E * t**3 / (12 * (1 - nu**2)) * kappa**2 * L * W
    beam = plate * (1 - nu**2)
    assert beam < load.energy <= plate * 1.01
    assert load.energy == pytest.approx(plate, rel=0.05)
    sx = E / (1 - nu**2) * kappa * t / 2
    assert load.peak_stress == pytest.approx(sx * np.sqrt(1 - nu + nu**2), rel=0.10)
    # a rigid motion added changes nothing
    moved = d + np.array([0.3, -0.2, 0.5]) + np.cross([0.0, 0.002, 0.001], X)
    assert fixture_load(lm, X, moved).energy == pytest.approx(load.energy, rel=1e-6)


def test_curved_shell_bends_as_shell_theory_says():
    """A cylindrical ABS panel (mid radius 220 mm, 1.8 mm wall, 124 mm arc x 100 mm) given
    the vertical field w = kappa x^2 / 2: its normal part is an inextensional bend of
    change of curvature kappa cos(phi) (cos^2 phi - 3 sin^2 phi) (shell theory), 0.794 of
    the flat plate's energy. The field's through-thickness part (the skins' normal
    displacements differ by kappa x t sin(phi)) is a change of the wall's thickness, held
    out: prescribed, it read 32 times the plate's energy."""
    R, t, L, W, kappa, mat = 220.0, 1.8, 124.0, 100.0, 1e-4, MATERIALS["abs"]
    X, T, F = _plate(L, W, t, 31, 25)
    phi = X[:, 0] / R
    X = np.stack([(R + X[:, 2]) * np.sin(phi), X[:, 1], (R + X[:, 2]) * np.cos(phi) - R], 1)
    lm = load_model(elastic_model(X, T, mat), X, F, "cylindrical panel")
    d = np.zeros_like(X)
    d[:, 2] = kappa * X[:, 0] ** 2 / 2
    load = fixture_load(lm, X, d)
    p = np.linspace(-L / 2 / R, L / 2 / R, 2001)
    shell = np.mean(np.cos(p) ** 2 * (np.cos(p) ** 2 - 3 * np.sin(p) ** 2) ** 2)
    plate = 0.5 * mat.E * t**3 / (12 * (1 - mat.nu**2)) * kappa**2 * L * W
    assert load.energy == pytest.approx(shell * plate, rel=0.06)
    assert load.thickness_change == pytest.approx(kappa * 62 * t * np.sin(62 / R), rel=0.1)


def _pressure_response(X: np.ndarray, lm) -> tuple[np.ndarray, float]:
    """The steel plate's static response (n, 3) mm to a smooth self-equilibrated pressure,
    10 N cos(2 pi x / 100) on its top skin less its mean, held statically determinate at
    three corners, and the load's work, mJ."""
    model = lm.model
    top = np.flatnonzero(X[:, 2] > 0)
    p = np.cos(2 * np.pi * X[top, 0] / 100.0)
    load = np.zeros(model.n_dofs)
    load[model.vertex_dofs[top, 2]] = 10.0 * (p - p.mean())
    a, b, c = (
        int(np.argmin(np.linalg.norm(X - q, axis=1)))
        for q in ((-50, -10, -1), (50, -10, -1), (-50, 10, -1))
    )
    sol = model.solve(fixed=[(a, 0), (a, 1), (a, 2), (b, 1), (b, 2), (c, 2)], load=load)
    return model.displacement_at(sol, X), 0.5 * float(load @ sol.dofs)


def test_least_energy_hold_reads_an_elastic_field(steel_plate):
    """The plate's own static response to a smooth self-equilibrated pressure (10 N
    cos(2 pi x / L) on its top skin, less its mean): held exactly it reads the load's work;
    within a misfit delta rms it reads the least energy of a state that close, for a
    field of one bending shape (1 - delta / rho)^2 of it (rho: the held normal
    displacements' rms), reached at a misfit within 5 % below delta. (The fields of the
    theory tests above prescribe their curvature up to the free edges, which an elastic
    plate cannot keep without edge moments: a misfit of 0.001 mm already relaxes 5 % of
    their energy, so they are read on the exact hold.)"""
    X, F, lm = steel_plate
    u, work = _pressure_response(X, lm)
    target = np.einsum("ij,ij->i", lm.W @ without_rigid_motion(X, u), lm.normals)
    rho = float(np.sqrt(np.mean(target**2)))
    exact = fixture_load(lm, X, u)
    assert exact.energy == pytest.approx(work, rel=1e-3) and exact.misfit == 0.0
    for delta in (0.002, 0.01):
        held = fixture_load(lm, X, u, delta, "test")
        assert 0.95 * delta <= held.misfit <= delta
        assert held.energy == pytest.approx(work * (1 - delta / rho) ** 2, rel=0.005)
        assert held.to_dict()["hold_misfit_allowed_mm"] == delta
        assert f"allowed {delta:.2g} mm: test" in held.describe()


def test_compliant_modes_keep_a_flexure_and_leave_a_bump(steel_plate):
    """The plate's lowest elastic modes are the beam's (first free-free bending 22.4 /
    L^2 sqrt(E t^2 / 12 rho), 6,690 rad/s); its static response to a smooth pressure lies in
    its compliant modes (the remainder within 1 % of its 1.08 mm); a 0.5 mm Gaussian bump of
    sigma 4 mm added at x = 25 mm stays outside them for at least 70 % of its height at its
    centre, and at most 20 % of it anywhere beyond three sigma; the narrowest bump they take
    more than half of is sigma 8 mm."""
    from qifreport.registration.restraint.elastic import elastic_modes

    X, F, lm = steel_plate
    mat = MATERIALS["steel"]
    t, L = 2.0, 100.0
    omega2, _ = elastic_modes(elastic_model(*_plate(L, 20.0, t, 20, 4)[:2], mat), 2)
    beam = 22.4 / L**2 * np.sqrt(mat.E * t**2 / (12 * mat.density))
    assert np.sqrt(omega2[0]) == pytest.approx(beam, rel=0.02)
    assert 4 <= lm.modes.shape[1] <= 12
    u, _ = _pressure_response(X, lm)
    flex = float(np.abs(without_rigid_motion(X, u)[:, 2]).max())
    assert fixture_load(lm, X, u, 0.001).max_departure < 0.01 * flex
    r2 = (X[:, 0] - 25.0) ** 2 + X[:, 1] ** 2
    bump = np.zeros_like(X)
    bump[:, 2] = 0.5 * np.exp(-r2 / (2 * 4.0**2))
    load = fixture_load(lm, X, u + bump, 0.001)
    left = load.departure[:, 2]  # the modal shape less the fitted one: below the bump
    assert np.all(left[r2 < 1.0] < -0.7 * 0.5)
    assert np.abs(left[r2 > 12.0**2]).max() < 0.2 * 0.5
    assert load.to_dict()["compliant_modes"] == lm.modes.shape[1]
    # the narrowest bump the modes take more than half of: sigma 8 mm (a 4 mm one keeps 83 %
    # of its height outside them), said in the load's line
    assert lm.absorbed_width == 8.0
    assert "sigma >= 8 mm lies mostly in them" in load.describe()


def test_refused_with_forces_named(steel_plate):
    """A stiff part forced beyond the limit is refused, the forces in the reason; within
    it and the yield strength, nothing is refused."""
    X, F, lm = steel_plate
    d = np.zeros_like(X)
    d[:, 2] = 1e-3 * X[:, 0] ** 2 / 2
    big = fixture_load(lm, X, d).bounded(100.0, "--max-restraint-force")
    assert big.over_force and big.equivalent_force > 100.0
    (why,) = [r for r in big.refusals() if "N to hold" in r]
    assert f"{big.equivalent_force:.3g} N" in why and "100 N limit" in why
    small = fixture_load(lm, X, 1e-3 * d).bounded(100.0, "default")
    assert small.refusals() == [] and 0 < small.equivalent_force < 1.0
    assert "> 100" in big.short() and "<= 100" in small.short()
    assert "over the 100 N limit" in big.describe() and "within" in small.describe()
    assert FixtureLoad.not_established("no material").refusals() == []


def test_yield_in_presets_and_values():
    assert MATERIALS["steel"].yield_strength == 235.0
    assert material("E=70000,nu=0.33,yield=240").yield_strength == 240.0
    with pytest.raises(ValueError):
        material("E=70000,nu=0.33,yield=-1")


@pytest.fixture(scope="module")
def ftc08_load():
    """NIST FTC 08 (its note 5 states a restraint: the virtual fixture applies) as the
    inspection prepares it for the fixture's load: its nominal mesh and its STEP solid's
    gmsh tetrahedra, aluminium (:func:`qifreport.restraint.build_load_model`)."""
    from qifreport.nominal import load_nominal
    from qifreport.restraint import LoadSpec, build_load_model
    from tests.conftest import shared_file

    part, _ = load_nominal(
        shared_file("step/nist/nist_ftc_08_asme1_ap242-e1.stp"), None, solid_mesh=True
    )
    solid = (part.solid_mesh.X, part.solid_mesh.T)
    # the load alone: the compliant modes have their own test (an eigensolve of 17 s here)
    lm = build_load_model(
        part.V, part.F, LoadSpec("aluminium"), solid=solid, step=True, modes=False
    )
    assert not isinstance(lm, str), lm
    return part.V, lm


def _bend(V: np.ndarray, kappa: float) -> np.ndarray:
    """A pure bend about y of curvature ``kappa`` 1/mm (sections turn with the neutral
    plane at the part's mid-height): ``u_z = kappa x^2 / 2``, ``u_x = -kappa x (z - z0)``."""
    x = V[:, 0] - V[:, 0].mean()
    z = V[:, 2] - 0.5 * (V[:, 2].min() + V[:, 2].max())
    d = np.zeros_like(V)
    d[:, 2] = 0.5 * kappa * x**2
    d[:, 0] = -kappa * x * z
    return d


def test_ftc08_restraint_beyond_the_limit_is_refused_with_its_forces(ftc08_load):
    """The fixture-load stage (:func:`qifreport.metrology.inspection.with_fixture_load`,
    as a fixtured inspection runs it) on a fitted field of FTC 08: a bend of 0.2 mm over
    its 312 mm length (kappa 1.6e-5 / mm). Its energy lies below the bounding block's
    plate energy (the part is that block less its pockets); the force to hold it exceeds
    ``--max-restraint-force`` 100 N, so a PASS is refused, the forces named (equivalent
    force, energy, correction, the most loaded contact, the limit's source) in the refusal
    and the JSON block; with a limit above the force, nothing is refused for it."""
    from dataclasses import replace
    from types import SimpleNamespace

    from qifreport.metrology.inspection import with_fixture_load

    V, lm = ftc08_load
    kappa = 2 * 0.2 / 156.0**2

    def stage(d: np.ndarray, limit: float | None):
        # a zone so tight that the hold is the exact one (within 0.1 um rms): its energy is
        # then bounded by the block's plate energy (the least-energy hold has its own tests)
        zone = SimpleNamespace(key="T", width=0.001, free_state=False)
        run = SimpleNamespace(
            ctx=SimpleNamespace(fixture_load=lm, bands=SimpleNamespace(zones=[zone])),
            params=SimpleNamespace(max_restraint_force=limit),
            reg=SimpleNamespace(V=V),
            timings={},
        )
        res = SimpleNamespace(fit=SimpleNamespace(V=V + d), fixture_load=None, passed=False)
        return with_fixture_load(res, run).fixture_load

    load = stage(_bend(V, kappa), 100.0)
    mat, (L, W, H) = MATERIALS["aluminium"], np.ptp(V, axis=0)
    plate = 0.5 * mat.E * H**3 / (12 * (1 - mat.nu**2)) * kappa**2 * L * W
    assert 0.05 * plate < load.energy < plate, (load.energy, plate)
    assert load.over_force and load.equivalent_force > 100.0
    why = next(r for r in load.refusals() if "N to hold" in r)
    for figure in (load.equivalent_force, load.energy, load.max_correction, load.peak_pad_force):
        assert f"{figure:.3g}" in why, (figure, why)
    assert "100 N limit (--max-restraint-force)" in why
    js = load.to_dict()
    assert js["refused"] and js["over_limit"] and js["limit_N"] == 100.0
    assert js["equivalent_force_N"] == pytest.approx(load.equivalent_force)
    # a limit the force stays within refuses nothing for the force
    within = replace(load).bounded(2 * load.equivalent_force, "--max-restraint-force")
    assert not within.over_force and "N to hold" not in " ".join(within.refusals())
