"""qifreport.qif.validate on the shared QIF 3.0 corpus: lxml, xmlschema, DMSC checks, the CLI.

Real validation throughout (no mocks). The XSDs are compiled once per session (the cache in
qif.validate): lxml in about 0.1 s, xmlschema in about 6-7 s; all 30 samples under both and
the DMSC checks take a few seconds more, so every sample is checked by every validator.

Facts recorded here (xmlschema 4.3.2, libxml2 2.14):

* all 30 samples (4 official, 26 community) are valid under libxml2 and, with the
  substitution-group workaround of qif.validate, under xmlschema;
* stock xmlschema (no workaround) fails 22 of them, all with ``FeatureItemIdKeyref`` (and
  ``FeatureNominalIdKeyref`` on ``testPython30.qif``): false positives, the referenced feature
  items exist (libxml2 and Xerces-C accept the files); it also misses duplicate ids between
  substitution-group members;
* DMSC CheckFormat is clean on every sample except the three community files with a
  Windows-style ``.\\File.QIF`` URI, which libxslt cannot load (Exploded_Results2,
  Exploded_Statistics, Mixed_Exploded_Results1).
"""

from __future__ import annotations

import os
import re
import shutil
from collections import Counter
from pathlib import Path

import pytest
from lxml import etree

from qifreport.qif import dmsc as D
from qifreport.qif import dmsc_report as R
from qifreport.qif.identities import identity_constraints, norm_value
from qifreport.qif.lxml_validator import lxml_schema
from qifreport.qif.validate import (
    Finding,
    SchemasUnavailable,
    ValidationReport,
    checks_dir,
    dmsc_checks,
    schema_dir,
    validate,
    validate_lxml,
    validate_xmlschema,
)
from qifreport.qif.xmlschema_validator import xmlschema_findings, xmlschema_schema
from qifreport.qif.xsd import QIF_NS, REPO_ROOT, dsig_path
from qifreport.validate_command import validate_main
from tests.conftest import SHARED, shared_file

OFFICIAL = [
    "QIF_Results_Sample.QIF",
    "SheetMetal_QIF_Results_sample_1.QIF",
    "WIDGET_QIF_PLAN.QIF",
    "WIDGET_QIF_RESULTS.QIF",
]
COMMUNITY = [
    "All-in-one-form_only.QIF",
    "All-in-one.QIF",
    "Exploded-form_only_Plan.QIF",
    "Exploded_Plan.QIF",
    "Exploded_Results1.QIF",
    "Exploded_Results2.QIF",
    "Exploded_Statistics.QIF",
    "Mixed_Exploded_Results1.QIF",
    "QIF_PTS_SAMPLE.QIF",
    "SheetMetal_QIF_Results_6_samples.QIF",
    "SheetMetal_QIF_Results_6_samples_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_1_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_2.QIF",
    "SheetMetal_QIF_Results_sample_2_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_3.QIF",
    "SheetMetal_QIF_Results_sample_3_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_4.QIF",
    "SheetMetal_QIF_Results_sample_4_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_5.QIF",
    "SheetMetal_QIF_Results_sample_5_w_UUIDs.QIF",
    "SheetMetal_QIF_Results_sample_6.QIF",
    "SheetMetal_QIF_Results_sample_6_w_UUIDs.QIF",
    "WIDGET_QIF_PLAN_W_QPIDS.QIF",
    "WIDGET_QIF_RESULTS_W_QPIDS.QIF",
    "mitutoyo_results_serialized_pass_fail_sample.QIF",
    "testPython30.qif",
]
SAMPLES = [f"qif/samples/{n}" for n in OFFICIAL] + [f"qif/samples/community/{n}" for n in COMMUNITY]

