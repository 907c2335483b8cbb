"""Linear elasticity of a part: the physical model behind a restrained virtual fixture.

A compliant part has no single shape until it is clamped (ISO 10579; ASME Y14.5 restraint
notes): what it does between its clamps is decided by its elasticity. This module holds
that elasticity for the fixture: a tetrahedral mesh of the part's solid (a STEP
part's from gmsh, :func:`qifreport.step.gmsh_mesh.gmsh_solid_mesh`; a sheet's mid-surface
thickened, :mod:`qifreport.registration.restraint.sheet_solid`), quadratic tetrahedra (a thin wall
in
bending does not lock: the displacement is quadratic through each element), assembled and
solved with scikit-fem.

Units are consistent throughout: mm, N, MPa (N/mm^2), t/mm^3 (tonne per cubic millimetre),
mm/s^2 for gravity (9810), so that a density times gravity is a force per volume in N/mm^3.

Public API
----------
:class:`Material` and :data:`MATERIALS` (presets) -- :func:`material` to pick one or
build one from explicit values; :func:`elastic_model` assembles the stiffness of a
tetrahedral mesh once; :meth:`ElasticModel.solve` applies prescribed displacements and
body forces and returns the displacement of every mesh vertex.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from qifreport.registration.arrays import unique_sorted
from qifreport.registration.linalg import SPDSolver
from qifreport.registration.ordering import nested_dissection
from qifreport.registration.restraint.clamp_set import rigid_motion_matrix

__all__ = [
    "GRAVITY",
    "rigid_rank",
    "MATERIALS",
    "ElasticModel",
    "ElasticSolution",
    "Material",
    "Pad",
    "elastic_model",
    "elastic_modes",
    "material",
]

log = logging.getLogger(__name__)

#: standard gravity, mm/s^2
GRAVITY = 9810.0


@dataclass(frozen=True)
class Material:
    """An isotropic linear elastic material.

    Attributes
    ----------
    name : a label for the reports.
    E : Young's modulus, MPa (N/mm^2).  nu : Poisson's ratio.
    density : t/mm^3 (1 g/cm^3 = 1e-9 t/mm^3).
    yield_strength : the stress beyond which the material no longer springs back, MPa
        (yield or 0.2 % proof stress; a brittle fill's strength at break); None: not known.
    """

    name: str
    E: float
    nu: float
    density: float
    yield_strength: float | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.E) and self.E > 0):
            raise ValueError(f"Young's modulus must be positive (MPa), got {self.E}")
        if not (-1.0 < self.nu < 0.5):
            raise ValueError(f"Poisson's ratio must lie in (-1, 0.5), got {self.nu}")
        if not (np.isfinite(self.density) and self.density >= 0):
            raise ValueError(f"density must be >= 0 (t/mm^3), got {self.density}")
        ys = self.yield_strength
        if ys is not None and not (np.isfinite(ys) and ys > 0):
            raise ValueError(f"yield strength must be positive (MPa), got {ys}")

    @property
    def lame(self) -> tuple[float, float]:
        """Lame's parameters (lambda, mu), MPa."""
        E, nu = self.E, self.nu
        return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "E_MPa": float(self.E),
            "nu": float(self.nu),
            "density_t_per_mm3": float(self.density),
            "yield_MPa": None if self.yield_strength is None else float(self.yield_strength),
        }


#: presets (handbook values at room temperature; a drawing's material overrides them). The
#: yield strengths are the low end of each class (docs/restraint.md gives the sources):
#: structural steel S235 (EN 10025-2, ReH), EN AW-6061-T6 (EN 755-2, Rp0.2), and the
#: plastics' tensile stress at yield (ISO 527, conditioned; PA6-GF30 at break)
MATERIALS = {
    "steel": Material("steel", 210_000.0, 0.30, 7.85e-9, 235.0),
    "aluminium": Material("aluminium", 70_000.0, 0.33, 2.70e-9, 240.0),
    "pp": Material("PP", 1_500.0, 0.42, 0.905e-9, 30.0),
    "abs": Material("ABS", 2_300.0, 0.35, 1.05e-9, 40.0),
    "pa6-gf30": Material("PA6-GF30", 9_500.0, 0.35, 1.36e-9, 100.0),
}


