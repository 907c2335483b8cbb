"""The judgement of one registered scan: deviations, tolerances, characteristics, verdict.

:func:`judge` takes the scan seated on the nominal (:class:`Registered`) and, when the part
is fixtured, the virtual fixture's fit, and measures and decides everything the result
reports (:class:`~qifreport.metrology.results.InspectionResult`): the vertices' and the scan
points' deviations, each tolerance zone's area and region criteria with the uncertainty,
coverage, the trim edges and the size, added material, the drawing's feature
characteristics in their datum frames. :func:`~qifreport.metrology.inspection.inspect`
schedules the judgements (the free state, the fixtured part) and the fixture.

What one inspection's judgements share (the prepared part, its zones, its drawing) is a
:class:`JudgeContext`. :func:`judge` runs the stages in order, each a public function with
a typed output a library user can run and look at one by one:

1. :func:`held_nominal` -- the nominal as the fixture holds it (:class:`HeldNominal`);
2. :func:`schedule_trim_edges` -- the trim edges and the size (:func:`trim_edge_stage`),
   started beside the rest;
3. :func:`deviation_stage` -- the points' and vertices' deviations, the free state's, the
   unscored bands (:class:`Deviations`);
4. :func:`scoring_stage` -- the judged field, the scan points that judge it, the noise and
   the uncertainties (:class:`Scores`);
5. :func:`characteristics_stage` -- the drawing's characteristics and the zones' datum
   frames (:class:`Characteristics`);
6. :func:`located_readings` -- the deviations read in the located zones' frames
   (:class:`Readings`);
7. :func:`acceptance_stage` -- area, region and coverage criteria on the whole part and on
   each zone (:func:`zone_result`; :class:`Decisions`), on the measuring stages' outputs
   (:class:`Measured`);
8. :func:`added_stage` -- added material; :func:`residual_scatter` -- the resolution;
9. :func:`assemble_result` -- the :class:`~qifreport.metrology.results.InspectionResult`.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import points_to_barycentric

from qifreport.errors import InputError
from qifreport.metrology.acceptance.added import AddedMaterial, added_material
from qifreport.metrology.acceptance.bands import (
    BandField,
    NotEvaluated,
    ToleranceZone,
    zone_vertex_areas,
)
from qifreport.metrology.acceptance.coverage import Coverage, unseen_neighbour_edges, zone_coverage
from qifreport.metrology.acceptance.criteria import (
    Acceptance,
    coverage_ceiling_ok,
    evaluate,
    scan_area,
)
from qifreport.metrology.acceptance.decision import vertex_uncertainty
from qifreport.metrology.acceptance.point_regions import ScanSamples, SurfacePoints, scan_samples
from qifreport.metrology.acceptance.resolution import Resolution, range_noise, resolution
from qifreport.metrology.acceptance.statistics import DeviationStats, deviation_statistics
from qifreport.metrology.deviation.closest import beyond_rim, closest_points
from qifreport.metrology.deviation.edge_statistics import EdgeDeviation
from qifreport.metrology.deviation.edges import edge_deviation
from qifreport.metrology.deviation.hygiene import MeshHygiene
from qifreport.metrology.deviation.local_planes import nominal_referenced
from qifreport.metrology.deviation.residual_fit import residual_referenced
from qifreport.metrology.deviation.size import SizeEstimate, size_error
from qifreport.metrology.deviation.surface import follow_triangles, point_faces, surface_distance
from qifreport.metrology.gdt.characteristics import (
    CharacteristicPlan,
    CharacteristicResult,
    frame_of,
    measure_characteristics,
)
from qifreport.metrology.gdt.composite import composite_zone_frame
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.gdt.measured_surface import MeasuredSurface
from qifreport.registration.deformable.bending_basis import BendingBasis
from qifreport.registration.deformable.methods import method_spec
from qifreport.registration.deformable.result import DeformResult, orient_scan_normals
from qifreport.registration.icp import RigidResult, robust_scale
from qifreport.registration.mesh import vertex_normals
from qifreport.registration.pose.prealign import PrealignResult

from .deferred import submit
from .params import InspectionParams
from .prepared import PreparedPart
from .results import InspectionResult, ZoneResult

__all__ = [
    "FAR_DIAGONAL",
    "FAR_HALF_WIDTHS",
    "MAX_FAR_SHARE",
    "Characteristics",
    "Decisions",
    "Deviations",
    "HeldNominal",
    "JudgeContext",
    "Measured",
    "Readings",
    "Registered",
    "Scores",
    "Stages",
    "acceptance_stage",
    "added_stage",
    "assemble_result",
    "characteristics_stage",
    "check_same_part",
    "deviation_stage",
    "free_state_deviation",
    "held_nominal",
    "judge",
    "located_readings",
    "residual_scatter",
    "schedule_trim_edges",
    "scoring_stage",
    "trim_edge_stage",
    "vertex_deviation",
    "zone_result",
]

log = logging.getLogger(__name__)

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
    tree: cKDTree | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nominal-referenced deviation (n,) mm of every vertex of ``(V, F)`` from scan ``P``,
    and its variance (n,) mm^2 from the scan points' scatter about the local fit (for
    :func:`qifreport.metrology.acceptance.decision.vertex_uncertainty`).

    Each point's signed distance to the nominal *surface* (its distance to the closest
    triangle, ``closest`` from :func:`~qifreport.metrology.deviation.signed.closest_points`,
    computed
    when not given, less the
    triangle's chord height there, :func:`~qifreport.metrology.deviation.signed.curved_offset`) is
    fitted about each vertex by :func:`~qifreport.metrology.deviation.signed.residual_referenced`,
    a vertex using only the points on its own B-rep faces (``face_id``, a STEP nominal);
    without ``face_id`` (a mesh nominal), the plane fit of
    :func:`~qifreport.metrology.deviation.signed.nominal_referenced`. ``residual`` (m,): those
    signed distances to the surface, when the caller has them (:func:`surface_distance`).
    ``brep_normals`` (f, 3, 3): the surface's normals at the triangle corners for
    :func:`surface_distance` (the B-rep's, :mod:`qifreport.step.normals`). ``tree``:
    ``cKDTree(P)`` when at hand (the plane fit searches the scan).
    """
    if face_id is None:  # a mesh nominal: the local plane fit (no faces to keep apart)
        return nominal_referenced(
            V, F, P, normals=normals, scan_normals=scan_normals, variance=True, tree=tree
        )
    C, cface, pdev = closest_points(V, F, P) if closest is None else closest
    if residual is None:
        residual = surface_distance(V, F, C, cface, pdev, face_id, brep_normals, P)
    return residual_referenced(
        V, F, P, residual, normals, point_faces(cface, face_id), face_id, variance=True
    )


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
class Registered:
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


