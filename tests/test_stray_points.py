"""Stray points never change a verdict up to the outlier model's limit; above it the verdict
is NOT ESTABLISHED with the share named.

The stray points are what a real scan holds besides the part: uniform points in the scan's
box grown 40 % (reflections, dust, ghosts). On the sample panel, 0.1 % of them once failed
the conforming part (a flange's flatness read 0.64-3.1 mm against 0.2 on one stray point).
Now the scan's own outlier model (:mod:`qifreport.registration.outliers`) leaves out the
points in no surface patch, and the seated points alone off their neighbourhood's surface
judge nothing (:mod:`qifreport.metrology.acceptance.point_regions`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.registration.outliers import MIN_PATCH_POINTS, STRAY_LIMIT, stray_points
from qifreport.simulate.scanner import with_stray_points
from tests.conftest import ROOT
from tests.nist_scans import run_cli

PANEL = ROOT / "samples" / "panel.step"


def test_the_model_leaves_out_points_in_no_patch_and_keeps_a_small_rib():
    rng = np.random.default_rng(0)
    g = np.arange(0, 60, 0.4)
    X, Y = np.meshgrid(g, g)
    surface = np.c_[X.ravel(), Y.ravel(), rng.normal(0, 0.01, X.size)]
    # a rib: 40 points 6 mm above the sheet, 0.4 mm apart (a patch, not stray)
    rib = np.c_[np.arange(40) * 0.4 + 10, np.full(40, 30.0), np.full(40, 6.0)]
    far = rng.uniform([0, 0, 3], [60, 60, 40], size=(200, 3))  # all >= 3 mm off the sheet
    P = np.vstack([surface, rib, far])
    s = stray_points(P)
    truth = np.r_[np.zeros(len(surface) + len(rib), bool), np.ones(len(far), bool)]
    assert not s.mask[: len(surface)].any()
    assert not s.mask[len(surface) : len(surface) + len(rib)].any()
    assert s.mask[truth].mean() > 0.97
    assert abs(s.spacing - 0.4) < 0.01 and s.min_patch == MIN_PATCH_POINTS
    assert not s.over_limit and s.refusal() is None
    more = rng.uniform([0, 0, 3], [60, 60, 40], size=(int(0.03 * len(surface)), 3))
    many = stray_points(np.vstack([surface, more]))
    assert many.share > STRAY_LIMIT and "stray points" in many.refusal()


@pytest.fixture(scope="module")
def panel_runs(tmp_path_factory):
    """The CLI's JSON summary per (scan, stray share): each run once."""
    tmp = tmp_path_factory.mktemp("stray")
    docs: dict[tuple[str, float], dict] = {}

    def run(scan: str, share: float) -> dict:
        if (scan, share) not in docs:
            P = np.asarray(trimesh.load(ROOT / "samples" / scan).vertices)
            path = tmp / f"{Path(scan).stem}_{share:g}.npy"
            np.save(path, with_stray_points(P, share, seed=1) if share else P)
            docs[scan, share] = run_cli(PANEL, path, tmp / path.stem)
        return docs[scan, share]

    return run


def _flatness(doc: dict) -> dict[str, float]:
    return {c["key"]: c["value"] for c in doc["characteristics"] if c["kind"] == "flatness"}


def test_one_percent_stray_points_leave_the_conforming_panel_as_it_was(panel_runs):
    clean, stray = panel_runs("panel_scan.ply", 0.0), panel_runs("panel_scan.ply", 0.01)
    assert clean["verdict"] == "PASS" and clean["_rc"] == 0
    assert stray["verdict"] == "PASS" and stray["_rc"] == 0, stray["decided_by"]
    # the stray points left out: over half of those added, none of the clean scan's; the
    # rest lie near the sheet, within the surface's links, and judge nothing as spikes
    assert clean["stray_points"]["count"] == 0
    added = round(0.01 * stray["scan_input"]["points_used"] / 1.01)
    assert 0.5 * added < stray["stray_points"]["count"] <= added
    spikes = stray["spike_points"] - clean["spike_points"]
    assert 0.9 * added < stray["stray_points"]["count"] + spikes <= 1.05 * added
    a, b = _flatness(clean), _flatness(stray)
    assert a.keys() == b.keys() and a
    for k in a:  # the flange flatness once read 0.64-3.1 mm on one stray point
        assert abs(a[k] - b[k]) < 0.01, (k, a[k], b[k])
    assert stray["added_material"]["regions"] == clean["added_material"]["regions"] == []


def test_stray_points_do_not_hide_the_defect(panel_runs):
    doc = panel_runs("panel_scan_defect.ply", 0.001)
    assert doc["verdict"] == "FAIL" and doc["_rc"] == 1
    t2 = next(z for z in doc["tolerances"] if z["key"] == "T2")
    assert t2["verdict"] == "FAIL" and t2["acceptance"]["largest_region_area"] > 50


def test_more_stray_points_than_the_model_holds_is_not_established(panel_runs):
    doc = panel_runs("panel_scan_defect.ply", 0.03)
    # even on the defect part: the data cannot decide, and the share is named
    assert doc["verdict"] == "NOT ESTABLISHED" and doc["_rc"] == 3
    assert doc["stray_points"]["share"] > STRAY_LIMIT
    assert "stray points" in doc["decided_by"][0] and "%" in doc["decided_by"][0]
    assert any("stray points" in w for w in doc["warnings"])


def test_themedian_link_of_a_large_surface_is_its_sorted_one():
    """The median link of a component with many links (selected on its own) is the one a
    sort of all links gives, beside small components and none: the upper median."""
    from scipy.sparse import coo_matrix

    from qifreport.registration.outliers import PARTITION_LINKS, median_link

    rng = np.random.default_rng(5)
    label = np.repeat(np.arange(5), [3 * PARTITION_LINKS, 40, 3, PARTITION_LINKS, 7])
    rng.shuffle(label)
    m = len(label)
    rows = rng.integers(0, m, 2 * m)
    data = rng.random(2 * m).round(3)  # ties
    links = coo_matrix((data, (rows, rng.integers(0, m, 2 * m))), shape=(m, m))
    got = median_link(links, label, 6)
    for g in range(6):
        x = np.sort(data[label[rows] == g])
        assert got[g] == (x[len(x) // 2] if len(x) else np.inf)
