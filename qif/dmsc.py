"""The DMSC QIF checks: ``Check.xsl`` (XSLT 1.0) run through ``lxml.etree.XSLT``.

:func:`dmsc_checks` runs the DMSC XSLT checks on a QIF file and parses their ``CheckReport``
into :class:`Finding` objects with their category (``CheckFormat``, ``CheckQuality``,
``CheckSemantic``, ``CheckConstraints``; ``CheckDocuments`` for the linked-document checks),
a rule naming the check and the line of the reported node. The checks' ``urn:my-scripts``
array-length functions are supplied here; the XSLT runs with an access control that denies
network reads, and the documents its ``document()`` calls load go through
:class:`_LinkedDocResolver`.

Linked documents (``ExternalQIFReferences``) are named by the file being checked, which may be
hostile. The resolver serves every one of them itself, read with the checks of
:func:`qifreport.qif.xsd.read_document` and parsed with the safe parser (no DTD, no entity
expansion; libxslt's own loader would expand external entities), and only if it is

* a local file (no network URL) inside the checked document's own folder tree (symbolic links
  and ``..`` resolved first: an absolute path elsewhere, ``/dev/...`` or ``../x.QIF`` is
  refused),
* a regular file (never a device, FIFO or socket) of at most
  :data:`~qifreport.qif.xsd.MAX_DOCUMENT_BYTES`, all linked documents of a run together at
  most :data:`LINKED_BYTES_BUDGET`, well-formed and without a DOCTYPE.

A refused document is served as "not found" (the checks report it so and go on) and reported
as a ``CheckDocuments`` error ``linked-document-refused`` ("linked document refused: WHY").
The whole run (the XSLT and the documents it loads) is bounded by :data:`DMSC_TIMEOUT_S`:
it runs in a worker thread, and a run over time is reported as a ``CheckFormat`` error
``timeout`` (its extension functions and resolver stop it at their next call).

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
import math
import os
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlparse
from urllib.request import url2pathname

from lxml import etree

from .findings import Finding
from .xsd import (
    MAX_DOCUMENT_BYTES,
    QIF_NS,
    DocumentRefused,
    checks_dir,
    format_size,
    parse_document,
    parse_document_bytes,
    read_document,
    xml_parser,
)

__all__ = [
    "DMSC_TIMEOUT_S",
    "LINKED_BYTES_BUDGET",
    "REFUSED_RULE",
    "dmsc_checks",
    "dmsc_findings",
]

#: the time limit of one DMSC run, seconds (far above what a document of the corpus takes)
DMSC_TIMEOUT_S = 300.0
#: the most bytes one DMSC run reads of linked documents, all of them together (200 MiB)
LINKED_BYTES_BUDGET = 2 * MAX_DOCUMENT_BYTES
#: the rule of a linked document the checks were not given (outside the folder, a device...)
REFUSED_RULE = "linked-document-refused"

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


class _Timeout(Exception):
    """The time limit of a DMSC run is over (raised by its extension functions)."""


@dataclass
class _Run:
    """The state of one DMSC run: where linked documents may be, what was loaded and refused."""

    #: the checked document's folders (resolved): linked documents must be inside one
    roots: tuple[Path, ...]
    #: :func:`time.monotonic` time the run must end by
    deadline: float
    #: bytes of linked documents still allowed
    budget: int = LINKED_BYTES_BUDGET
    #: Windows separators fixed in linked documents: (file, line, old, new)
    fixed: list[tuple[Path, int, str, str]] = field(default_factory=list)
    #: linked documents not there
    missing: list[Path] = field(default_factory=list)
    #: linked documents refused: (URL, resolved path or None, why)
    refused: list[tuple[str, Path | None, str]] = field(default_factory=list)
    #: linked documents served (resolved paths), read again for line numbers
    served: set[Path] = field(default_factory=set)


@dataclass
class _Checks:
    """Check.xsl compiled, the resolver its ``document()`` calls go through, and its lock."""

    xslt: etree.XSLT
    resolver: _LinkedDocResolver
    #: held for a whole run (released by the worker thread when the transform ends)
    lock: threading.Lock = field(default_factory=threading.Lock)


def _with_deadline(fn: Any, resolver: _LinkedDocResolver) -> Any:
    """An extension function that ends the transform once the run's time is over."""

    def call(context: Any, *args: Any) -> Any:
        run = resolver.run
        if run is not None and time.monotonic() > run.deadline:
            raise _Timeout
        return fn(context, *args)

    return call


