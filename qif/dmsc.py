"""The DMSC QIF checks: ``Check.xsl`` (XSLT 1.0) run through ``lxml.etree.XSLT``.

:func:`dmsc_checks` runs the DMSC XSLT checks on a QIF file and parses their ``CheckReport``
into :class:`Finding` objects with their category (``CheckFormat``, ``CheckQuality``,
``CheckSemantic``, ``CheckConstraints``; ``CheckDocuments`` for the linked-document checks),
a rule naming the check and the line of the reported node. The checks' ``urn:my-scripts``
array-length functions are supplied here; the XSLT runs with an access control that denies
network reads, and the documents its ``document()`` calls load go through
:class:`_LinkedDocResolver`.

Workaround, for a defect of libxslt: it aborts the whole transform when ``document()`` meets
a URI with Windows separators (``.\\Exploded_Results1.QIF``, as in the DMSC community samples)
or a linked file that is not there. Such a URI in the checked file is a ``CheckFormat`` error
(``external-URI``) and is checked as ``./Exploded_Results1.QIF``; in a linked file it is fixed
the same way by the resolver the checks load documents through (a warning); a missing linked
file is served as an empty placeholder so that the checks report it as DMSC does ("The
external document was not found") and go on.
"""

from __future__ import annotations

import copy
import functools
import logging
import os
import re
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlparse
from urllib.request import url2pathname

from lxml import etree

from .findings import Finding
from .xsd import QIF_NS, checks_dir, parse_document, xml_parser

__all__ = ["dmsc_checks", "dmsc_findings"]

log = logging.getLogger("qifreport.validate")

#: severity of a DMSC finding about this document, per category (quality checks are advice)
_DMSC_SEVERITY = {
    "CheckFormat": "error",
    "CheckSemantic": "error",
    "CheckConstraints": "error",
    "CheckDocuments": "error",
    "CheckQuality": "warning",
}


def _array_length(kind: type) -> Any:
    """The ``urn:my-scripts`` extension functions the checks call (C# in checkLibraryMSXML)."""

    def length(_context: Any, arg: Any) -> int:
        if isinstance(arg, list):
            arg = (
                "".join(arg[0].itertext())
                if arg and isinstance(arg[0], etree._Element)
                else (str(arg[0]) if arg else "")
            )
        try:
            return len([kind(x) for x in str(arg).split()])
        except ValueError:
            return -1

    return length


@functools.lru_cache(maxsize=4)
def _dmsc_xslt(cd: Path) -> tuple[etree.XSLT, _LinkedDocResolver]:
    """Check.xsl compiled, with the resolver its ``document()`` calls go through."""
    t0 = time.perf_counter()
    access = etree.XSLTAccessControl(
        read_file=True, write_file=False, create_dir=False, read_network=False, write_network=False
    )
    extensions = {
        ("urn:my-scripts", "LengthArrayDouble"): _array_length(float),
        ("urn:my-scripts", "LengthArrayInt"): _array_length(int),
    }
    resolver = _LinkedDocResolver(cd)
    xslt = etree.XSLT(
        etree.parse(str(cd / "Check.xsl"), xml_parser(resolver)),
        access_control=access,
        extensions=extensions,
    )
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


def _parse_check_report(
    report: etree._Element, root: etree._Element, base: Path, extra: list[Finding]
) -> list[Finding]:
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
                out.append(
                    Finding(
                        "dmsc",
                        _node_line(root, err.findtext("Node")),
                        _dmsc_rule(text, cat),
                        text,
                        cat,
                        _DMSC_SEVERITY.get(cat, "error"),
                    )
                )
    return out


def _linked_findings(
    block: etree._Element, root: etree._Element, base: Path, chain: tuple[str, ...]
) -> list[Finding]:
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
                out.append(
                    Finding(
                        "dmsc",
                        _node_line(root, node),
                        _dmsc_rule(text, "CheckDocuments"),
                        text,
                        "CheckDocuments",
                        "error",
                    )
                )
            else:
                out.append(_linked_finding(chain[:-1], base, node, text, "CheckDocuments"))
        elif child.tag == "CheckLinkedDocument":
            out.extend(_linked_findings(child, root, base, chain))
        elif child.tag.startswith("Check"):
            for err in child.iter("Error"):
                text = (err.findtext("Report") or "").strip()
                f = _linked_finding(chain, base, err.findtext("Node"), text, child.tag, linked_root)
                out.append(f)
    return out


