"""Where the official QIF 3.0 material is, and how it is read without the network.

* :func:`schema_dir`: the folder of the official QIF 3.0 XSDs (``QIFApplications/``,
  ``QIFLibrary/``); :func:`checks_dir`: the folder of the DMSC XSLT checks (``Check.xsl``).
  Either raises :class:`SchemasUnavailable`, whose message says how to provide them.
* The remote W3C xmldsig import of ``QIFDocument.xsd`` is mapped to a local copy
  (:func:`dsig_path`: the schema folder's ``QIFLibrary/xmldsig-core-schema.xsd``, else the copy
  bundled with ``xmlschema``); :class:`LocalResolver` does it for libxml2 and refuses every
  other network URL.
* :func:`xml_parser` is the parser every QIF or XSD file is read with (``no_network``, no
  DTD loaded or validated, entities never expanded, libxml2's size and amplification limits
  kept: no ``huge_tree``).
* Hostile files: :func:`read_document` reads only a regular file (never a device, FIFO,
  socket or directory) of at most :data:`MAX_DOCUMENT_BYTES`, with a bounded read;
  :func:`parse_document_bytes` refuses a document with a DOCTYPE (DTD or entity declarations,
  billion laughs, XXE) before and after libxml2 sees it; :func:`parse_document` does both.
  What is refused raises :class:`DocumentRefused` (an :class:`~qifreport.errors.InputError`).
* :func:`strip_ns` and :func:`local_name` shorten the QIF namespace in what is reported.
"""

from __future__ import annotations

import codecs
import logging
import os
import re
import stat
from pathlib import Path
from typing import Any

from lxml import etree

from qifreport.errors import InputError, file_kind
from qifreport.schemas import QIF_XSD_DIR, SCHEMA_DIR

__all__ = [
    "DSIG_LOCAL",
    "DSIG_NAME",
    "ENV_CHECKS_DIR",
    "ENV_XSD_DIR",
    "MAX_DOCUMENT_BYTES",
    "QIF_NS",
    "REPO_ROOT",
    "ROOT_XSD",
    "XSD_NS",
    "DocumentRefused",
    "LocalResolver",
    "SchemasUnavailable",
    "checks_dir",
    "dsig_path",
    "format_size",
    "is_remote_dsig",
    "local_name",
    "parse_document",
    "parse_document_bytes",
    "read_document",
    "refuse_doctype",
    "schema_dir",
    "strip_ns",
    "schema_advice",
    "xml_parser",
]

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
#: the largest QIF document read (command line and linked documents alike): 100 MiB. A QIF
#: results file of a big part is a few MB; libxml2 builds a tree of 5-10 times the file size.
MAX_DOCUMENT_BYTES = 100 * 1024 * 1024
#: the repository root in an editable install (``../shared`` may sit beside it)
REPO_ROOT = SCHEMA_DIR.parent


def schema_advice() -> str:
    """How to give qifreport the QIF schemas, for the way it was installed: a source
    checkout (``make install`` copies them from ``../shared``) or a wheel (pip: point
    ``QIFREPORT_XSD_DIR`` at them, or copy them into the package)."""
    env = (
        f"set {ENV_XSD_DIR} to a folder holding QIFApplications/ and QIFLibrary/ (the "
        "official QIF 3.0 XSDs)"
    )
    if (REPO_ROOT / "Makefile").is_file() and (REPO_ROOT / "pyproject.toml").is_file():
        return (
            "run `make install` with ../shared beside the checkout (it copies the official "
            f"XSDs to {QIF_XSD_DIR}), or {env}"
        )
    return f"{env}, or copy those two folders into {QIF_XSD_DIR}"


class SchemasUnavailable(Exception):
    """The QIF 3.0 XSDs (or the DMSC checks) cannot be found; the message says how to fix it."""


