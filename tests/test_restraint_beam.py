"""The restrained hold against a model it does not share: Euler-Bernoulli three-point bending.

A steel strip 300 x 30 x 2 mm (a STEP solid written here), its free state bowed 1 mm at mid
length (``w(x) = sin(pi x / 300)``), held by an N-2-1 clamp set nobody here tuned for it:
four normal supports under its ends (x = 10 and 290 mm), one normal clamp under its middle,
and three in-plane locators. The supports and the middle clamp drive their contacts back
to nominal; the middle's relative drive is ``d = 1 - sin(pi 10 / 300) = 0.8955`` mm, so beam
theory (span 280 mm, ``I = 30 * 2^3 / 12 = 20`` mm^4, ``E`` 210 GPa; slender and narrow: no
shear or anticlastic correction) puts ``48 E I d / L^3 = 8.23`` N on the middle clamp, the
same in sum on the supports, and nothing on the locators.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

from qifreport.step.write import PMISpecTolerance, write_step_with_pmi

EXE = Path(sys.executable).with_name("qifreport")
L, W, H = 300.0, 30.0, 2.0
BOW = 1.0  # mm at mid length
E = 210_000.0  # MPa, the steel preset's
CLAMPS = """name,x,y,z,directions,max_force_N
S1,10,7,0,n,100
S2,10,23,0,n,100
S3,290,7,0,n,100
S4,290,23,0,n,100
M,150,15,0,n,100
B1,0,15,1,x,
C1,50,0,1,y,
C2,250,0,1,y,
"""


@pytest.fixture(scope="module")
def held(tmp_path_factory) -> dict:
    """The bowed strip inspected held at its clamps: the JSON summary."""
    d = tmp_path_factory.mktemp("beam")
    shape = BRepPrimAPI_MakeBox(L, W, H).Shape()
    general = PMISpecTolerance("surface_profile", 1.0, [], name="ALL")
    write_step_with_pmi(shape, d / "strip.step", [general], [], "strip", timestamp="")
    (d / "clamps.csv").write_text(CLAMPS)
    box = trimesh.creation.box(extents=(L, W, H))
    box.apply_translation((L / 2, W / 2, H / 2))
    P, _ = trimesh.sample.sample_surface_even(box, 60000, seed=2)
    P[:, 2] += BOW * np.sin(np.pi * P[:, 0] / L)
    P += np.random.default_rng(1).normal(0.0, 0.005, P.shape)
    trimesh.PointCloud(P).export(d / "bowed.ply")
    r = subprocess.run(
        [str(EXE), str(d / "strip.step"), str(d / "bowed.ply"), "--out", str(d / "o")]
        + ["--json", "--no-pdf", "--no-qif", "--restraint", "clamps", "--judge-free-state"]
        + ["--clamps", str(d / "clamps.csv"), "--material", "steel"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads((d / "o" / "strip.json").read_text())


def test_the_clamp_forces_are_beam_theory_s(held):
    span, inertia = 280.0, W * H**3 / 12.0
    drive = BOW * (1.0 - math.sin(math.pi * 10.0 / L))
    expected = 48.0 * E * inertia * drive / span**3
    assert expected == pytest.approx(8.23, abs=0.01)
    force = {c["name"]: c["force_N"] for c in held["registration"]["restraint"]["clamps"]}
    assert force["M"] == pytest.approx(expected, rel=0.10), force
    supports = sum(force[s] for s in ("S1", "S2", "S3", "S4"))
    assert supports == pytest.approx(force["M"], rel=0.02), force  # equilibrium
    assert max(force[s] for s in ("B1", "C1", "C2")) < 1e-3 * expected, force


def test_held_it_conforms_and_free_it_does_not(held):
    assert held["verdict"] == "PASS"
    assert held["restraint"]["free_state"]["verdict"] == "FAIL"
    assert held["vertex_deviation"]["max_abs"] < 0.1
