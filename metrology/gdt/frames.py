"""Datum reference frames on the measured surface, as the small rigid motion that seats
the part's datum features on their nominal datums in the order of precedence (ASME
Y14.5-2018 sections 4 and 7; ISO 5459; a 3-2-1 / RPS fixture's reading).

The surface has been registered already (rigidly, then the virtual fixture removed its
compliance), so the frame is a small correction ``x -> x + w x x + t`` (``w`` rad, ``t``
mm). Each datum contributes linear conditions on ``(w, t)``:

* a **datum target** (a point): the surface at the target, measured ``d`` mm along the
  face's outward normal ``n``, is brought back onto the nominal: ``n . (w x p + t) = -d``;
* a **planar datum feature**: its simulator (:func:`qifreport.metrology.gdt.datums.simulate_datum`,
  the constrained tangent plane) is turned and moved onto the nominal plane (two rotations,
  one translation);
* a **cylindrical datum feature**: the simulator's axis (largest inscribed cylinder of a
  hole, smallest circumscribed of a pin, regardless of material boundary) onto the
  nominal axis (two rotations, two translations).

The primary's conditions are met first (least squares when they are more than it needs,
e.g. four targets on a plane), the secondary's in the motions the primary left free, and
so on; what no datum fixes stays at the registration's best fit and is reported
(:attr:`DatumFrameResult.free`).

Lengths mm, angles rad; rotations are scaled by the part's size so that a condition's
rank is judged on comparable numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np

from qifreport.metrology.gdt.datums import DatumFeature, simulate_datum
from qifreport.metrology.gdt.form import least_squares_cone
from qifreport.metrology.gdt.measured_surface import MeasuredSurface
from qifreport.registration.arrays import unique_sorted

__all__ = [
    "DatumSpec",
    "DatumFrameResult",
    "TargetSpec",
    "establish_frame",
]

#: a singular value below this share of the largest is no condition (rank)
_RANK = 1e-3
#: scan vertices within this many mm of a datum target measure it (at least the nearest)
TARGET_RADIUS = 2.0
#: how a datum feature's simulator is associated with its measured surface
#: (:func:`qifreport.metrology.gdt.datums.simulate_datum`): least squares, the plane moved out to
#: the high points (the L-infinity tangent simulator tilts with a scan's noisy extremes)
ASSOCIATION = "least squares"
#: ... or, without scan points there, its nearest measured vertices within this (mm): a
#: mesh's vertices are sparser than a scan's points
TARGET_VERTEX_RADIUS = 10.0
#: fewest scan points that measure a datum target
MIN_TARGET_POINTS = 3


@dataclass
class TargetSpec:
    """A datum target: its name, position (3,) mm and the mesh faces it lies on (empty: the
    faces under it, found by its placement). A target area also has its placement's unit
    ``normal`` and ``x_direction`` (3,) and its ``length`` (along ``x_direction``) and
    ``width`` (across) in mm, or its ``diameter`` (a circle); a point or a line none."""

    name: str
    position: np.ndarray
    faces: np.ndarray
    normal: np.ndarray | None = None
    x_direction: np.ndarray | None = None
    length: float | None = None
    width: float | None = None
    diameter: float | None = None

    @property
    def is_area(self) -> bool:
        return self.normal is not None and (
            self.diameter is not None or (self.length is not None and self.width is not None)
        )

    def area_vertices(self, surf: MeasuredSurface) -> np.ndarray:
        """Vertex ids of ``surf`` under the target area (projected along its normal inside
        its outline): of its faces, facing it; without faces (or a supplemental face, not
        meshed), any vertex within 1 mm of its plane whose normal lies along the area's."""
        n = self.normal
        tri = surf.triangles_on(self.faces)
        if len(tri):
            v = unique_sorted(surf.F[tri])
            X = surf.V[v] - self.position
            c = surf.N[v] @ n
            ok = np.abs(c) > 0.3
            ok &= np.sign(c) == np.sign(np.sum(c[ok])) if ok.any() else ok
        else:
            v = np.arange(len(surf.V))
            X = surf.V[v] - self.position
            ok = (np.abs(X @ n) < 1.0) & (np.abs(surf.N[v] @ n) > 0.9)
        if self.diameter is not None:
            across = X - np.outer(X @ n, n)
            ok &= np.linalg.norm(across, axis=1) <= 0.5 * self.diameter
        else:
            x = self.x_direction
            y = np.cross(n, x)
            ok &= (np.abs(X @ x) <= 0.5 * self.length) & (np.abs(X @ y) <= 0.5 * self.width)
        return v[ok]

    def measured_under(self, surf: MeasuredSurface) -> tuple[np.ndarray, np.ndarray]:
        """The measured vertex ids under the area (:meth:`area_vertices`, deviation known)
        and the area's unit normal turned out of the material (3,)."""
        v = self.area_vertices(surf)
        v = v[np.isfinite(surf.dev[v])]
        return v, self.normal * np.sign(np.sum(surf.N[v] @ self.normal))

    def size_text(self) -> str:
        if self.diameter is not None:
            return f"diameter {self.diameter:g} mm"
        return f"{self.length:g} x {self.width:g} mm"


