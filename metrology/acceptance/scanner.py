"""A scanner's acceptance figures (:class:`ScannerProfile`): what the instrument contributes
to a characteristic's uncertainty budget (:mod:`qifreport.metrology.acceptance.budget`).

The figures are those of an optical scanner's acceptance test, ISO 10360-8:2013 and VDI/VDE
2634 Part 2:2012, each a maximum permissible error (MPE) in mm:

* ``probing_form`` PF: the range of a sphere's points about their least-squares sphere;
* ``probing_size`` PS: the error of a sphere's measured diameter;
* ``length_a``, ``length_k``: the sphere-spacing / length measurement error of a length
  ``L`` mm, ``E(L) = length_a + L / length_k`` mm (ISO 10360's ``A + L/K`` in mm; a
  length-independent figure ``SD`` is ``length_a`` with ``length_k`` 0);
* ``flatness`` F: the range of a plane's points about their least-squares plane (None: PF);
* ``temperature``, ``cte``: the part's temperature during the scan (deg C) and its
  coefficient of thermal expansion (1/K), when the scan was not made at the 20 deg C
  reference of ISO 1.

A profile is read from a small JSON or TOML file (``--scanner FILE``, :func:`load_scanner`)::

    name = "ATOS line scanner, cell 3"
    model = "..."
    probing_form = 0.008
    probing_size = 0.006
    length_a = 0.012
    length_k = 50000
    flatness = 0.010          # optional
    temperature = 23.5        # optional, deg C
    cte = 23e-6               # optional, 1/K

Without a file the :data:`DEFAULT_SCANNER` class is used and every output says so.

**The default scanner class.** A mid-range structured-light scanner (measuring volume of
the order of 300-500 mm): PF 0.020 mm, PS 0.015 mm, E(L) = 0.025 mm + L/20000 (0.05 mm per
metre), F 0.025 mm. The figures are the conservative end of the 0.005-0.03 mm that
acceptance tests to VDI/VDE 2634-2 and ISO 10360-8 give for such scanners (the figures
vendors state for their mid-range volumes); the length term bounds the drift of a scan
stitched over a part larger than one view. A profile of the actual scanner, from its
acceptance or reverification certificate, replaces them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: profiles in JSON only
    tomllib = None

__all__ = [
    "DEFAULT_SCANNER",
    "REFERENCE_TEMPERATURE",
    "ScannerProfile",
    "ScannerProfileError",
    "load_scanner",
]

#: the reference temperature of geometrical product specification (ISO 1), deg C
REFERENCE_TEMPERATURE = 20.0


class ScannerProfileError(ValueError):
    """A scanner profile file that cannot be used (the message, one line, says why)."""


@dataclass(frozen=True)
class ScannerProfile:
    """A scanner's acceptance figures (module docstring), mm.

    Attributes
    ----------
    name, model : as the profile names them.
    probing_form, probing_size : PF and PS, mm (MPE).
    length_a : E(L)'s constant term, mm.  length_k : E(L)'s ``K`` (0: no length term).
    flatness : F, mm (None: PF stands for it).
    temperature : the part's temperature, deg C (None: at the 20 deg C reference).
    cte : the part's coefficient of thermal expansion, 1/K (None: not given).
    default : the documented default class (no profile given).
    source : where the figures come from (the file, or the default's rationale).
    """

    name: str
    model: str
    probing_form: float
    probing_size: float
    length_a: float
    length_k: float
    flatness: float | None = None
    temperature: float | None = None
    cte: float | None = None
    default: bool = False
    source: str = ""

    def length_error(self, length: float) -> float:
        """E(L) of a length ``length`` mm, mm."""
        slope = 0.0 if self.length_k <= 0.0 else abs(length) / self.length_k
        return self.length_a + slope

    def form_error(self, plane: bool = False) -> float:
        """The MPE of a form reading, mm: F for a plane when given, else PF."""
        return self.flatness if plane and self.flatness is not None else self.probing_form

    def surface_error(self) -> float:
        """The MPE of one surface point's position along the normal, mm: half the probing
        size error PS (a sphere's radius error: the scanner's local bias of a surface
        after its points are fitted)."""
        return 0.5 * self.probing_size

    @property
    def label(self) -> str:
        """How the outputs name it (``'default scanner class (...)'`` without a profile)."""
        return f"default scanner class ({self.name})" if self.default else self.name

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "model": self.model,
            "default_class": self.default,
            "probing_form_mm": self.probing_form,
            "probing_size_mm": self.probing_size,
            "length_error_a_mm": self.length_a,
            "length_error_k": self.length_k,
            "flatness_mm": self.flatness,
            "temperature_c": self.temperature,
            "cte_per_k": self.cte,
            "source": self.source,
        }


#: the documented default (module docstring): used, and said, when no profile is given
DEFAULT_SCANNER = ScannerProfile(
    name="mid-range structured-light scanner",
    model="generic",
    probing_form=0.020,
    probing_size=0.015,
    length_a=0.025,
    length_k=20000.0,
    flatness=0.025,
    default=True,
    source=(
        "conservative end of the VDI/VDE 2634-2 / ISO 10360-8 acceptance figures of "
        "mid-range structured-light scanners (0.005-0.03 mm)"
    ),
)

_REQUIRED = ("name", "probing_form", "probing_size", "length_a")
_LENGTHS = ("probing_form", "probing_size", "length_a", "flatness")
_KNOWN = {*_REQUIRED, "model", "length_k", "flatness", "temperature", "cte"}


def load_scanner(path: str | Path) -> ScannerProfile:
    """The scanner profile in the JSON (``.json``) or TOML file ``path``.

    Raises
    ------
    ScannerProfileError
        With a one-line message: the file is missing or unreadable, not JSON/TOML, lacks a
        required figure (``name``, ``probing_form``, ``probing_size``, ``length_a``), names
        an unknown key, or a figure is not a finite number (lengths > 0 mm, at most 10 mm;
        ``length_k`` >= 0; ``cte`` >= 0).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScannerProfileError(f"scanner profile {p}: cannot read: {exc.strerror}") from exc
    toml = p.suffix.lower() == ".toml"
    if toml and tomllib is None:
        raise ScannerProfileError(f"scanner profile {p}: TOML needs Python 3.11; use JSON")
    try:
        data = tomllib.loads(text) if toml else json.loads(text)
    except ValueError as exc:  # JSONDecodeError and TOMLDecodeError are ValueErrors
        first = str(exc).splitlines()[0]
        kind = "TOML" if toml else "JSON"
        raise ScannerProfileError(f"scanner profile {p}: not valid {kind}: {first}") from exc
    if not isinstance(data, dict):
        raise ScannerProfileError(f"scanner profile {p}: not a table of figures")
    return _profile(data, str(p))


def _profile(data: dict, where: str) -> ScannerProfile:
    """The profile of the parsed ``data`` (see :func:`load_scanner`)."""
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise ScannerProfileError(f"scanner profile {where}: missing {', '.join(missing)}")
    unknown = sorted(set(data) - _KNOWN)
    if unknown:
        raise ScannerProfileError(
            f"scanner profile {where}: unknown key(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(_KNOWN))})"
        )
    num = {k: _number(data[k], k, where) for k in _KNOWN - {"name", "model"} if k in data}
    for k in _LENGTHS:
        if k in num and not 0.0 < num[k] <= 10.0:
            raise ScannerProfileError(
                f"scanner profile {where}: {k} must be a length in (0, 10] mm, got {num[k]:g}"
            )
    for k in ("length_k", "cte"):
        if num.get(k, 0.0) < 0.0:
            raise ScannerProfileError(f"scanner profile {where}: {k} must be >= 0")
    return ScannerProfile(
        name=str(data["name"]),
        model=str(data.get("model", "")),
        probing_form=num["probing_form"],
        probing_size=num["probing_size"],
        length_a=num["length_a"],
        length_k=num.get("length_k", 0.0),
        flatness=num.get("flatness"),
        temperature=num.get("temperature"),
        cte=num.get("cte"),
        source=f"scanner profile {Path(where).name}",
    )


def _number(x, key: str, where: str) -> float:
    """``x`` as a finite float, else a one-line :class:`ScannerProfileError`."""
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ScannerProfileError(f"scanner profile {where}: {key} must be a number, got {x!r}")
    return float(x)
