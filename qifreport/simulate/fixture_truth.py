"""The simulated physical fixture: what a fixtured CMM measures, the restrained fixture's truth.

A compliant part's free state is its stress-free shape, which is not the nominal: it was
warped when it cooled (the lowest elastic modes at bounded energy, the paper's stated
design, Section 1.2), its clamp points were pushed while it was handled, and it may carry a
plastic defect (a dent, a bump, a flange that sprang back). A physical fixture clamps that
shape at its RPS points: each contact is driven back to its nominal position along the
directions it restrains, and what the part does between the contacts is decided by its
elasticity. Everything here is linear in the free state's displacement, so a fixture is
its responses to a unit drive of each contact (one factorisation per part).

This is the truth the product's restrained inspection is measured against; it must not be
the product's own model (the paper's Section 4.3 warning). The benchmark builds it on
another mesh (finer tetrahedra or another sheet tessellation), another Poisson's ratio and a
wall whose stiffness varies over the part (:func:`uneven_wall`); the product only ever sees
the resulting scan. Unlike the product, which holds its locators where the held part seats
best (a scan does not show a hole's offset), the truth drives every contact, locators
included, back to its nominal position: the part pushed against its stops.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from qifreport.registration.restraint.clamps import Clamp
from qifreport.registration.restraint.elastic import ElasticModel, Pad, elastic_modes
from qifreport.registration.restraint.restrained import clamp_pads

__all__ = [
    "FreeState",
    "HeldTruth",
    "SimulatedFixture",
    "dent",
    "hold",
    "simulated_fixture",
    "springback",
    "uneven_wall",
]

Field = Callable[[np.ndarray], np.ndarray]


@dataclass
class SimulatedFixture:
    """A part's physical fixture (:func:`simulated_fixture`).

    Attributes
    ----------
    model : the truth's elastic model.  clamps : the clamps; ``normals`` (c, 3) unit.
    pads : one contact per restrained direction; ``owner`` (p,) its clamp and
        ``directions`` (p, 3) its unit direction.
    D : (N, p) the model's degrees of freedom per mm of each contact's drive.
    G : (p, p) force along each direction per mm of each drive, N/mm.
    omega2, modes : (k,) 1/s^2 and (N, k) the lowest elastic modes of the free part.
    """

    model: ElasticModel
    clamps: list[Clamp]
    normals: np.ndarray
    pads: list[Pad]
    owner: np.ndarray
    directions: np.ndarray
    D: np.ndarray
    G: np.ndarray
    omega2: np.ndarray
    modes: np.ndarray

    def at(self, dofs: np.ndarray, points: np.ndarray | sp.spmatrix) -> np.ndarray:
        """(m, 3) displacement, mm, of the degrees of freedom ``dofs`` (N,) at ``points``
        (m, 3), or at the points of a probe matrix (:meth:`ElasticModel.probes`, (3m, N));
        (m, 3, q) for ``dofs`` (N, q)."""
        M = points if sp.issparse(points) else self.model.probes(points)
        A = np.asarray(M @ dofs)
        m = M.shape[0] // 3
        if A.ndim == 1:
            return A.reshape(3, m).T
        return A.reshape(3, m, -1).transpose(1, 0, 2)

    def mode_scale(self, points: np.ndarray) -> np.ndarray:
        """(k,) the largest displacement, mm, of each mode at ``points`` (the surface)."""
        u = self.at(self.modes, points)  # (m, 3, k)
        return np.linalg.norm(u, axis=1).max(axis=0)


def simulated_fixture(
    model: ElasticModel,
    clamps: list[Clamp],
    normals: np.ndarray,
    *,
    pad_radius: float,
    surface: np.ndarray | None = None,
    surface_normals: np.ndarray | None = None,
    n_modes: int = 6,
) -> SimulatedFixture:
    """Build the fixture: one contact per restrained direction (the model's surface
    vertices within ``pad_radius`` mm of the clamp, facing its surface), their responses
    (one factorisation) and the lowest ``n_modes`` elastic modes of the free part.

    Parameters
    ----------
    model : the truth's elastic model.  clamps : clamps holding the six rigid motions.
    normals : (c, 3) outward unit normals at the clamps.  pad_radius : mm.
    surface : (N,) bool the model's surface vertices; ``surface_normals`` (N, 3) theirs.
    """
    normals = np.asarray(normals, dtype=np.float64)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    pads, contacts = clamp_pads(model.X, clamps, normals, pad_radius, surface, surface_normals)
    owner = [k for k, _ in contacts]
    dirs = [np.asarray(e, dtype=np.float64) for _, e in contacts]
    D, G = model.pad_responses(pads)
    omega2, modes = elastic_modes(model, n_modes) if n_modes else (np.zeros(0), None)
    return SimulatedFixture(
        model=model,
        clamps=list(clamps),
        normals=normals,
        pads=pads,
        owner=np.asarray(owner, dtype=np.int64),
        directions=np.array(dirs),
        D=D,
        G=G,
        omega2=omega2,
        modes=modes,
    )


@dataclass
class FreeState:
    """A free (stress-free) shape: nominal + the elastic part ``dofs`` (N,) of the truth
    model (pushed clamp points, warp modes) + plastic ``defects`` (functions of the
    nominal position (m, 3) giving a displacement (m, 3), mm)."""

    dofs: np.ndarray
    defects: tuple[Field, ...] = ()

    def displacement(
        self, fx: SimulatedFixture, points: np.ndarray, probe: sp.spmatrix | None = None
    ) -> np.ndarray:
        """(m, 3) mm at ``points`` (m, 3) on the nominal surface (``probe``: their
        :meth:`ElasticModel.probes`, when known)."""
        u = fx.at(self.dofs, points if probe is None else probe)
        for d in self.defects:
            u = u + d(points)
        return u


@dataclass
class HeldTruth:
    """The free state clamped: ``u`` (m, 3) displacement from nominal at the points asked,
    mm; ``drives`` (p,) mm; ``forces`` (c, 3) N each clamp applies; ``force`` (c,) N."""

    u: np.ndarray
    drives: np.ndarray
    forces: np.ndarray

    @property
    def force(self) -> np.ndarray:
        return np.linalg.norm(self.forces, axis=1)


def hold(
    fx: SimulatedFixture, state: FreeState, points: np.ndarray, probe: sp.spmatrix | None = None
) -> HeldTruth:
    """Clamp ``state``: each contact (its pad's mean along its direction) driven back to
    nominal; the held displacement at ``points`` (m, 3) (``probe``: their probe matrix) and
    the clamps' forces."""
    X = fx.model.X
    off = np.empty(len(fx.pads))
    for j, pad in enumerate(fx.pads):
        v = np.asarray(pad.vertices, dtype=np.int64)
        u = state.displacement(fx, X[v])
        off[j] = float(np.mean(u @ fx.directions[j]))
    drives = -off
    dofs = state.dofs + fx.D @ drives
    u = fx.at(dofs, points if probe is None else probe)
    for d in state.defects:
        u = u + d(points)
    f = fx.G @ drives
    forces = np.zeros((len(fx.clamps), 3))
    np.add.at(forces, fx.owner, f[:, None] * fx.directions)
    return HeldTruth(u=u, drives=drives, forces=forces)


def dent(center: np.ndarray, direction: np.ndarray, amplitude: float, sigma: float) -> Field:
    """A plastic dent (``amplitude`` < 0 along ``direction``) or bump (> 0): the wall moved
    by ``a exp(-r^2 / sigma^2)`` mm along one direction (a punch's), ``r`` the distance
    from ``center`` (the paper's Eq. 16 width convention)."""
    c = np.asarray(center, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)

    def field(P: np.ndarray) -> np.ndarray:
        r2 = np.sum((np.asarray(P, dtype=np.float64) - c) ** 2, axis=1)
        return amplitude * np.exp(-r2 / sigma**2)[:, None] * d

    return field


def springback(origin: np.ndarray, axis: np.ndarray, side: np.ndarray, angle: float) -> Field:
    """A flange that sprang back: the part beyond the bend line (``origin`` + s ``axis``,
    on the side ``(p - origin) . side > 0``) turned by ``angle`` rad about it (small)."""
    o = np.asarray(origin, dtype=np.float64)
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    s = np.asarray(side, dtype=np.float64)

    def field(P: np.ndarray) -> np.ndarray:
        r = np.asarray(P, dtype=np.float64) - o
        beyond = (r @ s) > 0
        return angle * np.cross(a, r) * beyond[:, None]

    return field


def uneven_wall(
    centroids: np.ndarray, spread: float, length: float, rng: np.random.Generator
) -> np.ndarray:
    """(k,) stiffness factors ``(t / t0)^3`` of a wall whose thickness ``t`` varies
    smoothly by up to ``+/- spread`` (0.1: 10 %) over the part, with a correlation length
    ``length`` mm (a sum of random plane waves, scaled to the spread)."""
    C = np.asarray(centroids, dtype=np.float64)
    k = rng.normal(size=(8, 3))
    k = k / np.linalg.norm(k, axis=1, keepdims=True) * (2 * np.pi / length)
    phase = rng.uniform(0, 2 * np.pi, 8)
    w = np.sin(C @ k.T + phase).sum(axis=1)
    w = w / np.abs(w).max()
    return (1.0 + spread * w) ** 3
