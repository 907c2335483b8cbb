"""Validation of QIF 3.0 documents: the official XSDs and the DMSC quality checks.

Three independent validators, each reporting :class:`Finding` objects with a line number in
the QIF file and a rule naming what is violated:

* ``lxml`` (libxml2) against the official QIF 3.0 XSDs (``QIFApplications/QIFDocument.xsd``):
  :mod:`.lxml_validator`;
* ``xmlschema`` (strict, identity constraints included) against the same XSDs, with a
  workaround for xmlschema's identity constraints over substitution groups:
  :mod:`.xmlschema_validator`;
* ``dmsc``: the DMSC XSLT checks (``Check.xsl``, XSLT 1.0) run through ``lxml.etree.XSLT``;
  its ``CheckReport`` is parsed into findings with their category (``CheckFormat``,
  ``CheckQuality``, ``CheckSemantic``, ``CheckDocuments``): :mod:`.dmsc`.

:func:`validate` runs them on one file and gathers their findings in a
:class:`ValidationReport` (:mod:`.findings`). The XSDs and the checks are located by
:func:`schema_dir` and :func:`checks_dir` (:mod:`.xsd`). Nothing here touches the network:
the remote W3C xmldsig import of ``QIFDocument.xsd`` is mapped to a local copy, libxml2 runs
with ``no_network`` and the XSLT with an access control that denies network reads.

Hostile files: the file checked must be a regular file of at most
:data:`~qifreport.qif.xsd.MAX_DOCUMENT_BYTES` without a DOCTYPE (no DTD is loaded, no entity
expanded), else :class:`DocumentRefused`; the documents it links to are read by the DMSC
checks only inside its own folder tree, under the same limits (:mod:`.dmsc`), and the DMSC
run is bounded in time. A validator that raises on the document gives the finding
``internal`` instead of an exception.

This module is the public API of QIF validation; the command line ``qifreport validate
FILE...`` is the application's (``qifreport.validate_command``).
"""

from __future__ import annotations

import functools
import logging
import time
from pathlib import Path

from .dmsc import dmsc_checks, dmsc_findings
from .findings import Finding, ValidationReport, internal_finding
from .lxml_validator import lxml_findings, lxml_schema, validate_lxml
from .xmlschema_validator import validate_xmlschema, xmlschema_findings, xmlschema_schema
from .xsd import (
    MAX_DOCUMENT_BYTES,
    DocumentRefused,
    SchemasUnavailable,
    checks_dir,
    parse_document,
    schema_dir,
)

__all__ = [
    "MAX_DOCUMENT_BYTES",
    "DocumentRefused",
    "SchemasUnavailable",
    "Finding",
    "ValidationReport",
    "schema_dir",
    "checks_dir",
    "validate_lxml",
    "validate_xmlschema",
    "dmsc_checks",
    "validate",
]

log = logging.getLogger("qifreport.validate")


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
        A validator that raised on the document instead of reporting gives one finding
        ``internal`` (an error) and the others still run.

    Raises
    ------
    SchemasUnavailable
        No XSD folder, or (with ``checks``) no DMSC checks.
    FileNotFoundError, lxml.etree.XMLSyntaxError
        The file is missing or not well-formed XML.
    DocumentRefused
        Not a regular file (a device, FIFO, socket, directory), larger than
        :data:`MAX_DOCUMENT_BYTES`, or with a DOCTYPE (DTD/entity declarations).
    OSError
        The file cannot be read.
    """
    p = Path(path)
    sd = schema_dir()
    cd = checks_dir() if checks else None
    tree = parse_document(p)
    # the schemas compile here (cached): a broken schema folder is an error, not a finding
    lxml_schema(sd)
    if strict:
        xmlschema_schema(sd, True)
    runs = [("lxml", functools.partial(lxml_findings, tree, sd))]
    if strict:
        runs.append(("xmlschema", functools.partial(xmlschema_findings, tree, sd)))
    if cd is not None:
        runs.append(("dmsc", functools.partial(dmsc_findings, tree, p.resolve(), cd)))
    findings: list[Finding] = []
    ran: list[str] = []
    timings = []
    for name, run in runs:
        t0 = time.perf_counter()
        try:
            findings.extend(run())
        except Exception as exc:  # a validator's failure on this document is a finding
            log.debug("%s failed on %s", name, p, exc_info=True)
            findings.append(internal_finding(name, exc))
        ran.append(name)
        timings.append(f"{name} {time.perf_counter() - t0:.2f} s")
    log.debug("%s: %s", p, ", ".join(timings))
    return ValidationReport(path=p, schema_dir=sd, findings=findings, ran=ran)