FI = "keyref FeatureItemIdKeyref"
#: stock xmlschema (without qif.validate's workaround): false keyref findings per sample, each
#: at a referencing element (every sample not listed: none). libxml2 passes all of them.
STOCK_XMLSCHEMA = {
    "QIF_Results_Sample.QIF": {FI: 18},
    "SheetMetal_QIF_Results_sample_1.QIF": {FI: 42},
    "WIDGET_QIF_PLAN.QIF": {FI: 28},
    "WIDGET_QIF_RESULTS.QIF": {FI: 47},
    "QIF_PTS_SAMPLE.QIF": {FI: 39},
    "SheetMetal_QIF_Results_6_samples.QIF": {FI: 147},
    "SheetMetal_QIF_Results_6_samples_w_UUIDs.QIF": {FI: 147},
    **{
        f"SheetMetal_QIF_Results_sample_{i}{s}.QIF": {FI: 42}
        for i in range(1, 7)
        for s in ("", "_w_UUIDs")
        if (i, s) != (1, "")
    },
    "WIDGET_QIF_PLAN_W_QPIDS.QIF": {FI: 28},
    "WIDGET_QIF_RESULTS_W_QPIDS.QIF": {FI: 47},
    "testPython30.qif": {FI: 11, "keyref FeatureNominalIdKeyref": 3},
}

_Q = "CheckQuality"
_UV_NG = ("A-AN-UV", "A-AN-NG")
#: DMSC CheckReport per sample: (category, severity, rule) -> count
DMSC = {
    "QIF_Results_Sample.QIF": {(_Q, "warning", r): 16 for r in _UV_NG},
    "WIDGET_QIF_PLAN.QIF": {(_Q, "warning", r): 31 for r in _UV_NG},
    "WIDGET_QIF_RESULTS.QIF": {(_Q, "warning", r): 31 for r in _UV_NG},
    "WIDGET_QIF_PLAN_W_QPIDS.QIF": {(_Q, "warning", r): 31 for r in _UV_NG},
    "WIDGET_QIF_RESULTS_W_QPIDS.QIF": {(_Q, "warning", r): 31 for r in _UV_NG},
    **{
        n: {(_Q, "warning", r): 24 for r in _UV_NG}
        for n in OFFICIAL + COMMUNITY
        if n.startswith("SheetMetal")
    },
    "All-in-one-form_only.QIF": {(_Q, "warning", r): 1 for r in _UV_NG},
    "All-in-one.QIF": {(_Q, "warning", r): 2 for r in _UV_NG},
    "Exploded-form_only_Plan.QIF": {(_Q, "warning", r): 1 for r in _UV_NG},
    "Exploded_Plan.QIF": {(_Q, "warning", r): 2 for r in _UV_NG},
    # the plan it links to (./Exploded_Plan.QIF), reported as CheckDocuments warnings
    "Exploded_Results1.QIF": {("CheckDocuments", "warning", f"{_Q}:{r}"): 2 for r in _UV_NG},
    "Exploded_Results2.QIF": {
        ("CheckFormat", "error", "external-URI"): 1,
        **{("CheckDocuments", "warning", f"{_Q}:{r}"): 2 for r in _UV_NG},
    },
    "Exploded_Statistics.QIF": {
        ("CheckFormat", "error", "external-URI"): 2,
        ("CheckDocuments", "warning", "CheckFormat:external-URI"): 1,
        ("CheckDocuments", "warning", "CheckDocuments:MaxRecursionLevel"): 2,
    },
    "Mixed_Exploded_Results1.QIF": {
        ("CheckFormat", "error", "external-URI"): 1,
        **{(_Q, "warning", r): 1 for r in _UV_NG},
        **{("CheckDocuments", "warning", f"{_Q}:{r}"): 1 for r in _UV_NG},
    },
    "QIF_PTS_SAMPLE.QIF": {(_Q, "warning", r): 25 for r in _UV_NG},
    "mitutoyo_results_serialized_pass_fail_sample.QIF": {},
    "testPython30.qif": {(_Q, "warning", r): 9 for r in _UV_NG},
}


def _fail_or_skip(msg: str) -> None:
    if os.environ.get("CI") == "true":
        pytest.fail(msg)
    pytest.skip(msg)


