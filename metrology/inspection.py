"""One inspection, end to end on arrays: rigid alignment, virtual fixturing, deviation, verdict.

This is the library entry point the CLI (and later the QIF writer) calls. It takes the
nominal ``(V, F)`` and the scan ``P`` in mm, and returns an :class:`InspectionResult` with the
registered nominal, the signed deviation field, its statistics and the acceptance decision
of the paper's Section 10 (area criterion and region criterion).

Frames: the scan is moved into the nominal (CAD) frame once, by the rigid stage
(paper Section 3); everything reported (registered nominal, region centroids) is in the
nominal frame.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import points_to_barycentric

from qifreport.errors import InputError
from qifreport.registration.deformable import DeformResult, orient_scan_normals
from qifreport.registration.gbcicp import BendingBasis, bending_basis, part_solver
from qifreport.registration.icp import (
    RigidResult,
    rigid_icp,
    robust_scale,
)
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.mesh import (
    bounding_diagonal,
    vertex_normals,
)
from qifreport.registration.methods import METHODS, deform
from qifreport.registration.pointcloud import oriented_normals
from qifreport.registration.prealign import PrealignResult, seat_scan
from qifreport.registration.restrained import (
    Restraint,
    RestraintBasis,
)

from .acceptance import (
    DEFAULT_MAX_REGION_AREA,
    Acceptance,
    coverage_ceiling_ok,
    evaluate,
    scan_area,
)
from .added import AddedMaterial, added_material
from .bands import (
    DEFAULT_GENERAL_TOLERANCE,
    BandField,
    NotEvaluated,
    ToleranceZone,
    lay_bands,
    symmetric_zone,
    zone_vertex_areas,
)
from .characteristics import (
    CharacteristicPlan,
    CharacteristicResult,
    frame_of,
    measure_characteristics,
)
from .composite import composite_zone_frame
from .coverage import (
    DEFAULT_MIN_COVERAGE,
    GAP_AREA_FACTOR,
    Coverage,
    unseen_neighbour_edges,
    zone_coverage,
)
from .decision import vertex_uncertainty
from .deviation import (
    beyond_rim,
    closest_points,
    follow_triangles,
    nominal_referenced,
    point_faces,
    residual_referenced,
    surface_distance,
)
from .edges import EdgeDeviation, edge_deviation
from .frames import DatumFrameResult
from .held import hold_scan
from .hygiene import MeshHygiene
from .measured_surface import MeasuredSurface
from .params import METHOD_LABELS, InspectionParams, method_label
from .point_regions import ScanSamples, SurfacePoints, scan_samples
from .prepared import PreparedPart, prepare_part
from .repeatability import Repeatability
from .resolution import Resolution, range_noise, resolution
from .size import SizeEstimate, size_error
from .statistics import DeviationStats, deviation_statistics

#: :attr:`InspectionResult.fixture_decision` when the free state stands
FREE_STATE_CONFORMS = "free state conforms"
FREE_STATE_UNCERTAIN = "free state within the uncertainty"
FREE_STATE_LOCAL_DEFECTS = "free state fails on defects narrower than the mesh"
#: :attr:`InspectionResult.fixture_decision` of a restrained inspection
RESTRAINED = "restrained"

__all__ = [
    "FREE_STATE_CONFORMS",
    "FREE_STATE_LOCAL_DEFECTS",
    "FREE_STATE_UNCERTAIN",
    "METHOD_LABELS",
    "RESTRAINED",
    "InspectionParams",
    "InspectionResult",
    "ScanMeasures",
    "ZoneResult",
    "check_same_part",
    "check_units",
    "inspect",
    "method_label",
    "start_scan_measures",
]

log = logging.getLogger(__name__)

#: the area criterion's default share (InspectionParams.min_fraction)
DEFAULT_MIN_FRACTION = 0.95

#: scan-to-nominal extent ratios that betray a unit mix-up, and the unit behind each
_UNIT_FACTORS = {1 / 25.4: "in", 0.001: "m", 0.1: "cm", 25.4: "in", 1000.0: "m", 10.0: "cm"}


@dataclass
class ZoneResult:
    """The verdict of one toleranced surface, evaluated on its own faces with its own band.

    Attributes
    ----------
    zone : the tolerance zone.
    stats : area-weighted statistics of the deviation on the zone's faces (threshold: the
        zone's half-width about its centre is *not* applied here; ``frac_beyond`` uses the
        half-width about 0, exact for a bilateral zone).
    acceptance : area and region criteria on the zone's faces.
    fixtured : False when evaluated free-state (rigid alignment only).
    deviation : (n,) the deviation the zone was judged on, mm (the fixtured or free-state
        field on the zone's vertices, NaN elsewhere); None from older callers. Used by
        :mod:`qifreport.metrology.repeatability` to match regions between runs.
    coverage : whether the surface was measured (:mod:`qifreport.metrology.coverage`); None
        from older callers (taken as measured).
    reading : where the zone was laid: ``'best fit'`` (no datums: a form control), or in
        the datum reference frame the tolerance names (ASME Y14.5-2018 11.2.1:
        ``'datum frame |A|B|C|'``), or ``'best fit (datum frame not established: ...)'``.
    """

    zone: ToleranceZone
    stats: DeviationStats
    acceptance: Acceptance
    fixtured: bool = True
    deviation: np.ndarray | None = None
    coverage: Coverage | None = None
    reading: str = "best fit"

    @property
    def measured(self) -> bool:
        """Something of the surface was scored and the coverage and gap rules hold on it."""
        return self.acceptance.scored_area > 0 and (self.coverage is None or self.coverage.measured)

    @property
    def failed(self) -> bool:
        """A criterion fails on what was scored, under the decision rule (a surface the scan
        never saw fails none; :mod:`qifreport.metrology.decision`)."""
        return self.acceptance.scored_area > 0 and self.acceptance.decision == "FAIL"

    @property
    def uncertain(self) -> bool:
        """Neither conformance nor non-conformance is proven within the measurement
        uncertainty (the ``iso14253`` rule's third outcome)."""
        return self.acceptance.scored_area > 0 and self.acceptance.decision == "UNCERTAIN"

    @property
    def status(self) -> str:
        """``FAIL`` (a criterion fails on what was scored: rejected whatever was not seen),
        ``NOT MEASURED`` (too little of the surface scored to judge it, or none), ``NOT
        ESTABLISHED`` (on a zone limit within the measurement uncertainty), or ``PASS``."""
        if self.failed:
            return "FAIL"
        if not self.measured:
            return "NOT MEASURED"
        return "NOT ESTABLISHED" if self.uncertain else "PASS"

    def to_dict(self) -> dict:
        return {
            **self.zone.to_dict(),
            "description": self.zone.describe(),
            "verdict": self.status,
            "fixtured": self.fixtured,
            "reading": self.reading,
            "deviation": self.stats.to_dict(),
            "acceptance": self.acceptance.to_dict(),
            "measured": None if self.coverage is None else self.coverage.to_dict(),
        }


@dataclass
class InspectionResult:
    """Everything one inspection measured (arrays in the nominal frame, mm).

    Attributes
    ----------
    V, F : the nominal mesh.  V_registered : (n, 3) nominal after virtual fixturing.
    P : (m, 3) scan points moved into the nominal frame.
    deviation : (n,) signed nominal-referenced deviation per vertex, NaN where unscored.
    point_deviation : (m,) signed data-referenced deviation of every scan point (to the
        curved B-rep surface for a STEP nominal, :func:`surface_distance`; to the mesh else).
    vertex_stats : area-weighted statistics of ``deviation``.
    point_stats : statistics of ``point_deviation``.
    acceptance : area and region criteria on the whole part, each vertex under the tightest
        zone around it.
    zones : per toleranced surface results (the general zone last).
    not_evaluated : PMI items listed but not scored.
    bands : the zones laid on the mesh (per-vertex band of the combined map).
    rigid : the rigid alignment (pose of the scan as delivered -> nominal frame).
    fit : the virtual fixture's result (None with ``rigid_only``), from the method
        ``params.method`` (``fit.method``).
    prealign : how the rigid ICP was started
        (:class:`qifreport.registration.prealign.PrealignResult`; ``method == "identity"`` when the
        scan was already in the part frame).
    scan_area : estimated area covered by the scan, mm^2.
    coverage_ceiling_ok : coverage does not exceed scan area / nominal area (over-fit check).
    timings : seconds per stage.
    energy : the bending energy used.  edge_excluded_area : nominal area (mm^2) within the
        edge band of sharp creases, not scored.
    repeatability : the resampling study of ``qifreport --seeds`` (None without it): when
        set, ``acceptance`` and each zone's acceptance hold only the persistent regions
        (:func:`qifreport.metrology.repeatability.apply`).
    basis : the nominal's GB-CICP bending basis when one was used (per-part state: pass it
        to :func:`inspect` for further scans of the part).
    fixture_decision : why the part was judged as it was: ``"free state conforms"`` (the
        free state was judged first and conforms: no virtual fixture, ``fit`` is None),
        ``"free state within the uncertainty"`` (nothing of it is proven out of tolerance,
        something is on a zone limit within the measurement uncertainty: no fixture either),
        ``"free state does not conform"`` (it was judged first, then fixtured), ``"always"``
        (``always_fixture``: fixtured without judging the free state), ``"rigid only"`` or
        ``"restrained"`` (held at its clamps by its elastic model: :attr:`restraint`).
    free_state : the free state's verdict when it was judged first and did not conform
        (the fixtured verdict is :attr:`verdict`); None otherwise.
    free_state_decided_by : what the free state failed on (:meth:`decided_by` of its
        judgement), when it was judged first and did not conform.
    deviation_variance : (n,) the variance of each vertex's deviation, mm^2
        (:func:`vertex_deviation`), for the decision rule.
    solid : the nominal is a B-rep solid (its size check is reported, not a trust gate:
        every face's own deviation measures the size).
    characteristics : the drawing's feature tolerances and dimensions measured on the
        judged surface (:mod:`qifreport.metrology.characteristics`); a FAIL fails the part,
        an INDETERMINATE one leaves it NOT ESTABLISHED, one not measured is reported.
    frames : the datum reference frames established (profiles and characteristics).
    restraint : the restrained condition (``params.fixture == "restrained"``): the clamps'
        free-state offsets and forces (:class:`qifreport.registration.restrained.Restraint`);
        ``P`` then holds the restrained scan. A clamp above its force limit fails the part
        (not restrainable).
    """

    V: np.ndarray
    F: np.ndarray
    V_registered: np.ndarray
    P: np.ndarray
    deviation: np.ndarray
    point_deviation: np.ndarray
    vertex_stats: DeviationStats
    point_stats: DeviationStats
    acceptance: Acceptance
    rigid: RigidResult
    fit: DeformResult | None
    params: InspectionParams
    scan_area: float
    coverage_ceiling_ok: bool
    timings: dict[str, float]
    zones: list[ZoneResult] = field(default_factory=list)
    not_evaluated: list[NotEvaluated] = field(default_factory=list)
    bands: BandField | None = None
    energy: str = "hessian"
    edge_excluded_area: float = 0.0
    prealign: PrealignResult | None = None
    added: AddedMaterial | None = None
    hygiene: MeshHygiene | None = None
    repeatability: Repeatability | None = None
    basis: BendingBasis | None = None
    resolution: Resolution | None = None
    excluded: np.ndarray | None = None
    coverage: Coverage | None = None
    edges: EdgeDeviation | None = None
    size: SizeEstimate | None = None
    fixture_decision: str = "always"
    free_state: str | None = None
    free_state_decided_by: list[str] = field(default_factory=list)
    deviation_variance: np.ndarray | None = None
    solid: bool = False
    restraint: Restraint | None = None
    characteristics: list[CharacteristicResult] = field(default_factory=list)
    frames: list[DatumFrameResult] = field(default_factory=list)

    @property
    def free_state_stands(self) -> bool:
        """The free state was judged first and is the verdict: no virtual fixture applied."""
        return self.fixture_decision in (
            FREE_STATE_CONFORMS,
            FREE_STATE_UNCERTAIN,
            FREE_STATE_LOCAL_DEFECTS,
        )

    def fails_only_narrower_than_mesh(self) -> bool:
        """No surface fails on the nominal's vertices (each passes there or lies within the
        uncertainty of its limit), and some fail on regions of the scan points
        (:mod:`qifreport.metrology.point_regions`): defects narrower than the mesh, which
        no fixture bends out of a part (its compliance is smooth at the mesh's scale; a
        virtual one would only distort the rest of a stiff part), so the part fails
        whatever a fixture would do."""
        accs = [self.acceptance] + [z.acceptance for z in self.zones if z.measured]
        return bool(
            any(a.decision == "FAIL" for a in accs)
            and all(a.nominal_decision in ("PASS", "UNCERTAIN") for a in accs)
            and (self.added is None or self.added.passed)
            and (self.judged_size is None or not self.judged_size.flagged)
        )

    @property
    def judged_size(self) -> SizeEstimate | None:
        """The size check when it takes part in the verdict: not for a solid, whose faces
        measure its size themselves (its check is a note, :meth:`coverage_notes`)."""
        return None if self.solid else self.size

    @property
    def passed(self) -> bool:
        """No criterion fails on what was scored: the whole surface and every toleranced
        surface pass their area and region criteria (and, with ``fail_on_added_material``, no
        proud scan region exceeds the limit). Whether enough was scored is :attr:`measured`."""
        return bool(
            self.acceptance.decision != "FAIL"
            and not any(z.failed for z in self.zones)
            and (self.added is None or self.added.passed)
            and (self.judged_size is None or not self.judged_size.flagged)
            and not self.not_restrainable()
            and not any(c.status == "FAIL" for c in self.characteristics)
        )

    def not_restrainable(self) -> list[str]:
        """The clamps whose force exceeds their limit, one line each (the part cannot be
        held in its restrained condition within the forces its drawing allows)."""
        r = self.restraint
        if r is None:
            return []
        return [
            f"not restrainable within {c.max_force:g} N: clamp {c.name} needs {f:.3g} N"
            for c, f in zip(r.clamps, r.force, strict=True)
            if c.name in r.over_limit
        ]

    def trust_warnings(self) -> list[str]:
        """Why the registration cannot be trusted (empty when it can), one line each.

        * coverage above the scanned-to-nominal area ratio: the fit scored more of the nominal
          than the scan can have measured (over-fitting, paper Section 8.4.5);
        * the two-pass guard fired: the first pass flagged more than its limit of the covered
          surface as anomalous, so the band-limited refit fell back to a single pass
          (Section 6.4: on the paper's real part 23.9 % against a 20 % limit);
        * the measurement scatter (range noise, fit residual) is too large to resolve a
          tolerance zone (:mod:`qifreport.metrology.resolution`: 2 sigma <= width / 4);
        * ``--passes 1``: the single-pass fit has no two-pass guard;
        * the part's size cannot be established from its rim or trim edges
          (:mod:`qifreport.metrology.size`: too little of the rim seen, or a scale too
          uncertain or too close to the limit to decide);
        * with ``--seeds``: a resampled run whose own registration cannot be trusted (its
          regions decided which findings persist);
        * clamp force limits stated for a part held without a material: whether it can be
          held within them is not known.
        """
        out = []
        r = self.restraint
        if r is not None and not r.forces_known:
            limited = [c.name for c in r.clamps if c.max_force is not None]
            if limited:
                out.append(
                    f"clamp force limits are stated ({', '.join(limited)}) but not the "
                    "material (--material): whether the part can be held within them is not "
                    "known"
                )
        if not self.coverage_ceiling_ok:
            ratio = self.scan_area / max(self.acceptance.nominal_area, 1e-300)
            out.append(
                f"coverage {100 * self.acceptance.coverage:.1f} % exceeds the scanned-"
                f"to-nominal area ratio {100 * ratio:.1f} %: the fit followed the "
                "measurement (over-fit)"
            )
        if self.fit is not None and self.fit.fallback:
            fit = self.fit
            limit = getattr(fit.params, "max_flagged_fraction", float("nan"))
            out.append(
                f"the two-pass guard fired: pass {fit.guard_pass} flagged "
                f"{100 * fit.guard_fraction:.1f} % of the covered surface as anomalous "
                f"(limit {100 * limit:.0f} %), so the "
                "band-limited refit fell back to the single-pass fit"
            )
        if self.fit is not None and self.fit.method == "gbcicp" and self.params.gbcicp.passes < 2:
            out.append(
                "single-pass virtual fixture (--passes 1): the two-pass guard that keeps "
                "a defect from being fitted away is off, so a pass is not claimed"
            )
        if self.resolution is not None:
            out += self.resolution.warnings()
        size = self.judged_size
        if size is not None and size.status == "not established" and self.size_seen:
            out += size.reasons()
        if self.repeatability is not None:
            out += list(self.repeatability.warnings)
        return out

    @property
    def size_seen(self) -> bool:
        """The rim (or trim edges) was seen enough to judge the size (no size check: True)."""
        s = self.judged_size
        return (
            s is None
            or s.status in ("no rim", "conforming", "size error")
            or (s.seen_fraction >= s.min_seen)
        )

    @property
    def measured(self) -> bool:
        """The whole part and every toleranced surface were measured (coverage and gap rules,
        :mod:`qifreport.metrology.coverage`), and the rim seen enough for the size check."""
        return (
            (self.coverage is None or self.coverage.measured)
            and all(z.measured for z in self.zones)
            and self.size_seen
        )

    def not_measured(self) -> list[str]:
        """Why a surface is not measured, one line each (empty when all are)."""
        out = []
        if self.coverage is not None and not self.coverage.measured:
            out += [f"whole part: {r}" for r in self.coverage.reasons]
        for z in self.zones:
            if not z.measured:
                out += [f"{z.zone.key} {z.zone.describe()}: {r}" for r in z.coverage.reasons]
        if not self.size_seen:
            out += [f"size: {r}" for r in self.size.reasons()]
        return out

    def coverage_notes(self) -> list[str]:
        """Notes on what was left out by design (a surface more than 30 % in the unscored
        bands near creases and rims; a solid's size check, reported only), one line each,
        whether or not it was measured."""
        out = []
        if self.coverage is not None:
            out += [f"whole part: {w}" for w in self.coverage.warnings]
        for z in self.zones:
            if z.coverage is not None:
                out += [f"{z.zone.key}: {w}" for w in z.coverage.warnings]
        if self.solid and self.size is not None and self.size.status != "conforming":
            # a solid's faces measure its size themselves: the trim-edge check is reported
            out += [f"size (a solid: reported, not judged): {r}" for r in self.size.reasons()]
        return out

    def relaxed_guards(self) -> list[str]:
        """The settings that make a guard weaker than its default, one line each: they are
        named in every output (the verdict stands, on the user's responsibility)."""
        p = self.params
        out = []
        if p.min_coverage < DEFAULT_MIN_COVERAGE:
            out.append(
                f"min coverage {100 * p.min_coverage:g} % (default "
                f"{100 * DEFAULT_MIN_COVERAGE:g} %): a surface counts as measured with less scored"
            )
        low = [
            z.zone
            for z in self.zones
            if z.zone.min_coverage is not None and z.zone.min_coverage < DEFAULT_MIN_COVERAGE
        ]
        for zone in low:
            out.append(f"{zone.key}: min coverage {100 * zone.min_coverage:g} %")
        if p.max_gap_area is not None and p.max_gap_area > GAP_AREA_FACTOR * p.max_region_area:
            out.append(
                f"max gap area {p.max_gap_area:g} mm^2 (default "
                f"{GAP_AREA_FACTOR * p.max_region_area:g}): larger unmeasured patches accepted"
            )
        if p.min_fraction < DEFAULT_MIN_FRACTION:
            out.append(f"area criterion {100 * p.min_fraction:g} % (default 95 %)")
        if p.max_region_area > DEFAULT_MAX_REGION_AREA:
            out.append(
                f"region criterion {p.max_region_area:g} mm^2 (default "
                f"{DEFAULT_MAX_REGION_AREA:g} mm^2)"
            )
        return out

    @property
    def established(self) -> bool:
        """The registration can be trusted (no :meth:`trust_warnings`)."""
        return not self.trust_warnings()

    def uncertain(self) -> list[str]:
        """The surfaces whose conformance is neither proven nor disproven within the
        measurement uncertainty (:mod:`qifreport.metrology.decision`), one line each."""
        out = []
        if self.acceptance.decision == "UNCERTAIN":
            out += [f"whole part: {r}" for r in self.acceptance.uncertain_reasons]
        for z in self.zones:
            if z.uncertain:
                out += [
                    f"{z.zone.key} {z.zone.describe()}: {r}" for r in z.acceptance.uncertain_reasons
                ]
        for c in self.characteristics:
            if c.status == "INDETERMINATE":
                out.append(
                    f"{c.spec.key} {c.spec.name}: {c.value:.4g} within its uncertainty "
                    f"{c.uncertainty:.2g} of the limit {c.spec.limits_text()}"
                )
        return out

    @property
    def verdict(self) -> str:
        """``PASS``, ``FAIL``, ``NOT ESTABLISHED`` or ``NOT MEASURED``.

        ``FAIL`` when a criterion fails on what was scored (rejected either way; warnings
        and unmeasured surfaces are reported); otherwise ``NOT ESTABLISHED`` when the
        registration cannot be trusted (:meth:`trust_warnings`), ``NOT MEASURED`` when a
        surface was not measured (:meth:`not_measured`); ``PASS`` only when none of these."""
        if not self.passed:
            return "FAIL"
        if not self.established or self.uncertain():
            return "NOT ESTABLISHED"
        return "PASS" if self.measured else "NOT MEASURED"

    def decided_by(self) -> list[str]:
        """What failed the part (empty when it passed), one line each."""
        out = []
        if self.acceptance.decision == "FAIL":
            out += [f"whole part: {r}" for r in _fail_reasons(self.acceptance)]
        for z in self.zones:
            if z.failed:
                out += [
                    f"{z.zone.key} {z.zone.describe()}: {r}" for r in _fail_reasons(z.acceptance)
                ]
        if self.added is not None and not self.added.passed:
            out.append(f"added material: {self.added.describe()}")
        if self.judged_size is not None and self.judged_size.flagged:
            out += [f"size: {r}" for r in self.judged_size.reasons()]
        out += self.not_restrainable()
        out += [
            f"{c.spec.key} {c.spec.name} ({c.spec.kind}): {c.reason}"
            for c in self.characteristics
            if c.status == "FAIL"
        ]
        if self.passed:
            out += [f"not established: {w}" for w in self.trust_warnings()]
            out += [f"not established: {w}" for w in self.uncertain()]
            out += [f"not measured: {w}" for w in self.not_measured()]
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary: verdict, statistics, regions, registration and parameters."""
        fit = self.fit
        p = asdict(self.params)
        if fit is not None and fit.method == "gbcicp":
            p["gbcicp"] = asdict(fit.params)  # defaults resolved from the part size
        return {
            "verdict": self.verdict,
            "warnings": self.trust_warnings(),
            "decided_by": self.decided_by(),
            "relaxed_guards": self.relaxed_guards(),
            "acceptance": self.acceptance.to_dict(),
            "tolerances": [z.to_dict() for z in self.zones],
            "not_evaluated": [n.to_dict() for n in self.not_evaluated],
            "characteristics": [c.to_dict() for c in self.characteristics],
            "datum_frames": [f.to_dict() for f in self.frames],
            "vertex_deviation": self.vertex_stats.to_dict(),
            "point_deviation": self.point_stats.to_dict(),
            "added_material": None if self.added is None else self.added.to_dict(),
            "coverage": {
                "scored_area_mm2": self.acceptance.scored_area,
                "nominal_area_mm2": self.acceptance.nominal_area,
                "coverage": self.acceptance.coverage,
                "scan_area_mm2": self.scan_area,
                "ceiling_ok": self.coverage_ceiling_ok,
                "edge_excluded_area_mm2": self.edge_excluded_area,
                "measured": None if self.coverage is None else self.coverage.to_dict(),
            },
            "registration": {
                "energy": self.energy,
                "fixture": {
                    "decision": self.fixture_decision,
                    "free_state_verdict": self.free_state,
                    "free_state_decided_by": list(self.free_state_decided_by),
                },
                "restraint": None if self.restraint is None else self.restraint.to_dict(),
                "prealign": None if self.prealign is None else _prealign_dict(self.prealign),
                "rigid": {
                    "R": self.rigid.R.tolist(),
                    "t_mm": self.rigid.t.tolist(),
                    "rms_mm": self.rigid.rms,
                    "residual_scale_mm": self.rigid.scale,
                    "inlier_fraction": self.rigid.inlier_fraction,
                    "iterations": self.rigid.iterations,
                },
                "gbcicp": None if fit is None or fit.method != "gbcicp" else _fit_dict(fit),
                "fit": None
                if fit is None
                else {
                    "method": fit.method,
                    "label": method_label(fit.method),
                    **_fit_dict(fit),
                    "params": _params_dict(fit.params),
                },
            },
            "parameters": p,
            "repeatability": (None if self.repeatability is None else self.repeatability.to_dict()),
            "measurement": None if self.resolution is None else self.resolution.to_dict(),
            "edges": None if self.edges is None else self.edges.to_dict(),
            "size": None if self.size is None else self.size.to_dict(),
            "mesh": {
                "vertices": len(self.V),
                "triangles": len(self.F),
                "scan_points": len(self.P),
                **({} if self.hygiene is None else self.hygiene.to_dict()),
            },
            "timings_s": self.timings,
        }


def _fit_dict(fit: DeformResult) -> dict:
    """JSON-ready account of a virtual fixture's convergence (any method)."""
    return {
        "iterations": fit.iterations,
        "passes": fit.passes,
        "fallback": fit.fallback,
        "flagged_fraction": fit.flagged_fraction,
        "residual_scale_mm": fit.scale,
        "max_displacement_mm": fit.max_displacement,
    }


def _params_dict(params) -> dict:
    """A method's parameter dataclass as a dict (``{}`` when it is not a dataclass)."""
    if is_dataclass(params) and not isinstance(params, type):
        return asdict(params)
    return dict(params) if isinstance(params, dict) else {}


def _prealign_dict(a: PrealignResult) -> dict:
    """JSON-ready account of the pose search (the confidence report)."""
    return {
        "method": a.method,
        "inlier_fraction": a.inlier_fraction,
        "gate_mm": a.gate,
        "rms_mm": a.rms,
        "restart_agreement": a.restart_agreement,
        "starts": a.n_starts,
        "descriptor_matches": a.matches,
        "ransac_inliers": a.ransac_inliers,
        "ambiguous": a.ambiguous,
        "conditioning": a.conditioning,
        "weakly_constrained": a.weakly_constrained,
        "seconds": a.seconds,
    }


def check_units(V: np.ndarray, P: np.ndarray, scan_units: str | None = None) -> None:
    """Reject a scan whose extent betrays other units (or another part) than the nominal's.

    ``scan_units`` is what the user declared (``--scan-units``; None: the format's unit), for
    the hint. The overlap check needs the rigid pose and is made in :func:`inspect`.
    Raises :class:`InputError` with a one-line message.
    """
    dv, dp = bounding_diagonal(V), bounding_diagonal(P)
    if dv <= 0:
        raise InputError("the nominal mesh has zero extent")
    ratio = dp / dv
    if not 0.2 <= ratio <= 5.0:
        best = min(_UNIT_FACTORS, key=lambda r: abs(np.log(ratio / r)))
        hint = ""
        if abs(np.log(ratio / best)) < 0.4:
            unit = _UNIT_FACTORS[best]
            if best < 1:  # the scan is too small: its numbers are in a larger unit
                hint = (
                    f"; the scan looks {1 / best:g}x too small: in {unit}? use --scan-units {unit}"
                    if unit in ("in", "m")
                    else f"; the scan looks {1 / best:g}x too small (in {unit}?)"
                )
            elif scan_units not in (None, "mm"):
                hint = (
                    f"; the scan looks {best:g}x too large: it is in mm already? drop "
                    f"--scan-units {scan_units}"
                )
            else:
                hint = (
                    f"; the scan looks {best:g}x too large: is the nominal in {unit}? "
                    "(nominals are read in mm)"
                )
        raise InputError(
            f"scan extent {dp:.4g} mm vs nominal extent {dv:.4g} mm (ratio {ratio:.3g}): "
            f"wrong units or wrong part{hint}"
        )


#: a scan point this far from the fixtured nominal (in general half-widths, at least
#: :data:`FAR_DIAGONAL` of the diagonal) is explained by no defect or compliance
FAR_HALF_WIDTHS = 10.0
FAR_DIAGONAL = 0.01
#: share of such points above which, with a poor rigid fit or a fixture guard that fired,
#: the scan is not of this part
MAX_FAR_SHARE = 0.10


def check_same_part(
    point_dev: np.ndarray, half_width: float, diagonal: float, rigid: RigidResult, fit
) -> None:
    """Refuse a scan that is not of this part (:class:`InputError`: "scan does not match
    the nominal").

    After the virtual fixture a scan of the part lies within defects' reach of the nominal
    everywhere. The scan is refused when more than :data:`MAX_FAR_SHARE` of its points lie
    farther than ``max(FAR_HALF_WIDTHS * half_width, FAR_DIAGONAL * diagonal)`` from the
    fixtured nominal *and* the registration itself says so: fewer than 90 % rigid inliers, or
    the two-pass guard fired. Stray points (a fixture or the table in view) trip it too: the
    message says so, crop them.

    Parameters
    ----------
    point_dev : (m,) data-referenced deviation of each scan point, mm.
    half_width : the general zone's half-width, mm.  diagonal : the nominal's, mm.
    rigid : the rigid alignment.  fit : the virtual fixture's result, or None.
    """
    far_mm = max(FAR_HALF_WIDTHS * half_width, FAR_DIAGONAL * diagonal)
    d = np.abs(np.asarray(point_dev, dtype=np.float64))
    share = float(np.mean(~(d <= far_mm)))  # NaN (no correspondence) counts as far
    suspect = rigid.inlier_fraction < 0.9 or (fit is not None and fit.fallback)
    if share > MAX_FAR_SHARE and suspect:
        raise InputError(
            f"scan does not match the nominal: {100 * share:.1f} % of its points lie more than "
            f"{far_mm:.3g} mm from the fixtured part (rigid inliers "
            f"{100 * rigid.inlier_fraction:.0f} %): another part, or foreign objects in the scan"
        )


def vertex_deviation(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    normals: np.ndarray,
    face_id: np.ndarray | None,
    *,
    closest: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    scan_normals: np.ndarray | None = None,
    residual: np.ndarray | None = None,
    brep_normals: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nominal-referenced deviation (n,) mm of every vertex of ``(V, F)`` from scan ``P``,
    and its variance (n,) mm^2 from the scan points' scatter about the local fit (for
    :func:`qifreport.metrology.decision.vertex_uncertainty`).

    Each point's signed distance to the nominal *surface* (its distance to the closest
    triangle, ``closest`` from :func:`~qifreport.metrology.deviation.closest_points`, computed
    when not given, less the
    triangle's chord height there, :func:`~qifreport.metrology.deviation.curved_offset`) is
    fitted about each vertex by :func:`~qifreport.metrology.deviation.residual_referenced`,
    a vertex using only the points on its own B-rep faces (``face_id``, a STEP nominal);
    without ``face_id`` (a mesh nominal), the plane fit of
    :func:`~qifreport.metrology.deviation.nominal_referenced`. ``residual`` (m,): those
    signed distances to the surface, when the caller has them (:func:`surface_distance`).
    ``brep_normals`` (f, 3, 3): the surface's normals at the triangle corners for
    :func:`surface_distance` (the B-rep's, :mod:`qifreport.step.normals`).
    """
    if face_id is None:  # a mesh nominal: the local plane fit (no faces to keep apart)
        return nominal_referenced(
            V, F, P, normals=normals, scan_normals=scan_normals, variance=True
        )
    C, cface, pdev = closest_points(V, F, P) if closest is None else closest
    if residual is None:
        residual = surface_distance(V, F, C, cface, pdev, face_id, brep_normals, P)
    return residual_referenced(
        V, F, P, residual, normals, point_faces(cface, face_id), face_id, variance=True
    )


@dataclass
class ScanMeasures:
    """The scan's own normals and the area it covers, under way (:func:`start_scan_measures`).

    Attributes
    ----------
    P : (m, 3) the scan points they are measured on, mm (the very array later inspected).
    normals : pending ``(Ns, sheets)`` of
        :func:`~qifreport.registration.pointcloud.oriented_normals` (``result()``).
    area : pending covered area, mm^2, of :func:`~qifreport.metrology.acceptance.scan_area`;
        None: not started yet (:func:`inspect` starts it).
    """

    P: np.ndarray
    normals: Any
    area: Any = None

    def cancel(self) -> None:
        """Stop whatever of them is still running (a result taken already is kept)."""
        self.normals.cancel()
        if self.area is not None:
            self.area.cancel()


def start_scan_measures(
    P: np.ndarray, params: InspectionParams, executor=None, *, area: bool = True
) -> ScanMeasures:
    """Start measuring the scan's own normals and covered area (for :func:`inspect`).

    The normals (oriented consistently per connected sheet once; the inspection only chooses
    each sheet's side against its nominal) and the area do not depend on where the scan
    lies: they are measured on the points as read and turned with the scan. So they can run
    before the scan is seated, even while the part is still being prepared: on ``executor``
    (as :func:`inspect`'s) beside it, else when their results are asked for.

    Parameters
    ----------
    P : (m, 3) the scan points the inspection will be given, mm.
    params : the inspection's parameters (the normals' neighbourhood).
    executor : where they run; default: in this process, when asked for.
    area : start the area too (else :func:`inspect` starts it).
    """
    normals = _submit(executor, oriented_normals, P, params.gbcicp.scan_normal_k)
    pending = _submit(executor, scan_area, P) if area else None
    return ScanMeasures(P=P, normals=normals, area=pending)


def inspect(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    params: InspectionParams,
    progress=None,
    *,
    face_id: np.ndarray | None = None,
    zones: list[ToleranceZone] | None = None,
    not_evaluated: list[NotEvaluated] | None = None,
    scan_units: str | None = None,
    basis: BendingBasis | None = None,
    prepared: PreparedPart | None = None,
    solid: bool = False,
    brep_normals: np.ndarray | None = None,
    restraint: RestraintBasis | None = None,
    plan: CharacteristicPlan | None = None,
    executor=None,
    measures: ScanMeasures | None = None,
) -> InspectionResult:
    """Inspect the scan ``P`` against the nominal ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm.  F : (f, 3) triangles.
    P : (m, 3) scan points, mm, in any placement: a scan not already in the nominal frame
        is seated first by the pose search (``params.prealign``).
    params : :class:`InspectionParams`.
    progress : optional callable ``progress(k)`` advanced once per iteration of the virtual
        fixture (``params.method``).
    face_id : (f,) B-rep face id of each triangle (STEP nominals), for face-based zones.
    zones : tolerance zones (:func:`qifreport.metrology.bands.zones_from_pmi`); default one general
        zone of half-width ``params.tolerance``. Zones that cover no triangle are dropped.
    not_evaluated : PMI items listed in the result but not scored.
    scan_units : the unit the user declared for the scan file (for the units hint only).
    basis : the nominal's GB-CICP bending basis
        (:func:`qifreport.registration.gbcicp.bending_basis`), to reuse it across scans of one part;
        computed when needed if omitted.
    prepared : the nominal's scan-independent state
        (:func:`qifreport.metrology.prepared.prepare_part` with these ``params``), to reuse across
        scans of one part: operators, unscored bands, hygiene, bending basis (unless ``basis`` is
        given) and the pose search's model. ``ValueError`` if it was prepared for another mesh or
        other settings.
    solid : the nominal is a B-rep solid (a STEP part): its trim edges, for the size check, are
        its sharp creases, and open edges of its mesh (a B-rep's sewing gaps) are not a rim.
    brep_normals : (f, 3, 3) the B-rep's normals at the triangle corners (a STEP nominal,
        :func:`qifreport.step.normals.corner_normals_exact`): the scan points' distances to
        the curved surface are read with them (NaN rows: the mesh's).
    restraint : the part's clamps and their elastic responses
        (:func:`qifreport.registration.restrained.restraint_basis` on this mesh), for
        ``params.fixture == "restrained"``: the rigidly seated scan is held at its clamps
        and judged as held (no virtual fixture, no free-state shortcut: the drawing says
        how the part is inspected).
    plan : the drawing's feature characteristics and datums
        (:func:`qifreport.metrology.characteristics.specs_from_pmi`; a STEP nominal with
        ``brep_normals``): measured on the judged surface, and the profiles that name
        datums laid in their frame.
    executor : an object whose ``submit(fn, *args, **kwargs)`` returns a future (with
        ``result()`` and ``cancel()``, and ``done()`` to give up the fixture early), e.g. a
        :class:`concurrent.futures.Executor` or the command line's forked child
        (:class:`qifreport.forked.ForkExecutor`). Given to it: the scan's normals and area
        (beside the pose), the free-state judgement (beside the virtual fixture, which is
        given up once the free state stands) and the fixtured part's trim edges. The
        outcome is the sequential one. Default: sequential.
    measures : the scan's normals and area started already on these very points
        (:func:`start_scan_measures`, e.g. beside the part's preparation); default: started
        here, on ``executor``. The inspection takes them, or stops them when it fails.

    Raises
    ------
    InputError
        Wrong units, or a scan that does not overlap the nominal after rigid alignment;
        :class:`qifreport.registration.prealign.PoseNotEstablished` when no pose can be established.
    """
    if measures is not None and measures.P is not P:
        measures.cancel()
        raise ValueError("the scan measures were started on other points than these")
    try:
        if params.method not in METHODS:
            raise ValueError(f"unknown method {params.method!r} (one of {', '.join(METHODS)})")
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        check_units(V, P, scan_units)
        if prepared is None:
            prepared = prepare_part(V, F, params, basis=False, model=False)
        else:
            prepared.check(V, F, params)
            if basis is None:
                basis = prepared.basis
        energy, ops = prepared.energy, prepared.ops
        timings["operators"] = time.perf_counter() - t0
    except BaseException:
        if measures is not None:
            measures.cancel()
        raise
    if measures is None:
        measures = start_scan_measures(P, params, executor)
    elif measures.area is None:
        measures.area = _submit(executor, scan_area, P)
    normals, area = measures.normals, measures.area
    try:
        t0 = time.perf_counter()
        seat = seat_scan(V, F, P, mode=params.prealign, model=prepared.model)
        timings["prealign"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tree = prepared.model.tree if prepared.model is not None else cKDTree(V)
        rigid = rigid_icp(V, ops.normals, P, R0=seat.R, t0=seat.t, tree=tree)
        Pm = rigid.apply(P)
        timings["rigid"] = time.perf_counter() - t0
        diag = bounding_diagonal(V)
        d_near, _ = tree.query(Pm, workers=-1)
        overlap = float(np.mean(d_near < 0.02 * diag))
        if overlap < 0.3 or rigid.inlier_fraction < 0.3:
            raise InputError(
                f"scan does not overlap the nominal: after rigid alignment only "
                f"{100 * overlap:.0f} % of the points lie within {0.02 * diag:.3g} mm of it"
            )
        t0 = time.perf_counter()
        Ns, sheets = normals.result()
        Ns = Ns @ rigid.R.T
        area_mm2 = area.result()
        timings["scan normals, area"] = time.perf_counter() - t0
    finally:
        normals.cancel()
        area.cancel()
    if zones is None:
        tol = params.tolerance
        zones = [
            symmetric_zone(DEFAULT_GENERAL_TOLERANCE, "default")
            if tol is None
            else symmetric_zone(tol, "general")
        ]
    bands = lay_bands(F, len(V), face_id, zones)
    keep = [i for i, m in enumerate(bands.tri_masks) if m.any()]
    if len(keep) < len(zones):
        dropped = [zones[i].key for i in range(len(zones)) if i not in keep]
        log.info("zones covering no triangle dropped: %s", ", ".join(dropped))
        bands = lay_bands(F, len(V), face_id, [zones[i] for i in keep])
    reg = _Registered(
        V=V, F=F, P=Pm, rigid=rigid, seat=seat, scan_normals=Ns, sheets=sheets, diag=diag
    )
    reg.scan_area = area_mm2  # the cached property, known already
    judge = dict(
        face_id=face_id,
        bands=bands,
        not_evaluated=not_evaluated,
        prepared=prepared,
        solid=solid,
        energy=energy,
        basis=basis,
        brep_normals=brep_normals,
        plan=plan,
    )
    if params.rigid_only:
        res = _judge(reg, None, params, timings, **judge)
        res.fixture_decision = "rigid only"
        return res
    if params.fixture == "restrained":
        if restraint is None:
            raise ValueError("a restrained inspection needs the part's restraint basis")
        if len(restraint.points) != len(V):
            raise ValueError("the restraint basis was built for another mesh of the part")
        return _restrained(reg, restraint, params, timings, progress, zones, **judge)
    if params.always_fixture:
        return _fixtured(
            reg, None, params, prepared, zones, basis, progress, timings, judge, executor
        )
    # ISO 10579 / Y14.5: restraint is there to bring a compliant part to its drawing shape;
    # the free state (no force) is one of the states a fixture may hold it in. When it
    # conforms on its own, no restraint is needed and none is simulated: a virtual fixture
    # can then only add its own error (a stiff part moved by it).
    t0 = time.perf_counter()
    args = (reg, None, params, dict(timings))
    if executor is None:
        free = _judge(*args, check_part=False, **judge)
    elif not _fixture_likely(rigid, zones):
        # a seat well inside the tightest zone (a stiff part): its free state will most
        # likely stand, so no fixture is started beside it (its work would be wasted, and
        # would take a core from the judgement); judged here, its own steps beside it
        free = _judge(*args, check_part=False, executor=executor, **judge)
    else:  # judged beside the virtual fixture, which is given up when the free state stands
        pending = executor.submit(_judge, *args, check_part=False, **judge)
        stood = _StoodCheck(pending)
        # one factorisation for the basis and the fixture: their matrices share a pattern,
        # so the symbolic analysis is made once (and never again for the part: the basis
        # keeps its fill-reducing order)
        solver = part_solver(V, basis)
        try:
            if basis is None and _modal(params):
                # a new part's bending basis (a fixture's costliest step), built here and
                # given up between two of its solves once the free state stands
                t_basis = time.perf_counter()
                basis = bending_basis(prepared.ops, params.gbcicp.modes, solver=solver, check=stood)
                timings["bending basis"] = time.perf_counter() - t_basis

            def watched(k: int) -> None:  # between two fixture iterations, likewise
                stood()
                if progress is not None:
                    progress(k)

            return _fixtured(
                reg,
                pending,
                params,
                prepared,
                zones,
                basis,
                watched,
                timings,
                judge,
                executor,
                solver=solver,
            )
        except _FreeStateStood:  # its fixture_decision is set (_free_state_stands)
            free = pending.result()
            # taken when it was done already (between two fixture steps), or waited for
            timings.setdefault("free state (waited)", 0.0)
            # the stages this process ran beside it: their sum is the inspection's wall time
            free.timings = dict(timings)
            return free
        finally:
            pending.cancel()
    decided = _free_state_stands(free)
    if decided is not None:
        return decided
    timings["free state"] = time.perf_counter() - t0  # then the fixtured judgement's
    return _fixtured(reg, free, params, prepared, zones, basis, progress, timings, judge, executor)


#: the rigid seat's robust residual scale, in units of the tightest zone's half-width, from
#: which the virtual fixture is started beside the free state's judgement. Measured: the
#: compliant sample parts seat at 0.6-1.9 and the fandisk of ``bench/fandisk_command.py``
#: (bent and twisted, its free state fails) at 0.19; the NIST machined parts' perfect
#: scans at 0.02-0.18 (0.02-0.08 for five of the seven)
FIXTURE_LIKELY = 0.1


def _fixture_likely(rigid: RigidResult, zones: list[ToleranceZone]) -> bool:
    """Whether the rigid seat leaves the part far enough from its drawing shape that its
    free state may well not conform: its robust residual scale reaches a tenth of the
    tightest zone's half-width.

    Only the schedule depends on it, never the result: whether the fixture starts beside
    the free state's judgement or after it, if it does not stand. A wrong guess costs time,
    not a verdict: a fixture started for a free state that stands wastes the CPU it took (a
    stiff part's bending basis: 7 CPU-s on NIST FTC 08), and one not started for a free
    state that fails waits for the judgement (0.5 s on the fandisk); hence a low bar."""
    tightest = min(z.half_width for z in zones)
    return rigid.scale >= FIXTURE_LIKELY * tightest


def _modal(params: InspectionParams) -> bool:
    """Whether the inspection's virtual fixture iterates in the part's bending basis
    (GB-CICP's modal solver)."""
    g = params.gbcicp
    return params.method == "gbcicp" and g.solver == "modal" and g.lambda0 is None


class _FreeStateStood(Exception):
    """The free state, judged beside the virtual fixture, stands: the fixture is given up."""


class _StoodCheck:
    """Called between two steps of the virtual fixture: raises :class:`_FreeStateStood`
    when the free-state judgement beside it is done and stands."""

    def __init__(self, pending) -> None:
        self.pending = pending

    def __call__(self) -> None:
        done = getattr(self.pending, "done", None)
        if done is not None and done() and _free_state_stands(self.pending.result()):
            raise _FreeStateStood


def _trim_edges(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    tolerance: float,
    normals: np.ndarray,
    trim_edges: str,
    tree: cKDTree,
) -> tuple[EdgeDeviation, SizeEstimate]:
    """The trim-edge deviation of the scan ``P`` along the nominal ``(V, F)`` as the fixture
    holds it, and the size error read from it (:func:`edge_deviation`, :func:`size_error`)."""
    edges = edge_deviation(V, F, P, tolerance, normals=normals, trim_edges=trim_edges, tree=tree)
    return edges, size_error(edges)


class _Later:
    """A call made here when its result is asked for (the sequential order), with the
    future's interface :func:`_submit` returns."""

    def __init__(self, fn, args) -> None:
        self.fn, self.args, self.done, self.value = fn, args, False, None

    def result(self):
        if not self.done:
            self.value, self.done = self.fn(*self.args), True
        return self.value

    def cancel(self) -> bool:
        return False


def _submit(executor, fn, *args):
    """``executor.submit(fn, *args)``; without an executor, the call made when its result
    is asked for."""
    return _Later(fn, args) if executor is None else executor.submit(fn, *args)


def _free_state_stands(free: InspectionResult) -> InspectionResult | None:
    """The free-state judgement ``free`` as the inspection's result when it decides it:
    nothing of it proven out of tolerance with the registration trusted (PASS; NOT
    MEASURED where the scan has holes; NOT ESTABLISHED on a zone limit within the
    uncertainty: a fixture cannot decide what the measurement cannot), or only defects
    narrower than the mesh failed (which no fixture can remove). None: it does not."""
    if free.passed and free.established:  # its stages are the inspection's
        free.fixture_decision = FREE_STATE_UNCERTAIN if free.uncertain() else FREE_STATE_CONFORMS
        return free
    if free.established and free.fails_only_narrower_than_mesh():
        free.fixture_decision = FREE_STATE_LOCAL_DEFECTS
        return free
    return None


def _fixtured(
    reg: _Registered,
    free,
    params: InspectionParams,
    prepared: PreparedPart,
    zones: list[ToleranceZone],
    basis: BendingBasis | None,
    progress,
    timings: dict[str, float],
    judge: dict,
    executor,
    solver: SPDSolver | None = None,
) -> InspectionResult:
    """The virtual fixture and the judgement of the part as it holds it (``executor``: as
    :func:`inspect`'s; ``solver``: GB-CICP's factorisation, :func:`_virtual_fixture`).

    ``free``: the free state's judgement that did not stand, None (``always_fixture``), or
    its pending result (``executor.submit``): then it is taken when needed, and
    :class:`_FreeStateStood` raised when it decides the inspection
    (:func:`_free_state_stands`)."""
    t0 = time.perf_counter()
    fit = _virtual_fixture(reg, params, prepared, zones, basis, progress, solver)
    timings[params.method] = time.perf_counter() - t0
    if _pending(free) and any(z.free_state for z in judge["bands"].zones):
        free = _take(free, timings)  # the free-state zones take its deviation (below)
    free_dev = None
    if isinstance(free, InspectionResult):  # the free state, measured once
        free_dev = (free.deviation, free.deviation_variance)
    res = _judge(reg, fit, params, timings, free_deviation=free_dev, executor=executor, **judge)
    if _pending(free):
        free = _take(free, timings)
    res.fixture_decision = "always" if free is None else "free state does not conform"
    if free is not None:
        res.free_state = free.verdict
        res.free_state_decided_by = free.decided_by()
    return res


def _pending(free) -> bool:
    """Whether ``free`` is a pending free-state judgement (``executor.submit``'s)."""
    return free is not None and not isinstance(free, InspectionResult)


def _take(pending, timings: dict[str, float]) -> InspectionResult:
    """The pending free-state judgement's result (the time waited for it is a stage);
    :class:`_FreeStateStood` when it stands."""
    t0 = time.perf_counter()
    free = pending.result()
    timings["free state (waited)"] = time.perf_counter() - t0
    if _free_state_stands(free) is not None:
        raise _FreeStateStood
    return free


def _virtual_fixture(
    reg: _Registered,
    params: InspectionParams,
    prepared: PreparedPart,
    zones: list[ToleranceZone],
    basis: BendingBasis | None,
    progress,
    solver: SPDSolver | None = None,
) -> DeformResult:
    """The free virtual fixture (``params.method``) on the rigidly seated scan (``solver``:
    GB-CICP's factorisation, one that built the bending basis; a new one if None)."""
    near_crease, near_rim = prepared.near_crease, prepared.near_rim
    flaggable = ~near_rim if near_crease is None else ~(near_rim | near_crease)
    # the two-pass guard counts no residual under a quarter of the tightest half-width
    tightest = min(z.half_width for z in zones)
    gb = replace(params.gbcicp, guard_floor=max(params.gbcicp.guard_floor, 0.25 * tightest))
    return deform(
        params.method,
        reg.V,
        reg.F,
        prepared.ops,
        reg.P,
        gb if params.method == "gbcicp" else None,
        scan_normals=reg.scan_normals,
        scan_sheets=reg.sheets,
        progress=progress,
        basis=basis,
        flaggable=flaggable,
        solver=solver,
    )


def _restrained(
    reg: _Registered,
    restraint: RestraintBasis,
    params: InspectionParams,
    timings: dict[str, float],
    progress,
    zones: list[ToleranceZone],
    **judge,
) -> InspectionResult:
    """Hold the rigidly seated scan at its clamps (:func:`qifreport.metrology.held.hold_scan`)
    and judge it as held; the free-state zones are judged on the free state in the held
    seat, and the hold's uncertainty enters each deviation's."""
    prepared = judge["prepared"]

    def free_fit() -> np.ndarray:
        return _virtual_fixture(reg, params, prepared, zones, judge["basis"], progress).V

    held = hold_scan(
        reg.V,
        reg.F,
        reg.P,
        reg.scan_normals,
        reg.sheets,
        restraint,
        normals=prepared.ops.normals,
        free_fit=free_fit,
        face_id=judge["face_id"],
        brep_normals=judge["brep_normals"],
        tree=prepared.model.tree if prepared.model is not None else None,
        normal_k=params.gbcicp.scan_normal_k,
    )
    if "free fit" in held.seconds:
        timings[params.method] = held.seconds.pop("free fit")
    timings.update(held.seconds)
    res = _judge(
        replace(reg, P=held.P, scan_normals=held.normals, sheets=held.sheets),
        None,
        params,
        timings,
        free=replace(reg, P=held.P_free),
        model_uncertainty=(held.u_vertex, held.u_point),
        **judge,
    )
    res.restraint = held.restraint
    res.fixture_decision = RESTRAINED
    return res


def _fail_reasons(acc: Acceptance) -> list[str]:
    """Why a surface failed: its criteria's reasons, or (``guarded-acceptance``: the measured
    values pass, conformance is not proven) why it is not proven within the uncertainty."""
    if acc.reasons:
        return list(acc.reasons)
    return [f"not proven ({acc.decision_rule}): {r}" for r in acc.uncertain_reasons]


def _surface_points(
    samples: ScanSamples, sel: np.ndarray, half_width, center, extra_U=0.0
) -> SurfacePoints:
    """The points ``sel`` (m,) bool of ``samples`` with the band of their nearest vertex
    (``half_width``, ``center``, ``extra_U``: scalars or (n,) per vertex, mm)."""
    idx = np.flatnonzero(sel)
    v = samples.vertex[idx]

    def per_point(x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return np.full(len(idx), float(x)) if x.ndim == 0 else x[v]

    return SurfacePoints(
        samples=samples,
        index=idx,
        tolerance=per_point(half_width),
        center=per_point(center),
        extra_U=per_point(extra_U),
    )


@dataclass
class _Registered:
    """The scan seated rigidly on the nominal: what every judgement of one inspection shares."""

    V: np.ndarray
    F: np.ndarray
    P: np.ndarray
    rigid: RigidResult
    seat: PrealignResult
    scan_normals: np.ndarray
    sheets: np.ndarray
    diag: float

    @functools.cached_property
    def scan_tree(self) -> cKDTree:
        """``cKDTree(P)``: built once for every judgement's searches of the seated scan."""
        return cKDTree(self.P)

    @functools.cached_property
    def scan_area(self) -> float:
        """The area the seated scan covers, mm^2 (:func:`scan_area`): the same points for
        every judgement, measured once."""
        return scan_area(self.P)


def _judge(
    reg: _Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    timings: dict[str, float],
    *,
    face_id: np.ndarray | None,
    bands: BandField,
    not_evaluated: list[NotEvaluated] | None,
    prepared: PreparedPart,
    solid: bool,
    energy: str,
    basis: BendingBasis | None,
    check_part: bool = True,
    free_deviation: tuple[np.ndarray, np.ndarray] | None = None,
    brep_normals: np.ndarray | None = None,
    free: _Registered | None = None,
    model_uncertainty: tuple[np.ndarray, np.ndarray] | None = None,
    plan: CharacteristicPlan | None = None,
    executor=None,
) -> InspectionResult:
    """Judge the rigidly seated scan against the nominal as the fixture ``fit`` holds it
    (``None``: the free state, the nominal where the rigid alignment put it).

    ``free_deviation``: the free state's vertex deviation and its variance when it was
    judged already (the zones with the free-state modifier take them instead of measuring
    again). ``free``: the free state's registration when ``reg`` holds the scan otherwise
    (restrained): the free-state zones are judged on it. ``model_uncertainty``: expanded
    uncertainties (mm, (n,) per vertex and (m,) per scan point) the hold adds, combined in
    quadrature with the scanner's. ``executor``: where the trim-edge measure runs beside
    the rest (:func:`inspect`)."""
    V, F, Pm, rigid, diag = reg.V, reg.F, reg.P, reg.rigid, reg.diag
    Ns, sheets = reg.scan_normals, reg.sheets
    ops = prepared.ops
    V_reg = V if fit is None else fit.V
    if fit is not None:
        basis = fit.basis
    near_crease, near_rim, rim_band = prepared.near_crease, prepared.near_rim, prepared.rim_band
    # the free state of a B-rep nominal is scored up to its creases: the face-aware measure
    # (:func:`vertex_deviation`) fits each vertex to the points of its own faces and leaves
    # a crease vertex unscored unless all its faces were seen. A fixtured nominal keeps the
    # band: there the displacement field is least determined
    free_brep = fit is None and face_id is not None and params.edge_band is None
    if free_brep:
        near_crease = None
    t0 = time.perf_counter()
    N_reg = ops.normals if fit is None else vertex_normals(V_reg, F)
    # the size from the trim edges, on a fixture that moves the nominal along its normals
    # only (GB-CICP) or not at all; the baselines move it along the surface too, and so
    # absorb or make up a size error at the rim
    general = [z for z in bands.zones if z.faces is None]
    general_half = general[0].half_width if general else max(z.half_width for z in bands.zones)
    trim = None
    if fit is None or fit.method == "gbcicp":
        reg.scan_tree  # noqa: B018 - built once, before a child would build its own
        trim = _submit(
            executor,
            _trim_edges,
            V_reg,
            F,
            Pm,
            general_half,
            N_reg,
            "crease" if solid else "auto",
            reg.scan_tree,
        )
    # the B-rep's exact corner normals, turned with each triangle when the fixture bent it
    cn_reg = brep_normals
    if brep_normals is not None and fit is not None:
        cn_reg = follow_triangles(brep_normals, V, V_reg, F)
    C, cface, pdev = closest_points(V_reg, F, Pm)
    if face_id is not None:  # a B-rep nominal: the points' distances to its curved surface
        pdev = surface_distance(V_reg, F, C, cface, pdev, face_id, cn_reg, Pm)
    dev, var = vertex_deviation(
        V_reg,
        F,
        Pm,
        N_reg,
        face_id,
        closest=(C, cface, pdev),
        scan_normals=orient_scan_normals(Pm, Ns, V_reg, N_reg, sheets=sheets),
        residual=pdev if face_id is not None else None,
    )
    dev_free = var_free = None
    held = fit is not None or free is not None
    if held and any(z.free_state for z in bands.zones):
        fr = reg if free is None else free
        dev_free, var_free = (
            (free_deviation[0].copy(), free_deviation[1])
            if free_deviation is not None
            else vertex_deviation(
                V,
                F,
                fr.P,
                ops.normals,
                face_id,
                scan_normals=orient_scan_normals(
                    fr.P, fr.scan_normals, V, ops.normals, sheets=fr.sheets
                ),
                brep_normals=brep_normals,
            )
        )
    hygiene = replace(prepared.hygiene)  # a copy: the rim band is this inspection's
    hygiene.boundary_band = rim_band
    hygiene.boundary_excluded_area = float(ops.area[near_rim].sum())
    hygiene.boundary_excluded_fraction = hygiene.boundary_excluded_area / max(
        float(ops.area.sum()), 1e-300
    )
    if near_rim.any():
        if near_crease is not None:  # each excluded vertex is counted once, rim first
            near_crease = near_crease & ~near_rim
        dev[near_rim] = np.nan
        if dev_free is not None:
            dev_free[near_rim] = np.nan
    if near_crease is not None and near_crease.any():
        dev[near_crease] = np.nan
        if dev_free is not None:
            dev_free[near_crease] = np.nan
    if free_brep:
        near_crease = unseen_neighbour_edges(F, face_id, dev)
    excluded = near_rim if near_crease is None else near_rim | near_crease
    rim = beyond_rim(V_reg, F, C, cface)
    timings["deviation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    area = ops.area  # barycentric vertex areas of the nominal, mm^2
    dev_all = dev.copy()
    var_all = var.copy()
    if dev_free is not None:
        free_v = np.isin(bands.governing, [i for i, z in enumerate(bands.zones) if z.free_state])
        dev_all[free_v] = dev_free[free_v]
        var_all[free_v] = var_free[free_v]
    # threshold of the whole-part tail fractions (``general_half``): the general zone's
    # half-width, or (all faces under PMI profiles) the widest zone's: "beyond every band"
    # (per-zone fractions use their own band)
    # a STEP nominal's scan points grouped by their B-rep face: a thin wall's two skins are
    # kept apart in the noise estimate and in the points' own values
    plabel = None if face_id is None else point_faces(cface, face_id)
    sys_vertices: float | np.ndarray = params.scanner_uncertainty
    sys_points: float | np.ndarray = params.scanner_uncertainty
    if model_uncertainty is not None:
        sys_vertices = np.hypot(params.scanner_uncertainty, model_uncertainty[0])
        sys_points = np.hypot(params.scanner_uncertainty, model_uncertainty[1])
    t_pts = time.perf_counter()
    samples = scan_samples(
        V_reg, F, Pm, pdev, C, cface, plabel, systematic=sys_points, tree=reg.scan_tree
    )
    pvert = samples.vertex
    # a point judges a surface where its nearest vertex is scored there (the same crease
    # and rim bands); the free-state zones of a fixtured judgement are the free state's
    dev_pts = np.where(pvert >= 0, dev_all[np.maximum(pvert, 0)], np.nan)
    if dev_free is not None:
        dev_pts[free_v[np.maximum(pvert, 0)]] = np.nan
    pts_ok = (pvert >= 0) & np.isfinite(dev_pts)
    # a point standing proud beyond the whole part's band is added material (a rib, a
    # boss, flash, a clamp in the scan): judged by its own policy (:mod:`.added`, reported
    # unless --fail-on-added-material), as the vertex measure's robust fit drops it too
    with np.errstate(invalid="ignore"):
        pts_ok &= ~(samples.value > general_half)
    timings["scan points"] = time.perf_counter() - t_pts
    t_noise = time.perf_counter()
    noise = range_noise(Pm, labels=plabel)
    timings["resolution"] = time.perf_counter() - t_noise
    # the expanded uncertainty of each vertex's deviation, for the decision rule
    U = vertex_uncertainty(var_all, sys_vertices)
    U_free = None if var_free is None else vertex_uncertainty(var_free, params.scanner_uncertainty)
    rule = params.decision_rule
    U_base = U  # the vertices' own uncertainty (a located zone adds its frame's)
    point_center, point_U = bands.center, 0.0
    feats = frames_used = None
    zone_frames: dict[int, DatumFrameResult | None] = {}
    if plan is not None and face_id is not None and brep_normals is not None:
        t_feat = time.perf_counter()
        surf = _measured_surface(
            V, F, V_reg, face_id, brep_normals, dev_all, U, Pm, C, cface, pdev, plabel, pvert
        )
        free_surf = None
        if dev_free is not None and U_free is not None:
            free_surf = _measured_surface(
                V, F, V, face_id, brep_normals, dev_free, U_free, *_no_points()
            )
        cache: dict = {}
        # the profiles that name datums are laid in their frame (Y14.5-2018 11.2.1)
        for i, z in enumerate(bands.zones):
            if z.datums:
                use_free = z.free_state and free_surf is not None
                zone_frames[i] = frame_of(
                    z.datums, plan.datums, free_surf if use_free else surf, cache
                )
            if z.composite == "lower":  # its own placement, in its frame's orientation
                zone_frames[i] = composite_zone_frame(
                    zone_frames.get(i),
                    V,
                    ops.normals,
                    dev_all - z.center,
                    bands.governing == i,
                    z.half_width,
                )
        feats, frames_used = measure_characteristics(
            plan.specs, plan.datums, surf, rule, free_surface=free_surf, frames=cache
        )
        timings["characteristics"] = time.perf_counter() - t_feat
    located = {i: f for i, f in zone_frames.items() if f is not None and f.established}
    if located:
        # each vertex governed by a located zone takes its reading in the zone's frame, and
        # the frame's uncertainty with it
        U = U.copy()
        # the scan points judge against their vertex's band moved the other way
        point_center = np.broadcast_to(bands.center, (len(V),)).astype(np.float64).copy()
        point_U = np.zeros(len(V))
        for i, f in located.items():
            gv = bands.governing == i
            shift = f.normal_shift(V[gv], ops.normals[gv])
            dev_all[gv] = dev_all[gv] + shift
            point_center[gv] -= shift
            point_U[gv] = f.shift_uncertainty(V[gv], ops.normals[gv])
            U[gv] = np.hypot(U[gv], f.shift_uncertainty(V[gv], ops.normals[gv]))
    if check_part:
        check_same_part(pdev, general_half, diag, rigid, fit)
    edges = size = None
    if trim is not None:
        t_edges = time.perf_counter()
        edges, size = trim.result()
        timings["edges"] = time.perf_counter() - t_edges
    vstats = deviation_statistics(dev_all, weights=area, threshold=general_half)
    pstats = deviation_statistics(pdev, threshold=general_half)
    acc = evaluate(
        V,
        F,
        dev_all,
        bands.half_width,
        area=area,
        min_fraction=params.min_fraction,
        max_region_area=params.max_region_area,
        center=bands.center,
        uncertainty=U,
        decision_rule=rule,
        points=_surface_points(samples, pts_ok, bands.half_width, point_center, point_U),
    )
    # beside a drawing's own tolerances, qifreport's default band is no requirement: judged
    # where it was measured, its unmeasured patches reported (each PMI zone keeps its rules)
    advisory = any(z.source == "default" for z in bands.zones) and any(
        z.faces is not None for z in bands.zones
    )
    zone_results = []
    for i, (z, mask) in enumerate(zip(bands.zones, bands.tri_masks, strict=True)):
        az = zone_vertex_areas(V, F, mask)
        use_free = z.free_state and dev_free is not None
        dz = np.where(az > 0, dev_free if use_free else dev, np.nan)
        reading = "best fit"
        frame = zone_frames.get(i)
        zU = U_free if use_free else U
        zcenter, zpU = z.center, 0.0
        if i in located:
            shift = frame.normal_shift(V, ops.normals)
            dz = dz + shift
            zcenter = z.center - shift
            zpU = frame.shift_uncertainty(V, ops.normals)
            zU = np.hypot(U_free if use_free else U_base, frame.shift_uncertainty(V, ops.normals))
            reading = f"datum frame |{'|'.join(frame.labels)}|"
            if z.composite == "lower":
                reading = "composite lower segment: zone placed at its minimax position" + (
                    f", orientation in |{'|'.join(frame.labels)}|" if frame.labels else ""
                )
            elif frame.free:
                reading += " (best fit: " + ", ".join(frame.free) + ")"
        elif frame is not None:
            reading = "best fit (datum frame not established: " + "; ".join(frame.problems) + ")"
        zacc = evaluate(
            V,
            F[mask],
            dz,
            z.half_width,
            area=az,
            min_fraction=params.min_fraction,
            max_region_area=params.max_region_area,
            center=z.center,
            uncertainty=zU,
            decision_rule=rule,
            points=None
            if use_free
            else _surface_points(
                samples, pts_ok & mask[np.maximum(cface, 0)], z.half_width, zcenter, zpU
            ),
        )
        zstats = deviation_statistics(dz, weights=az, threshold=z.half_width)
        zcov = zone_coverage(
            V,
            F[mask],
            dz,
            az,
            excluded,
            center=z.center,
            half_width=z.half_width,
            min_coverage=params.min_coverage if z.min_coverage is None else z.min_coverage,
            max_region_area=params.max_region_area,
            max_gap_area=params.max_gap_area,
            advisory_gaps=advisory and z.source == "default",
        )
        zone_results.append(
            ZoneResult(
                zone=z,
                stats=zstats,
                acceptance=zacc,
                fixtured=held and not use_free,
                deviation=dz,
                coverage=zcov,
                reading=reading,
            )
        )
    whole = zone_coverage(
        V,
        F,
        dev_all,
        area,
        excluded,
        center=bands.center,
        half_width=bands.half_width,
        min_coverage=params.min_coverage,
        max_region_area=params.max_region_area,
        max_gap_area=params.max_gap_area,
        advisory_gaps=advisory,
    )
    s_area = reg.scan_area
    # the ceiling catches a deformable fit that met points of other features; a B-rep's free
    # state is rigid and scores each vertex from its own faces' points only, while the
    # scan-area estimate merges the two skins of a wall thinner than a point neighbourhood
    # (NIST CTC 03, 1.9 mm walls: 65 % "scanned" against 94 % scored)
    ceiling = free_brep or coverage_ceiling_ok(acc.coverage, s_area, acc.nominal_area)
    # added material: scan points beyond the rim of the nominal are not proud of it
    pdev_in = np.where(rim, np.nan, pdev)
    added = added_material(
        Pm,
        pdev_in,
        general_half,
        s_area,
        params.max_region_area,
        fail_on=params.fail_on_added_material,
        tree=samples.tree,
    )
    timings["metrology"] = time.perf_counter() - t0
    if fit is not None:
        residual_scale = fit.scale
    elif free is not None:
        # held otherwise (restrained): the held scan's deviations are the part's form, not a
        # scatter; its scatter is about the measured deviation field (each point against
        # its nearest scored vertex's value: a conforming panel with 0.23 mm of form the
        # clamps leave was "not established" when the form itself was taken for scatter)
        near = np.where(pvert >= 0, dev_all[np.maximum(pvert, 0)], np.nan)
        about = pdev - near
        residual_scale = (
            robust_scale(about[np.isfinite(about)]) if np.isfinite(about).any() else 0.0
        )
    else:
        residual_scale = rigid.scale
    scatter = resolution(
        noise,
        residual_scale,
        [(z.zone.key, float(z.zone.upper - z.zone.lower)) for z in zone_results],
    )
    return InspectionResult(
        V=V,
        F=F,
        V_registered=V_reg,
        P=Pm,
        deviation=dev_all,
        deviation_variance=var_all,
        solid=solid,
        point_deviation=pdev,
        vertex_stats=vstats,
        point_stats=pstats,
        acceptance=acc,
        rigid=rigid,
        fit=fit,
        params=params,
        scan_area=s_area,
        coverage_ceiling_ok=ceiling,
        timings=timings,
        zones=zone_results,
        not_evaluated=list(not_evaluated or []),
        bands=bands,
        energy=energy,
        edge_excluded_area=float(area[near_crease].sum()) if near_crease is not None else 0.0,
        prealign=reg.seat,
        added=added,
        hygiene=hygiene,
        basis=basis,
        resolution=scatter,
        excluded=excluded,
        coverage=whole,
        edges=edges,
        size=size,
        characteristics=feats or [],
        frames=frames_used or [],
    )


def _measured_surface(
    V, F, V_reg, face_id, corner_normals, dev, U, P, C, cface, pdev, plabel, pvert
) -> MeasuredSurface:
    """The judged surface for the feature characteristics: the vertices' deviations, and
    the scan points carried back through the fixture's displacement at their closest
    point (:class:`~qifreport.metrology.measured_surface.MeasuredSurface`)."""
    if len(P):
        bary = points_to_barycentric(V_reg[F[cface]], C)
        u = np.einsum("ij,ijk->ik", bary, (V_reg - V)[F[cface]])
        P0 = P - u
        PU = np.where(pvert >= 0, U[np.maximum(pvert, 0)], np.nan)
        PU = np.where(np.isfinite(PU), PU, np.nanmedian(U) if np.isfinite(U).any() else 0.0)
    else:
        P0, PU = P, np.empty(0)
    return MeasuredSurface(
        V, F, face_id, corner_normals, dev.copy(), U, P0, np.asarray(plabel), np.asarray(pdev), PU
    )


def _no_points() -> tuple:
    """Empty scan-point arrays for a surface measured on its vertices only."""
    e = np.empty(0)
    return (
        np.empty((0, 3)),
        np.empty((0, 3)),
        e.astype(np.int64),
        e,
        e.astype(np.int64),
        e.astype(np.int64),
    )
