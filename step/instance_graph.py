"""Reading the instance graph of a Part 21 model: attribute values, references, referrers.

STEP attributes of the PMI structures may be wrapped in typed parameters, nested in aggregates,
or unset (``$``). :func:`unwrap_typed`, :func:`refs_of`, :func:`enum_names` and :func:`text_of`
read such values without raising. :class:`GraphWalker` navigates a
:class:`~qifreport.step.p21.P21Model`: it resolves references, type names and referrers, and
records an unreadable record as a problem instead of failing. It is the base of the semantic PMI
readers (:mod:`.units`, :mod:`.face_links`, :mod:`.semantic`).
"""

from __future__ import annotations

from collections.abc import Iterable

from .p21 import Entity, Enum, P21Error, P21Model, Ref, Typed

__all__ = ["GraphWalker", "enum_names", "refs_of", "text_of", "unwrap_typed"]


def unwrap_typed(value: object) -> tuple[object, str]:
    """Strip nested typed parameters: ``POSITIVE_LENGTH_MEASURE(LENGTH_MEASURE(1.))``.

    Parameters
    ----------
    value : object
        An attribute value, possibly a (nested) :class:`~qifreport.step.p21.Typed`.

    Returns
    -------
    value : object
        The innermost value.
    type_name : str
        The outermost type name (``'POSITIVE_LENGTH_MEASURE'``), ``''`` if not typed.
    """
    name = ""
    while isinstance(value, Typed):
        name = name or value.type
        value = value.value
    return value, name


def refs_of(value: object) -> list[Ref]:
    """References in a parameter that is a reference or an aggregate of them (flattened).

    Parameters
    ----------
    value : object
        An attribute value: a :class:`~qifreport.step.p21.Ref`, a typed value or a (nested)
        aggregate.

    Returns
    -------
    list of Ref
        In order of appearance; empty for anything else (``$``, numbers, strings).
    """
    if isinstance(value, Ref):
        return [value]
    if isinstance(value, Typed):
        return refs_of(value.params)
    if isinstance(value, tuple):
        out: list[Ref] = []
        for v in value:
            out.extend(refs_of(v))
        return out
    return []


def enum_names(value: object) -> list[str]:
    """Lower-case names of the enumerations in a parameter (flattened).

    Parameters
    ----------
    value : object
        An attribute value: an :class:`~qifreport.step.p21.Enum`, a typed value or a (nested)
        aggregate.

    Returns
    -------
    list of str
        ``['mmc', 'free_state']`` for ``(.MMC., .FREE_STATE.)``; empty for anything else.
    """
    if isinstance(value, Enum):
        return [value.name.lower()]
    if isinstance(value, Typed):
        return enum_names(value.params)
    if isinstance(value, tuple):
        out: list[str] = []
        for v in value:
            out.extend(enum_names(v))
        return out
    return []


def text_of(value: object) -> str:
    """A string attribute, ``''`` for ``$`` or anything else.

    Parameters
    ----------
    value : object
        An attribute value.

    Returns
    -------
    str
    """
    return value if isinstance(value, str) else ""


class GraphWalker:
    """Navigation of one model's instance graph, collecting the problems met on the way.

    Parameters
    ----------
    model : P21Model
        The parsed file.

    Attributes
    ----------
    m : P21Model
        The model.
    problems : list of str
        What could not be read or established, in the order met.
    """

    def __init__(self, model: P21Model) -> None:
        self.m = model
        self.problems: list[str] = []

    def get(self, ref: object) -> Entity | None:
        """The entity of a reference, ``None`` for ``$``/dangling/unreadable."""
        if not isinstance(ref, Ref):
            return None
        try:
            return self.m.get(ref)
        except P21Error as exc:
            self.problems.append(f"#{ref.id}: unreadable record ({exc})")
            return None

    def types(self, ref: Ref | int) -> tuple[str, ...]:
        """Type names of an instance (its parts for a complex one), ``()`` if unreadable."""
        key = ref.id if isinstance(ref, Ref) else ref
        if key not in self.m.raw:
            return ()
        try:
            return self.m.type_names(key)
        except P21Error:
            return ()

    def referrers_with(self, eid: int, names: Iterable[str]) -> list[Entity]:
        """Referring entities having one of ``names`` as type or part."""
        wanted = set(names)
        out = []
        for src in self.m.referrers(eid):
            if wanted.intersection(self.types(src)):
                ent = self.get(Ref(src))
                if ent is not None:
                    out.append(ent)
        return out

    @staticmethod
    def params_of(ent: Entity, names: Iterable[str]) -> tuple | None:
        """Parameters of the first of ``names`` that ``ent`` has (type or part)."""
        for n in names:
            p = ent.part(n)
            if p is not None:
                return p
        return None
