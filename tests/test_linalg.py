"""The sparse SPD solves: SuperLU in its two orders and CHOLMOD give the same answers.

Both paths are the product: CHOLMOD where ``make install`` could build scikit-sparse (CI),
SuperLU otherwise. The systems are the shell's own bending operator, and GB-CICP is run
end to end on the shell with a bump (so its refits hold measurement out) on each path.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from qifreport.registration.deformable.bending_basis import bending_basis
from qifreport.registration.deformable.gbcicp import gbcicp
from qifreport.registration.icp import rigid_icp
from qifreport.registration.linalg import BACKEND_ENV, SPDSolver, default_backend, have_cholmod
from qifreport.registration.mesh import adjacency, bending_operator
from qifreport.registration.ordering import nested_dissection


def _need_cholmod() -> None:
    if have_cholmod():
        return
    if os.environ.get("CI") == "true":
        pytest.fail("CHOLMOD (scikit-sparse) is not installed: make install should build it")
    pytest.skip("CHOLMOD (scikit-sparse) is not installed")


@pytest.fixture(scope="module")
def shell_system(shell):
    V, F = shell
    ops = bending_operator(V, F, "hessian")
    # the full step's matrix: data weight on part of the vertices, stiffness everywhere
    w = np.where(V[:, 0] < np.median(V[:, 0]), 1.0, 0.0) * ops.area
    A = (sp.diags(w) + 10.0 * ops.Q + 1e-9 * ops.M).tocsc()
    return V, F, ops, A


def test_nested_dissection_is_a_fill_reducing_permutation(shell_system):
    V, F, _, A = shell_system
    p = nested_dissection(V, A)
    assert np.array_equal(np.sort(p), np.arange(len(V)))

    def fill(M, spec):
        lu = spla.splu(M, permc_spec=spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return lu.L.nnz + lu.U.nnz

    natural = fill(A, "NATURAL")  # the mesh's own vertex order
    nd = fill(sp.csc_matrix(A[p][:, p]), "NATURAL")
    mmd = fill(A, "MMD_AT_PLUS_A")
    # a dissection that ignored the stencil (separators one ring wide on a 2-ring operator)
    # or a wrong permutation fills several times more than minimum degree
    assert nd < 1.5 * mmd, (nd, mmd)
    assert nd < 0.5 * natural, (nd, natural)
    # the mesh graph is the vertex 1-ring: a subgraph of the Hessian energy's 2-ring pattern
    G = adjacency(F, len(V))
    assert G.nnz < A.nnz and (G != G.T).nnz == 0


def test_superlu_orders_and_cholmod_solve_alike(shell_system):
    V, _, _, A = shell_system
    b = np.random.default_rng(0).normal(size=(len(V), 3))
    xs = {
        "superlu-mmd": SPDSolver("superlu").factor(A)(b),
        "superlu-nd": SPDSolver("superlu", points=V).factor(A)(b),
        # a given order (NICP's block order is one): here the reverse vertex order
        "superlu-given": SPDSolver("superlu", order=np.arange(len(V))[::-1]).factor(A)(b),
    }
    if have_cholmod():
        xs["cholmod"] = SPDSolver("cholmod").factor(A)(b)
    for name, x in xs.items():
        r = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
        assert r < 1e-9, (name, r)
        rel = np.abs(x - xs["superlu-mmd"]).max() / np.abs(x).max()
        assert rel < 1e-8, (name, rel)
    # one vector as well as a block
    x1 = SPDSolver("superlu", points=V).factor(A)(b[:, 0])
    np.testing.assert_allclose(x1, xs["superlu-nd"][:, 0], rtol=0, atol=1e-10 * np.abs(x1).max())
    with pytest.raises(ValueError, match="points"):
        SPDSolver("superlu", points=V[:-1]).factor(A)
    with pytest.raises(ValueError, match="order"):
        SPDSolver("superlu", order=np.arange(len(V) - 1)).factor(A)
    _need_cholmod()


@pytest.mark.parametrize("backend", ["cholmod", "superlu"])
def test_a_solver_given_an_earlier_ones_order_factorises_exactly_as_it(shell_system, backend):
    """The order a solver found (CHOLMOD's analysis, SuperLU's nested dissection) given to
    another of the same pattern: its factors are the first one's, every solution bit for bit
    (so a part's warm inspections equal its cold one), for one matrix and the next of the
    sequence; a wrong order (the reverse) solves as well but not bit for bit."""
    if backend == "cholmod":
        _need_cholmod()
    V, _, ops, A = shell_system
    A2 = (sp.diags(ops.area) + 0.1 * ops.Q + 1e-9 * ops.M).tocsc()  # the same pattern
    b = np.random.default_rng(1).normal(size=(len(V), 10))
    first = SPDSolver(backend, points=V)
    assert first.order is None  # nothing analysed yet
    x = [first.factor(M)(b) for M in (A, A2)]
    order = first.order
    assert np.array_equal(np.sort(order), np.arange(len(V)))
    if backend == "cholmod":
        assert not np.array_equal(order, np.arange(len(V)))  # a fill-reducing one
    again = SPDSolver(backend, points=V, order=order)
    y = [again.factor(M)(b) for M in (A, A2)]
    assert np.array_equal(again.order, order)
    assert all(np.array_equal(u, v) for u, v in zip(x, y, strict=True))
    assert np.array_equal(again.factor(A)(b[:, 0]), first.factor(A)(b[:, 0]))  # one vector
    other = SPDSolver(backend, order=order[::-1].copy()).factor(A)(b)
    assert np.abs(other - x[0]).max() < 1e-8 * np.abs(x[0]).max()
    with pytest.raises(ValueError, match="order"):
        SPDSolver(backend, order=np.arange(len(V) - 1)).factor(A)  # another system's


def test_cholmod_orders_a_meshs_system_by_metis(shell_system):
    """Given the unknowns' positions (a mesh's system), CHOLMOD's analysis takes METIS's
    nested dissection, which fills less than its default choice on a bending system; without
    them, its default. Measured on the fandisk: 3.53M against 4.65M nonzeros in ``L``."""
    _need_cholmod()
    from sksparse.cholmod import analyze

    V, _, _, A = shell_system
    mesh = SPDSolver("cholmod", points=V)
    mesh.factor(A)
    plain = SPDSolver("cholmod")
    plain.factor(A)
    metis = analyze(A, ordering_method="metis")
    default = analyze(A)
    assert np.array_equal(mesh.order, metis.P())
    assert np.array_equal(plain.order, default.P())
    assert not np.array_equal(mesh.order, plain.order)
    fill = {k: f.cholesky(A).L().nnz for k, f in (("metis", metis), ("default", default))}
    assert fill["metis"] < 0.95 * fill["default"], fill


def test_the_bending_basis_keeps_its_order_for_the_parts_later_solvers(shell):
    """The basis records the fill-reducing order of its factorisation and the backend; the
    part's solver (:func:`part_solver`) takes it with the same backend, and not with the
    other one, nor for another mesh."""
    from qifreport.registration.deformable.bending_basis import part_solver

    V, F = shell
    ops = bending_operator(V, F, "hessian")
    solver = SPDSolver(points=V)
    basis = bending_basis(ops, 20, solver=solver)
    assert basis.order_backend == solver.backend
    assert np.array_equal(basis.order, solver.order)
    assert np.array_equal(part_solver(V, basis).order, basis.order)  # before any factor
    assert part_solver(V, None).order is None
    other = "superlu" if solver.backend == "cholmod" else "cholmod"
    foreign = type(basis)(**{**vars(basis), "order_backend": other})
    assert part_solver(V, foreign).order is None
    assert part_solver(V[:-1], basis).order is None


def test_backend_choice_follows_the_environment(monkeypatch):
    monkeypatch.setenv(BACKEND_ENV, "superlu")
    assert default_backend() == "superlu" and SPDSolver().backend == "superlu"
    monkeypatch.setenv(BACKEND_ENV, "umfpack")
    with pytest.raises(ValueError, match=BACKEND_ENV):
        default_backend()
    monkeypatch.delenv(BACKEND_ENV)
    assert default_backend() == ("cholmod" if have_cholmod() else "superlu")


def test_gbcicp_fits_alike_on_both_backends(shell_case_defect):
    """The whole fit (modal passes, full-resolution polish, flags, hold-outs) on each backend:
    the same flags and refits, vertex positions equal to far below the scanner. (The basis
    is one: its shifted factorisation is the solve checked above.)"""
    _need_cholmod()
    c = shell_case_defect
    ops = bending_operator(c.V, c.F, "hessian")
    Pm = rigid_icp(c.V, ops.normals, c.P).apply(c.P)
    B = bending_basis(ops, 100, solver=SPDSolver("superlu", points=c.V))
    fits = {}
    for backend in ("superlu", "cholmod"):
        fits[backend] = gbcicp(c.V, c.F, ops, Pm, solver=SPDSolver(backend, points=c.V), basis=B)
    a, b = fits["superlu"], fits["cholmod"]
    assert a.passes == b.passes >= 2  # the bump is flagged and refit
    assert a.flagged.sum() > 0 and np.array_equal(a.flagged, b.flagged)
    assert np.array_equal(a.held_out, b.held_out)
    assert np.abs(a.V - b.V).max() < 1e-6  # mm