class DocumentRefused(InputError):
    """A file that is not read or not parsed as a QIF document, the message saying why.

    Not a regular file (a device, FIFO, socket, directory), larger than
    :data:`MAX_DOCUMENT_BYTES`, or with a DOCTYPE (DTD/entity declarations). The message
    names the file and the problem on one line.

    Parameters
    ----------
    name : str
        The file (or URL), as the message is to name it.
    reason : str
        Why it is refused (``"not a regular file (a FIFO)"``...).

    Attributes
    ----------
    name, reason : str
        As given; the message is ``"NAME: REASON"``.
    """

    def __init__(self, name: str, reason: str) -> None:
        super().__init__(f"{name}: {reason}")
        self.name = name
        self.reason = reason


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
            f"{schema_advice()}"
        )
    candidates = [QIF_XSD_DIR, REPO_ROOT.parent / "shared" / "qif" / "xsd"]
    for p in candidates:
        if _is_schema_dir(p):
            return p.resolve()
    raise SchemasUnavailable(
        "QIF 3.0 XSD schemas not found (looked in "
        + ", ".join(map(str, candidates))
        + f" and {ENV_XSD_DIR} is not set); {schema_advice()}"
    )


def checks_dir() -> Path:
    """The folder of the DMSC XSLT checks (``Check.xsl``, ``CheckParameters.xml``).

    Looked up in this order: ``$QIFREPORT_CHECKS_DIR`` (if set, it must be right),
    ``<repo>/schemas/qif-checks``, the ``checks`` folder beside ``$QIFREPORT_XSD_DIR``,
    ``<repo>/../shared/qif/checks``. A folder counts if it contains ``Check.xsl``.

    Returns
    -------
    Path
        Absolute path of the folder.

    Raises
    ------
    SchemasUnavailable
        If none is found; the message says how to provide them (or skip the checks).
    """
    env = os.environ.get(ENV_CHECKS_DIR)
    if env:
        p = Path(env).expanduser()
        if (p / "Check.xsl").is_file():
            return p.resolve()
        raise SchemasUnavailable(
            f"DMSC checks not found: {ENV_CHECKS_DIR}={env} has no "
            "Check.xsl; point it at the folder of Check.xsl and "
            "CheckParameters.xml, or skip the checks (--no-checks)"
        )
    candidates = [SCHEMA_DIR / "qif-checks"]
    xsd_env = os.environ.get(ENV_XSD_DIR)
    if xsd_env:
        candidates.append(Path(xsd_env).expanduser().parent / "checks")
    candidates.append(REPO_ROOT.parent / "shared" / "qif" / "checks")
    for p in candidates:
        if (p / "Check.xsl").is_file():
            return p.resolve()
    raise SchemasUnavailable(
        "DMSC checks (Check.xsl) not found (looked in "
        + ", ".join(map(str, candidates))
        + f"); set {ENV_CHECKS_DIR} to the folder of Check.xsl, or skip the checks (--no-checks)"
    )


# ---------------------------------------------------------------------------------------------
# the xmldsig import, resolvers and parsers (no network)


def dsig_path(sd: Path) -> Path:
    """Local copy of the W3C xmldsig schema: the schema folder's, else xmlschema's bundled one.

    Parameters
    ----------
    sd : Path
        A schema folder (:func:`schema_dir`).

    Returns
    -------
    Path
        ``sd/QIFLibrary/xmldsig-core-schema.xsd`` if it exists, else the copy in the
        ``xmlschema`` package.
    """
    local = sd / DSIG_LOCAL
    if local.is_file():
        return local
    import xmlschema

    return Path(xmlschema.__file__).resolve().parent / "schemas" / "DSIG" / DSIG_NAME


def is_remote_dsig(url: str) -> bool:
    """True if ``url`` is an http(s) URL of the W3C xmldsig schema (mapped to :func:`dsig_path`)."""
    return url.lower().startswith(("http://", "https://")) and url.endswith(DSIG_NAME)


class LocalResolver(etree.Resolver):
    """Maps the remote xmldsig schema to a local file and any other http(s) URL to nothing.

    Parameters
    ----------
    dsig : Path
        The local xmldsig schema (:func:`dsig_path`).
    """

    def __init__(self, dsig: Path) -> None:
        super().__init__()
        self.dsig = dsig

    def resolve(self, url: str | None, pubid: str | None, context: Any) -> Any:
        if url and is_remote_dsig(url):
            log.debug("resolver: %s -> %s", url, self.dsig)
            return self.resolve_filename(str(self.dsig), context)
        if url and url.lower().startswith(("http://", "https://", "ftp://")):
            if url.endswith(".dtd"):  # e.g. the DOCTYPE of the W3C xmldsig copy: not needed
                return self.resolve_string("", context)
            log.warning("not fetching %s (no network access)", url)
        return None


