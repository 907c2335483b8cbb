"""What the QIF validators report: :class:`Finding` and the :class:`ValidationReport` of a file.

Every validator (:mod:`.lxml_validator`, :mod:`.xmlschema_validator`, :mod:`.dmsc`) reports
:class:`Finding` objects with a line number in the QIF file and a rule naming what is
violated; :func:`qifreport.qif.validate.validate` gathers them in a :class:`ValidationReport`,
which decides validity and formats the human-readable report.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "DMSC_CATEGORIES",
    "INTERNAL_RULE",
    "Finding",
    "ValidationReport",
    "format_finding",
    "internal_finding",
]

#: the CheckReport categories, in report order (CheckDocuments: the linked-document checks)
DMSC_CATEGORIES = (
    "CheckFormat",
    "CheckQuality",
    "CheckSemantic",
    "CheckConstraints",
    "CheckDocuments",
)
#: the rule of a finding that says a validator failed on the document instead of checking it
INTERNAL_RULE = "internal"


@dataclass
class Finding:
    """One problem found in a QIF document.

    Attributes
    ----------
    validator : str
        ``"lxml"``, ``"xmlschema"`` or ``"dmsc"``.
    line : int or None
        Line in the QIF file (None when the validator gives no location).
    rule : str
        What is violated: an XSD rule kind and the element or identity constraint
        (``"keyref FeatureItemIdKeyref"``, ``"content CircleFeatureItem"``), or the DMSC check
        (``"n-count"``, ``"idMax"``, ``"A-AN-UV"``...).
    message : str
        The validator's message (namespace ``{http://qifstandards.org/xsd/qif3}`` removed).
    category : str
        ``"schema"`` for the XSD validators; the ``CheckReport`` category for dmsc.
    severity : str
        ``"error"``, ``"warning"`` or ``"info"``.
    """

    validator: str
    line: int | None
    rule: str
    message: str
    category: str = "schema"
    severity: str = "error"


@dataclass
class ValidationReport:
    """The findings of the validators run on one file.

    Attributes
    ----------
    path : Path
        The QIF file.
    schema_dir : Path or None
        The XSD folder used (None if no XSD validator ran).
    findings : list of Finding
        Everything found, in validator order.
    ran : list of str
        The validators actually run.
    """

    path: Path
    schema_dir: Path | None
    findings: list[Finding]
    ran: list[str] = field(default_factory=list)

    def errors(self, validator: str | None = None, category: str | None = None) -> list[Finding]:
        """Error-severity findings, optionally of one validator and/or one category.

        Parameters
        ----------
        validator : str, optional
            ``"lxml"``, ``"xmlschema"`` or ``"dmsc"``.
        category : str, optional
            E.g. ``"schema"`` or ``"CheckFormat"``.

        Returns
        -------
        list of Finding
        """
        return [
            f
            for f in self.findings
            if f.severity == "error"
            and (validator is None or f.validator == validator)
            and (category is None or f.category == category)
        ]

    @property
    def valid(self) -> bool:
        """True if no XSD validator reported an error and DMSC ``CheckFormat`` found none.

        False when nothing ran. DMSC quality, semantic and linked-document findings do not
        make a document invalid (they are listed by :meth:`format`).
        """
        if not self.ran:
            return False
        return not (
            self.errors("lxml") or self.errors("xmlschema") or self.errors("dmsc", "CheckFormat")
        )

    def format(self) -> str:
        """A human-readable multi-line report.

        First line ``FILE: valid`` or ``FILE: INVALID``, then one line per validator run
        (``ok`` or ``N errors``; DMSC with counts per category), then one line per finding,
        ``FILE:LINE: [validator/rule] message`` (DMSC: ``[dmsc/Category/rule]``).

        Returns
        -------
        str
        """
        name = str(self.path)
        if not self.ran:
            return f"{name}: NOT CHECKED (no validator ran)"
        lines = [f"{name}: {'valid' if self.valid else 'INVALID'}"]
        for v in self.ran:
            if v == "dmsc":
                parts = []
                for cat in DMSC_CATEGORIES:
                    fs = [f for f in self.findings if f.validator == "dmsc" and f.category == cat]
                    if cat == "CheckConstraints" and not fs:
                        continue
                    parts.append(f"{cat} {_count_text(fs)}")
                lines.append("  dmsc: " + ", ".join(parts))
            else:
                fs = [f for f in self.findings if f.validator == v]
                lines.append(f"  {v}: {_count_text(fs)}")
        lines.extend(format_finding(name, f) for f in self.findings)
        return "\n".join(lines)


def format_finding(name: str, f: Finding) -> str:
    """One finding as a report line.

    Parameters
    ----------
    name : str
        The QIF file as it is to be shown.
    f : Finding
        The finding.

    Returns
    -------
    str
        ``FILE:LINE: [validator/rule] message`` (DMSC: ``[dmsc/Category/rule]``; no ``LINE``
        if unknown; a severity other than error is written before the message).
    """
    where = f"{name}:{f.line}:" if f.line is not None else f"{name}:"
    rule = (
        f"{f.validator}/{f.category}/{f.rule}"
        if f.validator == "dmsc"
        else f"{f.validator}/{f.rule}"
    )
    sev = "" if f.severity == "error" else f"{f.severity}: "
    msg = " ".join(f.message.splitlines())
    return f"{where} [{rule}] {sev}{msg}"


def internal_finding(validator: str, exc: BaseException) -> Finding:
    """The finding of a validator that raised instead of reporting (rule ``internal``).

    An error: the document was not checked by that validator, so it is not valid (for dmsc,
    category ``CheckFormat``).

    Parameters
    ----------
    validator : str
        ``"lxml"``, ``"xmlschema"`` or ``"dmsc"``.
    exc : BaseException
        What it raised.

    Returns
    -------
    Finding
        The message names the exception on one line (at most 300 characters of it).
    """
    detail = " ".join(str(exc).split())[:300]
    return Finding(
        validator,
        None,
        INTERNAL_RULE,
        f"{validator} failed on the document: {type(exc).__name__}"
        + (f": {detail}" if detail else ""),
        "CheckFormat" if validator == "dmsc" else "schema",
    )


def _count_text(fs: list[Finding]) -> str:
    """``ok``, or ``N errors`` / ``N warnings`` for a list of findings."""
    if not fs:
        return "ok"
    c = Counter(f.severity for f in fs)
    return ", ".join(
        f"{n} {sev}{'s' if n > 1 else ''}"
        for sev, n in sorted(c.items(), key=lambda kv: ("error", "warning", "info").index(kv[0]))
    )
