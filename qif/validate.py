"""Validation of QIF 3.0 documents: the official XSDs and the DMSC quality checks.

Three independent validators, each reporting :class:`Finding` objects with a line number in
the QIF file and a rule naming what is violated:

* ``lxml`` (libxml2) against the official QIF 3.0 XSDs (``QIFApplications/QIFDocument.xsd``);
* ``xmlschema`` (strict, identity constraints included) against the same XSDs;
* ``dmsc``: the DMSC XSLT checks (``Check.xsl``, XSLT 1.0) run through ``lxml.etree.XSLT``;
  its ``CheckReport`` is parsed into findings with their category (``CheckFormat``,
  ``CheckQuality``, ``CheckSemantic``, ``CheckDocuments``).

Nothing here touches the network: the remote W3C xmldsig import of ``QIFDocument.xsd`` is
mapped to a local copy (the schema folder's ``QIFLibrary/xmldsig-core-schema.xsd``, else the
copy bundled with ``xmlschema``), libxml2 runs with ``no_network`` and the XSLT with an access
control that denies network reads.

Workarounds, all for defects outside this project:

* ``xmlschema`` (3.4 and 4.3 alike) registers the elements an identity-constraint selector
  reaches only by their declared names, so members of a substitution group (every
  ``EdgePointFeatureItem``, ``DiameterCharacteristicItem`` ... selected by ``t:*``) are never
  collected: ``FeatureItemIdKeyref`` then fails on every document with feature items (false
  positives; libxml2 and Xerces-C accept them) while other keys, ``QIFIdUnique`` among them,
  are silently not checked. :func:`_register_substitutes` adds the members to the constraints
  their head is selected by; the constraint's own XPath still decides what is collected.
* ``xmlschema`` given an lxml tree takes a comment inside simple content for a child element
  (``QIF_PTS_SAMPLE.QIF``: "a simple content element can't have child elements"); comments
  and processing instructions are stripped from its copy of the tree (lines are kept).
* libxslt aborts the whole DMSC transform when ``document()`` meets a URI with Windows
  separators (``.\\Exploded_Results1.QIF``, as in the DMSC community samples) or a linked file
  that is not there. Such a URI in the checked file is a ``CheckFormat`` error (``external-URI``)
  and is checked as ``./Exploded_Results1.QIF``; in a linked file it is fixed the same way by
  the resolver the checks load documents through (a warning); a missing linked file is served
  as an empty placeholder so that the checks report it as DMSC does ("The external document
  was not found") and go on.

The command line ``qifreport validate FILE...`` is :func:`validate_main`.
"""

from __future__ import annotations

import argparse
import copy
import functools
import logging
import os
import re
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any
from urllib.parse import urlparse
from urllib.request import url2pathname

from lxml import etree

from qifreport.schemas import QIF_XSD_DIR, SCHEMA_DIR

log = logging.getLogger("qifreport.validate")

QIF_NS = "http://qifstandards.org/xsd/qif3"
XSD_NS = "http://www.w3.org/2001/XMLSchema"
#: the root schema, relative to a schema folder
ROOT_XSD = Path("QIFApplications") / "QIFDocument.xsd"
DSIG_NAME = "xmldsig-core-schema.xsd"
#: where a local copy of the W3C xmldsig schema is looked for, relative to a schema folder
DSIG_LOCAL = Path("QIFLibrary") / DSIG_NAME
ENV_XSD_DIR = "QIFREPORT_XSD_DIR"
ENV_CHECKS_DIR = "QIFREPORT_CHECKS_DIR"
#: the repository root in an editable install (``../shared`` may sit beside it)
REPO_ROOT = SCHEMA_DIR.parent
#: the CheckReport categories, in report order (CheckDocuments: the linked-document checks)
DMSC_CATEGORIES = ("CheckFormat", "CheckQuality", "CheckSemantic", "CheckConstraints",
                   "CheckDocuments")
#: severity of a DMSC finding about this document, per category (quality checks are advice)
_DMSC_SEVERITY = {"CheckFormat": "error", "CheckSemantic": "error", "CheckConstraints": "error",
                  "CheckDocuments": "error", "CheckQuality": "warning"}
_HOWTO = ("run `make install` with ../shared present (it copies the official XSDs to "
          f"{QIF_XSD_DIR}), or set QIFREPORT_XSD_DIR to a folder holding QIFApplications/ "
          f"and QIFLibrary/ (an installed wheel: or copy those two folders into {QIF_XSD_DIR})")

__all__ = [
    "SchemasUnavailable", "Finding", "ValidationReport", "schema_dir", "validate_lxml",
    "validate_xmlschema", "dmsc_checks", "validate", "validate_main",
]


class SchemasUnavailable(Exception):
    """The QIF 3.0 XSDs (or the DMSC checks) cannot be found; the message says how to fix it."""


@dataclass
class Finding:
    """One problem found in a QIF document.

    Attributes
    ----------
    validator : str
        ``"lxml"``, ``"xmlschema"`` or ``"dmsc"``.
    line : int or None
        Line in the QIF file (None when the validator gives no location).
    rule : str
        What is violated: an XSD rule kind and the element or identity constraint
        (``"keyref FeatureItemIdKeyref"``, ``"content CircleFeatureItem"``), or the DMSC check
        (``"n-count"``, ``"idMax"``, ``"A-AN-UV"``...).
    message : str
        The validator's message (namespace ``{http://qifstandards.org/xsd/qif3}`` removed).
    category : str
        ``"schema"`` for the XSD validators; the ``CheckReport`` category for dmsc.
    severity : str
        ``"error"``, ``"warning"`` or ``"info"``.
    """

    validator: str
    line: int | None
    rule: str
    message: str
    category: str = "schema"
    severity: str = "error"


