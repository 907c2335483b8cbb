"""Building blocks of the QIF 3.0 documents qifreport writes (results and statistics).

* :data:`E`: an ``lxml.builder.ElementMaker`` in the QIF namespace (the default namespace of
  every document, with ``xsi``), :data:`SCHEMA_LOCATION` the ``xsi:schemaLocation`` written;
* :class:`Ids`: sequential QIF ids and the document's ``idMax``; :func:`qpid`: a new QPId;
* literals: :func:`dec` (``xs:decimal``, fixed point), :func:`xml_double` (``xs:double``,
  exact), :func:`xml_time` (``xs:dateTime`` in UTC), :func:`token` (``xs:token``);
* :func:`id_array`: an array of ids with its ``n``; :class:`Attrs`: a typed ``Attributes``
  element.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterable
from datetime import datetime, timezone

import numpy as np
from lxml import etree
from lxml.builder import ElementMaker

__all__ = [
    "DECIMAL_PLACES",
    "NS",
    "SCHEMA_LOCATION",
    "XSI",
    "Attrs",
    "E",
    "Ids",
    "dec",
    "id_array",
    "qpid",
    "token",
    "xml_double",
    "xml_time",
]

NS = "http://qifstandards.org/xsd/qif3"
XSI = "http://www.w3.org/2001/XMLSchema-instance"
#: ``xsi:schemaLocation`` written in every document: the official root schema, relative to a
#: copy of the QIF XSD folder beside the file (readers that validate map it to their copy).
SCHEMA_LOCATION = f"{NS} ../QIFApplications/QIFDocument.xsd"
#: places after the decimal point of every ``xs:decimal`` length (mm): 0.1 um.
DECIMAL_PLACES = 4

#: element maker of the QIF namespace (default namespace, ``xsi`` declared)
E = ElementMaker(namespace=NS, nsmap={None: NS, "xsi": XSI})


class Ids:
    """Sequential QIF ids (1, 2, ...); ``max`` is the document's ``idMax``.

    Calling the object returns the next id, as text. :meth:`uuid` gives an element's UUID:
    with a ``namespace`` (a plan's QPId) the same element of the same plan gets the same
    UUID in every document that carries it; without one, a random UUID.
    """

    def __init__(self, namespace: str | None = None) -> None:
        self.max = 0
        self.namespace = None if namespace is None else uuid.UUID(namespace)

    def __call__(self) -> str:
        self.max += 1
        return str(self.max)

    def uuid(self, element_id: str, what: str) -> str:
        """The UUID of the element ``element_id`` (its QIF id) of kind ``what`` (e.g.
        ``"characteristic-item"``)."""
        if self.namespace is None:
            return qpid()
        return str(uuid.uuid5(self.namespace, f"{what}:{element_id}"))


def qpid() -> str:
    """A new QPId (a random UUID, as text)."""
    return str(uuid.uuid4())


def dec(x: float, places: int = DECIMAL_PLACES) -> str:
    """An ``xs:decimal`` literal (fixed point, no exponent, no ``-0``).

    Parameters
    ----------
    x : float
        The value.
    places : int
        Places after the decimal point (default :data:`DECIMAL_PLACES`).

    Returns
    -------
    str
    """
    s = f"{float(x):.{places}f}"
    if float(s) == 0.0:
        s = s.lstrip("-")
    return s


def xml_double(x: float) -> str:
    """An ``xs:double`` literal that round-trips exactly (``INF``/``NaN`` as XSD spells them)."""
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "INF" if x > 0 else "-INF"
    return repr(x)


def xml_time(t: datetime) -> str:
    """An ``xs:dateTime`` literal in UTC, to the second (``2024-01-02T03:04:05Z``).

    Parameters
    ----------
    t : datetime
        A timezone-aware time.

    Returns
    -------
    str
    """
    return t.astimezone(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def token(s: str) -> str:
    """Collapse whitespace (``xs:token``); never empty (``"-"``)."""
    return " ".join(str(s).split()) or "-"


def id_array(tag: str, ids: Iterable[str]) -> etree._Element:
    """An array of QIF ids: ``<tag n="k"><Id>..</Id>...</tag>``.

    Parameters
    ----------
    tag : str
        Local name of the array element (``"FeatureNominalIds"``...).
    ids : iterable of str
        The ids, in order.

    Returns
    -------
    lxml.etree._Element
    """
    ids = list(ids)
    return E(tag, *[E.Id(i) for i in ids], n=str(len(ids)))


class Attrs:
    """Builder of a QIF ``Attributes`` element (typed name/value pairs).

    Each adder returns the builder, so calls chain: ``Attrs().s("key", k).d("upper_mm", u)``.
    """

    def __init__(self) -> None:
        self.items: list[etree._Element] = []

    def d(self, name: str, value: float | None) -> Attrs:
        """An ``AttributeD1`` (a double); nothing if ``value`` is None or not finite."""
        if value is not None and math.isfinite(float(value)):
            self.items.append(E.AttributeD1(name=name, value=xml_double(value)))
        return self

    def i(self, name: str, value: int) -> Attrs:
        """An ``AttributeI1`` (an integer)."""
        self.items.append(E.AttributeI1(name=name, value=str(int(value))))
        return self

    def b(self, name: str, value: bool) -> Attrs:
        """An ``AttributeBool``."""
        self.items.append(E.AttributeBool(name=name, value="true" if value else "false"))
        return self

    def s(self, name: str, value: str) -> Attrs:
        """An ``AttributeStr``."""
        self.items.append(E.AttributeStr(name=name, value=str(value)))
        return self

    def d3(self, name: str, xyz) -> Attrs:
        """An ``AttributeD3`` (three doubles); nothing unless ``xyz`` is 3 finite numbers."""
        xyz = np.asarray(xyz, dtype=float).ravel()
        if xyz.shape == (3,) and np.all(np.isfinite(xyz)):
            self.items.append(E.AttributeD3(name=name, value=" ".join(xml_double(v) for v in xyz)))
        return self

    def element(self) -> etree._Element | None:
        """The ``Attributes`` element with its ``n``; None when no attribute was added."""
        if not self.items:
            return None
        return E.Attributes(*self.items, n=str(len(self.items)))
