"""Where the official QIF 3.0 material is, and how it is read without the network.

* :func:`schema_dir`: the folder of the official QIF 3.0 XSDs (``QIFApplications/``,
  ``QIFLibrary/``); :func:`checks_dir`: the folder of the DMSC XSLT checks (``Check.xsl``).
  Either raises :class:`SchemasUnavailable`, whose message says how to provide them.
* The remote W3C xmldsig import of ``QIFDocument.xsd`` is mapped to a local copy
  (:func:`dsig_path`: the schema folder's ``QIFLibrary/xmldsig-core-schema.xsd``, else the copy
  bundled with ``xmlschema``); :class:`LocalResolver` does it for libxml2 and refuses every
  other network URL.
* :func:`xml_parser` is the parser every QIF or XSD file is read with (``no_network``, no
  DTD, entities unexpanded); :func:`parse_document` reads a QIF file with it.
* :func:`strip_ns` and :func:`local_name` shorten the QIF namespace in what is reported.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from lxml import etree

from qifreport.schemas import QIF_XSD_DIR, SCHEMA_DIR

__all__ = [
    "DSIG_LOCAL",
    "DSIG_NAME",
    "ENV_CHECKS_DIR",
    "ENV_XSD_DIR",
    "QIF_NS",
    "REPO_ROOT",
    "ROOT_XSD",
    "XSD_NS",
    "LocalResolver",
    "SchemasUnavailable",
    "checks_dir",
    "dsig_path",
    "is_remote_dsig",
    "local_name",
    "parse_document",
    "schema_dir",
    "strip_ns",
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
#: the repository root in an editable install (``../shared`` may sit beside it)
REPO_ROOT = SCHEMA_DIR.parent
_HOWTO = (
    "run `make install` with ../shared present (it copies the official XSDs to "
    f"{QIF_XSD_DIR}), or set QIFREPORT_XSD_DIR to a folder holding QIFApplications/ "
    f"and QIFLibrary/ (an installed wheel: or copy those two folders into {QIF_XSD_DIR})"
)


class SchemasUnavailable(Exception):
    """The QIF 3.0 XSDs (or the DMSC checks) cannot be found; the message says how to fix it."""


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
            f"{_HOWTO}"
        )
    candidates = [QIF_XSD_DIR, REPO_ROOT.parent / "shared" / "qif" / "xsd"]
    for p in candidates:
        if _is_schema_dir(p):
            return p.resolve()
    raise SchemasUnavailable(
        "QIF 3.0 XSD schemas not found (looked in "
        + ", ".join(map(str, candidates))
        + f" and {ENV_XSD_DIR} is not set); {_HOWTO}"
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
    """A parser that never touches the network and keeps entities unexpanded from outside.

    Parameters
    ----------
    resolver : lxml.etree.Resolver, optional
        Added to the parser's resolvers.

    Returns
    -------
    lxml.etree.XMLParser
    """
    p = etree.XMLParser(no_network=True, huge_tree=True, resolve_entities=False, load_dtd=False)
    if resolver is not None:
        p.resolvers.add(resolver)
    return p


# ---------------------------------------------------------------------------------------------
# helpers on instance documents


def parse_document(path: Path) -> etree._ElementTree:
    """Parse a QIF file with :func:`xml_parser`.

    Parameters
    ----------
    path : Path
        The QIF document.

    Returns
    -------
    lxml.etree._ElementTree

    Raises
    ------
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    return etree.parse(str(path), xml_parser())


def strip_ns(text: str) -> str:
    """``text`` without the QIF namespace (``{ns}Name`` and ``ns:Name`` become ``Name``)."""
    return text.replace(f"{{{QIF_NS}}}", "").replace(f"{QIF_NS}:", "")


def local_name(tag: Any) -> str:
    """The local name of an element tag (``str(tag)`` if it is not a qualified name)."""
    try:
        return etree.QName(tag).localname
    except (ValueError, TypeError):
        return str(tag)