@dataclass
class ValidationReport:
    """The findings of the validators run on one file.

    Attributes
    ----------
    path : Path
        The QIF file.
    schema_dir : Path or None
        The XSD folder used (None if no XSD validator ran).
    findings : list of Finding
        Everything found, in validator order.
    ran : list of str
        The validators actually run.
    """

    path: Path
    schema_dir: Path | None
    findings: list[Finding]
    ran: list[str] = field(default_factory=list)

    def errors(self, validator: str | None = None, category: str | None = None) -> list[Finding]:
        """Error-severity findings, optionally of one validator and/or one category.

        Parameters
        ----------
        validator : str, optional
            ``"lxml"``, ``"xmlschema"`` or ``"dmsc"``.
        category : str, optional
            E.g. ``"schema"`` or ``"CheckFormat"``.

        Returns
        -------
        list of Finding
        """
        return [f for f in self.findings if f.severity == "error"
                and (validator is None or f.validator == validator)
                and (category is None or f.category == category)]

    @property
    def valid(self) -> bool:
        """True if no XSD validator reported an error and DMSC ``CheckFormat`` found none.

        False when nothing ran. DMSC quality, semantic and linked-document findings do not
        make a document invalid (they are listed by :meth:`format`).
        """
        if not self.ran:
            return False
        return not (self.errors("lxml") or self.errors("xmlschema")
                    or self.errors("dmsc", "CheckFormat"))

    def format(self) -> str:
        """A human-readable multi-line report.

        First line ``FILE: valid`` or ``FILE: INVALID``, then one line per validator run
        (``ok`` or ``N errors``; DMSC with counts per category), then one line per finding,
        ``FILE:LINE: [validator/rule] message`` (DMSC: ``[dmsc/Category/rule]``).

        Returns
        -------
        str
        """
        name = str(self.path)
        if not self.ran:
            return f"{name}: NOT CHECKED (no validator ran)"
        lines = [f"{name}: {'valid' if self.valid else 'INVALID'}"]
        for v in self.ran:
            if v == "dmsc":
                parts = []
                for cat in DMSC_CATEGORIES:
                    fs = [f for f in self.findings if f.validator == "dmsc" and f.category == cat]
                    if cat == "CheckConstraints" and not fs:
                        continue
                    parts.append(f"{cat} {_count_text(fs)}")
                lines.append("  dmsc: " + ", ".join(parts))
            else:
                fs = [f for f in self.findings if f.validator == v]
                lines.append(f"  {v}: {_count_text(fs)}")
        lines.extend(_finding_line(name, f) for f in self.findings)
        return "\n".join(lines)


def _finding_line(name: str, f: Finding) -> str:
    """``FILE:LINE: [validator/rule] message`` (``[dmsc/Category/rule]``; no LINE if unknown)."""
    where = f"{name}:{f.line}:" if f.line is not None else f"{name}:"
    rule = f"{f.validator}/{f.category}/{f.rule}" if f.validator == "dmsc" \
        else f"{f.validator}/{f.rule}"
    sev = "" if f.severity == "error" else f"{f.severity}: "
    msg = " ".join(f.message.splitlines())
    return f"{where} [{rule}] {sev}{msg}"


def _count_text(fs: list[Finding]) -> str:
    """``ok``, or ``N errors`` / ``N warnings`` for a list of findings."""
    if not fs:
        return "ok"
    c = Counter(f.severity for f in fs)
    return ", ".join(f"{n} {sev}{'s' if n > 1 else ''}" for sev, n in
                     sorted(c.items(), key=lambda kv: ("error", "warning", "info").index(kv[0])))


# ---------------------------------------------------------------------------------------------
# schema and check locations


def _is_schema_dir(p: Path) -> bool:
    return (p / ROOT_XSD).is_file()


def schema_dir() -> Path:
    """The folder of the official QIF 3.0 XSDs.

    Looked up in this order: ``$QIFREPORT_XSD_DIR`` (if set, it must be right),
    ``<repo>/schemas/qif-3.0`` (copied there by ``make install``), ``<repo>/../shared/qif/xsd``.
    A folder counts if it contains ``QIFApplications/QIFDocument.xsd``.

    Returns
    -------
    Path
        Absolute path of the folder.

    Raises
    ------
    SchemasUnavailable
        If none is found; the message says how to provide them.
    """
    env = os.environ.get(ENV_XSD_DIR)
    if env:
        p = Path(env).expanduser()
        if _is_schema_dir(p):
            return p.resolve()
        raise SchemasUnavailable(
            f"QIF 3.0 XSD schemas not found: {ENV_XSD_DIR}={env} has no {ROOT_XSD.as_posix()}; "
            f"{_HOWTO}")
    candidates = [QIF_XSD_DIR, REPO_ROOT.parent / "shared" / "qif" / "xsd"]
    for p in candidates:
        if _is_schema_dir(p):
            return p.resolve()
    raise SchemasUnavailable(
        "QIF 3.0 XSD schemas not found (looked in " + ", ".join(map(str, candidates))
        + f" and {ENV_XSD_DIR} is not set); {_HOWTO}")


def _checks_dir() -> Path:
    """The folder of the DMSC XSLT checks (``Check.xsl``, ``CheckParameters.xml``).

    ``$QIFREPORT_CHECKS_DIR`` (if set, it must be right), ``<repo>/schemas/qif-checks``, the
    ``checks`` folder beside ``$QIFREPORT_XSD_DIR``, ``<repo>/../shared/qif/checks``.
    """
    env = os.environ.get(ENV_CHECKS_DIR)
    if env:
        p = Path(env).expanduser()
        if (p / "Check.xsl").is_file():
            return p.resolve()
        raise SchemasUnavailable(f"DMSC checks not found: {ENV_CHECKS_DIR}={env} has no "
                                 "Check.xsl; point it at the folder of Check.xsl and "
                                 "CheckParameters.xml, or skip the checks (--no-checks)")
    candidates = [SCHEMA_DIR / "qif-checks"]
    xsd_env = os.environ.get(ENV_XSD_DIR)
    if xsd_env:
        candidates.append(Path(xsd_env).expanduser().parent / "checks")
    candidates.append(REPO_ROOT.parent / "shared" / "qif" / "checks")
    for p in candidates:
        if (p / "Check.xsl").is_file():
            return p.resolve()
    raise SchemasUnavailable(
        "DMSC checks (Check.xsl) not found (looked in " + ", ".join(map(str, candidates))
        + f"); set {ENV_CHECKS_DIR} to the folder of Check.xsl, or skip the checks (--no-checks)")


def _dsig_path(sd: Path) -> Path:
    """Local copy of the W3C xmldsig schema: the schema folder's, else xmlschema's bundled one."""
    local = sd / DSIG_LOCAL
    if local.is_file():
        return local
    import xmlschema

    return Path(xmlschema.__file__).resolve().parent / "schemas" / "DSIG" / DSIG_NAME


def _is_remote_dsig(url: str) -> bool:
    return url.lower().startswith(("http://", "https://")) and url.endswith(DSIG_NAME)


