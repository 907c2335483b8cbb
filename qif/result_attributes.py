"""The typed ``Attributes`` of a results document: what QIF has no element for.

RMS, mean, P95/P99/P99.9, tail fractions, in-tolerance area fraction, coverage,
out-of-tolerance regions, the registration and the resampling study are typed
``Attributes`` (``AttributeD1``, ``AttributeI1``, ``AttributeD3``, ``AttributeBool``,
``AttributeStr``) whose names end in the unit (``_mm``, ``_mm2``; fractions are 0..1); see
:mod:`qifreport.qif.writer` for where they go. :func:`measurement_results_attrs` gives the
whole-part ones (of the ``MeasurementResults``); :func:`stats_attrs` and
:func:`acceptance_attrs` are also used per tolerance (each characteristic measurement).
"""

from __future__ import annotations

import numpy as np

from qifreport.metrology.acceptance.added import AddedMaterial
from qifreport.metrology.acceptance.repeatability import Repeatability
from qifreport.metrology.acceptance.statistics import DeviationStats
from qifreport.metrology.inspection import InspectionResult
from qifreport.registration.deformable.methods import method_label

from .xmlkit import Attrs, xml_double

__all__ = [
    "MAX_REGIONS_LISTED",
    "acceptance_attrs",
    "coverage_attrs",
    "measurement_results_attrs",
    "stats_attrs",
]

#: at most this many out-of-tolerance regions are listed per surface (largest first); the
#: count of all regions is always given (``region_count``).
MAX_REGIONS_LISTED = 50


def stats_attrs(a: Attrs, s: DeviationStats, prefix: str = "") -> Attrs:
    """Add the deviation statistics ``s`` (``n_samples``, ``rms_mm``, ... ``area_weighted``).

    Parameters
    ----------
    a : Attrs
        The attributes being built.
    s : DeviationStats
        The statistics.
    prefix : str
        Put before every name (``"scan_points_"``).

    Returns
    -------
    Attrs
        ``a``.
    """
    a.i(f"{prefix}n_samples", s.n)
    for key in ("rms", "mean", "max_abs", "max_pos", "min_neg", "p95", "p99", "p999"):
        a.d(f"{prefix}{key}_mm", getattr(s, key))
    if s.threshold is not None:
        a.d(f"{prefix}threshold_mm", s.threshold)
        for key in ("frac_above", "frac_below", "frac_beyond"):
            a.d(f"{prefix}{key}", getattr(s, key))
    a.b(f"{prefix}area_weighted", s.weighted)
    return a


def acceptance_attrs(a: Attrs, acc, V: np.ndarray, prefix: str = "") -> None:
    """Add the acceptance decision ``acc``: both criteria, coverage, the regions, the reasons.

    Parameters
    ----------
    a : Attrs
        The attributes being built.
    acc : qifreport.metrology.acceptance.criteria.Acceptance
        The decision (whole part or one tolerance).
    V : numpy.ndarray
        The nominal's vertices (the regions' peak locations).
    prefix : str
        Put before every name.
    """
    a.d(f"{prefix}in_tolerance_area_fraction", acc.in_tolerance_fraction)
    a.d(f"{prefix}min_in_tolerance_fraction", acc.min_fraction)
    a.b(f"{prefix}area_criterion_ok", acc.area_ok)
    a.d(f"{prefix}scored_area_mm2", acc.scored_area)
    a.d(f"{prefix}nominal_area_mm2", acc.nominal_area)
    a.d(f"{prefix}coverage", acc.coverage)
    a.i(f"{prefix}region_count", len(acc.regions))
    a.d(f"{prefix}largest_region_area_mm2", acc.largest_region_area)
    a.d(f"{prefix}max_region_area_mm2", acc.max_region_area)
    a.b(f"{prefix}region_criterion_ok", acc.region_ok)
    for k, r in enumerate(acc.regions[:MAX_REGIONS_LISTED], start=1):
        a.d(f"{prefix}region_{k}_area_mm2", r.area)
        a.d(f"{prefix}region_{k}_peak_mm", r.peak)
        a.i(f"{prefix}region_{k}_sign", r.sign)
        a.d3(f"{prefix}region_{k}_centroid_mm", r.centroid)
        a.d3(f"{prefix}region_{k}_peak_location_mm", r.peak_at(V))
        a.s(f"{prefix}region_{k}_sampling", r.sampling)
    for k, reason in enumerate(acc.reasons, start=1):
        a.s(f"{prefix}reason_{k}", reason)
    a.s(f"{prefix}decision_rule", acc.decision_rule)
    a.s(f"{prefix}decision", acc.decision)
    if acc.proven_in is not None:
        a.b(f"{prefix}conformance_proven", acc.proven_in)
        a.b(f"{prefix}nonconformance_proven", acc.proven_out)
        a.d(f"{prefix}expanded_uncertainty_median_mm", acc.uncertainty_mm[0])
        a.d(f"{prefix}expanded_uncertainty_max_mm", acc.uncertainty_mm[1])
    for k, reason in enumerate(acc.uncertain_reasons, start=1):
        a.s(f"{prefix}uncertain_reason_{k}", reason)


