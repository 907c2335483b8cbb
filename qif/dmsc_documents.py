"""The documents linked from a QIF file that the DMSC checks load: served, or refused.

Linked documents (``ExternalQIFReferences``) are named by the file being checked, which may be
hostile. :class:`LinkedDocResolver` serves every one of them itself, read with the checks of
:func:`qifreport.qif.xsd.read_document` and parsed with the safe parser (no DTD, no entity
expansion; libxslt's own loader would expand external entities), and only if it is

* a local file (no network URL) inside the checked document's own folder tree (symbolic links
  and ``..`` resolved first: an absolute path elsewhere, ``/dev/...`` or ``../x.QIF`` is
  refused),
* a regular file (never a device, FIFO or socket) of at most
  :data:`~qifreport.qif.xsd.MAX_DOCUMENT_BYTES`, all linked documents of a run together at
  most :data:`LINKED_BYTES_BUDGET`, well-formed and without a DOCTYPE.

A refused document is served as "not found" (the checks report it so and go on) and reported
as a ``CheckDocuments`` error ``linked-document-refused`` (:func:`refused_findings`). Windows
separators in the ``URI`` of a linked document are fixed (:func:`fixed_findings`), and a
missing linked file is served as an empty placeholder (libxslt would abort the whole
transform). The checks themselves run in :mod:`qifreport.qif.dmsc`.
"""

from __future__ import annotations

import logging
import os
import re
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
    format_size,
    parse_document_bytes,
    read_document,
)

__all__ = [
    "LINKED_BYTES_BUDGET",
    "REFUSED_RULE",
    "DmscRun",
    "LinkedDocResolver",
    "fixed_findings",
    "local_path",
    "refused_findings",
    "resolved_path",
]

log = logging.getLogger("qifreport.validate")


#: the most bytes one DMSC run reads of linked documents, all of them together (200 MiB)
LINKED_BYTES_BUDGET = 2 * MAX_DOCUMENT_BYTES
#: the rule of a linked document the checks were not given (outside the folder, a device...)
REFUSED_RULE = "linked-document-refused"


@dataclass
class DmscRun:
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


def resolved_path(p: Path) -> Path | None:
    """``p`` with symbolic links and ``..`` resolved (None if that fails: a link loop...)."""
    try:
        return p.resolve()
    except (OSError, RuntimeError, ValueError):
        return None


_MISSING_DOC = b"<qifreport-document-not-found/>"
_RE_URI_BYTES = re.compile(rb"(<(?:[\w.-]+:)?URI\s*>)([^<]*)(</(?:[\w.-]+:)?URI\s*>)")
_RE_NETWORK_URL = re.compile(r"^[a-zA-Z][\w+.-]+://")


def local_path(url: str) -> Path | None:
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


class LinkedDocResolver(etree.Resolver):
    """Serves the documents the checks' ``document()`` calls load, or refuses them.

    The checks' own files (the ``.xsl`` files and ``CheckParameters.xml`` beside
    ``Check.xsl``, part of the installation) load normally. Any other document is read
    here, during a run (:attr:`run`), only if it passes :meth:`_load` (inside the checked
    document's folder tree, regular, size limits, well-formed, no DOCTYPE) and is served as
    bytes, parsed by the stylesheet's parser (no DTD, no entity expansion). A refused or
    missing document is served as an empty placeholder, so that the checks report it as not
    found and go on (libxslt would abort the whole transform). Windows separators in the
    ``URI`` of a linked document (``.\\Exploded_Plan.QIF``, not a URI reference: libxslt
    aborts) are replaced by ``/`` and the fix recorded in :attr:`DmscRun.fixed`.
    """

    def __init__(self, checks: Path) -> None:
        super().__init__()
        self.checks = checks
        #: the run in progress (None between runs)
        self.run: DmscRun | None = None

    def resolve(self, url: str | None, pubid: str | None, context: Any) -> Any:
        if not url:
            return None
        local = local_path(url)
        p = resolved_path(local) if local is not None else None
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
    def _load(url: str, p: Path | None, run: DmscRun) -> bytes:
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


def _fix_separators(p: Path, data: bytes, run: DmscRun) -> bytes:
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


def refused_findings(run: DmscRun, work: etree._ElementTree, path: Path) -> list[Finding]:
    """A ``CheckDocuments`` finding per linked document refused.

    One the checked document links to is an error at its ``URI`` element; one a linked
    document links to a warning, as the other findings about linked documents.
    """
    url = work.docinfo.URL
    local = local_path(url) if url else None
    base = local.absolute().parent if local is not None else path.parent
    uris = []
    for el in work.getroot().iterfind(
        f"{{{QIF_NS}}}ExternalQIFReferences/{{{QIF_NS}}}ExternalQIFDocument/{{{QIF_NS}}}URI"
    ):
        text = (el.text or "").strip()
        lp = local_path(text)
        uris.append((text, resolved_path(base / lp) if lp is not None else None, el.sourceline))
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


def fixed_findings(run: DmscRun, path: Path) -> list[Finding]:
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
