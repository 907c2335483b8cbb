"""Integrity of a Part 21 model before OpenCASCADE's result is used: is the file whole?

OCCT's STEP reader accepts a damaged file quietly: a reference to a record the file does not
define is dropped with a warning, a file cut short and closed with ``ENDSEC;
END-ISO-10303-21;`` reads as a smaller part, and the PMI that went with the missing records
is simply absent (the run would then score the part against the default general tolerance).
:func:`integrity_problems` lists what is wrong with the text itself, and :func:`check_integrity`
turns the first problems into one :class:`~qifreport.errors.InputError` line;
:func:`qifreport.step.reader.read_step` runs it on every file before XDE reads it.

The checks, in the order they are reported:

``structure``
    the DATA section must be closed by ``ENDSEC;`` and the file by ``END-ISO-10303-21;``;
    every piece of text in the DATA section must be a complete ``#id = ...;`` record (a file
    cut inside a record and then closed leaves such a fragment).
``duplicate``
    no instance id may be defined twice.
``dangling``
    every ``#id`` named by an entity's attributes must be defined in the file. Part 21 has no
    optional reference that may point nowhere (an unset optional attribute is ``$``), so
    there is no exception: all seven NIST AP242 test files and ``samples/panel.step`` resolve
    every reference. Deleted records (three ADVANCED_FACEs of a CLOSED_SHELL, say) and most
    truncations show here, as forward references to the lost part.
``no_solid``
    the file must define a solid OCCT builds: a ``MANIFOLD_SOLID_BREP`` or one of its
    subtypes (:data:`SOLID_TYPES`), or an AP242 tessellated solid or shell
    (:data:`TESSELLATED_TYPES`, read as faces that carry only their triangles), and use it:
    the solid is an item of a representation (the usual
    ``ADVANCED_BREP_SHAPE_REPRESENTATION``) that is the shape of a product -- named by a
    ``SHAPE_DEFINITION_REPRESENTATION`` directly or through representation relationships (or
    the ``REPRESENTATION_MAP`` / ``MAPPED_ITEM`` of an assembly). A
    ``SHELL_BASED_SURFACE_MODEL`` -- even of a ``CLOSED_SHELL`` -- is read by OCCT as a shell,
    not a solid (checked with the panel's solid so rewritten), so it does not count;
    constructive (CSG) solids are not translated by OCCT at all. The "in use" part catches
    files cut at a record boundary by a writer that names only earlier records: ``nist_ctc_04``
    cut at the last record boundary before 77 % keeps its solid but none of the records
    that used it, at 78 % its representation but no product link; ``nist_ftc_08``
    cut at 30-40 % likewise. In every case the whole PMI is gone and no reference dangles.

What no check of the text can see: a file cut exactly at a record boundary when the lost
records were only referrers -- the PMI block written last, with the geometry and its product
link complete before it (``nist_ctc_04`` cut at 79 %, ``nist_ftc_08`` at 41 %,
``samples/panel.step`` from 94 %). That is a valid, smaller exchange file; only a checksum
from the sender tells it apart. Part 21 edition 3 external references (a REFERENCE section)
are not supported: ids defined there count as missing.

Cost: the checks are passes over the record text (no record is parsed but the last one and
a few whose type is asked: a regular-expression pass for the references, substring scans for
solids and representations), a small part of what splitting the file, let alone reading it,
costs.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from dataclasses import dataclass

from qifreport.errors import InputError

from .p21 import P21Error, P21Model

__all__ = [
    "SOLID_TYPES",
    "TESSELLATED_TYPES",
    "IntegrityProblem",
    "check_integrity",
    "integrity_problems",
]

#: entity types that OCCT turns into a ``TopoDS_Solid`` (MANIFOLD_SOLID_BREP and subtypes)
SOLID_TYPES: tuple[str, ...] = (
    "MANIFOLD_SOLID_BREP",
    "BREP_WITH_VOIDS",
    "FACETED_BREP",
    "FACETED_BREP_AND_BREP_WITH_VOIDS",
)
#: tessellated shapes (AP242): OCCT reads their triangulated faces as faces without a surface
TESSELLATED_TYPES: tuple[str, ...] = ("TESSELLATED_SOLID", "TESSELLATED_SHELL")

_STRING = re.compile(r"'[^']*(?:''[^']*)*'")
_REF = re.compile(r"#(\d+)")

#: shells and faces: surfaces OCCT reads as such, not as a solid
_SURFACE_TYPES = ("CLOSED_SHELL", "OPEN_SHELL", "ADVANCED_FACE", "FACE_SURFACE")

#: how many missing ids a dangling-reference message lists
_LISTED = 3


@dataclass(frozen=True)
class IntegrityProblem:
    """One reason a Part 21 model cannot be trusted.

    Attributes
    ----------
    kind : str
        ``'structure'``, ``'duplicate'``, ``'dangling'`` or ``'no_solid'``.
    message : str
        One sentence naming the entity (``#id TYPE``) and the reason.
    step_id : int or None
        The entity concerned (the referencing one for a dangling reference), if any.
    """

    kind: str
    message: str
    step_id: int | None = None

    @property
    def damage(self) -> bool:
        """Whether the file is damaged (every kind but ``'no_solid'``)."""
        return self.kind != "no_solid"


def _type_label(model: P21Model, eid: int) -> str:
    """``TYPE`` of a simple instance, ``(A B ...)`` of a complex one, ``?`` if unreadable."""
    try:
        names = model.type_names(eid)
    except (P21Error, KeyError):
        return "?"
    if not names:
        return "?"
    return names[0] if len(names) == 1 else "(" + " ".join(names) + ")"


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _last_record_cut(model: P21Model) -> int | None:
    """The last record in file order when its text does not parse (cut off), else ``None``."""
    if not model.raw:
        return None
    last = next(reversed(model.raw))
    try:
        model[last]
    except P21Error:
        return last
    return None


def _structure(model: P21Model) -> list[IntegrityProblem]:
    """The end of the file: one ``unexpected end of file`` problem for a file cut short (what
    was found at the end, which closing line is missing), then any other stray text."""
    out: list[IntegrityProblem] = []
    frags = list(model.fragments)
    last = next(reversed(model.raw)) if model.raw else None
    tail = frags.pop() if frags and frags[-1][0] == last else None
    cut = _last_record_cut(model)
    ends: list[str] = []
    if cut is not None:
        ends.append(f"the last record, #{cut} {_type_label(model, cut)}, is cut off")
    elif tail is not None:
        where = f"after #{last} {_type_label(model, last)}" if last is not None else ""
        ends.append(f"the file ends inside a record ({tail[1][:40]!r} {where})".replace(" )", ")"))
    if not model.data_closed:
        ends.append("no ENDSEC; closes the DATA section")
    elif not model.terminated:
        ends.append("no END-ISO-10303-21; ends the file")
    if ends:
        closed = model.data_closed and model.terminated
        out.append(
            IntegrityProblem(
                "structure",
                "unexpected end of file: "
                + " and ".join(ends)
                + (
                    " (the file was cut short and closed again)"
                    if closed
                    else " (the file was cut short)"
                ),
                cut if cut is not None else last,
            )
        )
    if frags:
        after, text = frags[0]
        where = f"after #{after} {_type_label(model, after)}" if after is not None else "first"
        more = len(frags) - 1
        out.append(
            IntegrityProblem(
                "structure",
                f"text that is not a complete record ({where}: {text[:60]!r}): a record cut "
                "short or garbled" + (f" ({more} more such pieces)" if more else ""),
                after,
            )
        )
    return out


def _duplicates(model: P21Model) -> list[IntegrityProblem]:
    if not model.duplicates:
        return []
    eid = model.duplicates[0]
    more = len(model.duplicates) - 1
    return [
        IntegrityProblem(
            "duplicate",
            f"#{eid} is defined more than once (the last is {_type_label(model, eid)})"
            + (f"; {_plural(more, 'more id')} defined twice" if more else ""),
            eid,
        )
    ]


def _dangling(model: P21Model) -> list[IntegrityProblem]:
    pairs = model.dangling()
    if not pairs:
        return []
    src, missing = pairs[0]
    targets = sorted({t for _, t in pairs})
    sources = {s for s, _ in pairs}
    msg = f"#{src} {_type_label(model, src)} refers to #{missing}, which the file does not define"
    if len(pairs) > 1:
        listed = ", ".join(f"#{t}" for t in targets[:_LISTED])
        if len(targets) > _LISTED:
            listed += ", ..."
        msg += (
            f" ({_plural(len(targets), 'missing record')} ({listed}) named by "
            f"{_plural(len(sources), 'record')}, {_plural(len(pairs), 'reference')})"
        )
    return [IntegrityProblem("dangling", msg, src)]


def _is_representation(name: str) -> bool:
    """Whether an entity type holds representation items (SHAPE_REPRESENTATION and the like)."""
    if name.endswith("DEFINITION_REPRESENTATION"):  # points at representations, not items
        return False
    return name.endswith("REPRESENTATION") or name.endswith("REPRESENTATION_WITH_PARAMETERS")


def _types(model: P21Model, eid: int) -> tuple[str, ...]:
    try:
        return model.type_names(eid)
    except P21Error:
        return ()


def _with_word(model: P21Model, word: str, upper_only: bool) -> Iterator[tuple[int, str]]:
    """``(id, body)`` of the records whose text holds ``word`` (upper case, as ISO 10303-21
    spells keywords; ``upper_only=False`` also finds it in any case, which is slower)."""
    low = word.lower()
    for eid, body in model.raw.items():
        if word in body or (not upper_only and low in body.lower()):
            yield eid, body


def _solid_ids(model: P21Model, upper_only: bool) -> list[int]:
    """The solids, and the tessellated solids and shells, of the file."""
    out = []
    for word, types in (("BREP", SOLID_TYPES), ("TESSELLATED_S", TESSELLATED_TYPES)):
        wanted = set(types)
        out += [
            e
            for e, _ in _with_word(model, word, upper_only)
            if wanted.intersection(_types(model, e))
        ]
    return out


def _referrers_of(model: P21Model, eid: int) -> list[int]:
    """Records naming ``#eid`` outside strings (a scan: the reverse index costs more)."""
    token = f"#{eid}"
    exact = re.compile(rf"#{eid}(?!\d)")
    out = []
    for src, body in model.raw.items():
        if token in body:
            if "'" in body:
                body = _STRING.sub("''", body)
            if exact.search(body):
                out.append(src)
    return out


def _refs(model: P21Model, eid: int) -> set[int]:
    body = model.raw[eid]
    if "'" in body:
        body = _STRING.sub("''", body)
    return {int(t) for t in _REF.findall(body)}


def _anchored(model: P21Model, rep: int, seen: set[int]) -> bool:
    """Whether representation ``rep`` is the shape of a product: named by a
    SHAPE_DEFINITION_REPRESENTATION, directly or through representation relationships or the
    REPRESENTATION_MAP / MAPPED_ITEM of an assembly."""
    seen.add(rep)
    for src in _referrers_of(model, rep):
        types = _types(model, src)
        if "SHAPE_DEFINITION_REPRESENTATION" in types:
            return True
        if any(t.endswith("REPRESENTATION_RELATIONSHIP") for t in types):
            others = [r for r in _refs(model, src) if r not in seen and r in model.raw]
        elif "REPRESENTATION_MAP" in types:
            others = [
                outer
                for item in _referrers_of(model, src)
                if "MAPPED_ITEM" in _types(model, item)
                for outer in _referrers_of(model, item)
                if outer not in seen
            ]
        else:
            continue
        for other in others:
            if any(_is_representation(n) for n in _types(model, other)) and _anchored(
                model, other, seen
            ):
                return True
    return False


def _solid_reps(model: P21Model, solids: list[int], upper_only: bool) -> list[int]:
    """The representations that hold one of ``solids`` as an item (representations are few)."""
    solid_set = set(solids)
    out = []
    for src, body in _with_word(model, "REPRESENTATION", upper_only):
        if not any(_is_representation(n) for n in _types(model, src)):
            continue
        if "'" in body:
            body = _STRING.sub("''", body)
        if solid_set.intersection(int(t) for t in _REF.findall(body)):
            out.append(src)
    return out


def _solids(model: P21Model) -> list[IntegrityProblem]:
    # a pass over the text, not the type index (which parses every complex instance); the
    # case-blind pass only when the upper-case one finds nothing
    solids = _solid_ids(model, True) or _solid_ids(model, False)
    if not solids:
        n_surf = sum(len(model.by_type(t)) for t in _SURFACE_TYPES)
        return [
            IntegrityProblem(
                "no_solid",
                "no solid in the STEP file: it defines no "
                + ", ".join(SOLID_TYPES[:-1])
                + f", {SOLID_TYPES[-1]} or tessellated shape ("
                + (
                    f"only surfaces: {n_surf} shells and faces)"
                    if n_surf
                    else f"no shape to inspect at all: {_plural(len(model), 'record')}, "
                    "no shell or face)"
                ),
            )
        ]
    reps = _solid_reps(model, solids, True) or _solid_reps(model, solids, False)
    seen: set[int] = set()
    if any(_anchored(model, r, seen) for r in reps):
        return []
    eid = solids[0]
    if reps:
        return [
            IntegrityProblem(
                "no_solid",
                f"no solid in use: #{reps[0]} {_type_label(model, reps[0])}, which holds "
                f"#{eid} {_type_label(model, eid)}, is the shape of no product (no "
                "SHAPE_DEFINITION_REPRESENTATION leads to it: the records that linked it are "
                "missing, a file cut short?)",
                reps[0],
            )
        ]
    return [
        IntegrityProblem(
            "no_solid",
            f"no solid in use: #{eid} {_type_label(model, eid)}"
            + (f" and {len(solids) - 1} more solids are" if len(solids) > 1 else " is")
            + " an item of no shape representation, so no solid is read (the records that "
            "used it are missing: a file cut short?)",
            eid,
        )
    ]


def integrity_problems(model: P21Model) -> list[IntegrityProblem]:
    """Everything that makes a Part 21 model untrustworthy, most fundamental first.

    Parameters
    ----------
    model : P21Model
        The file as split by :meth:`qifreport.step.p21.P21Model.read` (records need not be
        parsed; only the type names of a few are).

    Returns
    -------
    list of IntegrityProblem
        ``structure``, then ``duplicate``, ``dangling`` and ``no_solid`` problems (see the
        module docstring for the rules); ``[]`` for a whole file with a solid.
    """
    return _structure(model) + _duplicates(model) + _dangling(model) + _solids(model)


def check_integrity(model: P21Model, name: str) -> float:
    """Refuse a damaged Part 21 model, or one without a solid, with one line naming why.

    Parameters
    ----------
    model : P21Model
        The file, as read by :meth:`qifreport.step.p21.P21Model.read`.
    name : str
        The file name that starts the message.

    Returns
    -------
    float
        Seconds the check took.

    Raises
    ------
    InputError
        ``"<name>: STEP file damaged: <first problem>[; also <second>][; and N more]"`` when
        the file is damaged, e.g. ``"part.stp: STEP file damaged: #16 CLOSED_SHELL refers to
        #17, which the file does not define"``; ``"<name>: no solid ..."`` when it is whole
        but defines no solid in use.
    """
    t0 = time.perf_counter()
    problems = integrity_problems(model)
    if problems:
        damage = [p for p in problems if p.damage]
        if not damage:
            raise InputError(f"{name}: {problems[0].message}")
        msg = f"{name}: STEP file damaged: {damage[0].message}"
        if len(damage) > 1:
            msg += f"; also {damage[1].message}"
        if len(damage) > 2:
            msg += f"; and {_plural(len(damage) - 2, 'more problem')}"
        raise InputError(msg)
    return time.perf_counter() - t0