class _LocalResolver(etree.Resolver):
    """Maps the remote xmldsig schema to a local file and any other http(s) URL to nothing."""

    def __init__(self, dsig: Path) -> None:
        super().__init__()
        self.dsig = dsig

    def resolve(self, url: str | None, pubid: str | None, context: Any) -> Any:
        if url and _is_remote_dsig(url):
            log.debug("resolver: %s -> %s", url, self.dsig)
            return self.resolve_filename(str(self.dsig), context)
        if url and url.lower().startswith(("http://", "https://", "ftp://")):
            if url.endswith(".dtd"):  # e.g. the DOCTYPE of the W3C xmldsig copy: not needed
                return self.resolve_string("", context)
            log.warning("not fetching %s (no network access)", url)
        return None


def _xml_parser(resolver: etree.Resolver | None = None) -> etree.XMLParser:
    """A parser that never touches the network and keeps entities unexpanded from outside."""
    p = etree.XMLParser(no_network=True, huge_tree=True, resolve_entities=False,
                        load_dtd=False)
    if resolver is not None:
        p.resolvers.add(resolver)
    return p


# ---------------------------------------------------------------------------------------------
# compiled schemas (once per process and schema folder)


@functools.lru_cache(maxsize=4)
def _lxml_schema(sd: Path) -> etree.XMLSchema:
    t0 = time.perf_counter()
    parser = etree.XMLParser(no_network=True, huge_tree=True)
    parser.resolvers.add(_LocalResolver(_dsig_path(sd)))
    doc = etree.parse(str(sd / ROOT_XSD), parser)
    schema = etree.XMLSchema(doc)
    log.debug("lxml: compiled %s in %.2f s", sd / ROOT_XSD, time.perf_counter() - t0)
    return schema


@functools.lru_cache(maxsize=4)
def _xmlschema_schema(sd: Path, register_substitutes: bool = True) -> Any:
    """The QIF schema as an ``xmlschema.XMLSchema10`` (5-10 s the first time)."""
    import xmlschema

    dsig_uri = _dsig_path(sd).as_uri()

    def uri_mapper(uri: str) -> str:
        return dsig_uri if _is_remote_dsig(uri) else uri

    t0 = time.perf_counter()
    schema = xmlschema.XMLSchema10(str(sd / ROOT_XSD), uri_mapper=uri_mapper, allow="local")
    t1 = time.perf_counter()
    n = _register_substitutes(schema) if register_substitutes else 0
    log.debug("xmlschema: loaded %s in %.2f s, %d substitution-group registrations in %.2f s",
              sd / ROOT_XSD, t1 - t0, n, time.perf_counter() - t1)
    return schema


def _register_substitutes(schema: Any) -> int:
    """Let identity constraints collect substitution-group members (xmlschema workaround).

    xmlschema binds an identity constraint to the element declarations its selector names;
    a selector step ``t:*`` over a list of ``FeatureItem`` substitutes reaches only the
    abstract head, so no ``CircleFeatureItem`` id is ever collected. Each member is given the
    constraints of its head (with cached field selectors); which elements are collected is
    still decided by evaluating the selector on the document. Returns the number of
    registrations added.
    """
    try:
        from xmlschema.validators.identities import FieldValueSelector
    except ImportError:  # pragma: no cover - a future xmlschema layout
        log.warning("xmlschema: cannot register substitution groups with identity constraints")
        return 0
    n = 0
    for identity in list(schema.maps.identities.values()):
        elements = getattr(identity, "elements", None)
        if not isinstance(elements, dict):
            continue
        for head in list(elements):
            for member in head.iter_substitutes():
                if member not in elements:
                    elements[member] = [FieldValueSelector(f, member) for f in identity.fields]
                if identity not in member.selected_by:
                    member.selected_by.add(identity)
                    n += 1
    return n


@dataclass(frozen=True)
class _Identity:
    """An xs:key / xs:keyref / xs:unique of the QIF XSDs, as written there."""

    kind: str          # "key" | "keyref" | "unique"
    name: str          # local name, e.g. "FeatureItemIdKeyref"
    scope: str         # local name of the element declaring it, e.g. "QIFDocument"
    refer: str | None  # keyref: local name of the key it refers to
    selector: str      # XPath (whitespace removed)
    fields: tuple[str, ...]
    nsmap: tuple[tuple[str, str], ...]


@functools.lru_cache(maxsize=4)
def _identities(sd: Path) -> dict[str, _Identity]:
    """All identity constraints declared in the XSD files of a schema folder, by name."""
    out: dict[str, _Identity] = {}
    parser = _xml_parser()
    for xsd in sorted(sd.rglob("*.xsd")):
        try:
            doc = etree.parse(str(xsd), parser)
        except etree.XMLSyntaxError:
            continue
        for el in doc.iter(f"{{{XSD_NS}}}key", f"{{{XSD_NS}}}keyref", f"{{{XSD_NS}}}unique"):
            name = el.get("name")
            sel = el.find(f"{{{XSD_NS}}}selector")
            scope = next((a.get("name") for a in el.iterancestors(f"{{{XSD_NS}}}element")
                          if a.get("name")), None)
            if not name or sel is None or scope is None:
                continue
            refer = el.get("refer")
            out[name] = _Identity(
                kind=etree.QName(el).localname, name=name, scope=scope,
                refer=refer.split(":")[-1] if refer else None,
                selector=re.sub(r"\s+", "", sel.get("xpath", "")),
                fields=tuple(re.sub(r"\s+", "", f.get("xpath", ""))
                             for f in el.iterfind(f"{{{XSD_NS}}}field")),
                nsmap=tuple((k, v) for k, v in el.nsmap.items() if k),
            )
    return out


# ---------------------------------------------------------------------------------------------
# helpers on instance documents


