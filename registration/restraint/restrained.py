"""The restrained condition: the free-state part clamped by its elastic model.

ISO 10579 inspects a non-rigid part held as its drawing says: at stated points, along stated
directions, with a bounded force. What the part does between the clamps is decided by its
elasticity, not by a smoothness prior: a dent between two clamps stays a dent. This module
turns a free-state measurement into that restrained state:

1. each clamp's free-state offset along its restrained directions is read from the scan
   near it (:func:`clamp_offsets`: the median signed distance of the scan points within
   the pad radius to the nominal surface; NaN where the scan does not see it);
2. the elastic model (:mod:`qifreport.registration.restraint.elastic`) is solved with every clamp's
   pad driven back by that offset (:func:`restrain`): the displacement field ``u`` of the
   part and the force at every clamp;
3. the scan points are carried by ``u`` (:meth:`Restraint.displacement_at`): the restrained
   scan, judged as any other.

The restrained state is linear in the clamps' offsets. :func:`restraint_basis` solves the
model once per part for each clamp direction's unit drive (and the part's weight) and keeps
only the responses at the nominal's vertices and the clamp forces: a per-part cache entry
of a few arrays. :meth:`RestraintBasis.apply` then restrains any scan in microseconds, with
the same result as :func:`restrain`'s direct solve.

A free-state offset is observed along the surface normal only (a scan of a smooth surface
does not see it slide along itself): a clamp restraining an axis takes the normal offset's
component along that axis, and an axis in the surface's plane (a pin) holds its position.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from qifreport.registration.mesh import barycentric
from qifreport.registration.restraint.clamps import Clamp
from qifreport.registration.restraint.elastic import ElasticModel, ElasticSolution, Pad

__all__ = [
    "FACING_ANGLE",
    "clamp_pads",
    "read_directions",
    "Restraint",
    "RestraintBasis",
    "clamp_offsets",
    "gradient_on_triangles",
    "interpolate_on_triangles",
    "pad_mean",
    "restrain",
    "restraint_basis",
    "rigid_motion",
    "transported_normals",
    "triangle_edges",
]

log = logging.getLogger(__name__)


@dataclass
class Restraint:
    """The part clamped: its displacement field and the clamps' forces.

    Attributes
    ----------
    clamps : the clamps, in order.  offsets : (c,) each clamp's free-state offset along its
        surface normal, mm (+: outside the material).
    normals : (c, 3) the nominal surface normal at each clamp.
    forces : (c, 3) the force each clamp applies to the part, N, in the part frame (the
        sum over its restrained directions); ``force`` (c,) its magnitude.
    energy : the strain energy the clamps put in, N mm (mJ).
    u, u_mid : (n, 3) and (e, 3) the displacement at the nominal's vertices and its edges'
        midpoints, mm (:meth:`RestraintBasis.apply`; None from :func:`restrain`): with
        ``F`` and ``tri_edges`` they interpolate it quadratically (:meth:`on_triangles`).
    over_limit : names of the clamps whose force exceeds their limit.
    offset_sources : where each offset was read (``"scan"``; ``"scan (local fit)"``: a
        locator placed with its face's neighbours; ``"free-state fit"``: a clamp the scan
        does not see; ``"seated (patch not seen)"``: a stop too little seen, placed by the
        held seat), when the caller says.
    model_info : the elastic model's provenance (material, mesh), from the basis.
    forces_known : False when the material was not stated: the held shape does not depend
        on Young's modulus, the forces do (reported as unknown, no limit checked).
    seat : (6,) the rigid motion ``(omega, t)`` (rad, mm) the free state was given before
        it was held, when the caller seated it (:func:`rigid_motion`).
    offset_uncertainty : (c,) expanded (k = 2) uncertainty of each offset read from the
        points under its pad, mm (0: not read there), when the caller says.
    solution, model : the elastic solution and model (:func:`restrain` only).
    """

    clamps: list[Clamp]
    offsets: np.ndarray
    normals: np.ndarray
    forces: np.ndarray
    energy: float
    u: np.ndarray | None = field(default=None, repr=False)
    u_mid: np.ndarray | None = field(default=None, repr=False)
    F: np.ndarray | None = field(default=None, repr=False)
    tri_edges: np.ndarray | None = field(default=None, repr=False)
    over_limit: list[str] = field(default_factory=list)
    offset_sources: list[str] = field(default_factory=list)
    seat: np.ndarray | None = None
    offset_uncertainty: np.ndarray | None = None
    forces_known: bool = True
    model_info: dict = field(default_factory=dict)
    solution: ElasticSolution | None = field(default=None, repr=False)
    model: ElasticModel | None = field(default=None, repr=False)

    @property
    def force(self) -> np.ndarray:
        return np.linalg.norm(self.forces, axis=1)

    @property
    def total_force(self) -> float:
        """The sum of the clamps' force magnitudes, N."""
        return float(self.force.sum())

    def displacement_at(self, points: np.ndarray) -> np.ndarray:
        """(m, 3) the displacement, mm, at ``points`` (m, 3) mm on or near the part (a
        point just outside the tetrahedra, by a chord's height, takes the value at the
        nearest point inside its nearest tetrahedron). Needs the model (:func:`restrain`);
        with a basis use :meth:`on_triangles`."""
        if self.model is None or self.solution is None:
            raise ValueError("a restraint from a basis carries its displacement on its mesh only")
        return self.model.displacement_at(self.solution, points)

    def on_triangles(self, V: np.ndarray, tri: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(m, 3) the displacement, mm, at ``points`` (m, 3) lying on the nominal's
        triangles ``tri`` (m,) (closest points), ``V`` (n, 3) its vertices: quadratic in
        each triangle through its corners' and edge midpoints' values."""
        if self.u is None:
            raise ValueError("a restraint from a direct solve: use displacement_at")
        return interpolate_on_triangles(self.u, V, self.F, tri, points, self.u_mid, self.tri_edges)

    def gradient_on_triangles(
        self, V: np.ndarray, tri: np.ndarray, points: np.ndarray
    ) -> np.ndarray:
        """(m, 3, 3) the displacement's gradient along each triangle's plane (zero along its
        normal) at the points of :meth:`on_triangles`: ``G[i] @ d`` is the change of the
        displacement over a step ``d`` (3,) mm in the surface."""
        if self.u is None:
            raise ValueError("a restraint from a direct solve: use displacement_at")
        return gradient_on_triangles(self.u, V, self.F, tri, points, self.u_mid, self.tri_edges)

    def to_dict(self) -> dict:
        src = self.offset_sources or [None] * len(self.clamps)
        unc = (
            np.zeros(len(self.clamps))
            if self.offset_uncertainty is None
            else np.asarray(self.offset_uncertainty, dtype=np.float64)
        )
        return {
            "clamps": [
                c.to_dict()
                | {
                    "free_state_offset_mm": None if not np.isfinite(o) else float(o),
                    "offset_source": s,
                    "free_state_offset_U_mm": float(u),
                    "force_N": float(f) if self.forces_known else None,
                    "force_vector_N": [float(x) for x in fv] if self.forces_known else None,
                    "over_limit": c.name in self.over_limit,
                }
                for c, o, f, fv, s, u in zip(
                    self.clamps, self.offsets, self.force, self.forces, src, unc, strict=True
                )
            ],
            "total_force_N": self.total_force if self.forces_known else None,
            "seat": None
            if self.seat is None
            else {
                "rotation_deg": float(np.degrees(np.linalg.norm(self.seat[:3]))),
                "translation_mm": [float(x) for x in self.seat[3:]],
            },
            "energy_mJ": float(self.energy) if self.forces_known else None,
            "not_restrainable": list(self.over_limit),
            "model": dict(self.model_info),
        }


@dataclass
class RestraintBasis:
    """A part's responses to its clamps (:func:`restraint_basis`): all a restrained
    inspection needs of the elastic model, as plain arrays (a per-part cache entry).

    Attributes
    ----------
    clamps : the clamps.  normals : (c, 3) unit nominal normals at them.
    owner : (p,) the clamp of each restrained direction.  directions : (p, 3) unit.
    coupling : (p,) ``normal . direction``: a free-state offset ``o`` along the normal
        drives direction j by ``-o * coupling[j]``.
    U : (n, 3, p) displacement at ``points`` (n, 3), the nominal's vertices, per mm of each
        drive; ``U_mid`` (e, 3, p) at the midpoints of its edges, ``F`` (f, 3) its
        triangles and ``tri_edges`` (f, 3) their edges (0-1, 1-2, 2-0).
    G : (p, p) force along each direction per mm of each drive, N/mm.
    U_load, U_mid_load, G_load : (n, 3), (e, 3) mm and (p,) N: the response to ``load``
        with the clamps at rest (None without a load).
    pad_radius : mm.  model : a summary of the elastic model (material, mesh, seconds).
    forces_known : the material was stated (else the forces are not reported nor checked).
    """

    clamps: list[Clamp]
    normals: np.ndarray
    owner: np.ndarray
    directions: np.ndarray
    coupling: np.ndarray
    points: np.ndarray
    F: np.ndarray
    tri_edges: np.ndarray
    U: np.ndarray
    U_mid: np.ndarray
    G: np.ndarray
    pad_radius: float
    U_load: np.ndarray | None = None
    U_mid_load: np.ndarray | None = None
    G_load: np.ndarray | None = None
    model: dict = field(default_factory=dict)
    forces_known: bool = True

    def apply(self, offsets: np.ndarray) -> Restraint:
        """Restrain a free state whose clamps sit ``offsets`` (c,) mm along their normals
        (NaN: unseen, taken as 0 -- the caller says so).

        A clamp face (``n``) is driven back by its offset, and so is a locator's axis the
        scan shows (:func:`read_directions`: a stop on a face seen facing it). A locator
        axis it does not show (a pin's axis in a smooth surface's plane) holds the free
        state where it was placed: the caller places it (:func:`rigid_motion`) where its
        held state fits best; such locators, statically determinate in a 3-2-1 scheme,
        then bend nothing."""
        d = _drives(self.clamps, self.owner, self.coupling, offsets)
        u, u_mid = self.U @ d, self.U_mid @ d
        f = self.G @ d
        energy = 0.5 * float(d @ f)  # the drives' (the weight's own is not the clamps')
        if self.U_load is not None:
            u, u_mid = u + self.U_load, u_mid + self.U_mid_load
            f = f + self.G_load
        forces = np.zeros((len(self.clamps), 3))
        np.add.at(forces, self.owner, f[:, None] * self.directions)
        res = Restraint(
            clamps=list(self.clamps),
            offsets=np.asarray(offsets, dtype=np.float64),
            normals=self.normals,
            forces=forces,
            energy=energy,
            u=u,
            u_mid=u_mid,
            F=self.F,
            tri_edges=self.tri_edges,
            forces_known=self.forces_known,
            model_info=dict(self.model),
        )
        res.over_limit = _over_limit(self.clamps, res.force) if self.forces_known else []
        return res


def rigid_motion(xi: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of the rigid motion ``xi = (omega, t)`` (rad, mm) about ``origin``: a
    point ``p`` goes to ``R p + t`` (Rodrigues' rotation by ``|omega|`` about ``omega``)."""
    w, tr = np.asarray(xi[:3], dtype=np.float64), np.asarray(xi[3:], dtype=np.float64)
    a = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if a < 1e-15:
        R = np.eye(3) + K
    else:
        K = K / a
        R = np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)
    o = np.asarray(origin, dtype=np.float64)
    return R, o + tr - R @ o