def coverage_attrs(a: Attrs, cov, prefix: str = "") -> None:
    """Add whether a surface was measured (``cov``:
    :class:`qifreport.metrology.acceptance.coverage.Coverage`, or None: nothing is added):
    ``measured``,
    its coverage of the surface's own area, the largest unmeasured patch, the rules' limits
    and the reasons it was not measured (``not_measured_reason_k``)."""
    if cov is None:
        return
    a.b(f"{prefix}measured", cov.measured)
    a.d(f"{prefix}surface_area_mm2", cov.area)
    a.d(f"{prefix}surface_coverage", cov.coverage)
    a.d(f"{prefix}min_surface_coverage", cov.min_coverage)
    a.d(f"{prefix}excluded_area_mm2", cov.excluded_area)
    a.d(f"{prefix}unmeasured_area_mm2", cov.unmeasured_area)
    a.d(f"{prefix}largest_unmeasured_patch_mm2", cov.largest_gap_area)
    a.d(f"{prefix}max_unmeasured_patch_mm2", cov.max_gap_area)
    for k, reason in enumerate(cov.reasons, start=1):
        a.s(f"{prefix}not_measured_reason_{k}", reason)


def detectable_attrs(a: Attrs, det, prefix: str = "") -> None:
    """Add what a surface's region criterion can see (``det``:
    :class:`qifreport.metrology.deviation.detectable.Detectable`, or None: nothing is
    added): the probed dent, the share of a region's area read, the largest region that
    proves the criterion and the shallowest dent read beyond the band."""
    if det is None:
        return
    a.d(f"{prefix}detectable_dent_sigma_mm", det.sigma_mm)
    a.d(f"{prefix}detectable_dent_depth_mm", det.smallest_depth_mm)
    a.d(f"{prefix}region_read_share", det.read_share)
    a.d(f"{prefix}region_passing_below_mm2", det.passing_below_mm2)
    a.b(f"{prefix}region_criterion_below_detection", det.below_detection)


