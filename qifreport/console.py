"""The inspection's text on stdout: the summary ``qifreport NOMINAL SCAN`` prints.

:func:`summary` is the verdict and the numbers it rests on, a few lines per criterion and
per toleranced surface; :func:`fixture_text` says how the virtual fixture was made (or why
none was), :func:`restraint_text` the restrained condition (clamps, model, forces), and
:func:`decision_text` the decision rule and the uncertainty it weighed. The job itself, and
the files it writes, are :mod:`qifreport.pipeline`'s.
"""

from __future__ import annotations

from qifreport.metrology.acceptance.criteria import Acceptance
from qifreport.metrology.inspection import (
    FREE_STATE_CONFORMS,
    FREE_STATE_LOCAL_DEFECTS,
    FREE_STATE_UNCERTAIN,
    InspectionResult,
)
from qifreport.registration.deformable.methods import method_label
from qifreport.registration.restraint.restrained import Restraint

__all__ = ["decision_text", "fixture_text", "restraint_text", "summary"]


def decision_text(a: Acceptance) -> str:
    """The decision rule of an :class:`~qifreport.metrology.acceptance.criteria.Acceptance` and the
    expanded uncertainty it weighed, for the reports."""
    if a.proven_in is None:
        return f"{a.decision_rule} (no uncertainty weighed)"
    med, top = a.uncertainty_mm
    return (
        f"{a.decision_rule}, expanded uncertainty U (k = 2) median {med:.4f} mm, max {top:.4f} mm"
    )


def summary(res: InspectionResult) -> str:
    """A short human-readable summary of the inspection."""
    a, s = res.acceptance, res.vertex_stats
    lines = [
        f"verdict: {res.verdict}",
        f"condition: {res.condition_text()}",
        f"restraint stated: {res.condition.statement}",
        f"registration: {fixture_text(res)}",
        *([] if res.fixture_load is None else [res.fixture_load.describe()]),
        f"deviation (area-weighted, {s.n} scored vertices): RMS {s.rms:.3f}  max {s.max_abs:.3f}"
        f"  P95 {s.p95:.3f}  P99.9 {s.p999:.3f}  mean {s.mean:+.3f} mm",
        f"area criterion: {100 * a.in_tolerance_fraction:.2f} % in tolerance "
        f"(>= {100 * a.min_fraction:.0f} %) {'ok' if a.area_ok else 'FAILED'}",
        f"region criterion: largest out-of-tolerance region {a.largest_region_area:.1f} mm^2 "
        f"(<= {a.max_region_area:g} mm^2) {'ok' if a.region_ok else 'FAILED'}; "
        f"{len(a.regions)} region(s)",
        f"decision rule: {decision_text(a)}",
        f"instrument (uncertainty budgets): {res.params.scanner.label}",
        f"coverage: {100 * a.coverage:.1f} % of the nominal area scored"
        + (
            f" ({res.edge_excluded_area:.0f} mm^2 along sharp creases not scored)"
            if res.edge_excluded_area > 0
            else ""
        ),
    ]
    if res.prealign is not None and res.prealign.method != "identity":
        lines.append(res.prealign.summary())
    for r in a.regions[:5]:
        c = r.centroid
        lines.append(
            f"  region {r.area:7.1f} mm^2  peak {r.peak:+.3f} mm"
            f"  at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f})"
        )
    lines.append("tolerances (each toleranced surface on its own faces):")
    for z in res.zones:
        za, zs = z.acceptance, z.stats
        cov = "" if z.coverage is None else f", {100 * z.coverage.coverage:.0f} % scored"
        lines.append(
            f"  {z.zone.key:8s} {z.status:12s}  {z.zone.describe()}: "
            f"{100 * za.in_tolerance_fraction:.1f} % in band, largest region "
            f"{za.largest_region_area:.1f} mm^2, max |dev| {zs.max_abs:.3f} mm{cov}"
            + ("" if z.fixtured else " (free state)")
            + ("" if z.judged else " (not from the drawing: reported, not judged)")
        )
    if res.not_evaluated:
        lines.append(
            f"  {len(res.not_evaluated)} PMI item(s) listed, not scored "
            "(see the JSON 'not_evaluated')"
        )
    if res.characteristics:
        lines.append("feature characteristics (the drawing's form, orientation, location, size):")
        for c in res.characteristics[:12]:
            sp = c.spec
            kind = sp.kind if sp.kind != "dimension" else sp.dim_type or "dimension"
            frame = f" |{'|'.join(sp.datums)}|" if sp.datums else ""
            value = "-" if c.value is None else f"{c.value:.4f}"
            tail = c.reason if c.status in ("NOT_MEASURED", "FAIL") else f"limit {sp.limits_text()}"
            lines.append(f"  {sp.key:8s} {c.status:13s} {kind}{frame} {value}: {tail}")
        if len(res.characteristics) > 12:
            lines.append(f"  ... {len(res.characteristics) - 12} more (see the JSON/QIF)")
    h = res.hygiene
    if h is not None and (
        h.boundary_edges or h.non_manifold_edges or h.degenerate_faces or h.duplicate_faces
    ):
        lines.append(f"nominal: {h.describe()}")
    if res.added is not None:
        a = res.added
        lines.append(
            f"added material (data-referenced, scan points): P99.9 signed "
            f"{a.p999_signed:+.3f} mm, {100 * a.frac_above:.3f} % beyond "
            f"+{a.threshold:g} mm; {a.describe()}"
            + ("" if a.passed else " FAILED")
            + ("" if a.fail_on or not a.found else " (reported, not judged)")
        )
    if res.repeatability is not None:
        lines.append(res.repeatability.describe())
    if res.edges is not None and res.edges.status == "measured":
        lines.append(res.edges.reasons()[0])
    if res.size is not None:
        lines += res.size.reasons()[:1]
    lines += [f"warning: {w}" for w in res.trust_warnings()]
    lines += [f"warning: drawing: {w}" for w in res.drawing_warnings]
    lines += [f"not measured: {w}" for w in res.not_measured()]
    lines += [f"note: {w}" for w in res.coverage_notes()]
    lines += [f"relaxed guard: {w}" for w in res.relaxed_guards()]
    return "\n".join(lines)


