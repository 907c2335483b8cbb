"""Form, orientation, runout and line profile of a feature, measured on its points
(:mod:`.characteristics` dispatches to them through :data:`qifreport.kinds.KINDS`).

=============  ==============================================================================
form           flatness (plane: minimum zone; per unit area: the worst window), cylindricity
               (minimum radial zone), roundness (the worst cross-section's minimum radial
               zone), straightness (plane or cylinder line elements; a cylinder's derived
               median line when the zone is cylindrical)
orientation    perpendicularity, parallelism, angularity: a plane's points across the zone's
               nominal normal in the frame (minimised over a rotation the frame leaves free);
               an axis: its lateral run over its length (diametral zone)
runout         circular (worst cross-section) and total, about the frame's datum axis: radial
               for a cylinder, axial for a face across the axis
line profile   with datums: twice the largest deviation of the faces' vertices in the frame
=============  ==============================================================================

Each per-feature function has the signature ``f(spec, S, sample, feat, frame, sizes, surf,
faces)``: the spec, the feature's points ``S`` (k, 3) mm (in the datum frame when the kind
is read in one), its :class:`~.measured_surface.FeatureSample`, its nominal feature, the
frame, the part's size dimensions, the surface and the feature's faces; it returns
``(value, least_squares, U, how, bonus)`` (mm) or raises ValueError when the feature cannot
be measured.
"""

from __future__ import annotations

import re

import numpy as np
from scipy.optimize import minimize_scalar

from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    Unmeasurable,
    fit_uncertainty,
    judge,
    not_measured,
    zone_uncertainty,
)
from qifreport.metrology.gdt.datums import DatumFeature, tangent_plane
from qifreport.metrology.gdt.form import (
    axis_frame,
    cylindricity,
    flatness,
    least_squares_circle,
    least_squares_cylinder,
    roundness,
)
from qifreport.metrology.gdt.form import straightness as line_straightness
from qifreport.metrology.gdt.frames import DatumFrameResult
from qifreport.metrology.gdt.measured_surface import MIN_VERTICES, MeasuredSurface

__all__ = [
    "measure_circular_runout",
    "measure_cylindricity",
    "measure_flatness",
    "measure_line_profile",
    "measure_orientation",
    "measure_roundness",
    "measure_straightness",
    "measure_total_runout",
    "per_unit",
]

#: fewest points in a cross-section or a line element
_SECTION_POINTS = 8