def _parse(path: Path) -> etree._ElementTree:
    """Parse a QIF file (FileNotFoundError, lxml.etree.XMLSyntaxError on failure)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    return etree.parse(str(path), _xml_parser())


def _strip_ns(text: str) -> str:
    return text.replace(f"{{{QIF_NS}}}", "").replace(f"{QIF_NS}:", "")


def _local(tag: Any) -> str:
    try:
        return etree.QName(tag).localname
    except (ValueError, TypeError):
        return str(tag)


def _norm_value(v: Any) -> str:
    """A key value compared as XSD does for QIF ids: numerically if numeric, else as text."""
    s = str(v).strip()
    try:
        d = Decimal(s)
    except InvalidOperation:
        return s
    if not d.is_finite():
        return s
    return format(d.normalize(), "f")


def _field_values(node: etree._Element, fld: str, ns: dict[str, str]) -> list[tuple[str, int]]:
    """Values (normalized) and lines of one identity field evaluated on a selected node."""
    try:
        res = node.xpath(fld, namespaces=ns)
    except etree.XPathError:
        return []
    out = []
    for r in res if isinstance(res, list) else [res]:
        if isinstance(r, etree._Element):
            out.append((_norm_value("".join(r.itertext())), r.sourceline or 0))
        elif isinstance(r, str):
            parent = getattr(r, "getparent", lambda: None)()
            out.append((_norm_value(r), parent.sourceline if parent is not None else 0))
    return out


def _locate_references(tree: etree._ElementTree, ident: _Identity,
                       values: tuple[str, ...]) -> list[int]:
    """Lines of the nodes whose fields of identity ``ident`` equal ``values``."""
    ns = dict(ident.nsmap) or {"t": QIF_NS}
    root = tree.getroot()
    scopes = [root] if _local(root.tag) == ident.scope else \
        list(root.iter(f"{{{QIF_NS}}}{ident.scope}"))
    lines: list[int] = []
    for scope in scopes:
        try:
            selected = scope.xpath(ident.selector, namespaces=ns)
        except etree.XPathError:
            return []
        for node in selected:
            if not isinstance(node, etree._Element):
                continue
            got = [_field_values(node, f, ns) for f in ident.fields]
            if len(got) != len(values) or any(len(g) != 1 for g in got):
                continue
            if tuple(g[0][0] for g in got) == values:
                lines.append(got[-1][0][1] or node.sourceline or 0)
    return sorted(set(lines))


# ---------------------------------------------------------------------------------------------
# lxml (libxml2)

_LXML_KINDS = {
    "SCHEMAV_ELEMENT_CONTENT": "content",
    "SCHEMAV_CVC_ELT_1": "root",
    "SCHEMAV_CVC_COMPLEX_TYPE_4": "attribute",
    "SCHEMAV_CVC_COMPLEX_TYPE_3_2_1": "attribute",
    "SCHEMAV_CVC_COMPLEX_TYPE_3_2_2": "attribute",
    "SCHEMAV_CVC_ATTRIBUTE_3": "datatype",
}
_RE_LXML_ELEM = re.compile(r"^Element '(?:\{[^}]*\})?([^']+)'(?:, attribute '([^']+)')?")
_RE_LXML_IDC = re.compile(
    r"(?:No match found for key-sequence \[(?P<seq>.*?)\] of keyref"
    r"|Duplicate key-sequence \[(?P<dup>.*?)\] in (?P<dkind>key|unique) identity-constraint"
    r"|(?P<okind>key|keyref|unique) identity-constraint)"
    r" '(?:\{[^}]*\})?(?P<name>[^']+)'")


def _lxml_kind(type_name: str) -> str:
    if type_name in _LXML_KINDS:
        return _LXML_KINDS[type_name]
    if "FACET" in type_name or (type_name.endswith("_VALID") and "DATATYPE" not in type_name):
        return "facet"
    if "DATATYPE" in type_name or "CVC_TYPE" in type_name or "SIMPLE_TYPE" in type_name \
            or "CVC_ELT" in type_name:
        return "datatype"
    if "COMPLEX_TYPE" in type_name:
        return "content"
    return type_name.removeprefix("SCHEMAV_").lower()


def _lxml_findings(tree: etree._ElementTree, sd: Path) -> list[Finding]:
    schema = _lxml_schema(sd)
    if schema.validate(tree):
        return []
    out: list[Finding] = []
    for e in schema.error_log:
        msg = e.message
        m = _RE_LXML_ELEM.match(msg)
        elem = (m.group(1) + (f"@{m.group(2)}" if m.group(2) else "")) if m else ""
        line = e.line or None
        idc = _RE_LXML_IDC.search(msg) if e.type_name == "SCHEMAV_CVC_IDC" else None
        if idc:
            kind = "keyref" if idc.group("seq") is not None else \
                (idc.group("dkind") or idc.group("okind"))
            rule = f"{kind} {idc.group('name')}"
            if idc.group("seq") is not None and line is not None:
                line = _refine_keyref_line(tree, sd, idc.group("name"),
                                           re.findall(r"'([^']*)'", idc.group("seq")), line)
        else:
            kind = _lxml_kind(e.type_name)
            if kind == "content" and m and "This element is not expected" in msg:
                # name the element whose content is wrong (as xmlschema does), not the child
                parent = _parent_of(tree, m.group(1), e.line)
                elem = parent if parent else elem
            if kind == "attribute" and "@" not in elem:
                a = re.search(r"attribute '([^']+)'", msg)
                elem += f"@{a.group(1)}" if a else ""
            rule = f"{kind} {elem}".strip()
        sev = "warning" if e.level_name == "WARNING" else "error"
        out.append(Finding("lxml", line, rule, _strip_ns(msg), "schema", sev))
    return out


def _parent_of(tree: etree._ElementTree, local: str, line: int) -> str | None:
    """Local name of the parent of the element ``local`` starting on ``line``."""
    for el in tree.getroot().iter(f"{{*}}{local}"):
        if el.sourceline == line:
            parent = el.getparent()
            return _local(parent.tag) if parent is not None else None
    return None


def _refine_keyref_line(tree: etree._ElementTree, sd: Path, name: str, seq: list[str],
                        line: int) -> int:
    """libxml2 reports a keyref at the selected element; give the referencing field's line."""
    ident = _identities(sd).get(name)
    if ident is None:
        return line
    lines = _locate_references(tree, ident, tuple(_norm_value(v) for v in seq))
    after = [n for n in lines if n >= line]
    return min(after) if after else line


