"""The batch's features, characteristics and measurements as a QIF 3.0 statistics document
(:mod:`qifreport.qif.statistics`) holds them: per designator a feature and its
characteristic (a surface profile's definition from its results read back, a feature
characteristic's copied from its results document, :class:`Definitions`), per inspection
its measurements copied (:class:`Runs`), with the statuses, times and numbers as the schema
writes them.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass, field
from datetime import datetime
from urllib.parse import quote

import numpy as np
from lxml import etree

from qifreport.metrology.gdt.characteristic_types import CharacteristicResult

from .batch_summary import (
    Observation,
    characteristic_description,
    designator_of,
    from_results,
    qif_type_of,
    statistics_rule,
)
from .composite import segment_elements
from .definitions import Sections, feature_definition
from .reader import QIFResults
from .xmlkit import NS, Attrs, E, Ids, id_array, token, xml_time

__all__ = [
    "CHARACTERISTIC_STATUSES",
    "INSPECTION_STATUSES",
    "Definitions",
    "Runs",
    "characteristic_status",
    "decimal_text",
    "feature_copies",
    "inspection_status",
    "parse_time",
    "source_uri",
    "worst_deviations",
]

log = logging.getLogger("qifreport.statistics")

#: ``CharacteristicStatusEnumType`` values (anything else is an ``OtherCharacteristicStatus``)
CHARACTERISTIC_STATUSES = frozenset(
    {
        "PASS",
        "FAIL",
        "REWORK",
        "SYSERROR",
        "INDETERMINATE",
        "NOT_ANALYZED",
        "BASIC_OR_TED",
        "UNDEFINED",
    }
)
#: ``InspectionStatusEnumType`` values (anything else is an ``OtherInspectionStatus``)
INSPECTION_STATUSES = frozenset(
    {"PASS", "FAIL", "REWORK", "SYSERROR", "UNKNOWN", "NOT_CALCULATED", "NOT_MEASURED", "UNDEFINED"}
)
_Q = f"{{{NS}}}"


def worst_deviations(kind: str) -> bool:
    """Whether QIF type ``kind``'s worst deviations are copied and summarised (a profile's)."""
    rule = statistics_rule(kind)
    return rule is not None and rule.worst_deviations


def decimal_text(x: float) -> str:
    """The shortest ``xs:decimal`` literal that reads back as the double ``x``."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"not a finite number: {x}")
    if x == 0.0:
        return "0"
    return np.format_float_positional(x, unique=True, trim="-")


def characteristic_status(text: str | None) -> etree._Element:
    """``Status`` of a characteristic measurement (``UNDEFINED`` when unknown)."""
    text = text or "UNDEFINED"
    if text in CHARACTERISTIC_STATUSES:
        return E.Status(E.CharacteristicStatusEnum(text))
    return E.Status(E.OtherCharacteristicStatus(text))


def inspection_status(tag: str, text: str | None) -> etree._Element:
    """An ``InspectionStatusType`` element (``UNKNOWN`` when unknown)."""
    text = text or "UNKNOWN"
    if text in INSPECTION_STATUSES:
        return E(tag, E.InspectionStatusEnum(text))
    return E(tag, E.OtherInspectionStatus(text))


def parse_time(text: str | None) -> datetime | None:
    """A timezone-aware time from an ``xs:dateTime`` text; None if absent, unreadable or
    without a timezone (it could not be ordered against the others)."""
    if not text:
        return None
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError:
        log.warning("inspection time %r is not an ISO date-time: left out", text)
        return None
    return t if t.tzinfo is not None else None


def source_uri(source: str) -> str:
    """A relative URI reference for a file name or relative path (``/`` separators)."""
    return quote(source.replace("\\", "/"), safe="/")


def feature_copies(
    key: str, obs: list[Observation], cd: str, cn: str, fn: str
) -> tuple[etree._Element, etree._Element]:
    """Copies of a feature characteristic's definition and nominal from its first results
    document, with the ids ``cd`` and ``cn``: the nominal refers to the definition ``cd`` and
    the feature nominal ``fn``; the definition without its ``DatumReferenceFrameId`` (this
    document has no datums) or a composite's lower segments (not carried), and with the
    first clause of its description (the rest says how that one scan was read)."""
    src = obs[0].source
    assert src.definition is not None and src.nominal is not None
    cdef, cnom = copy.deepcopy(src.definition), copy.deepcopy(src.nominal)
    cdef.set("id", cd)
    for drf in cdef.findall(f"{_Q}DatumReferenceFrameId"):
        cdef.remove(drf)
    for _, segment in segment_elements(cdef, "Definition"):
        cdef.remove(segment)  # a composite's lower segments are not carried
    desc = cdef.find(f"{_Q}Description")
    if desc is not None and desc.text:
        desc.text = characteristic_description(obs[0].char) or desc.text
    cnom.set("id", cn)
    ref = cnom.find(f"{_Q}CharacteristicDefinitionId")
    ref.text = cd
    for old in cnom.findall(f"{_Q}FeatureNominalIds"):
        old.addnext(id_array("FeatureNominalIds", [fn]))
        cnom.remove(old)
    log.debug("%s: definition and nominal copied from %s", key, obs[0].char.document.id)
    return cdef, cnom