@pytest.fixture(scope="module")
def xsd() -> Path:
    """The schema folder qif.validate uses (skips, or fails under CI, if there is none)."""
    try:
        return schema_dir()
    except SchemasUnavailable as exc:
        _fail_or_skip(str(exc))
        raise


@pytest.fixture(scope="module")
def checks_available() -> None:
    try:
        checks_dir()
    except SchemasUnavailable as exc:
        _fail_or_skip(str(exc))


def _line_of(text: str, needle: str) -> int:
    i = text.index(needle)
    return text.count("\n", 0, i) + 1


def _corrupt(
    tmp_path: Path, rel: str, old: str, new: str, name: str | None = None
) -> tuple[Path, str]:
    src = shared_file(rel).read_text(encoding="utf-8")
    assert src.count(old) >= 1, old
    out = src.replace(old, new, 1)
    p = tmp_path / (name or Path(rel).name)
    p.write_text(out, encoding="utf-8")
    return p, out


# --------------------------------------------------------------------------------------------
# the corpus


def test_sample_list_is_complete():
    folder = shared_file("qif/samples")
    found = sorted(
        p.relative_to(SHARED).as_posix() for p in folder.rglob("*") if p.suffix.lower() == ".qif"
    )
    assert found == sorted(SAMPLES)
    assert set(DMSC) == set(OFFICIAL + COMMUNITY)


@pytest.mark.parametrize("rel", SAMPLES, ids=[Path(s).name for s in SAMPLES])
def test_samples_valid_under_lxml_and_xmlschema(rel, xsd):
    path = shared_file(rel)
    assert validate_lxml(path) == []
    assert validate_xmlschema(path) == []


@pytest.mark.parametrize("rel", SAMPLES, ids=[Path(s).name for s in SAMPLES])
def test_stock_xmlschema_false_keyrefs(rel, xsd):
    """What xmlschema reports without the workaround: false FeatureItemIdKeyref failures.

    If this fails because stock xmlschema reports nothing, xmlschema has fixed identity
    constraints over substitution groups and ``_register_substitutes`` can go.
    """
    path = shared_file(rel)
    tree = etree.parse(str(path))
    stock = xmlschema_findings(tree, xsd, register_substitutes=False)
    assert dict(Counter(f.rule for f in stock)) == STOCK_XMLSCHEMA.get(path.name, {})
    # every one names an id that the key's own selector does find in the document
    idents = identity_constraints(xsd)
    for f in stock:
        m = re.match(r"value (\S+) not found for key (\w+)", f.message)
        assert m, f
        ns = {"t": QIF_NS}
        key = idents[m.group(2)]
        ids = {norm_value(x) for x in tree.getroot().xpath(f"({key.selector})/@id", namespaces=ns)}
        assert m.group(1) in ids, f"{m.group(1)} really missing from {key.name}"
        assert f.line is not None and f.line > 1


def test_stock_xmlschema_misses_duplicate_ids_of_substitutes(tmp_path, xsd):
    p, text = _corrupt(
        tmp_path,
        "qif/samples/community/All-in-one.QIF",
        '<SphericityCharacteristicItem id="6">',
        '<SphericityCharacteristicItem id="5">',
    )
    line = _line_of(text, '<SphericityCharacteristicItem id="5">')
    stock = xmlschema_findings(etree.parse(str(p)), xsd, register_substitutes=False)
    ours = validate_xmlschema(p)
    lx = validate_lxml(p)
    dup = {("key CharacteristicItemIdKey", line), ("unique QIFIdUnique", line)}
    assert dup <= {(f.rule, f.line) for f in ours}
    assert dup <= {(f.rule, f.line) for f in lx}
    assert not dup & {(f.rule, f.line) for f in stock}