def measurement_results_attrs(
    res: InspectionResult, nominal_sha256: str, scan_sha256: str
) -> Attrs:
    """The whole-part attributes of the ``MeasurementResults``.

    In this order: the verdict and why, the deviation statistics and acceptance, the scan
    points' statistics, the added material, the nominal's hygiene, the registration (scan
    area, pose, rigid, virtual fixture), the resampling study, what was not evaluated, sizes,
    timings and the input digests.

    Parameters
    ----------
    res : InspectionResult
        The inspection.
    nominal_sha256, scan_sha256 : str
        Hex SHA-256 digests of the input files.

    Returns
    -------
    Attrs
    """
    ra = Attrs().s("verdict", res.verdict)
    for k, line in enumerate(res.trust_warnings(), start=1):
        ra.s(f"warning_{k}", line)
    for k, line in enumerate(res.drawing_warnings, start=1):
        ra.s(f"drawing_warning_{k}", line)
    for k, line in enumerate(res.decided_by(), start=1):
        ra.s(f"decided_by_{k}", line)
    for k, line in enumerate(res.relaxed_guards(), start=1):
        ra.s(f"relaxed_guard_{k}", line)
    stats_attrs(ra, res.vertex_stats)
    acceptance_attrs(ra, res.acceptance, res.V)
    coverage_attrs(ra, res.coverage)
    detectable_attrs(ra, res.detectable)
    stats_attrs(ra, res.point_stats, prefix="scan_points_")
    if res.added is not None:
        _added_attrs(ra, res.added)
    _hygiene_attrs(ra, res)
    _size_attrs(ra, res)
    _registration_attrs(ra, res)
    if res.repeatability is not None:
        _repeatability_attrs(ra, res.repeatability)
    for k, ne in enumerate(res.not_evaluated, start=1):
        ref = f" #{ne.step_id}" if ne.step_id is not None else ""
        ra.s(f"not_evaluated_{k}", f"{ne.kind} {ne.name}{ref}: {ne.reason}")
    ra.i("nominal_vertices", len(res.V)).i("nominal_triangles", len(res.F))
    ra.i("scan_points", len(res.P))
    if res.stray is not None:
        ra.i("stray_points_left_out", res.stray.count).d("stray_points_share", res.stray.share)
        ra.d("stray_points_limit", res.stray.limit)
    if res.spikes is not None:
        ra.i("spike_points_left_out", int(res.spikes.sum()))
    for stage, sec in res.timings.items():
        ra.d(f"time_{stage}_s", sec)
    ra.s("nominal_sha256", nominal_sha256).s("scan_sha256", scan_sha256)
    return ra


def _size_attrs(ra: Attrs, res: InspectionResult) -> None:
    """The trim edges and the size check (``edge_*``, ``size_*``)."""
    e, s = res.edges, res.size
    if e is not None:
        ra.s("edge_status", e.status).s("edge_mode", e.rim.mode)
        ra.d("edge_seen_fraction", e.seen_fraction).d("edge_tolerance_mm", e.tolerance)
        for k, v in e.statistics().items():
            ra.d(f"edge_{k}_mm", v)
        ra.i("edge_segments_beyond_tolerance", len(e.segments))
    if s is not None:
        ra.s("size_status", s.status).d("size_scale", s.scale).d("size_scale_sd", s.scale_sd)
        ra.d("size_deviation_mm", s.size_deviation).d("size_uncertainty_mm", s.uncertainty)
        ra.d("size_limit_mm", s.limit)
        for k, line in enumerate(s.reasons(), start=1):
            ra.s(f"size_reason_{k}", line)


def _hygiene_attrs(ra: Attrs, res: InspectionResult) -> None:
    """The nominal mesh's defects and the boundary band (``nominal_*``, ``boundary_*``)."""
    h = res.hygiene
    if h is not None:
        ra.i("nominal_boundary_edges", h.boundary_edges)
        ra.i("nominal_non_manifold_edges", h.non_manifold_edges)
        ra.i("nominal_degenerate_faces", h.degenerate_faces)
        ra.i("nominal_duplicate_faces", h.duplicate_faces).i("nominal_components", h.components)
        ra.d("boundary_band_mm", h.boundary_band)
        ra.d("boundary_excluded_area_mm2", h.boundary_excluded_area)


