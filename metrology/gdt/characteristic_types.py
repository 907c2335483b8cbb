"""A characteristic to measure (:class:`CharacteristicSpec`), its result
(:class:`CharacteristicResult`) and what every measurement of one shares: the judgement of a
value against its limits, the expanded uncertainty of a zone width or a fitted parameter,
the reading's text.

:class:`CharacteristicResult` is the one type of a characteristic's result: the
measurements made here (feature characteristics, a toleranced surface's profile), what the
QIF writer writes, and what the QIF reader reads back from a results document (ours or
another application's), the document's own identifiers and text then in its
:class:`DocumentRecord`.

Statuses (:data:`STATUSES`): ``PASS``, ``FAIL``, ``INDETERMINATE``, ``NOT_MEASURED``,
``BASIC`` (a basic or reference dimension, reported without limits), and ``OTHER`` for a
status read from a document that none of these is (QIF's ``REWORK``, ``SYSERROR``,
``UNDEFINED`` or another application's own; its text kept in
:attr:`DocumentRecord.status`). Documents' vocabularies are mapped at their boundary
(:mod:`qifreport.qif.feature_characteristics`).

Lengths mm, angles degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from qifreport.metrology.acceptance.budget import UncertaintyBudget
from qifreport.metrology.acceptance.criteria import Acceptance
from qifreport.metrology.acceptance.decision import decide
from qifreport.metrology.acceptance.statistics import DeviationStats
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.gdt.measured_surface import FeatureSample

__all__ = [
    "OTHER_KIND",
    "STATUSES",
    "CharacteristicResult",
    "CharacteristicSpec",
    "DocumentRecord",
    "Unmeasurable",
    "faces_text",
    "fit_uncertainty",
    "judge",
    "undecided_reason",
    "implausible",
    "not_measured",
    "reading_text",
    "zone_uncertainty",
]

#: the statuses of a characteristic result (see the module docstring)
STATUSES = ("PASS", "FAIL", "INDETERMINATE", "NOT_MEASURED", "BASIC", "OTHER")
#: the kind of a characteristic that is neither a registered kind nor a dimension: one read
#: from a document whose type no kind has (a QIF ``UserDefinedAttribute``, another
#: application's type; the type is :attr:`DocumentRecord.type`)
OTHER_KIND = "other"


@dataclass
class CharacteristicSpec:
    """One PMI item to measure.

    Attributes
    ----------
    key : ``'G<k>'`` (geometric tolerance) or ``'D<k>'`` (dimension), file order; a
        toleranced surface's zone key (``'T1'``, ``'general'``); read from a document, its
        designator (``''``: none).
    kind : the tolerance kind (:data:`qifreport.kinds.KINDS`), ``'dimension'`` or
        :data:`OTHER_KIND`.
    name, step_id : the PMI item's name and STEP entity.
    faces : (k,) mesh face ids of the feature (a location's both ends).
    tolerance : zone width, mm (geometric).
    dim_type : the dimension's type (``'diameter'``, ``'linear distance'`` ...).
    nominal, lower_limit, upper_limit : a dimension's nominal and limits (mm or deg).
    unit : ``'mm'`` or ``'deg'``.
    datums : the frame's labels in precedence (``[]``: none).
    modifiers, zone_form : as read.  basic : a basic or reference dimension.
    origin_faces, target_faces : a location's two features.
    problems : why it cannot be measured (found when reading).
    datum_materials : each datum reference's material boundary as drawn (``'MAXIMUM'``,
        ``'LEAST'``, ``'NONE'``; same order as ``datums``).
    unit_basis : a per-unit tolerance's unit as read (``'per unit length 25 mm'``,
        ``'per rectangular area 6.35 mm x 6.35 mm'``), None for a whole-feature tolerance.
    composite : ``'upper'`` or ``'lower'`` segment of a composite feature control frame
        (:func:`qifreport.metrology.acceptance.bands.composite_segment`), ``''`` for none.
    composite_of : a lower segment's upper segment, by STEP entity id; None for any other.
    thread : the supplemental geometry a dimension of a thread is given on (``"'Thread
        Cylinder.1'"``: a cosmetic thread, its model a tap-drill hole), ``''`` for none.
    drawn : a location dimension between curves drawn on faces (supplemental geometry,
        e.g. construction lines), not between the faces.
    max_value : the zone's maximum (a MAX tolerance, ``1.016 (M) MAX 1.143``), mm: a
        material bonus never widens the zone beyond it; None: none stated.
    """

    key: str
    kind: str
    name: str
    step_id: int | None
    faces: np.ndarray
    tolerance: float | None = None
    dim_type: str = ""
    nominal: float | None = None
    lower_limit: float | None = None
    upper_limit: float | None = None
    unit: str = "mm"
    datums: list[str] = field(default_factory=list)
    modifiers: list[str] = field(default_factory=list)
    zone_form: str | None = None
    basic: bool = False
    origin_faces: np.ndarray | None = None
    target_faces: np.ndarray | None = None
    problems: list[str] = field(default_factory=list)
    datum_materials: list[str] = field(default_factory=list)
    unit_basis: str | None = None
    composite: str = ""
    composite_of: int | None = None
    thread: str = ""
    drawn: bool = False
    max_value: float | None = None

    @property
    def free_state(self) -> bool:
        return "free_state" in self.modifiers

    def limits_text(self) -> str:
        if self.kind != "dimension":
            return f"{self.tolerance:g} mm" if self.tolerance is not None else "?"
        lo, hi = self.lower_limit, self.upper_limit
        if lo is None and hi is None:
            return "basic" if self.basic else "no limits"
        return f"{_fmt(lo)} .. {_fmt(hi)} {self.unit}"


@dataclass
class DocumentRecord:
    """What a characteristic read from a results document carries besides its result: the
    document's identifiers and text, as written (a copy of it, e.g. a statistics document,
    repeats them). A characteristic measured here has none.

    Attributes
    ----------
    type : the document's characteristic type (QIF: the stem of ``<type>Characteristic
        Measurement``, ``"SurfaceProfile"``, ``"Diameter"``, ``"UserDefinedAttribute"``, or
        another application's).
    id : the measurement's id in the document.
    status : the status as written (QIF: ``CharacteristicStatusEnum`` or the other-status
        text; None: none), which :attr:`CharacteristicResult.status` maps.
    description : the definition's description, None when absent.
    unequally_disposed : the zone's part outside the material (QIF
        ``UnequallyDisposedZone``), mm; None when absent.
    attributes : the measurement's typed attributes, name -> value.
    """

    type: str
    id: str | None
    status: str | None = None
    description: str | None = None
    unequally_disposed: float | None = None
    attributes: dict = field(default_factory=dict)


@dataclass
class CharacteristicResult:
    """One characteristic's result: measured here, or read from a results document.

    Attributes
    ----------
    spec : what was measured.
    value : the measured value (mm or deg; a tolerance's zone width or profile value, a
        dimension's size), None when not measured.
    least_squares : the least-squares reading beside a minimum zone (form), else None.
    uncertainty : expanded uncertainty of ``value`` (k = 2).
    status : one of :data:`STATUSES`.
    reason : why not measured, or how it failed.
    reading : how it was measured (``'minimum zone, 1,204 vertices, frame |A|B|C|'`` ...).
    n_points : points used.  coverage : share of the feature's vertices measured (a
        toleranced surface's: of its nominal area scored).
    bonus : MMC/LMC bonus added to the tolerance, mm.
    direction : (3,) the feature's nominal normal or axis where a report needs it (a line
        profile's QIF ``Vector``), else None.
    worst_positive, worst_negative : a profile's signed extremes of the deviation, mm
        (None: not a toleranced surface's, or not scored).
    stats, acceptance : a toleranced surface's deviation statistics and acceptance (read
        back: their regions without vertex lists), else None.
    document : what the results document it was read from says besides (None: measured
        here).
    budget : the uncertainty's budget (its terms; ``uncertainty`` is its expanded total),
        None when not made (:mod:`qifreport.metrology.gdt.budgets`).
    """

    spec: CharacteristicSpec
    value: float | None = None
    least_squares: float | None = None
    uncertainty: float | None = None
    status: str = "NOT_MEASURED"
    reason: str = ""
    reading: str = ""
    n_points: int = 0
    coverage: float | None = None
    bonus: float = 0.0
    direction: np.ndarray | None = None
    worst_positive: float | None = None
    worst_negative: float | None = None
    stats: DeviationStats | None = None
    acceptance: Acceptance | None = None
    document: DocumentRecord | None = None
    budget: UncertaintyBudget | None = None

    @property
    def limit(self) -> float | None:
        """The upper limit the value is judged against (tolerance + bonus), mm."""
        if self.spec.kind == "dimension":
            return self.spec.upper_limit
        return None if self.spec.tolerance is None else self.spec.tolerance + self.bonus

    def to_dict(self) -> dict:
        s = self.spec
        return {
            "key": s.key,
            "kind": s.kind if s.kind != "dimension" else f"dimension ({s.dim_type})",
            "name": s.name,
            "step_id": s.step_id,
            "faces": [int(f) for f in s.faces],
            "datums": list(s.datums),
            "datum_materials": list(s.datum_materials) or ["NONE"] * len(s.datums),
            "modifiers": list(s.modifiers),
            "composite": s.composite,
            "tolerance_mm": s.tolerance,
            "nominal": s.nominal,
            "lower_limit": s.lower_limit,
            "upper_limit": s.upper_limit,
            "unit": s.unit,
            "value": _num(self.value),
            "least_squares": _num(self.least_squares),
            "uncertainty": _num(self.uncertainty),
            "bonus_mm": self.bonus,
            "status": self.status,
            "reason": self.reason,
            "reading": self.reading,
            "n_points": self.n_points,
            "coverage": _num(self.coverage),
            "uncertainty_budget": None if self.budget is None else self.budget.to_dict(),
        }


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:g}"


def not_measured(spec: CharacteristicSpec, reason: str) -> CharacteristicResult:
    """``spec`` not measured, ``reason`` saying why."""
    return CharacteristicResult(spec, status="NOT_MEASURED", reason=reason)


def faces_text(faces) -> str:
    """Face ids as a reading names them (``"12 13"``)."""
    return " ".join(str(int(f)) for f in faces)


class Unmeasurable(ValueError):
    """The characteristic cannot be measured on this feature (the message says why)."""


def reading_text(how: str, sample: FeatureSample, frame: DatumFrameResult | None) -> str:
    """How a feature was read: ``how``, its points, the frame (and what it leaves free)."""
    text = f"{how}; {len(sample.S)} {sample.source}"
    if frame is not None:
        text += f"; in |{'|'.join(frame.labels)}|"
        if frame.free:
            text += " (best fit: " + ", ".join(frame.free) + ")"
    return text


def implausible(res: CharacteristicResult, diagonal: float) -> str | None:
    """Why ``res``'s reading cannot be a measurement of a part ``diagonal`` mm across
    (``MeasuredSurface.diagonal``), or None when it can: ``'implausible reading: ...'``,
    naming the number and the bound.

    A reading is physically implausible when its value or expanded uncertainty is not
    finite; when a length (mm) is farther from its nominal (0 for a zone width) than the
    part's diagonal, or its uncertainty is wider than the diagonal (no deviation of a
    feature of the part is larger than the part); when a size dimension with a positive
    nominal reads ``<= 0``; when an angle (deg) is outside 0..180 or its uncertainty wider
    than 180. Such a number is a failed fit or a lost registration, not the part.
    """
    why = _implausible(res, diagonal)
    return None if why is None else f"implausible reading: {why}"


def _implausible(res: CharacteristicResult, diagonal: float) -> str | None:
    s, v, U = res.spec, res.value, res.uncertainty
    what = s.dim_type or s.kind
    if v is None or not math.isfinite(v) or (U is not None and not math.isfinite(U)):
        return f"{what} {_fmt(v)} {s.unit}, uncertainty {_fmt(U)}: not a finite number"
    if s.unit == "deg":
        if not 0.0 <= v <= 180.0 or (U is not None and U > 180.0):
            return f"{what} {v:.7g} deg (U {_fmt(U)} deg) outside an angle's 0..180 deg"
        return None
    bound = f"the part's {diagonal:.4g} mm diagonal"
    if s.nominal is not None and s.nominal > 0.0 and v <= 0.0:
        return f"{what} {v:.7g} mm, not a size (nominal {s.nominal:g} mm)"
    if s.nominal and abs(v - s.nominal) > diagonal:
        return f"{what} {v:.7g} mm is farther from its nominal {s.nominal:g} mm than {bound}"
    if not s.nominal and abs(v) > diagonal:
        return f"{what} {v:.7g} mm exceeds {bound}"
    if U is not None and U > diagonal:
        return f"{what} uncertainty U {U:.7g} mm exceeds {bound}"
    return None


def judge(
    res: CharacteristicResult, rule: str, lo: float | None, hi: float | None, diagonal: float
) -> None:
    """Set ``res.status`` from its value, uncertainty and limits ``[lo, hi]`` (None: open).

    A physically implausible reading (:func:`implausible`, ``diagonal`` the part's size,
    mm) is not judged: ``NOT_MEASURED``, the reason naming the number and the bound, never
    ``PASS``, ``FAIL`` or ``INDETERMINATE``.
    """
    why = implausible(res, diagonal)
    if why is not None:
        res.status, res.reason = "NOT_MEASURED", why
        return
    v, U = res.value, res.uncertainty or 0.0
    lo_ = -math.inf if lo is None else lo
    hi_ = math.inf if hi is None else hi
    passed = lo_ <= v <= hi_
    proven_in = lo_ + U <= v <= hi_ - U
    proven_out = v < lo_ - U or v > hi_ + U
    status = decide(rule, passed, proven_in, proven_out)
    res.status = "INDETERMINATE" if status == "UNCERTAIN" else status
    if res.status == "FAIL":
        if lo is None:
            res.reason = f"{v:.4g} > {hi:g}"
        elif hi is None or v < lo:
            res.reason = f"{v:.4g} < {lo:g}" if v < lo else f"{v:.4g} > {hi:g}"
        else:
            res.reason = f"{v:.4g} > {hi:g}"
    elif res.status == "INDETERMINATE":
        res.reason = undecided_reason(v, U, lo, hi)


def undecided_reason(v: float, U: float, lo: float | None, hi: float | None) -> str:
    """Why a value ``v`` with expanded uncertainty ``U`` is neither proven within its
    limits ``[lo, hi]`` (None: open) nor out of them (ISO 14253-1): the limit it lies
    within ``U`` of, and, when the zone left after ``U`` is taken off is empty, that no
    reading could prove conformance (a tolerance of zero or more: only its upper limit
    bounds it, ``2 U`` of a two-sided zone)."""
    near = [x for x in (lo, hi) if x is not None and abs(v - x) <= U]
    limit = min(near, key=lambda x: abs(v - x)) if near else (hi if lo is None else lo)
    why = f"{v:.7g} within its uncertainty U {U:.2g} of the limit {limit:g}"
    if lo is not None and hi is not None:
        unprovable = 2.0 * U >= hi - lo
    else:
        unprovable = lo is None and hi is not None and U >= hi
    if unprovable:
        why += " (U too wide for the zone: no reading could prove conformance)"
    return why + ": conformance neither proven nor disproven (ISO 14253-1)"


def zone_uncertainty(residuals: np.ndarray, U: np.ndarray) -> float:
    """Expanded uncertainty (mm) of a zone width: its two extremes' in quadrature.

    ``residuals`` (m,) mm: the points' signed distances from the fitted feature; ``U`` (m,)
    mm: each point's expanded uncertainty (k = 2).

    Each extreme's U is that of the points near it, weighted by how near: ``w = 1 - d / h``
    for a point ``d`` below the extreme (mm), ``h`` the median U, none beyond ``h``. A
    point that stands out by more than ``h`` gives its own U, as before. Where several points
    nearly tie, which one is the extreme is itself within the measurement's uncertainty, and
    the zone's U is their weighted U: a continuous function of the residuals. (The extreme
    point's U alone jumped by a third when round-off, a 1e-13 mm change of the fit, picked
    the other of two tied points of the sample panel's flatness G2.)
    """
    r = np.asarray(residuals, dtype=np.float64)
    U = np.asarray(U, dtype=np.float64)
    h = float(np.median(U))
    if not h > 0.0:
        return float(np.hypot(U[np.argmax(r)], U[np.argmin(r)]))

    def side(d: np.ndarray) -> float:
        w = np.clip(1.0 - d / h, 0.0, None)
        return float(w @ U / w.sum())

    return float(np.hypot(side(r.max() - r), side(r - r.min())))


def fit_uncertainty(U: np.ndarray, n_params: int = 1) -> float:
    """Expanded uncertainty of a fitted parameter from ``len(U)`` values; neighbouring
    vertices share scan points, so a quarter of them count as independent."""
    n_eff = max(len(U) / 4.0, float(n_params))
    return float(np.median(U)) / math.sqrt(n_eff)