def material(spec: str) -> Material:
    """A preset by name (``steel``, ``aluminium``, ``pp``, ``abs``, ``pa6-gf30``; case
    insensitive, ``aluminum`` accepted) or explicit values ``E=70000,nu=0.33,density=2.7e-9``
    (MPa, -, t/mm^3; ``density`` optional, 0 without gravity; ``yield=240`` MPa optional,
    unknown without it).

    Raises
    ------
    ValueError
        An unknown name or a malformed or out-of-range value, naming it.
    """
    key = spec.strip().lower().replace("aluminum", "aluminium")
    if key in MATERIALS:
        return MATERIALS[key]
    if "=" not in key:
        raise ValueError(
            f"unknown material {spec!r}: one of {', '.join(MATERIALS)} or "
            "E=...,nu=...[,density=...]"
        )
    values: dict[str, float] = {}
    for item in key.split(","):
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in ("e", "nu", "density", "yield"):
            raise ValueError(
                f"material {spec!r}: unknown property {name!r} (E, nu, density, yield)"
            )
        try:
            values[name] = float(value)
        except ValueError:
            raise ValueError(f"material {spec!r}: {name} is not a number: {value!r}") from None
    if "e" not in values or "nu" not in values:
        raise ValueError(f"material {spec!r}: E and nu are required")
    return Material(
        "custom", values["e"], values["nu"], values.get("density", 0.0), values.get("yield")
    )


@dataclass
class Pad:
    """A clamp's or support's contact: vertices that move together along one direction.

    Attributes
    ----------
    vertices : (k,) mesh vertices in the contact (a pad of real size, not a point: a point
        constraint in a solid has a mesh-dependent, singular local response).
    direction : (3,) the restrained direction (normalised on use).
    value : the prescribed displacement along it, mm.
    name : a label for the reports.
    mean : False (default): every vertex moves by ``value`` (a rigid clamp face, which also
        holds the surface's tilt there); True: their mean does (a pin or a locator, which
        holds a position and lets the surface turn about it).
    """

    vertices: np.ndarray
    direction: np.ndarray
    value: float = 0.0
    name: str = ""
    mean: bool = False


@dataclass
class ElasticSolution:
    """A solved load case.

    Attributes
    ----------
    u : (n, 3) displacement of each mesh vertex, mm.
    reaction : (n, 3) reaction force at each vertex where a displacement was prescribed,
        N (0 elsewhere; a prescribed mid-edge node's shared between the edge's ends): what
        the supports and clamps push with.
    energy : strain energy, N mm (mJ).
    pad_forces : (p,) the force each :class:`Pad` exerts on the part along its direction, N.
    dofs : (N,) every degree of freedom (the mid-edge ones too), mm.
    """

    u: np.ndarray
    reaction: np.ndarray
    energy: float
    pad_forces: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dofs: np.ndarray | None = field(default=None, repr=False)