@pytest.mark.parametrize("name", OFFICIAL + COMMUNITY)
def test_dmsc_report_per_sample(name, checks_available):
    rel = f"qif/samples/{name}" if name in OFFICIAL else f"qif/samples/community/{name}"
    findings = dmsc_checks(shared_file(rel))
    assert all(f.validator == "dmsc" for f in findings)
    got = Counter((f.category, f.severity, f.rule) for f in findings)
    assert dict(got) == DMSC[name]
    # findings about this file carry its line; those about linked files name them instead
    for f in findings:
        if f.category == "CheckDocuments" and f.severity == "warning":
            assert f.line is None and f.message.startswith("in linked document ")
        else:
            assert f.line is not None


def test_dmsc_all_in_one_details(checks_available):
    path = shared_file("qif/samples/community/All-in-one.QIF")
    text = path.read_text()
    findings = dmsc_checks(path)
    assert [(f.line, f.rule, f.message) for f in findings] == [
        (
            _line_of(text, '<SphericalDiameterCharacteristicNominal id="3">'),
            "A-AN-UV",
            "Unviewed Annotation (A-AN-UV): id=3",
        ),
        (
            _line_of(text, '<SphericalDiameterCharacteristicNominal id="3">'),
            "A-AN-NG",
            "Non-Graphical Annotation (A-AN-NG): id=3",
        ),
        (
            _line_of(text, '<SphericityCharacteristicNominal id="4">'),
            "A-AN-UV",
            "Unviewed Annotation (A-AN-UV): id=4",
        ),
        (
            _line_of(text, '<SphericityCharacteristicNominal id="4">'),
            "A-AN-NG",
            "Non-Graphical Annotation (A-AN-NG): id=4",
        ),
    ]
    rep = validate(path, checks=True)
    assert rep.valid and rep.ran == ["lxml", "dmsc"]
    assert (
        "dmsc: CheckFormat ok, CheckQuality 4 warnings, CheckSemantic ok, CheckDocuments ok"
        in rep.format()
    )


def test_dmsc_windows_uri_is_a_format_error(checks_available):
    path = shared_file("qif/samples/community/Exploded_Statistics.QIF")
    text = path.read_text()
    fmt = [f for f in dmsc_checks(path) if f.category == "CheckFormat"]
    assert [(f.line, f.rule) for f in fmt] == [
        (_line_of(text, r"<URI>.\Exploded_Results1.QIF</URI>"), "external-URI"),
        (_line_of(text, r"<URI>.\Exploded_Results2.QIF</URI>"), "external-URI"),
    ]
    assert "'.\\Exploded_Results1.QIF' is not a valid URI reference" in fmt[0].message
    rep = validate(path, checks=True)
    assert not rep.valid and rep.errors(validator="lxml") == []


def test_dmsc_missing_linked_document(tmp_path, checks_available):
    """A linked file that is not there: reported as DMSC says, the other checks still run."""
    src = shared_file("qif/samples/community/Exploded_Results1.QIF")
    p = tmp_path / src.name
    shutil.copy(src, p)
    findings = dmsc_checks(p)
    text = p.read_text()
    assert [(f.category, f.line, f.rule, f.message) for f in findings] == [
        (
            "CheckFormat",
            _line_of(text, '<ExternalQIFDocument id="1">'),
            "external-document",
            "The external document was not found URI = ./Exploded_Plan.QIF.",
        )
    ]
    shutil.copy(src.parent / "Exploded_Plan.QIF", tmp_path / "Exploded_Plan.QIF")
    assert [f for f in dmsc_checks(p) if f.category == "CheckFormat"] == []


def test_dmsc_array_length_extension_functions():
    """The urn:my-scripts functions the checks call (C# in checkLibraryMSXML.xsl)."""
    dbl, intg = D._array_length(float), D._array_length(int)
    el = etree.fromstring("<CPs count='2'> 1 2.5\n 3e1 4 </CPs>")
    assert dbl(None, [el]) == 4
    assert dbl(None, "1 x") == -1
    assert intg(None, "1 2 3") == 3 and intg(None, "1 2.0") == -1