def _registration_attrs(ra: Attrs, res: InspectionResult) -> None:
    """Scan area and coverage ceiling, the pose search, the rigid alignment, the fixture."""
    ra.d("scan_area_mm2", res.scan_area).b("coverage_ceiling_ok", res.coverage_ceiling_ok)
    ra.d("edge_excluded_area_mm2", res.edge_excluded_area).s("bending_energy", res.energy)
    a = res.prealign
    if a is not None:
        ra.s("pose_method", a.method)
        if a.method != "identity":
            ra.d("pose_inlier_fraction", a.inlier_fraction).d("pose_gate_mm", a.gate)
            ra.i("pose_restart_agreement", a.restart_agreement).i("pose_starts", a.n_starts)
            ra.i("pose_descriptor_matches", a.matches).i("pose_ransac_inliers", a.ransac_inliers)
            ra.b("pose_ambiguous", a.ambiguous).d("pose_conditioning", a.conditioning)
    rigid = res.rigid
    ra.d("rigid_rms_mm", rigid.rms).d("rigid_inlier_fraction", rigid.inlier_fraction)
    ra.i("rigid_iterations", rigid.iterations)
    ra.s("rigid_rotation", " ".join(xml_double(v) for v in np.asarray(rigid.R).ravel()))
    ra.d3("rigid_translation_mm", rigid.t)
    seat = res.rim_seat or {}
    if seat.get("rounds"):  # the slide and turn the open rim took back from the rigid fit
        ra.d3("rim_seat_slide_mm", seat["slide_mm"]).d("rim_seat_turn_deg", seat["turn_deg"])
    ra.s("fixture_decision", res.fixture_decision)
    c = res.condition  # the condition judged in, who stated it, what the free state gave
    ra.s("restraint_condition", c.condition).s("restraint_stated_by", c.stated_by)
    if c.statement:
        ra.s("restraint_statement", c.statement)
    ra.b("restraint_applied", res.restraint_applied).s("judged_condition", res.condition_text())
    if res.free_state is not None:
        ra.s("free_state_verdict", res.free_state)
    if res.restraint is not None:
        _restraint_attrs(ra, res.restraint)
    if res.fit is not None:
        fit = res.fit
        ra.s("fit_method", fit.method).s("fit_method_name", method_label(fit.method))
        ra.i("fit_iterations", fit.iterations).i("fit_passes", fit.passes)
        ra.b("fit_fallback", fit.fallback).d("fit_flagged_fraction", fit.flagged_fraction)
        ra.d("fit_residual_scale_mm", fit.scale)
        ra.d("fit_max_displacement_mm", float(np.linalg.norm(fit.e, axis=1).max()))
    if res.fixture_load is not None:
        _fixture_load_attrs(ra, res.fixture_load)


def _fixture_load_attrs(ra: Attrs, load) -> None:
    """What a physical fixture would need to hold the part in the virtual fixture's shape
    (``fixture_load_*``: energy, equivalent force, peak contact, stress against yield, the
    limit and whether it refuses the PASS), or why it is not established."""
    for key, value in load.to_dict().items():
        name = f"fixture_load_{key}"
        if isinstance(value, bool):
            ra.b(name, value)
        elif isinstance(value, int | float):
            ra.d(name, value)
        elif value is not None:
            ra.s(name, value)