@dataclass
class DatumSpec:
    """A datum of the drawing: its label, the mesh faces of its feature, its targets."""

    label: str
    faces: np.ndarray
    targets: list[TargetSpec] = field(default_factory=list)


@dataclass
class DatumFrameResult:
    """A datum reference frame established on the measured surface.

    Attributes
    ----------
    labels : the datums in precedence order.
    w, t : (3,), (3,): the small motion ``x -> x + w x x + t`` (rad, mm) seating the
        measured part on the frame; zero when not established.
    established : every datum was measured.
    problems : why not (one line per datum).
    free : the motions no datum fixes, e.g. ``['translation along x']`` (best fit).
    readings : per datum, how it was simulated (``'targets A1 A2 A3 A4'``,
        ``'tangent plane (1204 vertices)'``, ``'inscribed cylinder (...)'``).
    axis : the first cylindrical datum's nominal axis (point, unit direction), the axis
        of a runout or coaxiality; None without.
    free_basis : (6, k) the motions ``(w, t)`` no datum fixes, as columns.
    covariance : (6, 6) of ``(w, t)`` from the datums' readings' expanded uncertainties
        (so its square roots are expanded, k = 2), or None.
    """

    labels: tuple[str, ...]
    w: np.ndarray
    t: np.ndarray
    established: bool
    problems: list[str] = field(default_factory=list)
    free: list[str] = field(default_factory=list)
    readings: list[str] = field(default_factory=list)
    axis: tuple[np.ndarray, np.ndarray] | None = None
    free_basis: np.ndarray | None = None
    covariance: np.ndarray | None = None

    def move(self, P: np.ndarray) -> np.ndarray:
        """(m, 3) the points ``P`` in the frame."""
        P = np.asarray(P, dtype=np.float64)
        return P + np.cross(self.w, P) + self.t

    def normal_shift(self, V: np.ndarray, N: np.ndarray) -> np.ndarray:
        """(n,) how far the frame moves each point ``V`` along its unit normal ``N``, mm
        (added to a deviation measured along ``N``, it gives the deviation in the frame)."""
        V = np.asarray(V, dtype=np.float64)
        return np.einsum("ij,ij->i", N, np.cross(self.w, V) + self.t)

    def shift_uncertainty(self, V: np.ndarray, N: np.ndarray) -> np.ndarray:
        """(n,) expanded uncertainty (k = 2) of :meth:`normal_shift` at ``V`` along ``N``,
        mm, from the datums' readings (zeros when unknown)."""
        if self.covariance is None:
            return np.zeros(len(V))
        a = np.c_[np.cross(np.asarray(V, dtype=np.float64), N), N]  # shift = a . (w, t)
        return np.sqrt(np.maximum(np.einsum("ij,ij->i", a @ self.covariance, a), 0.0))

    def point_uncertainty(self, P: np.ndarray) -> float:
        """The largest expanded uncertainty (k = 2) of where the frame puts any of the
        points ``P`` (m, 3), in any direction, mm."""
        P = np.asarray(P, dtype=np.float64)
        return max(
            float(self.shift_uncertainty(P, np.tile(e, (len(P), 1))).max(initial=0.0))
            for e in np.eye(3)
        )

    def to_dict(self) -> dict:
        return {
            "datums": "|".join(self.labels),
            "established": self.established,
            "rotation_rad": [float(x) for x in self.w],
            "translation_mm": [float(x) for x in self.t],
            "free": list(self.free),
            "readings": list(self.readings),
            "problems": list(self.problems),
        }