@dataclass
class Definitions:
    """The features and characteristics of the document (``sections``, laid out as a results
    document's): per designator, one ``OtherSurfaceFeature`` definition, nominal and item,
    its characteristic's definition, nominal and item (``item_ids``: the characteristic
    item's id by designator)."""

    sections: Sections = field(default_factory=Sections)
    item_ids: dict[str, str] = field(default_factory=dict)

    def add(self, key: str, obs: list[Observation], ids: Ids) -> None:
        """The feature and characteristic of designator ``key``."""
        c = obs[0].char
        profile = from_results(qif_type_of(c))
        zs = self.sections
        fname = token(f"SURFACE_{key}".upper() if profile else f"FEATURE_{key}")
        fn, fi, _ = feature_definition(zs, fname, Attrs(), ids)
        cd, cn, ci = ids(), ids(), ids()
        self.item_ids[key] = ci
        name = token(c.spec.name or key)
        if profile:
            cdef_el, cnom_el = _profile_definition(obs, name, cd, cn, fn)
        else:
            cdef_el, cnom_el = feature_copies(key, obs, cd, cn, fn)
        zs.cdefs.append(cdef_el)
        zs.cnoms.append(cnom_el)
        zs.citems.append(
            E(
                f"{qif_type_of(c)}CharacteristicItem",
                E.Name(name),
                E.CharacteristicDesignator(E.Designator(token(key))),
                id_array("FeatureItemIds", [fi]),
                E.CharacteristicNominalId(cn),
                id=ci,
            )
        )


def _profile_definition(
    obs: list[Observation], name: str, cd: str, cn: str, fn: str
) -> tuple[etree._Element, etree._Element]:
    """A surface profile's characteristic definition and nominal, from its results read
    back (description, tolerance, unequal disposition)."""
    c = obs[0].char
    description = next(
        (o.char.document.description for o in obs if o.char.document.description), None
    )
    cdef = [E.Description(description)] if description else []
    cdef += [E.Name(name), E.ToleranceValue(decimal_text(c.spec.tolerance))]
    if c.document.unequally_disposed is not None:
        cdef.append(E.UnequallyDisposedZone(decimal_text(c.document.unequally_disposed)))
    nominal = E.SurfaceProfileCharacteristicNominal(
        E.CharacteristicDefinitionId(cd),
        id_array("FeatureNominalIds", [fn]),
        E.Name(name),
        id=cn,
    )
    return E.SurfaceProfileCharacteristicDefinition(*cdef, id=cd), nominal


@dataclass
class Runs:
    """The batch's measurements, copied: one ``MeasurementResults`` per inspection
    (``mrs``, ids ``mr_ids``) and its ``ActualComponent``; ``carried``: the (inspection,
    source measurement id) of the measurements to copy; ``meas_id``: the copied
    measurement's id by (inspection, source measurement id)."""

    carried: set[tuple[int, str]]
    mrs: list[etree._Element] = field(default_factory=list)
    mr_ids: list[str] = field(default_factory=list)
    actuals: list[etree._Element] = field(default_factory=list)
    meas_id: dict[tuple[int, str], str] = field(default_factory=dict)

    def add(
        self,
        k: int,
        res: QIFResults,
        item_ids: dict[str, str],
        sources: list[str] | None,
        path_id: str,
        ids: Ids,
    ) -> None:
        """Inspection ``k``'s results ``res``: its carried measurements copied."""
        actual_id, mr_id = ids(), ids()
        self.mr_ids.append(mr_id)
        meas = []
        for c in res.characteristics:
            if (k, c.document.id) not in self.carried:
                continue
            m = self.meas_id[(k, c.document.id)] = ids()
            meas.append(_copied_measurement(c, m, item_ids[designator_of(c)], actual_id))
        mr = _traceability(res)
        if sources is not None:
            mr.append(_source_reference(res, sources[k]))
        if meas:
            mr.append(
                E.MeasuredCharacteristics(E.CharacteristicMeasurements(*meas, n=str(len(meas))))
            )
        mr += [
            inspection_status("InspectionStatus", res.status),
            id_array("ActualComponentIds", [actual_id]),
        ]
        self.mrs.append(E.MeasurementResults(*mr, id=mr_id))
        serial = [E.SerialNumber(res.serial_number)] if res.serial_number else []
        self.actuals.append(
            E.ActualComponent(
                *serial,
                inspection_status("Status", res.status),
                E.AsmPathId(path_id),
                id=actual_id,
            )
        )


def _copied_measurement(
    c: CharacteristicResult, m: str, item_id: str, actual_id: str
) -> etree._Element:
    """A characteristic measurement copied with id ``m`` (status as written, value, a
    profile's worst deviations; its source id as an attribute)."""
    el = [
        Attrs().s("source_id", c.document.id).element(),
        characteristic_status(c.document.status),
        E.CharacteristicItemId(item_id),
        E.ActualComponentId(actual_id),
    ]
    copied = [("Value", c.value)]
    if worst_deviations(qif_type_of(c)):
        copied += [
            ("WorstPositiveDeviation", c.worst_positive),
            ("WorstNegativeDeviation", c.worst_negative),
        ]
    for tag, x in copied:
        if x is not None and math.isfinite(x):
            el.append(E(tag, decimal_text(x)))
    return E(f"{qif_type_of(c)}CharacteristicMeasurement", *el, id=m)


def _traceability(res: QIFResults) -> list[etree._Element]:
    """An inspection's ``InspectionTraceability`` (its start and end), if it has times."""
    times = [
        (tag, parse_time(t))
        for tag, t in (
            ("InspectionStart", res.inspection_start),
            ("InspectionEnd", res.inspection_end),
        )
    ]
    trace = [E(tag, xml_time(t)) for tag, t in times if t is not None]
    return [E.InspectionTraceability(*trace)] if trace else []


def _source_reference(res: QIFResults, source: str) -> etree._Element:
    """``ExternalFileReferences``: the results document the measurements are copied from."""
    return E.ExternalFileReferences(
        E.ExternalFileReference(
            E.URI(source_uri(source)),
            E.FileSpec(E.OtherFileSpec("QIF")),
            E.Description(
                f"the QIF results document (QPId {res.qpid}) these results are copied from"
            ),
        ),
        n="1",
    )