@dataclass
class ElasticModel:
    """The assembled stiffness of a tetrahedral mesh (:func:`elastic_model`).

    Attributes
    ----------
    X : (n, 3) mesh vertices, mm.  T : (k, 4) tetrahedra.
    material : the :class:`Material`.  order : element order (1 or 2).
    K : (N, N) stiffness, N/mm, over all degrees of freedom (vertices' first).
    vertex_dofs : (n, 3) the degrees of freedom of each vertex's x, y, z.
    edges : (e, 2) the mesh edges and ``edge_dofs`` (e, 3) their mid-edge degrees of
        freedom (quadratic elements; None for linear ones).
    """

    X: np.ndarray
    T: np.ndarray
    material: Material
    order: int
    K: sp.csr_matrix
    vertex_dofs: np.ndarray
    edges: np.ndarray | None = None
    edge_dofs: np.ndarray | None = None
    _basis: object = field(default=None, repr=False)
    _centroids: object = field(default=None, repr=False)
    _radii: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_dofs(self) -> int:
        return self.K.shape[0]

    def body_force(self, f: np.ndarray) -> np.ndarray:
        """(N,) load vector of a uniform body force ``f`` (3,) N/mm^3."""
        from skfem import LinearForm

        fx, fy, fz = (float(c) for c in f)

        @LinearForm
        def load(v, w):
            return fx * v[0] + fy * v[1] + fz * v[2]

        return load.assemble(self._basis)

    def mass(self) -> sp.csr_matrix:
        """(N, N) the consistent mass matrix, t (the material's density; unit density,
        mm^3, when it has none): the weight of the modes of :func:`elastic_modes`."""
        from skfem import BilinearForm
        from skfem.helpers import dot

        rho = self.material.density or 1.0

        @BilinearForm
        def m(u, v, w):
            return rho * dot(u, v)

        return m.assemble(self._basis).tocsr()

    def gravity(self, direction=(0.0, 0.0, -1.0), g: float = GRAVITY) -> np.ndarray:
        """(N,) load vector of the part's own weight along ``direction`` (a unit vector
        in the part frame), ``g`` mm/s^2."""
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        return self.body_force(self.material.density * g * d)

    def _prescribed(self, fixed: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All prescribed degrees of freedom and their values: the vertices' and, for
        quadratic elements, the mid-edge ones between two prescribed vertices."""
        dofs = self.vertex_dofs[fixed[:, 0], fixed[:, 1]]
        if self.edge_dofs is None:
            return dofs, values
        ed, ev = _edge_prescribed(self.edges, self.edge_dofs, fixed, values, len(self.X))
        return np.r_[dofs, ed], np.r_[values, ev]

    def solve(
        self,
        fixed: np.ndarray | None = None,
        values: np.ndarray | None = None,
        load: np.ndarray | None = None,
        pads: list[Pad] | None = None,
    ) -> ElasticSolution:
        """Displacements under prescribed vertex displacements, pads and a load.

        Parameters
        ----------
        fixed : (m, 2) int pairs ``(vertex, axis)`` whose displacement is prescribed
            (``axis`` 0, 1, 2 for x, y, z).
        values : (m,) the prescribed displacements, mm (default 0).
        load : (N,) load vector, N (:meth:`gravity`, :meth:`body_force`); default none.
        pads : contacts moved along a direction (:class:`Pad`; Lagrange multipliers, so a
            direction need not be an axis: a clamp restrains along the surface normal).
            Together with ``fixed`` they must hold the six rigid motions.

        Raises
        ------
        ValueError
            A singular system: the constraints leave a rigid motion free.
        """
        fixed = np.asarray([] if fixed is None else fixed, dtype=np.int64).reshape(-1, 2)
        pads = list(pads or [])
        self._check_held(fixed, pads)
        vals = np.zeros(len(fixed)) if values is None else np.asarray(values, dtype=np.float64)
        dofs, vals = self._prescribed(fixed, vals)
        x = np.zeros(self.n_dofs)
        x[dofs] = vals
        f = np.zeros(self.n_dofs) if load is None else np.asarray(load, dtype=np.float64)
        free = np.ones(self.n_dofs, dtype=bool)
        free[dofs] = False
        Kff = self.K[free][:, free]
        rhs = f[free] - self.K[free][:, ~free] @ x[~free]
        C, c, owner = self._pad_rows(pads)
        nf = Kff.shape[0]
        if len(c):  # saddle point [[K, C'], [C, 0]] [u; lambda] = [f; c]
            Cf = C[:, free]
            A = sp.bmat([[Kff, Cf.T], [Cf, None]], format="csc")
            rhs = np.r_[rhs, c - C[:, ~free] @ x[~free]]
        else:
            A = Kff.tocsc()
        try:
            lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
        except RuntimeError as e:  # "Factor is exactly singular"
            raise ValueError(
                "the elastic problem is singular: the constraints leave a rigid motion of "
                f"the part free ({e})"
            ) from None
        sol = lu.solve(rhs)
        x[free] = sol[:nf]
        lam = sol[nf:]
        pad_forces = -np.bincount(owner, weights=lam, minlength=len(pads)) if len(c) else None
        reaction = self._vertex_reactions(x, f, free)
        energy = 0.5 * float(x @ (self.K @ x))
        return ElasticSolution(
            u=x[self.vertex_dofs],
            reaction=reaction,
            energy=energy,
            pad_forces=np.zeros(len(pads)) if pad_forces is None else pad_forces,
            dofs=x,
        )

    def _check_held(self, fixed: np.ndarray, pads: list[Pad]) -> None:
        """Refuse constraints that leave a rigid motion free: the prescribed vertex axes
        ``fixed`` (m, 2) and the pads' directions must hold all six.

        Raises
        ------
        ValueError
            When fewer than six rigid motions are held.
        """
        rows = [(self.X[fixed[:, 0]], np.eye(3)[fixed[:, 1]])]
        for pad in pads:
            d = np.asarray(pad.direction, dtype=np.float64)
            v = np.asarray(pad.vertices, dtype=np.int64)
            rows.append((self.X[v], np.tile(d / np.linalg.norm(d), (len(v), 1))))
        free_motions = 6 - rigid_rank(
            np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows]), self.X
        )
        if free_motions:
            raise ValueError(
                f"the elastic problem is singular: the prescribed displacements leave "
                f"{free_motions} rigid motion(s) of the part free"
            )

    def _vertex_reactions(self, x: np.ndarray, f: np.ndarray, free: np.ndarray) -> np.ndarray:
        """(n, 3) the reaction forces, N, at the vertices: ``K x - f`` on the prescribed
        degrees of freedom (``~free``), a mid-edge node's shared by its edge's ends."""
        r = self.K @ x - f
        reaction = np.zeros(self.n_dofs)
        reaction[~free] = r[~free]
        at_vertex = reaction[self.vertex_dofs]
        if self.edge_dofs is not None:  # a mid-edge node's share goes to the edge's ends
            half = 0.5 * reaction[self.edge_dofs]
            np.add.at(at_vertex, self.edges[:, 0], half)
            np.add.at(at_vertex, self.edges[:, 1], half)
        return at_vertex

    def displacement_at(self, solution: ElasticSolution, points: np.ndarray) -> np.ndarray:
        """(m, 3) the displacement field of ``solution`` at ``points`` (m, 3) mm, with the
        elements' own (quadratic) interpolation. A point outside the tetrahedra (a surface
        point just beyond a chord) takes the value at the closest point of the nearest of
        the 8 tetrahedra with the nearest centroids."""
        return np.asarray(self.probes(points) @ solution.dofs).reshape(3, -1).T

    def probes(self, points: np.ndarray) -> sp.csr_matrix:
        """(3m, N) the matrix taking all degrees of freedom to the displacement at ``points``
        (m, 3) mm: rows ``[x of every point, y of every point, z of every point]`` (see
        :meth:`displacement_at`). The elements' Lagrange shape functions at each point's
        barycentric coordinates in its tetrahedron (quadratic: ``l (2 l - 1)`` at the
        corners, ``4 l_a l_b`` at the edges' midpoints)."""
        from scipy.spatial import cKDTree

        P = np.asarray(points, dtype=np.float64)
        X, T = self.X, self.T
        if self._centroids is None or self._radii is None:
            centre = X[T].mean(axis=1)
            self._centroids = cKDTree(centre)
            self._radii = np.linalg.norm(X[T] - centre[:, None, :], axis=2).max(axis=1)
        best_lam = np.zeros((len(P), 4))
        best_tet = np.zeros(len(P), dtype=np.int64)
        best_d = np.full(len(P), np.inf)
        todo = np.arange(len(P))
        tiny = 1e-9 * float(np.ptp(X, axis=0).max())
        for k in (8, 64):  # slender elements: a point's own may not be among the nearest 8
            if len(todo) == 0:
                break
            dc, cand = self._centroids.query(P[todo], k=min(k, len(T)), workers=-1)
            dc, cand = dc.reshape(len(todo), -1), cand.reshape(len(todo), -1)
            for j in range(cand.shape[1]):
                # a tetrahedron whose centre lies farther than its radius plus the best
                # distance so far cannot come nearer: only the others are tried
                at = np.flatnonzero(dc[:, j] - self._radii[cand[:, j]] < best_d[todo])
                q, c = todo[at], cand[at, j]
                tet = X[T[c]]  # (q, 4, 3)
                lam = _barycentric_tet(tet, P[q])
                lam = np.clip(lam, 0.0, None)
                lam /= lam.sum(axis=1, keepdims=True)
                y = np.einsum("qk,qkd->qd", lam, tet)
                d = np.linalg.norm(y - P[q], axis=1)
                better = d < best_d[q]
                idx = q[better]
                best_lam[idx], best_tet[idx], best_d[idx] = lam[better], c[better], d[better]
            todo = todo[best_d[todo] > tiny]
        corners = T[best_tet]  # (m, 4)
        if self.order == 1:
            w, nodes = best_lam, [self.vertex_dofs[corners[:, k]] for k in range(4)]
        else:
            pairs = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
            w = np.c_[
                best_lam * (2.0 * best_lam - 1.0),
                np.stack([4.0 * best_lam[:, a] * best_lam[:, b] for a, b in pairs], axis=1),
            ]
            edge = self.edge_index(np.stack([corners[:, [a, b]] for a, b in pairs], axis=1))
            nodes = [self.vertex_dofs[corners[:, k]] for k in range(4)]
            nodes += [self.edge_dofs[edge[:, k]] for k in range(6)]
        m, K = len(P), len(nodes)
        dofs = np.stack(nodes, axis=1)  # (m, K, 3)
        rows = (np.arange(3)[None, None, :] * m + np.arange(m)[:, None, None]).repeat(K, axis=1)
        vals = np.repeat(w[:, :, None], 3, axis=2)
        return sp.csr_matrix(
            (vals.ravel(), (rows.ravel(), dofs.ravel())), shape=(3 * m, self.n_dofs)
        )

    def edge_index(self, pairs: np.ndarray) -> np.ndarray:
        """The index in :attr:`edges` of vertex pairs ``pairs`` (..., 2)."""
        n = np.int64(len(self.X))
        e = np.sort(self.edges, axis=1)
        keys = e[:, 0] * n + e[:, 1]
        order = np.argsort(keys)
        q = np.sort(pairs, axis=-1)
        qk = q[..., 0] * n + q[..., 1]
        pos = np.searchsorted(keys[order], qk)
        return order[pos]

    def pad_responses(
        self, pads: list[Pad], load: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The responses to each pad's unit drive, the others held (one factorisation).

        A restrained state is linear in the clamps' drives: with these, any drives ``d``
        (p,) give the degrees of freedom ``D @ d`` and the pad forces ``G @ d``.

        Parameters
        ----------
        pads : the pads (their ``value`` ignored); together they must hold the six rigid
            motions.  load : (N,) an optional load vector, N, solved as one more column
            with every pad held at 0.

        Returns
        -------
        D : (N, p) degrees of freedom, mm per mm of drive (a last column for ``load``).
        G : (p, p) pad forces along their directions, N per mm (column j: pad j driven
            by 1 mm; a last column for ``load``, N).

        Raises
        ------
        ValueError
            The pads leave a rigid motion free.
        """
        pads = list(pads)
        rows = [
            (
                self.X[np.asarray(p.vertices, dtype=np.int64)],
                np.tile(_unit(p.direction), (len(p.vertices), 1)),
            )
            for p in pads
        ]
        free_motions = (
            6
            - rigid_rank(
                np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows]), self.X
            )
            if rows
            else 6
        )
        if free_motions:
            raise ValueError(
                f"the elastic problem is singular: the clamps leave {free_motions} rigid "
                "motion(s) of the part free"
            )
        C, _, owner = self._pad_rows(pads)
        n, m, p = self.n_dofs, C.shape[0], len(pads)
        cols = p + (load is not None)
        f = np.zeros((n, cols))
        c = np.zeros((m, cols))
        c[np.arange(m), owner] = 1.0
        if load is not None:
            f[:, p] = np.asarray(load, dtype=np.float64)
        u, lam = self._saddle_solve(C, f, c)
        G = np.zeros((p, cols))
        for j in range(cols):
            G[:, j] = -np.bincount(owner, weights=lam[:, j], minlength=p)
        return u, G

    def _saddle_solve(
        self, C: sp.csr_matrix, f: np.ndarray, c: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The degrees of freedom ``u`` (N, k) and multipliers ``lam`` (m, k) of
        ``K u + C' lam = f``, ``C u = c`` for the columns of ``f`` (N, k) and ``c`` (m, k),
        the constraints ``C`` (m, N) holding every rigid motion.

        The system is solved in its augmented form: ``K + rho C'C`` (rho: the mean of
        ``K``'s diagonal) is positive definite once the constraints hold the rigid motions,
        and adding ``rho C'(C u - c)`` to the first row changes neither ``u`` nor ``lam``.
        That matrix is factorised once (:class:`~qifreport.registration.linalg.SPDSolver`:
        CHOLMOD where installed, else SuperLU without pivoting) in a geometric nested
        dissection of the mesh's nodes (each node's three degrees of freedom together), and
        the multipliers come from the constraints' small dense Schur complement
        ``C (K + rho C'C)^-1 C'`` (m, m): the clamps' pads hold a few rows each.
        """
        rho = float(np.mean(self.K.diagonal()))
        Kr = (self.K + rho * (C.T @ C)).tocsc()
        try:
            solve = SPDSolver(order=self._node_order(Kr)).factor(Kr)
        except ValueError as e:
            raise ValueError(f"the elastic problem is singular ({e})") from None
        g = np.asarray(f + rho * (C.T @ c), dtype=np.float64)
        Y = solve(np.hstack([g, C.T.toarray()]))
        Yg, Yc = Y[:, : g.shape[1]], Y[:, g.shape[1] :]
        try:
            lam = np.linalg.solve(C @ Yc, C @ Yg - c)
        except np.linalg.LinAlgError as e:
            raise ValueError(f"the elastic problem is singular ({e})") from None
        u = Yg - Yc @ lam
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(lam))):
            raise ValueError("the elastic problem is singular (a non-finite solution)")
        return u, lam

    def _node_order(self, A: sp.spmatrix) -> np.ndarray:
        """(N,) the degrees of freedom in a nested-dissection order of the mesh's nodes
        (vertices, then mid-edge nodes at their edges' midpoints), each node's x, y, z
        together; ``A`` (N, N): the coupling pattern."""
        pos, dofs = [self.X], [self.vertex_dofs]
        if self.edge_dofs is not None:
            pos.append(self.X[self.edges].mean(axis=1))
            dofs.append(self.edge_dofs)
        X, nd = np.vstack(pos), np.vstack(dofs)
        node = np.empty(self.n_dofs, dtype=np.int64)
        node[nd.ravel()] = np.repeat(np.arange(len(nd)), 3)
        S = sp.csr_matrix(
            (np.ones(self.n_dofs), (node, np.arange(self.n_dofs))), shape=(len(nd), self.n_dofs)
        )
        return nd[nested_dissection(X, (S @ abs(A) @ S.T).tocsr())].ravel()

    def _pad_rows(self, pads: list[Pad]) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        """The pads' constraint rows ``C u = c`` (a rigid pad: one per vertex, and per
        mid-edge node between two of its vertices; a mean pad: one) and the pad owning each
        row."""
        rows, cols, vals, owner = [], [], [], []
        m = 0
        for k, pad in enumerate(pads):
            d = np.asarray(pad.direction, dtype=np.float64)
            d = d / np.linalg.norm(d)
            v = unique_sorted(np.asarray(pad.vertices, dtype=np.int64))
            if pad.mean:  # one row: the mean of its vertices' displacement along d
                dofs = self.vertex_dofs[v]  # (k, 3)
                rows.append(np.full(dofs.size, m))
                cols.append(dofs.ravel())
                vals.append(np.tile(d / len(v), len(v)))
                owner.append(np.full(1, k, dtype=np.int64))
                m += 1
                continue
            nodes = [self.vertex_dofs[v]]
            if self.edge_dofs is not None:
                inside = np.zeros(len(self.X), dtype=bool)
                inside[v] = True
                both = inside[self.edges[:, 0]] & inside[self.edges[:, 1]]
                nodes.append(self.edge_dofs[both])
            dofs = np.concatenate(nodes)  # (r, 3)
            r = len(dofs)
            rows.append(np.repeat(np.arange(m, m + r), 3))
            cols.append(dofs.ravel())
            vals.append(np.tile(d, r))
            owner.append(np.full(r, k, dtype=np.int64))
            m += r
        if not rows:
            return sp.csr_matrix((0, self.n_dofs)), np.zeros(0), np.zeros(0, dtype=np.int64)
        owner = np.concatenate(owner)
        C = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(m, self.n_dofs),
        )
        c = np.array([pads[k].value for k in owner], dtype=np.float64)
        return C, c, owner