def validate_lxml(path: Path | str) -> list[Finding]:
    """Validate a QIF file against the QIF 3.0 XSDs with lxml (libxml2).

    Parameters
    ----------
    path : Path or str
        The QIF document.

    Returns
    -------
    list of Finding
        Empty if valid. Identity-constraint findings are ruled ``keyref NAME`` /
        ``key NAME`` / ``unique NAME``, a dangling reference located at the referencing
        element; others ``content ELEMENT``, ``attribute ELEMENT@ATTR``, ``datatype ...``,
        ``facet ...``.

    Raises
    ------
    SchemasUnavailable
        No XSD folder (see :func:`schema_dir`).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    sd = schema_dir()
    return _lxml_findings(_parse(Path(path)), sd)


# ---------------------------------------------------------------------------------------------
# xmlschema

_RE_XS_NOT_FOUND = re.compile(
    r"value \((?P<vals>.*)\) not found for Xsd(?:Key|Unique)\(name='(?P<key>[^']+)'\)"
    r"(?: \((?P<times>\d+) times\))?")
_RE_XS_DUP = re.compile(
    r"duplicated value \((?P<vals>.*)\) for Xsd(?P<kind>Key|Unique)\(name='(?P<key>[^']+)'\)")
_RE_XS_VALUE = re.compile(r"Decimal\('([^']*)'\)|'((?:[^'\\]|\\.)*)'|\"([^\"]*)\"|([-\w.+]+)")


def _xs_values(text: str) -> tuple[str, ...]:
    """Values of a repr'd key tuple such as ``Decimal('10'),`` -> ('10',)."""
    vals = []
    for m in _RE_XS_VALUE.finditer(text):
        v = next((g for g in m.groups() if g is not None), "")
        if v in ("Decimal", ""):
            continue
        vals.append(_norm_value(v))
    return tuple(vals)


def _xs_kind(err: Any) -> str:
    import xmlschema

    v = err.validator
    cls = type(v).__name__
    if isinstance(err, xmlschema.XMLSchemaChildrenValidationError):
        return "content"
    if "Facet" in cls:
        return "facet"
    if cls in ("XsdAttribute", "XsdAttributeGroup"):
        return "attribute"
    if isinstance(err, xmlschema.XMLSchemaDecodeError) or "Atomic" in cls or cls in (
            "XsdList", "XsdUnion", "XsdSimpleType"):
        return "datatype"
    if cls in ("XsdElement", "XsdGroup", "XsdComplexType"):
        return "content"
    return cls.removeprefix("Xsd").lower() or "schema"


def _xmlschema_findings(tree: etree._ElementTree, sd: Path,
                        register_substitutes: bool = True) -> list[Finding]:
    """xmlschema findings; ``register_substitutes=False`` shows stock xmlschema's behaviour."""
    schema = _xmlschema_schema(sd, register_substitutes)
    idents = _identities(sd)
    if tree.getroot().xpath("boolean(//comment() | //processing-instruction())"):
        # xmlschema takes an lxml comment inside simple content for a child element ("a
        # simple content element can't have child elements"): drop them, lines are kept
        tree = copy.deepcopy(tree)
        etree.strip_tags(tree, etree.Comment, etree.ProcessingInstruction)
    out: list[Finding] = []
    for err in schema.iter_errors(tree, use_location_hints=False):
        reason = err.reason or str(err)
        line = err.sourceline
        m = _RE_XS_NOT_FOUND.search(reason)
        if m:
            out.extend(_xs_keyref_findings(tree, idents, m, err, line))
            continue
        m = _RE_XS_DUP.search(reason)
        if m:
            key = m.group("key").split(":")[-1]
            vals = ", ".join(_xs_values(m.group("vals")))
            out.append(Finding("xmlschema", line, f"{m.group('kind').lower()} {key}",
                               f"duplicated value {vals} for {m.group('kind').lower()} {key}"))
            continue
        elem = _local(err.elem.tag) if err.elem is not None else ""
        kind = _xs_kind(err)
        index = getattr(err, "index", None)
        if isinstance(index, int) and err.elem is not None and 0 <= index < len(err.elem):
            line = err.elem[index].sourceline or line  # the unexpected child, as libxml2
        if kind == "attribute":
            a = re.search(r"attribute '([^']+)'|'([^']+)' attribute", reason)
            if a:
                elem += "@" + _local(a.group(1) or a.group(2))
        km = re.match(r"missing key field '([^']*)'", reason)
        if km:  # the constraint is not named; find the keys that select this element
            names = _keys_selecting(tree, idents, err.elem, km.group(1))
            kind, elem = "key", " ".join(names) or elem
            reason = f"missing key field '{km.group(1)}' of key {elem}"
        out.append(Finding("xmlschema", line, f"{kind} {elem}".strip(), _strip_ns(reason)))
    return out


def _keys_selecting(tree: etree._ElementTree, idents: dict[str, _Identity], elem: Any,
                    fld: str) -> list[str]:
    """Names of the keys with field ``fld`` whose selector selects ``elem``."""
    if elem is None:
        return []
    root = tree.getroot()
    names = []
    for ident in idents.values():
        if ident.kind != "key" or fld not in ident.fields:
            continue
        ns = dict(ident.nsmap) or {"t": QIF_NS}
        scopes = [root] if _local(root.tag) == ident.scope else \
            list(root.iter(f"{{{QIF_NS}}}{ident.scope}"))
        try:
            if any(elem in scope.xpath(ident.selector, namespaces=ns) for scope in scopes):
                names.append(ident.name)
        except etree.XPathError:
            continue
    return names


def _xs_keyref_findings(tree: etree._ElementTree, idents: dict[str, _Identity],
                        m: re.Match[str], err: Any, line: int | None) -> list[Finding]:
    """One finding per dangling reference, located and named by the violated keyref.

    xmlschema names only the referred key and reports at the scope element; the keyrefs of
    that scope referring to the key are evaluated to find which one, and where.
    """
    key = m.group("key").split(":")[-1]
    vals = _xs_values(m.group("vals"))
    scope = _local(err.elem.tag) if err.elem is not None else None
    cands = [i for i in idents.values() if i.kind == "keyref" and i.refer == key
             and (scope is None or i.scope == scope)]
    shown = ", ".join(vals)
    out = []
    for ident in cands:
        for ln in _locate_references(tree, ident, vals):
            out.append(Finding("xmlschema", ln, f"keyref {ident.name}",
                               f"value {shown} not found for key {key} (keyref {ident.name})"))
    if not out:
        name = cands[0].name if len(cands) == 1 else f"-> {key}"
        times = f" ({m.group('times')} times)" if m.group("times") else ""
        out.append(Finding("xmlschema", line, f"keyref {name}",
                           f"value {shown} not found for key {key}{times}"))
    return out