def _cross_rows(n: np.ndarray) -> np.ndarray:
    """(3, 3) ``M`` with ``M w = w x n``."""
    return np.array([[0.0, n[2], -n[1]], [-n[2], 0.0, n[0]], [n[1], -n[0], 0.0]])


def _target_rows(
    spec: DatumSpec, surf: MeasuredSurface
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Rows of ``n . (w x p + t) = -d`` for each target of ``spec``: ``d`` the median
    deviation of the scan points on its faces within :data:`TARGET_RADIUS` of it; raises
    ValueError naming a target the scan does not reach. Also each row's expanded
    uncertainty (mm)."""
    rows, rhs, unc = [], [], []
    for tg in spec.targets:
        if tg.is_area:
            row, r, u = _area_row(tg, surf)
            rows.append(row)
            rhs.append(r)
            unc.append(u)
            continue
        d = surf.point_deviation_near(tg.faces, tg.position, TARGET_RADIUS)
        if len(d) < MIN_TARGET_POINTS:  # no scan points there: the measured vertices
            d = surf.vertex_deviation_near(
                tg.faces, tg.position, TARGET_VERTEX_RADIUS, MIN_TARGET_POINTS
            )
        if len(d) < MIN_TARGET_POINTS:
            raise ValueError(
                f"datum target {tg.name}: {len(d)} measured points within {TARGET_RADIUS:g} mm"
            )
        own = surf.own_vertices(tg.faces)
        if not len(own):
            raise ValueError(f"datum target {tg.name}: its face has no vertex of its own")
        near = own[np.argmin(np.linalg.norm(surf.V[own] - tg.position, axis=1))]
        n = surf.N[near]
        p = np.asarray(tg.position, dtype=np.float64)
        rows.append(np.r_[np.cross(p, n), n])  # n . (w x p) = w . (p x n)
        rhs.append(-float(np.median(d)))
        # the median's expanded uncertainty (k = 2) from the points' own scatter, and never
        # less than a measured vertex's there: a target is a few dozen points, whose
        # systematic share (the distance to a curved surface, the view's slant) does not
        # average out (CTC 02's perfect scan reads its targets 2 um off at 1.9 um)
        sigma = 1.4826 * float(np.median(np.abs(d - np.median(d))))
        unc.append(max(2 * 1.2533 * sigma / np.sqrt(len(d)), float(np.nanmedian(surf.U))))
    how = "targets " + " ".join(
        f"{t.name} (area {t.size_text()}: its highest point)" if t.is_area else t.name
        for t in spec.targets
    )
    return np.array(rows), np.array(rhs), np.array(unc), how


def _area_row(tg: TargetSpec, surf: MeasuredSurface) -> tuple[np.ndarray, float, float]:
    """The row of a target area: its simulator, a flat area of the target's outline held at
    its nominal orientation, moves along its normal until it meets the measured surface
    under it (the most material; on a curved face not where the nominal touches); the row
    says how far, at the contact, with that vertex's expanded uncertainty. Raises
    ValueError when too few measured vertices lie under it."""
    v, n = tg.measured_under(surf)
    if len(v) < MIN_TARGET_POINTS:
        raise ValueError(
            f"datum target {tg.name} ({tg.size_text()}): {len(v)} measured vertices under it"
        )
    h_nom = surf.V[v] @ n
    h = h_nom + surf.dev[v] * (surf.N[v] @ n)
    k = int(np.argmax(h))
    p = surf.V[v[k]]
    return np.r_[np.cross(p, n), n], -float(h[k] - h_nom.max()), float(surf.U[v[k]])


def _simulator_rows(
    spec: DatumSpec, surf: MeasuredSurface, keep: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, DatumFeature]:
    """Rows seating the datum feature simulator of ``spec`` (fitted to its measured
    surface) on its nominal feature; ``keep``: nominal directions of earlier datums its
    orientation is held to (as :func:`~qifreport.metrology.gdt.datums.simulate_datum`). A
    datum on a pattern (several holes) gives each member's rows: the pattern seated as a
    whole by least squares."""
    rows, rhs, unc, hows = [], [], [], []
    first = None
    for faces in surf.features(spec.faces):
        sample = surf.sample(faces, spec.label)
        feat = None if sample.nominal is None else replace(sample.nominal, label=spec.label)
        if feat is None or feat.kind not in ("plane", "cylinder", "cone"):
            raise ValueError(
                f"datum {spec.label}: its feature is neither a plane, a cylinder nor a cone"
            )
        if len(sample.S) < (3 if feat.kind == "plane" else 7 if feat.kind == "cone" else 6):
            raise ValueError(f"datum {spec.label}: {len(sample.S)} measured points on its feature")
        if feat.kind == "cone":
            # a conical datum feature's axis (its least-squares cone's); its apex along the
            # axis is left to the other datums (a primary plane fixes it)
            apex, axis, _ = least_squares_cone(
                sample.S, feat.origin, feat.direction, feat.half_angle
            )
            sim = SimpleNamespace(origin=apex, direction=axis, method="least-squares cone axis")
        else:
            sim = simulate_datum(
                sample.S, feat, keep if feat.kind == "plane" else keep[:1], ASSOCIATION
            )
        for r, b, u in _seat_rows(sample.S, sample.U, feat, sim):
            rows.append(r)
            rhs.append(b)
            unc.append(u)
        hows.append(f"{sim.method} ({len(sample.S)} {sample.source})")
        first = first or feat
    if first is None:
        raise ValueError(f"datum {spec.label}: no face of the part carries its feature")
    how = hows[0] if len(hows) == 1 else f"pattern of {len(hows)}: " + ", ".join(hows)
    return np.vstack(rows), np.concatenate(rhs), np.concatenate(unc), how, first


def _seat_rows(
    S: np.ndarray, U: np.ndarray, feat: DatumFeature, sim
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(rows, right-hand sides, expanded uncertainties) seating the simulator ``sim``
    (``origin``, ``direction``) fitted to the measured points ``S`` (m, 3) of uncertainties
    ``U`` (m,) on the nominal feature ``feat``: its orientation, then its location."""
    a_m, a_n = sim.direction, feat.direction
    if a_m @ a_n < 0:
        a_m = -a_m
    # orientation: a_m + w x a_m = a_n, two independent rows (across a_n), times the
    # feature's extent: the tilt as the displacement it makes across the feature, in mm as
    # the location rows (else a few micrometres at the location rows' far-apart contact
    # points would turn the part)
    E = _across(a_n)
    size = float(np.linalg.norm(np.ptp(S, axis=0)))
    # expanded uncertainties: a least-squares tilt over the feature (as the displacement
    # across it), the high points' height (a plane), a least-squares axis' place;
    # neighbouring vertices share scan points: a quarter of them count
    u = float(np.nanmedian(U))
    n_eff = max(len(S) / 4.0, 1.0)
    out = [
        (
            size * np.c_[E @ _cross_rows(a_m), np.zeros((2, 3))],
            size * (E @ (a_n - a_m)),
            np.full(2, u * np.sqrt(12.0 / n_eff)),
        )
    ]
    # location: the simulator at the middle of the measured points onto the nominal, across
    # the plane or the axis
    c = S.mean(axis=0)
    if feat.kind == "plane":
        Lr = a_n[None, :]
        o = c - ((c - sim.origin) @ a_m) * a_m
    else:
        Lr = E
        o = sim.origin + ((c - sim.origin) @ a_m) * a_m
    out.append(
        (
            np.c_[Lr @ _cross_rows(o), Lr],
            Lr @ (feat.origin - o),
            np.full(len(Lr), u if feat.kind == "plane" else u * np.sqrt(2.0 / n_eff)),
        )
    )
    return out


def _area_plane_rows(
    spec: DatumSpec, surf: MeasuredSurface, keep: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, DatumFeature] | None:
    """A datum established by one target area on a flat region (Y14.5 7.24: the target
    area's simulator is a flat area of its outline): the datum plane simulated on the
    measured vertices under the area only, as a planar datum feature's; None when the
    region under it is not flat (then the area meets the surface at one point,
    :func:`_area_row`)."""
    (tg,) = spec.targets
    v, n = tg.measured_under(surf)
    if len(v) < 3:
        return None
    X = surf.V[v]
    size = max(float(np.linalg.norm(np.ptp(X, axis=0))), 1.0)
    if np.min(surf.N[v] @ n) < 1 - 1e-6 or np.ptp(X @ n) > 1e-4 * size:
        return None
    feat = DatumFeature(spec.label, "plane", X.mean(axis=0), n)
    S = X + surf.dev[v, None] * surf.N[v]
    sim = simulate_datum(S, feat, keep, ASSOCIATION)
    parts = _seat_rows(S, surf.U[v], feat, sim)
    how = f"target area {tg.name} ({tg.size_text()}): {sim.method} ({len(v)} vertices under it)"
    return (
        np.vstack([r for r, _, _ in parts]),
        np.concatenate([b for _, b, _ in parts]),
        np.concatenate([u for _, _, u in parts]),
        how,
        feat,
    )


def _across(a: np.ndarray) -> np.ndarray:
    """(2, 3) two unit rows perpendicular to unit ``a`` and to each other."""
    t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, t)
    e1 /= np.linalg.norm(e1)
    return np.vstack([e1, np.cross(a, e1)])