def test_dmsc_node_paths_and_rule_names():
    """CheckReport node paths (``Name[pos]{id}`` steps) and the rule names of its reports."""
    root = etree.fromstring(
        f"<QIFDocument xmlns='{QIF_NS}'>\n<A>\n<B id='1'/>\n<B id='17'>\n<C/>\n</B>\n</A>\n"
        "</QIFDocument>".encode()
    )
    assert R._node_line(root, "/QIFDocument/A/B[2]{17}/C") == 5
    assert R._node_line(root, "/QIFDocument/A/B{17}") == 4
    assert R._node_line(root, "/QIFDocument/A/B") == 3
    assert R._node_line(root, "/QIFDocument/A/X") is None
    assert R._node_line(root, "/Other/A") is None
    examples = {  # reports quoted in CheckDescriptions.md
        'The number of array elements doesn\'t correspond to the specified "n" attribute: '
        "n(3) != nElem(2)": "n-count",
        "The id of element is greater than idMax. id(1520) greater than idMax(1515).": "idMax",
        "Nurbs12Core/Nurbs13Core: id=205, nCP(63) != nKt(66) - order(5)": "nurbs-control-points",
        "Nurbs12Core/Nurbs13Core/Nurbs23Core: id=208, nCP(5) != nWt(6)": "nurbs-weights",
        "ArrayPointType: nNumberActual(49) != nNumberRequired(48), count(16)": "ArrayPointType",
        "Free edge (G-SH-FR): id=204, nEdgeRef(1)": "G-SH-FR",
        "Unit vector too long: length of (1.0001 -0 0) greater than 1.00000001": "unit-vector",
        "PositionCharacteristicDefinition: id=704, ToleranceValue=0 and MaterialCondition(NONE) "
        "!= 'MAXIMUM'": "position-zero-tolerance",
        "Body form: id(6), form(TRIMMED_SURFACE), nShell(0), nFace(0) "
        "- should refer to faces": "body-form",
    }
    for text, rule in examples.items():
        assert R._dmsc_rule(text, "CheckFormat") == rule, text


# --------------------------------------------------------------------------------------------
# corrupted copies of valid samples: the right line and a rule naming the problem

ALL_IN_ONE = "qif/samples/community/All-in-one.QIF"


def test_missing_required_element(tmp_path, xsd):
    # (a) the only child of a characteristic nominal: its required CharacteristicDefinitionId
    p, text = _corrupt(
        tmp_path,
        ALL_IN_ONE,
        "        <CharacteristicDefinitionId>2</CharacteristicDefinitionId>\n",
        "",
    )
    line = _line_of(text, '<SphericityCharacteristicNominal id="4">')
    rep = validate(p, strict=True)
    assert not rep.valid and rep.ran == ["lxml", "xmlschema"]
    for v in ("lxml", "xmlschema"):
        errs = rep.errors(validator=v)
        assert [(f.line, f.rule) for f in errs] == [
            (line, "content SphericityCharacteristicNominal")
        ]
        assert "CharacteristicDefinitionId" in errs[0].message


def test_missing_required_element_before_a_sibling(tmp_path, xsd):
    # (a') a measurement's required Status: both report the unexpected next child's line
    old = re.search(
        r"<Status>\s*<CharacteristicStatusEnum>FAIL</CharacteristicStatusEnum>"
        r"\s*</Status>\s*",
        shared_file(ALL_IN_ONE).read_text(),
    ).group(0)
    p, text = _corrupt(tmp_path, ALL_IN_ONE, old, "")
    line = _line_of(text, "<CharacteristicItemId>5</CharacteristicItemId>")
    rep = validate(p, strict=True)
    for v in ("lxml", "xmlschema"):
        assert [(f.line, f.rule) for f in rep.errors(validator=v)] == [
            (line, "content SphericalDiameterCharacteristicMeasurement")
        ], v
        assert "Status" in rep.errors(validator=v)[0].message


