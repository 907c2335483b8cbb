"""Decision rules with the measurement uncertainty (ISO 14253-1; ASME B89.7.3.1):
:mod:`qifreport.metrology.acceptance.decision`,
:func:`qifreport.metrology.acceptance.criteria.evaluate` with an
uncertainty, and the variance of each vertex's measured deviation
(:func:`qifreport.metrology.deviation.local_planes.nominal_referenced`,
:func:`~qifreport.metrology.deviation.residual_fit.residual_referenced`).

A surface on a zone limit (NIST CTC 02's zones ``2.5 UZ 0`` put a perfect face on it) is the
case: simple acceptance fails it on noise, ISO 14253-1 proves neither; a defect beyond the
limit fails under every rule; a surface well inside passes under every rule.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.acceptance.criteria import evaluate
from qifreport.metrology.acceptance.decision import DECISION_RULES, decide, vertex_uncertainty
from qifreport.metrology.deviation.local_planes import nominal_referenced
from qifreport.metrology.deviation.residual_fit import residual_referenced
from tests.test_metrology import grid_mesh

SIGMA = 0.003  # mm, each vertex's deviation standard uncertainty in the synthetic fields


def field(kind: str, seed: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 60 x 60 mm plate on a 1 mm grid, its unilateral zone [0, +0.5] (centre 0.25,
    half-width 0.25) and a measured deviation: ``on-limit`` (a perfect face on the limit,
    noise only), ``inside`` (at the zone's centre), ``defect`` (at the centre with a 0.3 mm
    deep, 8 mm wide sink: out of the zone by 0.05 mm, 8 x its uncertainty)."""
    V, F = grid_mesh(61, 61, 1.0)
    rng = np.random.default_rng(seed)
    dev = rng.normal(0.0, SIGMA, len(V))
    if kind in ("inside", "defect"):
        dev += 0.25
    if kind == "defect":
        r2 = ((V[:, :2] - 30.0) ** 2).sum(axis=1)
        dev -= 0.3 * (r2 <= 4.0**2)
    return V, F, dev


def judged(kind: str, rule: str):
    V, F, dev = field(kind)
    return evaluate(V, F, dev, 0.25, center=0.25, uncertainty=2.0 * SIGMA, decision_rule=rule)


@pytest.mark.parametrize("rule", DECISION_RULES)
def test_inside_passes_and_a_defect_fails_under_every_rule(rule):
    assert judged("inside", rule).decision == "PASS"
    acc = judged("defect", rule)
    assert acc.decision == "FAIL" and acc.proven_out
    assert acc.regions[0].area == pytest.approx(49.0, abs=8.0)  # the 8 mm disk, 1 mm grid


def test_a_surface_on_its_limit():
    """Half the points of a perfect face on the limit read outside: simple acceptance FAILs
    it (on noise), ISO 14253-1 proves neither (NOT ESTABLISHED), guarded rejection accepts
    and guarded acceptance rejects; with the noise at 3 um and U = 6 um."""
    simple = judged("on-limit", "simple")
    assert not simple.passed and 0.4 < simple.in_tolerance_fraction < 0.6
    assert simple.decision == "FAIL"
    iso = judged("on-limit", "iso14253")
    assert iso.proven_in is False and iso.proven_out is False
    assert iso.decision == "UNCERTAIN" and iso.uncertain_reasons
    assert "uncertainty" in iso.uncertain_reasons[0]
    assert judged("on-limit", "guarded-rejection").decision == "PASS"
    assert judged("on-limit", "guarded-acceptance").decision == "FAIL"
    d = iso.to_dict()
    assert d["decision"] == "UNCERTAIN" and d["uncertainty_median_mm"] == pytest.approx(0.006)


def test_no_uncertainty_is_the_simple_decision():
    V, F, dev = field("on-limit")
    acc = evaluate(V, F, dev, 0.25, center=0.25, decision_rule="iso14253")
    assert acc.decision_rule == "simple" and acc.decision == "FAIL"


def test_decide_table():
    assert decide("iso14253", False, True, False) == "PASS"
    assert decide("iso14253", True, False, True) == "FAIL"
    assert decide("iso14253", True, False, False) == "UNCERTAIN"
    with pytest.raises(ValueError):
        decide("lenient", True, True, False)
    U = vertex_uncertainty(np.array([1e-6, np.nan]), systematic=0.003)
    assert U[0] == pytest.approx(np.hypot(0.002, 0.003)) and np.isnan(U[1])


def scanned_plate(noise: float, seed: int = 2):
    """A 40 x 40 mm plate on a 2 mm grid and a scan of it: uniform random points at about
    0.5 mm spacing, Gaussian noise ``noise`` mm along the normal."""
    V, F = grid_mesh(21, 21, 2.0)
    rng = np.random.default_rng(seed)
    m = 6400
    P = np.column_stack([rng.uniform(0, 40, m), rng.uniform(0, 40, m), rng.normal(0, noise, m)])
    return V, F, P


