"""The restrained hold (ISO 10579): the free-state scan read at its clamps, seated as the
fixture seats it and moved by the part's elastic response to the clamps driven home.

:func:`hold_scan` is the whole step; :mod:`qifreport.metrology.inspection` judges the held
scan it returns as it judges any other. The pieces: where each clamp's offset is read
(:func:`clamp_readings`), the locators on narrow faces
(:func:`qifreport.metrology.restraint.locators.patch_offset`), the placement the unread locators
leave (:func:`seat_held`) and the model's own uncertainty (:data:`MODEL_UNCERTAINTY`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import stdtrit

from qifreport.metrology.deviation.closest import closest_points
from qifreport.metrology.deviation.surface import surface_distance
from qifreport.metrology.restraint.locators import patch_offset
from qifreport.registration.deformable.result import orient_scan_normals
from qifreport.registration.icp import robust_scale, tukey_rho, tukey_weights
from qifreport.registration.mesh import face_normals
from qifreport.registration.restraint.restrained import (
    FACING_ANGLE,
    Restraint,
    RestraintBasis,
    pad_mean,
    read_directions,
    rigid_motion,
    transported_normals,
)

__all__ = [
    "FAR_HOLD",
    "LOCATOR_GATE",
    "LOCATOR_PATCH",
    "MODEL_UNCERTAINTY",
    "SEEN_SOURCES",
    "SOURCE_FREE_FIT",
    "SOURCE_PATCH",
    "SOURCE_SCAN",
    "SOURCE_SEATED",
    "ClampOffsets",
    "ClampReadings",
    "HeldScan",
    "clamp_readings",
    "hold_scan",
    "hold_too_far",
    "median_uncertainty",
    "seat_held",
    "seat_motions",
]

log = logging.getLogger(__name__)

#: a locator's patch (:func:`qifreport.metrology.restraint.locators.patch_offset`): its radius in
#: pad
#: radii, and the largest free-state motion of a pair there, mm
LOCATOR_PATCH = 3.0
LOCATOR_GATE = 3.0

#: where a clamp's offset came from (:attr:`Restraint.offset_sources`): the points under its
#: pad, a locator's patch fitted with its neighbours, the free virtual fixture (a clamp face
#: the scan does not see), the held seat (a stop too little seen); the first two are seen
SOURCE_SCAN = "scan"
SOURCE_PATCH = "scan (local fit)"
SOURCE_FREE_FIT = "free-state fit"
SOURCE_SEATED = "seated (patch not seen)"
SEEN_SOURCES = (SOURCE_SCAN, SOURCE_PATCH)

#: relative standard uncertainty of the displacement by which the elastic model holds the
#: scan (wall thickness, Poisson's ratio, mesh and contact size the model cannot know):
#: bench/fixture.py's truth (a +/-10 % wall, Poisson 0.05 off, another mesh) differed from
#: the product's held field by 1-3 % of the correction on the panel and the shell; it enters
#: each vertex's and point's expanded uncertainty (k = 2) in quadrature
MODEL_UNCERTAINTY = 0.025

#: scan points (besides those under the clamps) the held seat is fitted on, its
#: Gauss-Newton rounds, and the largest move (mm) of a round below which it has settled
_SEAT_SAMPLE = 6000
_SEAT_ROUNDS = 8
_SEAT_SETTLED = 1e-3
#: mm^2 of mean square held residual a 1 mm motion of the seat must gain, at least (a
#: quarter of the held residual's robust variance where the seat stands, when larger)
_SEAT_PRIOR = 1e-4


@dataclass
class HeldScan:
    """The scan as the fixture holds it (:func:`hold_scan`).

    Attributes
    ----------
    P_free : (m, 3) the free-state scan in the held seat, mm.
    P : (m, 3) the held scan, mm.  normals, sheets : its oriented PCA normals and sheets.
    restraint : the hold (offsets and their sources, seat, forces, displacement).
    u_vertex, u_point : (n,), (m,) expanded (k = 2) uncertainty, mm, of the hold at each
        nominal vertex and scan point (the model's; the unread placement's).
    seconds : stage timings, s.
    """

    P_free: np.ndarray
    P: np.ndarray
    normals: np.ndarray
    sheets: np.ndarray
    restraint: Restraint
    u_vertex: np.ndarray
    u_point: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)


def hold_scan(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    scan_normals: np.ndarray,
    sheets: np.ndarray,
    restraint: RestraintBasis,
    *,
    normals: np.ndarray,
    free_fit: Callable[[], np.ndarray],
    face_id: np.ndarray | None = None,
    brep_normals: np.ndarray | None = None,
    tree: cKDTree | None = None,
) -> HeldScan:
    """Hold the rigidly seated scan at its clamps (ISO 10579).

    Each clamp's free-state offset is read from the scan under its pad
    (:func:`clamp_readings`); a clamp the scan does not see takes the free virtual
    fixture's displacement there (``free_fit()``: its smoothness prior is then the only
    witness, said in the outputs). The clamps driven back to nominal move every scan point
    by the part's elastic response.

    A scan shows each contact's offset along its surface's normal only: a locator whose
    axis its surface faces (a stop on an end face the scan sees) is read from its patch
    (:func:`qifreport.metrology.restraint.locators.patch_offset`) and driven home like a clamp face
    (:func:`qifreport.registration.restraint.restrained.read_directions`); where a locator restrains
    a direction in its surface's plane (a pin) or was not seen, the held part keeps the
    placement whose held state fits the nominal best (:func:`seat_held`), not the free
    state's own best fit (the warp pulls that one along the surface). The elastic model's
    own uncertainty (:data:`MODEL_UNCERTAINTY` of the hold's displacement) and, where a pin
    places the part, the spread of the placements enter each deviation's expanded
    uncertainty.

    Parameters
    ----------
    V : (n, 3) nominal vertices, mm (the restraint basis's mesh).  F : (f, 3).
    P : (m, 3) the rigidly seated free-state scan, mm.
    scan_normals, sheets : its normals and sheets
        (:func:`qifreport.registration.normals.orient_normals_consistent`); the held scan's
        are these sheets and these normals carried by the hold's motion.
    restraint : the part's restraint basis.  normals : (n, 3) unit vertex normals.
    free_fit : the free virtual fixture's registered vertices (n, 3), mm, when asked.
    face_id : (f,) B-rep face of each triangle (a STEP nominal).
    brep_normals : (f, 3, 3) the B-rep's normals at the triangle corners.
    tree : ``cKDTree(V)``.
    """
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}
    tree = cKDTree(V) if tree is None else tree
    tri_n = face_normals(V, F)
    Ns_out = orient_scan_normals(P, scan_normals, V, normals, sheets=sheets)
    p_tree = cKDTree(P)
    readings = clamp_readings(P, Ns_out, restraint, V, F, face_id, brep_normals, tree=p_tree)
    _log_readings(readings, restraint)
    offs = _locator_offsets(V, F, tri_n, P, Ns_out, restraint, readings, p_tree)
    offs = _witnessed_offsets(offs, V, free_fit, tree, seconds)

    def distances(Q: np.ndarray):
        """Signed distances (m,) of points ``Q`` to the nominal, closest points, their
        triangles and the nominal normals there."""
        C, cface, pdev = closest_points(V, F, Q)
        if face_id is not None:
            pdev = surface_distance(V, F, C, cface, pdev, face_id, brep_normals, Q)
        return pdev, C, cface, tri_n[cface]

    t1 = time.perf_counter()
    xi = seat_held(P, restraint, V, distances, offs.origin, offs.at, offs.read)
    seconds["restraint seat"] = time.perf_counter() - t1
    out = _held(V, F, P, xi, offs, normals, tri_n, (scan_normals, sheets))
    seconds["restraint"] = time.perf_counter() - t0 - seconds.get("free fit", 0.0)
    out.seconds = seconds
    return out


@dataclass
class ClampOffsets:
    """The clamps' free-state offsets as the scan gives them, and how they move with the
    part (:func:`hold_scan`'s first steps).

    Attributes
    ----------
    readings : the scan points under each pad (:func:`clamp_readings`).
    restraint : the part's restraint basis.  origin : (3,) the seat's pivot, mm.
    offsets : (c,) each clamp's offset in the free state's seat, mm (NaN: a stop the held
        seat places, or a clamp face not seen).
    sources : where each offset came from (:data:`SOURCE_SCAN`, ...).
    local : (c,) a facing locator's offset from its patch, mm (NaN: none).
    unplaced : (c,) bool the stops whose patch is not seen: the held seat places them.
    unseen : the clamp faces the scan does not see (indices).
    witness : (c,) their offsets from the free virtual fixture, mm (0 elsewhere).
    read : (p,) bool per restrained direction: its drive is given by the scan.
    """

    readings: ClampReadings
    restraint: RestraintBasis
    origin: np.ndarray
    offsets: np.ndarray
    sources: list[str]
    local: np.ndarray
    unplaced: np.ndarray
    unseen: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    witness: np.ndarray | None = None
    read: np.ndarray | None = None

    def at(self, xi: np.ndarray) -> np.ndarray:
        """(c,) the clamps' offsets, mm, once the free state is moved by ``xi`` (6,)
        (rad, mm about :attr:`origin`)."""
        off = self.readings.offsets(*rigid_motion(xi, self.origin))
        # an unseen clamp face's offset, and a locator's from its patch, move with the part
        r = self.restraint
        at = np.array([c.position for c in r.clamps], dtype=np.float64) - self.origin
        shift = np.einsum("kd,kd->k", np.cross(xi[:3], at) + xi[3:], r.normals)
        by_patch = np.isfinite(self.local)
        off[self.unseen] = self.witness[self.unseen] + shift[self.unseen]
        off[by_patch] = self.local[by_patch] + shift[by_patch]
        off[self.unplaced] = np.nan
        return off


def _log_readings(readings: ClampReadings, restraint: RestraintBasis) -> None:
    """Each clamp's readings, their median and spread, in the log."""
    for k, c in enumerate(restraint.clamps):
        vals = readings.values(k)
        log.info(
            "clamp %s: %d readings, median %s mm, spread (IQR) %s mm",
            c.name,
            len(vals),
            f"{np.median(vals):+.3f}" if len(vals) else "-",
            f"{np.subtract(*np.percentile(vals, [75, 25])):.3f}" if len(vals) else "-",
        )


def _locator_offsets(
    V: np.ndarray,
    F: np.ndarray,
    tri_n: np.ndarray,
    P: np.ndarray,
    Ns_out: np.ndarray,
    restraint: RestraintBasis,
    readings: ClampReadings,
    p_tree: cKDTree,
) -> ClampOffsets:
    """The clamps' offsets from the points under their pads, a locator on a face that
    faces its axis read from its patch instead: its face and the neighbours placed together
    (:func:`qifreport.metrology.restraint.locators.patch_offset`: proximity alone reads the
    neighbouring faces once the free state moved a narrow face across its own width)."""
    offsets = readings.offsets()
    sources = [SOURCE_SCAN] * len(offsets)
    facing = np.abs(restraint.coupling) >= np.cos(np.radians(FACING_ANGLE))
    locator = np.array([restraint.clamps[k].directions != "n" for k in restraint.owner])
    local = np.full(len(offsets), np.nan)
    unplaced = np.zeros(len(offsets), dtype=bool)  # stops the seat places
    for k in np.unique(restraint.owner[facing & locator]):
        local[k] = patch_offset(
            V,
            F,
            tri_n,
            P,
            Ns_out,
            restraint.clamps[k].position,
            restraint.normals[k],
            LOCATOR_PATCH * restraint.pad_radius,
            LOCATOR_GATE,
            tree=p_tree,
        )
        if np.isfinite(local[k]):
            log.info(
                "locator %s: %+.3f mm from its patch (its face's points alone: %+.3f mm)",
                restraint.clamps[k].name,
                local[k],
                offsets[k],
            )
            offsets[k] = local[k]
            sources[k] = SOURCE_PATCH
        else:
            # too little of its patch seen to place it (on the bench's bracket, 4 points
            # of a 1.2 mm flange edge): its own face's few points are no better (they read
            # it 0.4 mm off and held the part turned), so the seat places it, with the
            # placement's uncertainty
            log.info(
                "locator %s: its patch is not seen; placed by the held seat",
                restraint.clamps[k].name,
            )
            offsets[k] = np.nan
            unplaced[k] = True
            sources[k] = SOURCE_SEATED
    return ClampOffsets(
        readings=readings,
        restraint=restraint,
        origin=V.mean(axis=0),
        offsets=offsets,
        sources=sources,
        local=local,
        unplaced=unplaced,
    )


def _witnessed_offsets(
    offs: ClampOffsets,
    V: np.ndarray,
    free_fit: Callable[[], np.ndarray],
    tree: cKDTree,
    seconds: dict[str, float],
) -> ClampOffsets:
    """``offs`` with the restrained directions whose drive the scan gives (the faces, the
    locators it shows; the seat searches the rigid motions the others hold) and an unseen
    clamp face's offset from the free virtual fixture (its witness; ``seconds``: its time
    added, "free fit")."""
    restraint, offsets, sources = offs.restraint, offs.offsets, list(offs.sources)
    read = read_directions(restraint.clamps, restraint.owner, restraint.coupling, offsets)
    faces = np.array([c.directions == "n" for c in restraint.clamps], dtype=bool)
    unseen = np.flatnonzero(~np.isfinite(offsets) & faces)
    fixed = np.zeros(len(offsets))
    if len(unseen):
        t1 = time.perf_counter()
        Vfit = free_fit()
        seconds["free fit"] = time.perf_counter() - t1
        _, near = tree.query([restraint.clamps[k].position for k in unseen])
        for k, v in zip(unseen, np.atleast_1d(near), strict=True):
            fixed[k] = float((Vfit[v] - V[v]) @ restraint.normals[k])
            sources[k] = SOURCE_FREE_FIT
        log.info(
            "clamp(s) %s not seen by the scan: offsets from the free virtual fixture",
            ", ".join(restraint.clamps[k].name for k in unseen),
        )
    return replace(offs, sources=sources, unseen=unseen, witness=fixed, read=read)


def _held(
    V: np.ndarray,
    F: np.ndarray,
    P0: np.ndarray,
    xi: np.ndarray,
    offs: ClampOffsets,
    normals: np.ndarray,
    tri_n: np.ndarray,
    oriented: tuple[np.ndarray, np.ndarray],
) -> HeldScan:
    """The free state ``P0`` (m, 3) moved by the held seat ``xi`` (6,) and by the part's
    elastic response to its clamps driven home, with the hold's uncertainty: the elastic
    model's own, a share of how far it moved each vertex and point, and the placement's
    where the seat placed the part (:func:`hold_scan`). ``oriented``: the free state's
    normals (m, 3) and sheets (m,); the held scan's are the same sheets and those normals
    carried by the motion (:func:`transported_normals`)."""
    restraint, origin = offs.restraint, offs.origin
    R, t = rigid_motion(xi, origin)
    Pseat = P0 @ R.T + t
    offsets = offs.at(xi)
    C, cface, _ = closest_points(V, F, Pseat)
    held = restraint.apply(offsets)
    held.offset_sources = offs.sources
    held.seat = xi
    moved = held.on_triangles(V, cface, C)
    Pr = Pseat + moved
    Ns = transported_normals(oriented[0], R, held.gradient_on_triangles(V, cface, C))
    k_model = 2.0 * MODEL_UNCERTAINTY
    u_v = k_model * np.linalg.norm(held.u, axis=1)
    u_p = k_model * np.linalg.norm(moved, axis=1)
    u_read = np.where([s == SOURCE_SCAN for s in offs.sources], offs.readings.uncertainty(), 0.0)
    held.offset_uncertainty = u_read
    read_v, read_p = _reading_spread(
        restraint, offsets, u_read, held, moved, (V, cface, C), normals, tri_n[cface]
    )
    u_v, u_p = np.hypot(u_v, read_v), np.hypot(u_p, read_p)
    if np.any(xi) and np.any(~offs.read):
        # a pin whose axis lies in its surface's plane cannot be read from any scan, nor
        # a stop the scan did not see: the placement along it is an estimate, which the
        # held best fit (the seat) and the free state's best fit bound, and their
        # difference at each vertex and point is its uncertainty (the seat slides form
        # away: on the bench's shell it read 0.10-0.14 mm rms off the physical fixture
        # where the free state's placement read 0.01, and passed parts the fixture
        # rejects).
        stay = restraint.apply(offs.at(np.zeros(6)))
        shift_v = (V - origin) @ R.T + origin + t - V + held.u - stay.u
        shift_p = (Pseat - P0) + moved - stay.on_triangles(V, cface, C)
        u_v = np.hypot(u_v, np.abs(np.einsum("ij,ij->i", normals, shift_v)))
        u_p = np.hypot(u_p, np.abs(np.einsum("ij,ij->i", tri_n[cface], shift_p)))
    return HeldScan(
        P_free=Pseat,
        P=Pr,
        normals=Ns,
        sheets=oriented[1],
        restraint=held,
        u_vertex=u_v,
        u_point=u_p,
    )


def _reading_spread(
    restraint: RestraintBasis,
    offsets: np.ndarray,
    u_read: np.ndarray,
    held: Restraint,
    moved: np.ndarray,
    on: tuple[np.ndarray, np.ndarray, np.ndarray],
    normals: np.ndarray,
    point_normals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """How far the clamps' reading uncertainties ``u_read`` (c,) mm move the held part:
    (n,) at the nominal's vertices along their ``normals`` and (m,) at the scan points
    along ``point_normals`` (their closest points' triangles), mm, each clamp's offset
    moved by its uncertainty in turn, the responses added in quadrature. ``on``: the
    nominal's vertices, the points' closest triangles and closest points; ``held`` and
    ``moved`` (m, 3) the hold at ``offsets`` (c,) and its displacement at the points."""
    V, cface, C = on
    sq_v, sq_p = np.zeros(len(V)), np.zeros(len(C))
    for k in np.flatnonzero(np.asarray(u_read) > 0):
        o = np.array(offsets, dtype=np.float64)
        o[k] += u_read[k]
        other = restraint.apply(o)
        sq_v += np.einsum("ij,ij->i", normals, other.u - held.u) ** 2
        dp = other.on_triangles(V, cface, C) - moved
        sq_p += np.einsum("ij,ij->i", point_normals, dp) ** 2
    return np.sqrt(sq_v), np.sqrt(sq_p)


def seat_held(
    P: np.ndarray,
    restraint: RestraintBasis,
    V: np.ndarray,
    distances,
    origin: np.ndarray,
    offsets_at,
    read: np.ndarray,
) -> np.ndarray:
    """(6,) the small rigid motion ``(omega, t)`` (rad, mm, about ``origin``) of the free
    state ``P`` (m, 3) whose held state fits the nominal best.

    Only the motions the clamps read from the scan do not take back are searched
    (:func:`seat_motions`, ``read`` (c,) bool). The held residual depends on the motion
    through each read clamp's offset (``offsets_at(xi)``) and through what the unread
    locators do not take back: robust Levenberg-Marquardt with a finite-difference Jacobian
    on a fixed sample of the points (Tukey weights: a defect does not seat the part) and a
    prior towards the free state's placement, each step accepted only if it lowers the
    cost. Each round re-takes the tangent planes of the sample's closest nominal points
    (``distances(Q)``: signed distances, closest points, triangles, normals)."""
    reach = float(np.linalg.norm(V - origin, axis=1).max())
    B = seat_motions(restraint, origin, reach, read)  # (6, q): xi = B z, mm at the reach
    if B.shape[1] == 0:
        return np.zeros(6)
    rng = np.random.default_rng(0)
    S = P[np.sort(rng.choice(len(P), min(_SEAT_SAMPLE, len(P)), replace=False))]
    q = B.shape[1]

    def linearised(z0: np.ndarray):
        """The held residual of the sample moved by ``B z`` (q,), on the tangent planes and
        held displacements of its closest nominal points with the sample moved by ``B z0``
        (re-taken each round: the held displacement varies along the surface, 16 um over
        a 0.8 mm slide on a shell lifted 2 mm at a corner)."""
        R0, t0 = rigid_motion(B @ z0, origin)
        pd0, C0, tri0, N0 = distances(S @ R0.T + t0)
        corr = pd0 - np.einsum("ij,ij->i", N0, S @ R0.T + t0 - C0)  # the curved surface's

        def residual(z: np.ndarray) -> np.ndarray:
            xi = B @ z
            R, t = rigid_motion(xi, origin)
            pd = np.einsum("ij,ij->i", N0, S @ R.T + t - C0) + corr
            u = restraint.apply(offsets_at(xi)).on_triangles(V, tri0, C0)
            return pd + np.einsum("ij,ij->i", N0, u)

        return residual

    z = np.zeros(q)
    residual = linearised(z)
    r0 = residual(z)
    scale = max(robust_scale(r0), 1e-3)
    z, r = _seat_rounds(linearised, residual, r0, scale, q)
    xi = B @ z
    log.info(
        "restrained seat: %.3g deg, %.3g mm (%d points; residual scale %.3g mm, rms %.3g -> "
        "%.3g mm)",
        np.degrees(np.linalg.norm(xi[:3])),
        np.linalg.norm(xi[3:]),
        len(S),
        scale,
        float(np.sqrt(np.mean(r0**2))),
        float(np.sqrt(np.mean(r**2))),
    )
    return xi


def _seat_rounds(
    linearised: Callable, residual: Callable, r: np.ndarray, scale: float, q: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`seat_held`'s robust Levenberg-Marquardt rounds from the free state's
    placement (``z = 0``, (q,); ``residual`` its linearisation there, ``r`` its held
    residual, mm; ``scale``: the Tukey scale, mm): the placement ``z`` and its residual."""
    z = np.zeros(q)
    # a prior on the placement (Tikhonov, towards the free state's): a motion must pay for
    # itself, 1 mm of it lowering the mean square held residual by a quarter of the held
    # residual's robust variance where it stands (at least (10 um)^2). Where the held state
    # explains the scan (a restrainable warp) that is little and the seat goes where it
    # fits; where it does not (a warp the clamps leave, a defect, another stiffness), a
    # slide over a gently curved surface could absorb it: such a seat, damped but without
    # a prior, slid 6 mm (bench/fixture.py, a thin shell with a bump)
    h = 0.05  # mm of motion at the part's reach

    def total(r: np.ndarray, z: np.ndarray, n_eff: float, prior: float) -> float:
        return float(tukey_rho(r, scale).sum()) + 0.5 * prior * n_eff * float(z @ z)

    for k in range(_SEAT_ROUNDS):
        if k:
            residual = linearised(z)
            r = residual(z)
        J = np.stack([(residual(z + h * np.eye(q)[i]) - r) / h for i in range(q)], 1)
        w = np.sqrt(tukey_weights(r, scale))
        n_eff = float(np.sum(w**2))
        prior = max(_SEAT_PRIOR, 0.25 * robust_scale(r) ** 2)
        cost = total(r, z, n_eff, prior)
        A = J * w[:, None]
        mu = prior * n_eff
        dz = np.linalg.solve(A.T @ A + mu * np.eye(q), -A.T @ (r * w) - mu * z)
        for step in (1.0, 0.5, 0.25):
            r_new = residual(z + step * dz)
            if total(r_new, z + step * dz, n_eff, prior) < cost:
                break
        else:
            break
        z, r = z + step * dz, r_new
        if step * np.linalg.norm(dz) < _SEAT_SETTLED:
            break
    return z, r


def seat_motions(
    restraint: RestraintBasis, origin: np.ndarray, reach: float, read: np.ndarray
) -> np.ndarray:
    """(6, q) the rigid motions ``(omega, t)`` per mm of motion at ``reach`` the seat
    searches: those that move an unread locator along its axis (``read`` (p,) bool per
    restrained direction). Every other motion is taken back by the drives the scan gives
    (its component along a read direction) or free at the contacts (along a face clamp's
    surface): the held state does not depend on it, and searching it let a seat walk along
    a flat valley (12.7 deg on a warped panel)."""
    S = np.r_[np.full(3, 1.0 / reach), np.ones(3)]
    held = np.flatnonzero(~np.asarray(read, dtype=bool))
    if len(held) == 0:
        return np.zeros((6, 0))
    at = (
        np.array([restraint.clamps[restraint.owner[j]].position for j in held], dtype=np.float64)
        - origin
    )
    e = restraint.directions[held]
    rows = np.c_[np.cross(at, e), e] * S  # each held axis' motion per mm of each motion
    _, sv, Vt = np.linalg.svd(rows, full_matrices=False)
    rank = int(np.sum(sv > 1e-3 * sv.max()))
    return S[:, None] * Vt[:rank].T


@dataclass
class ClampReadings:
    """Where each clamp's offset is read: the scan points under its pad on its own skin,
    each with its closest point ``C`` and normal ``n`` on the clamp's own face and the
    curved surface's correction ``corr`` (exact distance minus the tangent plane's)."""

    P: np.ndarray
    index: list[np.ndarray]
    C: list[np.ndarray]
    n: list[np.ndarray]
    corr: list[np.ndarray]

    def values(self, k: int) -> np.ndarray:
        """(r,) clamp ``k``'s readings, mm, the free state as it is."""
        idx = self.index[k]
        return np.einsum("ij,ij->i", self.n[k], self.P[idx] - self.C[k]) + self.corr[k]

    def uncertainty(self) -> np.ndarray:
        """(c,) expanded uncertainty of each clamp's offset, mm: the standard error of the
        median of its readings (:func:`median_uncertainty`; 0: fewer than 3 readings, the
        offset is not read from them)."""
        return np.array([median_uncertainty(self.values(k)) for k in range(len(self.index))])

    def offsets(self, R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
        """(c,) the clamps' offsets, mm (the median over each pad; NaN: fewer than 3
        points), the free state moved by ``R p + t`` (tangent planes: exact for a seat's
        small motions)."""
        out = np.full(len(self.index), np.nan)
        for k, idx in enumerate(self.index):
            if len(idx) < 3:
                continue
            Q = self.P[idx] if R is None else self.P[idx] @ R.T + t
            out[k] = pad_mean(np.einsum("ij,ij->i", self.n[k], Q - self.C[k]) + self.corr[k])
        return out


#: the held scan is nowhere near the part when the hold moves its points a median of more
#: than this share of the part's bounding diagonal (a clamp set or reading that no physical
#: fixture could apply to this scan)
FAR_HOLD = 0.1


def hold_too_far(held: HeldScan, diagonal: float) -> str | None:
    """Why the hold ``held`` places the scan nowhere near the part (None: it does not):
    the median distance, mm, its points were moved by the clamps is above
    :data:`FAR_HOLD` of the part's bounding ``diagonal`` (mm)."""
    moved = float(np.median(np.linalg.norm(held.P - held.P_free, axis=1)))
    if not np.isfinite(moved):
        return "the restrained hold gives no finite displacement: check the clamps"
    if moved <= FAR_HOLD * diagonal:
        return None
    return (
        f"the clamps move the held scan a median {moved:.1f} mm, more than "
        f"{FAR_HOLD:.0%} of the part's {diagonal:.0f} mm diagonal: the hold places the "
        "scan nowhere near the part (check the clamps' positions and directions)"
    )


def median_uncertainty(values: np.ndarray) -> float:
    """Expanded uncertainty, mm, of the median of a pad's readings ``values`` (r,) mm.

    The median's standard error, ``1.2533 sigma / sqrt(r)``, with ``sigma`` the readings'
    robust spread (interquartile range / 1.349), times Student's t at 95 % for ``r - 1``
    degrees of freedom (at least 2, the coverage of the other contributions). A pad read
    from a few points of both skins of a thin wall (a sparse scan whose normals there face
    either way) spreads its readings over the wall's thickness: its median is then known
    to a millimetre, not to the scan's noise, and the held deviations say so. 0 for fewer
    than 3 readings (the offset is not read from them)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if len(v) < 3:
        return 0.0
    sigma = float(np.subtract(*np.percentile(v, [75, 25]))) / 1.349
    k = max(2.0, float(stdtrit(len(v) - 1, 0.975)))  # Student's t quantile
    return k * 1.2533 * sigma / np.sqrt(len(v))


def clamp_readings(
    P: np.ndarray,
    Ns: np.ndarray,
    restraint: RestraintBasis,
    V: np.ndarray,
    F: np.ndarray,
    face_id: np.ndarray | None,
    brep_normals: np.ndarray | None,
    *,
    tree: cKDTree | None = None,
) -> ClampReadings:
    """The scan points that read each clamp's offset: within its pad radius, on the skin
    facing the clamp's way (outward scan normals ``Ns`` within
    :data:`qifreport.registration.restraint.restrained.FACING_ANGLE` of its normal: on a thin wall
    deflected beyond half its thickness the nearest nominal skin is the other one), each
    measured against the clamp's own B-rep face (a STEP nominal; the whole mesh else) and
    inside it (a point beyond the face's edge is not read). ``tree``: ``cKDTree(P)`` when at
    hand."""
    tree = cKDTree(P) if tree is None else tree
    cos = np.cos(np.radians(FACING_ANGLE))
    pos = np.array([c.position for c in restraint.clamps], dtype=np.float64)
    _, home, _ = closest_points(V, F, pos)
    index, Cs, ns, corrs = [], [], [], []
    for k in range(len(restraint.clamps)):
        idx = np.asarray(tree.query_ball_point(pos[k], restraint.pad_radius), dtype=np.int64)
        idx = idx[Ns[idx] @ restraint.normals[k] >= cos] if len(idx) else idx
        if len(idx) < 3:
            index.append(np.zeros(0, dtype=np.int64))
            Cs.append(np.zeros((0, 3)))
            ns.append(np.zeros((0, 3)))
            corrs.append(np.zeros(0))
            continue
        tris = np.arange(len(F)) if face_id is None else np.flatnonzero(face_id == face_id[home[k]])
        Fk = F[tris]
        C, local, pd = closest_points(V, Fk, P[idx])
        if face_id is not None:
            pd = surface_distance(
                V,
                Fk,
                C,
                local,
                pd,
                face_id[tris],
                None if brep_normals is None else brep_normals[tris],
                P[idx],
            )
        n = face_normals(V, Fk)[local]
        d = P[idx] - C
        plane = np.einsum("ij,ij->i", d, n)
        inside = np.linalg.norm(d - plane[:, None] * n, axis=1) < 1e-3  # mm: not beyond an edge
        index.append(idx[inside])
        Cs.append(C[inside])
        ns.append(n[inside])
        corrs.append((pd - plane)[inside])
    return ClampReadings(P=P, index=index, C=Cs, n=ns, corr=corrs)
