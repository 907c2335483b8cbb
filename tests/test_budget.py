"""The uncertainty budget of a characteristic (GUM; ISO 14253-1 decisions), on NIST FTC 06's
real part and drawing through the measurement a report runs:

* D15, a 6.35 mm hole (6.1468 .. 6.5532), its scan putting it 1 um under its lower limit:
  the points' statistics alone (U of a few um) "prove" it out (FAIL); with the default
  scanner class's instrument term (PS 0.015 mm) it is INDETERMINATE, as ISO 14253-1 says of
  a value within U of a limit, and says so (the limit, U, the budget's largest term). 0.1 mm
  under its limit it still FAILs;
* a scanner profile's figures drive the instrument term: doubling PS doubles it, and U
  follows as the terms' root-sum-square;
* the budget's terms are in the characteristic's JSON, U their expanded total;
* a bad profile file is refused in one line, exit 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from qifreport.metrology.acceptance.scanner import (
    DEFAULT_SCANNER,
    ScannerProfileError,
    load_scanner,
)
from qifreport.metrology.gdt.characteristics import measure_characteristics
from qifreport.metrology.gdt.dimensions import measure_dimension
from tests.test_characteristics import exact_surface

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ftc06(nist_nominal):
    return nist_nominal("nist_ftc_06_asme1_ap242-e1.stp")


def _hole_at(part, spec, diameter: float):
    """FTC 06 measured exactly, the hole(s) of ``spec`` at ``diameter`` mm (each vertex
    moved along its outward normal, which points to the axis in a hole)."""
    dev = np.zeros(len(part.V))
    on = np.isin(part.face_id, spec.faces)
    v = np.unique(part.F[on])
    dev[v] = 0.5 * (spec.nominal - diameter)
    return exact_surface(part, dev)


def _profile(tmp_path: Path, name: str, **figures) -> Path:
    p = tmp_path / name
    p.write_text(json.dumps({"name": "cell 3", **figures}))
    return p


def test_a_hole_on_its_lower_limit_is_indeterminate_not_fail(ftc06):
    part, drawing = ftc06
    spec = next(s for s in drawing.plan.specs if s.key == "D15")
    assert (spec.nominal, spec.lower_limit) == pytest.approx((6.35, 6.1468))
    surf = _hole_at(part, spec, spec.lower_limit - 0.001)
    # the points' statistics alone: U of micrometres, the hole "proven" out
    bare = measure_dimension(spec, surf, "iso14253")
    assert bare.value == pytest.approx(spec.lower_limit - 0.001, abs=2e-4)
    assert bare.uncertainty < 0.001 and bare.status == "FAIL"
    (res,), _ = measure_characteristics([spec], drawing.plan.datums, surf, "iso14253")
    assert res.value == bare.value
    assert res.status == "INDETERMINATE", (res.status, res.reason)
    # it says why: the limit it lies within U of, and the budget's largest term
    assert res.reason.startswith(
        f"{res.value:.7g} within its uncertainty U 0.017 of the limit 6.1468"
    )
    assert "no reading could" not in res.reason
    assert "its largest term: instrument" in res.reason and "PS 0.015 mm" in res.reason
    # U: PS 0.015 mm, rectangular, k = 2, with the sampling term in quadrature
    U_ps = 2 * DEFAULT_SCANNER.probing_size / math.sqrt(3)
    assert res.uncertainty == pytest.approx(math.hypot(U_ps, bare.uncertainty), rel=1e-9)
    assert 0.017 < res.uncertainty < 0.0175
    d = res.to_dict()["uncertainty_budget"]
    assert d["scanner"] == "default scanner class (mid-range structured-light scanner)"
    assert [t["name"] for t in d["terms"]] == ["sampling", "instrument"]
    assert d["expanded_uncertainty"] == pytest.approx(res.uncertainty, rel=1e-12)
    assert "PS 0.015 mm" in d["terms"][1]["source"]
    # clearly out of tolerance: still proven out
    far = _hole_at(part, spec, spec.lower_limit - 0.1)
    (out,), _ = measure_characteristics([spec], drawing.plan.datums, far, "iso14253")
    assert out.status == "FAIL" and out.reason.startswith("6.04"), out.reason


def test_the_scanner_profile_drives_the_instrument_term(ftc06, tmp_path):
    part, drawing = ftc06
    specs = [s for s in drawing.plan.specs if s.key in ("D15", "G1")]
    surf = _hole_at(part, specs[1], 6.35)
    terms = {}
    for ps in (0.01, 0.02):
        f = _profile(tmp_path, f"ps{ps}.json", probing_form=0.008, probing_size=ps, length_a=0.01)
        scanner = load_scanner(f)
        assert not scanner.default and scanner.label == "cell 3"
        res, _ = measure_characteristics(
            specs, drawing.plan.datums, surf, "iso14253", scanner=scanner
        )
        by = {r.spec.key: r for r in res}
        hole = {t.name: t.u for t in by["D15"].budget.terms}
        terms[ps] = hole
        assert hole["instrument"] == pytest.approx(ps / math.sqrt(3), rel=1e-12)
        assert by["D15"].uncertainty == pytest.approx(2 * math.hypot(*hole.values()), rel=1e-12)
        flat = {t.name: t.u for t in by["G1"].budget.terms}  # a flatness: PF, not PS
        assert flat["instrument"] == pytest.approx(0.008 / math.sqrt(3), rel=1e-12)
    assert terms[0.02]["instrument"] == pytest.approx(2 * terms[0.01]["instrument"], rel=1e-12)
    assert terms[0.02]["sampling"] == terms[0.01]["sampling"]


def test_a_temperature_adds_its_term(tmp_path):
    from qifreport.metrology.acceptance.budget import temperature_term

    f = _profile(
        tmp_path, "warm.json", probing_form=0.01, probing_size=0.01, length_a=0.01,
        temperature=25.0, cte=23e-6,
    )  # fmt: skip
    u, source = temperature_term(load_scanner(f), 100.0)
    assert u == pytest.approx(23e-6 * 5.0 * 100.0 / math.sqrt(3))  # 11.5 um bound
    assert "rectangular" in source


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("{not json", "not valid JSON"),
        ('{"name": "x", "probing_form": 0.01, "probing_size": 0.01}', "missing length_a"),
        (
            '{"name": "x", "probing_form": 0.01, "probing_size": -1, "length_a": 0.01}',
            "probing_size must be a length in (0, 10] mm",
        ),
        (
            '{"name": "x", "probing_form": 0.01, "probing_size": 0.01, "length_a": 0.01, "PS": 1}',
            "unknown key(s) PS",
        ),
    ],
)
def test_a_bad_profile_is_refused_in_one_line(tmp_path, text, says):
    f = tmp_path / "bad.json"
    f.write_text(text)
    with pytest.raises(ScannerProfileError) as e:
        load_scanner(f)
    assert says in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_the_command_line_refuses_a_bad_profile_with_exit_2(tmp_path, capsys):
    from qifreport.cli import main

    f = tmp_path / "bad.toml"
    f.write_text('name = "x"\nprobing_form = "fine"\n')
    argv = [
        str(ROOT / "samples/panel.step"),
        str(ROOT / "samples/panel_scan.ply"),
        "--scanner",
        str(f),
        "--out",
        str(tmp_path / "out"),
    ]
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("qifreport: error: --scanner:"), err
    assert err.endswith("missing probing_size, length_a"), err


def test_a_surface_with_a_u_wider_than_the_part_is_not_measured(ftc06):
    """A sparse scan's fit extrapolated far beyond its points (U max 766.9 mm on one
    vertex, as a real scan printed): the surface is NOT MEASURED with that reason, not
    judged within a 767 mm uncertainty."""
    from qifreport.metrology.acceptance.bands import zone_vertex_areas
    from qifreport.metrology.acceptance.coverage import plausible_uncertainty, zone_coverage
    from qifreport.metrology.acceptance.criteria import evaluate
    from qifreport.registration.mesh import bounding_diagonal

    part, _ = ftc06
    V, F = part.V, part.F
    area = zone_vertex_areas(V, F, np.ones(len(F), dtype=bool))
    dev = np.zeros(len(V))
    U = np.full(len(V), 0.01)
    cov = zone_coverage(V, F, dev, area, np.zeros(len(V), dtype=bool))
    assert cov.measured
    diagonal = bounding_diagonal(V)
    ok = evaluate(V, F, dev, 0.5, area=area, uncertainty=U, decision_rule="iso14253")
    assert plausible_uncertainty(cov, ok.uncertainty_mm[1], diagonal) is cov
    U[123] = 766.9
    acc = evaluate(V, F, dev, 0.5, area=area, uncertainty=U, decision_rule="iso14253")
    assert acc.uncertainty_mm[1] == pytest.approx(766.9)
    got = plausible_uncertainty(cov, acc.uncertainty_mm[1], diagonal)
    assert not got.measured
    assert got.reasons[-1].startswith(
        "implausible uncertainty: U max 766.9 mm exceeds the part's 404.7 mm diagonal"
    ), got.reasons


def test_resampled_registrations_add_their_spread_and_the_value_is_judged_again():
    """A flatness of 0.090 against 0.100 with U 0.004 PASSes; read 0.090, 0.099, 0.081 and
    0.093 over the resampled registrations (--seeds), its budget gains a registration term
    of their standard deviation (0.0075 mm) and it is INDETERMINATE; a value no run reads
    keeps its budget as it was."""
    from qifreport.metrology.acceptance.budget import UncertaintyBudget
    from qifreport.metrology.gdt.budgets import registration_term
    from qifreport.metrology.gdt.characteristic_types import (
        CharacteristicResult,
        CharacteristicSpec,
    )

    def flatness() -> CharacteristicResult:
        spec = CharacteristicSpec("G1", "flatness", "flat", None, np.array([0]), tolerance=0.1)
        budget = UncertaintyBudget()
        budget.add("sampling", 0.002, "points")
        return CharacteristicResult(
            spec, value=0.090, uncertainty=0.004, status="PASS", budget=budget
        )

    res = registration_term(flatness(), [0.099, 0.081, 0.093], "iso14253", 300.0)
    terms = {t.name: t.u for t in res.budget.terms}
    assert terms["registration"] == pytest.approx(np.std([0.09, 0.099, 0.081, 0.093], ddof=1))
    assert res.uncertainty == pytest.approx(2 * math.hypot(0.002, terms["registration"]))
    assert res.status == "INDETERMINATE"
    alone = registration_term(flatness(), [None, None], "iso14253", 300.0)
    assert [t.name for t in alone.budget.terms] == ["sampling"] and alone.status == "PASS"


def test_undecided_reason_says_when_no_reading_could_prove_conformance():
    """A position 0.0013 with U 0.085 against a 0.05 zone (CTC 02's G3 under the default
    scanner class): U alone exceeds the zone, which the reason says; a two-sided size
    whose zone is wider than 2 U does not get that clause."""
    from qifreport.metrology.gdt.characteristic_types import undecided_reason

    wide = undecided_reason(0.0013, 0.085, None, 0.05)
    assert wide.startswith("0.0013 within its uncertainty U 0.085 of the limit 0.05")
    # the digits that tell a value from the limit it lies on
    assert undecided_reason(35.0000194, 0.0173, 34.8, 35.0).startswith("35.00002 within")
    assert "no reading could prove conformance" in wide and wide.endswith("(ISO 14253-1)")
    size = undecided_reason(34.99995, 0.0173, 35.0, 35.2)
    assert "of the limit 35:" in size and "no reading could" not in size
    assert "no reading could" in undecided_reason(10.0, 0.011, 9.99, 10.01)
