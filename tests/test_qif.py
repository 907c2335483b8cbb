"""QIF 3.0 results documents written by ``qifreport``: valid, complete, read back.

Every QIF file written here (a conforming part, a failing part, a STEP part with several PMI
tolerances, a mesh nominal with no PMI) is checked by
- libxml2 (lxml) and xmlschema (strict, key/keyref) against the official QIF 3.0 XSDs,
- the DMSC XSLT checks (zero errors in CheckFormat),
- two consumers we did not write: a PyXB binding generated from the XSDs and Xerces-C,
- our own structural checks (unique ids, ``idMax``, every ``n=``, QPIds are UUIDs),
and read back with :func:`qifreport.qif.reader.read_results` number by number against the JSON
summary.
"""

from __future__ import annotations

import json
import re
import uuid
from pathlib import Path

import numpy as np
import pytest
import trimesh
from lxml import etree

from qifreport.qif.reader import read_results
from qifreport.qif.writer import DECIMAL_PLACES, NS
from tests.conftest import ROOT, assert_valid_summary
from tests.consumers import assert_read_by_independent_consumers
from tests.plan_refs import assert_refers_to_plan

Q = f"{{{NS}}}"


def _run_cli(argv: list[str]) -> int:
    from qifreport.cli import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    return exc.value.code


def _write_shell(V, F, P, d: Path) -> tuple[Path, Path]:
    nom, scan = d / "shell.ply", d / "shell_scan.npy"
    trimesh.Trimesh(V, F, process=False).export(nom)
    np.save(scan, P)
    return nom, scan


@pytest.fixture(scope="module")
def runs(tmp_path_factory, shell, shell_case, shell_case_defect):
    """name -> (exit code, qif path, summary dict) of four CLI inspections."""
    out = {}
    V, F = shell
    d = tmp_path_factory.mktemp("qif-pass")
    nom, scan = _write_shell(V, F, shell_case.P, d)
    rc = _run_cli(
        [
            str(nom),
            str(scan),
            "--tolerance",
            "0.5",
            "--out",
            str(d),
            "--json",
            "--quiet",
            "--serial",
            "SN-0001",
            "--author",
            "Ada Auditor",
            "--organization",
            "Test Lab",
            "--operator",
            "Op One",
        ]
    )
    # named after the part and its serial number
    out["pass"] = (rc, d / "shell_SN-0001.qif", json.loads((d / "shell_SN-0001.json").read_text()))

    d = tmp_path_factory.mktemp("qif-fail")
    nom, scan = _write_shell(V, F, shell_case_defect.P, d)
    rc = _run_cli([str(nom), str(scan), "--tolerance", "0.3", "--out", str(d), "--json", "--quiet"])
    out["fail"] = (rc, d / "shell.qif", json.loads((d / "shell.json").read_text()))
    out["fail_case"] = shell_case_defect

    d = tmp_path_factory.mktemp("qif-step")
    rc = _run_cli(
        [
            str(ROOT / "samples/panel.step"),
            str(ROOT / "samples/panel_scan_defect.ply"),
            "--max-edge",
            "6",
            "--restraint",
            "virtual",
            "--out",
            str(d),
            "--json",
            "--quiet",
        ]
    )
    out["step"] = (rc, d / "panel.qif", json.loads((d / "panel.json").read_text()))
    return out


CASES = ["pass", "fail", "step"]


def _qif_status(verdict: str) -> str:
    """The QIF InspectionStatusEnum of a summary verdict (NOT ESTABLISHED has none: UNKNOWN)."""
    return {"NOT ESTABLISHED": "UNKNOWN"}.get(verdict, verdict)


def _char_status(zone: dict, doc: dict) -> str:
    """A characteristic's QIF status: the zone's verdict, INDETERMINATE for a passing zone
    when the registration is not trusted (the summary's warnings)."""
    if zone["verdict"] == "PASS" and doc["warnings"]:
        return "INDETERMINATE"
    return zone["verdict"].replace(" ", "_")  # NOT MEASURED: QIF's NOT_MEASURED


