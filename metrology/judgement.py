"""The judgement of one registered scan: deviations, tolerances, characteristics, verdict.

:func:`judge` takes the scan seated on the nominal (:class:`Registered`) and, when the part
is fixtured, the virtual fixture's fit, and measures and decides everything the result
reports (:class:`~qifreport.metrology.results.InspectionResult`): the vertices' and the scan
points' deviations, each tolerance zone's area and region criteria with the uncertainty,
coverage, the trim edges and the size, added material, the drawing's feature
characteristics in their datum frames. :func:`~qifreport.metrology.inspection.inspect`
schedules the judgements (the free state, the fixtured part) and the fixture.
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
from qifreport.registration.deformable import DeformResult, orient_scan_normals
from qifreport.registration.gbcicp import BendingBasis
from qifreport.registration.icp import RigidResult, robust_scale
from qifreport.registration.mesh import vertex_normals
from qifreport.registration.methods import method_spec
from qifreport.registration.prealign import PrealignResult

from .acceptance import coverage_ceiling_ok, evaluate, scan_area
from .added import added_material
from .bands import BandField, NotEvaluated, zone_vertex_areas
from .characteristics import CharacteristicPlan, frame_of, measure_characteristics
from .composite import composite_zone_frame
from .coverage import unseen_neighbour_edges, zone_coverage
from .decision import vertex_uncertainty
from .deferred import submit
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
from .measured_surface import MeasuredSurface
from .params import InspectionParams
from .point_regions import ScanSamples, SurfacePoints, scan_samples
from .prepared import PreparedPart
from .resolution import range_noise, resolution
from .results import InspectionResult, ZoneResult
from .size import SizeEstimate, size_error
from .statistics import deviation_statistics

__all__ = [
    "FAR_DIAGONAL",
    "FAR_HALF_WIDTHS",
    "MAX_FAR_SHARE",
    "Registered",
    "check_same_part",
    "judge",
    "vertex_deviation",
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


def judge(
    reg: Registered,
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
    free: Registered | None = None,
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
    if fit is None or method_spec(fit.method).moves_along_normals_only:
        reg.scan_tree  # noqa: B018 - built once, before a child would build its own
        trim = submit(
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
        tree=reg.scan_tree,
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
                tree=fr.scan_tree,
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