@dataclass(frozen=True)
class JudgeContext:
    """What every judgement of one inspection shares besides the scan: the prepared part,
    its tolerance zones and its drawing.

    Attributes
    ----------
    prepared : the nominal's scan-independent state (operators, unscored bands, hygiene).
    bands : the tolerance zones laid on the nominal
    (:func:`~qifreport.metrology.acceptance.bands.lay_bands`).
    energy : the bending energy of the virtual fixture (``prepared.energy``), reported.
    face_id : (f,) B-rep face id of each triangle (a STEP nominal), for face-based zones;
        None: a mesh nominal.
    not_evaluated : PMI items listed in the result but not scored.
    solid : the nominal is a B-rep solid (a STEP part): its trim edges, for the size check,
        are its sharp creases, and open edges of its mesh (a B-rep's sewing gaps) are not a
        rim.
    basis : the nominal's GB-CICP bending basis, reported (a fixture's own replaces it).
    brep_normals : (f, 3, 3) the B-rep's normals at the triangle corners (a STEP nominal,
        :func:`qifreport.step.normals.corner_normals_exact`): the scan points' distances to
        the curved surface are read with them (NaN rows: the mesh's).
    plan : the drawing's feature characteristics and datums
        (:func:`qifreport.metrology.gdt.characteristics.specs_from_pmi`; a STEP nominal with
        ``brep_normals``): measured on the judged surface, and the profiles that name
        datums laid in their frame; None: none.
    """

    prepared: PreparedPart
    bands: BandField
    energy: str
    face_id: np.ndarray | None = None
    not_evaluated: list[NotEvaluated] | None = None
    solid: bool = False
    basis: BendingBasis | None = None
    brep_normals: np.ndarray | None = None
    plan: CharacteristicPlan | None = None

    @property
    def general_half(self) -> float:
        """The threshold of the whole-part tail fractions and of added material, mm: the
        general zone's half-width, or (all faces under PMI profiles) the widest zone's:
        "beyond every band" (per-zone fractions use their own band)."""
        general = [z for z in self.bands.zones if z.faces is None]
        return general[0].half_width if general else max(z.half_width for z in self.bands.zones)


@dataclass(frozen=True)
class HeldNominal:
    """The nominal as the judgement holds it (:func:`held_nominal`).

    Attributes
    ----------
    V : (n, 3) its vertices, mm: the virtual fixture's, or the nominal's (free state).
    normals : (n, 3) unit vertex normals of ``V``.
    corner_normals : (f, 3, 3) the B-rep's corner normals turned with each triangle the
        fixture bent; None: a mesh nominal.
    basis : the bending basis reported (the fixture's, else the context's).
    held : the part is held (a virtual fixture, or clamps), not in its free state.
    to_creases : the free state of a B-rep nominal, scored up to its creases (no crease
        band: :func:`vertex_deviation` keeps each vertex to its own faces' points).
    """

    V: np.ndarray
    normals: np.ndarray
    corner_normals: np.ndarray | None
    basis: BendingBasis | None
    held: bool
    to_creases: bool


@dataclass(frozen=True)
class Deviations:
    """The scan's deviations from the held nominal (:func:`deviation_stage`); ``n``
    vertices, ``m`` scan points, mm.

    Attributes
    ----------
    closest : (m, 3) each point's closest point on the held nominal.
    face : (m,) that point's triangle (-1: none).
    point : (m,) each point's signed distance to the nominal surface (the curved B-rep
        surface for a STEP nominal).
    vertex : (n,) each vertex's nominal-referenced deviation, NaN where unscored (the rim
        and crease bands).  variance : (n,) its variance, mm^2.
    free, free_variance : (n,) the free state's, for the free-state zones of a held part;
        None otherwise.
    near_crease : (n,) bool the crease band's vertices outside the rim band (or, for a
        B-rep's free state, the crease vertices not all of whose faces were seen); None:
        no crease band.
    excluded : (n,) bool every unscored band's vertices.
    beyond_rim : (m,) bool the points beyond the rim of the held nominal.
    hygiene : the mesh hygiene with this inspection's rim band.
    """

    closest: np.ndarray
    face: np.ndarray
    point: np.ndarray
    vertex: np.ndarray
    variance: np.ndarray
    free: np.ndarray | None
    free_variance: np.ndarray | None
    near_crease: np.ndarray | None
    excluded: np.ndarray
    beyond_rim: np.ndarray
    hygiene: MeshHygiene