def test_cli_verdicts_and_summaries(runs):
    assert runs["pass"][0] == 0 and runs["pass"][2]["verdict"] == "PASS"
    assert runs["fail"][0] == 1 and runs["fail"][2]["verdict"] == "FAIL"
    for name in CASES:
        rc, qif, doc = runs[name]
        assert_valid_summary(doc)
        assert doc["qif"]["valid"] is True and doc["qif"]["path"] == str(qif)
        assert qif.is_file()


@pytest.mark.parametrize("name", CASES)
def test_valid_under_lxml_and_xmlschema(runs, name):
    from qifreport.qif.validate import validate_lxml, validate_xmlschema

    path = runs[name][1]
    assert validate_lxml(path) == []
    assert validate_xmlschema(path) == []


@pytest.mark.parametrize("name", CASES)
def test_dmsc_checks_format_clean(runs, name):
    from qifreport.qif.validate import dmsc_checks

    findings = dmsc_checks(runs[name][1])
    assert [f for f in findings if f.category == "CheckFormat"] == []
    # what the quality checks do report: annotations without graphics (we write no views)
    # (the plan the results name, checked as a linked document, reports the same kind)
    other = {
        re.sub(r"\).*", ")", re.sub(r"^in linked document \S+ line \d+: ", "", f.message))
        for f in findings
    }
    assert other <= {"Unviewed Annotation (A-AN-UV)", "Non-Graphical Annotation (A-AN-NG)"}, other


@pytest.mark.parametrize("name", CASES)
def test_read_by_independent_consumers(runs, name, pyxb_qif, qif_xsd):
    assert_read_by_independent_consumers(runs[name][1], pyxb_qif, qif_xsd)


@pytest.mark.parametrize("name", CASES)
def test_ids_counts_and_qpids(runs, name):
    text = runs[name][1].read_bytes()
    assert text.startswith(b'<?xml version="1.0" encoding="UTF-8" standalone="no"?>\n<QIF')
    assert not text.startswith(b"\xef\xbb\xbf")
    root = etree.fromstring(text)
    assert root.tag == f"{Q}QIFDocument" and root.prefix is None
    assert root.get("versionQIF") == "3.0.0"
    ids = [int(e.get("id")) for e in root.iter() if e.get("id") is not None]
    assert len(ids) == len(set(ids)), "duplicate QIF ids"
    assert int(root.get("idMax")) == max(ids)
    for el in root.iter():
        if el.get("n") is not None:
            assert int(el.get("n")) == len(el), f"{el.tag} n={el.get('n')} has {len(el)} children"
    qpids = [
        e.text.strip() for e in root.iter(f"{Q}QPId", f"{Q}UUID", f"{Q}ThisResultsInstanceQPId")
    ]
    assert len(qpids) >= 4 and len(set(qpids)) == len(qpids)
    for q in qpids:
        assert str(uuid.UUID(q)) == q
    # every id reference points at an element of the document
    refs = [
        e.text.strip()
        for e in root.iter()
        if etree.QName(e).localname.endswith("Id") and e.text and e.text.strip().isdigit()
    ]
    assert set(map(int, refs)) <= set(ids)


def _profiles(r) -> list:
    return [c for c in r.characteristics if c.document.type == "SurfaceProfile"]


def _acceptances(r) -> dict:
    return {c.spec.key: c for c in r.characteristics if c.document.type == "UserDefinedAttribute"}


