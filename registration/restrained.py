"""The restrained condition: the free-state part clamped by its elastic model.

ISO 10579 inspects a non-rigid part held as its drawing says: at stated points, along stated
directions, with a bounded force. What the part does between the clamps is decided by its
elasticity, not by a smoothness prior: a dent between two clamps stays a dent. This module
turns a free-state measurement into that restrained state:

1. each clamp's free-state offset along its restrained directions is read from the scan
   near it (:func:`clamp_offsets`: the median signed distance of the scan points within
   the pad radius to the nominal surface; NaN where the scan does not see it);
2. the elastic model (:mod:`qifreport.registration.elastic`) is solved with every clamp's
   pad driven back by that offset (:func:`restrain`): the displacement field ``u`` of the
   part and the force at every clamp;
3. the scan points are carried by ``u`` (:meth:`Restraint.displacement_at`): the restrained
   scan, judged as any other.

A free-state offset is observed along the surface normal only (a scan of a smooth surface
does not see it slide along itself): a clamp restraining an axis takes the normal offset's
component along that axis, and an axis in the surface's plane (a pin) holds its position.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .clamps import Clamp
from .elastic import ElasticModel, ElasticSolution, Pad

__all__ = ["Restraint", "clamp_offsets", "restrain"]

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
    solution : the elastic solution.  model : the elastic model.
    over_limit : names of the clamps whose force exceeds their limit.
    """

    clamps: list[Clamp]
    offsets: np.ndarray
    normals: np.ndarray
    forces: np.ndarray
    solution: ElasticSolution
    model: ElasticModel = field(repr=False)
    over_limit: list[str] = field(default_factory=list)

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
        nearest point inside its nearest tetrahedron)."""
        return self.model.displacement_at(self.solution, points)

    def to_dict(self) -> dict:
        return {
            "clamps": [
                c.to_dict()
                | {
                    "free_state_offset_mm": None if not np.isfinite(o) else float(o),
                    "force_N": float(f),
                    "over_limit": c.name in self.over_limit,
                }
                for c, o, f in zip(self.clamps, self.offsets, self.force, strict=True)
            ],
            "total_force_N": self.total_force,
            "energy_mJ": float(self.solution.energy),
            "not_restrainable": list(self.over_limit),
        }


def clamp_offsets(
    clamps: list[Clamp], P: np.ndarray, residual: np.ndarray, pad_radius: float
) -> np.ndarray:
    """(c,) each clamp's free-state offset along the surface normal, mm: the median signed
    distance ``residual`` (m,) of the scan points ``P`` (m, 3) within ``pad_radius`` mm of
    its nominal position (NaN: fewer than 3 points there, the scan does not see it)."""
    tree = cKDTree(np.asarray(P, dtype=np.float64))
    out = np.full(len(clamps), np.nan)
    r = np.asarray(residual, dtype=np.float64)
    for k, c in enumerate(clamps):
        idx = np.asarray(tree.query_ball_point(np.asarray(c.position), pad_radius), dtype=int)
        vals = r[idx[np.isfinite(r[idx])]] if len(idx) else np.zeros(0)
        if len(vals) >= 3:
            out[k] = float(np.median(vals))
    return out


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
    """Clamp the part: drive every clamp's pad back by its free-state offset.

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
    X = model.X
    cand = np.flatnonzero(surface) if surface is not None else np.arange(len(X))
    tree = cKDTree(X[cand])
    pads: list[Pad] = []
    owner: list[tuple[int, np.ndarray]] = []  # (clamp, direction) of each pad
    offsets = np.nan_to_num(np.asarray(offsets, dtype=np.float64), nan=0.0)
    for k, c in enumerate(clamps):
        verts = cand[np.asarray(tree.query_ball_point(np.asarray(c.position), pad_radius), int)]
        if len(verts) == 0:
            verts = cand[[int(tree.query(np.asarray(c.position))[1])]]
            log.info(
                "clamp %s: no model vertex within %.3g mm, the nearest taken", c.name, pad_radius
            )
        n = np.asarray(normals[k], dtype=np.float64)
        n = n / np.linalg.norm(n)
        for e in c.axes(n):
            # the free-state surface sits offsets[k] along n: bring it back along e
            pads.append(Pad(verts, e, -offsets[k] * float(n @ e), name=c.name))
            owner.append((k, e))
    sol = model.solve(pads=pads, load=load)
    forces = np.zeros((len(clamps), 3))
    for (k, e), f in zip(owner, sol.pad_forces, strict=True):
        forces[k] += f * e
    res = Restraint(
        clamps=list(clamps),
        offsets=np.asarray(offsets, dtype=np.float64),
        normals=np.asarray(normals, dtype=np.float64),
        forces=forces,
        solution=sol,
        model=model,
    )
    res.over_limit = [
        c.name
        for c, f in zip(clamps, res.force, strict=True)
        if c.max_force is not None and f > c.max_force
    ]
    return res
