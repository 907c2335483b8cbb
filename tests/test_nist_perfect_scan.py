"""A perfect scan of every NIST AP242 part, sampled from its own B-rep (issue 20, item 6).

The scan is independent of the inspection's tessellation: points are evaluated on the exact
B-rep surfaces (:func:`qifreport.simulate.brep_scan.perfect_scan`) from four views planned to
see as much of the part as they can, with 10 um range noise (:mod:`tests.nist_scans`). On
such a scan a machined part conforms by construction, so every PMI-toleranced surface the
scan measured PASSes, nothing FAILs, the fit's robust residual is within 2x the noise, and
GB-CICP's two-pass guard does not fall back. The bump, pose and ``--rigid-only`` checks are in
``test_nist_bump_and_pose.py`` (a file of their own, so the two run on both workers).

Real OCP reading, real gmsh meshing, the real CLI.
"""

from __future__ import annotations

import pytest

from tests.conftest import NIST
from tests.nist_scans import (
    assert_conforms,
    assert_not_measured_only_where_unseen,
    scans_fixture,
)

scans = pytest.fixture(scope="module")(scans_fixture)

#: parts whose perfect scan is not yet judged right (issue 20 stays open on them), each
#: with what was measured (bench/nist_perfect_scan.py); strict: a fix makes the test fail
#: until its mark is removed
STILL_WRONG = {
    "nist_ctc_02_asme1_ap242-e2.stp": "unilateral zones [-2.5, 0] and [0, +2.5] put the "
    "nominal on a zone limit: the free state fails them, then GB-CICP moves the nominal by "
    "up to 2 mm and falls back",
    "nist_ctc_03_asme1_ap242-e2.stp": "its 1.9 mm walls at ~0.9 mm point spacing: the PCA "
    "normals mix the two skins (range noise read as 0.9 mm), the free state is not "
    "established, GB-CICP then fails it (conforms at 400k points)",
}

#: parts whose perfect scan conforms but is not judged measured where it was seen (CTC 04's
#: free disk on the solid, pmi #18835, was until supplemental faces left the mesh)
NOT_MEASURED_WRONGLY: dict[str, str] = {}


def _cases(wrong: dict):
    for name in NIST:
        marks = []
        if name in STILL_WRONG or name in wrong:
            reason = STILL_WRONG.get(name) or wrong[name]
            marks.append(pytest.mark.xfail(reason=reason, strict=True))
        yield pytest.param(name, marks=marks, id=name.split("_asme")[0])


@pytest.mark.parametrize("name", list(_cases({})))
def test_perfect_scan_conforms(scans, name):
    doc = scans(name).run()
    assert_conforms(doc)
    # the measure itself: the whole scored surface well inside the default +/-0.5 mm band
    # (10 um noise; before the residual-based measure: up to 1.1 mm on CTC 01)
    assert doc["vertex_deviation"]["max_abs"] < 0.2, doc["vertex_deviation"]


@pytest.mark.parametrize("name", list(_cases(NOT_MEASURED_WRONGLY)))
def test_perfect_scan_passes_where_it_was_seen(scans, name):
    """Exit 0, or NOT MEASURED (exit 3) only on toleranced surfaces with a real hole in the
    scan (the four views' occlusions): never on a surface the scan did see."""
    s = scans(name)
    doc = s.run()
    assert doc["_rc"] in (0, 3), doc["decided_by"]
    assert (doc["_rc"] == 0) == (doc["verdict"] == "PASS")
    assert_not_measured_only_where_unseen(doc, s.scan.P)