def restraint_text(r: Restraint) -> str:
    """The restrained condition in one paragraph: the clamps, the model, the forces."""
    m = r.model_info
    mat = m.get("material")
    material = (
        "material not stated: forces not known"
        if mat is None
        else f"{mat['name']}, E {mat['E_MPa']:g} MPa, nu {mat['nu']:g}"
    )
    if mat is not None and str(m.get("material_source") or "").startswith("drawing"):
        material += f", from the {m['material_source']}"
    g = m.get("gravity")
    weight = "" if g is None else f", under its own weight along ({g[0]:g}, {g[1]:g}, {g[2]:g})"
    lines = [
        f"restrained (ISO 10579): held at {len(r.clamps)} clamps ({m.get('clamps_source', '')}) "
        f"by the part's elastic model ({m.get('model', '')}; {material}){weight}, judged as "
        "held (no virtual fixture)"
    ]
    held = m.get("clamp_set") or {}
    if held.get("statement"):
        lines.append(f"  clamp set: {held['statement']}")
    src = r.offset_sources or [""] * len(r.clamps)
    unc = r.offset_uncertainty if r.offset_uncertainty is not None else [0.0] * len(r.clamps)
    for c, off, f, s, u in zip(r.clamps, r.offsets, r.force, src, unc, strict=True):
        force = f"{f:.3g} N" if r.forces_known else "force not known"
        limit = "" if c.max_force is None else f" (limit {c.max_force:g} N)"
        over = " OVER LIMIT" if c.name in r.over_limit else ""
        seen = "" if s in ("", "scan") else f" [{s}]"
        lines.append(
            f"  clamp {c.name:<6} {c.directions:<3} offset {off:+.3f}"
            f"{f' +/- {u:.3f}' if u > 0 else ''} mm{seen}  "
            f"{force}{limit}{over}"
        )
    if r.forces_known:
        lines.append(f"  total clamp force {r.total_force:.3g} N")
    return "\n".join(lines)


def fixture_text(res: InspectionResult) -> str:
    """How the virtual fixture was made, for the summary."""
    if res.restraint is not None:
        return restraint_text(res.restraint)
    if res.fit is None:
        if res.fixture_decision == FREE_STATE_UNCERTAIN:
            return (
                f"rigid ICP (robust residual {res.rigid.scale:.3f} mm); nothing of the free "
                "state is proven out of tolerance (it lies on a zone limit within the "
                "measurement uncertainty), so no virtual fixture was applied"
            )
        if res.fixture_decision == FREE_STATE_CONFORMS:
            return (
                f"rigid ICP (robust residual {res.rigid.scale:.3f} mm); the free state "
                "conforms, so no virtual fixture was needed (ISO 10579 restraint brings a "
                "part to its drawing shape; this one is there without it)"
            )
        if res.fixture_decision == FREE_STATE_LOCAL_DEFECTS:
            return (
                f"rigid ICP (robust residual {res.rigid.scale:.3f} mm); the free state "
                "conforms on the nominal's vertices and fails only on regions of the scan "
                "points narrower than the mesh: no fixture bends such a defect out of a "
                "part, so none was applied"
            )
        return "rigid ICP only: judged in the free state (no virtual fixture)"
    fit = res.fit
    text = (
        f"rigid ICP + virtual fixture {method_label(fit.method)} ({fit.iterations} "
        f"iterations, robust residual {fit.scale:.3f} mm, "
        f"largest displacement {fit.max_displacement:.3f} mm)"
    )
    if res.free_state is not None:
        text += f"; free state judged first: {res.free_state}"
    return text
