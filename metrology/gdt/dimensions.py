"""Dimensions measured on the part's surface: the geometric quantity of the faces (a
cylinder's or sphere's diameter or radius, a cone's angle and end diameters, the distance
between opposed planes or between features, a drilled hole's depth, an angle) that the
nominal mesh gives as the drawing's nominal, then measured the same way: ``actual = nominal
+ (measured - nominal mesh)``; a quantity whose nominal disagrees with the drawing is not
measured (never guessed). A basic dimension without a value is reported (status
``BASIC``); one that is a side of a datum target area is applied as given.

Lengths mm, angles degrees.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from qifreport.metrology.acceptance.budget import UncertaintyBudget
from qifreport.metrology.gdt.budgets import sampling_budget
from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    Unmeasurable,
    faces_text,
    fit_uncertainty,
    implausible,
    judge,
    not_measured,
)
from qifreport.metrology.gdt.datums import DatumFeature, design_text, max_unseen_arc, unseen_arc
from qifreport.metrology.gdt.form import (
    cone_draws,
    least_squares_cone,
    least_squares_cylinder,
    least_squares_sphere,
)
from qifreport.metrology.gdt.frames import TargetSpec
from qifreport.metrology.gdt.measured_surface import FeatureSample, MeasuredSurface
from qifreport.registration.arrays import unique_sorted

__all__ = ["measure_dimension"]

#: a drawing's nominal and the faces' own quantity agree within this share (or 0.02 mm)
_NOMINAL_AGREEMENT = 0.01


def _cylinder_values(surf: MeasuredSurface, faces) -> tuple[dict, dict, np.ndarray] | None:
    """Nominal and measured diameter/radius of one cylindrical (or spherical) feature, and
    its ``U`` values; None when it is neither or too little of it was measured."""
    sample = surf.sample(faces)
    feat = sample.nominal
    if feat is None or feat.kind == "plane" or len(sample.S) < 8:
        return None
    if feat.kind == "cone":
        return _cone_values(surf, faces, sample, feat)[0]
    if feat.kind == "sphere":
        r = least_squares_sphere(sample.S)[1]
        return (
            {"diameter": 2 * feat.radius, "radius": feat.radius},
            {"diameter": 2 * r, "radius": r},
            sample.U,
        )
    unseen = unseen_arc(sample.S, feat)
    if unseen > max_unseen_arc(feat):  # a radius from a narrow arc: not a reading
        raise Unmeasurable(
            f"faces {faces_text(faces)}: {unseen:.0f} deg of the cylinder's "
            f"{design_text(feat)} unseen (at most {max_unseen_arc(feat):.0f})"
        )
    r = least_squares_cylinder(sample.S, feat.origin, feat.direction, feat.radius)[2]
    nom = {"diameter": 2 * feat.radius, "radius": feat.radius}
    meas = {"diameter": 2 * r, "radius": r}
    # the same fit on the raw scan points: their difference is a systematic part of U
    on = surf.points_on(faces)
    if sample.source == "vertices" and on.sum() >= 8:
        r_pts = least_squares_cylinder(surf.P[on], feat.origin, feat.direction, feat.radius)[2]
        meas["_systematic_radius"] = abs(r_pts - r)
    return nom, meas, sample.U


def _cone_values(
    surf: MeasuredSurface,
    faces,
    sample: FeatureSample,
    feat: DatumFeature,
    gauge: float | None = None,
) -> list[tuple[dict, dict, np.ndarray]]:
    """A cone's included angle (degrees) and its diameters at the model's two ends (a
    countersink's at the face it opens on, a taper's at either end), nominal and measured:
    the least-squares cone's, in the same planes across the nominal axis; each measured
    value's expanded uncertainty from the fit's own spread (``_U_<key>``: a cone seen on a
    few dozen points of a narrow band is poorly known). Widest end first; then, with a
    ``gauge`` diameter (mm) between the ends, the measured diameter in the plane where the
    model's is ``gauge`` (a basic diameter locating a taper's gauge section)."""
    X = surf.V[unique_sorted(surf.F[surf.triangles_on(faces)])]
    z = (X - feat.origin) @ feat.direction
    draws = cone_draws(sample.S, feat.origin, feat.direction, feat.half_angle)
    out = []
    sections = [float(z.max()), float(z.min())]
    if gauge is not None:
        z_gauge = 0.5 * gauge / math.tan(feat.half_angle)
        if z.min() < z_gauge < z.max():
            sections.append(z_gauge)
    for z_end in sections:
        plane = feat.origin + z_end * feat.direction
        d = []
        for apex, axis, half in draws:
            t = float((plane - apex) @ feat.direction / (axis @ feat.direction))
            d.append(2 * t * np.tan(half))
        ang = [np.degrees(2 * h) for _, _, h in draws]
        d_nom = 2 * z_end * np.tan(feat.half_angle)
        out.append(
            (
                {"diameter": d_nom, "radius": d_nom / 2, "angle": np.degrees(2 * feat.half_angle)},
                {
                    "diameter": d[0],
                    "radius": d[0] / 2,
                    "angle": ang[0],
                    "_U_diameter": 2 * float(np.std(d[1:])),
                    "_U_radius": float(np.std(d[1:])),
                    "_U_angle": 2 * float(np.std(ang[1:])),
                },
                sample.U,
            )
        )
    return out


def _plane_pair_values(surf: MeasuredSurface, fa, fb) -> tuple[dict, dict, np.ndarray] | None:
    """Nominal and measured distance between two parallel planar features."""
    A, B = surf.nominal(fa), surf.nominal(fb)
    if A is None or B is None or A.kind != "plane" or B.kind != "plane":
        return None
    if abs(A.direction @ B.direction) < 0.999:
        return None
    ga, gb = surf.sample(fa), surf.sample(fb)
    if len(ga.S) < 3 or len(gb.S) < 3:
        return None
    n = A.direction
    nom = {"distance": abs(float((B.origin - A.origin) @ n))}
    meas = {"distance": abs(float((gb.S.mean(axis=0) - ga.S.mean(axis=0)) @ n))}
    return nom, meas, np.r_[ga.U, gb.U]


def _size_candidates(
    surf: MeasuredSurface, faces, pairs: bool, gauge: float | None = None
) -> list[tuple[dict, dict, np.ndarray]]:
    """The measurable sizes of a dimension's faces: each cylindrical (spherical) member's
    diameter and radius (a cone's at its ends, and at the ``gauge`` diameter's section,
    :func:`_cone_values`), or with ``pairs`` the distances (and angles) between every two
    members (parallel planes, a plane and an axis, two axes)."""
    members = surf.features(faces)
    if not pairs:
        out = []
        for m in members:
            feat = surf.nominal(m)
            if feat is not None and feat.kind == "cone":
                sample = surf.sample(m)
                if len(sample.S) >= 8:
                    out += _cone_values(surf, m, sample, feat, gauge)
                continue
            c = _cylinder_values(surf, m)
            if c is not None:
                out.append(c)
        return out
    out = []
    for i in range(len(members)):
        for j in range(i + 1, len(members)):
            v = _plane_pair_values(surf, members[i], members[j]) or _pair(
                surf, members[i], members[j]
            )
            if v is not None:
                out.append(v)
    return out


def _between(surf: MeasuredSurface, fa, fb) -> list[tuple[dict, dict, np.ndarray]]:
    """Distance and angle between two features (planes or axes), for each pair of their
    members; and a drilled hole's depth when one side is the plane it opens on and the
    other its cylinder and drill point (:func:`_depth_values`)."""
    out = []
    members_a, members_b = surf.features(fa), surf.features(fb)
    for ma in members_a:
        for mb in members_b:
            v = _pair(surf, ma, mb)
            if v is not None:
                out.append(v)
    for planes, hole in ((members_a, members_b), (members_b, members_a)):
        for m in planes:
            v = _depth_values(surf, m, hole)
            if v is not None:
                out.append(v)
    return out


def _depth_values(
    surf: MeasuredSurface, plane_faces, hole: list[np.ndarray]
) -> tuple[dict, dict, np.ndarray] | None:
    """A drilled hole's depth (mm): from the plane it opens on (``plane_faces``) along its
    axis to the circle where its cylinder meets its drill point (a coaxial cone), nominal
    and measured (the points' mean plane across the nominal normal; the least-squares
    cylinder's radius on the least-squares cone); None when ``hole`` is not one cylinder
    and one coaxial cone, or the plane is not across their axis."""
    P = surf.nominal(plane_faces)
    feats = [(m, surf.nominal(m)) for m in hole]
    cyl = [(m, f) for m, f in feats if f is not None and f.kind == "cylinder"]
    cone = [(m, f) for m, f in feats if f is not None and f.kind == "cone"]
    if P is None or P.kind != "plane" or len(cyl) != 1 or len(cone) != 1:
        return None
    (mc, C), (mk, K) = cyl[0], cone[0]
    if abs(C.direction @ K.direction) < 0.999 or abs(P.direction @ C.direction) < 0.999:
        return None
    off = K.origin - C.origin
    if np.linalg.norm(off - (off @ C.direction) * C.direction) > 1e-3 * max(C.radius, 1.0):
        return None
    sp, sc, sk = surf.sample(plane_faces), surf.sample(mc), surf.sample(mk)
    if len(sp.S) < 3 or len(sc.S) < 8 or len(sk.S) < 7:
        return None
    n = P.direction

    def depth(plane_point, r, apex, axis, half) -> float:
        edge = apex + axis * (r / math.tan(half))
        return abs(float((edge - plane_point) @ n))

    nom = {"distance": depth(P.origin, C.radius, K.origin, K.direction, K.half_angle)}
    r = least_squares_cylinder(sc.S, C.origin, C.direction, C.radius)[2]
    apex, axis, half = least_squares_cone(sk.S, K.origin, K.direction, K.half_angle)
    meas = {"distance": depth(sp.S.mean(axis=0), r, apex, axis, half)}
    return nom, meas, np.r_[sp.U, sc.U, sk.U]


def _pair(surf: MeasuredSurface, fa, fb) -> tuple[dict, dict, np.ndarray] | None:
    sa, sb = surf.sample(fa), surf.sample(fb)
    A, B = sa.nominal, sb.nominal
    if A is None or B is None or len(sa.S) < 8 or len(sb.S) < 8:
        return None
    if "cone" in (A.kind, B.kind):  # a drill point, a countersink: see _depth_values
        return None

    def fitted(sample: FeatureSample, feat: DatumFeature, nominal: bool):
        if feat.kind == "plane":
            if nominal:  # the nominal plane under the measured points
                P = sample.S - np.outer((sample.S - feat.origin) @ feat.direction, feat.direction)
                return P.mean(axis=0), feat.direction
            return sample.S.mean(axis=0), feat.direction
        if nominal:
            z = (sample.S - feat.origin) @ feat.direction
            return feat.origin + feat.direction * z.mean(), feat.direction
        o, a, _ = least_squares_cylinder(sample.S, feat.origin, feat.direction, feat.radius)
        z = (sample.S - o) @ a
        return o + a * z.mean(), a if a @ feat.direction > 0 else -a

    out: list[dict] = []
    for nominal in (True, False):
        (pa, da), (pb, db) = fitted(sa, A, nominal), fitted(sb, B, nominal)
        q: dict[str, float] = {}
        ang = math.degrees(math.acos(float(np.clip(abs(da @ db), 0.0, 1.0))))
        q["angle"] = ang
        q["angle_supplement"] = 180.0 - ang
        d = pb - pa
        if A.kind == "plane" and (B.kind != "plane" or abs(A.direction @ B.direction) > 0.999):
            q["distance"] = abs(float(d @ A.direction))
        elif B.kind == "plane":
            q["distance"] = abs(float(d @ B.direction))
        elif abs(A.direction @ B.direction) > 0.999:  # parallel axes: across them
            E = np.eye(3) - np.outer(A.direction, A.direction)
            q["distance"] = float(np.linalg.norm(E @ d))
        else:
            q["distance"] = float(np.linalg.norm(d))
        out.append(q)
    return out[0], out[1], np.r_[sa.U, sb.U]


def _reported(
    spec: CharacteristicSpec, cands: list, key: str, what: str, diagonal: float
) -> CharacteristicResult:
    """A dimension the drawing gives no value (and no limits): the size its faces give,
    measured and reported (status BASIC: a reference, not judged) when they give one
    quantity of its kind, not measured when they give none or several or an implausible
    one for a part ``diagonal`` mm across."""
    found = [(nom, meas, U_pts) for nom, meas, U_pts in cands if key in nom]
    values = sorted({round(nom[key], 6) for nom, _, _ in found})
    if len(values) != 1:
        return not_measured(
            spec,
            "the drawing gives no value and its faces give "
            + ("no " + key if not values else f"several ({', '.join(f'{v:g}' for v in values)})"),
        )
    nom, meas, U_pts = max(found, key=lambda f: abs(f[1][key] - f[0][key]))
    U, budget = _own_uncertainty(spec, meas, key, U_pts)
    res = CharacteristicResult(
        spec,
        value=float(meas[key]),
        uncertainty=U,
        budget=budget,
        reading=f"{key} {what}; the drawing gives no value (nominal {nom[key]:.4g} on the "
        "model): reported, not judged",
        n_points=len(U_pts),
    )
    return _basic(res, diagonal)


def _target_area_size(
    spec: CharacteristicSpec, surf: MeasuredSurface, areas: Sequence[tuple[str, TargetSpec]]
) -> CharacteristicResult | None:
    """A basic dimension between two curves of one face that is a side (or the diameter)
    of a datum target area on that face: theoretically exact, the extent of the simulator
    that establishes the datum, applied as given (QIF ``BASIC_OR_TED``; nothing of the part
    to measure); None when it is not one."""
    if spec.nominal is None or spec.origin_faces is None:
        return None
    for label, tg in areas:
        faces = tg.faces
        if not len(faces):
            v = tg.area_vertices(surf)
            tri = np.isin(surf.F, v).any(axis=1)
            faces = unique_sorted(surf.face_id[tri])
        if not np.isin(spec.origin_faces, faces).any():
            continue
        sides = {"diameter": tg.diameter, "length": tg.length, "width": tg.width}
        for side, size in sides.items():
            if size is not None and abs(size - spec.nominal) <= 1e-3 * max(size, 1.0):
                return CharacteristicResult(
                    spec,
                    status="BASIC",
                    reading=(
                        f"the {side} of datum target area {tg.name} ({tg.size_text()}): "
                        f"theoretically exact, the extent of the simulator establishing datum "
                        f"{label}, applied as given; nothing of the part to measure"
                    ),
                )
    return None


def measure_dimension(
    spec: CharacteristicSpec,
    surf: MeasuredSurface,
    rule: str,
    areas: Sequence[tuple[str, TargetSpec]] = (),
) -> CharacteristicResult:
    """Dimension ``spec`` measured on ``surf`` and judged by ``rule`` (module docstring);
    ``areas``: the part's datum target areas (label, target), whose sides a basic
    dimension may give. A physically implausible reading (a size farther from its nominal
    than the part's bounding-box diagonal, or with a wider uncertainty; a size ``<= 0``; an
    angle outside 0..180 deg; a non-finite number:
    :func:`~qifreport.metrology.gdt.characteristic_types.implausible`) is not measured, the
    reason naming the number and the bound, never judged or reported."""
    early = _not_measurable(spec, surf, areas)
    if early is not None:
        return early
    if spec.origin_faces is not None and spec.target_faces is not None:
        cands = _between(surf, spec.origin_faces, spec.target_faces)
        what = "between its origin and target features"
    else:
        gauge = spec.nominal if spec.dim_type == "diameter" else None
        cands = _size_candidates(surf, spec.faces, pairs=False, gauge=gauge)
        what = "of its feature"
    if spec.unit == "deg":
        keys = ["angle", "angle_supplement"]
    elif spec.dim_type == "radius":
        keys = ["radius", "distance"]
    else:
        keys = ["diameter", "distance", "radius"]
    if spec.nominal is None:
        natural = {"diameter": "diameter", "radius": "radius"}.get(spec.dim_type, "distance")
        quantity = "angle" if spec.unit == "deg" else natural
        return _reported(spec, cands, quantity, what, surf.diagonal)
    tol = max(_NOMINAL_AGREEMENT * abs(spec.nominal), 0.02 if spec.unit == "mm" else 0.1)
    found = _matching(spec, cands, keys, tol)
    if not found and spec.origin_faces is None:  # not its members' sizes: between them
        cands = cands + _size_candidates(surf, spec.faces, pairs=True)
        found = _matching(spec, cands, keys, tol)
    if not found:
        seen = sorted({f"{k} {nom[k]:.4g}" for nom, _, _ in cands for k in keys if k in nom})
        why = (
            f"the faces' geometry ({', '.join(seen) or 'no plane pair or cylinder measured'}) "
            f"does not give the drawing's nominal {spec.nominal:g} {spec.unit}"
        )
        if spec.drawn:
            why = (
                "its origin and target are curves drawn on faces "
                f"{faces_text(spec.origin_faces)} and {faces_text(spec.target_faces)} "
                f"(supplemental geometry), not the faces themselves, and {why}"
            )
        return not_measured(spec, why)
    return _judged(spec, found, what, rule, surf.diagonal)


def _not_measurable(
    spec: CharacteristicSpec, surf: MeasuredSurface, areas: Sequence[tuple[str, TargetSpec]]
) -> CharacteristicResult | None:
    """The result of a dimension the surface cannot measure (a thread's, one without its
    nominal, one without faces or between curves of the same faces; a side of a datum
    target area applied as given), or None when it is measured."""
    if spec.thread:
        return not_measured(
            spec,
            f"a thread's dimension, given on supplemental geometry {spec.thread}: the model "
            "carries the thread as its tap-drill hole (a cosmetic thread), so its size and "
            "depth are no surface a scan measures (a thread gauge does)",
        )
    if spec.nominal is None and (spec.lower_limit is not None or spec.upper_limit is not None):
        return not_measured(spec, "the dimension's nominal could not be established")
    if spec.origin_faces is not None and spec.target_faces is not None:
        if not len(spec.origin_faces) or not len(spec.target_faces):
            return not_measured(spec, "a feature of the location has no face on the part")
        if set(spec.origin_faces) == set(spec.target_faces):
            applied = _target_area_size(spec, surf, areas)
            if applied is not None:
                return applied
            return not_measured(
                spec,
                "its origin and target are both on face(s) "
                f"{faces_text(spec.origin_faces)} (curves of a face, not surfaces): not measured "
                "from the scanned surface",
            )
    elif not len(spec.faces):
        return not_measured(spec, "no B-rep face of the part is associated")
    return None


def _matching(spec: CharacteristicSpec, cands: list, keys: list[str], tol: float) -> list:
    """``(value, key, measured, U)`` of the candidates whose nominal quantity (the first of
    ``keys`` they have within ``tol`` of the drawing's nominal) is the drawing's; the value
    is the drawing's nominal + measured - mesh nominal."""
    found = []
    for nom, meas, U_pts in cands:
        k = next((k for k in keys if k in nom and abs(nom[k] - spec.nominal) <= tol), None)
        if k is not None:
            found.append((spec.nominal + (meas[k] - nom[k]), k, meas, U_pts))
    return found


def _judged(
    spec: CharacteristicSpec, found: list, what: str, rule: str, diagonal: float
) -> CharacteristicResult:
    """The result of the worst of the ``found`` features (:func:`_matching`), with its
    uncertainty, judged by ``rule`` (``BASIC`` for a basic or unlimited dimension); a
    reading implausible for a part ``diagonal`` mm across is not measured
    (:func:`~qifreport.metrology.gdt.characteristic_types.judge`)."""
    lo, hi = spec.lower_limit, spec.upper_limit
    mid = 0.5 * (lo + hi) if lo is not None and hi is not None else spec.nominal
    value, k, meas, U_pts = max(found, key=lambda f: abs(f[0] - mid))  # the worst member
    U, budget = _own_uncertainty(spec, meas, k, U_pts)
    n_members = f"worst of {len(found)} features; " if len(found) > 1 else ""
    res = CharacteristicResult(
        spec,
        value=value,
        uncertainty=U,
        reading=f"{n_members}{k.replace('_', ' ')} {what} (drawing nominal + measured "
        "- mesh nominal)",
        n_points=len(U_pts),
        budget=budget,
    )
    if spec.basic or (lo is None and hi is None):
        return _basic(res, diagonal)
    judge(res, rule, lo, hi, diagonal)
    return res


def _own_uncertainty(
    spec: CharacteristicSpec, meas: dict, key: str, U_pts: np.ndarray
) -> tuple[float | None, UncertaintyBudget | None]:
    """The expanded uncertainty (k = 2) of the measured ``key`` of ``meas`` from the
    measurement itself, and its budget: the points' statistics (``U_pts``), the mesh's
    difference from the scan points (a cylinder's radius), a fit's own spread (a cone's);
    (None, None) for an angle without a spread."""
    U_fit = U_mesh = U_spread = 0.0
    if spec.unit == "mm":
        U_fit = 2 * fit_uncertainty(U_pts, 2)
        U_mesh = meas.get("_systematic_radius", 0.0) * (2.0 if key == "diameter" else 1.0)
    U_spread = meas.get(f"_U_{key}", 0.0)
    if spec.unit != "mm" and f"_U_{key}" not in meas:
        return None, None
    budget = sampling_budget(U_fit, mesh_U=U_mesh)
    budget.add("fit spread", 0.5 * U_spread, "the spread of the fit over its points' draws")
    return float(np.sqrt(U_fit**2 + U_mesh**2 + U_spread**2)), budget


def _basic(res: CharacteristicResult, diagonal: float) -> CharacteristicResult:
    """``res`` reported, not judged (``BASIC``), unless its reading is implausible for a
    part ``diagonal`` mm across (:func:`implausible`: then not measured, saying why)."""
    why = implausible(res, diagonal)
    if why is not None:
        return not_measured(res.spec, why)
    res.status = "BASIC"
    return res
