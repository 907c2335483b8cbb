"""A small, fast, lazy reader of ISO 10303-21 ("Part 21", ``.stp``) exchange files.

The DATA section is split into records ``#id = ...;`` with one regular expression and the raw
text of each record is kept; a record's parameters are parsed only when the record is first
asked for (:meth:`P21Model.__getitem__`), then cached. Reverse references (which records point
at record *N*) and the index by entity type are built lazily, once.

Parameter values map to Python as follows:

=====================  ====================================================
Part 21                Python
=====================  ====================================================
``#12``                :class:`Ref` (``Ref(12)``)
``'text'``             :class:`str` (``''`` and ``\\X2\\...\\X0\\`` decoded)
``.NAME.``             :class:`Enum` (``.T.``/``.F.``/``.U.`` too; see
                       :attr:`Enum.value`)
``12`` / ``1.5E-3``    :class:`int` / :class:`float`
``$``                  ``None``
``*``                  :data:`DERIVED` (the :class:`Derived` singleton)
``"0A3F"``             :class:`Binary`
``NAME(...)``          :class:`Typed` (a typed parameter, e.g.
                       ``Typed('LENGTH_MEASURE', (0.75,))``)
``(a, b, ...)``        :class:`tuple`
=====================  ====================================================

A simple instance ``#5 = NAME(a, b);`` becomes ``Entity(5, 'NAME', (a, b))``; a complex
instance ``#6 = (A(a) B() C(c));`` becomes ``Entity(6, None, (), parts={'A': (a,), 'B': (),
'C': (c,)})``. :meth:`Entity.has`, :meth:`Entity.part` and :attr:`Entity.types` treat both forms
alike.

Examples
--------
>>> m = P21Model.from_text("DATA; #1 = (A(1) B('x;y')); #2 = C(#1, $, *, .T.); ENDSEC;")
>>> m[1].part('B')
('x;y',)
>>> m[2].params
(#1, None, *, .T.)
>>> m.referrers(1)
[2]
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

log = logging.getLogger(__name__)

__all__ = [
    "DERIVED",
    "Binary",
    "Derived",
    "Entity",
    "Enum",
    "P21Error",
    "P21Model",
    "Ref",
    "Typed",
    "decode_string",
    "parse_params",
]


class P21Error(ValueError):
    """The text is not a Part 21 exchange structure this reader understands."""


# --------------------------------------------------------------------------------------------
# value types
# --------------------------------------------------------------------------------------------


class Ref:
    """An entity instance name ``#id``.

    Parameters
    ----------
    id : int
        The instance number.
    """

    __slots__ = ("id",)

    def __init__(self, id: int) -> None:  # noqa: A002 - Part 21 calls it the instance id
        self.id = id

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Ref) and other.id == self.id

    def __hash__(self) -> int:
        return hash(("Ref", self.id))

    def __repr__(self) -> str:
        return f"#{self.id}"


class Enum:
    """An enumeration or logical/boolean literal ``.NAME.``.

    Parameters
    ----------
    name : str
        The literal without the dots, e.g. ``'MILLI'`` or ``'T'``.
    """

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    @property
    def value(self) -> bool | None:
        """``True`` for ``.T.``, ``False`` for ``.F.``, ``None`` otherwise (``.U.``, names)."""
        return {"T": True, "F": False}.get(self.name)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Enum) and other.name == self.name

    def __hash__(self) -> int:
        return hash(("Enum", self.name))

    def __repr__(self) -> str:
        return f".{self.name}."


class Derived:
    """The derived-value marker ``*`` (use the :data:`DERIVED` singleton)."""

    __slots__ = ()
    _instance: Derived | None = None

    def __new__(cls) -> Derived:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "*"

    def __reduce__(self) -> str:
        return "DERIVED"


DERIVED = Derived()


class Binary(str):
    """A binary literal ``"0ABC"`` (the hexadecimal text, first digit = unused bits)."""

    __slots__ = ()


class Typed(NamedTuple):
    """A typed parameter ``TYPE(value, ...)``, e.g. ``LENGTH_MEASURE(0.75)``.

    Being a named tuple it is also a :class:`tuple`: test ``isinstance(x, Typed)`` before
    ``isinstance(x, tuple)`` (an aggregate).

    Attributes
    ----------
    type : str
        The defined-type name, upper case.
    params : tuple
        Its parameters (usually one value).
    """

    type: str
    params: tuple

    @property
    def value(self) -> Any:
        """The single wrapped value (the first parameter), or ``None`` when empty."""
        return self.params[0] if self.params else None


@dataclass
class Entity:
    """One instance of the DATA section.

    Attributes
    ----------
    id : int
        The instance number.
    type : str or None
        The entity type of a simple instance (upper case); ``None`` for a complex instance.
    params : tuple
        The parameters of a simple instance (``()`` for a complex one).
    parts : dict or None
        For a complex instance, ``{TYPE: params}`` in file order; ``None`` otherwise.
    """

    id: int
    type: str | None
    params: tuple = ()
    parts: dict[str, tuple] | None = None

    @property
    def types(self) -> tuple[str, ...]:
        """All entity type names of the instance (one for a simple instance)."""
        if self.parts is None:
            return (self.type,) if self.type else ()
        return tuple(self.parts)

    @property
    def is_complex(self) -> bool:
        """Whether this is a complex (multi-part) instance."""
        return self.parts is not None

    def has(self, type_name: str) -> bool:
        """Whether ``type_name`` (case-insensitive) is the type or one of the parts."""
        name = type_name.upper()
        if self.parts is None:
            return self.type == name
        return name in self.parts

    def part(self, type_name: str) -> tuple | None:
        """Parameters of the part ``type_name`` (for a simple instance: of the instance).

        Returns ``None`` when the instance has no such type.
        """
        name = type_name.upper()
        if self.parts is None:
            return self.params if self.type == name else None
        return self.parts.get(name)

    def refs(self) -> list[int]:
        """Ids of all instances referenced by the parameters, in order, with repeats."""
        out: list[int] = []
        _collect_refs(self.params if self.parts is None else tuple(self.parts.values()), out)
        return out


def _collect_refs(value: Any, out: list[int]) -> None:
    if isinstance(value, Ref):
        out.append(value.id)
    elif isinstance(value, tuple):  # also Typed (a NamedTuple)
        for v in value:
            _collect_refs(v, out)


# --------------------------------------------------------------------------------------------
# lexical layer
# --------------------------------------------------------------------------------------------

#: one parameter token; strings use the unrolled ``'...''...'`` form (no catastrophic backtracking)
_TOKEN = re.compile(
    r"'[^']*(?:''[^']*)*'"  # string
    r"|#\d+"  # instance name
    r"|\.[A-Za-z_][A-Za-z0-9_]*\."  # enumeration / logical
    r"|[-+]?(?:\d+\.?\d*|\.\d+)(?:[Ee][-+]?\d+)?"  # number
    r"|!?[A-Za-z_][A-Za-z0-9_]*"  # keyword (type name), '!' for user-defined
    r'|"[0-9A-Fa-f]*"'  # binary
    r"|[(),$*]"
    r"|\S"  # anything else: reported as an error by parse_params
)
_NUMBER_START = frozenset("0123456789+-.")
#: a whole record after comments are gone: ``#id = <anything but ; outside strings> ;``
_RECORD = re.compile(r"#(\d+)\s*=\s*([^;']*(?:'[^']*'[^;']*)*);")
#: strings or comments; comments are replaced by a blank, strings kept
_STRING_OR_COMMENT = re.compile(r"('[^']*(?:''[^']*)*')|/\*.*?\*/", re.S)
_STRING = re.compile(r"'[^']*(?:''[^']*)*'")
_REF = re.compile(r"#(\d+)")
_LEADING_KEYWORD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")
#: the section keywords, in any case (Part 21 spells them in capitals; OCCT reads ``Data;``)
_SECTION = re.compile(r"\b(HEADER|DATA|ENDSEC)\b\s*(\([^;]*\))?\s*;", re.IGNORECASE)
_TRAILER = re.compile(r"\s*END-ISO-10303-21\s*;", re.IGNORECASE)
_CONTROL = re.compile(r"\\(X2|X4)\\([0-9A-Fa-f]*)\\X0\\|\\X\\([0-9A-Fa-f]{2})|\\S\\(.)|\\P.\\|\\\\")


def strip_comments(text: str) -> str:
    """Remove ``/* ... */`` comments outside strings (each becomes one blank)."""
    if "/*" not in text:
        return text
    return _STRING_OR_COMMENT.sub(lambda m: m.group(1) or " ", text)


def decode_string(token: str) -> str:
    """Decode a Part 21 string token (with its quotes) into Python text.

    Handles the ``''`` quote escape, ``\\\\``, ``\\X\\hh`` (ISO 8859-1), ``\\X2\\...\\X0\\``
    (UCS-2), ``\\X4\\...\\X0\\`` (UCS-4) and ``\\S\\c`` (upper half); code-page directives
    ``\\P?\\`` are dropped.
    """
    s = token[1:-1]
    if "''" in s:
        s = s.replace("''", "'")
    if "\\" not in s:
        return s

    def control(m: re.Match) -> str:
        kind, hexa, byte, upper = m.group(1), m.group(2), m.group(3), m.group(4)
        if kind:
            width = 4 if kind == "X2" else 8
            return "".join(
                chr(int(hexa[i : i + width], 16)) for i in range(0, len(hexa) - width + 1, width)
            )
        if byte:
            return chr(int(byte, 16))
        if upper:
            return chr(ord(upper) + 128)
        if m.group(0) == "\\\\":
            return "\\"
        return ""

    return _CONTROL.sub(control, s)


def parse_params(text: str) -> list:
    """Parse a sequence of Part 21 parameters into Python values.

    Parameters
    ----------
    text : str
        Parameter text, e.g. ``"'name', #12, (1., 2.), .T."`` or a whole record body
        ``"NAME('x', $)"``. Comments must already be removed.

    Returns
    -------
    list
        The top-level values; a ``NAME(...)`` becomes a :class:`Typed`, ``(...)`` a tuple.

    Raises
    ------
    P21Error
        On unbalanced parentheses, a missing or extra separator, or an unexpected character.
    """
    tokens = _TOKEN.findall(text)
    stack: list[tuple[list, str | None]] = []
    cur: list = []
    keyword: str | None = None
    sep = False  # a value was just completed: a ',' or ')' must follow
    for tok in tokens:
        c = tok[0]
        if keyword is not None:
            if c != "(":
                raise P21Error(f"{keyword} not followed by '(' in {text[:80]!r}")
            stack.append((cur, keyword))
            cur, keyword, sep = [], None, False
            continue
        if c == ",":
            if not sep:
                raise P21Error(f"missing value before ',' in {text[:80]!r}")
            sep = False
            continue
        if c == ")":
            if not stack:
                raise P21Error(f"unbalanced ')' in {text[:80]!r}")
            if cur and not sep:
                raise P21Error(f"missing value before ')' in {text[:80]!r}")
            value = tuple(cur)
            cur, kw = stack.pop()
            cur.append(Typed(kw, value) if kw is not None else value)
            sep = True
            continue
        is_keyword = c.isalpha() or c == "_" or c == "!"
        if sep and not (is_keyword and isinstance(cur[-1], Typed)):
            # only the parts of a complex instance, A(...) B(...), follow each other unseparated
            raise P21Error(f"missing ',' before {tok!r} in {text[:80]!r}")
        sep = True
        if c == "(":
            stack.append((cur, None))
            cur, sep = [], False
        elif is_keyword:
            keyword, sep = tok.upper(), False
        else:
            cur.append(_atom(tok, c, text))
    if stack:
        raise P21Error(f"unbalanced '(' in {text[:80]!r}")
    if keyword is not None:
        raise P21Error(f"{keyword} not followed by '(' in {text[:80]!r}")
    if cur and not sep:
        raise P21Error(f"trailing ',' in {text[:80]!r}")
    return cur


def _atom(tok: str, c: str, text: str):
    """The value of a one-token parameter: a reference, string, ``$``, ``*``, number,
    enumeration or binary.

    Parameters
    ----------
    tok : the token; ``c`` its first character.
    text : the parameter text it was read from (for the error message).

    Raises
    ------
    P21Error
        On a malformed number or an unexpected character.
    """
    if c == "#":
        return Ref(int(tok[1:]))
    if c == "'":
        return decode_string(tok)
    if c == "$":
        return None
    if c == "*":
        return DERIVED
    if c in _NUMBER_START:
        if c == "." and len(tok) > 2 and tok[-1] == "." and not tok[1].isdigit():
            return Enum(tok[1:-1].upper())
        try:
            if "." in tok or "e" in tok or "E" in tok:
                return float(tok)
            return int(tok)
        except ValueError:
            raise P21Error(f"bad number {tok!r} in {text[:80]!r}") from None
    if c == '"' and len(tok) > 1:
        return Binary(tok[1:-1])
    raise P21Error(f"unexpected {tok!r} in {text[:80]!r}")


def parse_record(eid: int, body: str) -> Entity:
    """Parse the body of record ``#eid = body;`` (comments removed) into an :class:`Entity`."""
    values = parse_params(body)
    if len(values) != 1:
        raise P21Error(f"#{eid}: expected one instance, got {len(values)} values")
    value = values[0]
    if isinstance(value, Typed):
        return Entity(eid, value.type, value.params)
    if isinstance(value, tuple) and all(isinstance(v, Typed) for v in value):
        return Entity(eid, None, (), {v.type: v.params for v in value})
    raise P21Error(f"#{eid}: not an entity instance: {body[:80]!r}")


