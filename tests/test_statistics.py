"""The QIF 3.0 statistics document of a batch (qif/statistics.py).

Three inspections of the shell sample by the real command line (a passing scan, a scan with a
bump that fails, and the passing scan rigidly aligned only), read back, summarised and written
as one statistics document beside them. The document is validated by every validator of the
project and by the independent consumers, and its numbers, read with plain lxml XPath, are
checked against the values read, likewise, from the per-scan documents (``statistics`` of the
standard library, not numpy, computes the expectations).
"""

from __future__ import annotations

import hashlib
import math
import statistics as pystats
from datetime import datetime, timezone
from pathlib import Path
from types import SimpleNamespace

import pytest
from lxml import etree

from qifreport.qif.reader import CharacteristicResult, QIFResults, read_results
from qifreport.qif.statistics import (
    NO_VALUE_REASON,
    build_statistics,
    summarize,
    write_statistics,
)
from qifreport.qif.validate import validate
from tests.consumers import assert_read_by_independent_consumers

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
NS = {"q": "http://qifstandards.org/xsd/qif3"}
CREATED = datetime(2026, 3, 1, 12, 0, 0, tzinfo=timezone.utc)
#: (output folder, scan, extra options): PASS, FAIL (a 1 mm bump), rigid alignment only
RUNS = [
    ("scan_ok", "shell_scan.ply", []),
    ("scan_defect", "shell_scan_defect.ply", []),
    ("scan_rigid", "shell_scan.ply", ["--rigid-only"]),
]


def _xp(el, path: str) -> list:
    return el.xpath(path, namespaces=NS)


def _one(el, path: str):
    found = _xp(el, path)
    assert len(found) == 1, f"{path}: {len(found)} matches"
    return found[0]


def _num(el, path: str) -> float:
    return float(_one(el, path).strip())


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """The three per-scan QIF files (``<run>/shell_nominal.qif``), the statistics document
    ``statistics.qif`` beside their folders, and what was read back."""
    from qifreport.cli import main

    d = tmp_path_factory.mktemp("batch")
    nominal = SAMPLES / "shell_nominal.ply"
    for name, scan, extra in RUNS:
        with pytest.raises(SystemExit) as exc:
            main(
                [
                    str(nominal),
                    str(SAMPLES / scan),
                    "--tolerance",
                    "0.5",
                    "--out",
                    str(d / name),
                    "--serial",
                    name,
                    "--no-pdf",
                    "--quiet",
                    *extra,
                ]
            )
        assert exc.value.code in (0, 1), f"{name}: exit {exc.value.code}"
    sources = [f"{name}/shell_nominal.qif" for name, _, _ in RUNS]
    results = [read_results(d / s) for s in sources]
    sha = hashlib.sha256(nominal.read_bytes()).hexdigest()
    tree = build_statistics(
        results,
        part_name="shell_nominal",
        created=CREATED,
        nominal_sha256=sha,
        sources=sources,
        software_version="9.9.9",
    )
    path = d / "statistics.qif"
    write_statistics(path, tree)
    return SimpleNamespace(
        dir=d, path=path, sources=sources, results=results, doc=etree.parse(str(path)).getroot()
    )


def _per_scan(path: Path) -> list[dict]:
    """The characteristic measurements of a per-scan results document, by XPath."""
    root = etree.parse(str(path)).getroot()
    out = []
    for m in _xp(
        root,
        "//q:MeasuredCharacteristics/q:CharacteristicMeasurements/"
        "q:SurfaceProfileCharacteristicMeasurement",
    ):
        item = _one(
            root,
            f"//q:SurfaceProfileCharacteristicItem[@id='"
            f"{_one(m, 'q:CharacteristicItemId/text()')}']",
        )
        nominal = _one(
            root,
            f"//q:SurfaceProfileCharacteristicNominal[@id='"
            f"{_one(item, 'q:CharacteristicNominalId/text()')}']",
        )
        definition = _one(
            root,
            f"//q:SurfaceProfileCharacteristicDefinition[@id='"
            f"{_one(nominal, 'q:CharacteristicDefinitionId/text()')}']",
        )
        value = _xp(m, "q:Value/text()")
        out.append(
            dict(
                id=m.get("id"),
                designator=_one(item, "q:CharacteristicDesignator/q:Designator/text()"),
                status=_one(m, "q:Status/q:CharacteristicStatusEnum/text()"),
                value=float(value[0]) if value else None,
                worst_positive=_num(m, "q:WorstPositiveDeviation/text()"),
                tolerance=_num(definition, "q:ToleranceValue/text()"),
                qpid=_one(root, "/q:QIFDocument/q:QPId/text()"),
            )
        )
    return out