def validate_xmlschema(path: Path | str) -> list[Finding]:
    """Validate a QIF file against the QIF 3.0 XSDs with xmlschema, identity constraints included.

    Parameters
    ----------
    path : Path or str
        The QIF document.

    Returns
    -------
    list of Finding
        Empty if valid. A dangling reference gives one finding per referencing element, at
        its line, ruled ``keyref NAME``; duplicates ``key NAME`` / ``unique NAME``; others
        ``content ELEMENT``, ``attribute ELEMENT``, ``datatype ELEMENT``, ``facet ELEMENT``.

    Raises
    ------
    SchemasUnavailable
        No XSD folder (see :func:`schema_dir`).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    sd = schema_dir()
    return _xmlschema_findings(_parse(Path(path)), sd)


# ---------------------------------------------------------------------------------------------
# DMSC XSLT checks


def _array_length(kind: type) -> Any:
    """The ``urn:my-scripts`` extension functions the checks call (C# in checkLibraryMSXML)."""

    def length(_context: Any, arg: Any) -> int:
        if isinstance(arg, list):
            arg = "".join(arg[0].itertext()) if arg and isinstance(arg[0], etree._Element) \
                else (str(arg[0]) if arg else "")
        try:
            return len([kind(x) for x in str(arg).split()])
        except ValueError:
            return -1

    return length


@functools.lru_cache(maxsize=4)
def _dmsc_xslt(cd: Path) -> tuple[etree.XSLT, _LinkedDocResolver]:
    """Check.xsl compiled, with the resolver its ``document()`` calls go through."""
    t0 = time.perf_counter()
    access = etree.XSLTAccessControl(read_file=True, write_file=False, create_dir=False,
                                     read_network=False, write_network=False)
    extensions = {("urn:my-scripts", "LengthArrayDouble"): _array_length(float),
                  ("urn:my-scripts", "LengthArrayInt"): _array_length(int)}
    resolver = _LinkedDocResolver(cd)
    xslt = etree.XSLT(etree.parse(str(cd / "Check.xsl"), _xml_parser(resolver)),
                      access_control=access, extensions=extensions)
    log.debug("dmsc: compiled %s in %.3f s", cd / "Check.xsl", time.perf_counter() - t0)
    return xslt, resolver


_DMSC_RULES: tuple[tuple[str, str], ...] = (
    (r"number of array elements", "n-count"),
    (r"greater than idMax", "idMax"),
    (r"external document was not found", "external-document"),
    (r"external document has a different QPId", "external-QPId"),
    (r"external entity with this id was not found", "external-xId"),
    (r"not a valid URI reference", "external-URI"),
    (r"^Nurbs\S*: id=\d+, nCP\(\S*\) != nWt", "nurbs-weights"),
    (r"^Nurbs", "nurbs-control-points"),
    (r"^MeshTriangleCore", "mesh-triangle"),
    (r"^FaceMesh", "face-mesh"),
    (r"^(Array\w+Type):", r"\1"),
    (r"^Base64", "base64-length"),
    (r"^Unit vector", "unit-vector"),
    (r"Maximum recursion level", "MaxRecursionLevel"),
    (r"^PositionCharacteristicDefinition", "position-zero-tolerance"),
    (r"^Body form", "body-form"),
    (r"^Body:", "body-topology"),
    (r"refers to \w+ from another body|sewed with face", "body-topology"),
    (r"FeatureNominal not connected", "FeatureNominalTopologyLink"),
    (r"^(\w+Keyref) failed", r"\1"),
    (r"in the\s+referenced external document", "external-type"),
)


def _dmsc_rule(report: str, category: str) -> str:
    m = re.search(r"\(([A-Z]-[A-Z]{2}-[A-Z]{2})\)", report)
    if m:
        return m.group(1)
    for pat, rule in _DMSC_RULES:
        m = re.search(pat, report)
        if m:
            return m.expand(rule)
    return category


_RE_STEP = re.compile(r"^([^\[{]+)(?:\[(\d+)\])?(?:\{([^}]*)\})?$")


def _node_line(root: etree._Element, path: str | None) -> int | None:
    """Line of a CheckReport ``<Node>``: ``/QIFDocument/A/B[2]{17}/C`` ([pos] and {id} optional)."""
    if not path or not path.startswith("/"):
        return None
    el: etree._Element | None = None
    for step in path.strip("/").split("/"):
        m = _RE_STEP.match(step)
        if not m:
            return None
        name, pos, ident = m.group(1), int(m.group(2) or 1), m.group(3)
        if el is None:
            cands = [root]
        else:
            cands = [c for c in el if isinstance(c.tag, str) and _qname(c) == name]
        if len(cands) < pos or _qname(cands[pos - 1]) != name:
            return None
        el = cands[pos - 1]
        if ident is not None and el.get("id") != ident:
            match = [c for c in cands if c.get("id") == ident]
            if not match:
                return None
            el = match[0]
    return el.sourceline if el is not None else None


def _qname(el: etree._Element) -> str:
    """XPath name() of an element: prefix:local, or local in the default namespace."""
    local = etree.QName(el).localname
    return f"{el.prefix}:{local}" if el.prefix else local


def _parse_check_report(report: etree._Element, root: etree._Element, base: Path,
                        extra: list[Finding]) -> list[Finding]:
    """Findings of a CheckReport; ``root`` is the checked document (for line numbers)."""
    out: list[Finding] = list(extra)
    for child in report:
        if not isinstance(child.tag, str):
            continue
        if child.tag == "CheckLinkedDocument":
            out.extend(_linked_findings(child, root, base, chain=()))
        elif child.tag.startswith("Check"):
            cat = child.tag
            for err in child.iter("Error"):
                text = (err.findtext("Report") or "").strip()
                out.append(Finding("dmsc", _node_line(root, err.findtext("Node")),
                                   _dmsc_rule(text, cat), text, cat,
                                   _DMSC_SEVERITY.get(cat, "error")))
    return out


def _linked_findings(block: etree._Element, root: etree._Element, base: Path,
                     chain: tuple[str, ...]) -> list[Finding]:
    """Findings of a ``CheckLinkedDocument`` block (category ``CheckDocuments``).

    Errors directly in the block (cross-document reference checks, recursion limit) are about
    the referring document; those in its nested categories are about the linked file and are
    reported as warnings naming that file and its line.
    """
    uri = block.get("uri", "")
    chain = (*chain, uri)
    linked_root = _load_linked(base, chain)
    out: list[Finding] = []
    for child in block:
        if not isinstance(child.tag, str):
            continue
        if child.tag == "Error":
            text = (child.findtext("Report") or "").strip()
            node = child.findtext("Node")
            if len(chain) == 1:
                out.append(Finding("dmsc", _node_line(root, node), _dmsc_rule(text,
                                   "CheckDocuments"), text, "CheckDocuments", "error"))
            else:
                out.append(_linked_finding(chain[:-1], base, node, text, "CheckDocuments"))
        elif child.tag == "CheckLinkedDocument":
            out.extend(_linked_findings(child, root, base, chain))
        elif child.tag.startswith("Check"):
            for err in child.iter("Error"):
                text = (err.findtext("Report") or "").strip()
                f = _linked_finding(chain, base, err.findtext("Node"), text, child.tag,
                                    linked_root)
                out.append(f)
    return out


def _linked_finding(chain: tuple[str, ...], base: Path, node: str | None, text: str,
                    inner: str, linked_root: etree._Element | None = None) -> Finding:
    if linked_root is None:
        linked_root = _load_linked(base, chain)
    ln = _node_line(linked_root, node) if linked_root is not None else None
    where = " -> ".join(chain) + (f" line {ln}" if ln else "")
    rule = _dmsc_rule(text, inner)
    return Finding("dmsc", None, f"{inner}:{rule}",
                   f"in linked document {where}: {text}", "CheckDocuments", "warning")


def _load_linked(base: Path, chain: tuple[str, ...]) -> etree._Element | None:
    """The root of a linked document (URIs relative to the referring file), if readable."""
    here = base
    root = None
    for uri in chain:
        p = (here.parent / uri.replace("\\", "/")).resolve() if "://" not in uri else None
        if p is None or not p.is_file():
            return None
        try:
            root = etree.parse(str(p), _xml_parser()).getroot()
        except (etree.XMLSyntaxError, OSError):
            return None
        here = p
    return root


_MISSING_DOC = b"<qifreport-document-not-found/>"
_RE_URI_BYTES = re.compile(rb"(<(?:[\w.-]+:)?URI\s*>)([^<]*)(</(?:[\w.-]+:)?URI\s*>)")


class _LinkedDocResolver(etree.Resolver):
    """Serves documents loaded by the checks' ``document()`` calls, fixing Windows separators.

    libxslt aborts the whole transform on a ``URI`` such as ``.\\Exploded_Plan.QIF`` (not a URI
    reference) met in a linked document; such a document is served with ``/`` instead and the
    fix recorded in :attr:`fixed` (file, line, old, new). Everything else loads normally.
    """

    def __init__(self, checks: Path) -> None:
        super().__init__()
        self.checks = checks
        self.fixed: list[tuple[Path, int, str, str]] = []
        self.missing: list[Path] = []

    def resolve(self, url: str | None, pubid: str | None, context: Any) -> Any:
        if not url or re.match(r"^[a-zA-Z][\w+.-]+://", url) and not url.startswith("file:"):
            return None  # network URLs: denied by the access control
        try:
            p = Path(url2pathname(urlparse(url).path) if url.startswith("file:") else url)
            p = p.resolve()
            if p.parent == self.checks:
                return None
            if not p.exists():
                # libxslt would abort the transform; a placeholder without a QIFDocument
                # lets the checks report the document as not found and go on
                self.missing.append(p)
                return self.resolve_string(_MISSING_DOC, context, base_url=url)
            data = p.read_bytes()
        except (OSError, ValueError):
            return None
        if b"\\" not in data:
            return None
        fixed: list[tuple[Path, int, str, str]] = []

        def fix(m: re.Match[bytes]) -> bytes:
            if b"\\" not in m.group(2):
                return m.group(0)
            new = m.group(2).replace(b"\\", b"/")
            line = data.count(b"\n", 0, m.start()) + 1
            fixed.append((p, line, m.group(2).decode(errors="replace").strip(),
                          new.decode(errors="replace").strip()))
            return m.group(1) + new + m.group(3)

        out = _RE_URI_BYTES.sub(fix, data)
        if not fixed:
            return None
        self.fixed.extend(fixed)
        return self.resolve_string(out, context, base_url=url)


_DMSC_LOCK = threading.Lock()


def _dmsc_findings(tree: etree._ElementTree, path: Path, cd: Path) -> list[Finding]:
    xslt, resolver = _dmsc_xslt(cd)
    extra: list[Finding] = []
    work = tree
    bad = [u for u in tree.getroot().iterfind(f"{{{QIF_NS}}}ExternalQIFReferences/"
                                                f"{{{QIF_NS}}}ExternalQIFDocument/{{{QIF_NS}}}URI")
           if "\\" in (u.text or "")]
    if bad:
        work = copy.deepcopy(tree)  # keeps the base URL and the line numbers
        for uri_el in work.getroot().iter(f"{{{QIF_NS}}}URI"):
            text = (uri_el.text or "").strip()
            if "\\" in text:
                uri_el.text = text.replace("\\", "/")
                extra.append(Finding(
                    "dmsc", uri_el.sourceline, "external-URI",
                    f"URI '{text}' is not a valid URI reference (backslash): an XSLT processor "
                    f"cannot load it (libxslt aborts); checked as '{uri_el.text}'",
                    "CheckFormat"))
    with _DMSC_LOCK:
        resolver.fixed.clear()
        resolver.missing.clear()
        try:
            result = xslt(work)
        except etree.XSLTApplyError as exc:
            msgs = [e.message for e in xslt.error_log if e.message]
            detail = "; ".join(dict.fromkeys(msgs)) or str(exc)
            return [*extra, Finding("dmsc", None, "xslt-error",
                                    f"the DMSC checks could not run: {detail}", "CheckFormat")]
        linked_fixes = list(resolver.fixed)
        missing = bool(resolver.missing)
    for p, line, old, new in dict.fromkeys(linked_fixes):
        try:
            shown = os.path.relpath(p, path.parent)
        except ValueError:
            shown = str(p)
        extra.append(Finding(
            "dmsc", None, "CheckFormat:external-URI",
            f"in linked document {shown} line {line}: URI '{old}' is not a valid URI reference "
            f"(backslash); checked as '{new}'", "CheckDocuments", "warning"))
    report = result.getroot()
    if report is None or report.tag != "CheckReport":
        return [*extra, Finding("dmsc", None, "no-report",
                                "Check.xsl produced no CheckReport (is the root element "
                                "QIFDocument in the QIF 3.0 namespace?)", "CheckFormat")]
    if missing:
        _report_missing_documents(report)
    return _parse_check_report(report, tree.getroot(), path, extra)


_RE_QPID_EMPTY = re.compile(r"The external document has a different QPId\.\s*"
                            r"URI = (.*?),\s*QPId\(.*?\)\s*!= QPIdExt\(\)\.?$", re.S)


def _report_missing_documents(report: etree._Element) -> None:
    """Say "not found" where the checks compared a QPId with a missing document's."""
    for rep in report.iter("Report"):
        m = _RE_QPID_EMPTY.match(rep.text or "")
        if m:
            rep.text = f"The external document was not found URI = {m.group(1)}."


def dmsc_checks(path: Path | str) -> list[Finding]:
    """Run the DMSC XSLT checks (``Check.xsl``) on a QIF file.

    The checks read ``CheckParameters.xml`` beside ``Check.xsl`` (which categories run, the
    recursion depth into linked documents, quality limits) and the documents the file links
    to (``ExternalQIFReferences/ExternalQIFDocument/URI``, relative to the file); their
    ``urn:my-scripts`` array-length functions are supplied here. Network access is denied.

    Parameters
    ----------
    path : Path or str
        The QIF document.

    Returns
    -------
    list of Finding
        One per ``<Error>`` of the ``CheckReport``: ``category`` is the report section
        (``CheckFormat``, ``CheckQuality``, ``CheckSemantic``; ``CheckDocuments`` for a
        ``CheckLinkedDocument``), ``rule`` the check (``n-count``, ``idMax``,
        ``external-document``, ``A-AN-UV``...), ``line`` from the report's node path.
        Quality findings and findings inside linked documents are warnings.

    Raises
    ------
    SchemasUnavailable
        ``Check.xsl`` not found (``$QIFREPORT_CHECKS_DIR``, ``../shared/qif/checks``).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    p = Path(path)
    return _dmsc_findings(_parse(p), p.resolve(), _checks_dir())


# ---------------------------------------------------------------------------------------------
# all together


def validate(path: Path | str, *, strict: bool = False, checks: bool = False) -> ValidationReport:
    """Validate a QIF file: lxml always, xmlschema if ``strict``, DMSC checks if ``checks``.

    Parameters
    ----------
    path : Path or str
        The QIF document.
    strict : bool
        Also validate with xmlschema (identity constraints checked independently of libxml2).
    checks : bool
        Also run the DMSC XSLT checks.

    Returns
    -------
    ValidationReport

    Raises
    ------
    SchemasUnavailable
        No XSD folder, or (with ``checks``) no DMSC checks.
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    p = Path(path)
    sd = schema_dir()
    cd = _checks_dir() if checks else None
    tree = _parse(p)
    runs = [("lxml", functools.partial(_lxml_findings, tree, sd))]
    if strict:
        runs.append(("xmlschema", functools.partial(_xmlschema_findings, tree, sd)))
    if cd is not None:
        runs.append(("dmsc", functools.partial(_dmsc_findings, tree, p.resolve(), cd)))
    findings: list[Finding] = []
    ran: list[str] = []
    timings = []
    for name, run in runs:
        t0 = time.perf_counter()
        findings.extend(run())
        ran.append(name)
        timings.append(f"{name} {time.perf_counter() - t0:.2f} s")
    log.debug("%s: %s", p, ", ".join(timings))
    return ValidationReport(path=p, schema_dir=sd, findings=findings, ran=ran)


def _arg_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="qifreport validate",
        description="Check QIF 3.0 documents against the official XSDs (lxml/libxml2 and "
        "xmlschema, key/keyref included) and the DMSC XSLT checks. Exit 0 if every file "
        "passes, 1 if one does not, 2 if a file cannot be read or the schemas are missing.")
    ap.add_argument("files", nargs="+", type=Path, metavar="FILE", help="QIF document(s)")
    ap.add_argument("--no-strict", action="store_true",
                    help="skip the xmlschema validation (lxml only; faster)")
    ap.add_argument("--no-checks", action="store_true", help="skip the DMSC XSLT checks")
    ap.add_argument("--quiet", action="store_true",
                    help="print only the errors of failing files")
    return ap