# --------------------------------------------------------------------------------------------
# model
# --------------------------------------------------------------------------------------------


@dataclass
class P21Model:
    """The instances of a Part 21 file, parsed on demand.

    Attributes
    ----------
    raw : dict[int, str]
        Record body text by instance id (after ``=``, without the final ``;``).
    header : dict[str, tuple]
        HEADER entities by name (``FILE_DESCRIPTION``, ``FILE_NAME``, ``FILE_SCHEMA``) with
        their parsed parameters.
    path : Path or None
        Where the text came from.
    data_closed : bool
        Whether every DATA section is closed by ``ENDSEC;`` (``False`` for a file cut short).
    terminated : bool
        Whether ``END-ISO-10303-21;`` follows the last section.
    fragments : list of (int or None, str)
        Text of a DATA section that is not part of a complete ``#id = ...;`` record (a record
        cut short, stray characters): the id of the record before it (``None`` at the start
        of a section) and the text, cut to 80 characters. ``[]`` for a well-formed file.
    duplicates : list of int
        Instance ids defined more than once, in file order (the last definition is kept).

    The last four are facts about the text for :mod:`qifreport.step.integrity`; this reader
    itself accepts such text.
    """

    raw: dict[int, str]
    header: dict[str, tuple] = field(default_factory=dict)
    path: Path | None = None
    data_closed: bool = True
    terminated: bool = True
    fragments: list[tuple[int | None, str]] = field(default_factory=list)
    duplicates: list[int] = field(default_factory=list)
    _cache: dict[int, Entity] = field(default_factory=dict, repr=False)
    _referrers: dict[int, list[int]] | None = field(default=None, repr=False)
    _by_type: dict[str, list[int]] | None = field(default=None, repr=False)

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_text(cls, text: str, path: Path | None = None) -> P21Model:
        """Split Part 21 text into records (no parameter parsing yet).

        Parameters
        ----------
        text : str
            The whole file, or at least a ``DATA; ... ENDSEC;`` section.
        path : Path, optional
            Recorded for messages.

        Raises
        ------
        P21Error
            When no DATA section is found.
        """
        t0 = time.perf_counter()
        text = strip_comments(text)
        header: dict[str, tuple] = {}
        data_parts: list[str] = []
        pos = 0
        section: str | None = None
        for m in _SECTION.finditer(text):
            if text.count("'", 0, m.start()) % 2:
                continue  # the keyword is inside a string ('' escapes keep the parity)
            if section == "HEADER":
                header = _parse_header(text[pos : m.start()])
            elif section == "DATA":
                data_parts.append(text[pos : m.start()])
            kw = m.group(1).upper()
            section = None if kw == "ENDSEC" else kw
            pos = m.end()
        data_closed = section != "DATA"
        if not data_closed:  # missing ENDSEC
            data_parts.append(text[pos:])
        if not data_parts:
            raise P21Error(f"no DATA section in {path or 'text'}")
        terminated = data_closed and _TRAILER.match(text, pos) is not None
        raw: dict[int, str] = {}
        fragments: list[tuple[int | None, str]] = []
        duplicates: list[int] = []
        for part in data_parts:
            end, last = 0, None
            for m in _RECORD.finditer(part):
                start = m.start()
                if start > end and not part[end:start].isspace():
                    fragments.append((last, part[end:start].strip()[:80]))
                last = int(m.group(1))
                if last in raw:
                    duplicates.append(last)
                raw[last] = m.group(2)
                end = m.end()
            if part[end:].strip():
                fragments.append((last, part[end:].strip()[:80]))
        log.debug(
            "p21: %d records split in %.3f s (%s)", len(raw), time.perf_counter() - t0, path or ""
        )
        return cls(
            raw=raw,
            header=header,
            path=path,
            data_closed=data_closed,
            terminated=terminated,
            fragments=fragments,
            duplicates=duplicates,
        )

    @classmethod
    def read(cls, path: str | Path) -> P21Model:
        """Read a ``.stp`` file (UTF-8, falling back to ISO 8859-1)."""
        p = Path(path)
        data = p.read_bytes()
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            text = data.decode("latin-1")
        return cls.from_text(text, path=p)

    # ---- header -------------------------------------------------------------------------
    @property
    def schema(self) -> str:
        """FILE_SCHEMA names joined with ``'; '`` (``''`` when absent)."""
        params = self.header.get("FILE_SCHEMA")
        if not params:
            return ""
        names = params[0] if isinstance(params[0], tuple) else params
        return "; ".join(str(n) for n in names)

    # ---- access -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.raw)

    def __contains__(self, eid: object) -> bool:
        key = eid.id if isinstance(eid, Ref) else eid
        return key in self.raw

    def __iter__(self) -> Iterator[int]:
        return iter(self.raw)

    def __getitem__(self, eid: int | Ref) -> Entity:
        """The parsed instance ``eid`` (parsed once, then cached).

        Raises
        ------
        KeyError
            When there is no such instance.
        """
        key = eid.id if isinstance(eid, Ref) else eid
        ent = self._cache.get(key)
        if ent is None:
            ent = parse_record(key, self.raw[key])
            self._cache[key] = ent
        return ent

    def get(self, eid: int | Ref | None) -> Entity | None:
        """Like ``self[eid]`` but ``None`` for ``None``, a non-reference or a dangling id."""
        if isinstance(eid, Ref):
            eid = eid.id
        if not isinstance(eid, int) or eid not in self.raw:
            return None
        return self[eid]

    def parse_all(self) -> None:
        """Parse every record now (to measure, or to validate the whole file)."""
        for eid in self.raw:
            self[eid]

    def type_names(self, eid: int) -> tuple[str, ...]:
        """Entity type names of instance ``eid`` without parsing a simple instance."""
        body = self.raw[eid]
        if body.lstrip().startswith("("):
            return self[eid].types
        m = _LEADING_KEYWORD.match(body)
        return (m.group(1).upper(),) if m else ()

    def by_type(self, type_name: str) -> list[Entity]:
        """All instances having ``type_name`` as type or complex part, in id order."""
        if self._by_type is None:
            index: dict[str, list[int]] = {}
            for eid in sorted(self.raw):
                for name in self.type_names(eid):
                    index.setdefault(name, []).append(eid)
            self._by_type = index
        return [self[i] for i in self._by_type.get(type_name.upper(), ())]

    def _reverse_index(self) -> dict[int, list[int]]:
        """Referenced id -> sorted unique referencing ids (built once; strings skipped)."""
        if self._referrers is None:
            t0 = time.perf_counter()
            back: dict[int, set[int]] = {}
            for src, body in self.raw.items():
                if "'" in body:
                    body = _STRING.sub("''", body)
                for target in _REF.findall(body):
                    back.setdefault(int(target), set()).add(src)
            self._referrers = {k: sorted(v) for k, v in back.items()}
            log.debug("p21: reverse references in %.3f s", time.perf_counter() - t0)
        return self._referrers

    def referrers(self, eid: int | Ref) -> list[int]:
        """Ids of the instances whose parameters reference ``eid`` (sorted, unique)."""
        key = eid.id if isinstance(eid, Ref) else eid
        return self._reverse_index().get(key, [])

    def dangling(self) -> list[tuple[int, int]]:
        """References to instances the model does not define.

        Returns
        -------
        list of (int, int)
            ``(referencing id, missing id)`` pairs, sorted; ``[]`` when every reference
            resolves. References inside strings do not count.

        Notes
        -----
        One regular-expression pass over all record text answers the usual case (nothing
        missing); only then is the index of
        :meth:`referrers` built, to name the referencing records.
        """
        raw = self.raw
        if self._referrers is None:
            text = "\n".join(raw.values())  # each body holds whole strings only
            if "'" in text:
                text = _STRING.sub("''", text)
            if not {int(t) for t in _REF.findall(text)}.difference(raw):
                return []
        return sorted(
            (src, target)
            for target, srcs in self._reverse_index().items()
            if target not in raw
            for src in srcs
        )

    def referrers_of_type(self, eid: int | Ref, type_name: str) -> list[Entity]:
        """Referring instances that have ``type_name`` as type or part."""
        name = type_name.upper()
        out = []
        for src in self.referrers(eid):
            if name in self.type_names(src):
                out.append(self[src])
        return out


def _parse_header(text: str) -> dict[str, tuple]:
    """Parse HEADER entities ``NAME(...);`` into ``{NAME: params}``."""
    out: dict[str, tuple] = {}
    for stmt in re.finditer(
        r"([A-Za-z_][A-Za-z0-9_]*)\s*(\(([^;']*(?:'[^']*'[^;']*)*)\))\s*;", text
    ):
        try:
            values = parse_params(stmt.group(2))
        except P21Error as exc:
            log.warning("p21: unreadable header entity %s: %s", stmt.group(1), exc)
            continue
        out[stmt.group(1).upper()] = values[0] if values else ()
    return out
