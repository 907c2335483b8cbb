"""The versioned JSON Schema of the ``qifreport --json`` summary, and its validation.

The summary document (:meth:`qifreport.metrology.results.InspectionResult.to_dict` plus the keys
:mod:`qifreport.pipeline` adds) carries ``"schema": "qifreport-summary/1"``
(:data:`SUMMARY_SCHEMA_VERSION`); its structure is the JSON Schema (draft 2020-12)
``schemas/summary-1.schema.json``.

The schema is package data of :mod:`qifreport.schemas` (the repository's ``schemas/``
folder, shipped in the wheel).
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

from qifreport.schemas import SCHEMA_DIR

__all__ = [
    "SUMMARY_SCHEMA_FILE",
    "SUMMARY_SCHEMA_VERSION",
    "summary_schema",
    "summary_schema_path",
    "validate_summary",
]

#: value of the summary's top-level ``"schema"`` key
SUMMARY_SCHEMA_VERSION = "qifreport-summary/1"
#: file name of the schema of :data:`SUMMARY_SCHEMA_VERSION`
SUMMARY_SCHEMA_FILE = "summary-1.schema.json"


def summary_schema_path() -> Path:
    """Path of the summary schema (package data of :mod:`qifreport.schemas`).

    Raises FileNotFoundError naming the place looked at.
    """
    p = SCHEMA_DIR / SUMMARY_SCHEMA_FILE
    if not p.is_file():
        raise FileNotFoundError(f"summary schema {SUMMARY_SCHEMA_FILE} not found in {SCHEMA_DIR}")
    return p


@functools.lru_cache(maxsize=1)
def _load(path: str) -> dict:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def summary_schema() -> dict:
    """The JSON Schema (draft 2020-12) of the summary, as a dict (a fresh copy)."""
    return json.loads(json.dumps(_load(str(summary_schema_path()))))


@functools.lru_cache(maxsize=1)
def _validator(path: str):
    from jsonschema import Draft202012Validator

    schema = _load(path)
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema)


def _where(path) -> str:
    """JSON-pointer-like location of an error: ``/tolerances/0/verdict``, ``/`` at the root."""
    return "/" + "/".join(str(p) for p in path)


def _non_finite(x, path=()):
    """Locations of NaN/inf floats: JSON has no such numbers (the summary writes null)."""
    if isinstance(x, float) and not math.isfinite(x):
        yield path, x
    elif isinstance(x, dict):
        for k, v in x.items():
            yield from _non_finite(v, (*path, k))
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            yield from _non_finite(v, (*path, i))


def _short(err) -> str:
    """The error message with a long instance (a whole array or object) abbreviated."""
    msg, inst = err.message, err.instance
    r = repr(inst)
    if len(r) > 80 and isinstance(inst, (dict, list)):
        kind = f"array of {len(inst)}" if isinstance(inst, list) else "object"
        msg = msg.replace(r, f"<{kind}>")
    return msg


def validate_summary(doc: dict) -> list[str]:
    """Every violation of the summary schema in ``doc``, each as ``"path: message"``.

    ``path`` is the location in the document (``/acceptance/regions/0/area``; ``/`` is the
    document itself). An empty list means ``doc`` is a valid summary. Errors under
    ``anyOf`` report their best-matching sub-error. Sorted by path. A NaN or infinite number (as
    ``json.loads`` reads the non-standard ``NaN``/``Infinity`` tokens) is an error too: JSON
    Schema's ``minimum``/``maximum`` cannot catch it, and the summary writes null instead.
    """
    from jsonschema.exceptions import best_match

    v = _validator(str(summary_schema_path()))
    found = [
        (list(p), f"{x!r} is not a JSON number (undefined values are null)")
        for p, x in _non_finite(doc)
    ]
    for err in v.iter_errors(doc):
        if err.context:  # anyOf/oneOf: the sub-error that matched best
            err = best_match(err.context) or err
        found.append((list(err.absolute_path), _short(err)))
    found.sort(key=lambda e: ([str(k) for k in e[0]], e[1]))
    out = []
    for p, msg in found:
        line = f"{_where(p)}: {msg}"
        if line not in out:
            out.append(line)
    return out