def test_the_condition_and_who_stated_it_are_in_the_json_and_the_qif(runs):
    """The operator's --restraint virtual (the panel's drawing note states it too: the
    operator's word is the one recorded), the mesh nominal's operator-level default, each in
    the JSON's restraint block and the QIF's result attributes, with the free state's
    verdict where the fixture was applied."""
    for name, stated_by, statement in (
        ("step", "operator", "--restraint virtual"),
        ("pass", "default", "no drawing (mesh nominal)"),
    ):
        _, qif, doc = runs[name]
        held = doc["restraint"]
        assert (held["condition"], held["stated_by"]) == ("virtual", stated_by)
        assert held["statement"].startswith(statement)
        assert doc["parameters"]["restraint"] == {
            k: held[k] for k in ("condition", "stated_by", "statement")
        }
        attrs = {
            a.get("name"): a.get("value") for a in etree.parse(str(qif)).iter(f"{Q}AttributeStr")
        }
        assert attrs["restraint_condition"] == "virtual"
        assert attrs["restraint_stated_by"] == stated_by
        assert attrs["judged_condition"] == held["judged"]
        if held["applied"]:
            assert held["judged"].startswith(f"{doc['verdict']} in a virtually restrained")
            assert attrs["free_state_verdict"] == held["free_state"]["verdict"] == "FAIL"


def test_failing_part_carries_fail_and_its_regions(runs):
    rc, path, doc = runs["fail"]
    r = read_results(path)
    assert r.status == "FAIL"
    (c,) = _profiles(r)
    assert c.document.type == "SurfaceProfile" and c.spec.key == "general"
    assert c.status == "FAIL"
    assert _acceptances(r)["general_ACCEPTANCE"].status == "FAIL"
    assert c.spec.tolerance == pytest.approx(0.6)
    # the profile value found: the zone width that would contain every scored point
    assert c.value == pytest.approx(2 * max(abs(c.worst_positive), abs(c.worst_negative)), abs=2e-4)
    assert c.value > c.spec.tolerance
    regions = c.acceptance.regions
    assert len(regions) == doc["tolerances"][0]["acceptance"]["n_regions"] >= 1
    case = runs["fail_case"]
    # the largest region is the injected bump (1.0 mm, sigma 7 mm): proud, at the defect site
    top = regions[0]
    assert top.sign == +1 and top.peak > 0.3 and top.area > 25.0
    assert np.linalg.norm(top.centroid - case.V[case.defect_vertex]) < 7.0
    assert any(x.startswith("region of") and "exceeds" in x for x in c.acceptance.reasons)
    root = etree.parse(str(path)).getroot()
    ncd = root.find(f".//{Q}SurfaceProfileCharacteristicMeasurement/{Q}NonConformanceDesignator")
    assert ncd is not None and "beyond" in ncd.text
    ncd = root.find(
        f".//{Q}UserDefinedAttributeCharacteristicMeasurement/{Q}NonConformanceDesignator"
    )
    assert ncd is not None and "region" in ncd.text


def test_conforming_part_passes_everywhere(runs):
    r = read_results(runs["pass"][1])
    assert r.status == "PASS"
    assert [c.status for c in r.characteristics] == ["PASS", "PASS"]  # profile, acceptance
    root = etree.parse(str(runs["pass"][1])).getroot()
    assert root.find(f".//{Q}ActualComponent/{Q}Status/{Q}InspectionStatusEnum").text == "PASS"
    assert r.serial_number == "SN-0001"
    assert root.find(f"{Q}Header/{Q}Author/{Q}Name").text == "Ada Auditor"
    assert root.find(f".//{Q}InspectionTraceability/{Q}InspectionOperator/{Q}Name").text == (
        "Op One"
    )