def xml_parser(resolver: etree.Resolver | None = None) -> etree.XMLParser:
    """A parser that never touches the network, loads no DTD and expands no entity.

    ``no_network``, ``load_dtd=False``, ``dtd_validation=False``, ``resolve_entities=False``
    and ``huge_tree=False`` (libxml2's limits stay on: entity amplification, text nodes of at
    most 10 MB, nesting depth).

    Parameters
    ----------
    resolver : lxml.etree.Resolver, optional
        Added to the parser's resolvers.

    Returns
    -------
    lxml.etree.XMLParser
    """
    p = etree.XMLParser(
        no_network=True,
        huge_tree=False,
        resolve_entities=False,
        load_dtd=False,
        dtd_validation=False,
    )
    if resolver is not None:
        p.resolvers.add(resolver)
    return p


# ---------------------------------------------------------------------------------------------
# helpers on instance documents


def format_size(n: int) -> str:
    """A byte count as shown in messages: ``100 MiB``, ``1.5 KiB``, ``12 bytes``."""
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.4g} {unit}"
    return f"{n} bytes"


def _check_stat(st: os.stat_result, name: str, max_bytes: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise DocumentRefused(name, f"not a regular file ({file_kind(st)})")
    if st.st_size > max_bytes:
        raise DocumentRefused(name, f"larger than {format_size(max_bytes)} ({st.st_size} bytes)")


_OPEN_FLAGS = (
    os.O_RDONLY
    | getattr(os, "O_NONBLOCK", 0)  # a FIFO swapped in after the stat must not block the open
    | getattr(os, "O_NOCTTY", 0)
    | getattr(os, "O_CLOEXEC", 0)
    | getattr(os, "O_BINARY", 0)
)
_CHUNK = 1 << 20


def read_document(path: Path | str, max_bytes: int = MAX_DOCUMENT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``, read with a bounded read.

    The file is checked with :func:`os.stat` before it is opened (a device, FIFO, socket or
    directory is never opened), opened non-blocking and checked again on the open descriptor
    (:func:`os.fstat`), then read: never more than ``max_bytes + 1`` bytes, so a file that
    grows or lies about its size (``/proc``) is refused too.

    Parameters
    ----------
    path : Path or str
        The file (a symbolic link is followed; what it points to is checked).
    max_bytes : int
        The largest size accepted (:data:`MAX_DOCUMENT_BYTES`).

    Returns
    -------
    bytes

    Raises
    ------
    FileNotFoundError
        No such file.
    DocumentRefused
        Not a regular file, or larger than ``max_bytes``.
    OSError
        The file cannot be read (permissions...).
    """
    name = os.fspath(path)
    try:
        st = os.stat(name)
    except FileNotFoundError:
        raise FileNotFoundError(f"{name}: no such file") from None
    _check_stat(st, name, max_bytes)
    fd = os.open(name, _OPEN_FLAGS)
    try:
        st = os.fstat(fd)
        _check_stat(st, name, max_bytes)
        parts = [os.read(fd, min(st.st_size, max_bytes) + 1)]
        total = len(parts[0])
        while parts[-1] and total <= max_bytes:
            parts.append(os.read(fd, min(_CHUNK, max_bytes + 1 - total)))
            total += len(parts[-1])
    finally:
        os.close(fd)
    if total > max_bytes:
        raise DocumentRefused(name, f"larger than {format_size(max_bytes)}")
    return parts[0] if len(parts) == 1 or not parts[1] else b"".join(parts)


_NO_DTD = "DTD/entity declarations are not allowed in a QIF document"
_RE_BLANKS = re.compile(r"[ \t\r\n]*")
_BOMS = (
    (codecs.BOM_UTF32_LE, "utf-32-le"),
    (codecs.BOM_UTF32_BE, "utf-32-be"),
    (codecs.BOM_UTF16_LE, "utf-16-le"),
    (codecs.BOM_UTF16_BE, "utf-16-be"),
    (codecs.BOM_UTF8, "utf-8"),
)


def _prolog_has_doctype(data: bytes) -> bool:
    """True if a DOCTYPE is seen in the first 1 MiB of a document, before its root element.

    The prolog is skipped as XML defines it (XML declaration, processing instructions,
    comments, blanks), in linear time.
    """
    head = data[: 1 << 20]
    encoding = "latin-1"  # any ASCII-compatible encoding: the markup looked for is ASCII
    for bom, enc in _BOMS:
        if head.startswith(bom):
            head, encoding = head[len(bom) :], enc
            break
    else:
        if head.startswith(b"<\x00?\x00"):
            encoding = "utf-16-le"
        elif head.startswith(b"\x00<\x00?"):
            encoding = "utf-16-be"
    text = head.decode(encoding, errors="replace")
    i = 0
    while True:
        i = _RE_BLANKS.match(text, i).end()
        for start, end in (("<?", "?>"), ("<!--", "-->")):
            if text.startswith(start, i):
                j = text.find(end, i + len(start))
                if j < 0:
                    return False
                i = j + len(end)
                break
        else:
            return text.startswith("<!DOCTYPE", i)


def refuse_doctype(tree: etree._ElementTree, name: str) -> None:
    """Refuse a parsed document that has a DOCTYPE or an entity reference.

    QIF documents are defined by XSDs; a DOCTYPE only brings DTD and entity declarations
    (external entities, entity expansion bombs), none of which is loaded or expanded here.

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The document, parsed with :func:`xml_parser`.
    name : str
        The file, as the message is to name it.

    Raises
    ------
    DocumentRefused
        If it has a DOCTYPE (internal subset or external DTD) or an entity reference.
    """
    info = tree.docinfo
    if info.internalDTD is not None or info.doctype or info.system_url or info.public_id:
        raise DocumentRefused(name, f"{_NO_DTD} (it has a DOCTYPE)")
    root = tree.getroot()
    if root is not None and next(root.iter(etree.Entity), None) is not None:
        raise DocumentRefused(name, f"{_NO_DTD} (it has entity references)")


def parse_document_bytes(data: bytes, name: str, base_url: str | None = None) -> etree._ElementTree:
    """Parse the bytes of a QIF document with :func:`xml_parser`, refusing any DOCTYPE.

    A DOCTYPE in the prolog is refused before libxml2 parses anything (so neither an
    entity bomb nor an external entity is looked at), and again on the parsed document
    (:func:`refuse_doctype`), whatever its encoding.

    Parameters
    ----------
    data : bytes
        The document (:func:`read_document`).
    name : str
        The file, as messages are to name it.
    base_url : str, optional
        The document's URL, against which its relative references are resolved (default:
        ``name``).

    Returns
    -------
    lxml.etree._ElementTree

    Raises
    ------
    DocumentRefused
        It has a DOCTYPE or an entity reference.
    lxml.etree.XMLSyntaxError
        Not well-formed XML.
    """
    if _prolog_has_doctype(data):
        raise DocumentRefused(name, f"{_NO_DTD} (it has a DOCTYPE)")
    root = etree.fromstring(data, xml_parser(), base_url=name if base_url is None else base_url)
    tree = root.getroottree()
    refuse_doctype(tree, name)
    return tree


def parse_document(path: Path | str, max_bytes: int = MAX_DOCUMENT_BYTES) -> etree._ElementTree:
    """Read (:func:`read_document`) and parse (:func:`parse_document_bytes`) a QIF file.

    Parameters
    ----------
    path : Path or str
        The QIF document.
    max_bytes : int
        The largest file accepted (:data:`MAX_DOCUMENT_BYTES`).

    Returns
    -------
    lxml.etree._ElementTree
        Its URL is ``str(path)`` (relative references resolve against it).

    Raises
    ------
    FileNotFoundError
        The file is missing.
    DocumentRefused
        Not a regular file, larger than ``max_bytes``, or with a DOCTYPE.
    lxml.etree.XMLSyntaxError
        Not well-formed XML.
    OSError
        The file cannot be read.
    """
    name = os.fspath(path)
    return parse_document_bytes(read_document(name, max_bytes), name)


def strip_ns(text: str) -> str:
    """``text`` without the QIF namespace (``{ns}Name`` and ``ns:Name`` become ``Name``)."""
    return text.replace(f"{{{QIF_NS}}}", "").replace(f"{QIF_NS}:", "")


def local_name(tag: Any) -> str:
    """The local name of an element tag (``str(tag)`` if it is not a qualified name)."""
    try:
        return etree.QName(tag).localname
    except (ValueError, TypeError):
        return str(tag)
