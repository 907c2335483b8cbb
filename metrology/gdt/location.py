"""Location of a feature, measured on its points: position (a plane from true position, 2 x
farthest; an axis, the actual mating envelope's size for the MMC/LMC bonus, from its true
position at both ends, diametral; a sphere's centre; a width feature's center plane; a
composite lower segment's pattern placed as a whole), coaxiality and concentricity about
the nominal axis. The per-feature functions have the signature of
:mod:`.geometric`'s; :func:`measure_position_pattern` measures a pattern as a whole.
"""

from __future__ import annotations

import numpy as np

from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    Unmeasurable,
    faces_text,
    fit_uncertainty,
    judge,
    not_measured,
    reading_text,
)
from qifreport.metrology.gdt.composite import free_rotations, minimax_offsets, orientation_only
from qifreport.metrology.gdt.datums import (
    DatumFeature,
    design_text,
    max_unseen_arc,
    unseen_arc,
)
from qifreport.metrology.gdt.form import axis_frame, least_squares_cylinder, least_squares_sphere
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.gdt.measured_surface import FeatureSample, MeasuredSurface
from qifreport.metrology.gdt.projected import projected_axis, projected_height

__all__ = ["measure_coaxiality", "measure_position", "measure_position_pattern"]


def measure_position_pattern(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
) -> CharacteristicResult | None:
    """A position measured on its features together: a composite lower segment's pattern
    (:func:`_pattern_position`), a width feature's center plane (two opposed planes,
    :func:`_center_plane`); None when it is neither (each feature is then measured)."""
    pattern = spec.composite == "lower" or len(members) == 2
    if pattern and any(m.startswith("projected") for m in spec.modifiers):
        return not_measured(spec, "projected tolerance zone on a pattern or a center plane")
    if spec.composite == "lower":
        return _pattern_position(spec, surf, members, frame, rule, sizes)
    if len(members) == 2:
        return _center_plane(spec, surf, members, frame, rule)
    return None


def measure_position(spec, S, sample, feat, frame, sizes, surf, faces):
    """Position of one feature: a sphere's centre, a plane's farthest point, an axis at
    both ends, from true position (diametral; an axis with its MMC/LMC bonus)."""
    if feat.kind in ("sphere", "plane") and projected_height(spec.modifiers) is not None:
        raise Unmeasurable(f"projected tolerance zone on a {feat.kind}: it projects an axis")
    if feat.kind == "sphere":  # a spherical zone about the true centre
        c, _ = least_squares_sphere(S)
        return (
            2 * float(np.linalg.norm(c - feat.origin)),
            None,
            2 * fit_uncertainty(sample.U, 4),
            "centre (least-squares sphere) from true position",
            0.0,
        )
    if feat.kind == "plane":
        d = (S - feat.origin) @ feat.direction
        return (
            2 * float(np.abs(d).max()),
            None,
            float(sample.U[np.argmax(np.abs(d))]) * 2,
            ("surface from true position (2 x farthest)"),
            0.0,
        )
    return _axis_location(spec, S, sample, feat, sizes, faces, position=True, surf=surf)


def measure_coaxiality(spec, S, sample, feat, frame, sizes, surf, faces):
    """Coaxiality or concentricity of a cylinder: its axis about the nominal axis at both
    ends (diametral)."""
    if feat.kind != "cylinder":
        raise Unmeasurable(f"{spec.kind} of a feature that is not a cylinder")
    return _axis_location(spec, S, sample, feat, sizes, faces, position=False)