def _axial(S: np.ndarray, o: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X = (S - o) @ axis_frame(a).T
    return X[:, 2], np.hypot(X[:, 0], X[:, 1])


def _sections(z: np.ndarray, n_min: int = _SECTION_POINTS) -> list[np.ndarray]:
    """Index sets of cross-sections along ``z`` with at least ``n_min`` points each."""
    m = len(z)
    k = int(np.clip(m // (3 * n_min), 1, 12))
    edges = np.linspace(z.min(), z.max() + 1e-9, k + 1)
    out = []
    for i in range(k):
        sel = np.flatnonzero((z >= edges[i]) & (z < edges[i + 1]))
        if len(sel) >= n_min:
            out.append(sel)
    return out


def _form(fit, U: np.ndarray, how: str) -> tuple:
    """A minimum-zone form reading: value, least squares, ``U``, how, no bonus."""
    return fit.minimum_zone, fit.least_squares, zone_uncertainty(fit.residuals, U), how, 0.0


def measure_flatness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "plane":
        raise Unmeasurable("flatness of a feature that is not a plane")
    unit = per_unit(spec.unit_basis)
    if unit is not None and unit[0] != "length":
        # a unit area is a few mm wide: a surface read on vertices is read on the scan
        # points on the face when they are denser; a sample of scan points is already the
        # feature's own judging points, filtered (the face's other points include a
        # neighbouring face's near the crease, read as a phantom 0.1 mm in one window)
        U = sample.U
        if sample.source != "scan points":
            on = surf.points_on(faces)
            if on.sum() > len(S):
                S, U = surf.P[on], surf.P_U[on]
        return _flatness_per_area(S, U, feat, unit)
    return _form(flatness(S), sample.U, "minimum zone (least squares beside)")


#: a unit area's window holds at least this many measured points to be judged
_WINDOW_POINTS = 6
#: the windows whose least-squares peak-to-valley is largest are then judged by the
#: minimum zone (the least-squares one is never below it), this many
_WINDOWS_EXACT = 8


def _flatness_per_area(S, U, feat: DatumFeature, unit: tuple[str, list[float]]) -> tuple:
    """Flatness per unit area (Y14.5-2018 5.4.2.1): the worst minimum-zone flatness of the
    surface within any unit area (a rectangle a x b, square to the plane's principal
    directions, or a circle), its windows centred on a grid of a quarter of the unit's size
    over the measured points; the worst few by least squares, then by the minimum zone."""
    kind, dims = unit
    E = axis_frame(feat.direction)
    X = (S - feat.origin) @ E.T
    # the face's own in-plane directions (its principal axes), for the rectangles
    C = np.cov(X[:, :2].T)
    _, vec = np.linalg.eigh(C)
    UV = X[:, :2] @ vec
    a = dims[0]
    b = dims[1] if kind == "rectangular" else dims[0]
    lo, hi = UV.min(axis=0), UV.max(axis=0)
    cu = np.arange(lo[0], hi[0] + a / 4, a / 4)
    cv = np.arange(lo[1], hi[1] + b / 4, b / 4)
    from scipy.spatial import cKDTree

    tree = cKDTree(UV)
    windows = []
    for u0 in cu:
        for v0 in cv:
            idx = np.array(tree.query_ball_point([u0, v0], 0.5 * np.hypot(a, b)), dtype=np.int64)
            if kind == "circular":
                idx = idx[np.hypot(*(UV[idx] - [u0, v0]).T) <= a / 2] if len(idx) else idx
            elif len(idx):
                d = np.abs(UV[idx] - [u0, v0])
                idx = idx[(d[:, 0] <= a / 2) & (d[:, 1] <= b / 2)]
            if len(idx) >= _WINDOW_POINTS:
                h = X[idx, 2]
                A = np.c_[UV[idx], np.ones(len(idx))]
                r = h - A @ np.linalg.lstsq(A, h, rcond=None)[0]
                windows.append((float(np.ptp(r)), idx, (u0, v0)))
    if not windows:
        raise Unmeasurable(f"no unit area ({kind} {a:g} x {b:g} mm) holds enough points")
    windows.sort(key=lambda w: -w[0])
    best = None
    for ls, idx, at in windows[:_WINDOWS_EXACT]:
        fit = flatness(S[idx])
        if best is None or fit.minimum_zone > best[0].minimum_zone:
            best = (fit, idx, ls, at)
    fit, idx, ls, at = best
    size = f"{a:g} x {b:g} mm" if kind == "rectangular" else f"diameter {a:g} mm"
    return (
        fit.minimum_zone,
        ls,
        zone_uncertainty(fit.residuals, U[idx]),
        f"per unit area ({kind} {size}): worst of {len(windows)} windows, minimum zone "
        f"(least squares beside)",
        0.0,
    )


def per_unit(text: str | None) -> tuple[str, list[float]] | None:
    """A per-unit tolerance's unit from the PMI's text (mm): ``('length', [L])``,
    ``('rectangular', [a, b])``, ``('circular', [d])``; None when there is none."""
    if not text:
        return None
    nums = [float(x) for x in re.findall(r"[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?", text)]
    if not nums:
        return None
    if "length" in text:
        return "length", nums[:1]
    if "circular" in text:
        return "circular", nums[:1]
    return "rectangular", (nums + nums)[:2]  # a square area gives one side


def measure_cylindricity(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "cylinder":
        raise Unmeasurable("cylindricity of a feature that is not a cylinder")
    fit = cylindricity(S, feat.origin, feat.direction, feat.radius)
    return _form(fit, sample.U, "minimum radial zone (least squares beside)")


def measure_roundness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind != "cylinder":
        raise Unmeasurable("roundness of a feature that is not a cylinder")
    o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    E = axis_frame(a)
    X = (S - o) @ E.T
    fits = ((roundness(X[sel, :2]), sel) for sel in _sections(X[:, 2]))
    return _worst_zone(fits, sample.U, "worst cross-section's minimum radial zone", "cross-section")


def _worst_zone(fits, U: np.ndarray, how: str, element: str) -> tuple:
    """The widest minimum zone of ``fits`` ((FormFit, point indices) of each cross-section
    or line element, in order; the first of equals): a form reading with the ``U`` of its
    points."""
    worst = None
    for fit, sel in fits:
        if worst is None or fit.minimum_zone > worst[0].minimum_zone:
            worst = (fit, sel)
    if worst is None:
        raise Unmeasurable(f"no {element} with enough points")
    fit, sel = worst
    return fit.minimum_zone, fit.least_squares, zone_uncertainty(fit.residuals, U[sel]), how, 0.0


def measure_straightness(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind == "cylinder":
        o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
        E = axis_frame(a)
        X = (S - o) @ E.T
        if spec.zone_form and "cylindrical" in spec.zone_form:
            # the derived median line: centres of the cross-sections
            centres = []
            for sel in _sections(X[:, 2]):
                c, _ = least_squares_circle(X[sel, :2])
                centres.append(np.r_[c, X[sel, 2].mean()])
            if len(centres) < 2:
                raise Unmeasurable("fewer than two cross-sections with enough points")
            C = np.array(centres)
            lat = np.linalg.norm(C[:, :2] - C[:, :2].mean(axis=0), axis=1)
            return (
                2 * float(lat.max()),
                None,
                2 * fit_uncertainty(sample.U, 3),
                ("derived median line (cross-section centres)"),
                0.0,
            )
        ang = np.arctan2(X[:, 1], X[:, 0])
        groups = [np.flatnonzero(np.floor((ang + np.pi) / (np.pi / 4)) == k) for k in range(8)]
        lines = [np.c_[X[g, 2], np.hypot(X[g, 0], X[g, 1])] for g in groups]
        what = "worst surface line element (8 sectors)"
    elif feat.kind == "plane":
        E = axis_frame(feat.direction)
        X = (S - feat.origin) @ E.T
        _, _, Vt = np.linalg.svd(X[:, :2] - X[:, :2].mean(axis=0), full_matrices=False)
        u, v = X[:, :2] @ Vt[0], X[:, :2] @ Vt[1]
        k = 8
        edges = np.linspace(v.min(), v.max() + 1e-9, k + 1)
        groups = [np.flatnonzero((v >= edges[i]) & (v < edges[i + 1])) for i in range(k)]
        lines = [np.c_[u[g], X[g, 2]] for g in groups]
        what = "worst line element along the face's length (8 strips)"
    else:
        raise Unmeasurable("straightness of this feature")
    fits = (
        (line_straightness(Q), g)
        for g, Q in zip(groups, lines, strict=True)
        if len(Q) >= _SECTION_POINTS
    )
    return _worst_zone(fits, sample.U, what, "line element")


def measure_orientation(spec, S, sample, feat, frame, sizes, surf, faces):
    if feat.kind == "sphere":
        raise Unmeasurable(f"{spec.kind} of a sphere")
    tangent = "tangent_plane" in spec.modifiers
    if tangent and feat.kind != "plane":
        raise Unmeasurable(f"tangent plane modifier on a {feat.kind}")
    if feat.kind == "plane":
        n = feat.direction
        how = "planes at the nominal orientation in the frame"
        if tangent:  # (T): the plane contacting the high points, not the surface, is held
            o_t, n_t = tangent_plane(S, n, [])
            S = S - np.outer((S - o_t) @ n_t, n_t)
            how = "the tangent plane (contacting the high points) over the feature, " + how
        w = S @ n
        rot = _free_rotation(frame)
        if rot is not None and abs(rot @ n) < 1 - 1e-9:
            u = S @ np.cross(rot, n)

            def width(th: float) -> float:
                return float(np.ptp(w + th * u))

            best = minimize_scalar(width, bounds=(-0.05, 0.05), method="bounded")
            w = w + best.x * u
            how += " (turned about the free axis)"
        res = w - 0.5 * (w.max() + w.min())
        return float(np.ptp(w)), None, zone_uncertainty(res, sample.U), how, 0.0
    o, a, _ = least_squares_cylinder(S, feat.origin, feat.direction, feat.radius)
    z = (S - o) @ a
    ends = o + np.outer([z.min(), z.max()], a)
    E = np.eye(3) - np.outer(feat.direction, feat.direction)
    run = float(np.linalg.norm(E @ (ends[1] - ends[0])))
    return (
        run,
        None,
        2 * fit_uncertainty(sample.U, 4),
        "axis (least squares) across its length",
        0.0,
    )


def _free_rotation(frame: DatumFrameResult | None) -> np.ndarray | None:
    """The axis of a rotation the frame leaves free (None: none)."""
    if frame is None or frame.free_basis is None or frame.free_basis.shape[1] == 0:
        return None
    W = frame.free_basis[:3]
    U_, sv, _ = np.linalg.svd(W, full_matrices=False)
    if sv[0] < 1e-9:
        return None
    return U_[:, 0]


def _runout_reading(S, feat, frame) -> tuple[np.ndarray, np.ndarray, str]:
    """Runout's radial reading of each point about the frame's datum axis and its place
    along the element (a cylinder: radius and height; a face across the axis: height and
    radius), and how it is read."""
    if frame is None or frame.axis is None:
        raise Unmeasurable("runout needs a datum axis (a cylindrical datum)")
    o, a = frame.axis
    z, rho = _axial(S, o, a)
    if feat.kind == "cylinder":
        return rho, z, "radial about the datum axis"
    if feat.kind == "plane" and abs(feat.direction @ a) > 0.99:
        return z, rho, "axial (face across the datum axis)"
    raise Unmeasurable("runout of a feature neither coaxial with nor across the axis")


def measure_total_runout(spec, S, sample, feat, frame, sizes, surf, faces):
    """Total runout: the whole surface's radial (or axial) spread about the datum axis."""
    radial, _, how = _runout_reading(S, feat, frame)
    res = radial - 0.5 * (radial.max() + radial.min())
    return float(np.ptp(radial)), None, zone_uncertainty(res, sample.U), "total " + how, 0.0


def measure_circular_runout(spec, S, sample, feat, frame, sizes, surf, faces):
    """Circular runout: the worst circular element's radial (or axial) spread about the
    datum axis."""
    radial, along, how = _runout_reading(S, feat, frame)
    worst, worst_sel = -1.0, None
    for sel in _sections(along):
        if np.ptp(radial[sel]) > worst:
            worst, worst_sel = float(np.ptp(radial[sel])), sel
    if worst_sel is None:
        raise Unmeasurable("no circular element with enough points")
    r = radial[worst_sel]
    return worst, None, zone_uncertainty(r - r.mean(), sample.U[worst_sel]), "circular " + how, 0.0


def measure_line_profile(
    spec: CharacteristicSpec, surf: MeasuredSurface, frame: DatumFrameResult | None, rule: str
) -> CharacteristicResult:
    """Profile of a line with datums (Y14.5 11.3.1.2): each line element of the faces within
    a zone of the tolerance's width, equally disposed about the true profile and located in
    the datum frame. The zone is one for every element, so the value is twice the largest
    deviation of the faces' measured vertices in the frame (exact when the frame fixes every
    motion; with motions left free, the frame's fit of them is kept, and the value bounds
    each element's from above)."""
    res = not_measured(spec, "")
    feat = surf.nominal(spec.faces) if len(spec.faces) else None
    if feat is not None and feat.kind != "sphere":
        res.direction = feat.direction  # the sections' normal, for its QIF
    if not spec.datums:
        res.reason = "line profile without datums (the form of each line element): not measured"
        return res
    if any("unequal" in m for m in spec.modifiers):
        res.reason = "line profile with an unequally disposed zone: not measured"
        return res
    if frame is None or not frame.established:
        why = "; ".join(frame.problems) if frame is not None else "its datums are not defined"
        res.reason = f"datum frame not established: {why}"
        return res
    v = surf.own_vertices(spec.faces)
    v = v[np.isfinite(surf.dev[v])]
    if len(v) < MIN_VERTICES:
        res.reason = f"{len(v)} measured vertices on its faces"
        return res
    d = surf.dev[v] + frame.normal_shift(surf.V[v], surf.N[v])
    k = int(np.argmax(np.abs(d)))
    U = float(
        np.hypot(
            surf.U[v[k]], frame.shift_uncertainty(surf.V[v[k : k + 1]], surf.N[v[k : k + 1]])[0]
        )
    )
    out = CharacteristicResult(
        spec,
        value=2.0 * float(np.abs(d).max()),
        uncertainty=2.0 * U,
        reading=(
            f"twice the largest deviation ({d[k]:+.4f} mm) of {len(v)} measured vertices in "
            f"|{'|'.join(frame.labels)}|, one zone for every line element"
            + (f" (best fit: {', '.join(frame.free)}: an upper bound)" if frame.free else "")
        ),
        n_points=len(v),
        direction=res.direction,
    )
    judge(out, rule, None, out.limit, surf.diagonal)
    return out