@dataclass(frozen=True)
class Scores:
    """The judged deviation field and what decides on it (:func:`scoring_stage`).

    Attributes
    ----------
    deviation : (n,) the judged vertex deviation, mm: the held state's, the free state's
        on the free-state zones' vertices.  variance : (n,) its variance, mm^2.
    free_vertices : (n,) bool the vertices governed by a free-state zone; None: the free
        state not measured.
    labels : (m,) B-rep face of each scan point (-1: none); None: a mesh nominal.
    samples : the scan points' local values and uncertainties.
    points_ok : (m,) bool the points that judge the surface (nearest vertex scored there,
        not added material).
    noise : the scan's range noise, mm.
    uncertainty : (n,) expanded uncertainty of ``deviation``, mm.
    free_uncertainty : (n,) that of the free state's deviation, mm; None: not measured.
    """

    deviation: np.ndarray
    variance: np.ndarray
    free_vertices: np.ndarray | None
    labels: np.ndarray | None
    samples: ScanSamples
    points_ok: np.ndarray
    noise: float
    uncertainty: np.ndarray
    free_uncertainty: np.ndarray | None


@dataclass(frozen=True)
class Characteristics:
    """The drawing's characteristics measured (:func:`characteristics_stage`).

    Attributes
    ----------
    results : the feature characteristics, measured on the judged surface.
    frames : the datum reference frames established.
    zone_frames : the frame of each zone (by index in ``bands.zones``) that names datums,
        or a composite lower segment's own placement (None: not established at all).
    """

    results: list[CharacteristicResult]
    frames: list[DatumFrameResult]
    zone_frames: dict[int, DatumFrameResult | None]


@dataclass(frozen=True)
class Readings:
    """The deviations read where the located zones lie (:func:`located_readings`).

    Attributes
    ----------
    deviation : (n,) the judged deviation, each located zone's vertices in its frame, mm.
    uncertainty : (n,) its expanded uncertainty, the frame's combined in, mm.
    point_center : the scan points' band centre: scalar or (n,) per vertex, mm.
    point_uncertainty : 0.0, or (n,) the frames' expanded uncertainty per vertex, mm.
    zone_frames : as :attr:`Characteristics.zone_frames`.
    located : the established ones among them.
    """

    deviation: np.ndarray
    uncertainty: np.ndarray
    point_center: float | np.ndarray
    point_uncertainty: float | np.ndarray
    zone_frames: dict[int, DatumFrameResult | None]
    located: dict[int, DatumFrameResult]


@dataclass(frozen=True)
class Measured:
    """The measuring stages' outputs the decisions read (:func:`acceptance_stage`)."""

    nominal: HeldNominal
    deviations: Deviations
    scores: Scores
    readings: Readings


@dataclass(frozen=True)
class Decisions:
    """The tolerance decisions on the readings (:func:`acceptance_stage`).

    Attributes
    ----------
    vertex_stats : area-weighted statistics of the judged deviation.
    point_stats : statistics of the scan points' deviation.
    acceptance : area and region criteria on the whole part.
    zones : each zone's result.
    coverage : the whole part's measured coverage.
    coverage_ceiling_ok : coverage does not exceed scan area / nominal area.
    """

    vertex_stats: DeviationStats
    point_stats: DeviationStats
    acceptance: Acceptance
    zones: list[ZoneResult]
    coverage: Coverage
    coverage_ceiling_ok: bool


def held_nominal(
    reg: Registered,
    fit: DeformResult | None,
    ctx: JudgeContext,
    params: InspectionParams,
    *,
    restrained: bool = False,
) -> HeldNominal:
    """The nominal as the fixture ``fit`` holds it (None: where the rigid alignment put
    it); ``restrained``: the scan ``reg`` is held at its clamps (:class:`HeldNominal`)."""
    V_reg = reg.V if fit is None else fit.V
    corners = ctx.brep_normals
    if corners is not None and fit is not None:  # turned with each triangle the fit bent
        corners = follow_triangles(corners, reg.V, V_reg, reg.F)
    return HeldNominal(
        V=V_reg,
        normals=ctx.prepared.ops.normals if fit is None else vertex_normals(V_reg, reg.F),
        corner_normals=corners,
        basis=ctx.basis if fit is None else fit.basis,
        held=fit is not None or restrained,
        # the free state of a B-rep nominal is scored up to its creases: the face-aware
        # measure (:func:`vertex_deviation`) fits each vertex to the points of its own faces
        # and leaves a crease vertex unscored unless all its faces were seen. A fixtured
        # nominal keeps the band: there the displacement field is least determined
        to_creases=fit is None and ctx.face_id is not None and params.edge_band is None,
    )


def trim_edge_stage(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    tolerance: float,
    normals: np.ndarray,
    trim_edges: str,
    tree: cKDTree,
) -> tuple[EdgeDeviation, SizeEstimate]:
    """The trim-edge deviation of the scan ``P`` (m, 3) along the nominal ``(V, F)`` as the
    fixture holds it, and the size error read from it (:func:`edge_deviation`,
    :func:`size_error`); ``tolerance``: the general half-width, mm; ``normals`` (n, 3);
    ``trim_edges``: ``"crease"`` (a solid) or ``"auto"``; ``tree``: ``cKDTree(P)``."""
    edges = edge_deviation(V, F, P, tolerance, normals=normals, trim_edges=trim_edges, tree=tree)
    return edges, size_error(edges)


