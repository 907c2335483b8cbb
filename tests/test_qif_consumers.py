"""Software we did not write reads QIF 3.0 files: PyXB (a binding generated from the official
XSDs) and Xerces-C (``DOMCount``, a full XSD validator with key/keyref), over the shared
sample corpus; both reject corrupted copies; and where the two disagree with the XSD spec.

The PyXB binding is generated once per session (``pyxb_qif`` in conftest.py, about 20 s).
"""

from __future__ import annotations

import re
from decimal import Decimal
from pathlib import Path

import pytest
from lxml import etree

from tests.conftest import shared_file
from tests.consumers import (
    DOMCOUNT_ERROR_EXIT,
    DSIG_LOCAL,
    DSIG_REMOTE,
    QIF_NS,
    assert_read_by_independent_consumers,
    local_xsd_copy,
    pyxb_read,
    shared_xsd_dir,
    with_schema_location,
    xerces_validate,
)

S = "qif/samples/"
C = "qif/samples/community/"
MITUTOYO = C + "mitutoyo_results_serialized_pass_fail_sample.QIF"
STATISTICS = C + "Exploded_Statistics.QIF"
POINTS = C + "QIF_PTS_SAMPLE.QIF"

#: a representative corpus: the four top-level samples (plan and results from commercial
#: and reference software) and community files of every kind (results with point sets, a
#: pass/fail-only results file, a statistics document, plans, 6-sample results with UUIDs,
#: a document written by a Python tool)
CORPUS = [
    S + "QIF_Results_Sample.QIF",
    S + "SheetMetal_QIF_Results_sample_1.QIF",
    S + "WIDGET_QIF_PLAN.QIF",
    S + "WIDGET_QIF_RESULTS.QIF",
    MITUTOYO,
    POINTS,
    STATISTICS,
    C + "All-in-one.QIF",
    C + "Exploded_Plan.QIF",
    C + "SheetMetal_QIF_Results_6_samples_w_UUIDs.QIF",
    C + "WIDGET_QIF_RESULTS_W_QPIDS.QIF",
    C + "testPython30.qif",
]
#: Both consumers accept every corpus file (checked on all 30 files of qif/samples). Note
#: that xmlschema 4.3 reports FeatureItemIdKeyref errors on 23 of them (all with
#: FeatureItemIds), which Xerces-C and libxml2 accept: the keyref is satisfied.
PYXB_REJECTS: dict[str, str] = {}
XERCES_REJECTS: dict[str, str] = {}


def _name(rel: str) -> str:
    return rel.rsplit("/", 1)[-1]


# ------------------------------------------------------------------------ corpus, PyXB


@pytest.mark.parametrize("rel", CORPUS, ids=_name)
def test_pyxb_reads_corpus(rel, pyxb_qif):
    path = shared_file(rel)
    if rel in PYXB_REJECTS:
        with pytest.raises(Exception, match=PYXB_REJECTS[rel]):
            pyxb_read(pyxb_qif, path)
        return
    root = pyxb_read(pyxb_qif, path)
    assert isinstance(root, pyxb_qif.QIFDocumentType)
    assert root.versionQIF == "3.0.0"
    assert root.idMax >= 1


def test_pyxb_reads_typed_values(pyxb_qif):
    """Not only accepted: values come back typed as the XSD says."""
    doc = pyxb_read(pyxb_qif, shared_file(MITUTOYO))
    results = doc.Results.MeasurementResultsSet.MeasurementResults[0]
    assert results.InspectionStatus.InspectionStatusEnum == "PASS"
    component = doc.Results.ActualComponentSets.ActualComponentSet[0].ActualComponent[0]
    assert component.SerialNumber == "SN#1234-56789"
    assert list(doc.Product.PartSet.Part[0].originMassProperty) == [1.0, 2.0, 0.0]

    # measured point sets: a list of doubles, 3 per point, as many points as `count` says
    doc = pyxb_read(pyxb_qif, shared_file(POINTS))
    sets = doc.Results.MeasurementResultsSet.MeasurementResults[0].MeasuredPointSets
    assert sets.n == len(sets.MeasuredPointSet) == 12
    for ps in sets.MeasuredPointSet:
        assert len(ps.Points) == 3 * ps.count
        assert all(isinstance(v, float) for v in ps.Points)
    assert sets.MeasuredPointSet[0].Points[:3] == [3.54516458565, 0.0037440421, -1.82916012241]

    # statistics: decimals stay exact
    doc = pyxb_read(pyxb_qif, shared_file(STATISTICS))
    (study,) = [c.value for c in doc.Statistics.StatisticalStudiesResults.orderedContent()]
    assert study.NumberOfSamples == 2
    stats = [c.value for c in study.CharacteristicsStats.orderedContent()]
    average = stats[0].ValueStats.orderedContent()[0].value
    assert average.Value.value() == Decimal("25.3441663869135")  # xs:decimal, exact


# ---------------------------------------------------------------------- corpus, Xerces-C


