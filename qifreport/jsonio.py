"""Strict JSON of numpy-bearing documents (foundation: any layer may use it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["finite", "json_default"]


def finite(o: Any) -> Any:
    """The document with every non-finite float replaced by None (strict JSON).

    Dicts, lists, tuples and arrays are walked; numpy floats become Python floats.
    """
    if isinstance(o, dict):
        return {k: finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return finite(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def json_default(o: Any) -> Any:
    """``json.dumps(default=...)`` for arrays, numpy scalars and paths.

    Raises
    ------
    TypeError
        For any other type: a document never carries an object by its ``str()``.
    """
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
