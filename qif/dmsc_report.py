"""The findings of a DMSC ``CheckReport``: its errors as :class:`~qifreport.qif.findings.Finding`.

:func:`parse_check_report` turns each ``<Error>`` of the report the DMSC checks
(:mod:`qifreport.qif.dmsc`) produced into a finding with its category (``CheckFormat``,
``CheckQuality``, ``CheckSemantic``, ``CheckConstraints``; ``CheckDocuments`` for the
linked-document checks), a rule naming the check and the line of the reported node, in the
checked document or, for a finding inside a linked document, in that document
(:class:`LinkedRoots`).
"""

from __future__ import annotations

import re
from pathlib import Path

from lxml import etree

from .dmsc_documents import DmscRun, resolved_path
from .findings import Finding
from .xsd import DocumentRefused, parse_document_bytes, read_document

__all__ = [
    "LinkedRoots",
    "parse_check_report",
    "report_missing_documents",
]


#: severity of a DMSC finding about this document, per category (quality checks are advice)
_DMSC_SEVERITY = {
    "CheckFormat": "error",
    "CheckSemantic": "error",
    "CheckConstraints": "error",
    "CheckDocuments": "error",
    "CheckQuality": "warning",
}


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


def parse_check_report(
    report: etree._Element, root: etree._Element, linked: LinkedRoots, extra: list[Finding]
) -> list[Finding]:
    """Findings of a CheckReport; ``root`` is the checked document (for line numbers)."""
    out: list[Finding] = list(extra)
    for child in report:
        if not isinstance(child.tag, str):
            continue
        if child.tag == "CheckLinkedDocument":
            out.extend(_linked_findings(child, root, linked, chain=()))
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
    block: etree._Element, root: etree._Element, linked: LinkedRoots, chain: tuple[str, ...]
) -> list[Finding]:
    """Findings of a ``CheckLinkedDocument`` block (category ``CheckDocuments``).

    Errors directly in the block (cross-document reference checks, recursion limit) are about
    the referring document; those in its nested categories are about the linked file and are
    reported as warnings naming that file and its line.
    """
    uri = block.get("uri", "")
    chain = (*chain, uri)
    linked_root = linked.root(chain)
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
                out.append(_linked_finding(chain[:-1], linked, node, text, "CheckDocuments"))
        elif child.tag == "CheckLinkedDocument":
            out.extend(_linked_findings(child, root, linked, chain))
        elif child.tag.startswith("Check"):
            for err in child.iter("Error"):
                text = (err.findtext("Report") or "").strip()
                f = _linked_finding(
                    chain, linked, err.findtext("Node"), text, child.tag, linked_root
                )
                out.append(f)
    return out


def _linked_finding(
    chain: tuple[str, ...],
    linked: LinkedRoots,
    node: str | None,
    text: str,
    inner: str,
    linked_root: etree._Element | None = None,
) -> Finding:
    if linked_root is None:
        linked_root = linked.root(chain)
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


class LinkedRoots:
    """The roots of the linked documents a run was served, for line numbers (each read once).

    Only documents the resolver served (inside the checked document's folder, regular, within
    the size limits) are read again, with the same checks.
    """

    def __init__(self, base: Path, run: DmscRun) -> None:
        self.base = base
        self.run = run
        self._roots: dict[Path, etree._Element | None] = {}

    def root(self, chain: tuple[str, ...]) -> etree._Element | None:
        """The root of the document a chain of URIs leads to (relative to each referrer)."""
        here = self.base
        root = None
        for uri in chain:
            p = resolved_path(here.parent / uri.replace("\\", "/")) if "://" not in uri else None
            if p is None or p not in self.run.served:
                return None
            if p not in self._roots:
                try:
                    self._roots[p] = parse_document_bytes(read_document(p), str(p)).getroot()
                except (etree.XMLSyntaxError, DocumentRefused, OSError):
                    self._roots[p] = None
            root = self._roots[p]
            if root is None:
                return None
            here = p
        return root


_RE_QPID_EMPTY = re.compile(
    r"The external document has a different QPId\.\s*"
    r"URI = (.*?),\s*QPId\(.*?\)\s*!= QPIdExt\(\)\.?$",
    re.S,
)


def report_missing_documents(report: etree._Element) -> None:
    """Say "not found" where the checks compared a QPId with a missing document's."""
    for rep in report.iter("Report"):
        m = _RE_QPID_EMPTY.match(rep.text or "")
        if m:
            rep.text = f"The external document was not found URI = {m.group(1)}."
