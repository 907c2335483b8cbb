"""The identity constraints (``xs:key``, ``xs:keyref``, ``xs:unique``) of the QIF 3.0 XSDs.

The XSD validators report a violated identity constraint at the scope element (xmlschema)
or at the selected element (libxml2), and xmlschema names only the referred key. The
constraints are read from the XSD files as written there (:func:`identity_constraints`) and
evaluated on the instance document to name the violated constraint and to locate the
referencing element (:func:`locate_references`, :func:`keys_selecting`); key values are
compared as XSD compares QIF ids (:func:`norm_value`).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

from lxml import etree

from .xsd import QIF_NS, XSD_NS, local_name, xml_parser

__all__ = [
    "IdentityConstraint",
    "identity_constraints",
    "keys_selecting",
    "locate_references",
    "norm_value",
]


@dataclass(frozen=True)
class IdentityConstraint:
    """An xs:key / xs:keyref / xs:unique of the QIF XSDs, as written there.

    Attributes
    ----------
    kind : str
        ``"key"``, ``"keyref"`` or ``"unique"``.
    name : str
        Local name, e.g. ``"FeatureItemIdKeyref"``.
    scope : str
        Local name of the element declaring it, e.g. ``"QIFDocument"``.
    refer : str or None
        keyref: local name of the key it refers to.
    selector : str
        The selector's XPath (whitespace removed).
    fields : tuple of str
        The fields' XPaths (whitespace removed).
    nsmap : tuple of (str, str)
        The prefixed namespaces in scope of the declaration.
    """

    kind: str
    name: str
    scope: str
    refer: str | None
    selector: str
    fields: tuple[str, ...]
    nsmap: tuple[tuple[str, str], ...]


@functools.lru_cache(maxsize=4)
def identity_constraints(sd: Path) -> dict[str, IdentityConstraint]:
    """All identity constraints declared in the XSD files of a schema folder, by name.

    Parameters
    ----------
    sd : Path
        A schema folder (:func:`qifreport.qif.xsd.schema_dir`); read once per folder.

    Returns
    -------
    dict of str to IdentityConstraint
    """
    out: dict[str, IdentityConstraint] = {}
    parser = xml_parser()
    for xsd in sorted(sd.rglob("*.xsd")):
        try:
            doc = etree.parse(str(xsd), parser)
        except etree.XMLSyntaxError:
            continue
        for el in doc.iter(f"{{{XSD_NS}}}key", f"{{{XSD_NS}}}keyref", f"{{{XSD_NS}}}unique"):
            name = el.get("name")
            sel = el.find(f"{{{XSD_NS}}}selector")
            scope = next(
                (a.get("name") for a in el.iterancestors(f"{{{XSD_NS}}}element") if a.get("name")),
                None,
            )
            if not name or sel is None or scope is None:
                continue
            refer = el.get("refer")
            out[name] = IdentityConstraint(
                kind=etree.QName(el).localname,
                name=name,
                scope=scope,
                refer=refer.split(":")[-1] if refer else None,
                selector=re.sub(r"\s+", "", sel.get("xpath", "")),
                fields=tuple(
                    re.sub(r"\s+", "", f.get("xpath", ""))
                    for f in el.iterfind(f"{{{XSD_NS}}}field")
                ),
                nsmap=tuple((k, v) for k, v in el.nsmap.items() if k),
            )
    return out


def norm_value(v: Any) -> str:
    """A key value compared as XSD does for QIF ids: numerically if numeric, else as text.

    Parameters
    ----------
    v : Any
        The value (text, number).

    Returns
    -------
    str
        A finite decimal in fixed notation without trailing zeros, else the stripped text.
    """
    s = str(v).strip()
    try:
        d = Decimal(s)
    except InvalidOperation:
        return s
    if not d.is_finite():
        return s
    return format(d.normalize(), "f")


def _field_values(node: etree._Element, fld: str, ns: dict[str, str]) -> list[tuple[str, int]]:
    """Values (normalized) and lines of one identity field evaluated on a selected node."""
    try:
        res = node.xpath(fld, namespaces=ns)
    except etree.XPathError:
        return []
    out = []
    for r in res if isinstance(res, list) else [res]:
        if isinstance(r, etree._Element):
            out.append((norm_value("".join(r.itertext())), r.sourceline or 0))
        elif isinstance(r, str):
            parent = getattr(r, "getparent", lambda: None)()
            out.append((norm_value(r), parent.sourceline if parent is not None else 0))
    return out


def locate_references(
    tree: etree._ElementTree, ident: IdentityConstraint, values: tuple[str, ...]
) -> list[int]:
    """Lines of the nodes whose fields of identity ``ident`` equal ``values``.

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document.
    ident : IdentityConstraint
        The constraint whose selector and fields are evaluated.
    values : tuple of str
        The field values looked for (:func:`norm_value`).

    Returns
    -------
    list of int
        Sorted, distinct; the line of the last field, else of the selected node.
    """
    ns = dict(ident.nsmap) or {"t": QIF_NS}
    root = tree.getroot()
    scopes = (
        [root]
        if local_name(root.tag) == ident.scope
        else list(root.iter(f"{{{QIF_NS}}}{ident.scope}"))
    )
    lines: list[int] = []
    for scope in scopes:
        try:
            selected = scope.xpath(ident.selector, namespaces=ns)
        except etree.XPathError:
            return []
        for node in selected:
            if not isinstance(node, etree._Element):
                continue
            got = [_field_values(node, f, ns) for f in ident.fields]
            if len(got) != len(values) or any(len(g) != 1 for g in got):
                continue
            if tuple(g[0][0] for g in got) == values:
                lines.append(got[-1][0][1] or node.sourceline or 0)
    return sorted(set(lines))


def keys_selecting(
    tree: etree._ElementTree, idents: dict[str, IdentityConstraint], elem: Any, fld: str
) -> list[str]:
    """Names of the keys with field ``fld`` whose selector selects ``elem``.

    Parameters
    ----------
    tree : lxml.etree._ElementTree
        The QIF document.
    idents : dict of str to IdentityConstraint
        The schema's constraints (:func:`identity_constraints`).
    elem : lxml.etree._Element or None
        An element of ``tree``.
    fld : str
        A field XPath as written in the XSD.

    Returns
    -------
    list of str
    """
    if elem is None:
        return []
    root = tree.getroot()
    names = []
    for ident in idents.values():
        if ident.kind != "key" or fld not in ident.fields:
            continue
        ns = dict(ident.nsmap) or {"t": QIF_NS}
        scopes = (
            [root]
            if local_name(root.tag) == ident.scope
            else list(root.iter(f"{{{QIF_NS}}}{ident.scope}"))
        )
        try:
            if any(elem in scope.xpath(ident.selector, namespaces=ns) for scope in scopes):
                names.append(ident.name)
        except etree.XPathError:
            continue
    return names