def schedule_trim_edges(
    reg: Registered, nominal: HeldNominal, ctx: JudgeContext, fit: DeformResult | None, executor
):
    """:func:`trim_edge_stage` started on ``executor`` (None: made when its result is asked
    for, :func:`~qifreport.metrology.deferred.submit`), or None: no size check.

    The size is read from the trim edges on a fixture that moves the nominal along its
    normals only (GB-CICP) or not at all; the baselines move it along the surface too, and
    so absorb or make up a size error at the rim."""
    if fit is not None and not method_spec(fit.method).moves_along_normals_only:
        return None
    reg.scan_tree  # noqa: B018 - built once, before a child would build its own
    return submit(
        executor,
        trim_edge_stage,
        nominal.V,
        reg.F,
        reg.P,
        ctx.general_half,
        nominal.normals,
        "crease" if ctx.solid else "auto",
        reg.scan_tree,
    )


def deviation_stage(
    reg: Registered,
    nominal: HeldNominal,
    ctx: JudgeContext,
    *,
    free_deviation: tuple[np.ndarray, np.ndarray] | None = None,
    free: Registered | None = None,
) -> Deviations:
    """The scan points' and the vertices' deviations from the held nominal, and the free
    state's for the free-state zones of a held part, with the unscored bands left out
    (:class:`Deviations`).

    Parameters
    ----------
    reg : the seated scan.  nominal : :func:`held_nominal`.  ctx : the judgement's context.
    free_deviation : the free state's (n,) vertex deviation, mm, and its variance, mm^2,
        when it was judged already; None: measured here when needed.
    free : the free state's registration when ``reg`` holds the scan otherwise (restrained).
    """
    F, Pm, face_id = reg.F, reg.P, ctx.face_id
    C, cface, pdev = closest_points(nominal.V, F, Pm)
    if face_id is not None:  # a B-rep nominal: the points' distances to its curved surface
        pdev = surface_distance(nominal.V, F, C, cface, pdev, face_id, nominal.corner_normals, Pm)
    dev, var = vertex_deviation(
        nominal.V,
        F,
        Pm,
        nominal.normals,
        face_id,
        closest=(C, cface, pdev),
        scan_normals=orient_scan_normals(
            Pm, reg.scan_normals, nominal.V, nominal.normals, sheets=reg.sheets
        ),
        residual=pdev if face_id is not None else None,
        tree=reg.scan_tree,
    )
    dev_free = var_free = None
    if nominal.held and any(z.free_state for z in ctx.bands.zones):
        if free_deviation is not None:
            dev_free, var_free = free_deviation[0].copy(), free_deviation[1]
        else:
            dev_free, var_free = free_state_deviation(reg if free is None else free, ctx)
    dev, dev_free, near_crease, excluded = _unscored(dev, dev_free, F, nominal, ctx)
    return Deviations(
        closest=C,
        face=cface,
        point=pdev,
        vertex=dev,
        variance=var,
        free=dev_free,
        free_variance=var_free,
        near_crease=near_crease,
        excluded=excluded,
        beyond_rim=beyond_rim(nominal.V, F, C, cface),
        hygiene=_rim_hygiene(ctx.prepared),
    )


def free_state_deviation(free: Registered, ctx: JudgeContext) -> tuple[np.ndarray, np.ndarray]:
    """The free state's (n,) vertex deviation, mm, and its variance, mm^2: the scan
    ``free`` on the nominal where the rigid alignment put it (:func:`vertex_deviation`)."""
    normals = ctx.prepared.ops.normals
    return vertex_deviation(
        free.V,
        free.F,
        free.P,
        normals,
        ctx.face_id,
        scan_normals=orient_scan_normals(
            free.P, free.scan_normals, free.V, normals, sheets=free.sheets
        ),
        brep_normals=ctx.brep_normals,
        tree=free.scan_tree,
    )


