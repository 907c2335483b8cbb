"""The result of one inspection: what was judged, on what, and the verdict.

:class:`InspectionResult` holds the registered nominal and the scan, the deviation field and
its statistics, each tolerance's :class:`ZoneResult`, the feature characteristics, the trim
edges and the size, and the registration's account; :meth:`InspectionResult.verdict` is the
decision and :meth:`InspectionResult.to_dict` the JSON summary. :func:`~qifreport.metrology.
inspection.inspect` makes it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, is_dataclass

import numpy as np

from qifreport.metrology.acceptance.added import AddedMaterial
from qifreport.metrology.acceptance.bands import BandField, NotEvaluated, ToleranceZone
from qifreport.metrology.acceptance.coverage import DEFAULT_MIN_COVERAGE, GAP_AREA_FACTOR, Coverage
from qifreport.metrology.acceptance.criteria import DEFAULT_MAX_REGION_AREA, Acceptance
from qifreport.metrology.acceptance.repeatability import Repeatability
from qifreport.metrology.acceptance.resolution import Resolution
from qifreport.metrology.acceptance.statistics import DeviationStats
from qifreport.metrology.deviation.detectable import Detectable
from qifreport.metrology.deviation.edge_statistics import EdgeDeviation
from qifreport.metrology.deviation.hygiene import MeshHygiene
from qifreport.metrology.deviation.size import SizeEstimate
from qifreport.metrology.gdt.characteristic_types import CharacteristicResult
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.registration.deformable.bending_basis import BendingBasis
from qifreport.registration.deformable.methods import METHODS, method_label, method_spec
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.icp import RigidResult
from qifreport.registration.outliers import StrayPoints
from qifreport.registration.pose.prealign import PrealignResult
from qifreport.registration.restraint.fixture_load import FixtureLoad
from qifreport.registration.restraint.restrained import Restraint

from .params import CLAMPS, VIRTUAL, InspectionParams, RestraintCondition

#: :attr:`InspectionResult.fixture_decision` when the free state stands
FREE_STATE_CONFORMS = "free state conforms"
FREE_STATE_UNCERTAIN = "free state within the uncertainty"
FREE_STATE_LOCAL_DEFECTS = "free state fails on defects narrower than the mesh"
#: :attr:`InspectionResult.fixture_decision` of a restrained inspection
RESTRAINED = "restrained"

__all__ = [
    "DEFAULT_MIN_FRACTION",
    "FREE_STATE_CONFORMS",
    "FREE_STATE_LOCAL_DEFECTS",
    "FREE_STATE_UNCERTAIN",
    "RESTRAINED",
    "InspectionResult",
    "ZoneResult",
]

#: the area criterion's default share (InspectionParams.min_fraction)
DEFAULT_MIN_FRACTION = 0.95


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
        :mod:`qifreport.metrology.acceptance.repeatability` to match regions between runs.
    coverage : whether the surface was measured (:mod:`qifreport.metrology.acceptance.coverage`);
    None
        from older callers (taken as measured).
    reading : where the zone was laid: ``'best fit'`` (no datums: a form control), or in
        the datum reference frame the tolerance names (ASME Y14.5-2018 11.2.1:
        ``'datum frame |A|B|C|'``), or ``'best fit (datum frame not established: ...)'``.
    detectable : the dent its region criterion is sure to catch
        (:mod:`qifreport.metrology.deviation.detectable`); None: not probed.
    judged : the zone takes part in the verdict; False for qifreport's default band beside
        a drawing (no requirement of the drawing: reported, status ``REPORTED``).
    """

    zone: ToleranceZone
    stats: DeviationStats
    acceptance: Acceptance
    fixtured: bool = True
    deviation: np.ndarray | None = None
    coverage: Coverage | None = None
    reading: str = "best fit"
    detectable: Detectable | None = None
    judged: bool = True

    @property
    def measured(self) -> bool:
        """Something of the surface was scored and the coverage and gap rules hold on it."""
        return self.acceptance.scored_area > 0 and (self.coverage is None or self.coverage.measured)

    @property
    def failed(self) -> bool:
        """A criterion fails on what was scored, under the decision rule (a surface the scan
        never saw fails none; :mod:`qifreport.metrology.acceptance.decision`)."""
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
        ESTABLISHED`` (on a zone limit within the measurement uncertainty), or ``PASS``;
        ``REPORTED`` when the zone is not judged (:attr:`judged`)."""
        if not self.judged:
            return "REPORTED"
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
            "judged": self.judged,
            "fixtured": self.fixtured,
            "reading": self.reading,
            "deviation": self.stats.to_dict(),
            "acceptance": self.acceptance.to_dict(),
            "measured": None if self.coverage is None else self.coverage.to_dict(),
            "detectable": None if self.detectable is None else self.detectable.to_dict(),
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
    drawing_warnings : exporter quirks the drawing's reader put right (bounds in reverse
        order), one line each (:attr:`qifreport.metrology.model.Drawing.warnings`).
    bands : the zones laid on the mesh (per-vertex band of the combined map).
    rigid : the rigid alignment (pose of the scan as delivered -> nominal frame).
    fit : the virtual fixture's result (None with ``rigid_only``), from the method
        ``params.method`` (``fit.method``).
    prealign : how the rigid ICP was started
        (:class:`qifreport.registration.pose.prealign.PrealignResult`; ``method == "identity"`` when
        the
        scan was already in the part frame).
    scan_area : estimated area covered by the scan, mm^2.
    coverage_ceiling_ok : coverage does not exceed scan area / nominal area (over-fit check).
    timings : seconds per stage.
    energy : the bending energy used.  edge_excluded_area : nominal area (mm^2) within the
        edge band of sharp creases, not scored.
    repeatability : the resampling study of ``qifreport --seeds`` (None without it): when
        set, ``acceptance`` and each zone's acceptance hold only the persistent regions
        (:func:`qifreport.metrology.acceptance.repeatability.apply`).
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
        judged surface (:mod:`qifreport.metrology.gdt.characteristics`); a FAIL fails the part,
        an INDETERMINATE one leaves it NOT ESTABLISHED, one not measured is reported.
    frames : the datum reference frames established (profiles and characteristics).
    restraint : the restrained condition (``params.fixture == "restrained"``): the clamps'
        free-state offsets and forces
        (:class:`qifreport.registration.restraint.restrained.Restraint`);
        ``P`` then holds the restrained scan. A clamp above its force limit fails the part
        (not restrainable).
    fixture_load : what a physical fixture would need to hold the part in the virtual
        fixture's shape (:class:`qifreport.registration.restraint.fixture_load.FixtureLoad`;
        a fixtured result only): above its force limit or beyond the material's yield
        strength, a PASS is not established.
    stray : the scan points left out as stray (in no surface patch,
        :func:`qifreport.registration.outliers.stray_points`); above the outlier model's
        limit the verdict is NOT ESTABLISHED, a FAIL included. None: not looked for.
    spikes : (m,) bool, the scan points of ``P`` alone off their neighbourhood's surface
        (:mod:`qifreport.metrology.acceptance.point_regions`): they judge nothing and are
        in no scan-point statistic. None: not looked for.
    detectable : the dent the whole part's region criterion is sure to catch
        (:mod:`qifreport.metrology.deviation.detectable`); None: not probed.
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
    drawing_warnings: list[str] = field(default_factory=list)
    bands: BandField | None = None
    energy: str = "hessian"
    edge_excluded_area: float = 0.0
    prealign: PrealignResult | None = None
    rim_seat: dict | None = None
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
    fixture_load: FixtureLoad | None = None
    characteristics: list[CharacteristicResult] = field(default_factory=list)
    frames: list[DatumFrameResult] = field(default_factory=list)
    stray: StrayPoints | None = None
    spikes: np.ndarray | None = None
    detectable: Detectable | None = None

    @property
    def condition(self) -> RestraintCondition:
        """The condition the part was judged in and who stated it (its parameters'
        :attr:`~qifreport.metrology.params.InspectionParams.held_condition`)."""
        return self.params.held_condition

    @property
    def restraint_applied(self) -> bool:
        """A restraint was applied: the virtual fixture's fit, or the hold at the clamps."""
        return self.fit is not None or self.restraint is not None

    def condition_text(self) -> str:
        """The verdict, the condition it was judged in, who stated it and what the free
        state gave: e.g. ``"PASS in a virtually restrained condition (stated by: drawing
        note); free state FAIL: T2 ..."``."""
        c = self.condition
        text = f"{self.verdict} {self.condition_words()} (stated by: {c.stated_by})"
        if self.restraint_applied:
            return f"{text}; {self.free_state_text()}"
        if c.condition == VIRTUAL:
            return f"{text}; the virtual restraint stated was not applied: {self.fixture_decision}"
        return f"{text}; no restraint applied"

    def condition_words(self) -> str:
        """Where the verdict holds: ``"restrained at its clamps"``, ``"in a virtually
        restrained condition"`` (the virtual fixture applied) or ``"in the free state"``."""
        if self.condition.condition == CLAMPS:
            return "restrained at its clamps"
        return (
            "in a virtually restrained condition" if self.fit is not None else "in the free state"
        )

    def free_state_text(self) -> str:
        """What the free state gave, when a restraint was applied: its verdict and the
        first thing it failed on, or that it was not judged."""
        if self.free_state is None:
            if self.fixture_decision == RESTRAINED:
                return "free state not judged (it decides nothing when held)"
            return "free state not judged"
        why = self.free_state_decided_by
        more = f" (and {len(why) - 1} more)" if len(why) > 1 else ""
        return f"free state {self.free_state}" + (f": {why[0]}{more}" if why else "")

    def restraint_dict(self) -> dict:
        """JSON-ready: the condition, who stated it and the statement, whether a restraint
        was applied, the sentence of :meth:`condition_text`, and the free state's verdict
        and what decided it (None: not judged); when no restraint was applied the free
        state is the result itself."""
        if not self.restraint_applied:
            free = {"verdict": self.verdict, "decided_by": self.decided_by()}
        elif self.free_state is None:
            free = None
        else:
            free = {"verdict": self.free_state, "decided_by": list(self.free_state_decided_by)}
        return {
            **self.condition.to_dict(),
            "applied": self.restraint_applied,
            "judged": self.condition_text(),
            "free_state": free,
        }

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
        (:mod:`qifreport.metrology.acceptance.point_regions`): defects narrower than the mesh, which
        no fixture bends out of a part (its compliance is smooth at the mesh's scale; a
        virtual one would only distort the rest of a stiff part), so the part fails
        whatever a fixture would do."""
        accs = [self.acceptance] if self.whole_part_judged else []
        accs += [z.acceptance for z in self.judged_zones if z.measured]
        return bool(
            any(a.decision == "FAIL" for a in accs)
            and all(a.nominal_decision in ("PASS", "UNCERTAIN") for a in accs)
            and (self.added is None or self.added.passed)
            and (self.judged_size is None or not self.judged_size.flagged)
        )

    @property
    def judged_size(self) -> SizeEstimate | None:
        """The size check when it takes part in the verdict: not for a solid
        (:mod:`qifreport.metrology.deviation.part_class`: a machined block, not a sheet),
        whose faces measure its size themselves (its check is a note,
        :meth:`coverage_notes`)."""
        return None if self.edges is not None and not self.edges.judged else self.size

    @property
    def judged_zones(self) -> list[ZoneResult]:
        """The zones that take part in the verdict (:attr:`ZoneResult.judged`)."""
        return [z for z in self.zones if z.judged]

    @property
    def whole_part_judged(self) -> bool:
        """The whole part's criteria take part in the verdict: not when its general band is
        qifreport's default beside a drawing (the drawing's zones are each judged on their
        own faces; the whole part is reported)."""
        return all(z.judged for z in self.zones)

    @property
    def part_failed(self) -> bool:
        """The whole part's criteria fail on what was scored (nothing scored fails nothing:
        it is not measured, :meth:`not_measured`), when they are judged."""
        a = self.acceptance
        return self.whole_part_judged and a.scored_area > 0 and a.decision == "FAIL"

    @property
    def passed(self) -> bool:
        """No criterion fails on what was scored: the whole surface and every toleranced
        surface pass their area and region criteria (and, with ``fail_on_added_material``, no
        proud scan region exceeds the limit). Whether enough was scored is :attr:`measured`."""
        return bool(
            not self.part_failed
            and not any(z.failed for z in self.judged_zones)
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
          tolerance zone (:mod:`qifreport.metrology.acceptance.resolution`: 2 sigma <= width / 4);
        * ``--passes 1``: the single-pass fit has no two-pass guard;
        * a virtual fixture that flags no defect candidates (NICP, CPD, RBF-FEM): what it
          bends away is not seen;
        * the part's size cannot be established from its rim or trim edges
          (:mod:`qifreport.metrology.deviation.size`: too little of the rim seen, or a scale too
          uncertain or too close to the limit to decide);
        * with ``--seeds``: a resampled run whose own registration cannot be trusted (its
          regions decided which findings persist);
        * clamp force limits stated for a part held without a material: whether it can be
          held within them is not known;
        * the virtual fixture's shape needs more force than its limit to hold, or stresses
          the material beyond its yield strength (:attr:`fixture_load`): no physical
          fixture could hold the part so.
        """
        out = []
        refusal = None if self.stray is None else self.stray.refusal()
        if refusal is not None:
            out.append(refusal)
        if self.fixture_load is not None:
            out += self.fixture_load.refusals()
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
        if self.fit is not None and not method_spec(self.fit.method).flags_defects:
            out.append(
                f"the virtual fixture {method_label(self.fit.method)} flags no defect "
                "candidates: a defect it bends out of the part goes unseen, so a pass is not "
                "claimed (a baseline for comparison; the default GB-CICP flags them)"
            )
        if (
            self.fit is not None
            and method_spec(self.fit.method).flags_defects
            and self.params.gbcicp.passes < 2
        ):
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
            or (s.seen_fraction >= s.min_seen and not s.too_sparse)
        )

    @property
    def measured(self) -> bool:
        """The whole part and every toleranced surface were measured (coverage and gap rules,
        :mod:`qifreport.metrology.acceptance.coverage`), and the rim seen enough for the size
        check."""
        return (
            self.acceptance.scored_area > 0
            and (self.coverage is None or self.coverage.measured or not self.whole_part_judged)
            and all(z.measured for z in self.judged_zones)
            and self.size_seen
        )

    def not_measured(self) -> list[str]:
        """Why a surface is not measured, one line each (empty when all are)."""
        out = []
        if not self.acceptance.scored_area > 0 and (
            self.coverage is None or self.coverage.measured
        ):
            out.append(
                "whole part: no vertex scored (no scan point lies near the part's surface "
                "as it was seated or held): no statistic exists to judge"
            )
        if self.coverage is not None and not self.coverage.measured and self.whole_part_judged:
            out += [f"whole part: {r}" for r in self.coverage.reasons]
        for z in self.judged_zones:
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
        if self.stray is not None and self.stray.count and not self.stray.over_limit:
            out.append(f"scan: {self.stray.describe()}")
        n_spikes = 0 if self.spikes is None else int(self.spikes.sum())
        if n_spikes:
            out.append(
                f"scan: {n_spikes} point(s) alone off their neighbourhood's surface (a stray "
                "point near it, or a one-point burr) judge nothing"
            )
        if self.coverage is not None:
            out += [f"whole part: {w}" for w in self.coverage.warnings]
        for z in self.zones:
            if z.coverage is not None:
                out += [f"{z.zone.key}: {w}" for w in z.coverage.warnings]
        out += self.detectability_notes()
        if self.judged_size is None and self.size is not None and self.size.status != "conforming":
            # a solid's faces measure its size themselves: the trim-edge check is reported
            what = self.edges.part.describe()
            out += [f"size ({what}: reported, not judged): {r}" for r in self.size.reasons()]
        return out

    def detectability_notes(self) -> list[str]:
        """What the region criteria can see: the whole part's detectable dent, and the
        surfaces whose region criterion is below detection (one line for them all)."""
        out = []
        if self.detectable is not None:
            out.append(f"whole part: {self.detectable.line()}")
            if self.detectable.below_detection:
                out.append(f"whole part: {self.detectable.blind()}")
        blind = [z.zone.key for z in self.zones if z.detectable and z.detectable.below_detection]
        if blind:
            out.append(
                f"region criterion below what this scan and mesh detect on {', '.join(blind)}"
            )
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
        """The measured surfaces whose conformance is neither proven nor disproven within
        the measurement uncertainty (:mod:`qifreport.metrology.acceptance.decision`), one
        line each."""
        out = []
        # a surface not measured is that, whatever its reading's uncertainty
        part_measured = self.coverage is None or self.coverage.measured
        if self.acceptance.decision == "UNCERTAIN" and self.whole_part_judged and part_measured:
            out += [f"whole part: {r}" for r in self.acceptance.uncertain_reasons]
        for z in self.judged_zones:
            if z.uncertain and z.measured:
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
        surface was not measured (:meth:`not_measured`); ``PASS`` only when none of these.
        More stray points than the outlier model is stated for leave even a FAIL NOT
        ESTABLISHED (:attr:`stray`): the data cannot decide."""
        if self.stray is not None and self.stray.over_limit:
            return "NOT ESTABLISHED"
        if not self.passed:
            return "FAIL"
        if not self.established or self.uncertain():
            return "NOT ESTABLISHED"
        return "PASS" if self.measured else "NOT MEASURED"

    def decided_by(self) -> list[str]:
        """What failed the part (empty when it passed), one line each; first, when there
        are more stray points than the outlier model is stated for, that refusal."""
        refusal = None if self.stray is None else self.stray.refusal()
        out = [] if refusal is None else [f"not established: {refusal}"]
        if self.part_failed:
            out += [f"whole part: {r}" for r in _fail_reasons(self.acceptance)]
        for z in self.judged_zones:
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
            out += [f"not established: {w}" for w in self.trust_warnings() if w != refusal]
            out += [f"not established: {w}" for w in self.uncertain()]
            out += [f"not measured: {w}" for w in self.not_measured()]
        return out

    def registration_dict(self) -> dict:
        """The JSON summary's ``registration`` block: the fixture's decision, the restraint,
        the load, the seat, the rigid fit and the virtual fixture's fit."""
        fit = self.fit
        own = None if fit is None else method_spec(fit.method).params_field
        return {
            "energy": self.energy,
            "fixture": {
                "decision": self.fixture_decision,
                "free_state_verdict": self.free_state,
                "free_state_decided_by": list(self.free_state_decided_by),
            },
            "restraint": None if self.restraint is None else self.restraint.to_dict(),
            "fixture_load": None if self.fixture_load is None else self.fixture_load.to_dict(),
            "prealign": None if self.prealign is None else _prealign_dict(self.prealign),
            "rigid": {
                "R": self.rigid.R.tolist(),
                "t_mm": self.rigid.t.tolist(),
                "rms_mm": self.rigid.rms,
                "residual_scale_mm": self.rigid.scale,
                "inlier_fraction": self.rigid.inlier_fraction,
                "iterations": self.rigid.iterations,
                "rim_seat": self.rim_seat,
            },
            # the fit under its parameters' name too (the GB-CICP record: "gbcicp")
            **{
                m.params_field: _fit_dict(fit) if own == m.params_field else None
                for m in METHODS.values()
                if m.params_field is not None
            },
            "fit": None
            if fit is None
            else {
                "method": fit.method,
                "label": method_label(fit.method),
                **_fit_dict(fit),
                "params": _params_dict(fit.params),
            },
        }

    def to_dict(self) -> dict:
        """JSON-ready summary: verdict, statistics, regions, registration and parameters."""
        fit = self.fit
        p = asdict(self.params)
        own = None if fit is None else method_spec(fit.method).params_field
        if own is not None:
            p[own] = asdict(fit.params)  # defaults resolved from the part size
        return {
            "verdict": self.verdict,
            "restraint": self.restraint_dict(),
            "scanner": self.params.scanner.label,
            # the instrument's k = 2 term in every surface point's and vertex's U, mm
            "instrument_surface_uncertainty_mm": self.params.surface_uncertainty,
            "warnings": self.trust_warnings(),
            "drawing_warnings": list(self.drawing_warnings),
            "decided_by": self.decided_by(),
            "relaxed_guards": self.relaxed_guards(),
            "acceptance": self.acceptance.to_dict(),
            "detectable": None if self.detectable is None else self.detectable.to_dict(),
            "tolerances": [z.to_dict() for z in self.zones],
            "whole_part_judged": self.whole_part_judged,
            "not_evaluated": [n.to_dict() for n in self.not_evaluated],
            "characteristics": [c.to_dict() for c in self.characteristics],
            "datum_frames": [f.to_dict() for f in self.frames],
            "vertex_deviation": self.vertex_stats.to_dict(),
            "point_deviation": self.point_stats.to_dict(),
            "added_material": None if self.added is None else self.added.to_dict(),
            "stray_points": None if self.stray is None else self.stray.to_dict(),
            "spike_points": None if self.spikes is None else int(self.spikes.sum()),
            "coverage": {
                "scored_area_mm2": self.acceptance.scored_area,
                "nominal_area_mm2": self.acceptance.nominal_area,
                "coverage": self.acceptance.coverage,
                "scan_area_mm2": self.scan_area,
                "ceiling_ok": self.coverage_ceiling_ok,
                "edge_excluded_area_mm2": self.edge_excluded_area,
                "measured": None if self.coverage is None else self.coverage.to_dict(),
            },
            "registration": self.registration_dict(),
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


def _fail_reasons(acc: Acceptance) -> list[str]:
    """Why a surface failed: its criteria's reasons, or (``guarded-acceptance``: the measured
    values pass, conformance is not proven) why it is not proven within the uncertainty."""
    if acc.reasons:
        return list(acc.reasons)
    return [f"not proven ({acc.decision_rule}): {r}" for r in acc.uncertain_reasons]
