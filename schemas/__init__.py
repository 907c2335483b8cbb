"""The project's schemas, as package data (``qifreport.schemas``).

* ``summary-1.schema.json``: the JSON Schema of ``qifreport --json`` (shipped in the wheel).
* ``qif-3.0/``: the official QIF 3.0 XSDs, never committed nor shipped: ``make install``
  copies them here from ``../shared/qif/xsd`` (git-ignored); a wheel install finds them
  through ``QIFREPORT_XSD_DIR`` or in this folder's ``qif-3.0/``.
"""

from pathlib import Path

#: the folder holding the schemas (the repository's ``schemas/`` in an editable install)
SCHEMA_DIR = Path(__file__).resolve().parent
#: where ``make install`` (or the user of a wheel install) puts the QIF 3.0 XSDs
QIF_XSD_DIR = SCHEMA_DIR / "qif-3.0"

__all__ = ["QIF_XSD_DIR", "SCHEMA_DIR"]