def _expected(batch) -> dict[str, dict]:
    """Per designator, from the per-scan files: values, statuses, tolerance, worst deviations."""
    exp: dict[str, dict] = {}
    for src in batch.sources:
        for m in _per_scan(batch.dir / src):
            e = exp.setdefault(
                m["designator"], dict(values=[], statuses=[], wpos=[], tolerance=m["tolerance"])
            )
            assert e["tolerance"] == m["tolerance"]
            e["statuses"].append(m["status"])
            e["wpos"].append(m["worst_positive"])
            if m["value"] is not None:
                e["values"].append(m["value"])
    return exp


def _stats_by_designator(doc) -> dict[str, etree._Element]:
    """Each SurfaceProfileCharacteristicStats by the designator of the items its measurements
    measure (followed through the ids, not read from its own attribute)."""
    out = {}
    for st in _xp(
        doc, "//q:CapabilityStudyResults/q:CharacteristicsStats/q:SurfaceProfileCharacteristicStats"
    ):
        designators = set()
        for mid in _xp(st, "q:MeasuredIds/q:Ids/q:Id/text()"):
            m = _one(doc, f"//q:SurfaceProfileCharacteristicMeasurement[@id='{mid}']")
            item = _one(
                doc,
                f"//q:SurfaceProfileCharacteristicItem[@id='"
                f"{_one(m, 'q:CharacteristicItemId/text()')}']",
            )
            designators.add(_one(item, "q:CharacteristicDesignator/q:Designator/text()"))
        assert len(designators) == 1, designators
        (key,) = designators
        assert key not in out
        out[key] = st
    return out


# ---------------------------------------------------------------------------- validity


def test_statistics_document_valid(batch):
    rep = validate(batch.path, strict=True, checks=True)
    assert rep.ran == ["lxml", "xmlschema", "dmsc"]
    assert not rep.errors(), rep.format()
    # the DMSC checks followed every external reference (a missing one is a CheckFormat error)
    uris = _xp(batch.doc, "q:ExternalQIFReferences/q:ExternalQIFDocument/q:URI/text()")
    assert uris == batch.sources
    assert not [f for f in rep.findings if "not found" in f.message], rep.format()


def test_read_by_independent_consumers(batch, pyxb_qif, qif_xsd):
    assert_read_by_independent_consumers(batch.path, pyxb_qif, qif_xsd)


# ---------------------------------------------------------------------------- numbers


def test_numbers_equal_those_of_the_per_scan_documents(batch):
    exp = _expected(batch)
    doc = batch.doc
    study = _one(doc, "q:Statistics/q:StatisticalStudiesResults/q:CapabilityStudyResults")
    assert _num(study, "q:NumberOfSamples/text()") == len(RUNS)
    assert _one(study, "q:Status/q:StatsEvalStatusEnum/text()") == "INFORMATIONAL"
    stats = _stats_by_designator(doc)
    assert list(stats) == list(exp)  # first-seen order, every designator once
    assert _one(study, "q:CharacteristicsStats/@n") == str(len(exp))

    for key, e in exp.items():
        st, values, tol = stats[key], e["values"], e["tolerance"]
        assert len(values) == len(RUNS) >= 3  # every inspection measured it
        vs = _one(st, "q:ValueStats")
        attrs = {a.get("name"): a.get("value") for a in _xp(st, "q:Attributes/*")}
        assert attrs["designator"] == key
        assert int(attrs["n_pass"]) == e["statuses"].count("PASS")
        assert int(attrs["n_fail"]) == e["statuses"].count("FAIL")
        assert int(attrs["n_other"]) == len(e["statuses"]) - e["statuses"].count("PASS") - e[
            "statuses"
        ].count("FAIL")
        assert _num(vs, "q:TotalNumber/q:Value/text()") == len(e["statuses"])
        assert _num(vs, "q:EffectiveNumber/q:Value/text()") == len(values)
        mean, sd = pystats.fmean(values), pystats.stdev(values)
        assert _num(vs, "q:Average/q:Value/text()") == pytest.approx(mean, rel=1e-12)
        assert _num(vs, "q:StandardDeviation/q:Value/text()") == pytest.approx(sd, rel=1e-12)
        assert _num(vs, "q:Minimum/q:Value/text()") == min(values)
        assert _num(vs, "q:Maximum/q:Value/text()") == max(values)
        assert _num(vs, "q:Range/q:Value/text()") == pytest.approx(max(values) - min(values))
        above = [v for v in values if v > tol]
        assert _num(vs, "q:NumberOutOfTolerance/q:Value/text()") == len(above)
        assert len(_xp(vs, "q:NumberOutOfTolerance/q:Ids/q:Id")) == len(above)
        assert _num(vs, "q:Cpk/q:Value/text()") == pytest.approx((tol - mean) / (3 * sd), rel=1e-12)
        assert _xp(vs, "q:Cp") == []  # one-sided tolerance: no Cp
        assert _one(st, "q:CapabilityCalculationMethod/text()") == "THREE_SIGMA"
        assert _num(st, "q:WorstPositiveDeviationStats/q:Maximum/q:Value/text()") == max(e["wpos"])
        # the extremes name the measurements that have them
        for tag, v in (("Minimum", min(values)), ("Maximum", max(values))):
            m = _one(
                doc,
                f"//q:SurfaceProfileCharacteristicMeasurement[@id='"
                f"{_one(vs, f'q:{tag}/q:Id/text()')}']",
            )
            assert _num(m, "q:Value/text()") == v