@functools.lru_cache(maxsize=4)
def _dmsc_xslt(cd: Path) -> _Checks:
    """Check.xsl compiled, with the resolver its ``document()`` calls go through."""
    t0 = time.perf_counter()
    access = etree.XSLTAccessControl(
        read_file=True, write_file=False, create_dir=False, read_network=False, write_network=False
    )
    resolver = _LinkedDocResolver(cd)
    extensions = {
        ("urn:my-scripts", "LengthArrayDouble"): _with_deadline(_array_length(float), resolver),
        ("urn:my-scripts", "LengthArrayInt"): _with_deadline(_array_length(int), resolver),
    }
    xslt = etree.XSLT(
        etree.parse(str(cd / "Check.xsl"), xml_parser(resolver)),
        access_control=access,
        extensions=extensions,
    )
    log.debug("dmsc: compiled %s in %.3f s", cd / "Check.xsl", time.perf_counter() - t0)
    return _Checks(xslt, resolver)


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
    report: etree._Element, root: etree._Element, linked: _LinkedRoots, extra: list[Finding]
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
    block: etree._Element, root: etree._Element, linked: _LinkedRoots, chain: tuple[str, ...]
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
    linked: _LinkedRoots,
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


def _resolved(p: Path) -> Path | None:
    """``p`` with symbolic links and ``..`` resolved (None if that fails: a link loop...)."""
    try:
        return p.resolve()
    except (OSError, RuntimeError, ValueError):
        return None


class _LinkedRoots:
    """The roots of the linked documents a run was served, for line numbers (each read once).

    Only documents the resolver served (inside the checked document's folder, regular, within
    the size limits) are read again, with the same checks.
    """

    def __init__(self, base: Path, run: _Run) -> None:
        self.base = base
        self.run = run
        self._roots: dict[Path, etree._Element | None] = {}

    def root(self, chain: tuple[str, ...]) -> etree._Element | None:
        """The root of the document a chain of URIs leads to (relative to each referrer)."""
        here = self.base
        root = None
        for uri in chain:
            p = _resolved(here.parent / uri.replace("\\", "/")) if "://" not in uri else None
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


_MISSING_DOC = b"<qifreport-document-not-found/>"
_RE_URI_BYTES = re.compile(rb"(<(?:[\w.-]+:)?URI\s*>)([^<]*)(</(?:[\w.-]+:)?URI\s*>)")
_RE_NETWORK_URL = re.compile(r"^[a-zA-Z][\w+.-]+://")


def _local_path(url: str) -> Path | None:
    """The local file a URL of ``document()`` names; None if it is not one (a network URL)."""
    if url.startswith("file:"):
        parsed = urlparse(url)
        if parsed.netloc not in ("", "localhost"):
            return None
        return Path(url2pathname(parsed.path))
    if _RE_NETWORK_URL.match(url):
        return None
    return Path(url)


def _is_checks_file(p: Path) -> bool:
    """A file of the DMSC checks themselves (an XSLT, CheckParameters.xml), not a QIF file."""
    return p.suffix.lower() == ".xsl" or p.name == "CheckParameters.xml"


class _LinkedDocResolver(etree.Resolver):
    """Serves the documents the checks' ``document()`` calls load, or refuses them.

    The checks' own files (the ``.xsl`` files and ``CheckParameters.xml`` beside
    ``Check.xsl``, part of the installation) load normally. Any other document is read
    here, during a run (:attr:`run`), only if it passes :meth:`_load` (inside the checked
    document's folder tree, regular, size limits, well-formed, no DOCTYPE) and is served as
    bytes, parsed by the stylesheet's parser (no DTD, no entity expansion). A refused or
    missing document is served as an empty placeholder, so that the checks report it as not
    found and go on (libxslt would abort the whole transform). Windows separators in the
    ``URI`` of a linked document (``.\\Exploded_Plan.QIF``, not a URI reference: libxslt
    aborts) are replaced by ``/`` and the fix recorded in :attr:`_Run.fixed`.
    """

    def __init__(self, checks: Path) -> None:
        super().__init__()
        self.checks = checks
        #: the run in progress (None between runs)
        self.run: _Run | None = None

    def resolve(self, url: str | None, pubid: str | None, context: Any) -> Any:
        if not url:
            return None
        local = _local_path(url)
        p = _resolved(local) if local is not None else None
        if p is not None and p.parent == self.checks and _is_checks_file(p):
            return None  # the checks' own files (CheckParameters.xml, the included checks)
        run = self.run
        if run is None:
            return None  # compiling Check.xsl: only its own files are loaded
        try:
            if local is not None and p is None:
                raise DocumentRefused(url, "its path cannot be resolved")
            data = self._load(url, p, run)
        except FileNotFoundError:
            # libxslt would abort the transform; a placeholder without a QIFDocument
            # lets the checks report the document as not found and go on
            run.missing.append(p or Path(url))
            return self.resolve_string(_MISSING_DOC, context, base_url=url)
        except DocumentRefused as exc:
            log.debug("dmsc: linked document refused: %s", exc)
            run.refused.append((url, p, exc.reason))
            return self.resolve_string(_MISSING_DOC, context, base_url=url)
        except Exception as exc:  # never let a linked document end the whole run
            run.refused.append((url, p, f"cannot be read ({type(exc).__name__}: {exc})"))
            return self.resolve_string(_MISSING_DOC, context, base_url=url)
        return self.resolve_string(_fix_separators(p, data, run), context, base_url=url)

    @staticmethod
    def _load(url: str, p: Path | None, run: _Run) -> bytes:
        """The bytes of a linked document, if it may be read.

        Raises
        ------
        DocumentRefused
            A network URL, outside the checked document's folder tree, not a regular file,
            over :data:`~qifreport.qif.xsd.MAX_DOCUMENT_BYTES` or over what is left of
            :data:`LINKED_BYTES_BUDGET`, not well-formed, with a DOCTYPE; or the time of the
            run is over.
        FileNotFoundError
            It is not there.
        """
        if p is None:
            raise DocumentRefused(url, "not a local file (network access is not allowed)")
        if time.monotonic() > run.deadline:
            raise DocumentRefused(url, "the time limit of the DMSC checks is over")
        if not any(p == r or p.is_relative_to(r) for r in run.roots):
            raise DocumentRefused(
                url, f"outside the folder of the checked document ({run.roots[0]})"
            )
        try:
            data = read_document(p)
        except (FileNotFoundError, DocumentRefused):
            raise
        except OSError as exc:
            raise DocumentRefused(url, f"cannot be read ({exc.strerror or exc})") from None
        if len(data) > run.budget:
            raise DocumentRefused(
                url,
                f"the linked documents of one run are limited to "
                f"{format_size(LINKED_BYTES_BUDGET)} in all",
            )
        run.budget -= len(data)
        try:
            parse_document_bytes(data, str(p), base_url=url)
        except etree.XMLSyntaxError as exc:
            detail = " ".join(str(exc).split())
            raise DocumentRefused(url, f"not well-formed XML ({detail})") from None
        run.served.add(p)
        return data


