"""The part's material as a STEP file states it.

AP242 carries a material in two forms, both read here:

* a ``MATERIAL_DESIGNATION('ABS', (#pds))``: the designation's name, on the product's
  shape (AP214/AP242 "material designation" practice; a ``PRODUCT_DEFINITION_SHAPE`` or
  ``PRODUCT_DEFINITION``);
* a drawing note whose line says ``MATERIAL: ...`` (also ``MATL:``, ``MATERIAL =``, ``-``):
  the rest of that line, from any text :func:`qifreport.step.notes.drawing_texts` reads.

The designation is preferred when both are present: it is the semantic form. The text is
returned as written; whether it names a known material (and which preset's properties it
carries) is decided by the caller, never guessed here.
"""

from __future__ import annotations

import re

from .notes import drawing_texts
from .p21 import P21Model
from .pmi import MaterialNote

__all__ = ["material_note"]

#: a note's material line: "MATERIAL: ABS ...", "MATL = PP", "MATERIAL - S235JR"
_MATERIAL_LINE = re.compile(r"\bMAT(?:ERIA)?L\s*(?::|=|\s-)\s*(\S[^\n]*)", re.IGNORECASE)
#: longest designation kept, characters
MAX_TEXT = 200


def _clean(text: str) -> str:
    """``text`` whitespace collapsed, a closing full stop dropped, at most :data:`MAX_TEXT`
    characters."""
    words = " ".join(text.split()).rstrip(" .;,")
    return words[:MAX_TEXT]


def material_note(model: P21Model) -> MaterialNote | None:
    """The first material the file states (module docstring): its designation entity's,
    else a note's ``MATERIAL:`` line; None when it states none.

    Parameters
    ----------
    model : the parsed Part 21 file.

    Returns
    -------
    MaterialNote or None
    """
    for ent in model.by_type("MATERIAL_DESIGNATION"):
        p = ent.part("MATERIAL_DESIGNATION") or ()
        if p and isinstance(p[0], str) and _clean(p[0]):
            return MaterialNote(_clean(p[0]), "material designation", ent.id)
    for eid, text in drawing_texts(model):
        m = _MATERIAL_LINE.search(text)
        if m is not None and _clean(m.group(1)):
            return MaterialNote(_clean(m.group(1)), "drawing note", eid)
    return None