def _unit(d) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    return d / np.linalg.norm(d)


def _barycentric_tet(tet: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(q, 4) barycentric coordinates of points ``P`` (q, 3) in tetrahedra ``tet`` (q, 4, 3)."""
    A = np.transpose(tet[:, 1:] - tet[:, :1], (0, 2, 1))  # (q, 3, 3) columns: edges from 0
    lam = np.linalg.solve(A, (P - tet[:, 0])[..., None])[..., 0]
    return np.c_[1.0 - lam.sum(axis=1), lam]


def _edge_prescribed(
    edges: np.ndarray, edge_dofs: np.ndarray, fixed: np.ndarray, values: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """The mid-edge degrees of freedom of quadratic elements on the edges whose two
    vertices are both prescribed along the same axis, and their values (the mean of the
    ends': the boundary moves as the vertices say, not just at them). ``edges`` (e, 2),
    ``edge_dofs`` (e, 3), ``fixed`` (m, 2) (vertex, axis), ``values`` (m,), ``n`` vertices."""
    out_d, out_v = [], []
    for axis in range(3):
        sel = fixed[:, 1] == axis
        if not sel.any():
            continue
        val = np.full(n, np.nan)
        val[fixed[sel, 0]] = values[sel]
        both = np.isfinite(val[edges[:, 0]]) & np.isfinite(val[edges[:, 1]])
        out_d.append(edge_dofs[both, axis])
        out_v.append(0.5 * (val[edges[both, 0]] + val[edges[both, 1]]))
    if not out_d:
        return np.empty(0, dtype=np.int64), np.empty(0)
    return np.concatenate(out_d), np.concatenate(out_v)


def rigid_rank(points: np.ndarray, directions: np.ndarray, X: np.ndarray) -> int:
    """How many of the six rigid motions of a part (vertices ``X`` (n, 3) mm) are held by
    restraining ``points`` (m, 3) mm along ``directions`` (m, 3) unit (6: all; the elastic
    problem is then regular)."""
    if len(points) == 0:
        return 0
    A, _, _ = rigid_motion_matrix(points, directions, X)
    return int(np.linalg.matrix_rank(A, tol=1e-9))


#: the shift of :func:`elastic_modes`' shift-invert, as a share of the model's largest
#: eigenvalue (a plate's lowest elastic modes lie some 1e-10 to 1e-6 of it)
SHIFT_SHARE = 1e-8


def elastic_modes(model: ElasticModel, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` lowest elastic (non-rigid) vibration modes of the free part.

    Returns
    -------
    omega2 : (k,) squared angular frequencies, 1/s^2 (with the material's density).
    modes : (N, k) degrees of freedom of each mode, mass-normalised (``phi' M phi = 1``),
        its largest component positive.
    """
    M = model.mass().tocsc()
    K = model.K.tocsc()
    # shift-invert below zero: K - sigma M is positive definite although K is singular. The
    # shift is scaled to the model's spectrum (its largest eigenvalue is of the order of the
    # largest ratio of their diagonals): a shift far below the lowest elastic mode, as a
    # unit one is with a density in t/mm^3, leaves K - sigma M singular in floating point
    # and the modes wrong
    top = float(np.max(K.diagonal() / np.maximum(M.diagonal(), 1e-300)))
    v0 = np.random.default_rng(0).standard_normal(model.n_dofs)  # the same modes every run
    shift = SHIFT_SHARE * top
    solve = SPDSolver().factor(K + shift * M)
    inverse = spla.LinearOperator(K.shape, matvec=solve, dtype=np.float64)
    # to machine precision: a looser tolerance leaves some of the six degenerate rigid
    # motions unfound, and an elastic mode is then taken for one
    w, phi = spla.eigsh(K, k=k + 6, M=M, sigma=-shift, which="LM", v0=v0, OPinv=inverse)
    order = np.argsort(w)
    w, phi = w[order[6:]], phi[:, order[6:]]
    # each mode's sign fixed (its largest component positive): the eigensolver's is
    # arbitrary, and a rounding change in the stiffness may flip it, and with it a shape
    # built from the modes
    big = np.argmax(np.abs(phi), axis=0)
    phi *= np.sign(phi[big, np.arange(phi.shape[1])])
    return w, phi


def _stiffness(basis, lam: float, mu: float, scale: np.ndarray) -> sp.csr_matrix:
    """The linear elastic stiffness (N, N), N/mm, on a scikit-fem vector ``basis``: each
    element's ``scale * integral (2 mu eps(u) : eps(v) + lam tr eps(u) tr eps(v))`` over
    every pair of its basis functions at once, from the basis' own gradients, quadrature
    weights and degrees of freedom (the bilinear form of scikit-fem's ``linear_elasticity``
    model, to rounding, which its ``asm`` evaluates one pair of basis functions at a time).

    Parameters
    ----------
    basis : ``skfem.Basis`` of an ``ElementVector`` on a tetrahedral mesh, mm.
    lam, mu : the Lame parameters, MPa.  scale : (k,) a factor per element.
    """
    G = np.stack([phi[0].grad for phi in basis.basis])  # (nb, 3, 3, k, q)
    nb, _, _, k, q = G.shape
    eps = 0.5 * (G + G.transpose(0, 2, 1, 3, 4))
    wq = basis.dx * scale[:, None]  # (k, q) quadrature weights, mm^3
    e = eps.transpose(3, 0, 1, 2, 4).reshape(k, nb, 9 * q)
    Ke = (2.0 * mu) * np.matmul(e, (e * np.tile(wq, (1, 9))[:, None, :]).transpose(0, 2, 1))
    tr = np.einsum("iaakq->kiq", eps)  # (k, nb, q)
    Ke += lam * np.matmul(tr, (tr * wq[:, None, :]).transpose(0, 2, 1))
    dofs = np.asarray(basis.element_dofs).T  # (k, nb)
    rows = np.broadcast_to(dofs[:, :, None], (k, nb, nb)).ravel()
    cols = np.broadcast_to(dofs[:, None, :], (k, nb, nb)).ravel()
    K = sp.coo_matrix((Ke.ravel(), (rows, cols)), shape=(basis.N, basis.N)).tocsr()
    K.eliminate_zeros()
    return K


def elastic_model(
    X: np.ndarray,
    T: np.ndarray,
    mat: Material,
    *,
    order: int = 2,
    stiffness_scale: np.ndarray | None = None,
) -> ElasticModel:
    """Assemble the linear elastic stiffness of a tetrahedral mesh.

    Parameters
    ----------
    X : (n, 3) vertices, mm.  T : (k, 4) tetrahedra (any orientation).
    mat : the material.  order : 2 (quadratic tetrahedra, default: a thin wall in bending
        does not lock) or 1 (linear, for comparison only: it locks).
    stiffness_scale : (k,) a positive factor on each tetrahedron's Young's modulus (a
        simulator's uneven wall: ``(t / t0)^3`` makes a wall of thickness ``t`` as stiff in
        bending as the nominal ``t0``); None: 1 everywhere.

    Returns
    -------
    ElasticModel
    """
    from skfem import Basis, ElementTetP1, ElementTetP2, ElementVector, MeshTet

    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64)
    if X.ndim != 2 or X.shape[1] != 3 or T.ndim != 2 or T.shape[1] != 4:
        raise ValueError(f"need X (n, 3) and T (k, 4), got {X.shape} and {T.shape}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    # positive orientation (scikit-fem's reference mappings want it)
    a, b, c, d = (X[T[:, i]] for i in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    T = T.copy()
    T[neg, 2], T[neg, 3] = T[neg, 3], T[neg, 2].copy()
    mesh = MeshTet(X.T.copy(), T.T.copy())
    elem = ElementVector(ElementTetP2() if order == 2 else ElementTetP1())
    basis = Basis(mesh, elem)
    if stiffness_scale is None:
        scale = np.ones(len(T))
    else:
        scale = np.asarray(stiffness_scale, dtype=np.float64)
        if scale.shape != (len(T),) or not np.all(np.isfinite(scale) & (scale > 0)):
            raise ValueError(f"stiffness_scale must be ({len(T)},) positive factors")
    K = _stiffness(basis, *mat.lame, scale)
    vertex_dofs = np.asarray(basis.nodal_dofs).T.copy()  # (n, 3)
    log.info(
        "elastic model: %d vertices, %d tetrahedra (P%d), %d dofs",
        len(X),
        len(T),
        order,
        K.shape[0],
    )
    edges = edge_dofs = None
    if order == 2:
        edges = np.asarray(mesh.edges).T.copy()
        edge_dofs = np.asarray(basis.edge_dofs).T.copy()
    return ElasticModel(
        X=X,
        T=T,
        material=mat,
        order=order,
        K=K,
        vertex_dofs=vertex_dofs,
        edges=edges,
        edge_dofs=edge_dofs,
        _basis=basis,
    )
