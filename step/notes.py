"""A drawing's restraint statement, read from the text an AP242 file carries.

ASME Y14.5 applies tolerances in the free state unless the drawing says otherwise; ISO
10579 asks the drawing of a non-rigid part to say "ISO 10579-NR" and to state the
restraint. Neither is a semantic PMI entity in AP242: a CAD system exports such a note as
text, in one of these forms, all read here:

* **semantic text** (the CAx-IF practice for notes): a ``PROPERTY_DEFINITION('semantic
  text', ...)`` whose ``REPRESENTATION`` holds one ``DESCRIPTIVE_REPRESENTATION_ITEM`` per
  line (NIST FTC 08 #12880, note 5: "DIMENSIONING AND TOLERANCING APPLY WITH PART
  RESTRAINED AS FOLLOWS ..."); the lines of one representation are read as one text;
* a lone ``DESCRIPTIVE_REPRESENTATION_ITEM`` (a PMI validation property's "equivalent
  unicode string", its lines joined by a literal ``\\n``);
* a ``TEXT_LITERAL`` of a presentation (its literal).

A text states a restraint when it carries "ISO 10579-NR" (or "ISO 10579") or a word of
the restraint family ("RESTRAIN", "RESTRAINED", "RESTRAINT", "RESTRAINING") that no "NOT",
"NO", "WITHOUT" or "UN-" denies. The free-state modifier (F) on a tolerance is read with
the tolerance (:attr:`qifreport.step.pmi.GeometricTolerance.modifiers`); alone it states no
restraint (it marks a tolerance that holds in the free state even where the rest is
restrained), and datum targets alone state none either (a rigid part has them too).

The note's force limit, when it states one (ISO 10579: "forces not exceeding those which
can be expected under normal assembly conditions", which a drawing gives as a figure), is
read from the same note (:func:`restraint_force`): a force word, then a bound ("AT MOST",
"MAX", "MAXIMUM", "NOT TO EXCEED", "<=") and a value in N, kN or lbf, within one sentence.

Where the note holds the part, when it says so (:func:`restraint_targets`): the datum
targets it names after the word "TARGET(S)" ("HELD ... AT TARGETS A1-A4, ... B1, C1-C2":
A1, A2, A3, A4, B1, C1, C2; a range runs within one datum's letter), or all of them when it
says the part is held at its datum targets without naming them ("AT THE DATUM TARGETS").
A note that holds the part against its datum feature simulators (NIST FTC 08's note 5)
names no target: where it is held is the simulators', not points of the part.
"""

from __future__ import annotations

import re

from .p21 import P21Model
from .pmi import ALL_TARGETS, RestraintNote

__all__ = ["drawing_texts", "restraint_force", "restraint_note", "restraint_targets"]

#: a restraint statement: the ISO 10579 non-rigid indication or a restraint word
_RESTRAINT = re.compile(r"ISO\s*10579(?:\s*-\s*NR)?|\bRESTRAIN(?:ED|T|ING|S)?\b", re.IGNORECASE)
#: a word just before the match that denies it ("NOT RESTRAINED", "NO RESTRAINT")
_DENIED = re.compile(r"\b(?:NOT|NO|WITHOUT|NEVER)\s+(?:\w+\s+)?$", re.IGNORECASE)
#: the line that opens a numbered note ("5. DIMENSIONING ...", "2) ...")
_NOTE_START = re.compile(r"^\s*\d{1,3}\s*[.)](?:\s|$)")
#: a force limit: a force word, a bound, a value and its unit, within one sentence
_FORCE = re.compile(
    r"\bFORCES?\b[^.;]*?(?:AT\s+MOST|MAX(?:IMUM)?\.?|NOT\s+(?:TO\s+)?EXCEED(?:ING)?|<=|\u2264)"
    r"\s*(\d+(?:\.\d+)?)\s*(KN|N|LBF)\b",
    re.IGNORECASE,
)
#: the force units read, in N
_FORCE_UNITS = {"N": 1.0, "KN": 1000.0, "LBF": 4.4482216152605}

#: the targets a note holds the part at: the word TARGET(S), then a list of target labels
#: (a datum letter or two and a number; a range "A1-A4", "A1 THRU A4", "A1 TO A4"),
#: separated by commas, "AND" or "&"
_LABEL = r"[A-Z]{1,2}\s?\d{1,3}"
_RANGE = (
    rf"{_LABEL}(?:\s*(?:-|\u2013|\bTHRU\b|\bTHROUGH\b|\bTO\b)\s*(?:[A-Z]{{1,2}}\s?)?\d{{1,3}})?"
)
_TARGET_LIST = re.compile(
    rf"\bTARGETS?\b\s*((?:{_RANGE})(?:\s*(?:,|\bAND\b|&)\s*(?:{_RANGE}))*)", re.IGNORECASE
)
#: the note holds the part at its datum targets without naming them
_AT_TARGETS = re.compile(r"\bAT\s+(?:THE\s+|ITS\s+|ALL\s+)?DATUM\s+TARGETS\b", re.IGNORECASE)
_ONE = re.compile(
    r"([A-Z]{1,2})\s?(\d{1,3})(?:\s*(?:-|\u2013|THRU|THROUGH|TO)\s*(?:([A-Z]{1,2})\s?)?(\d{1,3}))?",
    re.IGNORECASE,
)
#: the longest range of target numbers expanded
MAX_RANGE = 50