@pytest.mark.parametrize("measure", ["plane", "residual"])
def test_vertex_variance_predicts_the_scatter(measure):
    """The deviation's variance from the local fit predicts its actual scatter: on a flat
    plate under 20 um noise the standardised deviations ``dev / sqrt(var)`` have a spread
    of 1 within 25 % (a variance without the 1/N of the fit would give about 0.2, one
    without the points' scatter would be off by the noise itself)."""
    noise = 0.02
    V, F, P = scanned_plate(noise)
    N = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    if measure == "plane":
        dev, var = nominal_referenced(V, F, P, normals=N, variance=True)
    else:
        dev, var = residual_referenced(
            V, F, P, P[:, 2], N, np.zeros(len(P), int), np.zeros(len(F), int), variance=True
        )
    ok = np.isfinite(dev)
    assert ok.mean() > 0.9
    z = dev[ok] / np.sqrt(var[ok])
    assert 0.75 < float(np.std(z)) < 1.25, float(np.std(z))
    # about N = 30 points per vertex: the deviation is ~sqrt(30) times steadier than a point
    assert 2.0 < noise / float(np.sqrt(np.median(var[ok]))) < 12.0


def test_options_refuse_an_unknown_rule_and_a_negative_scanner_uncertainty():
    from qifreport.errors import InputError
    from qifreport.options import InspectOptions

    InspectOptions(decision_rule="guarded-rejection", scanner_uncertainty=0.01).check()
    with pytest.raises(InputError, match="--decision-rule"):
        InspectOptions(decision_rule="lenient").check()
    with pytest.raises(InputError, match="--scanner-uncertainty"):
        InspectOptions(scanner_uncertainty=-0.01).check()
    p = InspectOptions(decision_rule="simple", scanner_uncertainty=0.02).inspection_params()
    assert p.decision_rule == "simple" and p.scanner_uncertainty == 0.02


def test_cli_on_a_zone_limit_is_not_established_and_says_why(tmp_path):
    """End to end, free state (``--rigid-only``): a 120 mm plate whose middle (a 40 mm disk,
    ramped to nothing at 60 mm) stands exactly 0.5 mm proud, judged with +/-0.5 mm: the
    disk is on the limit. ISO 14253-1: NOT ESTABLISHED (exit 3) and every output says so
    and validates; ``simple`` FAILs it (exit 1), ``guarded-rejection`` accepts it (exit 0),
    ``guarded-acceptance`` rejects it (exit 1)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    import trimesh
    from lxml import etree

    from tests.conftest import assert_valid_summary

    V, F = grid_mesh(121, 121, 1.0)
    trimesh.Trimesh(V, F, process=False).export(tmp_path / "plate.ply")
    rng = np.random.default_rng(0)
    xy = rng.uniform(0.0, 120.0, (60_000, 2))
    r = np.linalg.norm(xy - 60.0, axis=1)
    z = 0.5 * np.clip((30.0 - r) / 10.0, 0.0, 1.0) + rng.normal(0.0, 0.005, len(xy))
    np.save(tmp_path / "scan.npy", np.column_stack([xy, z]))
    exe = Path(sys.executable).parent / "qifreport"

    def run(rule: str) -> tuple[int, dict, Path]:
        out = tmp_path / rule
        r = subprocess.run(
            [str(exe), tmp_path / "plate.ply", tmp_path / "scan.npy", "--tolerance", "0.5"]
            + ["--decision-rule", rule, "--rigid-only", "--json", "--force", "--out", out]
            + (["--no-pdf"] if rule != "iso14253" else []),
            capture_output=True,
            text=True,
        )
        assert r.returncode in (0, 1, 3), r.stderr[-2000:]
        return r.returncode, json.loads((out / "plate.json").read_text()), out

    rc, doc, out = run("iso14253")
    assert_valid_summary(doc)
    assert rc == 3 and doc["verdict"] == "NOT ESTABLISHED", doc["decided_by"]
    acc = doc["acceptance"]
    assert acc["decision"] == "UNCERTAIN" and not acc["proven_in"] and not acc["proven_out"]
    assert 0.0 < acc["uncertainty_median_mm"] < 0.01
    assert any("uncertainty of the zone limit" in s for s in doc["decided_by"])
    qif = etree.parse(str(out / "plate.qif"))
    ns = {"q": "http://qifstandards.org/xsd/qif3"}
    status = qif.xpath("//q:CharacteristicStatusEnum/text()", namespaces=ns)
    assert status and set(status) == {"INDETERMINATE"}
    assert set(qif.xpath("//q:InspectionStatusEnum/text()", namespaces=ns)) == {"UNKNOWN"}
    text = subprocess.run(
        ["pdftotext", "-layout", str(out / "plate.pdf"), "-"], capture_output=True, text=True
    ).stdout
    assert "NOT ESTABLISHED" in text and "Decision ISO 14253-1" in text
    assert "on the zone limit within the measurement uncertainty" in text
    rc, doc, _ = run("simple")
    assert rc == 1 and doc["verdict"] == "FAIL" and doc["acceptance"]["decision"] == "FAIL"
    rc, doc, _ = run("guarded-rejection")
    assert rc == 0 and doc["verdict"] == "PASS", doc["decided_by"]
    rc, doc, _ = run("guarded-acceptance")
    assert_valid_summary(doc)
    assert rc == 1 and doc["verdict"] == "FAIL" and doc["decided_by"]
