"""Clamps and supports of a restrained inspection (ISO 10579; ASME Y14.5 restraint notes).

A drawing that inspects a non-rigid part in the restrained condition states where it is
held, along which directions, and with how much force at most. Each such point is a
:class:`Clamp`: its nominal position on the part, the directions it restrains (``n``: along
the surface normal there; ``x``, ``y``, ``z``: along the part frame's axes, in any
combination), an optional force limit (N) and where it came from (a file, a PMI datum
target). :func:`parse_clamps` reads the ``--clamps`` file: CSV rows
``name, x, y, z, directions[, max_force_N]`` (mm), ``#`` comments and an optional header.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Clamp", "parse_clamps"]

_AXES = "xyz"


@dataclass(frozen=True)
class Clamp:
    """One clamp or support point.

    Attributes
    ----------
    name : its label (e.g. a datum target ``A1``).
    position : (3,) nominal position on the part, mm (part frame).
    directions : what it restrains: ``"n"`` (the surface normal) or axes from ``"xyz"``.
    max_force : the largest force it may apply, N (None: no limit stated).
    source : where it was read (``"clamps file line 3"``, ``"PMI datum target #123"``).
    """

    name: str
    position: tuple[float, float, float]
    directions: str
    max_force: float | None = None
    source: str = ""

    def axes(self, normal: np.ndarray) -> list[np.ndarray]:
        """The unit directions it restrains, given the surface's unit ``normal`` (3,) there."""
        if self.directions == "n":
            n = np.asarray(normal, dtype=np.float64)
            return [n / np.linalg.norm(n)]
        return [np.eye(3)[_AXES.index(a)] for a in self.directions]

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "position_mm": [float(c) for c in self.position],
            "directions": self.directions,
            "max_force_N": None if self.max_force is None else float(self.max_force),
            "source": self.source,
        }


def _directions(text: str, where: str) -> str:
    d = text.strip().lower()
    if d in ("n", "normal"):
        return "n"
    if d and all(c in _AXES for c in d) and len(set(d)) == len(d):
        return "".join(a for a in _AXES if a in d)  # canonical order
    raise ValueError(f"{where}: directions {text.strip()!r} are not 'n' or axes from 'xyz'")


def _number(text: str, what: str, where: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{where}: {what} is not a number: {text.strip()!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{where}: {what} is not finite: {text.strip()!r}")
    return x


def parse_clamps(text: str, source: str = "clamps file") -> list[Clamp]:
    """The clamps of a ``--clamps`` CSV text (module docstring).

    Raises
    ------
    ValueError
        A malformed row, a duplicate name or no clamp at all, naming the line.
    """
    out: list[Clamp] = []
    seen: set[str] = set()
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        where = f"{source} line {lineno}"
        if not out and not seen and cells[0].lower() == "name":
            continue  # the header (the first row that is not a comment)
        if len(cells) not in (5, 6):
            raise ValueError(
                f"{where}: {len(cells)} fields, expected name, x, y, z, directions[, max_force_N]"
            )
        name = cells[0]
        if not name:
            raise ValueError(f"{where}: a clamp needs a name")
        if name in seen:
            raise ValueError(f"{where}: clamp {name!r} named twice")
        seen.add(name)
        x, y, z = (_number(c, a, where) for c, a in zip(cells[1:4], _AXES, strict=True))
        limit = None
        if len(cells) == 6 and cells[5]:
            limit = _number(cells[5], "max force", where)
            if limit <= 0:
                raise ValueError(f"{where}: max force must be positive (N), got {limit:g}")
        out.append(Clamp(name, (x, y, z), _directions(cells[4], where), limit, where))
    if not out:
        raise ValueError(f"{source}: no clamp in it")
    return out