def _linked_finding(
    chain: tuple[str, ...],
    base: Path,
    node: str | None,
    text: str,
    inner: str,
    linked_root: etree._Element | None = None,
) -> Finding:
    if linked_root is None:
        linked_root = _load_linked(base, chain)
    ln = _node_line(linked_root, node) if linked_root is not None else None
    where = " -> ".join(chain) + (f" line {ln}" if ln else "")
    rule = _dmsc_rule(text, inner)
    return Finding(
        "dmsc",
        None,
        f"{inner}:{rule}",
        f"in linked document {where}: {text}",
        "CheckDocuments",
        "warning",
    )


def _load_linked(base: Path, chain: tuple[str, ...]) -> etree._Element | None:
    """The root of a linked document (URIs relative to the referring file), if readable."""
    here = base
    root = None
    for uri in chain:
        p = (here.parent / uri.replace("\\", "/")).resolve() if "://" not in uri else None
        if p is None or not p.is_file():
            return None
        try:
            root = etree.parse(str(p), xml_parser()).getroot()
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
            fixed.append(
                (
                    p,
                    line,
                    m.group(2).decode(errors="replace").strip(),
                    new.decode(errors="replace").strip(),
                )
            )
            return m.group(1) + new + m.group(3)

        out = _RE_URI_BYTES.sub(fix, data)
        if not fixed:
            return None
        self.fixed.extend(fixed)
        return self.resolve_string(out, context, base_url=url)


_DMSC_LOCK = threading.Lock()


def dmsc_findings(tree: etree._ElementTree, path: Path, cd: Path) -> list[Finding]:
    """The DMSC findings of a parsed QIF document (see :func:`dmsc_checks`).

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document (:func:`qifreport.qif.xsd.parse_document`).
    path : Path
        Its file, resolved (linked documents are relative to it).
    cd : Path
        The folder of ``Check.xsl`` (:func:`qifreport.qif.xsd.checks_dir`).

    Returns
    -------
    list of Finding
    """
    xslt, resolver = _dmsc_xslt(cd)
    extra: list[Finding] = []
    work = tree
    bad = [
        u
        for u in tree.getroot().iterfind(
            f"{{{QIF_NS}}}ExternalQIFReferences/{{{QIF_NS}}}ExternalQIFDocument/{{{QIF_NS}}}URI"
        )
        if "\\" in (u.text or "")
    ]
    if bad:
        work = copy.deepcopy(tree)  # keeps the base URL and the line numbers
        for uri_el in work.getroot().iter(f"{{{QIF_NS}}}URI"):
            text = (uri_el.text or "").strip()
            if "\\" in text:
                uri_el.text = text.replace("\\", "/")
                extra.append(
                    Finding(
                        "dmsc",
                        uri_el.sourceline,
                        "external-URI",
                        f"URI '{text}' is not a valid URI reference (backslash): an XSLT processor "
                        f"cannot load it (libxslt aborts); checked as '{uri_el.text}'",
                        "CheckFormat",
                    )
                )
    with _DMSC_LOCK:
        resolver.fixed.clear()
        resolver.missing.clear()
        try:
            result = xslt(work)
        except etree.XSLTApplyError as exc:
            msgs = [e.message for e in xslt.error_log if e.message]
            detail = "; ".join(dict.fromkeys(msgs)) or str(exc)
            return [
                *extra,
                Finding(
                    "dmsc",
                    None,
                    "xslt-error",
                    f"the DMSC checks could not run: {detail}",
                    "CheckFormat",
                ),
            ]
        linked_fixes = list(resolver.fixed)
        missing = bool(resolver.missing)
    for p, line, old, new in dict.fromkeys(linked_fixes):
        try:
            shown = os.path.relpath(p, path.parent)
        except ValueError:
            shown = str(p)
        extra.append(
            Finding(
                "dmsc",
                None,
                "CheckFormat:external-URI",
                f"in linked document {shown} line {line}: URI '{old}' is not a valid URI reference "
                f"(backslash); checked as '{new}'",
                "CheckDocuments",
                "warning",
            )
        )
    report = result.getroot()
    if report is None or report.tag != "CheckReport":
        return [
            *extra,
            Finding(
                "dmsc",
                None,
                "no-report",
                "Check.xsl produced no CheckReport (is the root element "
                "QIFDocument in the QIF 3.0 namespace?)",
                "CheckFormat",
            ),
        ]
    if missing:
        _report_missing_documents(report)
    return _parse_check_report(report, tree.getroot(), path, extra)


_RE_QPID_EMPTY = re.compile(
    r"The external document has a different QPId\.\s*"
    r"URI = (.*?),\s*QPId\(.*?\)\s*!= QPIdExt\(\)\.?$",
    re.S,
)


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
        ``Check.xsl`` not found (see :func:`qifreport.qif.xsd.checks_dir`).
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    p = Path(path)
    return dmsc_findings(parse_document(p), p.resolve(), checks_dir())