def test_dangling_reference(tmp_path, xsd, checks_available):
    # (b) a characteristic measurement refers to an item id that does not exist
    p, text = _corrupt(
        tmp_path,
        ALL_IN_ONE,
        "<CharacteristicItemId>5</CharacteristicItemId>",
        "<CharacteristicItemId>55</CharacteristicItemId>",
    )
    line = _line_of(text, "<CharacteristicItemId>55</CharacteristicItemId>")
    rep = validate(p, strict=True, checks=True)
    rule = "keyref SphericalDiameterCharacteristicMeasurementToItemKeyref"
    for v in ("lxml", "xmlschema"):
        errs = rep.errors(validator=v)
        assert [(f.line, f.rule) for f in errs] == [(line, rule)], v
        assert "55" in errs[0].message
    assert rep.errors(validator="dmsc") == []  # no DMSC check covers internal references
    assert not rep.valid
    assert (
        f"{p}:{line}: [xmlschema/{rule}] value 55 not found for key "
        "SphericalDiameterCharacteristicItemKey" in rep.format()
    )


def test_dangling_feature_item_reference(tmp_path, xsd):
    # (b') where stock xmlschema gives false positives: the workaround still catches it
    p, text = _corrupt(
        tmp_path, "qif/samples/SheetMetal_QIF_Results_sample_1.QIF", "<Id>10</Id>", "<Id>1010</Id>"
    )
    line = _line_of(text, "<Id>1010</Id>")
    for errs in (validate_lxml(p), validate_xmlschema(p)):
        assert [(f.line, f.rule) for f in errs] == [(line, FI)]


def test_wrong_n_count(tmp_path, xsd, checks_available):
    # (c) no XSD validator checks n=; DMSC CheckFormat does
    p, text = _corrupt(
        tmp_path, ALL_IN_ONE, '<CharacteristicItems n="2">', '<CharacteristicItems n="3">'
    )
    line = _line_of(text, '<CharacteristicItems n="3">')
    rep = validate(p, strict=True, checks=True)
    assert rep.errors(validator="lxml") == [] and rep.errors(validator="xmlschema") == []
    fmt = rep.errors(validator="dmsc", category="CheckFormat")
    assert [(f.line, f.rule) for f in fmt] == [(line, "n-count")]
    assert "n(3) != nElem(2)" in fmt[0].message
    assert not rep.valid
    assert f"{p}:{line}: [dmsc/CheckFormat/n-count] The number of array elements" in rep.format()


def test_other_schema_errors_name_the_rule(tmp_path, xsd):
    cases = [
        (
            "<CharacteristicStatusEnum>FAIL<",
            "<CharacteristicStatusEnum>BROKEN<",
            "facet CharacteristicStatusEnum",
        ),
        ("<MaxValue>0.25</MaxValue>", "<MaxValue>0.2.5</MaxValue>", "datatype MaxValue"),
        ('<Standard id="14">', '<Standard id="14" foo="1">', "attribute Standard@foo"),
    ]
    for i, (old, new, rule) in enumerate(cases):
        p, text = _corrupt(tmp_path, ALL_IN_ONE, old, new, name=f"c{i}.QIF")
        line = _line_of(text, new)
        for errs in (validate_lxml(p), validate_xmlschema(p)):
            assert [(f.line, f.rule) for f in errs] == [(line, rule)], errs
    # a missing key field: the attribute and the key it feeds are both named
    p, text = _corrupt(
        tmp_path,
        ALL_IN_ONE,
        '<SphericalDiameterCharacteristicDefinition id="1">',
        "<SphericalDiameterCharacteristicDefinition>",
        name="noid.QIF",
    )
    line = _line_of(text, "<SphericalDiameterCharacteristicDefinition>")
    for errs in (validate_lxml(p), validate_xmlschema(p)):
        rules = {(f.line, f.rule) for f in errs}
        assert (line, "attribute SphericalDiameterCharacteristicDefinition@id") in rules
        assert (line, "key SphericalDiameterCharacteristicDefinitionKey") in rules
        assert (
            _line_of(text, "<CharacteristicDefinitionId>1<"),
            "keyref SphericalDiameterCharacteristicNominalToDefinitionKeyref",
        ) in rules


# --------------------------------------------------------------------------------------------
# schema location and resolution


