"""Free states made by the part's own elasticity (the physical simulator).

A compliant part's free state is what its elasticity makes of the loads it saw: it lay on
supports under gravity, its clamp points were pushed while it cooled or was handled. Such
a state is, by construction, one a fixture can take back within the forces it needs (a
plastic defect superimposed on it is not). :func:`elastic_free_state` makes one: the part's
elastic model (:mod:`qifreport.registration.restraint.elastic`) held at its clamps, each displaced
by
a given amount along its first restrained direction, optionally under its own weight.

The truth of a benchmark must not be the product's own model, or it only measures itself
(the paper's Section 4.3 warning about its generator). The callers here use a finer mesh
than the product's (its own tetrahedra, :func:`qifreport.step.gmsh_mesh.gmsh_solid_mesh`),
another Poisson's ratio and clamp pads of another size; the product only ever sees the
resulting scan.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from qifreport.registration.restraint.clamps import Clamp
from qifreport.registration.restraint.elastic import ElasticModel, ElasticSolution
from qifreport.registration.restraint.restrained import clamp_pads

__all__ = ["elastic_free_state", "held_free_solution"]


def elastic_free_state(
    model: ElasticModel,
    clamps: list[Clamp],
    normals: np.ndarray,
    lifts: dict[str, float],
    points: np.ndarray,
    *,
    pad_radius: float,
    surface: np.ndarray | None = None,
    surface_normals: np.ndarray | None = None,
    load: np.ndarray | None = None,
) -> np.ndarray:
    """(m, 3) the displacement, mm, at ``points`` (m, 3) of the part held at its clamps
    with clamp ``name`` displaced by ``lifts[name]`` mm along its first restrained
    direction (the others held at nominal), under ``load`` (N per degree of freedom).

    Parameters
    ----------
    model : the truth's elastic model.  clamps : the clamps (holding six rigid motions).
    normals : (c, 3) unit outward normals at the clamps.
    lifts : mm per clamp name (absent: 0).
    points : where the displacement is wanted (the scanned surface's vertices).
    pad_radius : mm, each contact's radius.  surface : (N,) bool, the model's surface
        vertices (default all); ``surface_normals`` (N, 3) their normals: a pad touches
        only the vertices facing its clamp's surface within 45 degrees.
    """
    sol = held_free_solution(
        model,
        clamps,
        normals,
        lifts,
        pad_radius=pad_radius,
        surface=surface,
        surface_normals=surface_normals,
        load=load,
    )
    return model.displacement_at(sol, points)


def held_free_solution(
    model: ElasticModel,
    clamps: list[Clamp],
    normals: np.ndarray,
    lifts: dict[str, float],
    *,
    pad_radius: float,
    surface: np.ndarray | None = None,
    surface_normals: np.ndarray | None = None,
    load: np.ndarray | None = None,
) -> ElasticSolution:
    """The model's solution behind :func:`elastic_free_state` (same parameters): its
    ``energy`` is the free state's strain energy (mJ), its ``pad_forces`` the clamps' (N)."""
    pads, contacts = clamp_pads(model.X, clamps, normals, pad_radius, surface, surface_normals)
    first = {}
    for j, (k, _) in enumerate(contacts):  # each clamp's first direction is lifted
        first.setdefault(k, j)
    pads = [
        replace(p, value=lifts.get(clamps[k].name, 0.0)) if first[k] == j else p
        for j, (p, (k, _)) in enumerate(zip(pads, contacts, strict=True))
    ]
    return model.solve(pads=pads, load=load)