def _fix_separators(p: Path, data: bytes, run: _Run) -> bytes:
    """``data`` with ``\\`` replaced by ``/`` in its ``URI`` elements, the fixes recorded."""
    if b"\\" not in data:
        return data
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
    run.fixed.extend(fixed)
    return out


#: the C stack of the worker thread the XSLT runs in (libxslt recurses; a thread's default
#: can be as small as 2 MiB where the main thread's is 8 MiB or more)
_WORKER_STACK = 64 * 1024 * 1024
_STACK_LOCK = threading.Lock()


def _transform(checks: _Checks, work: etree._ElementTree, run: _Run, timeout: float) -> Any:
    """Run Check.xsl on ``work`` in a worker thread, for at most ``timeout`` seconds.

    Returns
    -------
    dict or None
        ``{"result": tree}``, or ``{"error": exception, "log": [messages]}``; None if the
        transform did not end in time (it is left to end at its next callback, with the
        compiled checks it holds: the next run compiles its own).
    """
    t0 = time.monotonic()
    if not checks.lock.acquire(timeout=timeout):
        return None
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["result"] = checks.xslt(work)
        except BaseException as exc:
            box["error"] = exc
            box["log"] = [e.message for e in checks.xslt.error_log if e.message]
        finally:
            checks.resolver.run = None
            checks.lock.release()

    checks.resolver.run = run
    worker = threading.Thread(target=target, name="qifreport-dmsc", daemon=True)
    try:
        with _STACK_LOCK:
            old = threading.stack_size(_WORKER_STACK)
            try:
                worker.start()
            finally:
                threading.stack_size(old)
    except BaseException:
        checks.resolver.run = None
        checks.lock.release()
        raise
    worker.join(max(0.0, timeout - (time.monotonic() - t0)))
    if worker.is_alive():
        run.deadline = -math.inf  # its extension functions and resolver end it
        _dmsc_xslt.cache_clear()
        return None
    return box


def _roots(tree: etree._ElementTree, path: Path) -> tuple[Path, ...]:
    """The folders linked documents may be in: the checked document's (as named, resolved)."""
    roots = [path.resolve().parent]
    url = tree.docinfo.URL
    local = _local_path(url) if url else None
    if local is not None:
        d = _resolved(local.absolute().parent)
        if d is not None and d not in roots:
            roots.append(d)
    return tuple(roots)


