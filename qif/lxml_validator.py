"""Validation of QIF 3.0 documents against the official XSDs with lxml (libxml2).

The root schema ``QIFApplications/QIFDocument.xsd`` is compiled once per process and schema
folder (:func:`lxml_schema`), its remote xmldsig import mapped to a local copy
(:class:`qifreport.qif.xsd.LocalResolver`). libxml2's messages become :class:`Finding`
objects with a rule naming the problem: ``keyref NAME`` / ``key NAME`` / ``unique NAME`` for
identity constraints (a dangling reference located at the referencing element, not at the
selected one libxml2 reports), ``content ELEMENT`` (the element whose content is wrong, as
xmlschema names it), ``attribute ELEMENT@ATTR``, ``datatype ...``, ``facet ...``.
"""

from __future__ import annotations

import functools
import logging
import re
import time
from pathlib import Path

from lxml import etree

from .findings import Finding
from .identities import identity_constraints, locate_references, norm_value
from .xsd import (
    ROOT_XSD,
    LocalResolver,
    dsig_path,
    local_name,
    parse_document,
    schema_dir,
    strip_ns,
    xml_parser,
)

__all__ = ["lxml_findings", "lxml_schema", "validate_lxml"]

log = logging.getLogger("qifreport.validate")

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
    r" '(?:\{[^}]*\})?(?P<name>[^']+)'"
)


@functools.lru_cache(maxsize=4)
def lxml_schema(sd: Path) -> etree.XMLSchema:
    """The QIF schema compiled by libxml2 (once per process and schema folder).

    Parameters
    ----------
    sd : Path
        A schema folder (:func:`qifreport.qif.xsd.schema_dir`).

    Returns
    -------
    lxml.etree.XMLSchema
    """
    t0 = time.perf_counter()
    doc = etree.parse(str(sd / ROOT_XSD), xml_parser(LocalResolver(dsig_path(sd))))
    schema = etree.XMLSchema(doc)
    log.debug("lxml: compiled %s in %.2f s", sd / ROOT_XSD, time.perf_counter() - t0)
    return schema


def _lxml_kind(type_name: str) -> str:
    if type_name in _LXML_KINDS:
        return _LXML_KINDS[type_name]
    if "FACET" in type_name or (type_name.endswith("_VALID") and "DATATYPE" not in type_name):
        return "facet"
    if (
        "DATATYPE" in type_name
        or "CVC_TYPE" in type_name
        or "SIMPLE_TYPE" in type_name
        or "CVC_ELT" in type_name
    ):
        return "datatype"
    if "COMPLEX_TYPE" in type_name:
        return "content"
    return type_name.removeprefix("SCHEMAV_").lower()


def lxml_findings(tree: etree._ElementTree, sd: Path) -> list[Finding]:
    """The libxml2 findings of a parsed QIF document (see :func:`validate_lxml`).

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document (:func:`qifreport.qif.xsd.parse_document`).
    sd : Path
        The schema folder.

    Returns
    -------
    list of Finding
    """
    schema = lxml_schema(sd)
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
            kind = (
                "keyref"
                if idc.group("seq") is not None
                else (idc.group("dkind") or idc.group("okind"))
            )
            rule = f"{kind} {idc.group('name')}"
            if idc.group("seq") is not None and line is not None:
                line = _refine_keyref_line(
                    tree, sd, idc.group("name"), re.findall(r"'([^']*)'", idc.group("seq")), line
                )
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
        out.append(Finding("lxml", line, rule, strip_ns(msg), "schema", sev))
    return out


def _parent_of(tree: etree._ElementTree, local: str, line: int) -> str | None:
    """Local name of the parent of the element ``local`` starting on ``line``."""
    for el in tree.getroot().iter(f"{{*}}{local}"):
        if el.sourceline == line:
            parent = el.getparent()
            return local_name(parent.tag) if parent is not None else None
    return None


def _refine_keyref_line(
    tree: etree._ElementTree, sd: Path, name: str, seq: list[str], line: int
) -> int:
    """libxml2 reports a keyref at the selected element; give the referencing field's line."""
    ident = identity_constraints(sd).get(name)
    if ident is None:
        return line
    lines = locate_references(tree, ident, tuple(norm_value(v) for v in seq))
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
        No XSD folder (see :func:`qifreport.qif.xsd.schema_dir`).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    DocumentRefused
        Not a regular file, too large, or with a DOCTYPE
        (:func:`qifreport.qif.xsd.parse_document`).
    """
    sd = schema_dir()
    return lxml_findings(parse_document(Path(path)), sd)
