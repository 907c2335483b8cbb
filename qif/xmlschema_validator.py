"""Validation of QIF 3.0 documents against the official XSDs with xmlschema (strict).

The same XSDs as :mod:`.lxml_validator`, checked by an independent implementation, identity
constraints included (:func:`validate_xmlschema`). The schema is loaded once per process and
schema folder (:func:`xmlschema_schema`, a costly load), the remote xmldsig import mapped to a
local copy (:func:`qifreport.qif.xsd.dsig_path`).

Workarounds, both for defects of xmlschema:

* xmlschema (3.4 and 4.3 alike) registers the elements an identity-constraint selector
  reaches only by their declared names, so members of a substitution group (every
  ``EdgePointFeatureItem``, ``DiameterCharacteristicItem`` ... selected by ``t:*``) are never
  collected: ``FeatureItemIdKeyref`` then fails on every document with feature items (false
  positives; libxml2 and Xerces-C accept them) while other keys, ``QIFIdUnique`` among them,
  are silently not checked. :func:`_register_substitutes` adds the members to the constraints
  their head is selected by; the constraint's own XPath still decides what is collected.
* xmlschema given an lxml tree takes a comment inside simple content for a child element
  (``QIF_PTS_SAMPLE.QIF``: "a simple content element can't have child elements"); comments
  and processing instructions are stripped from its copy of the tree (lines are kept).

xmlschema names only the referred key of a dangling reference and reports it at the scope
element: the keyrefs referring to that key are evaluated (:mod:`.identities`) to name the
violated one and give one finding per referencing element, at its line.

xmlschema is never given a tree with an entity reference (it stops with "Internal error in
XML Schema validation"): such a tree, which :func:`qifreport.qif.xsd.parse_document` refuses
anyway, gives the finding ``entity``; an error xmlschema raises instead of reporting gives
the finding ``internal``.
"""

from __future__ import annotations

import copy
import functools
import logging
import re
import time
from pathlib import Path
from typing import Any

from lxml import etree

from .findings import Finding
from .identities import (
    IdentityConstraint,
    identity_constraints,
    keys_selecting,
    locate_references,
    norm_value,
)
from .xsd import (
    ROOT_XSD,
    dsig_path,
    is_remote_dsig,
    local_name,
    parse_document,
    schema_dir,
    strip_ns,
)

__all__ = ["validate_xmlschema", "xmlschema_findings", "xmlschema_schema"]

log = logging.getLogger("qifreport.validate")


@functools.lru_cache(maxsize=4)
def xmlschema_schema(sd: Path, register_substitutes: bool = True) -> Any:
    """The QIF schema as an ``xmlschema.XMLSchema10`` (loaded once: a costly build).

    Parameters
    ----------
    sd : Path
        A schema folder (:func:`qifreport.qif.xsd.schema_dir`).
    register_substitutes : bool
        Apply the substitution-group workaround (False: stock xmlschema's behaviour).

    Returns
    -------
    xmlschema.XMLSchema10
    """
    import xmlschema

    dsig_uri = dsig_path(sd).as_uri()

    def uri_mapper(uri: str) -> str:
        return dsig_uri if is_remote_dsig(uri) else uri

    t0 = time.perf_counter()
    schema = xmlschema.XMLSchema10(str(sd / ROOT_XSD), uri_mapper=uri_mapper, allow="local")
    t1 = time.perf_counter()
    n = _register_substitutes(schema) if register_substitutes else 0
    log.debug(
        "xmlschema: loaded %s in %.2f s, %d substitution-group registrations in %.2f s",
        sd / ROOT_XSD,
        t1 - t0,
        n,
        time.perf_counter() - t1,
    )
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


_RE_XS_NOT_FOUND = re.compile(
    r"value \((?P<vals>.*)\) not found for Xsd(?:Key|Unique)\(name='(?P<key>[^']+)'\)"
    r"(?: \((?P<times>\d+) times\))?"
)
_RE_XS_DUP = re.compile(
    r"duplicated value \((?P<vals>.*)\) for Xsd(?P<kind>Key|Unique)\(name='(?P<key>[^']+)'\)"
)
_RE_XS_VALUE = re.compile(r"Decimal\('([^']*)'\)|'((?:[^'\\]|\\.)*)'|\"([^\"]*)\"|([-\w.+]+)")


def _xs_values(text: str) -> tuple[str, ...]:
    """Values of a repr'd key tuple such as ``Decimal('10'),`` -> ('10',)."""
    vals = []
    for m in _RE_XS_VALUE.finditer(text):
        v = next((g for g in m.groups() if g is not None), "")
        if v in ("Decimal", ""):
            continue
        vals.append(norm_value(v))
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
    if (
        isinstance(err, xmlschema.XMLSchemaDecodeError)
        or "Atomic" in cls
        or cls in ("XsdList", "XsdUnion", "XsdSimpleType")
    ):
        return "datatype"
    if cls in ("XsdElement", "XsdGroup", "XsdComplexType"):
        return "content"
    return cls.removeprefix("Xsd").lower() or "schema"


