"""A toleranced surface's two characteristics in a results document, as
:class:`~qifreport.metrology.gdt.characteristic_types.CharacteristicResult` (the type the
drawing's feature characteristics have, and the one :func:`qifreport.qif.reader.read_results`
reads back): its profile (:func:`profile_characteristic`, a ``SurfaceProfile``
characteristic) and its acceptance under qifreport's rule (:func:`acceptance_characteristic`,
a ``UserDefinedAttribute`` characteristic ``<key>_ACCEPTANCE``). :func:`written_characteristics`
lists every characteristic of an inspection in the order the writer writes them.

The profile's value is the QIF profile value (:func:`profile_value`), its status the
profile read as the drawing states it (:func:`strict_profile_status`); the acceptance's status
is the inspection's decision for the surface (:func:`characteristic_status`). These two give
QIF's ``CharacteristicStatusEnum``; the results hold it mapped
(:func:`qifreport.qif.feature_characteristics.status_from_qif`). See
:mod:`qifreport.qif.writer` for why a surface has both.
"""

from __future__ import annotations

import math

import numpy as np

from qifreport.metrology.acceptance.bands import ToleranceZone
from qifreport.metrology.gdt.characteristic_types import (
    OTHER_KIND,
    CharacteristicResult,
    CharacteristicSpec,
)
from qifreport.metrology.inspection import InspectionResult, ZoneResult

from .feature_characteristics import status_from_qif

__all__ = [
    "NOT_WITHIN_PROFILE",
    "acceptance_characteristic",
    "acceptance_key",
    "characteristic_status",
    "profile_characteristic",
    "profile_value",
    "strict_profile_status",
    "worst_deviations",
    "written_characteristics",
    "zone_spec",
]

#: a failing profile's non-conformance
NOT_WITHIN_PROFILE = "profile value beyond the tolerance"


def worst_deviations(z: ZoneResult) -> tuple[float, float]:
    """The signed extremes (mm) of a surface's deviation: its scored vertices' and the
    peaks of its out-of-tolerance regions (a region found on the scan points, narrower
    than the mesh, peaks beyond every vertex); NaN when nothing was scored."""
    s = z.stats
    if s.n == 0 or not math.isfinite(s.max_pos):
        return math.nan, math.nan
    peaks = [r.peak for r in z.acceptance.regions if math.isfinite(r.peak)]
    return max([s.max_pos, *peaks]), min([s.min_neg, *peaks])


def profile_value(z: ZoneResult) -> float:
    """QIF profile value of a surface: ``2 max |d - c|`` over its scored points and its
    regions' peaks (:func:`worst_deviations`), mm; NaN if nothing was scored."""
    hi, lo = worst_deviations(z)
    if not math.isfinite(hi):
        return math.nan
    c = z.zone.center
    return 2.0 * max(hi - c, c - lo)


def characteristic_status(z: ZoneResult, established: bool = True) -> str:
    """The ``CharacteristicStatusEnum`` of one tolerance's measurement.

    Parameters
    ----------
    z : ZoneResult
        The tolerance's result.
    established : bool
        Whether the registration is trusted (:attr:`InspectionResult.established`).

    Returns
    -------
    str
        ``NOT_ANALYZED`` (nothing scored, or too little of the surface to measure it:
        :attr:`ZoneResult.measured`; QIF's characteristic status has no "not measured"),
        ``FAIL``, ``PASS``, or ``INDETERMINATE`` (would pass, the registration is not trusted;
        or neither conformance nor non-conformance is proven within the measurement
        uncertainty, :mod:`qifreport.metrology.acceptance.decision`).
    """
    if z.acceptance.scored_area <= 0 or z.stats.n == 0:
        return "NOT_ANALYZED"
    if z.failed:
        return "FAIL"
    if not z.measured:
        return "NOT_ANALYZED"
    return "PASS" if established and not z.uncertain else "INDETERMINATE"


