"""Perfect scans of the NIST AP242 parts for the tests (issue 20, item 6).

:class:`Scan` samples a part's exact B-rep (:func:`qifreport.simulate.brep_scan.perfect_scan`:
four planned views, 10 um noise) and runs the real CLI on it; :func:`scans` is the module
fixture that builds each part's scan once per test module.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qifreport.metrology.inspection import FREE_STATE_CONFORMS, FREE_STATE_UNCERTAIN
from tests.conftest import NIST, shared_file

EXE = Path(sys.executable).with_name("qifreport")
NOISE = 0.01  # mm
#: about 0.7-1 mm point spacing on these parts (a structured-light scan, thinned); CTC 03's
#: 1.9 mm walls need about 0.5 mm (400,000 points), or the scan normals mix the two skins
POINTS = 150_000


class Scan:
    """A part's perfect scan, its truth (face, normal per point) and its fine B-rep mesh."""

    def __init__(self, step: Path, tmp: Path):
        from qifreport.simulate.brep_scan import technician_scan
        from qifreport.step.reader import read_step
        from qifreport.step.tessellate import shape_diagonal

        self.step = step
        self.part = read_step(step)
        self.diag = float(shape_diagonal(self.part.shape))
        # the views aimed at the toleranced surfaces first, as a technician would
        self.scan, self.mesh = technician_scan(self.part, noise=NOISE, points=POINTS)
        self.tmp = tmp
        self.path = tmp / f"{step.stem}.npy"
        np.save(self.path, self.scan.P)
        self._done: dict[str, dict] = {}

    def run(
        self, points: np.ndarray | None = None, tag: str = "perfect", *extra, pdf: bool = False
    ) -> dict:
        """The CLI's JSON summary (plus its exit code as ``_rc``) on the perfect scan, or on
        ``points`` (a run per ``tag``, each once; ``pdf``: its page written too, in
        ``self.tmp / tag``)."""
        if tag in self._done:
            return self._done[tag]
        scan = self.path
        if points is not None:
            scan = self.tmp / f"{self.step.stem}_{tag}.npy"
            np.save(scan, points)
        self._done[tag] = run_cli(self.step, scan, self.tmp / tag, *extra, pdf=pdf)
        return self._done[tag]


def run_cli(step: Path, scan: Path, out: Path, *extra: str, pdf: bool = False) -> dict:
    """The CLI's JSON summary of ``scan`` against ``step`` (written to ``out``, with its
    page when ``pdf``), its exit code as ``_rc`` (0, 1 or 3: anything else fails the
    test)."""
    r = subprocess.run(
        [str(EXE), str(step), str(scan), "--json", "--force"]
        + ([] if pdf else ["--no-pdf"])
        + ["--out", str(out), *extra],
        capture_output=True,
        text=True,
    )
    assert r.returncode in (0, 1, 3), r.stderr[-2000:]
    doc = json.loads((out / f"{step.stem}.json").read_text())
    doc["_rc"] = r.returncode
    return doc


def scans_fixture(tmp_path_factory):
    """name -> :class:`Scan`, each built once."""
    cache: dict[str, Scan] = {}

    def get(name: str) -> Scan:
        if name not in cache:
            step = shared_file(f"step/nist/{name}")
            cache[name] = Scan(step, tmp_path_factory.mktemp(name.split("_asme")[0]))
        return cache[name]

    return get


def pmi_zones(doc: dict) -> list[dict]:
    return [z for z in doc["tolerances"] if z["source"] == "pmi"]