def _axis_fit(
    S: np.ndarray, feat: DatumFeature
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The least-squares axis of a cylinder's points: origin, unit direction (as the
    nominal's), radius, and its two ends over the measured length (2, 3)."""
    unseen = unseen_arc(S, feat)
    if unseen > max_unseen_arc(feat):
        raise Unmeasurable(
            f"too little of the cylinder's {design_text(feat)} measured: {unseen:.0f} deg "
            f"of it unseen (at most {max_unseen_arc(feat):.0f})"
        )
    o, a, r_ls = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    a = a if a @ feat.direction > 0 else -a
    z = (S - o) @ a
    return o, a, r_ls, o + np.outer([z.min(), z.max()], a)


def _material_bonus(spec, S, o, a, r_ls, feat: DatumFeature, sizes, faces) -> tuple[float, str]:
    """The MMC/LMC bonus of a position from the feature's measured size and its size
    dimension's limits (0 without a material condition), and how it was found."""
    mods = " ".join(spec.modifiers)
    if not ("maximum_material" in mods or "least_material" in mods):
        return 0.0, ""
    size = next((s for s in sizes if set(faces) <= set(s.faces)), None)
    if size is None or size.lower_limit is None or size.upper_limit is None:
        return 0.0, "; no size limits for the material condition: no bonus"
    scale = 2.0 if size.dim_type == "radius" else 1.0
    lo, hi = size.lower_limit * scale, size.upper_limit * scale
    rho = np.linalg.norm((S - o) @ (np.eye(3) - np.outer(a, a)), axis=1)
    mmc = "maximum_material" in mods
    if mmc:  # the mating size about the axis
        actual = 2 * float(rho.min() if feat.internal else rho.max())
        bonus = actual - lo if feat.internal else hi - actual
    else:
        actual = 2 * r_ls
        bonus = hi - actual if feat.internal else actual - lo
    bonus = max(bonus, 0.0)
    cap = ""
    if spec.max_value is not None and spec.tolerance is not None:
        limit = max(spec.max_value - spec.tolerance, 0.0)
        if bonus > limit:
            bonus, cap = limit, f", held to the MAX {spec.max_value:g} mm"
    return bonus, f"; {'MMC' if mmc else 'LMC'} bonus {bonus:.4f} mm (size {actual:.4f} mm{cap})"


def _axis_location(spec, S, sample, feat: DatumFeature, sizes, faces, position: bool, surf=None):
    """An axis from true position at both ends of its measured length, diametral (a
    position with a projected zone: over its height beyond the feature's open end,
    :func:`~qifreport.metrology.gdt.projected.projected_axis`); the axis is the
    least-squares cylinder's (ISO 14405's default association: a tangent mating cylinder
    rests on a few extreme points, and on the partial arc a scan sees of a hole it tilts
    with them), the mating size the largest inscribed (smallest circumscribed) cylinder
    about that axis (never more bonus than the true envelope)."""
    height = projected_height(spec.modifiers) if position else None
    o, a, r_ls, ends = _axis_fit(S, feat)
    E = np.eye(3) - np.outer(feat.direction, feat.direction)
    off = np.linalg.norm((ends - feat.origin) @ E, axis=1)
    value = 2 * float(off.max())
    how = "axis (least squares) from true position at both ends"
    bonus, more, lever = 0.0, "", 1.0
    if position:
        bonus, more = _material_bonus(spec, S, o, a, r_ls, feat, sizes, faces)
    if height is not None:
        zone = (spec.tolerance or 0.0) + bonus
        stations = tuple((ends - feat.origin) @ feat.direction)
        value, how, lever = projected_axis(o, a, feat, surf, faces, height, zone, stations)
    return value, None, 2 * lever * fit_uncertainty(sample.U, 4), how + more, bonus


def _pattern_position(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
    sizes: list[CharacteristicSpec],
) -> CharacteristicResult:
    """The lower segment of a composite position (:mod:`.composite`): each member's
    least-squares axis in the orientation of the segment's frame, the pattern placed as a
    whole (translation, and rotation about what the segment's datums leave free) at the
    position that minimises its worst member's offset beyond its bonus; that member's
    diametral offset reported against the tolerance plus its bonus."""
    fo = None if frame is None else orientation_only(frame)
    rotations = free_rotations(fo)
    Q, P, axes, allow, owner, info = [], [], [], [], [], []
    for j, faces in enumerate(members):
        sample = surf.sample(faces)
        feat = sample.nominal
        why = None
        if feat is None or feat.kind != "cylinder":
            why = "a composite lower segment of a feature that is not a hole or a pin"
        elif len(sample.S) < 8:
            why = f"{len(sample.S)} measured points on a feature"
        try:
            if why is not None:
                raise Unmeasurable(why)
            S = sample.S if fo is None else fo.move(sample.S)
            o, a, r_ls, ends = _axis_fit(S, feat)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            why = str(exc) if len(members) == 1 else f"faces {faces_text(faces)}: {exc}"
            return not_measured(spec, why)
        bonus, more = _material_bonus(spec, S, o, a, r_ls, feat, sizes, faces)
        d = feat.direction
        for e in ends:
            Q.append(e - (feat.origin + ((e - feat.origin) @ d) * d))
            P.append(e)
            axes.append(d)
            allow.append(bonus / 2)
            owner.append(j)
        U = 2 * fit_uncertainty(sample.U, 4)
        if fo is not None:
            U = float(np.hypot(U, 2 * fo.point_uncertainty(S)))
        info.append((bonus, more, U, len(S), sample))
    try:
        _, _, off = minimax_offsets(
            np.array(Q), np.array(P), np.array(axes), rotations, np.array(allow)
        )
    except RuntimeError as exc:
        return not_measured(spec, str(exc))
    owner = np.array(owner)
    values = np.array([2 * float(off[owner == j].max()) for j in range(len(members))])
    margin = values - np.array([b for b, *_ in info])
    k = int(np.argmax(margin))
    bonus, more, U, n, sample = info[k]
    moves = "translation" + (
        ", rotation about " + ", ".join(_axis_name(r) for r in rotations) if len(rotations) else ""
    )
    frame_txt = f"orientation in |{'|'.join(frame.labels)}|" if frame is not None else "no datums"
    res = CharacteristicResult(
        spec,
        value=float(values[k]),
        uncertainty=U,
        reading=(
            f"composite lower segment: axes (least squares) relative to the pattern of "
            f"{len(members)}, placed as a whole at its minimax position ({moves}); "
            f"{frame_txt}; worst: faces {faces_text(members[k])}{more}"
        ),
        n_points=n,
        coverage=sample.coverage,
        bonus=bonus,
    )
    judge(res, rule, None, res.limit, surf.diagonal)
    return res


def _axis_name(v: np.ndarray) -> str:
    i = int(np.argmax(np.abs(v)))
    return "xyz"[i] if abs(v[i]) > 1 - 1e-6 else "(" + ", ".join(f"{x:.3f}" for x in v) + ")"


def _center_plane(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    members: list[np.ndarray],
    frame: DatumFrameResult | None,
    rule: str,
) -> CharacteristicResult | None:
    """Position of a width feature (a slot or a tab: two opposed parallel planes): its
    center plane from true position, ``2 x`` the farthest center-plane point (each side's
    least-squares plane evaluated at every measured point of both); None when the members
    are not such a pair."""
    A, B = surf.nominal(members[0]), surf.nominal(members[1])
    if A is None or B is None or A.kind != "plane" or B.kind != "plane":
        return None
    if A.direction @ B.direction > -0.999:
        return None
    sa, sb = surf.sample(members[0]), surf.sample(members[1])
    if len(sa.S) < 3 or len(sb.S) < 3:
        return None
    Sa, Sb = (sa.S, sb.S) if frame is None else (frame.move(sa.S), frame.move(sb.S))
    n = A.direction
    E = axis_frame(n)
    mid0 = 0.5 * (A.origin + B.origin) @ n  # the nominal center plane's offset

    def side(S: np.ndarray) -> np.ndarray:  # w = a u + b v + c, least squares
        X = S @ E.T
        coef, *_ = np.linalg.lstsq(np.c_[X[:, :2], np.ones(len(X))], X[:, 2], rcond=None)
        return coef

    ca, cb = side(Sa), side(Sb)
    X = np.vstack([Sa, Sb]) @ E.T
    at = np.c_[X[:, :2], np.ones(len(X))]
    centre = 0.5 * (at @ ca + at @ cb) - mid0
    U = np.r_[sa.U, sb.U]
    res = CharacteristicResult(
        spec,
        value=2 * float(np.abs(centre).max()),
        uncertainty=2 * fit_uncertainty(U, 3),
        reading=reading_text(
            "center plane of the width feature from true position (2 x farthest)",
            FeatureSample(np.vstack([Sa, Sb]), U, sa.source, sa.coverage, A),
            frame,
        ),
        n_points=len(U),
        coverage=sa.coverage,
    )
    judge(res, rule, None, res.limit, surf.diagonal)
    return res