def test_schema_dir_env_var(monkeypatch, tmp_path, xsd):
    official = shared_file("qif/xsd/QIFApplications/QIFDocument.xsd").parents[1]
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(official))
    assert schema_dir() == official.resolve()
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(tmp_path))
    with pytest.raises(SchemasUnavailable) as exc:
        schema_dir()
    msg = str(exc.value)
    assert "make install" in msg and "QIFREPORT_XSD_DIR" in msg and "QIFLibrary" in msg
    with pytest.raises(SchemasUnavailable):
        validate(shared_file(ALL_IN_ONE))
    monkeypatch.delenv("QIFREPORT_XSD_DIR")
    assert schema_dir() == xsd


def test_official_folder_without_local_dsig_uses_bundled_copy(monkeypatch):
    """../shared/qif/xsd has no QIFLibrary/xmldsig copy: the remote import maps to xmlschema's."""
    official = shared_file("qif/xsd/QIFApplications/QIFDocument.xsd").parents[1]
    assert not (official / "QIFLibrary" / "xmldsig-core-schema.xsd").exists()
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(official))
    import xmlschema

    assert (
        dsig_path(official).parent == Path(xmlschema.__file__).resolve().parent / "schemas" / "DSIG"
    )
    assert validate_lxml(shared_file(ALL_IN_ONE)) == []


def test_dsig_copy_with_doctype_loads(monkeypatch, tmp_path, xsd):
    """A W3C-style xmldsig copy with its DOCTYPE (external DTD, internal subset) loads offline."""
    d = tmp_path / "xsd"
    shutil.copytree(xsd, d)
    dsig = d / "QIFLibrary" / "xmldsig-core-schema.xsd"
    text = dsig_path(xsd).read_text(encoding="utf-8")
    text = re.sub(r"<!--\s*<!DOCTYPE.*?\]>\s*-->", "", text, flags=re.S)
    head, rest = text.split("\n", 1)
    assert head.startswith("<?xml") and "<!DOCTYPE" not in rest
    dsig.write_text(head + "\n" + DSIG_DOCTYPE + rest, encoding="utf-8")
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(d))
    assert validate_lxml(shared_file(ALL_IN_ONE)) == []
    p, _ = _corrupt(tmp_path, ALL_IN_ONE, "<CharacteristicItemId>5<", "<CharacteristicItemId>7<")
    assert [f.rule for f in validate_lxml(p)] == [
        "keyref SphericalDiameterCharacteristicMeasurementToItemKeyref"
    ]


DSIG_DOCTYPE = """<!DOCTYPE schema
  PUBLIC "-//W3C//DTD XMLSchema 200102//EN" "http://www.w3.org/2001/XMLSchema.dtd"
 [
   <!ATTLIST schema
     xmlns:ds CDATA #FIXED "http://www.w3.org/2000/09/xmldsig#">
   <!ENTITY dsig 'http://www.w3.org/2000/09/xmldsig#'>
   <!ENTITY % p ''>
   <!ENTITY % s ''>
  ]>
"""


def test_installed_schema_copy_has_the_dsig_schema():
    """``make install`` puts the xmldsig schema beside the official files (Makefile step)."""
    installed = Path(REPO_ROOT) / "schemas" / "qif-3.0"
    if not (installed / "QIFApplications" / "QIFDocument.xsd").is_file():
        pytest.skip("schemas/qif-3.0 not installed (make install)")
    assert (installed / "QIFLibrary" / "xmldsig-core-schema.xsd").is_file(), (
        "re-run the XSD copy step of `make install`"
    )


def test_schemas_compiled_once(xsd):
    path = shared_file(ALL_IN_ONE)
    validate(path, strict=True)
    lx, xs = lxml_schema.cache_info(), xmlschema_schema.cache_info()
    validate(path, strict=True)
    assert lxml_schema.cache_info().misses == lx.misses
    assert xmlschema_schema.cache_info().misses == xs.misses
    assert xmlschema_schema.cache_info().hits > xs.hits