@pytest.mark.parametrize("rel", CORPUS, ids=_name)
def test_xerces_validates_corpus(rel, qif_xsd):
    res = xerces_validate(shared_file(rel), qif_xsd)
    if rel in XERCES_REJECTS:
        assert res.returncode == DOMCOUNT_ERROR_EXIT
        assert any(XERCES_REJECTS[rel] in e for e in res.errors), res.output
        return
    assert res.ok, "\n".join(res.errors + res.warnings)
    assert res.returncode == 0 and "elems)" in res.output  # DOMCount's "N ms (M elems)."


def test_assert_read_by_independent_consumers(pyxb_qif, qif_xsd):
    assert_read_by_independent_consumers(shared_file(MITUTOYO), pyxb_qif, qif_xsd)


# ------------------------------------------------------------------------------ negatives


def _corrupt(tmp_path: Path, rel: str, old: str, new, *, flags=0) -> Path:
    """A copy of a shared sample with the first match of regex ``old`` replaced by ``new``
    (a ``re.sub`` replacement: string or function); the pattern must match."""
    text = shared_file(rel).read_text(encoding="utf-8")
    out, n = re.subn(old, new, text, count=1, flags=flags)
    assert n == 1, f"{old!r} not in {rel}"
    p = tmp_path / _name(rel)
    p.write_text(out, encoding="utf-8")
    return p


#: corruptions each consumer must reject: (sample, regex, replacement, PyXB exception and
#: message, Xerces-C message)
CORRUPTIONS = {
    # InspectionStatus is required in MeasurementResults
    "missing-required-element": (
        MITUTOYO,
        r"\s*<InspectionStatus>.*?</InspectionStatus>",
        "",
        ("UnrecognizedContentError", "Invalid content .*ActualComponentIds"),
        "element 'ActualComponentIds' is not allowed for content model",
    ),
    "bad-enumeration": (
        MITUTOYO,
        r"<InspectionStatusEnum>PASS<",
        "<InspectionStatusEnum>PASSED<",
        ("SimpleFacetValueError", "enumeration constraint violated by value PASSED"),
        "value 'PASSED' not in enumeration",
    ),
    "bad-decimal": (
        STATISTICS,
        r"25\.3441663869135",
        "25,3441663869135",
        ("SimpleTypeValueError", r"decimal cannot be created from: 25,3441663869135"),
        "invalid character encountered",
    ),
    "bad-list-length": (
        MITUTOYO,
        r'originMassProperty="1 2 0"',
        'originMassProperty="1 2"',
        ("SimpleFacetValueError", "length"),
        "has length '2' which is not equal to length facet value '3'",
    ),
    "wrong-element-order": (
        MITUTOYO,
        r"(<ThisResultsInstanceQPId>.*?</ThisResultsInstanceQPId>)(\s*)"
        r"(<InspectionStatus>.*?</InspectionStatus>)",
        r"\3\2\1",
        ("UnrecognizedContentError", "Invalid content .*ThisResultsInstanceQPId"),
        "element 'ThisResultsInstanceQPId' is not allowed for content model",
    ),
}


@pytest.mark.parametrize("case", CORRUPTIONS)
def test_pyxb_rejects_corrupted(case, tmp_path, pyxb_qif, qif_xsd):
    import pyxb

    rel, old, new, (exc, msg), _ = CORRUPTIONS[case]
    path = _corrupt(tmp_path, rel, old, new, flags=re.S)
    with pytest.raises(pyxb.ValidationError, match=msg) as e:
        pyxb_read(pyxb_qif, path)
    assert type(e.value).__name__ == exc
    with pytest.raises(AssertionError, match=f"(?s)PyXB rejects .*{exc}"):
        assert_read_by_independent_consumers(path, pyxb_qif, qif_xsd)


@pytest.mark.parametrize("case", CORRUPTIONS)
def test_xerces_rejects_corrupted(case, tmp_path, qif_xsd):
    rel, old, new, _, msg = CORRUPTIONS[case]
    path = _corrupt(tmp_path, rel, old, new, flags=re.S)
    rc, output, errors, warnings = xerces_validate(path, qif_xsd)
    assert rc == DOMCOUNT_ERROR_EXIT, output
    assert len(errors) == 1 and msg in errors[0], output
    assert errors[0].startswith("line ") and str(path) in output


def test_xerces_checks_keyrefs_pyxb_does_not(tmp_path, pyxb_qif, qif_xsd):
    """A dangling id reference (ActualComponentIds/Id -> no ActualComponent 99): only
    Xerces-C sees it; PyXB does not implement identity constraints."""
    path = _corrupt(tmp_path, MITUTOYO, r"<Id>3</Id>", "<Id>99</Id>")
    assert isinstance(pyxb_read(pyxb_qif, path), pyxb_qif.QIFDocumentType)
    res = xerces_validate(path, qif_xsd)
    assert res.returncode == DOMCOUNT_ERROR_EXIT
    assert len(res.errors) == 1, res.output
    assert "identity constraint key for element 'Results' not found" in res.errors[0]
    with pytest.raises(AssertionError, match="(?s)Xerces-C rejects .*identity constraint"):
        assert_read_by_independent_consumers(path, pyxb_qif, qif_xsd)