def establish_frame(datums: list[DatumSpec], surf: MeasuredSurface) -> DatumFrameResult:
    """The datum reference frame of ``datums`` (precedence order) on the measured surface.

    Returns the frame; ``established`` False (and zero motion) when a datum could not be
    simulated, with the reason in ``problems``.
    """
    labels = tuple(d.label for d in datums)
    L = max(surf.diagonal, 1.0)
    scale = np.r_[np.full(3, 1.0 / L), np.ones(3)]  # unknowns (w L, t)
    x = np.zeros(6)
    Z = np.eye(6)  # free motions (columns), scaled unknowns
    # x = X b over every row so far (the solution is linear in the readings), for the
    # frame's uncertainty from each reading's
    X = np.zeros((6, 0))
    A_all = np.zeros((0, 6))
    u_all = np.zeros(0)
    kept: list[np.ndarray] = []
    readings: list[str] = []
    axis = None
    for spec in datums:
        try:
            single_area = len(spec.targets) == 1 and spec.targets[0].is_area
            area = _area_plane_rows(spec, surf, kept) if single_area else None
            if area is not None:
                A, b, u, how, feat = area
                kept.append(feat.direction)
            elif spec.targets:
                A, b, u, how = _target_rows(spec, surf)
            else:
                A, b, u, how, feat = _simulator_rows(spec, surf, kept)
                kept.append(feat.direction)
                if feat.kind in ("cylinder", "cone") and axis is None:
                    axis = (feat.origin, feat.direction)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            return DatumFrameResult(labels, np.zeros(3), np.zeros(3), False, [str(exc)])
        readings.append(f"{spec.label}: {how}")
        As = A * scale  # columns of the scaled unknowns
        k0 = len(u_all)
        X = np.c_[X, np.zeros((6, len(b)))]
        A_all = np.vstack([A_all, As])
        u_all = np.r_[u_all, u]
        if Z.shape[1] == 0:
            continue
        M = As @ Z
        U_, sv, Vt = np.linalg.svd(M, full_matrices=True)
        r = int(np.sum(sv > _RANK * max(sv.max(initial=0.0), 1e-300)))
        if r == 0:
            continue
        Pg = Vt[:r].T @ (U_[:, :r].T / sv[:r, None])  # (q, rows of this datum)
        y = Pg @ (b - As @ x)
        x = x + Z @ y
        # d x / d b: this datum's rows directly, every earlier row through x
        sel = np.zeros((len(b), len(u_all)))
        sel[:, k0:] = np.eye(len(b))
        X = X + Z @ Pg @ (sel - As @ X)
        Z = Z @ Vt[r:].T
    w, t = x[:3] / L, x[3:]
    D = np.diag(scale)
    cov = D @ X @ np.diag(u_all**2) @ X.T @ D  # of (w, t), expanded (k = 2) squared
    return DatumFrameResult(
        labels,
        w,
        t,
        True,
        [],
        _free_names(Z),
        readings,
        axis=axis,
        free_basis=Z * scale[:, None],
        covariance=cov,
    )


def _free_names(Z: np.ndarray) -> list[str]:
    """Names of the motions spanned by the columns of ``Z`` (scaled ``(w L, t)``)."""
    if Z.shape[1] == 0:
        return []
    names = []
    Q, _ = np.linalg.qr(Z)
    for part, what in ((slice(3, 6), "translation along "), (slice(0, 3), "rotation about ")):
        B = Q[part]
        U_, sv, _ = np.linalg.svd(B, full_matrices=False)
        for k in range(int(np.sum(sv > 0.5))):
            v = U_[:, k]
            i = int(np.argmax(np.abs(v)))
            v = v * np.sign(v[i])
            names.append(what + ("xyz"[i] if abs(v[i]) > 1 - 1e-6 else _vec(v)))
    return names


def _vec(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"
