"""The parameters of one inspection (:class:`InspectionParams`); the deformable methods'
display names are the registry's (:func:`qifreport.registration.deformable.methods.method_label`).

Kept apart from :mod:`qifreport.metrology.inspection` so that the per-part preparation
(:mod:`qifreport.metrology.prepared`), which depends on a few of these parameters, needs
nothing of the inspection itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from qifreport.metrology.acceptance.coverage import DEFAULT_MIN_COVERAGE
from qifreport.metrology.acceptance.criteria import DEFAULT_MAX_REGION_AREA
from qifreport.metrology.acceptance.decision import DEFAULT_DECISION_RULE
from qifreport.metrology.acceptance.scanner import DEFAULT_SCANNER, ScannerProfile
from qifreport.registration.deformable.gbcicp import GBCICPParams
from qifreport.registration.deformable.methods import method_label

__all__ = [
    "CLAMPS",
    "FREE",
    "RESTRAINT_CONDITIONS",
    "STATED_BY_DEFAULT",
    "STATED_BY_DRAWING",
    "STATED_BY_NOTE",
    "STATED_BY_OPERATOR",
    "VIRTUAL",
    "InspectionParams",
    "RestraintCondition",
    "method_label",
]

#: the conditions a part is judged in: its free state only (no fixture), a virtual fixture
#: (the free state judged first, GB-CICP when it does not conform), or held at its clamps
FREE, VIRTUAL, CLAMPS = "free", "virtual", "clamps"
RESTRAINT_CONDITIONS = (FREE, VIRTUAL, CLAMPS)
#: who stated the condition: a restraint note of the drawing; the drawing, by stating none
#: (free state, ASME Y14.5 / ISO 10579); the operator (a command-line option or a library
#: caller's parameters); nobody (a mesh nominal has no drawing: the operator-level default)
STATED_BY_NOTE = "drawing note"
STATED_BY_DRAWING = "drawing"
STATED_BY_OPERATOR = "operator"
STATED_BY_DEFAULT = "default"


@dataclass(frozen=True)
class RestraintCondition:
    """The condition a part is judged in and who stated it.

    Attributes
    ----------
    condition : :data:`FREE`, :data:`VIRTUAL` or :data:`CLAMPS`.
    stated_by : :data:`STATED_BY_NOTE`, :data:`STATED_BY_DRAWING`,
        :data:`STATED_BY_OPERATOR` or :data:`STATED_BY_DEFAULT`.
    statement : the statement itself: the drawing note's text, the operator's option, or
        why the default applies.
    """

    condition: str = VIRTUAL
    stated_by: str = STATED_BY_DEFAULT
    statement: str = ""

    def to_dict(self) -> dict:
        """JSON-ready: ``condition``, ``stated_by``, ``statement``."""
        return {
            "condition": self.condition,
            "stated_by": self.stated_by,
            "statement": self.statement,
        }


@dataclass
class InspectionParams:
    """Parameters of :func:`inspect` (lengths in mm).

    Attributes
    ----------
    tolerance : half-width of the general profile band (mm): where no other zone applies a
        vertex is in tolerance if ``|dev| <= tol``. None: the zones passed to
        :func:`inspect` decide, with
        :data:`qifreport.metrology.acceptance.bands.DEFAULT_GENERAL_TOLERANCE`
        where none applies.
    min_fraction : area criterion, fraction of the scored area that must be in tolerance.
    max_region_area : region criterion, largest admissible connected out-of-tolerance
        region (mm^2).
    energy : bending energy, ``"hessian"`` (natural boundary conditions at open boundaries),
        ``"laplacian"`` (the paper's ``L M^-1 L``) or ``"auto"`` (default): Hessian for a
        nominal with open boundary edges (a sheet: the Laplacian's boundary behaviour hurts
        there), Laplacian for a closed solid (no boundary; the Hessian energy is degraded by
        the needle triangles of B-rep tessellations: on the STEP panel it flags 8.4 % of the
        covered vertices in the first pass, the Laplacian 3.1 %).
    edge_band : vertices within this distance (mm, along the mesh) of a sharp crease
        (dihedral angle above ``crease_angle`` degrees) are not scored: there the vertex
        normal is the average of two faces and the local scan mixes both, so the deviation
        is an artefact. None: the deviation's neighbourhood radius (1.5 median edges);
        0 scores every vertex. The excluded area is reported.
    boundary_band : vertices within this distance (mm) of an open boundary of the nominal
        (rim, holes, unwelded seams) are not scored (:mod:`qifreport.metrology.deviation.hygiene`);
        None: the
        same width as ``edge_band``'s default (1.5 median edges); 0 scores the rim. The excluded
        area is reported with the mesh's defects.
    rigid_only : skip the virtual fixture (the fixtureless rigid baseline).
    always_fixture : apply the virtual fixture even when the free state conforms. By default
        the free state (the rigid alignment, no force) is judged first and the fixture is
        applied only when it does not conform (ISO 10579: restraint is there to bring a
        compliant part to its drawing shape; a part that conforms without it needs none).
        For comparing registration methods.
    judge_free_state : with a restraint applied at clamps, judge the free state too (in its
        own best fit), for what the outputs say it gave; it decides nothing. By default
        only the stated condition is judged and the outputs say the free state was not.
    prealign : pose search before the rigid ICP
    (:func:`qifreport.registration.pose.prealign.seat_scan`):
        ``"auto"`` (default) searches only when the scan is not already in the part frame,
        ``"always"`` always searches, ``"never"`` trusts that scan and nominal share a frame.
    fail_on_added_material : a connected scan region standing proud of the nominal beyond
        the whole-part threshold and larger than ``max_region_area`` fails the part
        (:mod:`qifreport.metrology.acceptance.added`); otherwise it is reported only.
    method : the deformable method of the virtual fixture, a key of
        :data:`qifreport.registration.deformable.methods.METHODS`: ``"gbcicp"`` (default, paper
        Section 6.4) or
        one of the paper's baselines ``"nicp"``, ``"cpd"``, ``"rbffem"`` (run with their own
        default parameters).
    gbcicp : parameters of the GB-CICP stage (used only with ``method="gbcicp"``; its
        ``scan_normal_k`` sets the PCA scan normals for every method).
    min_coverage : least scored share of a toleranced surface's own area for its tolerance to
        be measured (:mod:`qifreport.metrology.acceptance.coverage`); a zone may set its own.
    max_gap_area : largest unmeasured patch on a toleranced surface, mm^2; None:
        ``GAP_AREA_FACTOR * max_region_area``.
    decision_rule : how the measurement uncertainty enters each decision, one of
        :data:`qifreport.metrology.acceptance.decision.DECISION_RULES` (default ``"iso14253"``: PASS
        proven, FAIL proven, otherwise not established).
    scanner_uncertainty : the scanner's own expanded uncertainty (k = 2), mm, combined in
        quadrature with each vertex's uncertainty from the range noise (0: none stated;
        the scanner profile's surface term then stands for it, :attr:`surface_uncertainty`).
    scanner : the scanner's acceptance figures, the instrument terms of each
        characteristic's uncertainty budget (:mod:`qifreport.metrology.gdt.budgets`;
        default: the documented default scanner class).
    fixture : ``"free"`` (default: the free state judged first, then the virtual fixture
        ``method`` when it does not conform) or ``"restrained"`` (ISO 10579: the part held
        at its clamps by its elastic model, :mod:`qifreport.registration.restraint.restrained`; the
        inspection then needs the part's restraint basis).
    restraint : the condition the part is judged in and who stated it
        (:class:`RestraintCondition`; default: the virtual fixture, nobody's statement). The
        application decides it from the drawing and the operator's options; ``rigid_only``
        and ``fixture="restrained"`` state :data:`FREE` and :data:`CLAMPS` too
        (:meth:`held_condition`).
    max_restraint_force : the force a physical fixture may use to hold the part in the
        virtual fixture's shape, N (None: the drawing's, else
        :data:`qifreport.registration.restraint.fixture_load.DEFAULT_MAX_FORCE`): a
        fixtured PASS that needs more is not established
        (:mod:`qifreport.registration.restraint.fixture_load`).
    """

    tolerance: float | None = None
    min_fraction: float = 0.95
    max_region_area: float = DEFAULT_MAX_REGION_AREA
    energy: str = "auto"
    edge_band: float | None = None
    boundary_band: float | None = None
    crease_angle: float = 45.0
    rigid_only: bool = False
    always_fixture: bool = False
    judge_free_state: bool = False
    prealign: str = "auto"
    fail_on_added_material: bool = False
    method: str = "gbcicp"
    gbcicp: GBCICPParams = field(default_factory=GBCICPParams)
    min_coverage: float = DEFAULT_MIN_COVERAGE
    max_gap_area: float | None = None
    decision_rule: str = DEFAULT_DECISION_RULE
    scanner_uncertainty: float = 0.0
    scanner: ScannerProfile = DEFAULT_SCANNER
    fixture: str = "free"
    max_restraint_force: float | None = None
    restraint: RestraintCondition = field(default_factory=RestraintCondition)

    @property
    def surface_uncertainty(self) -> float:
        """The instrument's expanded uncertainty (k = 2) of a surface point's deviation, mm:
        :attr:`scanner_uncertainty` when stated, else the scanner profile's
        :meth:`~qifreport.metrology.acceptance.scanner.ScannerProfile.surface_error` taken
        as a rectangular distribution's half-width (``U = 2 MPE / sqrt(3)``, GUM 4.3.7)."""
        if self.scanner_uncertainty > 0.0:
            return float(self.scanner_uncertainty)
        return 2.0 * self.scanner.surface_error() / math.sqrt(3.0)

    @property
    def held_condition(self) -> RestraintCondition:
        """The condition these parameters ask for: :attr:`restraint`, or the one a caller's
        flags state (``rigid_only``: free; ``fixture="restrained"``: clamps), stated by
        the operator."""
        r = self.restraint
        if self.rigid_only and r.condition != FREE:
            return RestraintCondition(FREE, STATED_BY_OPERATOR, "rigid only")
        if self.fixture == "restrained" and r.condition != CLAMPS:
            return RestraintCondition(CLAMPS, STATED_BY_OPERATOR, "restrained at its clamps")
        return r