#: lexical forms on which the consumers differ (the XSD verdict is Xerces-C's, which agrees
#: with libxml2): PyXB converts with Python's Decimal/float/datetime, so it accepts what
#: Python accepts (exponents and underscores in xs:decimal, "+INF") and rejects what
#: datetime cannot hold (hour 24, year 0 or > 9999). Our writer must avoid all of these.
_START = "<ThisResultsInstanceQPId>"
_TRACE = "<InspectionTraceability><InspectionStart>{}</InspectionStart></InspectionTraceability>"
LEXICAL = {
    # name: (sample, old, new, PyXB accepts, Xerces-C accepts)
    "decimal-exponent": (STATISTICS, "25.3441663869135", "2.5e1", True, False),
    "decimal-underscore": (STATISTICS, "25.3441663869135", "25_3", True, False),
    "double-plus-INF": (MITUTOYO, '"1 2 0"', '"+INF 2 0"', True, False),
    "dateTime-hour-24": (
        MITUTOYO,
        _START,
        _TRACE.format("2024-05-01T24:00:00Z") + _START,
        False,
        True,
    ),
    "dateTime-nanoseconds": (
        MITUTOYO,
        _START,
        _TRACE.format("2024-05-01T10:00:00.123456789Z") + _START,
        True,
        True,
    ),
}


@pytest.mark.parametrize("case", LEXICAL)
def test_lexical_edge_cases(case, tmp_path, pyxb_qif, qif_xsd):
    import pyxb

    rel, old, new, pyxb_ok, xerces_ok = LEXICAL[case]
    path = _corrupt(tmp_path, rel, re.escape(old), lambda _m: new)
    try:
        pyxb_read(pyxb_qif, path)
        pyxb_accepts = True
    except (pyxb.PyXBException, ValueError):  # ValueError: from datetime
        pyxb_accepts = False
    assert pyxb_accepts is pyxb_ok
    assert xerces_validate(path, qif_xsd).ok is xerces_ok


# ------------------------------------------------------------------------ the plumbing


def test_local_xsd_copy_changes_only_the_dsig_import(tmp_path):
    src = shared_xsd_dir()
    xsd = local_xsd_copy(tmp_path / "xsd")
    assert xsd == tmp_path / "xsd" / "QIFApplications" / "QIFDocument.xsd"
    copied = {p.relative_to(tmp_path / "xsd") for p in (tmp_path / "xsd").rglob("*") if p.is_file()}
    original = {p.relative_to(src) for p in src.rglob("*") if p.is_file()}
    assert copied == original | {Path(DSIG_LOCAL)}
    for rel in original - {Path("QIFApplications/QIFDocument.xsd")}:
        assert (src / rel).read_bytes() == (tmp_path / "xsd" / rel).read_bytes(), rel
    old = (src / "QIFApplications/QIFDocument.xsd").read_text(encoding="utf-8").splitlines()
    new = xsd.read_text(encoding="utf-8").splitlines()
    diff = [(a, b) for a, b in zip(old, new, strict=True) if a != b]
    assert diff == [
        (f'    schemaLocation="{DSIG_REMOTE}"/>', f'    schemaLocation="../{DSIG_LOCAL}"/>')
    ]
    dsig = (tmp_path / "xsd" / DSIG_LOCAL).read_text(encoding="utf-8")
    assert 'targetNamespace="http://www.w3.org/2000/09/xmldsig#"' in dsig
    assert etree.parse(tmp_path / "xsd" / DSIG_LOCAL).docinfo.doctype == ""


def test_with_schema_location_changes_only_that_attribute(tmp_path):
    xsd = tmp_path / "my xsd" / "QIFDocument.xsd"
    uri = xsd.resolve().as_uri()
    assert "%20" in uri
    src = shared_file(MITUTOYO).read_bytes()
    out = with_schema_location(src, xsd)
    old = b'"http://qifstandards.org/xsd/qif3 ../QIFApplications/QIFDocument.xsd"'
    assert out == src.replace(old, f'"{QIF_NS} {uri}"'.encode())

    # no schemaLocation and no xsi declaration: both are added to the root start tag
    bare = (
        b'<?xml version="1.0"?>\n<!-- <QIFDocument> -->\n'
        b"<QIFDocument xmlns='http://qifstandards.org/xsd/qif3' a='x>y'>\n<Id>1</Id>\n"
        b"</QIFDocument>"
    )
    assert with_schema_location(bare, xsd) == bare.replace(
        b"a='x>y'>",
        b"a='x>y' xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" "
        + f'xsi:schemaLocation="{QIF_NS} {uri}">'.encode(),
    )
    # another prefix for the XSI namespace, single quotes, a remote location
    other = (
        b"<QIFDocument xmlns='http://qifstandards.org/xsd/qif3' "
        b"xmlns:i='http://www.w3.org/2001/XMLSchema-instance' "
        b"i:schemaLocation='http://qifstandards.org/xsd/qif3 https://x.org/QIFDocument.xsd'/>"
    )
    assert with_schema_location(other, xsd) == other.replace(
        b"https://x.org/QIFDocument.xsd", uri.encode()
    )