def xmlschema_findings(
    tree: etree._ElementTree, sd: Path, register_substitutes: bool = True
) -> list[Finding]:
    """The xmlschema findings of a parsed QIF document (see :func:`validate_xmlschema`).

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document (:func:`qifreport.qif.xsd.parse_document`).
    sd : Path
        The schema folder.
    register_substitutes : bool
        False shows stock xmlschema's behaviour (without the substitution-group workaround).

    Returns
    -------
    list of Finding
        An entity reference in the tree gives the one finding ``entity`` (xmlschema is not
        run); an exception of xmlschema's validation the finding ``internal`` after those
        reported until then.
    """
    schema = xmlschema_schema(sd, register_substitutes)
    idents = identity_constraints(sd)
    ent = next(tree.getroot().iter(etree.Entity), None)
    if ent is not None:
        return [
            Finding(
                "xmlschema",
                ent.sourceline,
                "entity",
                f"entity reference {ent.text} not expanded: DTD/entity declarations are not "
                "allowed in a QIF document (not validated)",
            )
        ]
    out: list[Finding] = []
    try:
        _collect_findings(schema, idents, tree, out)
    except Exception as exc:  # xmlschema raises on what it cannot validate
        detail = " ".join(str(getattr(exc, "message", None) or exc).split())[:300]
        out.append(
            Finding(
                "xmlschema",
                None,
                "internal",
                f"xmlschema could not validate the document: {type(exc).__name__}: {detail}",
            )
        )
    return out


def _collect_findings(
    schema: Any, idents: dict[str, IdentityConstraint], tree: etree._ElementTree, out: list[Finding]
) -> None:
    """Append the findings of xmlschema's errors on ``tree`` to ``out``."""
    if tree.getroot().xpath("boolean(//comment() | //processing-instruction())"):
        # xmlschema takes an lxml comment inside simple content for a child element ("a
        # simple content element can't have child elements"): drop them, lines are kept
        tree = copy.deepcopy(tree)
        etree.strip_tags(tree, etree.Comment, etree.ProcessingInstruction)
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
            out.append(
                Finding(
                    "xmlschema",
                    line,
                    f"{m.group('kind').lower()} {key}",
                    f"duplicated value {vals} for {m.group('kind').lower()} {key}",
                )
            )
            continue
        elem = local_name(err.elem.tag) if err.elem is not None else ""
        kind = _xs_kind(err)
        index = getattr(err, "index", None)
        if isinstance(index, int) and err.elem is not None and 0 <= index < len(err.elem):
            line = err.elem[index].sourceline or line  # the unexpected child, as libxml2
        if kind == "attribute":
            a = re.search(r"attribute '([^']+)'|'([^']+)' attribute", reason)
            if a:
                elem += "@" + local_name(a.group(1) or a.group(2))
        km = re.match(r"missing key field '([^']*)'", reason)
        if km:  # the constraint is not named; find the keys that select this element
            names = keys_selecting(tree, idents, err.elem, km.group(1))
            kind, elem = "key", " ".join(names) or elem
            reason = f"missing key field '{km.group(1)}' of key {elem}"
        out.append(Finding("xmlschema", line, f"{kind} {elem}".strip(), strip_ns(reason)))


def _xs_keyref_findings(
    tree: etree._ElementTree,
    idents: dict[str, IdentityConstraint],
    m: re.Match[str],
    err: Any,
    line: int | None,
) -> list[Finding]:
    """One finding per dangling reference, located and named by the violated keyref.

    xmlschema names only the referred key and reports at the scope element; the keyrefs of
    that scope referring to the key are evaluated to find which one, and where.
    """
    key = m.group("key").split(":")[-1]
    vals = _xs_values(m.group("vals"))
    scope = local_name(err.elem.tag) if err.elem is not None else None
    cands = [
        i
        for i in idents.values()
        if i.kind == "keyref" and i.refer == key and (scope is None or i.scope == scope)
    ]
    shown = ", ".join(vals)
    out = []
    for ident in cands:
        for ln in locate_references(tree, ident, vals):
            out.append(
                Finding(
                    "xmlschema",
                    ln,
                    f"keyref {ident.name}",
                    f"value {shown} not found for key {key} (keyref {ident.name})",
                )
            )
    if not out:
        name = cands[0].name if len(cands) == 1 else f"-> {key}"
        times = f" ({m.group('times')} times)" if m.group("times") else ""
        out.append(
            Finding(
                "xmlschema", line, f"keyref {name}", f"value {shown} not found for key {key}{times}"
            )
        )
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
        No XSD folder (see :func:`qifreport.qif.xsd.schema_dir`).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    DocumentRefused
        Not a regular file, too large, or with a DOCTYPE
        (:func:`qifreport.qif.xsd.parse_document`).
    """
    sd = schema_dir()
    return xmlschema_findings(parse_document(Path(path)), sd)