def assert_conforms(doc: dict) -> None:
    """The judgement of a perfect scan: nothing fails, judged in the free state (only, when
    the drawing states no restraint; first, and it conforms or lies on a zone limit within
    the uncertainty, when it does: no virtual fixture applied to these stiff, machined
    parts), the rigid fit is tight, and every PMI-toleranced surface measured
    PASSes or, on its zone limit, is not established."""
    fails = [z["description"] for z in doc["tolerances"] if z["verdict"] == "FAIL"]
    assert not fails, f"perfect scan fails {fails}"
    assert doc["verdict"] != "FAIL" and doc["_rc"] != 1, doc["decided_by"]
    reg = doc["registration"]
    held = doc["restraint"]
    # no restraint note (all but FTC 08): judged in the free state only, as the drawing
    # states; FTC 08's note states a restraint: the free state first, which conforms (a
    # face on its zone limit stands within the uncertainty)
    free_only = held["condition"] == "free"
    assert free_only == (held["stated_by"] == "drawing"), held
    assert not held["applied"] and held["free_state"]["verdict"] == doc["verdict"], held
    if free_only:
        assert reg["fixture"]["decision"] == "rigid only", reg
    else:
        assert reg["fixture"]["decision"] in (FREE_STATE_CONFORMS, FREE_STATE_UNCERTAIN), reg
    # nor a feature characteristic (issue 22): a perfect part is within every limit, or on
    # one (a hole modelled at its size limit, CTC 01's 35 +0/-0.2 at 35) within the
    # uncertainty
    bad = [
        (c["key"], c["value"], c["reason"]) for c in doc["characteristics"] if c["status"] == "FAIL"
    ]
    assert not bad, f"perfect scan fails characteristics {bad}"
    on_limit = any(z["acceptance"]["decision"] == "UNCERTAIN" for z in doc["tolerances"]) or any(
        c["status"] == "INDETERMINATE" for c in doc["characteristics"]
    )
    if not free_only:
        assert (reg["fixture"]["decision"] == FREE_STATE_UNCERTAIN) == on_limit
    assert reg["fit"] is None
    assert reg["rigid"]["residual_scale_mm"] <= 2.0 * NOISE, reg["rigid"]
    measured = [z for z in pmi_zones(doc) if z["verdict"] != "NOT MEASURED"]
    assert all(z["verdict"] in ("PASS", "NOT ESTABLISHED") for z in measured)
    # a zone is measured, or the scan is too sparse for its region criterion (issue 47: a
    # minimum density per tolerance, 9 points per criterion area), said with the numbers
    for z in pmi_zones(doc):
        if z["verdict"] == "NOT MEASURED" and too_sparse(z):
            m = z["measured"]
            assert m["points_per_mm2"] < m["min_points_per_mm2"], (z["description"], m)
    if pmi_zones(doc):
        assert measured or all(map(too_sparse, pmi_zones(doc))), "no surface measured"


def too_sparse(z: dict) -> bool:
    """The zone is not measured because the scan is too sparse for it."""
    return any("scan too sparse" in r for r in z["measured"]["reasons"])


def assert_not_measured_only_where_unseen(doc: dict, P: np.ndarray, face: np.ndarray) -> None:
    """A perfect scan's surface is NOT MEASURED only where the scan has a hole: each toleranced
    surface not measured has an unmeasured patch larger than allowed whose centroid lies
    more than three point spacings from every scan point of the surface's own faces (``face``:
    the true B-rep face of each point; the other skin of a thin wall may be nearer: an
    occlusion of the planned views) or where they are too sparse to measure (a grazing
    view: FTC 06's T4 has 3-8 points within 3 mm of its patch's vertices, not the ~70 of
    the scan's spacing), and is not measured for no other reason."""
    from scipy.spatial import cKDTree

    spacing = float(np.median(cKDTree(P).query(P, k=2)[0][:, 1]))
    for z in pmi_zones(doc):
        if z["verdict"] != "NOT MEASURED" or too_sparse(z):
            continue
        m = z["measured"]
        assert m["coverage"] >= m["min_coverage"], (z["description"], m["reasons"])
        assert m["largest_gap_area_mm2"] > m["max_gap_area_mm2"], (z["description"], m)
        own = P if z["faces"] is None else P[np.isin(face, z["faces"])]
        tree = cKDTree(own)
        centre = m["largest_gap_centroid_mm"]
        far = float(tree.query(centre)[0])
        # or seen too sparsely to measure (a grazing view): under a quarter of the points a
        # 3 mm disk holds at the scan's median spacing
        near = len(tree.query_ball_point(centre, 3.0))
        sparse = near < 0.25 * np.pi * 9.0 / spacing**2
        assert far > 3.0 * spacing or sparse, (
            f"{z['description']}: NOT MEASURED on a patch whose centre has a scan point "
            f"{far:.2f} mm away and {near} within 3 mm (spacing {spacing:.2f} mm): "
            f"{m['reasons']}"
        )