def test_a_wrong_implementation_would_be_caught(batch):
    """The batch tells the sample from the population deviation and PASS from FAIL apart."""
    exp = _expected(batch)
    for key, st in _stats_by_designator(batch.doc).items():
        values, statuses = exp[key]["values"], exp[key]["statuses"]
        written = _num(st, "q:ValueStats/q:StandardDeviation/q:Value/text()")
        assert abs(written - pystats.pstdev(values)) > 1e-3 * written  # ddof=0 would fail
        assert statuses.count("PASS") != statuses.count("FAIL")  # a swap would fail
        assert {"PASS", "FAIL"} <= set(statuses)


def test_summarize_equals_the_document(batch):
    exp = _expected(batch)
    summaries = summarize(batch.results)
    assert [s.designator for s in summaries] == list(exp)
    for s in summaries:
        values = exp[s.designator]["values"]
        assert s.kind == "SurfaceProfile" and s.tolerance == exp[s.designator]["tolerance"]
        assert s.count == len(values) and s.mean == pytest.approx(pystats.fmean(values))
        assert s.std == pytest.approx(pystats.stdev(values))
        assert (s.min, s.max) == (min(values), max(values))
        assert s.n_pass == exp[s.designator]["statuses"].count("PASS")
        assert s.n_fail == exp[s.designator]["statuses"].count("FAIL")
        assert s.cp is None
        assert s.cpk == pytest.approx((s.tolerance - s.mean) / (3 * s.std))


# ---------------------------------------------------------------------------- layout


def test_measurements_are_copies_traced_to_their_sources(batch):
    doc = batch.doc
    ext = {d.get("id"): d for d in _xp(doc, "q:ExternalQIFReferences/q:ExternalQIFDocument")}
    mrs = _xp(doc, "q:Results/q:MeasurementResultsSet/q:MeasurementResults")
    study = _one(doc, "//q:CapabilityStudyResults")
    assert _xp(study, "q:ResultsIds/q:Id/text()") == [mr.get("id") for mr in mrs]
    assert len(mrs) == len(batch.sources) == len(ext)
    for mr, src, (name, _, _) in zip(mrs, batch.sources, RUNS, strict=True):
        source = {m["id"]: m for m in _per_scan(batch.dir / src)}
        qpid = next(iter(source.values()))["qpid"]
        (decl,) = [d for d in ext.values() if _one(d, "q:URI/text()") == src]
        assert _one(decl, "q:QPId/text()") == qpid
        assert _one(mr, "q:ExternalFileReferences/q:ExternalFileReference/q:URI/text()") == src
        copies = _xp(mr, ".//q:SurfaceProfileCharacteristicMeasurement")
        assert len(copies) == len(source)
        for c in copies:
            orig = source[_one(c, "q:Attributes/q:AttributeStr[@name='source_id']/@value")]
            assert _num(c, "q:Value/text()") == orig["value"]
            assert _one(c, "q:Status/q:CharacteristicStatusEnum/text()") == orig["status"]
        actual = _one(
            doc, f"//q:ActualComponent[@id='{_one(mr, 'q:ActualComponentIds/q:Id/text()')}']"
        )
        assert _one(actual, "q:SerialNumber/text()") == name


# ---------------------------------------------------------------------------- small cases


def _result(path: str, chars: list[tuple], status: str = "PASS") -> QIFResults:
    """A read-back results document: ``chars`` = (designator, value, status, tolerance)."""
    cs = [
        CharacteristicResult(
            kind="SurfaceProfile",
            id=str(10 + k),
            name=f"profile {d}",
            designator=d,
            status=st,
            value=v,
            tolerance=tol,
            worst_positive=None if v is None else v / 2,
            worst_negative=None if v is None else -v / 4,
        )
        for k, (d, v, st, tol) in enumerate(chars)
    ]
    return QIFResults(
        path=Path(path),
        version="3.0.0",
        qpid=None,
        application="qifreport",
        software_version="0.1.0",
        status=status,
        characteristics=cs,
        attributes={},
        inputs=[],
        inspection_start="2026-01-01T10:00:00Z",
        inspection_end="2026-01-01T12:00:05+01:00",
    )


