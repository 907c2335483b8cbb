"""A clamp's reading carries its uncertainty into the held verdict.

A restrained hold reads each clamp's free-state offset as the median of the scan points
under its pad. On the sample panel's scan thinned to every 40th point, three pads are read
from 8-9 points of both skins of the 1.8 mm wall (their readings spread over the wall: an
interquartile range of 1.8 mm), and A3 reads -0.41 mm where the full scan reads +0.51. Held
at that reading, the conforming panel once FAILed with a 2,092 mm^2 region. The median's
uncertainty from its readings' own spread now enters every held deviation's uncertainty
through the part's elastic response, so the sparse scan cannot FAIL (nor PASS) the panel.

The real sample STEP read by OCP, the real command line.
"""

from __future__ import annotations

import numpy as np
import trimesh

from qifreport.metrology.restraint.held import HeldScan, hold_too_far, median_uncertainty
from tests.conftest import ROOT
from tests.nist_scans import run_cli

PANEL = ROOT / "samples" / "panel.step"


def test_a_median_read_from_both_skins_is_known_to_the_wall_not_the_noise():
    rng = np.random.default_rng(3)
    dense = rng.normal(0.5, 0.04, 150)  # a pad's readings at full density
    assert median_uncertainty(dense) < 0.02
    both = np.r_[rng.normal(0.5, 0.04, 4), rng.normal(-1.3, 0.04, 4)]  # 1.8 mm apart
    assert median_uncertainty(both) > 0.9
    assert median_uncertainty(np.array([0.5, 0.51])) == 0.0  # not read from two points
    # three readings: Student's t for two degrees of freedom (4.30), not 2
    three = np.array([0.0, 0.1, 0.2])
    sigma = 0.1 / 1.349
    assert abs(median_uncertainty(three) - 4.303 * 1.2533 * sigma / np.sqrt(3)) < 1e-3


def test_a_sparse_scan_does_not_fail_the_conforming_panel_on_its_clamp_readings(tmp_path):
    P = np.asarray(trimesh.load(ROOT / "samples" / "panel_scan.ply").vertices)
    np.save(tmp_path / "sparse.npy", P[::40])
    doc = run_cli(PANEL, tmp_path / "sparse.npy", tmp_path / "out")
    assert doc["_rc"] != 1 and doc["verdict"] != "FAIL"
    clamps = {c["name"]: c for c in doc["registration"]["restraint"]["clamps"]}
    # A3 and A4 read from both skins: their medians known to about a millimetre
    assert clamps["A3"]["free_state_offset_U_mm"] > 0.8
    assert clamps["A4"]["free_state_offset_U_mm"] > 0.8
    # a clamp not read from its pad carries no reading uncertainty
    assert clamps["A2"]["offset_source"] != "scan"
    assert clamps["A2"]["free_state_offset_U_mm"] == 0.0
    # held as the drawing states, the free state decides nothing and is not judged unless
    # asked for (--judge-free-state), and the outputs say so
    assert doc["restraint"]["free_state"] is None
    assert "free state not judged" in doc["restraint"]["judged"]


def test_a_hold_that_moves_the_scan_off_the_part_is_an_input_error_not_a_verdict():
    rng = np.random.default_rng(0)
    P = rng.uniform(-50, 50, size=(500, 3))

    def held(shift: float) -> HeldScan:
        return HeldScan(
            P_free=P,
            P=P + [0.0, 0.0, shift],
            normals=np.zeros_like(P),
            sheets=np.zeros(len(P), dtype=int),
            restraint=None,
            u_vertex=np.zeros(1),
            u_point=np.zeros(len(P)),
        )

    diagonal = 173.2
    assert hold_too_far(held(2.0), diagonal) is None  # a hold's ordinary correction
    why = hold_too_far(held(40.0), diagonal)
    assert why is not None and "nowhere near the part" in why and "40.0 mm" in why
    assert "no finite displacement" in hold_too_far(held(np.nan), diagonal)