def test_step_part_one_characteristic_per_profile_tolerance(runs):
    rc, path, doc = runs["step"]
    r = read_results(path)
    keys = [z["key"] for z in doc["tolerances"]]
    assert [c.spec.key for c in _profiles(r)] == keys
    assert len(keys) >= 2
    accept = _acceptances(r)
    assert set(accept) == {f"{k}_ACCEPTANCE" for k in keys}
    for c, z in zip(_profiles(r), doc["tolerances"], strict=True):
        assert c.document.type == "SurfaceProfile"
        assert c.spec.tolerance == pytest.approx(z["width_mm"])
        assert c.spec.datums == z["datums"]
        # the acceptance rule's decision is its own characteristic; the profile's status is
        # its value against its tolerance
        assert accept[f"{z['key']}_ACCEPTANCE"].status == _char_status(z, doc)
        if z["verdict"] == "NOT MEASURED":  # e.g. its datum frame not established
            assert c.status == "NOT_MEASURED"
        elif c.value > c.spec.tolerance:
            assert c.status == "FAIL"
        else:
            assert c.status in ("PASS", "INDETERMINATE", "FAIL")
    assert _profiles(r)[0].spec.datums == ["A", "B", "C"]
    # the panel's two flatness tolerances, each as a FlatnessCharacteristic with its value
    flat = [c for c in r.characteristics if c.document.type == "Flatness"]
    assert [c.spec.key for c in flat] == ["G1", "G2"]
    assert all(c.spec.tolerance == pytest.approx(0.2) and 0 < c.value < 0.2 for c in flat)
    root = etree.parse(str(path)).getroot()
    labels = [e.text for e in root.iter(f"{Q}DatumLabel")]
    assert labels == ["A", "B", "C"]
    # the results name the part's plan (qifreport plan) by its QPId and file name
    from qifreport.qif.plan import plan_qpid

    ref = root.find(f"{Q}ExternalQIFReferences/{Q}ExternalQIFDocument")
    assert ref.findtext(f"{Q}QPId") == plan_qpid(doc["inputs"]["nominal"]["sha256"])
    assert ref.findtext(f"{Q}URI") == "panel_plan.qif"
    # ... and carry it: the plan's elements with its ids and UUIDs, each item measured
    n = assert_refers_to_plan(path, path.with_name("panel_plan.qif"))
    assert n["plan_items"] == 4 and n["references"] > 90
    # each surface names its B-rep faces by STEP entity id too
    step_text = (ROOT / "samples/panel.step").read_text().replace(" ", "")
    for f in root.iter(f"{Q}OtherSurfaceFeatureNominal"):
        attrs = {a.get("name"): a.get("value") for a in f.iter(f"{Q}AttributeStr")}
        if "b_rep_faces" in attrs:
            assert all(f"#{sid}=" in step_text for sid in attrs["step_faces"].split())
    # traceability: both inputs with their SHA-256, the software version, time of inspection
    digests = {doc["inputs"]["nominal"]["sha256"], doc["inputs"]["scan"]["sha256"]}
    assert {d.rsplit(" ", 1)[-1] for _, d in r.inputs} == digests
    assert r.software_version == doc["software"]["version"]
    # the sparse factorisation the numbers came from (CHOLMOD or SuperLU: see test_linalg)
    from qifreport.registration.linalg import default_backend

    assert doc["software"]["sparse_solver"] == default_backend()
    assert r.inspection_start and r.inspection_end >= r.inspection_start
    alg = root.find(f"{Q}AlgorithmDefinitions")
    assert "band_limit" in alg[1].find(f"{Q}Parameters").text


def _close(a, b, places=None):
    if b is None:
        return a is None or not np.isfinite(a)
    tol = 0.0 if places is None else 0.51 * 10.0**-places
    return abs(a - b) <= tol + 1e-12 * abs(b)


@pytest.fixture(scope="module")
def panel_job(tmp_path_factory, qifreport_cache):
    """The panel sample's failing scan inspected as the command does (its two profile
    tolerances, their acceptances and two flatness tolerances), the QIF written."""
    from qifreport.options import InspectJob, InspectOptions
    from qifreport.pipeline import run_job

    job = InspectJob(
        nominal=ROOT / "samples/panel.step",
        scan=ROOT / "samples/panel_scan_defect.ply",
        out=tmp_path_factory.mktemp("qif-panel"),
        options=InspectOptions(max_edge=6.0, no_pdf=True, cache_dir=qifreport_cache),
    )
    return run_job(job, progress=False)