def test_report_without_validators_is_not_valid(tmp_path):
    rep = ValidationReport(path=tmp_path / "x.qif", schema_dir=None, findings=[], ran=[])
    assert rep.valid is False
    assert not re.search(r"\bvalid\b", rep.format())
    warn = Finding("dmsc", 3, "A-AN-UV", "m", "CheckQuality", "warning")
    rep = ValidationReport(path=tmp_path / "x.qif", schema_dir=None, findings=[warn], ran=["dmsc"])
    assert rep.valid and rep.errors() == []


# --------------------------------------------------------------------------------------------
# qifreport validate


def test_validate_main_valid(capsys, xsd, checks_available):
    path = shared_file(ALL_IN_ONE)
    assert validate_main([str(path)]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[:4] == [
        f"{path}: valid",
        "  lxml: ok",
        "  xmlschema: ok",
        "  dmsc: CheckFormat ok, CheckQuality 4 warnings, CheckSemantic ok, CheckDocuments ok",
    ]
    assert lines[4].startswith(f"{path}:37: [dmsc/CheckQuality/A-AN-UV] warning: ")
    assert err == ""
    assert validate_main([str(path), "--quiet"]) == 0
    assert capsys.readouterr().out == ""


def test_validate_main_corrupted(tmp_path, capsys, xsd, checks_available):
    p, text = _corrupt(
        tmp_path,
        ALL_IN_ONE,
        "<CharacteristicItemId>5</CharacteristicItemId>",
        "<CharacteristicItemId>55</CharacteristicItemId>",
    )
    line = _line_of(text, "<CharacteristicItemId>55<")
    ok = shared_file(ALL_IN_ONE)
    assert validate_main([str(ok), str(p)]) == 1
    out, err = capsys.readouterr()
    assert f"{ok}: valid" in out and f"{p}: INVALID" in out
    assert "  lxml: 1 error\n  xmlschema: 1 error\n" in out
    rule = "keyref SphericalDiameterCharacteristicMeasurementToItemKeyref"
    assert f"{p}:{line}: [lxml/{rule}] " in out
    assert f"{p}:{line}: [xmlschema/{rule}] value 55 not found" in out
    assert err == ""
    assert validate_main([str(p), "--quiet", "--no-checks", "--no-strict"]) == 1
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"{p}: INVALID"
    assert [ln.split(" [")[1].split("]")[0] for ln in out.splitlines()[1:]] == [f"lxml/{rule}"]


def test_validate_main_missing_or_not_xml(tmp_path, capsys, xsd, checks_available):
    missing = tmp_path / "nope.qif"
    assert validate_main([str(missing)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == f"qifreport: error: {missing}: no such file\n"
    junk = tmp_path / "junk.qif"
    junk.write_text("this is not XML")
    assert validate_main([str(junk), str(shared_file(ALL_IN_ONE))]) == 2
    out, err = capsys.readouterr()
    assert err.startswith(f"qifreport: error: {junk}: not well-formed XML") and err.count("\n") == 1
    assert f"{shared_file(ALL_IN_ONE)}: valid" in out  # the other file is still checked


def test_validate_main_schemas_unavailable(monkeypatch, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("QIFREPORT_XSD_DIR", str(empty))
    assert validate_main([str(shared_file(ALL_IN_ONE))]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1 and err.startswith(
        "qifreport: error: QIF 3.0 XSD schemas not found"
    )
    assert "make install" in err and "QIFREPORT_XSD_DIR" in err
    assert not re.search(r"\bvalid\b", out + err, re.I)


def test_validate_main_checks_unavailable(monkeypatch, tmp_path, capsys, xsd):
    monkeypatch.setenv("QIFREPORT_CHECKS_DIR", str(tmp_path))
    path = shared_file(ALL_IN_ONE)
    assert validate_main([str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "DMSC checks not found" in err and "--no-checks" in err
    assert validate_main([str(path), "--no-checks"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines() == [f"{path}: valid", "  lxml: ok", "  xmlschema: ok"]
