"""Who the part is: its part number, name and revision as the STEP file's product states them.

A STEP file names its part in ``PRODUCT('part number', 'name', 'description', ...)`` and its
revision in the ``PRODUCT_DEFINITION_FORMATION`` (or ``..._WITH_SPECIFIED_SOURCE``) of that
product (``('revision', 'description', #product)``). The inspection's outputs carry them
(QIF ``Part/ModelNumber`` and ``Version``, the report's header, the JSON summary, the batch
table), so that a result is traced to the drawing's revision it was judged against.

Public API
----------
:class:`ProductIdentity`, :func:`product_identity`
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from .p21 import P21Model, Ref

__all__ = ["ProductIdentity", "product_identity"]

#: texts exporters write where a field has no value
_EMPTY = {"", "none", "null", "unknown", "n/a", "-", "$"}
_FORMATIONS = ("PRODUCT_DEFINITION_FORMATION", "PRODUCT_DEFINITION_FORMATION_WITH_SPECIFIED_SOURCE")


@dataclass(frozen=True)
class ProductIdentity:
    """The part as the file names it: ``number`` (``PRODUCT.id``), ``name``, ``revision``
    (its formation's id); None where the file leaves a field empty. ``step_id``: the
    ``PRODUCT`` record's ``#id``."""

    number: str | None
    name: str | None
    revision: str | None
    step_id: int

    def to_dict(self) -> dict:
        return asdict(self)


def _text(value) -> str | None:
    return value.strip() if isinstance(value, str) and value.strip().lower() not in _EMPTY else None


def product_identity(model: P21Model) -> ProductIdentity | None:
    """The part's identity (:class:`ProductIdentity`) from the first ``PRODUCT`` of
    ``model`` that names anything (an assembly's files list the root product first); None
    when the file has no product."""
    products = model.by_type("PRODUCT")
    named = [p for p in products if _text(p.params[0]) or _text(p.params[1])] if products else []
    if not named:
        return None
    p = named[0]
    revision = None
    for t in _FORMATIONS:
        for f in model.by_type(t):
            if len(f.params) > 2 and isinstance(f.params[2], Ref) and f.params[2].id == p.id:
                revision = revision or _text(f.params[0])
    return ProductIdentity(_text(p.params[0]), _text(p.params[1]), revision, p.id)