def _err(msg: str) -> None:
    print(f"qifreport: error: {msg}", file=sys.stderr)


def validate_main(argv: list[str]) -> int:
    """``qifreport validate FILE.qif [FILE...] [--no-strict] [--no-checks] [--quiet]``.

    Runs lxml, xmlschema and the DMSC checks (unless disabled) on each file and prints its
    report (:meth:`ValidationReport.format`).

    Parameters
    ----------
    argv : list of str
        The arguments after ``validate``.

    Returns
    -------
    int
        0 if all files are valid, 1 if one is not, 2 if a file is missing or not XML, or the
        schemas (or checks) are unavailable; each such problem is one line on stderr
        (``qifreport: error: ...``).
    """
    try:
        args = _arg_parser().parse_args(argv)
    except SystemExit as exc:  # usage error (2) or --help (0)
        return int(exc.code) if isinstance(exc.code, int) else 2
    strict, checks = not args.no_strict, not args.no_checks
    try:
        schema_dir()
        if checks:
            _checks_dir()
    except SchemasUnavailable as exc:
        _err(f"{exc}; nothing was checked")
        return 2
    status = 0
    for f in args.files:
        try:
            rep = validate(f, strict=strict, checks=checks)
        except FileNotFoundError:
            _err(f"{f}: no such file")
            status = 2
            continue
        except etree.XMLSyntaxError as exc:
            _err(f"{f}: not well-formed XML: {exc}")
            status = 2
            continue
        except (OSError, SchemasUnavailable) as exc:
            _err(f"{f}: {exc}")
            status = 2
            continue
        if not rep.valid:
            status = max(status, 1)
        if args.quiet:
            if not rep.valid:
                print("\n".join(_error_lines(rep)))
        else:
            print(rep.format())
    return status


def _error_lines(rep: ValidationReport) -> Iterator[str]:
    """For --quiet: the header and the findings that make the file invalid."""
    yield rep.format().splitlines()[0]
    for f in rep.findings:
        if f.severity == "error" and (f.validator != "dmsc" or f.category == "CheckFormat"):
            yield _finding_line(str(rep.path), f)