def _restraint_attrs(ra: Attrs, r) -> None:
    """The restrained condition (``restraint_*``): the model, each clamp (position,
    directions, free-state offset and where it was read, force and limit), the total."""
    model = r.model_info
    ra.s("restraint_model", str(model.get("model", "")))
    mat = model.get("material")
    ra.s("restraint_material", "not stated" if mat is None else str(mat["name"]))
    if mat is not None:
        ra.d("restraint_material_E_MPa", mat["E_MPa"]).d("restraint_material_nu", mat["nu"])
    if "pad_radius_mm" in model:
        ra.d("restraint_pad_radius_mm", model["pad_radius_mm"])
    ra.s("restraint_clamps_source", str(model.get("clamps_source", "")))
    held = model.get("clamp_set") or {}
    if held:
        ra.s("restraint_clamp_set", str(held["kind"]))
        ra.b("restraint_removes_flex", bool(held["removes_flex"]))
        ra.d("restraint_motion_per_mm_misread", float(held["motion_per_mm_misread"]))
    ra.i("restraint_clamps", len(r.clamps))
    src = r.offset_sources or [""] * len(r.clamps)
    for k, (c, off, f, s) in enumerate(
        zip(r.clamps, r.offsets, r.force, src, strict=True), start=1
    ):
        ra.s(f"clamp_{k}_name", c.name).s(f"clamp_{k}_directions", c.directions)
        ra.d3(f"clamp_{k}_position_mm", c.position)
        ra.d(f"clamp_{k}_free_state_offset_mm", float(off))
        if r.offset_uncertainty is not None and r.offset_uncertainty[k - 1] > 0:
            ra.d(f"clamp_{k}_free_state_offset_U_mm", float(r.offset_uncertainty[k - 1]))
        if s:
            ra.s(f"clamp_{k}_offset_source", s)
        if r.forces_known:
            ra.d(f"clamp_{k}_force_N", float(f))
        if c.max_force is not None:
            ra.d(f"clamp_{k}_force_limit_N", c.max_force)
            ra.b(f"clamp_{k}_over_limit", c.name in r.over_limit)
    if r.forces_known:
        ra.d("restraint_total_force_N", r.total_force)
    ra.b("restraint_not_restrainable", bool(r.over_limit))


def _added_attrs(ra: Attrs, a: AddedMaterial) -> None:
    """The data-referenced pass (added material) as ``added_*`` attributes."""
    ra.d("added_threshold_mm", a.threshold).d("added_mean_signed_mm", a.mean_signed)
    ra.d("added_p99_signed_mm", a.p99_signed).d("added_p999_signed_mm", a.p999_signed)
    ra.d("added_max_signed_mm", a.max_signed).d("added_min_signed_mm", a.min_signed)
    ra.d("added_frac_above", a.frac_above).d("added_frac_below", a.frac_below)
    ra.i("added_region_count", len(a.regions)).d("added_largest_region_mm2", a.largest_area)
    ra.b("added_fail_on", a.fail_on).b("added_passed", a.passed)
    for k, r in enumerate(a.regions[:50], start=1):
        ra.d(f"added_region_{k}_area_mm2", r.area).d(f"added_region_{k}_peak_mm", r.peak)
        ra.d3(f"added_region_{k}_centroid_mm", r.centroid)


def _repeatability_attrs(ra: Attrs, rep: Repeatability) -> None:
    """The resampling study (``--seeds``) as ``repeatability_*`` attributes."""
    ra.i("repeatability_seeds", rep.seeds).d("repeatability_keep_fraction", rep.keep_fraction)
    ra.s("repeatability_reported_run", "full scan")
    ra.i("repeatability_regions", rep.n_regions)
    ra.i("repeatability_persistent_regions", rep.n_persistent)
    ra.d("repeatability_rms_spread_mm", rep.rms_spread)
    ra.d("repeatability_max_spread_mm", rep.max_spread)
    for k, (rms, mx) in enumerate(zip(rep.rms, rep.max_abs, strict=True)):
        run = "full" if k == 0 else f"seed_{k - 1}"
        ra.d(f"repeatability_{run}_rms_mm", rms).d(f"repeatability_{run}_max_abs_mm", mx)
    dropped = [(s.key, d) for s in rep.surfaces for d in s.dropped]
    ra.i("repeatability_dropped_count", len(dropped))
    for k, (key, d) in enumerate(dropped[:MAX_REGIONS_LISTED], start=1):
        ra.s(f"repeatability_dropped_{k}_surface", key)
        ra.d(f"repeatability_dropped_{k}_area_mm2", d.area)
        ra.d(f"repeatability_dropped_{k}_peak_mm", d.peak)
        ra.d3(f"repeatability_dropped_{k}_centroid_mm", d.centroid)
        ra.i(f"repeatability_dropped_{k}_runs_found", d.runs_found)