#: parts whose perfect scan is not yet judged right (issue 20 stays open on them), each
#: with what was measured (bench/nist_perfect_scan.py); strict: a fix makes the test fail
#: until its mark is removed
STILL_WRONG: dict[str, str] = {}

#: parts whose bump test does not pass yet, with what was measured (strict xfail; run with
#: ``QIFREPORT_ALL_NIST_BUMPS=1``): CTC 04's bump FAILs T2 (+/-0.1 mm) on the vertices too,
#: so the free state does not stand and GB-CICP, applied to this stiff solid, absorbs part of
#: the bump and distorts the rest, its nearest region 4.2 mm from the bump; the restrained,
#: physical fixture of issue 21 is the answer
BUMP_STILL_WRONG = {
    "nist_ctc_04_asme1_ap242-e1.stp": "the bump FAILs T2 on the vertices too; GB-CICP, "
    "applied to this stiff solid, distorts it: nearest region 4.2 mm from the bump",
}

#: the parts whose 150,000-point scan runs in the suite only with
#: ``QIFREPORT_ALL_NIST_SCANS=1``: their zones are too sparse at that density (CTC 02, CTC 04:
#: CTC 01 stands for the case) or FTC 08, whose exact scan at 2 points/mm^2 the suite runs
#: (tests/test_nist_exact_scan.py); ``python bench/nist_exact_scan.py`` sweeps them all
OPT_IN = ("nist_ctc_02", "nist_ctc_04", "nist_ftc_08")
_ALL = bool(os.environ.get("QIFREPORT_ALL_NIST_SCANS"))

#: the parts of each test module (two modules: they run on both workers); FTC 06 is with its
#: bump and pose tests (one scan, one prepared part)
GROUPS = {
    group: [n for n in NIST if n.startswith(parts) and (_ALL or not n.startswith(OPT_IN))]
    for group, parts in (
        ("a", ("nist_ctc_01", "nist_ctc_02", "nist_ctc_03", "nist_ctc_04")),
        ("b", ("nist_ctc_05", "nist_ftc_06", "nist_ftc_08")),
    )
}


def _params(names: list[str], still_wrong: dict[str, str]) -> list:
    """``names`` as pytest params, the ``still_wrong`` ones strict xfail with their reason."""
    out = []
    for name in names:
        marks = []
        if name in still_wrong:
            marks.append(pytest.mark.xfail(reason=still_wrong[name], strict=True))
        out.append(pytest.param(name, marks=marks, id=name.split("_asme")[0]))
    return out


def cases(group: str) -> list:
    """The group's parts as pytest params, the :data:`STILL_WRONG` ones strict xfail."""
    return _params(GROUPS[group], STILL_WRONG)


#: the parts of each module whose bump test runs: in the suite (its 15-minute budget) CTC 03
#: (CTC 01's 150,000-point scan is too sparse for its zones' region criterion: not measured),
#: and FTC 06 (in its own module), whose bump the
#: vertices see and the fixtured judgement keeps; with ``QIFREPORT_ALL_NIST_BUMPS=1`` also
#: CTC 01, CTC 02 (measured: FAIL, a region 1.9 mm from the bump) and CTC 04
#: (:data:`BUMP_STILL_WRONG`). CTC 05 and FTC 08 have no well-scanned toleranced face under
#: +/-0.4 mm passing on their perfect scan.
BUMP_GROUPS = {
    "a": GROUPS["a"]
    if os.environ.get("QIFREPORT_ALL_NIST_BUMPS")
    else [n for n in GROUPS["a"] if n.startswith("nist_ctc_03")],
}