def read_directions(
    clamps: list[Clamp], owner: np.ndarray, coupling: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """(p,) bool: the restrained directions whose drive is read from the free state's
    offsets (c,) mm along the clamps' normals (NaN: not seen). A clamp face (``n``) is
    always driven (an unseen one by the caller's witness); a locator's axis is read where
    the surface under it faces that axis within :data:`FACING_ANGLE` (``|coupling|``: a
    stop on an end face, seen by the scan, shows how far the part is from it) and the scan
    saw it; else it is not (a pin's axis in a smooth surface's plane: a scan of that
    surface does not show where its material went)."""
    off = np.asarray(offsets, dtype=np.float64)
    face = np.array([clamps[k].directions == "n" for k in owner], dtype=bool)
    facing = np.abs(coupling) >= np.cos(np.radians(FACING_ANGLE))
    return face | (facing & np.isfinite(off[owner]))


def _drives(
    clamps: list[Clamp], owner: np.ndarray, coupling: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """(p,) each restrained direction's drive, mm: a direction read from the free state
    (:func:`read_directions`) takes its offset back along it (``coupling`` (p,): normal .
    direction); a locator's axis that cannot be read holds where the free state was
    placed (0). ``owner`` (p,): the clamp of each direction; ``offsets`` (c,) NaN taken as
    0."""
    read = read_directions(clamps, owner, coupling, offsets)
    off = np.nan_to_num(np.asarray(offsets, dtype=np.float64), nan=0.0)
    return np.where(read, -off[owner] * coupling, 0.0)


def _over_limit(clamps: list[Clamp], force: np.ndarray) -> list[str]:
    return [
        c.name
        for c, f in zip(clamps, force, strict=True)
        if c.max_force is not None and f > c.max_force
    ]


def clamp_pads(
    X: np.ndarray,
    clamps: list[Clamp],
    normals: np.ndarray,
    pad_radius: float,
    surface: np.ndarray | None,
    surface_normals: np.ndarray | None = None,
) -> tuple[list[Pad], list[tuple[int, np.ndarray]]]:
    """The contacts of clamps on an elastic model: one :class:`Pad` per clamp direction
    (value 0, holding its mean position), and (clamp index, unit direction) of each.

    Parameters
    ----------
    X : (N, 3) the model's vertices, mm.  clamps : the clamps.
    normals : (c, 3) the surface's normal at each clamp.  pad_radius : mm.
    surface : (N,) bool the model's surface vertices (None: all).
    surface_normals : (N, 3) their normals: a pad takes the surface vertices within
        ``pad_radius`` of its clamp whose surface faces the clamp's within
        :data:`FACING_ANGLE`, either side (its nearest vertex when none is that close).
    """
    cand = np.flatnonzero(surface) if surface is not None else np.arange(len(X))
    tree = cKDTree(X[cand])
    pads: list[Pad] = []
    owner: list[tuple[int, np.ndarray]] = []
    cos = np.cos(np.radians(FACING_ANGLE))
    for k, c in enumerate(clamps):
        verts = cand[np.asarray(tree.query_ball_point(np.asarray(c.position), pad_radius), int)]
        if surface_normals is not None and len(verts):
            facing = np.abs(surface_normals[verts] @ np.asarray(normals[k], dtype=float)) >= cos
            verts = verts[facing] if facing.any() else verts
        if len(verts) == 0:
            verts = cand[[int(tree.query(np.asarray(c.position))[1])]]
            log.info(
                "clamp %s: no model vertex within %.3g mm, the nearest taken", c.name, pad_radius
            )
        n = np.asarray(normals[k], dtype=np.float64)
        n = n / np.linalg.norm(n)
        for e in c.axes(n):
            # a contact holds its mean position along its direction and lets the surface
            # turn under it: a rigid face that also holds the tilt made the held shape
            # depend on how many mesh vertices the pad caught (two meshes of one 2 mm sheet
            # held 0.108 mm rms apart with rigid faces, 0.011 mm with mean contacts)
            pads.append(Pad(verts, e, 0.0, name=c.name, mean=True))
            owner.append((k, e))
    return pads, owner


def restraint_basis(
    model: ElasticModel,
    clamps: list[Clamp],
    normals: np.ndarray,
    V: np.ndarray,
    F: np.ndarray,
    *,
    pad_radius: float,
    surface: np.ndarray | None = None,
    surface_normals: np.ndarray | None = None,
    load: np.ndarray | None = None,
) -> RestraintBasis:
    """Solve the part's elastic model once for each clamp direction's unit drive.

    Parameters
    ----------
    model : the part's elastic model.  clamps : the clamps (together holding the six rigid
        motions).  normals : (c, 3) unit outward surface normals at the clamps.
    V : (n, 3) mm, F : (f, 3) the nominal's mesh: the responses are kept at its vertices
        and edge midpoints.
    pad_radius : mm, the contact's radius: the model's vertices within it move together.
    surface : (N,) bool, the model's vertices on the part's surface (default all).
    surface_normals : (N, 3) unit normals at the model's surface vertices: a pad takes
        only those facing its clamp's surface (a locator on a thin end face does not
        hold the faces beside it).
    load : (N_dofs,) a load vector (the part's weight, :meth:`ElasticModel.gravity`), N.

    Raises
    ------
    ValueError
        Clamps that leave a rigid motion free.
    """
    pads, owner = clamp_pads(model.X, clamps, normals, pad_radius, surface, surface_normals)
    D, G = model.pad_responses(pads, load)
    V = np.asarray(V, dtype=np.float64)
    edges, tri_edges = triangle_edges(F)
    Q = np.vstack([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])])
    M = model.probes(Q)
    n, p = len(V), len(pads)
    U = np.asarray(M @ D).reshape(3, len(Q), -1).transpose(1, 0, 2)  # (n + e, 3, p[+1])
    nrm = np.asarray(normals, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    k = np.array([o[0] for o in owner], dtype=np.int64)
    E = np.array([o[1] for o in owner], dtype=np.float64).reshape(-1, 3)
    return RestraintBasis(
        clamps=list(clamps),
        normals=nrm,
        owner=k,
        directions=E,
        coupling=np.einsum("pd,pd->p", nrm[k], E),
        points=V,
        F=np.asarray(F, dtype=np.int64),
        tri_edges=tri_edges,
        U=np.ascontiguousarray(U[:n, :, :p]),
        U_mid=np.ascontiguousarray(U[n:, :, :p]),
        G=G[:, :p],
        pad_radius=float(pad_radius),
        U_load=None if load is None else U[:n, :, p].copy(),
        U_mid_load=None if load is None else U[n:, :, p].copy(),
        G_load=None if load is None else G[:, p].copy(),
        model={
            "material": model.material.to_dict(),
            "vertices": len(model.X),
            "tetrahedra": len(model.T),
            "order": model.order,
            "dofs": model.n_dofs,
        },
    )


def triangle_edges(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unique edges ``(e, 2)`` of triangles ``F`` (f, 3) and each triangle's edges
    ``(f, 3)``: 0-1, 1-2, 2-0."""
    F = np.asarray(F, dtype=np.int64)
    half = np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1).reshape(-1, 2)
    edges, inv = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True)
    return edges, inv.reshape(-1, 3)


#: a scan point reads a clamp's offset when its surface faces the clamp's within this angle
#: (either side: a thin wall's two skins move together), degrees
FACING_ANGLE = 45.0


def clamp_offsets(
    clamps: list[Clamp],
    P: np.ndarray,
    residual: np.ndarray,
    pad_radius: float,
    normals: np.ndarray | None = None,
    point_normals: np.ndarray | None = None,
    inside: np.ndarray | None = None,
) -> np.ndarray:
    """(c,) each clamp's free-state offset along its surface normal, mm: the median
    (:func:`pad_mean`) of the signed distances ``residual`` (m,) of the scan points ``P``
    (m, 3) within ``pad_radius`` mm of its nominal position (NaN: fewer than 3 points
    there, the scan does not see it).

    With the clamps' ``normals`` (c, 3) and the nominal normals ``point_normals`` (m, 3)
    where each point was measured, only the points on surfaces facing the clamp's within
    :data:`FACING_ANGLE` count (a locator on a thin end face is not read from the faces
    beside it), a point on the opposite skin with its sign turned. ``inside`` (m,) bool:
    the points measured inside a face (their closest point not on an edge: a point beyond
    a thin face's edge reads its distance to the edge, not the face's offset)."""
    tree = cKDTree(np.asarray(P, dtype=np.float64))
    out = np.full(len(clamps), np.nan)
    r = np.asarray(residual, dtype=np.float64)
    cos = np.cos(np.radians(FACING_ANGLE))
    for k, c in enumerate(clamps):
        idx = np.asarray(tree.query_ball_point(np.asarray(c.position), pad_radius), dtype=int)
        if len(idx):
            ok = np.isfinite(r[idx]) & (True if inside is None else inside[idx])
            idx = idx[ok]
        vals = r[idx] if len(idx) else np.zeros(0)
        if len(idx) and normals is not None and point_normals is not None:
            dot = point_normals[idx] @ np.asarray(normals[k], dtype=np.float64)
            keep = np.abs(dot) >= cos
            vals = vals[keep] * np.sign(dot[keep])
        if len(vals) >= 3:
            out[k] = pad_mean(vals)
    return out


def pad_mean(values: np.ndarray) -> float:
    """A clamp's offset from the readings under its pad, mm: their median. Robust to the
    readings of the other skin of a thin wall or of a neighbouring face that slip through
    (a trimmed mean, closer to the contact's mean position on a sloping pad, was moved by
    0.8 mm on the sample panel's flanges); on a pad clipped by a corner where the surface
    slopes it reads the centre's value, within 1.5 % of the slope's lift."""
    return float(np.median(np.asarray(values, dtype=np.float64)))


def restrain(
    model: ElasticModel,
    clamps: list[Clamp],
    offsets: np.ndarray,
    normals: np.ndarray,
    *,
    pad_radius: float,
    surface: np.ndarray | None = None,
    load: np.ndarray | None = None,
) -> Restraint:
    """Clamp the part: drive every clamp face back by its free-state offset (locators hold
    the placement given, as :meth:`RestraintBasis.apply`); one direct solve.

    Parameters
    ----------
    model : the part's elastic model.  clamps : the clamps (together holding the six rigid
        motions).
    offsets : (c,) free-state offsets along the surface normal, mm (:func:`clamp_offsets`;
        NaN: unseen, taken as 0 -- the caller says so).
    normals : (c, 3) unit surface normals at the clamps (outward).
    pad_radius : mm, the contact's radius: the model's vertices within it move together.
    surface : (n,) bool, the model's vertices on the part's surface (default all).
    load : (N,) a load vector (gravity), N.

    Raises
    ------
    ValueError
        A pad with no vertex of the model, or clamps that leave a rigid motion free.
    """
    pads, owner = clamp_pads(model.X, clamps, normals, pad_radius, surface)
    offsets = np.asarray(offsets, dtype=np.float64)
    k = np.array([o[0] for o in owner], dtype=np.int64)
    nrm = np.asarray(normals, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    coupling = np.array([float(nrm[j] @ e) for j, e in owner])
    for pad, d in zip(pads, _drives(clamps, k, coupling, offsets), strict=True):
        pad.value = float(d)
    sol = model.solve(pads=pads, load=load)
    forces = np.zeros((len(clamps), 3))
    for (k, e), f in zip(owner, sol.pad_forces, strict=True):
        forces[k] += f * e
    res = Restraint(
        clamps=list(clamps),
        offsets=offsets,
        normals=np.asarray(normals, dtype=np.float64),
        forces=forces,
        energy=float(sol.energy),
        solution=sol,
        model=model,
    )
    res.over_limit = _over_limit(clamps, res.force)
    return res


def _inside_weights(V: np.ndarray, F: np.ndarray, tri: np.ndarray, points: np.ndarray):
    """(m, 3) the barycentric coordinates of ``points`` (m, 3) in their triangles ``tri``
    (m,), clipped to the triangle (no negative weight) and summing to 1."""
    w = np.clip(barycentric(V, F, tri, points), 0.0, None)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    return w


def interpolate_on_triangles(
    values: np.ndarray,
    V: np.ndarray,
    F: np.ndarray,
    tri: np.ndarray,
    points: np.ndarray,
    mid: np.ndarray | None = None,
    tri_edges: np.ndarray | None = None,
) -> np.ndarray:
    """(m, k) a field at ``points`` (m, 3) on the triangles ``tri`` (m,) of the mesh
    ``(V, F)`` (closest points): from its vertex ``values`` (n, k), linear in each triangle;
    with its values ``mid`` (e, k) at the edges' midpoints (``tri_edges`` (f, 3), see
    :func:`triangle_edges`), quadratic."""
    w = _inside_weights(V, F, tri, points)
    vals = np.asarray(values)
    if mid is None:
        return np.einsum("ij,ij...->i...", w, vals[F[tri]])
    # quadratic (P2) shape functions: corners l(2l - 1), edge midpoints 4 l_a l_b
    wc = w * (2.0 * w - 1.0)
    we = 4.0 * np.c_[w[:, 0] * w[:, 1], w[:, 1] * w[:, 2], w[:, 2] * w[:, 0]]
    return np.einsum("ij,ij...->i...", wc, vals[F[tri]]) + np.einsum(
        "ij,ij...->i...", we, np.asarray(mid)[tri_edges[tri]]
    )


def gradient_on_triangles(
    values: np.ndarray,
    V: np.ndarray,
    F: np.ndarray,
    tri: np.ndarray,
    points: np.ndarray,
    mid: np.ndarray | None = None,
    tri_edges: np.ndarray | None = None,
) -> np.ndarray:
    """(m, k, 3) the surface gradient of the field :func:`interpolate_on_triangles` gives
    (same arguments) at ``points`` (m, 3): per unit length (field unit per mm) along the
    plane of each point's triangle, zero along its normal; ``G[i] @ d`` is the field's change
    over a step ``d`` (3,) mm in that plane. A degenerate triangle gives zero."""
    w = _inside_weights(V, F, tri, points)
    X = V[F[tri]]  # (m, 3 corners, 3)
    n = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    twice_area = np.linalg.norm(n, axis=1)
    twice_area[twice_area == 0] = np.inf  # a degenerate triangle: no normal, no gradient
    n /= twice_area[:, None]
    # the gradients of the barycentric coordinates: each corner's opposite edge turned in
    # the plane towards it, over twice the area
    opposite = np.stack([X[:, 2] - X[:, 1], X[:, 0] - X[:, 2], X[:, 1] - X[:, 0]], axis=1)
    grad_l = np.cross(n[:, None, :], opposite) / twice_area[:, None, None]
    vals = np.asarray(values)
    if mid is None:
        return np.einsum("ijk,ijl->ikl", vals[F[tri]], grad_l)
    grad_c = (4.0 * w - 1.0)[:, :, None] * grad_l
    a, b = (0, 1, 2), (1, 2, 0)
    grad_e = 4.0 * (w[:, b, None] * grad_l[:, a] + w[:, a, None] * grad_l[:, b])
    return np.einsum("ijk,ijl->ikl", vals[F[tri]], grad_c) + np.einsum(
        "ijk,ijl->ikl", np.asarray(mid)[tri_edges[tri]], grad_e
    )


def transported_normals(N: np.ndarray, R: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(m, 3) unit normals ``N`` (m, 3) of points moved by the rotation ``R`` (3, 3) and
    then by a displacement whose surface gradient there is ``G`` (m, 3, 3)
    (:func:`gradient_on_triangles`): the cofactor of the deformation ``I + G`` on each
    rotated normal, ``(I + G)^-T R n``, the normal of the moved surface (exact for an
    affine displacement of a plane)."""
    D = np.eye(3) + G
    out = np.linalg.solve(np.swapaxes(D, 1, 2), (N @ R.T)[:, :, None])[:, :, 0]
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out