def test_panel_characteristics_read_back_as_written(panel_job):
    """Each characteristic the writer writes (:func:`written_characteristics`: the
    surfaces' profiles with their statistics and acceptance, their acceptances, the flatness
    tolerances) is the one the reader reads back, field by field."""
    from qifreport.kinds import kind_for_qif_type
    from qifreport.metrology.gdt.characteristic_types import OTHER_KIND
    from qifreport.qif.profile_characteristics import written_characteristics
    from tests.round_trip import assert_same_result

    written = written_characteristics(panel_job.result)
    read = read_results(panel_job.paths["qif"]).characteristics
    assert [c.spec.key for c in read] == [c.spec.key for c in written]
    profile, flatness = kind_for_qif_type("SurfaceProfile"), kind_for_qif_type("Flatness")
    kinds = [c.spec.kind for c in read]
    assert kinds == [profile.name, OTHER_KIND] * 2 + [flatness.name] * 2
    for w, r in zip(written, read, strict=True):
        assert_same_result(w, r)
    # the failing scan: a profile fails on its value, its acceptance on the regions
    assert {c.status for c in read} >= {"PASS", "FAIL"}
    assert all(c.stats is not None and c.worst_positive is not None for c in read[:3:2])


def test_budget_in_qif_names_the_scanner_and_its_combined_uncertainty(panel_job):
    """The flatness tolerances' uncertainty budgets in QIF's own elements: the scanner a
    ``MeasurementDevice`` (the default class, said so), each measurement naming it and its
    ``Value`` stating the budget's combined standard uncertainty; its terms as Attributes
    (read back field by field by the round-trip test above)."""
    root = etree.parse(str(panel_job.paths["qif"])).getroot()
    q = {"q": NS}
    (device,) = root.findall("q:MeasurementResources/q:MeasurementDevices/q:MeasurementDevice", q)
    assert device.findtext("q:Name", namespaces=q) == "mid-range structured-light scanner"
    assert "default scanner class" in device.findtext("q:Description", namespaces=q)
    flat = root.findall(".//q:FlatnessCharacteristicMeasurement", q)
    by_key = {c.spec.key: c for c in panel_job.result.characteristics}
    assert len(flat) == 2
    for m in flat:
        assert m.findtext("q:MeasurementDeviceIds/q:Id", namespaces=q) == device.get("id")
        key = m.find("q:Attributes/*[@name='budget_instrument_u']", q)
        assert float(key.get("value")) == pytest.approx(0.025 / np.sqrt(3), rel=1e-12)
        value = m.find("q:Value", q)
        u_c = float(value.get("combinedUncertainty"))
        assert value.get("meanError") == "0" + "." + "0" * DECIMAL_PLACES
        assert any(abs(u_c - c.budget.combined) < 10**-DECIMAL_PLACES for c in by_key.values())