def bump_cases(group: str) -> list:
    """The group's bump parts as pytest params, the :data:`BUMP_STILL_WRONG` ones strict
    xfail."""
    return _params(BUMP_GROUPS[group], BUMP_STILL_WRONG)


def bump_target(s: Scan, doc: dict) -> tuple[dict, int, np.ndarray]:
    """(zone, B-rep face, centre) of the bump: the tightest PMI zone passing on the perfect
    scan whose faces carry a well-scanned spot, at the scan point of its face with the most
    points of that face within 1.5 sigma (4.5 mm, where the bump stands 0.16 mm and more),
    at least 40 % of a full disk at the scan's spacing: where the scan saw the face squarely,
    away from its edges (a bump cut by the face's edge, or on a grazing strip of sparse
    points, is not the 0.5 x sigma 3 mm bump the test means; CTC 01's first pick had 2
    points within 3 mm of it and read 0.22 mm)."""
    from scipy.spatial import cKDTree

    zones = sorted(
        (z for z in pmi_zones(doc) if z["verdict"] == "PASS" and z["upper_mm"] < 0.4),
        key=lambda z: z["width_mm"],
    )
    spacing = float(np.median(cKDTree(s.scan.P).query(s.scan.P[::50], k=2)[0][:, 1]))
    full = np.pi * 4.5**2 / spacing**2  # points in a 4.5 mm disk at the scan's spacing
    for z in zones:
        for f in z["faces"]:
            pts = s.scan.P[s.scan.face == f]
            if len(pts) < 10:
                continue
            n = cKDTree(pts).query_ball_point(pts, 4.5, return_length=True)
            if n.max() >= 0.4 * full:
                return z, f, pts[int(np.argmax(n))]
    raise AssertionError("no well-scanned toleranced face to bump")


def check_bump(scans, name: str) -> dict:
    """A 0.5 mm x sigma 3 mm bump on the part's tightest measured toleranced face
    (:func:`bump_target`) FAILs that tolerance, a failing region's centroid within 3 mm of
    the bump, exit 1; returns the run's summary."""
    from qifreport.simulate.brep_scan import bump

    s = scans(name)
    zone, face, centre = bump_target(s, s.run())
    Q = bump(s.scan.P, s.scan.normal, s.scan.face, centre, face, 0.5, 3.0)
    doc = s.run(Q, "bump")
    hit = next(z for z in doc["tolerances"] if z["key"] == zone["key"])
    assert hit["verdict"] == "FAIL", hit["description"]
    at = [np.array(r["centroid"]) for r in hit["acceptance"]["regions"]]
    assert at and min(np.linalg.norm(c - centre) for c in at) <= 3.0
    assert doc["_rc"] == 1
    return doc


def check_perfect_scan(scans, name: str) -> None:
    """Its perfect scan conforms (:func:`assert_conforms`), the measure well inside the
    default +/-0.5 mm band (10 um noise; before the residual-based measure: up to 1.1 mm
    on CTC 01), and it PASSes (exit 0) or is NOT MEASURED (exit 3) only on toleranced
    surfaces with a real hole in the scan (:func:`assert_not_measured_only_where_unseen`)."""
    s = scans(name)
    doc = s.run()
    assert_conforms(doc)
    assert doc["vertex_deviation"]["max_abs"] < 0.2, doc["vertex_deviation"]
    # the scan points' own distances are to the curved surface, not to the chords: no scan
    # region proud of the part (CTC 01 had 25, peak +0.62 mm, measured to the mesh)
    added = doc["added_material"]
    assert added["n_regions"] == 0 and added["max_signed_mm"] < 0.4, added
    assert doc["_rc"] in (0, 3), doc["decided_by"]
    assert (doc["_rc"] == 0) == (doc["verdict"] == "PASS")
    assert_not_measured_only_where_unseen(doc, s.scan.P, s.scan.face)
