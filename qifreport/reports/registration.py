"""The registration facts of the inspection page (beside the region table).

How the scan was brought onto the nominal: the pose search that started the rigid ICP (how
many starts agreed; ambiguous or sliding poses flagged), the rigid fit (residual RMS, inliers,
rotation and shift) and the virtual fixture (``--method``: residual, iterations, passes,
fallback, flagged fraction, largest displacement and the method's parameters), then the
chain floor and the sizes of the inputs. Lengths in mm, angles in degrees.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qifreport.metrology.inspection import InspectionResult
from qifreport.metrology.restraint.held import SEEN_SOURCES
from qifreport.registration.deformable.methods import method_label, method_spec

from .kit import DASH, Table, finite, fmt_mm, fmt_pct

__all__ = ["registration_table"]


def registration_table(res: InspectionResult, chain_floor: float | None, width: float) -> Table:
    """The registration facts, ``width`` points wide: the pose search, the rigid ICP, the
    virtual fixture (its method, residual, iterations, fallback, displacement and
    parameters), the chain floor (mm; None: "not measured") and the sizes of the inputs.
    Rows that undermine the result (fallback, an ambiguous or sliding pose) are emphasised."""
    rows = _rigid_rows(res)
    if res.restraint is not None:
        rows += _restraint_rows(res)
    elif res.fit is None:
        none = f"none: {res.fixture_decision}" if res.free_state_stands else "none: rigid only"
        rows.append(["Non-rigid (virtual fixture)", none])
    else:
        rows += _fixture_rows(res)
    rows.append(
        ["Chain floor, mm", fmt_mm(chain_floor) if chain_floor is not None else "not measured"]
    )
    rows.append(["Vertices / triangles / points", f"{len(res.V)} / {len(res.F)} / {len(res.P)}"])
    w2 = width * 0.42
    return Table(
        columns=[("", width - w2, "l"), ("", w2, "r")],
        rows=rows,
        title=_title(res),
        head_h=0.0,
        emphasis=[_undermines(res, row[0]) for row in rows],
    )


def _rigid_rows(res: InspectionResult) -> list[list[str]]:
    """The pose search and the rigid fit: residual, inliers, rotation and shift."""
    rg = res.rigid
    R = np.asarray(rg.R, dtype=float)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))
    t = np.asarray(rg.t, dtype=float)
    return [
        ["Pose search: starts agreeing", _pose_text(res.prealign)],
        ["Rigid residual RMS, mm", fmt_mm(rg.rms)],
        ["Rigid inliers, % / iterations", f"{fmt_pct(rg.inlier_fraction)} / {rg.iterations}"],
        ["Rigid rotation, deg / shift, mm", f"{angle:.3f} / {np.linalg.norm(t):.3f}"],
    ]


#: a clamp set's kind on the page
_CLAMP_SET_WORDS = {
    "kinematic": "kinematic (3-2-1): free shape, located",
    "over-constrained": "over-constrained (N-2-1): held shape",
}


def _restraint_rows(res: InspectionResult) -> list[list[str]]:
    """The restrained condition: clamps, material, clamp forces, the clamps over their
    limit."""
    r = res.restraint
    held = f"{len(r.clamps)} clamps"
    unseen = sum(s not in SEEN_SOURCES for s in r.offset_sources)
    if unseen:
        held += f" ({unseen} unseen)"
    mat = r.model_info.get("material")
    rows = [
        [
            "Restrained (ISO 10579) at",
            f"{held}, {'material not stated' if mat is None else mat['name']}",
        ],
        [
            "Clamp force total / largest, N",
            f"{r.total_force:.3g} / {r.force.max():.3g}" if r.forces_known else "not known",
        ],
    ]
    held = r.model_info.get("clamp_set") or {}
    if held:
        rows.append(["Clamp set", _CLAMP_SET_WORDS.get(held["kind"], held["kind"])])
    if r.over_limit:
        rows.append(["Not restrainable at", ", ".join(r.over_limit)])
    return rows


def _fixture_rows(res: InspectionResult) -> list[list[str]]:
    """The virtual fixture: method, residual, iterations, flagged fraction, displacement and
    the method's parameters."""
    fit = res.fit
    fp = fit.params
    rows = [
        [
            "Virtual fixture method",
            method_label(fit.method)
            + ("" if res.free_state is None else f" (free state: {res.free_state})"),
        ],
        ["Non-rigid residual (robust), mm", fmt_mm(fit.scale)],
        [
            "Iterations / passes / fallback",
            f"{fit.iterations} / {fit.passes} / {'YES' if fit.fallback else 'no'}",
        ],
    ]
    spec = method_spec(fit.method)
    if spec.flags_defects:
        rows.append(["Flagged as defect candidates, %", fmt_pct(fit.flagged_fraction)])
    rows.append(
        [
            "Max fixture displacement, mm",
            fmt_mm(fit.max_displacement) if len(fit.e) else DASH,
        ]
    )
    if spec.band_limited:
        rows += [
            [
                "Energy; band limits l1, l2, mm",
                f"{res.params.energy}; {_num(fp.band_limit)}, {_num(fp.band_limit_refit)}",
            ],
            [
                "Start length; coverage radius, mm",
                f"{_num(fp.band_limit_start)}; {_num(fp.coverage_radius)}",
            ],
        ]
    else:
        rows.append([f"{method_label(fit.method)} parameters", _params_text(fp)])
    return rows


def _undermines(res: InspectionResult, label: str) -> bool:
    """Whether the row ``label`` undermines the result (emphasised): the fixture fell back,
    a clamp is over its limit, the pose is ambiguous or sliding."""
    fit = res.fit
    return bool(
        (label == "Iterations / passes / fallback" and fit is not None and fit.fallback)
        or label == "Not restrainable at"
        or (
            label.startswith("Pose")
            and res.prealign is not None
            and (res.prealign.ambiguous or res.prealign.weakly_constrained)
        )
    )


def _title(res: InspectionResult) -> str:
    """The table's title: what brought the scan onto the nominal."""
    fit = res.fit
    return (
        "Registration: rigid ICP + restrained at its clamps"
        if res.restraint is not None
        else f"Registration: rigid ICP + virtual fixture ({method_label(fit.method)})"
        if fit is not None
        else "Registration: rigid ICP only (free state)"
        if not res.free_state_stands
        else f"Registration: rigid ICP, {res.fixture_decision}"
    )


def _num(x) -> str:
    return f"{float(x):.2f}" if finite(x) else DASH


def _params_text(params, limit: int = 4) -> str:
    """The first ``limit`` set scalar fields of a method's parameter dataclass, ``k=v``."""
    if not dataclasses.is_dataclass(params) or isinstance(params, type):
        return "defaults"
    items = []
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, (int, float, np.integer, np.floating)):
            items.append(f"{f.name}={float(v):.3g}")
        elif isinstance(v, str):
            items.append(f"{f.name}={v}")
        if len(items) == limit:
            break
    return ", ".join(items) or "defaults"


def _pose_text(a) -> str:
    """One cell: how the rigid ICP was started (the pose search's confidence in short)."""
    if a is None or a.method == "identity":
        return "none: scan in part frame"
    text = f"{a.restart_agreement}/{a.n_starts}"
    if a.ambiguous:
        text += " AMBIGUOUS"
    elif a.weakly_constrained:
        text += " (slides)"
    return text
