"""A drawing's modifiers as the QIF elements that state them, so a QMS importer sees the
requirement the drawing states, not only a plain tolerance:

================================  =============================================
PMI modifier (as the STEP reader   QIF element of the characteristic definition
names it)
================================  =============================================
``free_state`` (F)                ``FreeState``
``statistical_tolerance`` (ST)    ``StatisticalCharacteristic``
``common_zone`` (CZ)              ``CommonZone``
``continuous_feature`` (CF)       ``UnitedOrContinuousFeature``
``tangent_plane`` (T)             ``TangentPlane`` (orientation)
``projected <h> mm`` (P)          ``ProjectedToleranceZoneValue`` (position,
                                  orientation), mm
``all_around``, ``all_over``,     a profile's ``Extent`` (``ALL_AROUND``,
``between``                       ``ALL_OVER``, ``OtherExtent`` "between")
================================  =============================================

Whether qifreport applies a modifier is the metrology's business
(:func:`qifreport.kinds.unapplied_modifiers`); the definition states it either way.
"""

from __future__ import annotations

from lxml import etree

from qifreport.metrology.gdt.characteristic_types import Unmeasurable
from qifreport.metrology.gdt.projected import projected_height

from .xmlkit import E, dec

__all__ = ["FLAG_ELEMENTS", "extent", "modifier_flags", "projected_value"]

#: modifier -> the boolean element of ``CharacteristicDefinitionBaseType``, schema order
_FLAGS = (
    ("free_state", "FreeState"),
    ("statistical_tolerance", "StatisticalCharacteristic"),
    ("common_zone", "CommonZone"),
    ("continuous_feature", "UnitedOrContinuousFeature"),
)
#: every boolean element a definition states a modifier with (an orientation's
#: ``TangentPlane`` too)
FLAG_ELEMENTS = (*(tag for _, tag in _FLAGS), "TangentPlane")


def _words(modifiers: list[str]) -> set[str]:
    """The modifiers' names (a projected zone's ``projected 10.795 mm``: ``projected``)."""
    return {m.split()[0] for m in modifiers if m.strip()}


def modifier_flags(modifiers: list[str]) -> list[etree._Element]:
    """The base definition's boolean elements (``FreeState``, ``StatisticalCharacteristic``
    ...) the ``modifiers`` set, in the schema's order (after the ``Name``)."""
    words = _words(modifiers)
    return [E(tag, "true") for mod, tag in _FLAGS if mod in words]


def projected_value(modifiers: list[str]) -> etree._Element | None:
    """``ProjectedToleranceZoneValue`` (the projected zone's height, mm) of a projected
    zone, None without one (or without a height the drawing gives)."""
    try:
        height = projected_height(modifiers)
    except Unmeasurable:
        return None
    return None if height is None else E.ProjectedToleranceZoneValue(dec(height))


def extent(modifiers: list[str]) -> etree._Element | None:
    """A profile's ``Extent`` (all around, all over, between), None for none stated."""
    words = _words(modifiers)
    if "all_around" in words:
        return E.Extent(E.ExtentEnum("ALL_AROUND"))
    if "all_over" in words:
        return E.Extent(E.ExtentEnum("ALL_OVER"))
    if "between" in words:
        return E.Extent(E.OtherExtent("between"))
    return None
