"""Which material preset (:data:`qifreport.registration.restraint.elastic.MATERIALS`) a
drawing's material designation names, if any.

A drawing states its material as text ("ABS", "MATERIAL: PP, UNFILLED", "EN AW-6061-T6",
"S235JR"). A preset is taken only where the text names exactly that material class: its
stiffness and yield strength then hold. Anything else has no preset and the caller says
so; nothing is guessed from a near name:

* a plastic preset (ABS, PP) is named by its ISO 1043 symbol or its full name standing
  alone, not as part of a blend (``PC/ABS``, ``PP+EPDM``, ``ABS-PC``) nor filled or
  reinforced (``GF30``, ``T20``, "GLASS", "TALC", "MINERAL", "FILLED"): those are other
  materials, stiffer by a factor up to 5;
* PA6-GF30 by its symbol (``PA6-GF30``, ``PA 6 GF 30``);
* the aluminium preset is EN AW-6061-T6 and is named by its alloy and temper (``6061-T6``);
  "ALUMINIUM" alone (a yield strength between 20 and 500 MPa) has none;
* the steel preset is S235 (``S235``, ``S235JR``, ``1.0038``, "STRUCTURAL STEEL",
  "MILD STEEL"); "STEEL" alone, a stainless or a tool steel has none;
* a text that names two presets has none.
"""

from __future__ import annotations

import re

__all__ = ["preset_of"]

#: ISO 1043 filler and reinforcement codes, or words, that make a plastic another material
_FILLED = re.compile(
    r"(?<![A-Z])(?:GF|CF|GB|MD|TD|T|M)\s*-?\s*\d+|\b(?:GLASS|CARBON|TALC|MINERAL|FILLED|"
    r"REINFORCED)\b",
    re.IGNORECASE,
)


def _alone(symbol: str) -> str:
    """A pattern for ``symbol`` standing alone: not inside a word, nor joined to another
    by ``/``, ``+`` or ``-`` (a blend)."""
    return rf"(?<![\w/+\-]){symbol}(?![\w/+\-])"


#: preset name -> (pattern naming it, whether a filler code in the text excludes it)
_PRESETS: dict[str, tuple[re.Pattern, bool]] = {
    "abs": (
        re.compile(_alone("ABS") + r"|ACRYLONITRILE[\s-]+BUTADIENE[\s-]+STYRENE", re.I),
        True,
    ),
    "pp": (re.compile(_alone("PP") + r"|\bPOLYPROPYLENE\b", re.I), True),
    "pa6-gf30": (re.compile(r"(?<![\w/+])PA\s*6\s*-?\s*GF\s*-?\s*30(?!\d)", re.I), False),
    "aluminium": (re.compile(r"(?<!\d)6061\s*-?\s*T6(?!\d)", re.I), False),
    "steel": (
        re.compile(r"(?<![\w.])(?:S235\w*|1\.0038)(?![\w.])|\b(?:STRUCTURAL|MILD)\s+STEEL\b", re.I),
        False,
    ),
}


def preset_of(text: str) -> str | None:
    """The preset ``text`` names (module docstring), or None.

    Parameters
    ----------
    text : a material designation as the drawing states it.

    Returns
    -------
    str or None
        A key of :data:`qifreport.registration.restraint.elastic.MATERIALS`.
    """
    filled = _FILLED.search(text) is not None
    found = [
        name
        for name, (pattern, plain) in _PRESETS.items()
        if pattern.search(text) is not None and not (plain and filled)
    ]
    return found[0] if len(found) == 1 else None