def strict_profile_status(z: ZoneResult, established: bool = True) -> str:
    """The ``CharacteristicStatusEnum`` of a profile read as the drawing states it: every
    scored point within the zone. ``FAIL`` when the profile value exceeds the tolerance
    (whatever the area and region rule says) unless it does so only within the measurement
    uncertainty (``INDETERMINATE``: the decision rule proved neither), ``NOT_ANALYZED`` as
    :func:`characteristic_status`, ``INDETERMINATE`` when the value is within it but the
    registration is not trusted or a point lies within the uncertainty of the limit, else
    ``PASS``. So a ``Value`` beyond its ``ToleranceValue`` is never ``PASS``."""
    if z.acceptance.scored_area <= 0 or z.stats.n == 0:
        return "NOT_ANALYZED"
    pv = profile_value(z)
    if z.failed:
        return "FAIL"
    if math.isfinite(pv) and pv > z.zone.width + 1e-12:
        # beyond the tolerance; within the measurement uncertainty of it when the decision
        # rule could not prove the surface out (a face on its zone limit)
        return "INDETERMINATE" if z.uncertain else "FAIL"
    if not z.measured:
        return "NOT_ANALYZED"
    return "PASS" if established and not z.uncertain else "INDETERMINATE"


def zone_spec(zone: ToleranceZone) -> CharacteristicSpec:
    """The spec of a toleranced surface's profile: its key, kind, name, tolerance (the zone
    width, mm), datums, modifiers and faces (``[]`` for the general zone)."""
    return CharacteristicSpec(
        key=zone.key,
        kind=zone.kind,
        name=zone.name,
        step_id=zone.step_id,
        faces=zone.faces if zone.faces is not None else np.zeros(0, dtype=np.int64),
        tolerance=zone.width,
        datums=list(zone.datums),
        modifiers=list(zone.modifiers),
        datum_materials=list(zone.datum_materials),
        composite=zone.composite,
    )


def profile_characteristic(z: ZoneResult, established: bool = True) -> CharacteristicResult:
    """A toleranced surface's profile: the profile value and worst deviations (None when
    nothing was scored), its strict status (:func:`strict_profile_status`), reading,
    scored vertices, coverage of the nominal area, statistics and acceptance."""
    status = status_from_qif(strict_profile_status(z, established))
    pv = profile_value(z)
    hi, lo = worst_deviations(z)
    scored = math.isfinite(pv)
    return CharacteristicResult(
        zone_spec(z.zone),
        value=pv if scored else None,
        status=status,
        reason=NOT_WITHIN_PROFILE if status == "FAIL" else "",
        reading=z.reading,
        n_points=z.stats.n,
        coverage=z.acceptance.coverage,
        worst_positive=hi if scored else None,
        worst_negative=lo if scored else None,
        stats=z.stats,
        acceptance=z.acceptance,
    )


def acceptance_key(zone: ToleranceZone) -> str:
    """The designator (and name) of a surface's acceptance characteristic."""
    return f"{zone.key}_ACCEPTANCE"


def acceptance_characteristic(z: ZoneResult, established: bool = True) -> CharacteristicResult:
    """A toleranced surface's acceptance under qifreport's rule: no value (QIF's is
    ``CONFORMS`` or ``DOES_NOT_CONFORM``), the decision's status
    (:func:`characteristic_status`) and, when it failed, its reasons."""
    key = acceptance_key(z.zone)
    reason = ("; ".join(z.acceptance.reasons) or "not conforming") if z.failed else ""
    return CharacteristicResult(
        CharacteristicSpec(
            key=key, kind=OTHER_KIND, name=key, step_id=None, faces=np.zeros(0, dtype=np.int64)
        ),
        status=status_from_qif(characteristic_status(z, established)),
        reason=reason,
    )


def written_characteristics(res: InspectionResult) -> list[CharacteristicResult]:
    """Every characteristic of the inspection ``res`` in the results document's order: per
    toleranced surface its profile and its acceptance, then the drawing's feature
    characteristics."""
    out = []
    for z in res.zones:
        out += [
            profile_characteristic(z, res.established),
            acceptance_characteristic(z, res.established),
        ]
    return out + list(res.characteristics)