def test_summarize_by_hand_and_excluded_measurements(tmp_path):
    batch = [
        _result("a.qif", [("T2", 0.2, "PASS", 1.0)]),
        _result("b.qif", [("T1", 0.8, "PASS", 0.5), ("T2", 0.4, "PASS", 1.0)]),
        _result("c.qif", [("T1", None, "NOT_ANALYZED", 0.5), ("T2", 0.9, "FAIL", 1.0)], "FAIL"),
        _result("d.qif", [("T2", None, "NOT_ANALYZED", 1.0)], "UNKNOWN"),
    ]
    t2, t1 = summarize(batch)
    assert (t2.designator, t1.designator) == ("T2", "T1")
    assert (t2.count, t2.n_pass, t2.n_fail, t2.n_other) == (3, 2, 1, 1)
    assert t2.mean == pytest.approx(0.5)
    assert t2.std == pytest.approx(math.sqrt(((0.3**2) + (0.1**2) + (0.4**2)) / 2))
    assert (t2.min, t2.max, t2.n_out_of_tolerance) == (0.2, 0.9, 0)
    assert t2.cp is None and t2.cpk == pytest.approx((1.0 - 0.5) / (3 * t2.std))
    # one value: no deviation, no Cpk; the value is above the tolerance
    assert (t1.count, t1.mean, t1.n_out_of_tolerance, t1.cpk) == (1, 0.8, 1, None)
    assert math.isnan(t1.std) and (t1.n_pass, t1.n_other) == (1, 1)

    path = tmp_path / "stats.qif"
    write_statistics(path, build_statistics(batch, part_name="synthetic", created=CREATED))
    rep = validate(path, strict=True, checks=True)
    assert not rep.errors(), rep.format()
    doc = etree.parse(str(path)).getroot()
    stats = _stats_by_designator(doc)
    assert list(stats) == ["T2", "T1"]
    excl = _xp(stats["T2"], "q:MeasuredIds/q:Exclusions/q:Exclusion")
    assert len(excl) == 1
    assert _one(excl[0], "q:Reason/q:OtherExclusionReason/text()") == NO_VALUE_REASON
    m = _one(
        doc, f"//q:SurfaceProfileCharacteristicMeasurement[@id='{_one(excl[0], 'q:Id/text()')}']"
    )
    assert _xp(m, "q:Value") == []
    assert _num(stats["T2"], "q:ValueStats/q:TotalNumber/q:Value/text()") == 4
    assert _num(stats["T2"], "q:ValueStats/q:EffectiveNumber/q:Value/text()") == 3
    t1_values = _one(stats["T1"], "q:ValueStats")
    assert _xp(t1_values, "q:StandardDeviation | q:Cpk") == []
    assert _num(t1_values, "q:NumberOutOfTolerance/q:Value/text()") == 1
    assert _xp(stats["T1"], "q:CapabilityCalculationMethod") == []
    # inspection times in UTC (12:00:05+01:00 is 11:00:05Z)
    trace = _one(doc, "//q:CapabilityStudyResults/q:InspectionTraceability")
    assert _one(trace, "q:InspectionStart/text()") == "2026-01-01T10:00:00Z"
    assert _one(trace, "q:InspectionEnd/text()") == "2026-01-01T11:00:05Z"


def test_rejects_what_it_cannot_write():
    ok = _result("a.qif", [("T1", 0.2, "PASS", 1.0)])
    with pytest.raises(ValueError, match="no inspection results"):
        build_statistics([], part_name="p", created=CREATED)
    with pytest.raises(ValueError, match="2 sources for 1 results"):
        build_statistics([ok], part_name="p", created=CREATED, sources=["a.qif", "b.qif"])
    with pytest.raises(ValueError, match="without a QPId"):
        build_statistics([ok], part_name="p", created=CREATED, sources=["a.qif"])
    with pytest.raises(ValueError, match="tolerance"):
        summarize([ok, _result("b.qif", [("T1", 0.2, "PASS", 2.0)])])
    # a feature characteristic (issue 22) is not carried by the Statistics document yet:
    # left out, never written as a profile
    flat = _result("c.qif", [("F1", 0.1, "PASS", 0.2), ("T1", 0.2, "PASS", 1.0)])
    flat.characteristics[0].kind = "Flatness"
    doc = etree.tostring(build_statistics([flat], part_name="p", created=CREATED, sources=None))
    assert b"F1" not in doc and b"T1" in doc
    other = _result("d.qif", [("T1", 0.2, "PASS", 1.0)])
    other.attributes["nominal_sha256"] = "0" * 64
    with pytest.raises(ValueError, match="another nominal"):
        build_statistics([other], part_name="p", created=CREATED, nominal_sha256="1" * 64)