#: longest excerpt kept, characters
MAX_EXCERPT = 400


def drawing_texts(model: P21Model) -> list[tuple[int, str]]:
    """The file's texts in id order, each with its entity: the lines of each
    representation of descriptive items joined, then each descriptive item of no such
    representation, then each text literal."""
    out: list[tuple[int, str]] = []
    grouped: set[int] = set()
    for rep in model.by_type("REPRESENTATION"):
        params = rep.part("REPRESENTATION") or ()
        items = [model.get(r) for r in params[1]] if len(params) > 1 else []
        if not items or not all(
            e is not None and e.types == ("DESCRIPTIVE_REPRESENTATION_ITEM",) for e in items
        ):
            continue
        lines = [str(e.params[1]) if len(e.params) > 1 else "" for e in items]
        grouped.update(e.id for e in items)
        out.append((rep.id, "\n".join(lines)))
    for item in model.by_type("DESCRIPTIVE_REPRESENTATION_ITEM"):
        p = item.part("DESCRIPTIVE_REPRESENTATION_ITEM") or ()
        if item.id not in grouped and len(p) > 1 and isinstance(p[1], str):
            out.append((item.id, p[1].replace("\\n", "\n")))
    for lit in model.by_type("TEXT_LITERAL"):
        p = lit.part("TEXT_LITERAL") or ()
        if len(p) > 1 and isinstance(p[1], str):
            out.append((lit.id, p[1].replace("\\n", "\n")))
    return out


def _excerpt(text: str, start: int) -> str:
    """The note of ``text`` around character ``start``: from the numbered line that opens it
    (else the paragraph's first line) to the next numbered line (else the paragraph's end),
    whitespace collapsed, at most :data:`MAX_EXCERPT` characters."""
    lines = text.split("\n")
    offsets, pos = [], 0
    for line in lines:
        offsets.append(pos)
        pos += len(line) + 1
    at = max(i for i, o in enumerate(offsets) if o <= start)
    first = next((i for i in range(at, -1, -1) if _NOTE_START.match(lines[i])), None)
    numbered = first is not None
    if not numbered:
        first = at
        while first > 0 and lines[first - 1].strip():
            first -= 1
    last = at
    while last + 1 < len(lines) and not _NOTE_START.match(lines[last + 1]):
        if not numbered and not lines[last + 1].strip():
            break
        last += 1
    words = " ".join(" ".join(lines[first : last + 1]).split())
    return words if len(words) <= MAX_EXCERPT else words[: MAX_EXCERPT - 3].rstrip() + "..."


def restraint_note(model: P21Model) -> RestraintNote | None:
    """The first text of the file that states a restraint (module docstring), with the
    phrase found and the note around it; None when none does.

    Parameters
    ----------
    model : the parsed Part 21 file.

    Returns
    -------
    RestraintNote or None
    """
    for eid, text in drawing_texts(model):
        for m in _RESTRAINT.finditer(text):
            if _DENIED.search(text[: m.start()]):
                continue
            note = _excerpt(text, m.start())
            force = restraint_force(note)
            return RestraintNote(
                text=note,
                phrase=" ".join(m.group(0).upper().split()),
                step_id=eid,
                force_limit=None if force is None else force[0],
                force_text="" if force is None else force[1],
                targets=restraint_targets(note),
            )
    return None


def restraint_force(note: str) -> tuple[float, str] | None:
    """The force limit a restraint note states (module docstring), N, and the words it was
    read from; None when it states none."""
    m = _FORCE.search(note)
    if m is None:
        return None
    return float(m.group(1)) * _FORCE_UNITS[m.group(2).upper()], " ".join(m.group(0).split())


def restraint_targets(note: str) -> tuple[str, ...]:
    """The datum targets a restraint note holds the part at (module docstring), upper case
    in the note's order (``('A1', 'A2', 'A3', 'A4', 'B1', 'C1', 'C2')``); :data:`ALL_TARGETS`
    when it says "at the datum targets" without naming them; ``()`` when it names none."""
    names: list[str] = []
    for m in _TARGET_LIST.finditer(note):
        for one in _ONE.finditer(m.group(1)):
            letter, first, other, last = one.groups()
            letter = letter.upper()
            if last is None:
                numbers = [int(first)]
            elif other is not None and other.upper() != letter:
                numbers = []  # "A1-B2" is no range: neither end is trusted
            else:
                lo, hi = int(first), int(last)
                numbers = list(range(lo, hi + 1)) if 0 <= hi - lo <= MAX_RANGE else []
            for k in numbers:
                if f"{letter}{k}" not in names:
                    names.append(f"{letter}{k}")
    if names:
        return tuple(names)
    return ALL_TARGETS if _AT_TARGETS.search(note) else ()
