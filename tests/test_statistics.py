"""The QIF 3.0 statistics document of a batch (qif/statistics.py).

Three inspections of the shell sample by the real command line (a passing scan, a scan with a
bump that fails, and the passing scan rigidly aligned only), read back, summarised and written
as one statistics document beside them. The document is validated by every validator of the
project and by the independent consumers, and its numbers, read with plain lxml XPath, are
checked against the values read, likewise, from the per-scan documents (``statistics`` of the
standard library, not numpy, computes the expectations).

The feature characteristics (issue 22): four results documents whose flatness, position,
per-unit-area flatness, diameter, angle and basic dimension are written by the product's own
builders with values chosen here; their statistics (one-sided for a tolerance, two-sided with
Cp for a dimension, the basic dimension left out) are checked the same way.
"""

from __future__ import annotations

import hashlib
import math
import statistics as pystats
from datetime import datetime, timezone
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from lxml import etree

from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    DocumentRecord,
)
from qifreport.qif.feature_characteristics import kind_of_qif_type, status_from_qif
from qifreport.qif.reader import QIFResults, read_results
from qifreport.qif.statistics import (
    NO_VALUE_REASON,
    build_statistics,
    summarize,
    write_statistics,
)
from qifreport.qif.validate import validate
from tests.consumers import assert_read_by_independent_consumers
from tests.round_trip import assert_same_result

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
    """The three per-scan QIF files (``<run>/shell_nominal_<run>.qif``: named with their
    serial numbers), the statistics document ``statistics.qif`` beside their folders, and
    what was read back."""
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
    sources = [f"{name}/shell_nominal_{name}.qif" for name, _, _ in RUNS]
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
    """A read-back results document: ``chars`` = (designator, value, QIF status,
    tolerance)."""
    kind = kind_of_qif_type("SurfaceProfile")[0]
    cs = [
        CharacteristicResult(
            CharacteristicSpec(
                key=d,
                kind=kind,
                name=f"profile {d}",
                step_id=None,
                faces=np.zeros(0),
                tolerance=tol,
            ),
            value=v,
            status=status_from_qif(st),
            worst_positive=None if v is None else v / 2,
            worst_negative=None if v is None else -v / 4,
            document=DocumentRecord(type="SurfaceProfile", id=str(10 + k), status=st),
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
    # a feature characteristic whose results document (its definition) cannot be read is
    # left out (test_unreadable_feature_source_left_out), never written as a profile
    flat = _result("c.qif", [("F1", 0.1, "PASS", 0.2), ("T1", 0.2, "PASS", 1.0)])
    flat.characteristics[0].document.type = "Flatness"
    doc = etree.tostring(build_statistics([flat], part_name="p", created=CREATED, sources=None))
    assert b"F1" not in doc and b"T1" in doc
    other = _result("d.qif", [("T1", 0.2, "PASS", 1.0)])
    other.attributes["nominal_sha256"] = "0" * 64
    with pytest.raises(ValueError, match="another nominal"):
        build_statistics([other], part_name="p", created=CREATED, nominal_sha256="1" * 64)


# ------------------------------------------------------------------ feature characteristics
#
# Results documents whose feature characteristics (issue 22) are written by the product's own
# builders (qif/feature_characteristics.py), as a results document holds them; the values,
# limits and statuses are chosen here, so the expectations are known independently.

#: designator -> the fields of its CharacteristicSpec (a basic dimension, D3, has no limits)
FEATURES = {
    "G1": dict(kind="flatness", tolerance=0.2),
    "G2": dict(
        kind="position",
        tolerance=0.5,
        datums=["A", "B"],
        datum_materials=["NONE", "NONE"],
        zone_form="cylindrical",
    ),
    "G3": dict(kind="flatness", tolerance=0.05, unit_basis="per rectangular area 25 mm x 25 mm"),
    "D1": dict(
        kind="dimension", dim_type="diameter", nominal=10.0, lower_limit=9.9, upper_limit=10.1
    ),
    "D2": dict(
        kind="dimension",
        dim_type="angular",
        unit="deg",
        nominal=90.0,
        lower_limit=89.5,
        upper_limit=90.5,
        origin_faces=np.array([1]),
        target_faces=np.array([2]),
    ),
    "D3": dict(
        kind="dimension",
        dim_type="linear distance",
        nominal=42.0,
        basic=True,
        origin_faces=np.array([1]),
        target_faces=np.array([3]),
    ),
}
#: per inspection, (value, status) of each feature characteristic: D1 sits low in its
#: limits (its lower side decides Cpk) and fails below them once; G1 is INDETERMINATE once;
#: G2 is not measured once (no value: an exclusion)
FEATURE_RUNS = [
    {
        "G1": (0.12, "PASS"),
        "G2": (0.21, "PASS"),
        "G3": (0.031, "PASS"),
        "D1": (9.92, "PASS"),
        "D2": (90.12, "PASS"),
        "D3": (42.013, "BASIC"),
    },
    {
        "G1": (0.19, "INDETERMINATE"),
        "G2": (None, "NOT_MEASURED"),
        "G3": (0.044, "PASS"),
        "D1": (9.94, "PASS"),
        "D2": (89.93, "PASS"),
        "D3": (41.995, "BASIC"),
    },
    {
        "G1": (0.08, "PASS"),
        "G2": (0.33, "PASS"),
        "G3": (0.052, "FAIL"),
        "D1": (9.97, "PASS"),
        "D2": (90.61, "FAIL"),
        "D3": (42.004, "BASIC"),
    },
    {
        "G1": (0.15, "PASS"),
        "G2": (0.28, "PASS"),
        "G3": (0.038, "PASS"),
        "D1": (9.89, "FAIL"),
        "D2": (90.02, "PASS"),
        "D3": (42.02, "BASIC"),
    },
]
STATUS_QIF = {
    "PASS": "PASS",
    "FAIL": "FAIL",
    "INDETERMINATE": "INDETERMINATE",
    "NOT_MEASURED": "NOT_ANALYZED",
    "BASIC": "BASIC_OR_TED",
}


def _feature_measured(run: dict, serial: str) -> list[CharacteristicResult]:
    """The feature characteristics of ``FEATURES`` measured as ``run`` says."""
    out = []
    for k, (key, fields) in enumerate(FEATURES.items()):
        spec = CharacteristicSpec(
            key=key, name=f"item_{key}", step_id=100 + k, faces=np.array([k]), **fields
        )
        value, status = run[key]
        out.append(
            CharacteristicResult(
                spec,
                value=value,
                uncertainty=None if value is None else 0.004,
                status=status,
                reason="not seen" if status == "NOT_MEASURED" else "",
                reading="" if value is None else f"scan {serial}: 1,234 vertices",
                n_points=0 if value is None else 1234,
            )
        )
    return out


def _feature_results(path: Path, run: dict, serial: str) -> Path:
    """A results document with the feature characteristics of ``FEATURES`` measured as
    ``run`` says, written with the product's builders."""
    from qifreport.qif.definitions import Sections
    from qifreport.qif.feature_characteristics import (
        characteristic_definition,
        characteristic_measurement,
    )
    from qifreport.qif.xmlkit import E, Ids, id_array, qpid

    ids, zs = Ids(), Sections()
    actual_id, std_id, mr_id = ids(), ids(), ids()
    meas = []
    for c in _feature_measured(run, serial):
        spec = c.spec
        _, ci, fm = characteristic_definition(zs, spec, ids, {}, result=c, actual_id=actual_id)
        meas.append(characteristic_measurement(c, ids, ci, fm, actual_id))
    fail = any(s == "FAIL" for _, s in run.values())
    root = E.QIFDocument(
        E.QPId(qpid()),
        E.Header(E.Application(E.Name("qifreport"))),
        zs.features(),
        zs.characteristics(std_id),
        E.Results(
            E.MeasurementResultsSet(
                E.MeasurementResults(
                    E.InspectionTraceability(E.InspectionStart("2026-02-01T08:00:00Z")),
                    E.MeasuredCharacteristics(
                        E.CharacteristicMeasurements(*meas, n=str(len(meas)))
                    ),
                    E.InspectionStatus(E.InspectionStatusEnum("FAIL" if fail else "PASS")),
                    id_array("ActualComponentIds", [actual_id]),
                    id=mr_id,
                ),
                n="1",
            ),
        ),
        versionQIF="3.0.0",
        idMax=str(ids.max),
    )
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    return path


def _measurements(path: Path) -> dict[str, dict]:
    """Per designator, a per-scan document's feature measurement read by XPath: value,
    status, kind, and the limits its definition (and nominal) states."""
    root = etree.parse(str(path)).getroot()
    out = {}
    for m in _xp(root, "//q:CharacteristicMeasurements/*"):
        kind = etree.QName(m).localname.removesuffix("CharacteristicMeasurement")
        item = _one(root, f"//*[@id='{_one(m, 'q:CharacteristicItemId/text()')}']")
        nominal = _one(root, f"//*[@id='{_one(item, 'q:CharacteristicNominalId/text()')}']")
        definition = _one(
            root, f"//*[@id='{_one(nominal, 'q:CharacteristicDefinitionId/text()')}']"
        )
        value = _xp(m, "q:Value/text()")
        target = _xp(nominal, "q:TargetValue/text()")
        hi = _xp(definition, "q:Tolerance/q:MaxValue/text()")
        lo = _xp(definition, "q:Tolerance/q:MinValue/text()")
        tol = _xp(definition, "q:ToleranceValue/text() | .//q:ToleranceValuePerUnit/text()")
        out[_one(item, "q:CharacteristicDesignator/q:Designator/text()")] = dict(
            id=m.get("id"),
            kind=kind,
            value=float(value[0]) if value else None,
            status=_one(m, "q:Status/q:CharacteristicStatusEnum/text()"),
            tolerance=float(tol[0]) if tol else None,
            upper=float(target[0]) + float(hi[0]) if hi else None,
            lower=float(target[0]) + float(lo[0]) if lo else None,
        )
    return out


def _all_stats(doc) -> dict[str, etree._Element]:
    """Each ``*CharacteristicStats`` of the study by the designator of the items its
    measurements measure (followed through the ids)."""
    out = {}
    for st in _xp(doc, "//q:CapabilityStudyResults/q:CharacteristicsStats/*"):
        designators = set()
        for mid in _xp(st, "q:MeasuredIds/q:Ids/q:Id/text()"):
            m = _one(doc, f"//q:CharacteristicMeasurements/*[@id='{mid}']")
            item = _one(doc, f"//*[@id='{_one(m, 'q:CharacteristicItemId/text()')}']")
            designators.add(_one(item, "q:CharacteristicDesignator/q:Designator/text()"))
        (key,) = designators
        out[key] = st
    return out


@pytest.fixture(scope="module")
def features(tmp_path_factory):
    """Four inspections with feature characteristics, their statistics document, what was
    read back and the log of leaving out the basic dimension."""
    import logging

    d = tmp_path_factory.mktemp("features")
    paths = [
        _feature_results(d / f"scan_{k}.qif", run, f"S{k}") for k, run in enumerate(FEATURE_RUNS)
    ]
    results = [read_results(p) for p in paths]
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append
    logger = logging.getLogger("qifreport.statistics")
    logger.addHandler(handler)
    old = logger.level
    logger.setLevel(logging.INFO)
    try:
        tree = build_statistics(
            results,
            part_name="bracket",
            created=CREATED,
            sources=[p.name for p in paths],
            software_version="9.9.9",
        )
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
    path = d / "statistics.qif"
    write_statistics(path, tree)
    return SimpleNamespace(
        dir=d,
        path=path,
        paths=paths,
        results=results,
        doc=etree.parse(str(path)).getroot(),
        log=[r.getMessage() for r in records],
        per_scan=[_measurements(p) for p in paths],
    )


def test_feature_characteristics_read_back_as_written(features):
    """Every feature characteristic written (each status, a per-unit tolerance, dimensions
    with limits and a basic one) is read back as the one type it was written from, field
    by field (:mod:`tests.round_trip`)."""
    for k, (run, res) in enumerate(zip(FEATURE_RUNS, features.results, strict=True)):
        written = _feature_measured(run, f"S{k}")
        assert len(res.characteristics) == len(written)
        for w, r in zip(written, res.characteristics, strict=True):
            # these documents are written without datum reference frames
            w.spec.datums = []
            assert_same_result(w, r)
    statuses = {c.status for res in features.results for c in res.characteristics}
    assert statuses == {"PASS", "FAIL", "INDETERMINATE", "NOT_MEASURED", "BASIC"}


def test_feature_statistics_valid(features):
    rep = validate(features.path, strict=True, checks=True)
    assert not rep.errors(), rep.format()
    # every measured kind has its own typed statistics, the basic dimension none
    kinds = {key: etree.QName(st).localname for key, st in _all_stats(features.doc).items()}
    assert kinds == {
        "G1": "FlatnessCharacteristicStats",
        "G2": "PositionCharacteristicStats",
        "G3": "FlatnessCharacteristicStats",
        "D1": "DiameterCharacteristicStats",
        "D2": "AngleBetweenCharacteristicStats",
    }
    assert not _xp(features.doc, "//*[q:CharacteristicDesignator/q:Designator='D3']")
    assert any("D3" in m and "basic" in m for m in features.log), features.log
    # degrees are declared for the angle
    assert _xp(features.doc, "q:FileUnits/q:PrimaryUnits/q:AngularUnit/q:UnitName/text()") == [
        "degree"
    ]


def test_feature_statistics_equal_the_per_scan_values(features):
    stats = _all_stats(features.doc)
    for key, st in stats.items():
        runs = [scan[key] for scan in features.per_scan]
        values = [r["value"] for r in runs if r["value"] is not None]
        statuses = [r["status"] for r in runs]
        assert values == [v for v in (run[key][0] for run in FEATURE_RUNS) if v is not None]
        vs = _one(st, "q:ValueStats")
        attrs = {a.get("name"): a.get("value") for a in _xp(st, "q:Attributes/*")}
        assert attrs["designator"] == key
        assert int(attrs["n_pass"]) == statuses.count("PASS")
        assert int(attrs["n_fail"]) == statuses.count("FAIL")
        assert _num(vs, "q:TotalNumber/q:Value/text()") == len(runs)
        assert _num(vs, "q:EffectiveNumber/q:Value/text()") == len(values)
        mean, sd = pystats.fmean(values), pystats.stdev(values)
        assert _num(vs, "q:Average/q:Value/text()") == pytest.approx(mean, rel=1e-12)
        assert _num(vs, "q:StandardDeviation/q:Value/text()") == pytest.approx(sd, rel=1e-12)
        assert (_num(vs, "q:Minimum/q:Value/text()"), _num(vs, "q:Maximum/q:Value/text()")) == (
            min(values),
            max(values),
        )
        if key.startswith("G"):  # one-sided: 0 .. tolerance
            tol = runs[0]["tolerance"]
            above = [v for v in values if v > tol]
            assert _num(vs, "q:NumberOutOfTolerance/q:Value/text()") == len(above)
            assert _num(vs, "q:Cpk/q:Value/text()") == pytest.approx(
                (tol - mean) / (3 * sd), rel=1e-12
            )
            assert _xp(vs, "q:Cp | q:NumberUnderLowerTolerance") == []
            assert _one(st, "q:CapabilityCalculationMethod/text()") == "THREE_SIGMA"
        else:  # two-sided: between the limits the definition states about the nominal
            lo, hi = runs[0]["lower"], runs[0]["upper"]
            over = [v for v in values if v > hi]
            under = [v for v in values if v < lo]
            assert _num(vs, "q:NumberOverUpperTolerance/q:Value/text()") == len(over)
            assert _num(vs, "q:NumberUnderLowerTolerance/q:Value/text()") == len(under)
            assert _num(vs, "q:NumberOutOfTolerance/q:Value/text()") == len(over) + len(under)
            assert _num(vs, "q:Cp/q:Value/text()") == pytest.approx((hi - lo) / (6 * sd), rel=1e-12)
            cpk = min(hi - mean, mean - lo) / (3 * sd)
            assert _num(vs, "q:Cpk/q:Value/text()") == pytest.approx(cpk, rel=1e-12)
            assert _xp(st, "q:CapabilityCalculationMethod") == []
    # the position not measured once: its measurement excluded, named
    excl = _xp(stats["G2"], "q:MeasuredIds/q:Exclusions/q:Exclusion/q:Id/text()")
    assert len(excl) == 1
    m = _one(features.doc, f"//q:PositionCharacteristicMeasurement[@id='{excl[0]}']")
    assert _one(m, "q:Status/q:CharacteristicStatusEnum/text()") == "NOT_ANALYZED"
    # the per-unit-area flatness is judged against its tolerance per unit (0.05)
    assert features.per_scan[0]["G3"]["tolerance"] == 0.05
    assert _num(stats["G3"], "q:ValueStats/q:NumberOutOfTolerance/q:Value/text()") == 1


def test_a_wrong_capability_would_be_caught(features):
    """D1 sits low between its limits: its lower side decides Cpk (an upper-only index, or
    Cpk for Cp, would fail); one value below the lower limit, none above."""
    stats = _all_stats(features.doc)
    vs = _one(stats["D1"], "q:ValueStats")
    values = [scan["D1"]["value"] for scan in features.per_scan]
    mean, sd = pystats.fmean(values), pystats.stdev(values)
    assert (10.1 - mean) / (3 * sd) > 2 * _num(vs, "q:Cpk/q:Value/text()")
    assert _num(vs, "q:Cp/q:Value/text()") > 1.5 * _num(vs, "q:Cpk/q:Value/text()")
    assert _num(vs, "q:NumberUnderLowerTolerance/q:Value/text()") == 1
    assert _num(vs, "q:NumberOverUpperTolerance/q:Value/text()") == 0
    (under,) = _xp(vs, "q:NumberUnderLowerTolerance/q:Ids/q:Id/text()")
    m = _one(features.doc, f"//q:DiameterCharacteristicMeasurement[@id='{under}']")
    assert _num(m, "q:Value/text()") == 9.89


def test_feature_definitions_copied(features):
    doc = features.doc
    pos = _one(doc, "//q:PositionCharacteristicDefinition")
    # as the results document has it, but without the frame this document has no datums for
    assert _one(pos, "q:MaterialCondition/text()") == "NONE"
    assert _xp(pos, "q:ZoneShape/q:DiametricalZone")
    assert _xp(pos, "q:DatumReferenceFrameId") == []
    assert _num(pos, "q:ToleranceValue/text()") == 0.5
    # the description says what the characteristic is, not how one scan was read
    assert _one(pos, "q:Description/text()") == "position 0.5 mm |A|B| (pmi #101)"
    dia = _one(doc, "//q:DiameterCharacteristicDefinition")
    assert (
        _num(dia, "q:Tolerance/q:MaxValue/text()"),
        _num(dia, "q:Tolerance/q:MinValue/text()"),
    ) == (
        0.1,
        -0.1,
    )
    nom = _one(
        doc, f"//q:DiameterCharacteristicNominal[q:CharacteristicDefinitionId='{dia.get('id')}']"
    )
    assert _num(nom, "q:TargetValue/text()") == 10.0
    feature = _one(
        doc, f"//q:OtherSurfaceFeatureNominal[@id='{_one(nom, 'q:FeatureNominalIds/q:Id/text()')}']"
    )
    assert _one(feature, "q:Name/text()") == "FEATURE_D1"
    assert _one(doc, "//q:AngleBetweenCharacteristicNominal/q:AnalysisMode/text()") == (
        "THREEDIMENSIONAL"
    )
    # the measurements are copies of the per-scan ones, traced to them
    mrs = _xp(doc, "q:Results/q:MeasurementResultsSet/q:MeasurementResults")
    for mr, scan in zip(mrs, features.per_scan, strict=True):
        copies = _xp(mr, ".//q:CharacteristicMeasurements/*")
        assert len(copies) == 5  # the basic dimension is not carried
        for c in copies:
            source = _one(c, "q:Attributes/q:AttributeStr[@name='source_id']/@value")
            (orig,) = [m for m in scan.values() if m["id"] == source]
            assert etree.QName(c).localname == f"{orig['kind']}CharacteristicMeasurement"
            assert _one(c, "q:Status/q:CharacteristicStatusEnum/text()") == orig["status"]
            value = _xp(c, "q:Value/text()")
            assert (float(value[0]) if value else None) == orig["value"]


def test_summarize_feature_characteristics(features):
    by_key = {s.designator: s for s in summarize(features.results)}
    assert list(by_key) == ["G1", "G2", "G3", "D1", "D2"]
    d1, d2, g1 = by_key["D1"], by_key["D2"], by_key["G1"]
    assert (d1.kind, d1.lower, d1.upper, d1.nominal, d1.unit) == ("Diameter", 9.9, 10.1, 10.0, "mm")
    assert d1.tolerance is None and d1.two_sided
    assert d1.cp == pytest.approx(0.2 / (6 * d1.std))
    assert d1.cpk == pytest.approx((d1.mean - 9.9) / (3 * d1.std))
    assert (d1.n_below, d1.n_above, d1.n_out_of_tolerance) == (1, 0, 1)
    assert (d2.kind, d2.unit, d2.n_above, d2.n_fail) == ("AngleBetween", "deg", 1, 1)
    assert (g1.kind, g1.tolerance, g1.upper, g1.lower, g1.cp) == ("Flatness", 0.2, 0.2, None, None)
    assert g1.n_other == 1  # the INDETERMINATE one
    assert g1.description == "flatness 0.2 mm (pmi #100)"
    assert by_key["G2"].count == 3 and by_key["G2"].n_other == 1


def test_unreadable_feature_source_left_out(tmp_path, caplog):
    """A feature characteristic whose results document cannot be read (its definition is
    needed) is left out, logged; the profiles are still written."""
    flat = _result(str(tmp_path / "gone.qif"), [("F1", 0.1, "PASS", 0.2), ("T1", 0.2, "PASS", 1.0)])
    flat.characteristics[0].document.type = "Flatness"
    with caplog.at_level("INFO", logger="qifreport.statistics"):
        doc = etree.tostring(build_statistics([flat], part_name="p", created=CREATED))
    assert b"F1" not in doc and b"T1" in doc
    assert any("F1" in r.getMessage() and "gone.qif" in r.getMessage() for r in caplog.records)
