"""Added material (paper Section 8.4.5, Table 4): invisible to the nominal-referenced profile,
carried by the upper tail of the data-referenced deviation, reported (and, on request,
failing) as connected proud regions of the scan."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.added import added_material
from qifreport.metrology.inspection import InspectionParams, inspect
from qifreport.registration.mesh import vertex_normals
from qifreport.simulate.cases import make_case
from qifreport.simulate.shapes import thin_shell

FIN_LENGTH, FIN_HEIGHT = 30.0, 4.0  # mm: a rib the nominal does not model


def _with_fin(case, lift: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """The scan plus a rib standing 4 mm proud of the free-state surface near its middle,
    sampled at the scan's own spacing (one sheet of points, 0.02 mm noise); ``lift`` mm
    raises it off the surface (an object in the scan, standing apart from the part)."""
    V, P = case.V_scanned, case.P
    N = vertex_normals(V, case.F)
    c0 = np.median(P, axis=0)
    i = int(cKDTree(V).query(c0)[1])
    c, n = V[i], N[i]
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    h = float(np.median(cKDTree(P).query(P[::50], k=2)[0][:, 1]))  # scan spacing, mm
    s, z = np.meshgrid(np.arange(-FIN_LENGTH / 2, FIN_LENGTH / 2, h), np.arange(0.3, FIN_HEIGHT, h))
    fin = c + s.reshape(-1, 1) * u + (z.reshape(-1, 1) + lift) * n
    fin += 0.02 * np.random.default_rng(1).standard_normal(fin.shape)
    return np.vstack([P, fin]), c + 0.5 * FIN_HEIGHT * n, len(fin) * h * h


@pytest.fixture(scope="module")
def fin_results():
    V, F = thin_shell()
    case = make_case(V, F, generator="analytic", amplitude=0.02, seed=0)
    P_fin, centre, fin_area = _with_fin(case)
    out = {"centre": centre, "fin_area": fin_area}
    for name, P in (("clean", case.P), ("fin", P_fin)):
        out[name] = inspect(V, F, P, InspectionParams(tolerance=0.5))
    out["fin_judged"] = inspect(
        V, F, P_fin, InspectionParams(tolerance=0.5, fail_on_added_material=True)
    )
    out["apart"] = inspect(V, F, _with_fin(case, lift=6.0)[0], InspectionParams(tolerance=0.5))
    return out


def test_added_material_moves_the_tail_not_the_profile(fin_results):
    """Table 4's mechanism: the nominal-referenced RMS barely moves, the data-referenced
    P99.9 and the share beyond +threshold move by large factors, the negative tail does
    not (the control)."""
    clean, fin = fin_results["clean"], fin_results["fin"]
    rms0, rms1 = clean.vertex_stats.rms, fin.vertex_stats.rms
    assert abs(rms1 - rms0) < 0.15 * rms0, (rms0, rms1)
    a0, a1 = clean.added, fin.added
    assert a1.p999_signed > 5 * max(a0.p999_signed, 0.05), (a0.p999_signed, a1.p999_signed)
    assert a1.frac_above > 20 * max(a0.frac_above, 1e-4), (a0.frac_above, a1.frac_above)
    assert a1.frac_below <= 2 * a0.frac_below + 1e-4  # the control does not move
    assert not a0.regions or a0.largest_area < a0.max_region_area


def test_added_material_is_localised_and_reported(fin_results):
    fin = fin_results["fin"]
    top = fin.added.regions[0]
    assert np.linalg.norm(top.centroid - fin_results["centre"]) < 5.0
    # area of the rib above the threshold (its lower 0.5 mm is within the band)
    expect = fin_results["fin_area"] * (FIN_HEIGHT - 0.5) / (FIN_HEIGHT - 0.3)
    assert 0.5 * expect < top.area < 2.0 * expect, (top.area, expect)
    assert 3.0 < top.peak < FIN_HEIGHT + 0.5
    # the rib stands on the surface, continuous with it: the part's own material, judged by
    # the surface it stands on (a proud region there), and reported as added material
    assert fin.added.found and fin.added.passed and fin.verdict == "FAIL"
    proud = [r for r in fin.acceptance.regions if r.sign > 0]
    assert proud and np.linalg.norm(proud[0].centroid - fin_results["centre"]) < 5.0
    judged = fin_results["fin_judged"]
    assert judged.verdict == "FAIL"
    assert any(r.startswith("added material:") for r in judged.decided_by())
    doc = judged.to_dict()
    assert doc["added_material"]["found"] is True and doc["added_material"]["passed"] is False


def test_added_material_regions_are_connected_components():
    """Two proud blobs 20 mm apart on a flat grid are two regions with the right areas."""
    h = 0.5
    x, y = np.meshgrid(np.arange(0, 60, h), np.arange(0, 30, h))
    P = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    dev = np.zeros(len(P))
    blob_a = (np.abs(P[:, 0] - 15) < 3) & (np.abs(P[:, 1] - 15) < 3)  # 11 x 11 points
    blob_b = (np.abs(P[:, 0] - 45) < 2) & (np.abs(P[:, 1] - 15) < 2)  # 7 x 7 points
    dev[blob_a], dev[blob_b] = 1.0, 2.0
    dev[:5] = -3.0  # sunk points are not added material
    a = added_material(P, dev, 0.5, scan_area=60 * 30, max_region_area=25.0)
    assert len(a.regions) == 2
    # 0.25 mm^2 per point: 30.25 and 12.25 mm^2 (local density within 2.5 spacings)
    assert abs(a.regions[0].area - 30.25) < 0.15 * 30.25
    assert abs(a.regions[1].area - 12.25) < 0.15 * 12.25
    assert np.allclose(a.regions[0].centroid, [15.0, 15.0, 0.0], atol=1e-9)
    assert a.regions[1].peak == 2.0 and a.found and a.passed  # not judged unless asked
    assert not added_material(P, dev, 0.5, 1800.0, 25.0, fail_on=True).passed


def test_material_standing_apart_is_reported_not_judged(fin_results):
    """The same rib lifted 6 mm off the surface (an object in the scan that does not touch
    the part): added material, reported; the part's verdict is the clean scan's. Before,
    the 0.3 % of the shell's points that saw the object behind them decided the side of
    the whole scan sheet (inward), no vertex was scored, and the virtual fixture, matching
    nothing, solved a zero system to NaN and crashed."""
    apart, clean = fin_results["apart"], fin_results["clean"]
    assert apart.added.found and apart.added.passed
    assert apart.verdict == clean.verdict, apart.decided_by()
    assert abs(apart.acceptance.coverage - clean.acceptance.coverage) < 0.01