def _unscored(
    dev: np.ndarray,
    dev_free: np.ndarray | None,
    F: np.ndarray,
    nominal: HeldNominal,
    ctx: JudgeContext,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """``dev`` and ``dev_free`` (n,) with the rim band's and the crease band's vertices
    unscored (NaN, copies), the crease band's vertices outside the rim band (each excluded
    vertex is counted once, rim first; a B-rep's free state: the crease vertices not all of
    whose faces were seen), and every excluded vertex, (n,) bool."""
    near_rim = ctx.prepared.near_rim
    near_crease = None if nominal.to_creases else ctx.prepared.near_crease
    if near_crease is not None:
        near_crease = near_crease & ~near_rim
    unscored = near_rim if near_crease is None else near_rim | near_crease
    dev = dev.copy()
    dev[unscored] = np.nan
    if dev_free is not None:
        dev_free = dev_free.copy()
        dev_free[unscored] = np.nan
    if nominal.to_creases:
        near_crease = unseen_neighbour_edges(F, ctx.face_id, dev)
    excluded = near_rim if near_crease is None else near_rim | near_crease
    return dev, dev_free, near_crease, excluded


def _rim_hygiene(prepared: PreparedPart) -> MeshHygiene:
    """The part's mesh hygiene (a copy) with this inspection's rim band."""
    ops, near_rim = prepared.ops, prepared.near_rim
    hygiene = replace(prepared.hygiene)
    hygiene.boundary_band = prepared.rim_band
    hygiene.boundary_excluded_area = float(ops.area[near_rim].sum())
    hygiene.boundary_excluded_fraction = hygiene.boundary_excluded_area / max(
        float(ops.area.sum()), 1e-300
    )
    return hygiene


def scoring_stage(
    reg: Registered,
    nominal: HeldNominal,
    deviations: Deviations,
    ctx: JudgeContext,
    params: InspectionParams,
    timings: dict[str, float],
    model_uncertainty: tuple[np.ndarray, np.ndarray] | None = None,
) -> Scores:
    """The judged deviation field, the scan points that judge the surface with their local
    values, the scan's noise, and the expanded uncertainties (:class:`Scores`).

    Parameters
    ----------
    reg, nominal, deviations : the earlier stages'.  ctx : the judgement's context.
    params : the inspection's parameters (the scanner's stated uncertainty, mm).
    timings : seconds per stage, added to ("scan points", "resolution").
    model_uncertainty : expanded uncertainties the hold adds, mm, (n,) per vertex and (m,)
        per scan point, combined in quadrature with the scanner's; None: none.
    """
    d = deviations
    dev_all, var_all = d.vertex.copy(), d.variance.copy()
    free_v = None
    if d.free is not None:
        free_v = np.isin(
            ctx.bands.governing, [i for i, z in enumerate(ctx.bands.zones) if z.free_state]
        )
        dev_all[free_v] = d.free[free_v]
        var_all[free_v] = d.free_variance[free_v]
    # a STEP nominal's scan points grouped by their B-rep face: a thin wall's two skins are
    # kept apart in the noise estimate and in the points' own values
    plabel = None if ctx.face_id is None else point_faces(d.face, ctx.face_id)
    sys_vertices: float | np.ndarray = params.scanner_uncertainty
    sys_points: float | np.ndarray = params.scanner_uncertainty
    if model_uncertainty is not None:
        sys_vertices = np.hypot(params.scanner_uncertainty, model_uncertainty[0])
        sys_points = np.hypot(params.scanner_uncertainty, model_uncertainty[1])
    t_pts = time.perf_counter()
    samples = scan_samples(
        nominal.V,
        reg.F,
        reg.P,
        d.point,
        d.closest,
        d.face,
        plabel,
        systematic=sys_points,
        tree=reg.scan_tree,
    )
    points_ok = _points_judging(samples, dev_all, free_v, ctx.general_half)
    timings["scan points"] = time.perf_counter() - t_pts
    t_noise = time.perf_counter()
    noise = range_noise(reg.P, labels=plabel)
    timings["resolution"] = time.perf_counter() - t_noise
    return Scores(
        deviation=dev_all,
        variance=var_all,
        free_vertices=free_v,
        labels=plabel,
        samples=samples,
        points_ok=points_ok,
        noise=noise,
        # the expanded uncertainty of each vertex's deviation, for the decision rule
        uncertainty=vertex_uncertainty(var_all, sys_vertices),
        free_uncertainty=None
        if d.free_variance is None
        else vertex_uncertainty(d.free_variance, params.scanner_uncertainty),
    )


def _points_judging(
    samples: ScanSamples, dev_all: np.ndarray, free_v: np.ndarray | None, general_half: float
) -> np.ndarray:
    """(m,) bool: the scan points that judge the surface. A point judges a surface where
    its nearest vertex is scored there (the same crease and rim bands); the free-state
    zones of a held judgement are the free state's (no points)."""
    pvert = samples.vertex
    dev_pts = np.where(pvert >= 0, dev_all[np.maximum(pvert, 0)], np.nan)
    if free_v is not None:
        dev_pts[free_v[np.maximum(pvert, 0)]] = np.nan
    pts_ok = (pvert >= 0) & np.isfinite(dev_pts)
    # a point standing proud beyond the whole part's band is added material (a rib, a
    # boss, flash, a clamp in the scan): judged by its own policy (:mod:`.added`, reported
    # unless --fail-on-added-material), as the vertex measure's robust fit drops it too
    with np.errstate(invalid="ignore"):
        pts_ok &= ~(samples.value > general_half)
    return pts_ok


def characteristics_stage(
    reg: Registered,
    nominal: HeldNominal,
    deviations: Deviations,
    scores: Scores,
    ctx: JudgeContext,
    params: InspectionParams,
    timings: dict[str, float],
) -> Characteristics:
    """The drawing's feature characteristics measured on the judged surface, and the frames
    of the profiles that name datums (Y14.5-2018 11.2.1) or are a composite's lower
    segment (:class:`Characteristics`; nothing without a plan, a B-rep nominal and its
    corner normals). ``timings``: seconds per stage, added to ("characteristics")."""
    plan, face_id, corners = ctx.plan, ctx.face_id, ctx.brep_normals
    if plan is None or face_id is None or corners is None:
        return Characteristics(results=[], frames=[], zone_frames={})
    t_feat = time.perf_counter()
    V, F, d = reg.V, reg.F, deviations
    surf = _measured_surface(
        V,
        F,
        nominal.V,
        face_id,
        corners,
        scores.deviation,
        scores.uncertainty,
        reg.P,
        d.closest,
        d.face,
        d.point,
        scores.labels,
        scores.samples.vertex,
    )
    free_surf = None
    if d.free is not None and scores.free_uncertainty is not None:
        free_surf = _measured_surface(
            V, F, V, face_id, corners, d.free, scores.free_uncertainty, *_no_points()
        )
    cache: dict = {}
    zone_frames: dict[int, DatumFrameResult | None] = {}
    for i, z in enumerate(ctx.bands.zones):
        if z.datums:
            use_free = z.free_state and free_surf is not None
            zone_frames[i] = frame_of(z.datums, plan.datums, free_surf if use_free else surf, cache)
        if z.composite == "lower":  # its own placement, in its frame's orientation
            zone_frames[i] = composite_zone_frame(
                zone_frames.get(i),
                V,
                ctx.prepared.ops.normals,
                scores.deviation - z.center,
                ctx.bands.governing == i,
                z.half_width,
            )
    feats, frames_used = measure_characteristics(
        plan.specs, plan.datums, surf, params.decision_rule, free_surface=free_surf, frames=cache
    )
    timings["characteristics"] = time.perf_counter() - t_feat
    return Characteristics(results=feats or [], frames=frames_used or [], zone_frames=zone_frames)


def located_readings(
    reg: Registered, scores: Scores, characteristics: Characteristics, ctx: JudgeContext
) -> Readings:
    """The judged deviation read in the located zones' frames (:class:`Readings`): each
    vertex governed by a zone whose datum frame is established takes its reading in that
    frame, and the frame's uncertainty with it; the scan points judge against their
    vertex's band moved the other way."""
    zone_frames = characteristics.zone_frames
    located = {i: f for i, f in zone_frames.items() if f is not None and f.established}
    dev_all, U = scores.deviation, scores.uncertainty
    point_center: float | np.ndarray = ctx.bands.center
    point_U: float | np.ndarray = 0.0
    if located:
        V, normals, governing = reg.V, ctx.prepared.ops.normals, ctx.bands.governing
        dev_all, U = dev_all.copy(), U.copy()
        point_center = np.broadcast_to(ctx.bands.center, (len(V),)).astype(np.float64).copy()
        point_U = np.zeros(len(V))
        for i, f in located.items():
            gv = governing == i
            shift = f.normal_shift(V[gv], normals[gv])
            dev_all[gv] = dev_all[gv] + shift
            point_center[gv] -= shift
            point_U[gv] = f.shift_uncertainty(V[gv], normals[gv])
            U[gv] = np.hypot(U[gv], f.shift_uncertainty(V[gv], normals[gv]))
    return Readings(
        deviation=dev_all,
        uncertainty=U,
        point_center=point_center,
        point_uncertainty=point_U,
        zone_frames=zone_frames,
        located=located,
    )


def acceptance_stage(
    reg: Registered, m: Measured, ctx: JudgeContext, params: InspectionParams
) -> Decisions:
    """The area, region and coverage criteria on the whole part and on each zone
    (:class:`Decisions`), from the measuring stages' outputs ``m``.

    Beside a drawing's own tolerances, qifreport's default band is no requirement: it is
    judged where it was measured and its unmeasured patches are reported (each PMI zone
    keeps its rules).
    """
    V, F, bands, area = reg.V, reg.F, ctx.bands, ctx.prepared.ops.area
    deviations, scores, readings = m.deviations, m.scores, m.readings
    general_half, dev_all = ctx.general_half, readings.deviation
    vstats = deviation_statistics(dev_all, weights=area, threshold=general_half)
    pstats = deviation_statistics(deviations.point, threshold=general_half)
    points = _surface_points(
        scores.samples,
        scores.points_ok,
        bands.half_width,
        readings.point_center,
        readings.point_uncertainty,
    )
    acc = _acceptance(V, F, dev_all, bands, area, readings.uncertainty, points, params)
    advisory = any(z.source == "default" for z in bands.zones) and any(
        z.faces is not None for z in bands.zones
    )
    zones = [
        zone_result(i, reg, m, ctx, params, advisory=advisory) for i in range(len(bands.zones))
    ]
    whole = _coverage(
        V, F, dev_all, bands, area, deviations.excluded, params.min_coverage, params, advisory
    )
    # the ceiling catches a deformable fit that met points of other features; a B-rep's free
    # state is rigid and scores each vertex from its own faces' points only, while the
    # scan-area estimate merges the two skins of a wall thinner than a point neighbourhood
    # (NIST CTC 03, 1.9 mm walls: 65 % "scanned" against 94 % scored)
    ceiling = m.nominal.to_creases or coverage_ceiling_ok(
        acc.coverage, reg.scan_area, acc.nominal_area
    )
    return Decisions(
        vertex_stats=vstats,
        point_stats=pstats,
        acceptance=acc,
        zones=zones,
        coverage=whole,
        coverage_ceiling_ok=ceiling,
    )


def zone_result(
    i: int,
    reg: Registered,
    m: Measured,
    ctx: JudgeContext,
    params: InspectionParams,
    *,
    advisory: bool = False,
) -> ZoneResult:
    """The result of zone ``i`` of ``ctx.bands``: its deviation (the free state's for a
    free-state zone of a held part; in its datum frame when located), statistics, area and
    region criteria (on its scan points too, unless the free state's), and measured
    coverage (``advisory``: its gaps reported, not failed, for qifreport's default band
    beside a drawing's zones)."""
    V, F, normals = reg.V, reg.F, ctx.prepared.ops.normals
    deviations, scores, readings = m.deviations, m.scores, m.readings
    z, mask = ctx.bands.zones[i], ctx.bands.tri_masks[i]
    az = zone_vertex_areas(V, F, mask)
    use_free = z.free_state and deviations.free is not None
    dz = np.where(az > 0, deviations.free if use_free else deviations.vertex, np.nan)
    frame = readings.zone_frames.get(i)
    located = i in readings.located
    zU = scores.free_uncertainty if use_free else readings.uncertainty
    zcenter, zpU = z.center, 0.0
    if located:
        shift = frame.normal_shift(V, normals)
        dz = dz + shift
        zcenter = z.center - shift
        zpU = frame.shift_uncertainty(V, normals)
        own_U = scores.free_uncertainty if use_free else scores.uncertainty
        zU = np.hypot(own_U, frame.shift_uncertainty(V, normals))
    points = None
    if not use_free:
        on_zone = scores.points_ok & mask[np.maximum(deviations.face, 0)]
        points = _surface_points(scores.samples, on_zone, z.half_width, zcenter, zpU)
    zacc = _acceptance(V, F[mask], dz, z, az, zU, points, params)
    zstats = deviation_statistics(dz, weights=az, threshold=z.half_width)
    min_coverage = params.min_coverage if z.min_coverage is None else z.min_coverage
    advisory = advisory and z.source == "default"
    zcov = _coverage(V, F[mask], dz, z, az, deviations.excluded, min_coverage, params, advisory)
    return ZoneResult(
        zone=z,
        stats=zstats,
        acceptance=zacc,
        fixtured=m.nominal.held and not use_free,
        deviation=dz,
        coverage=zcov,
        reading=_zone_reading(z, frame, located),
    )


def _acceptance(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    band: BandField | ToleranceZone,
    area: np.ndarray,
    uncertainty: np.ndarray,
    points: SurfacePoints | None,
    params: InspectionParams,
) -> Acceptance:
    """:func:`evaluate` of the surface ``F`` against ``band``'s half-width and centre, by
    the inspection's criteria and decision rule."""
    return evaluate(
        V,
        F,
        dev,
        band.half_width,
        area=area,
        min_fraction=params.min_fraction,
        max_region_area=params.max_region_area,
        center=band.center,
        uncertainty=uncertainty,
        decision_rule=params.decision_rule,
        points=points,
    )


def _coverage(
    V: np.ndarray,
    F: np.ndarray,
    dev: np.ndarray,
    band: BandField | ToleranceZone,
    area: np.ndarray,
    excluded: np.ndarray,
    min_coverage: float,
    params: InspectionParams,
    advisory: bool,
) -> Coverage:
    """:func:`zone_coverage` of the surface ``F`` in ``band`` with the inspection's region
    and gap limits (``advisory``: its gaps reported only)."""
    return zone_coverage(
        V,
        F,
        dev,
        area,
        excluded,
        center=band.center,
        half_width=band.half_width,
        min_coverage=min_coverage,
        max_region_area=params.max_region_area,
        max_gap_area=params.max_gap_area,
        advisory_gaps=advisory,
    )


def _zone_reading(z: ToleranceZone, frame: DatumFrameResult | None, located: bool) -> str:
    """How a zone's deviation was read: best fit, or in its datum frame (``located``: the
    frame established), or a composite lower segment at its own placement."""
    if located:
        labels = "|".join(frame.labels)
        if z.composite == "lower":
            return "composite lower segment: zone placed at its minimax position" + (
                f", orientation in |{labels}|" if frame.labels else ""
            )
        reading = f"datum frame |{labels}|"
        if frame.free:
            reading += " (best fit: " + ", ".join(frame.free) + ")"
        return reading
    if frame is not None:
        return "best fit (datum frame not established: " + "; ".join(frame.problems) + ")"
    return "best fit"


def added_stage(
    reg: Registered,
    deviations: Deviations,
    scores: Scores,
    ctx: JudgeContext,
    params: InspectionParams,
) -> AddedMaterial:
    """The added material (:func:`added_material`): scan points standing proud of the
    nominal beyond the whole part's band; points beyond its rim are not proud of it."""
    pdev_in = np.where(deviations.beyond_rim, np.nan, deviations.point)
    return added_material(
        reg.P,
        pdev_in,
        ctx.general_half,
        reg.scan_area,
        params.max_region_area,
        fail_on=params.fail_on_added_material,
        tree=scores.samples.tree,
    )


def residual_scatter(
    reg: Registered,
    fit: DeformResult | None,
    deviations: Deviations,
    scores: Scores,
    readings: Readings,
    zones: list[ZoneResult],
    *,
    restrained: bool = False,
) -> Resolution:
    """The measurement's resolution against each zone's width (:func:`resolution`): the
    scan's noise and the registration's residual scatter, mm.

    The scatter is the fixture's residual scale, or the rigid fit's; a scan held otherwise
    (``restrained``) has the part's form in its deviations, not a scatter: its scatter is
    about the measured deviation field (each point against its nearest scored vertex's
    value: a conforming panel with 0.23 mm of form the clamps leave was "not established"
    when the form itself was taken for scatter)."""
    if fit is not None:
        residual_scale = fit.scale
    elif restrained:
        pvert = scores.samples.vertex
        near = np.where(pvert >= 0, readings.deviation[np.maximum(pvert, 0)], np.nan)
        about = deviations.point - near
        residual_scale = (
            robust_scale(about[np.isfinite(about)]) if np.isfinite(about).any() else 0.0
        )
    else:
        residual_scale = reg.rigid.scale
    return resolution(
        scores.noise,
        residual_scale,
        [(z.zone.key, float(z.zone.upper - z.zone.lower)) for z in zones],
    )


@dataclass(frozen=True)
class Stages:
    """Every stage's output of one judgement, for :func:`assemble_result`."""

    nominal: HeldNominal
    deviations: Deviations
    scores: Scores
    characteristics: Characteristics
    readings: Readings
    decisions: Decisions
    added: AddedMaterial
    resolution: Resolution
    edges: EdgeDeviation | None = None
    size: SizeEstimate | None = None


def assemble_result(
    reg: Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    ctx: JudgeContext,
    timings: dict[str, float],
    s: Stages,
) -> InspectionResult:
    """The :class:`InspectionResult` of one judgement from its stages' outputs."""
    d, decisions, near_crease = s.deviations, s.decisions, s.deviations.near_crease
    area = ctx.prepared.ops.area
    return InspectionResult(
        V=reg.V,
        F=reg.F,
        V_registered=s.nominal.V,
        P=reg.P,
        deviation=s.readings.deviation,
        deviation_variance=s.scores.variance,
        solid=ctx.solid,
        point_deviation=d.point,
        vertex_stats=decisions.vertex_stats,
        point_stats=decisions.point_stats,
        acceptance=decisions.acceptance,
        rigid=reg.rigid,
        fit=fit,
        params=params,
        scan_area=reg.scan_area,
        coverage_ceiling_ok=decisions.coverage_ceiling_ok,
        timings=timings,
        zones=decisions.zones,
        not_evaluated=list(ctx.not_evaluated or []),
        bands=ctx.bands,
        energy=ctx.energy,
        edge_excluded_area=float(area[near_crease].sum()) if near_crease is not None else 0.0,
        prealign=reg.seat,
        added=s.added,
        hygiene=d.hygiene,
        basis=s.nominal.basis,
        resolution=s.resolution,
        excluded=d.excluded,
        coverage=decisions.coverage,
        edges=s.edges,
        size=s.size,
        characteristics=s.characteristics.results,
        frames=s.characteristics.frames,
    )


def judge(
    reg: Registered,
    fit: DeformResult | None,
    params: InspectionParams,
    timings: dict[str, float],
    ctx: JudgeContext,
    *,
    check_part: bool = True,
    free_deviation: tuple[np.ndarray, np.ndarray] | None = None,
    free: Registered | None = None,
    model_uncertainty: tuple[np.ndarray, np.ndarray] | None = None,
    executor=None,
) -> InspectionResult:
    """Judge the rigidly seated scan ``reg`` against the nominal as the fixture ``fit``
    holds it (``None``: the free state, the nominal where the rigid alignment put it): the
    stages in order, each a public function of this module.

    Parameters
    ----------
    reg : the seated scan.  fit : the virtual fixture's result, or None.
    params : the inspection's parameters.  ctx : what the inspection's judgements share.
    timings : seconds per stage, added to.
    check_part : refuse a scan that is not of this part (:func:`check_same_part`).
    free_deviation : the free state's (n,) vertex deviation, mm, and its variance, mm^2,
        when it was judged already (the zones with the free-state modifier take them
        instead of measuring again).
    free : the free state's registration when ``reg`` holds the scan otherwise
        (restrained): the free-state zones are judged on it.
    model_uncertainty : expanded uncertainties (mm, (n,) per vertex and (m,) per scan point)
        the hold adds, combined in quadrature with the scanner's.
    executor : where the trim-edge measure runs beside the rest (:func:`inspect`'s).
    """
    t0 = time.perf_counter()
    nominal = held_nominal(reg, fit, ctx, params, restrained=free is not None)
    trim = schedule_trim_edges(reg, nominal, ctx, fit, executor)
    deviations = deviation_stage(reg, nominal, ctx, free_deviation=free_deviation, free=free)
    timings["deviation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    scores = scoring_stage(reg, nominal, deviations, ctx, params, timings, model_uncertainty)
    characteristics = characteristics_stage(reg, nominal, deviations, scores, ctx, params, timings)
    readings = located_readings(reg, scores, characteristics, ctx)
    if check_part:
        check_same_part(deviations.point, ctx.general_half, reg.diag, reg.rigid, fit)
    edges = size = None
    if trim is not None:
        t_edges = time.perf_counter()
        edges, size = trim.result()
        timings["edges"] = time.perf_counter() - t_edges
    measured = Measured(nominal, deviations, scores, readings)
    decisions = acceptance_stage(reg, measured, ctx, params)
    added = added_stage(reg, deviations, scores, ctx, params)
    timings["metrology"] = time.perf_counter() - t0
    scatter = residual_scatter(
        reg, fit, deviations, scores, readings, decisions.zones, restrained=free is not None
    )
    stages = Stages(
        nominal,
        deviations,
        scores,
        characteristics,
        readings,
        decisions,
        added,
        scatter,
        edges,
        size,
    )
    return assemble_result(reg, fit, params, ctx, timings, stages)


def _measured_surface(
    V, F, V_reg, face_id, corner_normals, dev, U, P, C, cface, pdev, plabel, pvert
) -> MeasuredSurface:
    """The judged surface for the feature characteristics: the vertices' deviations, and
    the scan points carried back through the fixture's displacement at their closest
    point (:class:`~qifreport.metrology.gdt.measured_surface.MeasuredSurface`)."""
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
