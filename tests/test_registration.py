"""Rigid ICP and GB-CICP on generated cases with exact ground truth."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qifreport.metrology.inspection import InspectionParams, inspect
from qifreport.registration.deformable.gbcicp import GBCICPParams, gbcicp
from qifreport.registration.icp import kabsch, rigid_icp
from qifreport.registration.mesh import bending_operator, vertex_normals
from qifreport.simulate.cases import inspection_error


def test_kabsch_exact_and_reflection_guard():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3)) * [30, 20, 5]
    R_true = Rotation.from_euler("xyz", [10, -20, 35], degrees=True).as_matrix()
    B = A @ R_true.T + [1.0, -2.0, 3.0]
    R, t = kabsch(A, B)
    assert np.abs(R - R_true).max() < 1e-10
    assert np.abs(t - [1.0, -2.0, 3.0]).max() < 1e-9
    # a mirror image has no proper rotation; the guard must still return det(R) = +1
    mirrored = A * [1, 1, -1]
    R, _ = kabsch(A, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)


def _pose_recovery(V, F, step, max_iter):
    from qifreport.simulate.scanner import ScanSpec, virtual_scan

    scan = virtual_scan(V, F, ScanSpec(views=3, noise=0.02, seed=3))
    R_true = Rotation.from_euler("xyz", [2.0, -1.5, 3.0], degrees=True).as_matrix()
    t_true = np.array([2.0, -1.0, 1.5])
    P = scan.P @ R_true.T + t_true
    rng = np.random.default_rng(0)
    k = len(P) // 10  # 10 % gross outliers
    P = np.vstack([P, P[rng.integers(0, len(P), k)] + rng.normal(0, 5.0, (k, 3))])
    res = rigid_icp(V, vertex_normals(V, F), P, step=step, max_iter=max_iter)
    ang = np.degrees(Rotation.from_matrix(res.R @ R_true).magnitude())  # R_res = R_true^-1
    back = res.apply(scan.P @ R_true.T + t_true)
    return ang, np.abs(back - scan.P).max()


def test_rigid_icp_point_to_plane_recovers_pose_on_smooth_shell(shell):
    ang, err = _pose_recovery(*shell, step="plane", max_iter=60)
    assert ang < 0.02
    assert err < 0.05


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["modal", "full"])
def test_gbcicp_removes_compliance(shell_case, solver):
    """Done-when 1: inspection RMS below 0.1 x the rigid-only RMS on measured vertices, with
    the modal solver (the default) and with the paper's full-resolution schedule."""
    c = shell_case
    ops = bending_operator(c.V, c.F, "hessian")
    rigid = rigid_icp(c.V, ops.normals, c.P)
    Pm = rigid.apply(c.P)
    V_true = c.V_true @ rigid.R.T + rigid.t  # the truth in the nominal frame
    fit = gbcicp(c.V, c.F, ops, Pm, GBCICPParams(solver=solver))
    assert fit.params.solver == solver
    S = c.measured_vertices()
    e_rigid = inspection_error(c.V, V_true, c.F)[S]
    e_fit = inspection_error(fit.V, V_true, c.F)[S]
    rms_rigid = np.sqrt(np.mean(e_rigid**2))
    rms_fit = np.sqrt(np.mean(e_fit**2))
    assert rms_rigid > 0.5  # the compliance is real: ~2 % of the diagonal
    assert rms_fit < 0.1 * rms_rigid, (rms_fit, rms_rigid)
    assert np.percentile(e_fit, 95) < 0.1
    if solver == "modal":  # the modal first pass needs far fewer full-resolution solves
        assert sum(h["pass_no"] == 1 for h in fit.history) <= 25


def test_bending_basis_is_m_orthonormal_and_diagonalises_q(shell):
    """The per-part modes: Phi^T M Phi = I, Phi^T Q Phi = diag(mu), mu ascending from the
    affine null space (0) upwards."""
    from qifreport.registration.deformable.bending_basis import bending_basis

    V, F = shell
    ops = bending_operator(V, F, "hessian")
    B = bending_basis(ops, 30)
    G = B.Phi.T @ (ops.M @ B.Phi)
    np.testing.assert_allclose(G, np.eye(30), atol=1e-8)
    H = B.Phi.T @ (ops.Q @ B.Phi)
    np.testing.assert_allclose(H, np.diag(B.mu), atol=1e-8 * max(B.mu.max(), 1e-300))
    assert np.all(np.diff(B.mu) >= -1e-12)
    # the Hessian energy vanishes on affine fields: 3 null modes on a surface
    assert B.mu[2] < 1e-8 * B.mu[-1] < B.mu[3]


@pytest.mark.slow
def test_conforming_part_passes_and_bump_fails_by_region(shell_case, shell_case_defect):
    """Done-when 2: conforming passes; 1.0 mm / sigma 7 mm bump fails by the region criterion."""
    params = InspectionParams(tolerance=0.5)
    good = inspect(shell_case.V, shell_case.F, shell_case.P, params)
    assert good.passed, good.acceptance.reasons
    assert good.acceptance.largest_region_area == 0.0 or good.acceptance.region_ok

    c = shell_case_defect
    bad = inspect(c.V, c.F, c.P, params)
    acc = bad.acceptance
    assert not bad.passed
    assert acc.area_ok  # a small bump cannot move the area criterion
    assert not acc.region_ok
    top = acc.regions[0]
    centre = c.V[c.defect_vertex]  # region centroids are reported on the nominal (CAD)
    assert np.linalg.norm(top.centroid - centre) < 3.0
    assert 0.6 < top.peak < 1.1  # proud bump, most of its 1.0 mm kept in the residual