@pytest.mark.parametrize("name", CASES)
def test_round_trip_reproduces_verdicts_and_statistics(runs, name):
    rc, path, doc = runs[name]
    r = read_results(path)
    assert r.status == _qif_status(doc["verdict"])
    assert r.written_by_qifreport
    whole = [("vertex_deviation", r.stats), ("point_deviation", r.point_stats)]
    for key, got in whole:
        ref = doc[key]
        for f in (
            "rms",
            "mean",
            "max_abs",
            "max_pos",
            "min_neg",
            "p95",
            "p99",
            "p999",
            "frac_above",
            "frac_below",
            "frac_beyond",
            "threshold",
        ):
            assert _close(getattr(got, f), ref[f]), (key, f, getattr(got, f), ref[f])
        assert got.n == ref["n"]
    acc, ref = r.acceptance, doc["acceptance"]
    assert acc.passed == ref["passed"] and acc.reasons == ref["reasons"]
    for f in (
        "in_tolerance_fraction",
        "scored_area",
        "nominal_area",
        "coverage",
        "largest_region_area",
    ):
        assert _close(getattr(acc, f), ref[f]), f
    assert len(acc.regions) == ref["n_regions"]
    for got_r, ref_r in zip(acc.regions, ref["regions"], strict=True):
        assert _close(got_r.area, ref_r["area"]) and _close(got_r.peak, ref_r["peak"])
        np.testing.assert_allclose(got_r.centroid, ref_r["centroid"], rtol=0, atol=1e-12)
    accept = _acceptances(r)
    for c, z in zip(_profiles(r), doc["tolerances"], strict=True):
        assert accept[f"{z['key']}_ACCEPTANCE"].status == _char_status(z, doc)
        # the extremes are the vertices' or, beyond them, a region's peak on the points
        peaks = [g["peak"] for g in z["acceptance"]["regions"]]
        assert _close(c.worst_positive, max([z["deviation"]["max_pos"], *peaks]), DECIMAL_PLACES)
        assert _close(c.worst_negative, min([z["deviation"]["min_neg"], *peaks]), DECIMAL_PLACES)
        for f in ("rms", "p95", "p999", "frac_beyond"):
            assert _close(getattr(c.stats, f), z["deviation"][f]), f
        assert c.acceptance.passed == z["acceptance"]["passed"]
        assert _close(c.acceptance.in_tolerance_fraction, z["acceptance"]["in_tolerance_fraction"])
    assert r.attributes["rigid_rms_mm"] == pytest.approx(
        doc["registration"]["rigid"]["rms_mm"], rel=0, abs=0
    )


@pytest.mark.parametrize("name", CASES)
def test_no_characteristic_passes_beyond_its_tolerance(runs, name):
    """Status never contradicts Value: no PASS with a value beyond its limits (issue 22)."""
    from qifreport.qif.consistency import status_contradictions

    root = etree.parse(str(runs[name][1])).getroot()
    assert status_contradictions(root) == []
    measured = [
        e for e in root.iter() if etree.QName(e).localname.endswith("CharacteristicMeasurement")
    ]
    assert measured


def test_consistency_check_catches_a_pass_beyond_tolerance(runs):
    """The check can fail: a profile's PASS written over a value beyond its tolerance."""
    from qifreport.qif.consistency import status_contradictions

    root = etree.parse(str(runs["fail"][1])).getroot()
    m = root.find(f".//{Q}SurfaceProfileCharacteristicMeasurement")
    m.find(f"{Q}Status/{Q}CharacteristicStatusEnum").text = "PASS"
    found = status_contradictions(root)
    assert len(found) == 1 and "PASS with value" in found[0]


def test_validate_subcommand_catches_a_corrupted_file(runs, tmp_path, capsys):
    from qifreport.cli import main

    src = runs["fail"][1].read_text()
    # (a) a required element removed: the characteristic measurement's Status
    bad = re.sub(
        r"<Status>\s*<CharacteristicStatusEnum>FAIL</CharacteristicStatusEnum>\s*"
        r"</Status>",
        "",
        src,
        count=1,
    )
    assert bad != src
    a = tmp_path / "missing.qif"
    a.write_text(bad)
    # (b) a dangling id reference: the characteristic item points at no nominal
    m = re.search(r"<CharacteristicNominalId>(\d+)</CharacteristicNominalId>", src)
    b = tmp_path / "dangling.qif"
    b.write_text(
        src.replace(m.group(0), "<CharacteristicNominalId>99999</CharacteristicNominalId>")
    )
    line_b = src[: m.start()].count("\n") + 1
    for path, needle in ((a, "Status"), (b, "99999")):
        with pytest.raises(SystemExit) as exc:
            main(["validate", str(path)])
        out = capsys.readouterr().out
        assert exc.value.code == 1, out
        assert needle in out
    with pytest.raises(SystemExit) as exc:
        main(["validate", str(b)])
    out = capsys.readouterr().out
    assert re.search(rf"dangling\.qif:{line_b}:", out), out
    assert "Keyref" in out or "keyref" in out
    with pytest.raises(SystemExit) as exc:
        main(["validate", str(runs["fail"][1])])
    assert exc.value.code == 0, capsys.readouterr().out