def _refused_findings(run: _Run, work: etree._ElementTree, path: Path) -> list[Finding]:
    """A ``CheckDocuments`` finding per linked document refused.

    One the checked document links to is an error at its ``URI`` element; one a linked
    document links to a warning, as the other findings about linked documents.
    """
    url = work.docinfo.URL
    local = _local_path(url) if url else None
    base = local.absolute().parent if local is not None else path.parent
    uris = []
    for el in work.getroot().iterfind(
        f"{{{QIF_NS}}}ExternalQIFReferences/{{{QIF_NS}}}ExternalQIFDocument/{{{QIF_NS}}}URI"
    ):
        text = (el.text or "").strip()
        lp = _local_path(text)
        uris.append((text, _resolved(base / lp) if lp is not None else None, el.sourceline))
    out: list[Finding] = []
    for url_, p, why in dict.fromkeys(run.refused):
        direct = [
            (text, line) for text, rp, line in uris if (p is not None and rp == p) or text == url_
        ]
        if direct:
            text, line = direct[0]
            outside = p is not None and not any(p.is_relative_to(r) for r in run.roots)
            shown = f"{text} (= {p})" if outside and str(p) != text else text
            out.append(
                Finding(
                    "dmsc",
                    line,
                    REFUSED_RULE,
                    f"linked document refused: {shown}: {why}",
                    "CheckDocuments",
                    "error",
                )
            )
        else:
            out.append(
                Finding(
                    "dmsc",
                    None,
                    f"CheckDocuments:{REFUSED_RULE}",
                    f"in a linked document: linked document refused: {p or url_}: {why}",
                    "CheckDocuments",
                    "warning",
                )
            )
    return out


def _format_finding(rule: str, message: str) -> Finding:
    """A ``CheckFormat`` error of the run itself (no line): timeout, XSLT error, no report."""
    return Finding("dmsc", None, rule, message, "CheckFormat")


def _backslash_uris(tree: etree._ElementTree) -> tuple[etree._ElementTree, list[Finding]]:
    """The document the checks run on and an ``external-URI`` finding per ``URI`` with
    Windows separators: when there is one, a copy of ``tree`` (the base URL and the line
    numbers kept) with them turned into ``/`` (libxslt aborts on them), else ``tree``."""
    extra: list[Finding] = []
    bad = [
        u
        for u in tree.getroot().iterfind(
            f"{{{QIF_NS}}}ExternalQIFReferences/{{{QIF_NS}}}ExternalQIFDocument/{{{QIF_NS}}}URI"
        )
        if "\\" in (u.text or "")
    ]
    if not bad:
        return tree, extra
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
    return work, extra


def _fixed_findings(run: _Run, path: Path) -> list[Finding]:
    """A ``CheckDocuments`` warning per URI with Windows separators the resolver fixed in a
    linked document (its file named relative to the checked document ``path``)."""
    out: list[Finding] = []
    for p, line, old, new in dict.fromkeys(run.fixed):
        try:
            shown = os.path.relpath(p, path.parent)
        except ValueError:
            shown = str(p)
        out.append(
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
    return out


def dmsc_findings(
    tree: etree._ElementTree, path: Path, cd: Path, *, timeout: float = DMSC_TIMEOUT_S
) -> list[Finding]:
    """The DMSC findings of a parsed QIF document (see :func:`dmsc_checks`).

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document (:func:`qifreport.qif.xsd.parse_document`).
    path : Path
        Its file, resolved (linked documents are relative to it and must be in its folder).
    cd : Path
        The folder of ``Check.xsl`` (:func:`qifreport.qif.xsd.checks_dir`).
    timeout : float
        The time limit of the run, seconds (:data:`DMSC_TIMEOUT_S`); over it, the finding
        ``timeout`` (``CheckFormat`` error) is all that is reported.

    Returns
    -------
    list of Finding
    """
    if not timeout > 0:
        raise ValueError(f"timeout must be positive, not {timeout!r}")
    checks = _dmsc_xslt(cd)
    work, extra = _backslash_uris(tree)
    run = _Run(roots=_roots(tree, path), deadline=time.monotonic() + timeout)
    box = _transform(checks, work, run, timeout)
    if box is None or isinstance(box.get("error"), _Timeout):
        return [
            *extra,
            _format_finding(
                "timeout", f"the DMSC checks did not finish within {timeout:g} s; not checked"
            ),
        ]
    refused = _refused_findings(run, work, path)
    exc = box.get("error")
    if isinstance(exc, etree.XSLTApplyError):
        detail = "; ".join(dict.fromkeys(box.get("log", []))) or str(exc)
        return [
            *extra,
            _format_finding("xslt-error", f"the DMSC checks could not run: {detail}"),
            *refused,
        ]
    if exc is not None:
        raise exc
    result = box["result"]
    extra.extend(_fixed_findings(run, path))
    report = result.getroot()
    if report is None or report.tag != "CheckReport":
        return [
            *extra,
            _format_finding(
                "no-report",
                "Check.xsl produced no CheckReport (is the root element "
                "QIFDocument in the QIF 3.0 namespace?)",
            ),
            *refused,
        ]
    if run.missing or run.refused:
        _report_missing_documents(report)
    linked = _LinkedRoots(path, run)
    return [*_parse_check_report(report, tree.getroot(), linked, extra), *refused]


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
