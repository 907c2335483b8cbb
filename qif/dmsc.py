"""The DMSC QIF checks: ``Check.xsl`` (XSLT 1.0) run through ``lxml.etree.XSLT``.

:func:`dmsc_checks` runs the DMSC XSLT checks on a QIF file; their ``CheckReport`` is parsed
into :class:`~qifreport.qif.findings.Finding` objects by
:func:`~qifreport.qif.dmsc_report.parse_check_report`. The checks' ``urn:my-scripts``
array-length functions are supplied here; the XSLT runs with an access control that denies
network reads, and the documents its ``document()`` calls load go through
:class:`~qifreport.qif.dmsc_documents.LinkedDocResolver`, which serves the linked documents
(``ExternalQIFReferences``) itself, or refuses them (:mod:`qifreport.qif.dmsc_documents`).

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
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lxml import etree

from .dmsc_documents import (
    DmscRun,
    LinkedDocResolver,
    fixed_findings,
    local_path,
    refused_findings,
    resolved_path,
)
from .dmsc_report import LinkedRoots, parse_check_report, report_missing_documents
from .findings import Finding
from .xsd import QIF_NS, checks_dir, parse_document, xml_parser

__all__ = [
    "DMSC_TIMEOUT_S",
    "dmsc_checks",
    "dmsc_findings",
]


#: the time limit of one DMSC run, seconds (far above what a document of the corpus takes)
DMSC_TIMEOUT_S = 300.0


log = logging.getLogger("qifreport.validate")


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
class _Checks:
    """Check.xsl compiled, the resolver its ``document()`` calls go through, and its lock."""

    xslt: etree.XSLT
    resolver: LinkedDocResolver
    #: held for a whole run (released by the worker thread when the transform ends)
    lock: threading.Lock = field(default_factory=threading.Lock)


def _with_deadline(fn: Any, resolver: LinkedDocResolver) -> Any:
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
    resolver = LinkedDocResolver(cd)
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


#: the C stack of the worker thread the XSLT runs in (libxslt recurses; a thread's default
#: can be as small as 2 MiB where the main thread's is 8 MiB or more)
_WORKER_STACK = 64 * 1024 * 1024
_STACK_LOCK = threading.Lock()


def _transform(checks: _Checks, work: etree._ElementTree, run: DmscRun, timeout: float) -> Any:
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
    local = local_path(url) if url else None
    if local is not None:
        d = resolved_path(local.absolute().parent)
        if d is not None and d not in roots:
            roots.append(d)
    return tuple(roots)


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
    run = DmscRun(roots=_roots(tree, path), deadline=time.monotonic() + timeout)
    box = _transform(checks, work, run, timeout)
    if box is None or isinstance(box.get("error"), _Timeout):
        return [
            *extra,
            _format_finding(
                "timeout", f"the DMSC checks did not finish within {timeout:g} s; not checked"
            ),
        ]
    refused = refused_findings(run, work, path)
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
    extra.extend(fixed_findings(run, path))
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
        report_missing_documents(report)
    linked = LinkedRoots(path, run)
    return [*parse_check_report(report, tree.getroot(), linked, extra), *refused]


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
