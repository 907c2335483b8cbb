"""The ``qifreport validate FILE...`` command: QIF 3.0 validation of files, reported.

Runs :func:`qifreport.qif.validate.validate` (lxml, xmlschema and the DMSC checks, unless
disabled) on each file and prints its report (:meth:`ValidationReport.format`), or with
``--quiet`` only the findings that make a file invalid. :func:`add_arguments` and :func:`run`
are the sub-command for an argparse-based command line; :func:`validate_main` is the whole
command on its own.

The files checked may be hostile: a file that is not a regular file (``/dev/zero``, a FIFO, a
directory, a socket), is larger than :data:`~qifreport.qif.validate.MAX_DOCUMENT_BYTES`
(100 MiB) or has a DOCTYPE (DTD/entity declarations) is refused with one line on stderr and
exit 2 before anything parses it; linked documents are followed only inside the file's own
folder tree (see :mod:`qifreport.qif.dmsc`). No problem of a file ends the command with a
traceback: what a validator cannot check is a finding, anything else one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path

from lxml import etree

from qifreport.qif.findings import format_finding
from qifreport.qif.validate import (
    MAX_DOCUMENT_BYTES,
    DocumentRefused,
    SchemasUnavailable,
    ValidationReport,
    checks_dir,
    schema_dir,
    validate,
)

__all__ = ["DESCRIPTION", "PROG", "add_arguments", "run", "validate_main"]

PROG = "qifreport validate"
#: the command's description (``--help``)
DESCRIPTION = (
    "Check QIF 3.0 documents against the official XSDs (lxml/libxml2 and "
    "xmlschema, key/keyref included) and the DMSC XSLT checks. Exit 0 if every file "
    "passes, 1 if one does not, 2 if a file cannot be read or the schemas are missing. "
    f"Only regular files of at most {MAX_DOCUMENT_BYTES >> 20} MiB without a DOCTYPE are read "
    "(no DTD, no entity expansion, no network); the documents a file links to are followed "
    "only inside its own folder."
)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """Add the arguments of ``qifreport validate`` to a parser.

    ``FILE...`` (``files``, paths), ``--no-strict``, ``--no-checks``, ``--quiet``.

    Parameters
    ----------
    ap : argparse.ArgumentParser
        The (sub-)command's parser.
    """
    ap.add_argument("files", nargs="+", type=Path, metavar="FILE", help="QIF document(s)")
    ap.add_argument(
        "--no-strict", action="store_true", help="skip the xmlschema validation (lxml only; faster)"
    )
    ap.add_argument("--no-checks", action="store_true", help="skip the DMSC XSLT checks")
    ap.add_argument("--quiet", action="store_true", help="print only the errors of failing files")


def _arg_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description=DESCRIPTION)
    add_arguments(ap)
    return ap


def _err(msg: str) -> None:
    print(f"qifreport: error: {msg}", file=sys.stderr)


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (at most 500 characters)."""
    return " ".join(str(exc).split())[:500]


def run(args: argparse.Namespace) -> int:
    """Validate the files of parsed ``qifreport validate`` arguments and print the reports.

    Parameters
    ----------
    args : argparse.Namespace
        As parsed with :func:`add_arguments`.

    Returns
    -------
    int
        0 if all files are valid, 1 if one is not, 2 if a file is missing, refused (not a
        regular file, larger than :data:`~qifreport.qif.validate.MAX_DOCUMENT_BYTES`, with a
        DOCTYPE), not XML or cannot be checked, or the schemas (or checks) are unavailable;
        each such problem is one line on stderr (``qifreport: error: ...``).
    """
    strict, checks = not args.no_strict, not args.no_checks
    try:
        schema_dir()
        if checks:
            checks_dir()
    except SchemasUnavailable as exc:
        _err(f"{exc}; nothing was checked")
        return 2
    status = 0
    for f in args.files:
        try:
            rep = validate(f, strict=strict, checks=checks)
        except FileNotFoundError:
            _err(f"{f}: no such file")
            status = 2
            continue
        except etree.XMLSyntaxError as exc:
            _err(f"{f}: not well-formed XML: {_one_line(exc)}")
            status = 2
            continue
        except DocumentRefused as exc:
            _err(f"{_one_line(exc)}; not checked")
            status = 2
            continue
        except (OSError, SchemasUnavailable) as exc:
            _err(f"{f}: {_one_line(exc)}")
            status = 2
            continue
        except MemoryError:
            _err(f"{f}: out of memory; not checked")
            status = 2
            continue
        except Exception as exc:  # never a traceback: one line, exit 2
            _err(f"{f}: internal error: {type(exc).__name__}: {_one_line(exc)}; not checked")
            status = 2
            continue
        if not rep.valid:
            status = max(status, 1)
        if args.quiet:
            if not rep.valid:
                print("\n".join(_error_lines(rep)))
        else:
            print(rep.format())
    return status


def validate_main(argv: list[str]) -> int:
    """``qifreport validate FILE.qif [FILE...] [--no-strict] [--no-checks] [--quiet]``.

    Runs lxml, xmlschema and the DMSC checks (unless disabled) on each file and prints its
    report (:meth:`ValidationReport.format`).

    Parameters
    ----------
    argv : list of str
        The arguments after ``validate``.

    Returns
    -------
    int
        As :func:`run`; a usage error is 2, ``--help`` 0.
    """
    try:
        args = _arg_parser().parse_args(argv)
    except SystemExit as exc:  # usage error (2) or --help (0)
        return int(exc.code) if isinstance(exc.code, int) else 2
    return run(args)


def _error_lines(rep: ValidationReport) -> Iterator[str]:
    """For --quiet: the header and the findings that make the file invalid."""
    yield rep.format().splitlines()[0]
    for f in rep.findings:
        if f.severity == "error" and (f.validator != "dmsc" or f.category == "CheckFormat"):
            yield format_finding(str(rep.path), f)