def test_without_schemas_the_qif_is_written_but_never_called_valid(
    shell, shell_case, tmp_path, monkeypatch, capsys
):
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(tmp_path / "no-schemas-here"))
    nom, scan = _write_shell(*shell, shell_case.P, tmp_path)
    rc = _run_cli(
        [
            str(nom),
            str(scan),
            "--tolerance",
            "0.5",
            "--out",
            str(tmp_path),
            "--json",
            "--quiet",
            "--rigid-only",
        ]
    )
    out = capsys.readouterr().out
    assert rc in (0, 1)
    assert (tmp_path / "shell.qif").is_file()
    assert "NOT validated" in out and "QIFREPORT_XSD_DIR" in out
    assert "(valid against" not in out
    doc = json.loads((tmp_path / "shell.json").read_text())
    assert_valid_summary(doc)
    assert doc["qif"]["valid"] is None and doc["qif"]["validated_with"] == []


def test_outputs_are_all_or_nothing(tmp_path):
    from qifreport.atomic_io import atomic_write_many

    (tmp_path / "b.txt").write_text("old")

    def boom(p):
        raise RuntimeError("render failed")

    with pytest.raises(RuntimeError):
        atomic_write_many(
            [
                (tmp_path / "a.qif", lambda p: p.write_text("qif")),
                (tmp_path / "b.txt", lambda p: p.write_text("new")),
                (tmp_path / "c.pdf", boom),
            ]
        )
    assert sorted(x.name for x in tmp_path.iterdir()) == ["b.txt"]
    assert (tmp_path / "b.txt").read_text() == "old"
    atomic_write_many(
        [
            (tmp_path / "a.qif", lambda p: p.write_text("qif")),
            (tmp_path / "b.txt", lambda p: p.write_text("new")),
        ]
    )
    assert (tmp_path / "a.qif").read_text() == "qif" and (tmp_path / "b.txt").read_text() == "new"


def test_a_max_tolerance_is_written_as_its_maximum_tolerance_value_and_read_back(tmp_path):
    """A position ``1.016 (M) MAX 1.143`` caps its bonus at 1.143 mm: the definition states
    it as ``MaximumToleranceValue`` (after ``ZoneShape``, as the XSD orders them), the
    document is valid, and the reader gives the cap back."""
    from qifreport.metrology.gdt.characteristic_types import (
        CharacteristicResult,
        CharacteristicSpec,
    )
    from qifreport.qif.lxml_validator import validate_lxml
    from tests.round_trip import one_characteristic_document

    spec = CharacteristicSpec(
        key="G7",
        kind="position",
        name="hole pattern",
        step_id=11,
        faces=np.array([0]),
        tolerance=1.016,
        modifiers=["maximum_material_requirement"],
        max_value=1.143,
    )
    c = CharacteristicResult(spec, value=0.9, uncertainty=0.01, status="PASS")
    path = tmp_path / "max.qif"
    path.write_bytes(one_characteristic_document(c))
    # the content model holds (the bare document defines no actual component: its keyrefs
    # are the only findings)
    findings = validate_lxml(path)
    assert [f for f in findings if not f.rule.startswith("keyref")] == [], findings
    text = path.read_text()
    assert "<MaximumToleranceValue>1.1430</MaximumToleranceValue>" in text
    assert text.index("</ZoneShape>") < text.index("<MaximumToleranceValue>")
    (back,) = read_results(path).characteristics
    assert back.spec.max_value == pytest.approx(1.143) and back.spec.tolerance == 1.016
