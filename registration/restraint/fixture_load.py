"""What a physical fixture would need to hold a part in the virtual fixture's shape.

The virtual fixture (:mod:`qifreport.registration.deformable`) bends the nominal onto the
free-state scan by a smooth displacement field; nothing in it knows what the part is made
of. A physical restraint (ISO 10579: "by applying pressure or forces not exceeding those
which can be expected under normal assembly conditions") can only hold a part in a shape
its elasticity allows with bounded forces. This module measures that load on the part's
elastic model (:mod:`qifreport.registration.restraint.elastic`):

1. the fixture's displacement ``d`` at the nominal's vertices, its rigid part removed
   (:func:`without_rigid_motion`), is carried to the model's surface nodes
   (:class:`LoadModel`: each node's closest point on the nominal, linear in its triangle).
   On a thin wall (its opposite skin within :data:`THIN_WALL_SHARE` of the part's
   diagonal) each skin node takes the mean of its own skin's and the opposite skin's
   normal displacement (:func:`_opposite_skin`): the fixture holds the wall's mid-surface.
   The fit displaces the two skins of a wall independently, and the difference, a change
   of the wall's thickness, is the part's own form, not a shape a fixture can bend it into:
   prescribed, it is a squeeze through the thickness whose energy dwarfs the bending and
   grows as the model refines (reported as :attr:`FixtureLoad.thickness_change`);
2. the model is solved with each surface node's displacement along its outward normal
   prescribed, the tangential ones free (:func:`fixture_load`). A scan observes a surface
   along its normal only, a fixture's contacts push along it, and the smooth field's
   tangential part is the prior's, not the part's: the state solved is the least strained
   one that has the fitted surface. A node on an edge is held along its largest face's
   normal, and faces narrower than the model resolves are left free (:func:`_held_nodes`):
   on the rim of a thin wall or a hole's wall the field of a smooth prior carries no
   rotation of the wall's section, and holding them would shear or stretch the wall, a
   load no fixture applies. The fit's field is not all elastic (its prior's smoothness is
   not the part's stiffness): held exactly, its non-elastic residue is charged to the
   fixture, often many times the load that bends the part into shape. The held state is
   the least-energy one whose normal displacement at the held nodes lies within a stated
   root-mean-square misfit of the fitted field (:func:`least_energy_hold`; the caller
   states it, as a share of the tolerance the verdict rests on, :data:`HOLD_SHARE`), the
   exact hold its limit at zero misfit;
3. the strain energy, the reactions, the force a fixture pushing through the largest
   correction would need to store that energy (:attr:`FixtureLoad.equivalent_force`), and
   the peak von Mises stress against the material's yield strength;
4. what of the fitted field lies outside the part's compliant modes
   (:attr:`FixtureLoad.departure`, :mod:`.compliant_modes`): the fitted normal displacement
   at the held nodes is fitted by the rigid motions and the part's lowest elastic modes
   within a decade of frequency of its softest (a stiffness within a hundredfold), and the
   remainder carried to the nominal's vertices. A fixture removes a compliant part's
   flexure, which lies in those modes; a dent or bump does not, and a smooth field that
   follows one puts it there (the paper's Section 11: "confining the admissible
   deformation to the compliant, physically realizable modes of the part"). The caller
   judges the part in that modal shape too (:mod:`qifreport.metrology.inspection`).

Units: mm, N, MPa, mJ (N mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from qifreport.registration.linalg import NotPositiveDefinite, SPDSolver
from qifreport.registration.mesh import barycentric
from qifreport.registration.restraint.compliant_modes import (
    absorbed_width,
    back_to_nominal,
    beyond_modes,
    compliant_modes,
)
from qifreport.registration.restraint.elastic import ElasticModel

__all__ = [
    "DEFAULT_MAX_FORCE",
    "FACE_ANGLE",
    "HOLD_SHARE",
    "PAD_RADIUS",
    "THIN_WALL_SHARE",
    "FixtureLoad",
    "LoadModel",
    "boundary_faces",
    "fixture_load",
    "least_energy_hold",
    "load_model",
    "vertex_von_mises",
    "without_rigid_motion",
]

#: a surface node is held along the mean normal of its boundary faces within this angle of
#: its largest one (a gentle fillet's faces together; not a sharp edge's), degrees
FACE_ANGLE = 30.0

#: the virtual fixture's force limit when neither the drawing nor the operator states one,
#: N (docs/restraint.md: ISO 10579's "forces ... expected under normal assembly conditions",
#: taken as what one hand presses in assembly)
DEFAULT_MAX_FORCE = 100.0

#: the contact whose force is reported as the peak: an RPS pad of 10 mm diameter, mm
PAD_RADIUS = 5.0

#: the share of the tightest tolerance zone the held shape may miss the fitted one by, root
#: mean square over the held nodes (the gauge-maker's rule: a gauge's own error within a
#: tenth of the tolerance it checks)
HOLD_SHARE = 0.1

#: the least-energy hold's search: the misfit reached within this share below the one
#: allowed, in at most :data:`HOLD_SOLVES` solves (the best one within the allowance kept)
HOLD_REACH = 0.05
HOLD_SOLVES = 12

#: a wall is thin, its two skins held together at its mid-surface, when the opposite skin
#: lies within this share of the part's diagonal (the thin-shell rule, thickness at most a
#: twentieth of the span)
THIN_WALL_SHARE = 1.0 / 20.0


@dataclass
class LoadModel:
    """A part's elastic model ready to take a fixture's displacement (:func:`load_model`):
    built once per part, reused for every scan.

    Attributes
    ----------
    model : the elastic model (its assembly basis dropped: not needed, not cached).
    nodes : (m,) the held surface nodes (model vertices).
    normals : (m, 3) their outward unit normals.
    W : (m, n) sparse: a field at the nominal's n vertices to its value at the held nodes
        (on a thin wall, the mean of the node's skin and the opposite skin).
    thickness : (m, n) sparse: a field at the nominal's vertices to the change of the wall's
        thickness it makes at the held nodes along their normals (zero rows off thin walls).
    back : (n, m) sparse: a field at the held nodes to its value at the nominal's vertices,
        linear on the model's surface triangle closest to each vertex (over its held
        corners; a zero row where none is held).
    modes : (m, k) the normal displacement at the held nodes of each of the part's
        compliant modes (:mod:`.compliant_modes`), unit columns; None: not computed.
    absorbed_width : the narrowest Gaussian bump (sigma, mm) that its compliant modes
        take more than half of (:func:`absorbed_width`): a defect this wide or wider the
        virtual fixture can absorb unseen (:func:`.compliant_modes.absorbed_width`); None:
        not computed.
    description : what the model is (``"STEP solid, gmsh tetrahedra"``, a sheet's
        thickness), for the reports.
    material_source : where the material came from (the operator, the drawing), for the
        reports.
    """

    model: ElasticModel
    nodes: np.ndarray
    normals: np.ndarray
    W: sp.csr_matrix
    thickness: sp.csr_matrix | None = None
    back: sp.csr_matrix | None = None
    modes: np.ndarray | None = None
    absorbed_width: float | None = None
    description: str = ""
    material_source: str = ""

    @property
    def n_nominal(self) -> int:
        return self.W.shape[1]


@dataclass
class FixtureLoad:
    """The load a physical fixture would need to hold the part in the fitted shape.

    Attributes
    ----------
    established : False when there is no elastic model of the part (``reason`` says what
        is needed); every figure is then None.
    energy : strain energy, mJ (N mm).
    max_correction : the largest normal displacement held, mm (rigid motion removed).
    equivalent_force : ``2 energy / max_correction``, N: the force that, pushing the part
        through its largest correction with the stiffness it shows, stores the same energy
        (exact for a single contact; a distributed fixture's forces are of its order).
    total_reaction : the sum of the magnitudes of the held nodes' reactions, N (a
        distributed contact: where the fitted shape keeps a curvature up to a free edge
        the reactions there form a couple on the mesh's spacing, so this sum grows as the
        mesh refines; reported, not judged).
    peak_pad_force : the largest resultant of the reactions within :data:`PAD_RADIUS` of a
        held node, N: what the most loaded 10 mm contact would carry.
    peak_stress : the largest von Mises stress, MPa (vertex-averaged stress tensors).
    thickness_change : the largest change of a thin wall's thickness in the fitted shape,
        mm: the part's own form, which the fixture holds at the wall's mid-surface and no
        load can bend away (module docstring).
    yield_strength : the material's, MPa (None: not known).
    material : the material's name.  material_source : where it came from (the operator's
        ``--material``, the drawing).  model : the model's description.
    misfit_allowed : the root-mean-square normal misfit to the fitted field the held shape
        was allowed at the held nodes, mm (0: held exactly), and ``misfit_source`` what it
        is a share of; ``misfit`` the one reached, mm (:func:`least_energy_hold`).
    limit : the force limit the equivalent force is checked against, N, and
        ``limit_source`` where it comes from (set by :meth:`bounded`).
    reason : why the load is not established (``established`` False).
    departure : (n, 3) mm at the nominal's vertices: the fitted shape's remainder outside
        the part's compliant modes, the modal shape less the fitted one (empty: not
        computed); ``modes`` how many compliant modes; ``absorbed_width`` the narrowest
        bump, sigma mm, they take more than half of (:attr:`LoadModel.absorbed_width`).
    beyond_modes : why the verdict rests on that remainder (set by the caller, who judged
        the part in the modal shape too): a refusal.
    """

    established: bool
    energy: float | None = None
    max_correction: float | None = None
    equivalent_force: float | None = None
    total_reaction: float | None = None
    peak_pad_force: float | None = None
    peak_stress: float | None = None
    thickness_change: float | None = None
    yield_strength: float | None = None
    material: str = ""
    material_source: str = ""
    model: str = ""
    held_nodes: int = 0
    misfit_allowed: float | None = None
    misfit: float | None = None
    misfit_source: str = ""
    limit: float | None = None
    limit_source: str = ""
    reason: str = ""
    pad_forces: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    departure: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    modes: int = 0
    absorbed_width: float | None = None
    beyond_modes: str = ""

    @property
    def max_departure(self) -> float | None:
        """The largest distance, mm, between the modal shape and the fitted one at a
        nominal vertex (None: not computed)."""
        if not self.established or not len(self.departure):
            return None
        return float(np.linalg.norm(self.departure, axis=1).max())

    @classmethod
    def not_established(cls, reason: str) -> FixtureLoad:
        """No elastic model of the part: ``reason`` says what is needed."""
        return cls(established=False, reason=reason)

    def bounded(self, limit: float, source: str) -> FixtureLoad:
        """This load checked against the force ``limit`` N from ``source``."""
        self.limit, self.limit_source = float(limit), source
        return self

    @property
    def over_force(self) -> bool:
        return bool(
            self.established and self.limit is not None and self.equivalent_force > self.limit
        )

    @property
    def beyond_yield(self) -> bool:
        return bool(
            self.established
            and self.yield_strength is not None
            and self.peak_stress > self.yield_strength
        )

    def refusals(self) -> list[str]:
        """Why no physical fixture could hold the part so (empty when one could), one
        line each: a load above the limit, or a correction that is not elastic."""
        out = []
        if self.over_force:
            out.append(
                f"the virtual fixture's shape needs {self.equivalent_force:.3g} N to hold "
                f"({self.energy:.3g} mJ over a {self.max_correction:.3g} mm correction; "
                f"peak {self.peak_pad_force:.3g} N on one 10 mm contact), above the "
                f"{self.limit:g} N limit ({self.limit_source})"
            )
        if self.beyond_modes:
            out.append(self.beyond_modes)
        if self.beyond_yield:
            out.append(
                f"the virtual fixture's correction is not elastic: it stresses the "
                f"{self.material} to {self.peak_stress:.3g} MPa, beyond its yield strength "
                f"{self.yield_strength:g} MPa"
            )
        return out

    def describe(self) -> str:
        """One line: the load and whether it lies within the limit and the yield
        strength, or why it is not established."""
        if not self.established:
            return f"fixture load not established: {self.reason}"
        ys = "yield not known" if self.yield_strength is None else f"yield {self.yield_strength:g}"
        src = f" from the {self.material_source}" if self.material_source else ""
        thick = (
            ""
            if not self.thickness_change
            else f"; walls' own thickness change {self.thickness_change:.3g} mm not held"
        )
        return (
            f"fixture load {self.equivalent_force:.3g} N ({self._force_status()}): "
            f"{self.energy:.3g} mJ over {self.max_correction:.3g} mm, peak contact "
            f"{self.peak_pad_force:.3g} N, stress {self.peak_stress:.3g} MPa ({ys}, "
            f"{self.material}{src}){self._hold()}{thick}{self._absorbed()}"
        )

    def _absorbed(self) -> str:
        """What the virtual fixture cannot see: the defects its compliant modes take."""
        if not self.modes:
            return ""
        if self.absorbed_width is None:
            return f"; {self.modes} compliant modes"
        return (
            f"; {self.modes} compliant modes: a bump or dent of sigma >= "
            f"{self.absorbed_width:g} mm lies mostly in them and the fixture may absorb it"
        )

    def _hold(self) -> str:
        """How closely the held shape follows the fitted one (empty: held exactly)."""
        if not self.misfit_allowed:
            return ""
        of = f": {self.misfit_source}" if self.misfit_source else ""
        return (
            f"; held within {self.misfit:.2g} mm rms of the fitted shape "
            f"(allowed {self.misfit_allowed:.2g} mm{of})"
        )

    def short(self) -> str:
        """A few words for a report's verdict box: the force and the stress against their
        limits (``>`` beyond, ``<=`` within)."""
        if not self.established:
            return "fixture load not established"
        force = f"fixture {self.equivalent_force:.3g} N"
        if self.limit is not None:
            force += f" {'>' if self.over_force else '<='} {self.limit:g}"
        stress = f"{self.peak_stress:.3g} MPa"
        if self.yield_strength is not None:
            stress += f" {'>' if self.beyond_yield else '<='} yield {self.yield_strength:g}"
        return f"{force}, {stress}"

    def _force_status(self) -> str:
        if self.limit is None:
            return "no limit set"
        return f"{'over' if self.over_force else 'within'} the {self.limit:g} N limit"

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None else float(x)

        return {
            "established": self.established,
            "reason": self.reason or None,
            "energy_mJ": num(self.energy),
            "max_correction_mm": num(self.max_correction),
            "equivalent_force_N": num(self.equivalent_force),
            "total_reaction_N": num(self.total_reaction),
            "peak_pad_force_N": num(self.peak_pad_force),
            "pad_radius_mm": PAD_RADIUS,
            "peak_von_mises_MPa": num(self.peak_stress),
            "wall_thickness_change_mm": num(self.thickness_change),
            "yield_MPa": num(self.yield_strength),
            "material": self.material or None,
            "material_source": self.material_source or None,
            "model": self.model or None,
            "held_nodes": int(self.held_nodes),
            "hold_misfit_allowed_mm": num(self.misfit_allowed),
            "hold_misfit_mm": num(self.misfit),
            "hold_misfit_source": self.misfit_source or None,
            "compliant_modes": int(self.modes),
            "absorbed_bump_sigma_mm": num(self.absorbed_width),
            "beyond_modes_max_mm": num(self.max_departure),
            "beyond_modes": self.beyond_modes or None,
            "limit_N": num(self.limit),
            "limit_source": self.limit_source or None,
            "over_limit": self.over_force,
            "beyond_yield": self.beyond_yield,
            "refused": bool(self.refusals()),
        }


def boundary_faces(X: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boundary triangles ``(b, 3)`` of tetrahedra ``T`` (k, 4) over ``X`` (n, 3) mm,
    and their outward normals ``(b, 3)`` scaled by twice their area (mm^2)."""
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64)
    local = ((1, 2, 3, 0), (0, 2, 3, 1), (0, 1, 3, 2), (0, 1, 2, 3))
    faces = np.concatenate([T[:, [a, b, c]] for a, b, c, _ in local])
    opposite = np.concatenate([T[:, d] for *_, d in local])
    _, inv, count = np.unique(
        np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    once = count[inv.ravel()] == 1
    f, o = faces[once], opposite[once]
    n = np.cross(X[f[:, 1]] - X[f[:, 0]], X[f[:, 2]] - X[f[:, 0]])
    inward = np.einsum("ij,ij->i", n, X[o] - X[f[:, 0]]) > 0
    n[inward] *= -1.0
    return f, n


def _held_nodes(X: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surface nodes held and the direction each is held along.

    A node is held along the area-weighted normal of its boundary faces within
    :data:`FACE_ANGLE` of its largest one: a node on the edge of a thin wall along the
    wall's skin, not the narrow face beside it. A node off every sharp edge but closer to
    one than the surface's median edge lies on a face narrower than the model resolves
    (a thin wall's rim, a hole's wall): it is left free. The fit's smooth prior
    does not carry the rotation of such a face with the wall, and holding it there would
    strain the wall in its plane, a load no fixture applies."""
    f, n = boundary_faces(X, T)
    area = np.linalg.norm(n, axis=1)
    fn = n / area[:, None]
    best = np.zeros(len(X))
    for k in range(3):
        np.maximum.at(best, f[:, k], area)
    dominant = np.zeros((len(X), 3))
    for k in range(3):
        top = area >= best[f[:, k]]
        dominant[f[top, k]] = fn[top]
    acc = np.zeros((len(X), 3))
    sharp = np.zeros(len(X), dtype=bool)
    cos = np.cos(np.radians(FACE_ANGLE))
    for k in range(3):
        near = np.einsum("ij,ij->i", fn, dominant[f[:, k]]) >= cos
        np.add.at(acc, f[near, k], n[near])
        sharp[f[~near, k]] = True
    norm = np.linalg.norm(acc, axis=1)
    held = norm > 0
    if sharp.any():
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        h = float(np.median(np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)))
        smooth = np.flatnonzero(held & ~sharp)
        dist, _ = cKDTree(X[sharp]).query(X[smooth])
        held[smooth[dist < h]] = False
    idx = np.flatnonzero(held)
    return idx, acc[idx] / norm[idx, None]


def load_model(
    model: ElasticModel,
    V: np.ndarray,
    F: np.ndarray,
    description: str = "",
    material_source: str = "",
    *,
    modes: bool = True,
) -> LoadModel:
    """Prepare ``model`` (the part's elastic model) to take displacements given at the
    vertices of the nominal mesh ``(V, F)`` (mm, outward-wound triangles); ``modes``: with
    the part's compliant modes (:mod:`.compliant_modes`; False: the load alone, without
    their eigensolve).

    Each held surface node (:func:`_held_nodes`) takes the field at its closest point on
    the nominal, linear in that triangle; on a thin wall, the mean of that and the field at
    the opposite skin's point behind it (:func:`_opposite_skin`). A sheet's model (its
    skins at +/- half the thickness of a mid-surface nominal) takes the mid-surface's value
    on both skins. ``description`` and ``material_source`` are for the reports.

    Raises
    ------
    ValueError
        A model with no surface node inside a face.
    """
    import igl

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nodes, normals = _held_nodes(model.X, model.T)
    if len(nodes) == 0:
        raise ValueError("the elastic model has no surface node inside a face to hold")
    _, tri, C = igl.point_mesh_squared_distance(model.X[nodes], V, F)
    tri = np.asarray(tri, dtype=np.int64)
    w = np.clip(barycentric(V, F, tri, C), 0.0, None)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    m = len(nodes)
    own = sp.csr_matrix(
        (w.ravel(), (np.repeat(np.arange(m), 3), F[tri].ravel())), shape=(m, len(V))
    )
    reach = THIN_WALL_SHARE * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    opposite = _opposite_skin(model, nodes, normals, V, F, reach)
    wall = sp.diags(np.asarray(opposite.sum(axis=1)).ravel())  # 1 on a thin wall's rows
    back = back_to_nominal(model.X, boundary_faces(model.X, model.T)[0], nodes, V)
    compliant = compliant_modes(model, nodes, normals) if modes else None
    absorbed = absorbed_width(model.X[nodes], normals, compliant) if modes else None
    return LoadModel(
        model=ElasticModel(
            X=model.X,
            T=model.T,
            material=model.material,
            order=model.order,
            K=model.K,
            vertex_dofs=model.vertex_dofs,
            edges=model.edges,
            edge_dofs=model.edge_dofs,
        ),
        nodes=nodes,
        normals=normals,
        W=(own - 0.5 * (wall @ own) + 0.5 * opposite).tocsr(),
        thickness=((wall @ own) - opposite).tocsr(),
        back=back,
        modes=compliant,
        absorbed_width=absorbed,
        description=description,
        material_source=material_source,
    )


def _opposite_skin(
    model: ElasticModel,
    nodes: np.ndarray,
    normals: np.ndarray,
    V: np.ndarray,
    F: np.ndarray,
    reach: float,
) -> sp.csr_matrix:
    """(m, n) sparse: a field at the nominal's vertices to its value at the opposite skin
    behind each held node (zero rows where there is none within ``reach`` mm).

    The opposite skin is the first nominal triangle facing the other way (within
    :data:`FACE_ANGLE` of antiparallel) hit by the ray from the node inward along its
    normal. A ray from a node on a wall's rim runs along the rim's face and may slip past
    the skin's edge: it is cast again from a point a little inside the node's face."""
    import igl

    X = model.X[nodes]
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    cos = np.cos(np.radians(FACE_ANGLE))
    eps = 1e-4 * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    tree = igl.AABB()
    Vc, Fc = np.ascontiguousarray(V), np.ascontiguousarray(F)
    tree.init(Vc, Fc)
    rows, cols, vals = [], [], []
    todo = np.arange(len(nodes))
    for start in (X, X + _inward_steps(model, nodes, normals)):
        hits = tree.intersect_ray(
            Vc,
            Fc,
            np.ascontiguousarray(start[todo] + eps * normals[todo]),
            np.ascontiguousarray(-normals[todo]),
        )
        missed = []
        for i, node_hits in zip(todo, hits, strict=True):
            hit = _exit(node_hits, fn, normals[i])
            if hit is None or hit[1] - eps > reach or fn[hit[0]] @ normals[i] > -cos:
                missed.append(i)
                continue
            f, _, u, v = hit
            rows += [i, i, i]
            cols += list(F[f])
            vals += [1.0 - u - v, u, v]
        todo = np.asarray(missed, dtype=np.int64)
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(nodes), len(V)))


def _exit(hits: list, fn: np.ndarray, normal: np.ndarray) -> tuple | None:
    """The first of a ray's ``hits`` ``(triangle, t, u, v)`` where it leaves the solid (a
    triangle of unit normal ``fn`` facing along the ray, against ``normal``; a face the ray
    grazes, within about 6 degrees, is passed)."""
    for h in sorted(hits, key=lambda h: h[1]):
        if fn[h[0]] @ normal < -0.1:
            return h
    return None


def _inward_steps(model: ElasticModel, nodes: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m, 3) mm: a twentieth of the way from each held node toward the mean of its
    neighbours on the model's surface, in its tangent plane (off a rim, into its face)."""
    f, _ = boundary_faces(model.X, model.T)
    n = len(model.X)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    A = sp.csr_matrix(
        (
            np.ones(2 * len(edges)),
            (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]]),
        ),
        shape=(n, n),
    )
    A.data[:] = 1.0
    mean = (A @ model.X) / np.maximum(np.asarray(A.sum(axis=1)), 1.0)
    step = mean[nodes] - model.X[nodes]
    step -= np.einsum("ij,ij->i", step, normals)[:, None] * normals
    return step / 20.0


def without_rigid_motion(V: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(n, 3) the displacement ``d`` (n, 3) mm at points ``V`` (n, 3) mm less its
    least-squares small rigid motion ``t + w x (V - c)``."""
    V = np.asarray(V, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    c = V - V.mean(axis=0)
    A = np.zeros((3 * len(V), 6))
    for k in range(3):
        A[k::3, k] = 1.0
    # w x c = -c x w: rows of the cross-product matrix of c, negated
    A[0::3, 4], A[0::3, 5] = c[:, 2], -c[:, 1]
    A[1::3, 3], A[1::3, 5] = -c[:, 2], c[:, 0]
    A[2::3, 3], A[2::3, 4] = c[:, 1], -c[:, 0]
    x, *_ = np.linalg.lstsq(A, d.ravel(), rcond=None)
    return d - (A @ x).reshape(-1, 3)


def _tangents(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (m, 3) each orthogonal to ``normals`` (m, 3) and to each other."""
    a = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


def _held_basis(lm: LoadModel) -> sp.csr_matrix:
    """(N, N - m) the degrees of freedom the normal constraints leave free: every
    unheld one as it is, a held node's two tangential directions."""
    n = lm.model.n_dofs
    vd = lm.model.vertex_dofs[lm.nodes]  # (m, 3)
    held = np.zeros(n, dtype=bool)
    held[vd.ravel()] = True
    free = np.flatnonzero(~held)
    t1, t2 = _tangents(lm.normals)
    m, k = len(lm.nodes), len(free)
    rows = np.r_[free, vd.ravel(), vd.ravel()]
    cols = np.r_[np.arange(k), np.repeat(k + np.arange(m), 3), np.repeat(k + m + np.arange(m), 3)]
    vals = np.r_[np.ones(k), t1.ravel(), t2.ravel()]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, k + 2 * m))


def _free_rigid_motions(lm: LoadModel) -> np.ndarray:
    """(N, r) the rigid motions of the model the normal constraints leave free (a surface
    of revolution turns about its axis): at the vertices only, zero elsewhere."""
    X = lm.model.X
    c = X - X.mean(axis=0)
    scale = max(float(np.abs(c).max()), 1e-12)
    A = np.hstack([lm.normals, np.cross(c[lm.nodes] / scale, lm.normals)])
    _, s, vt = np.linalg.svd(A, full_matrices=True)
    free = vt[int(np.sum(s > 1e-9 * s[0])) :]
    out = np.zeros((lm.model.n_dofs, len(free)))
    for j, v in enumerate(free):  # t + w x c at every vertex
        out[lm.model.vertex_dofs.ravel(), j] = (v[:3] + np.cross(v[3:], c / scale)).ravel()
    return out


def fixture_load(
    lm: LoadModel, V: np.ndarray, d: np.ndarray, misfit: float = 0.0, misfit_source: str = ""
) -> FixtureLoad:
    """The load that holds the part in the nominal ``V`` (n, 3) mm displaced by ``d``
    (n, 3) mm (module docstring).

    Parameters
    ----------
    lm : the part's load model (:func:`load_model` on this mesh).
    V, d : the nominal's vertices and the fitted displacement, (n, 3) mm.
    misfit : the root-mean-square misfit to the fitted normal displacements the held shape
        may keep at the held nodes, mm: the least-energy hold within it
        (:func:`least_energy_hold`); 0 holds them exactly (:func:`_exact_hold`).
    misfit_source : what ``misfit`` is a share of, for the reports.

    Returns
    -------
    FixtureLoad
        Energy, equivalent force, reactions, peak stress, the misfit reached and the fitted
        shape's remainder outside the compliant modes (no limit set:
        :meth:`FixtureLoad.bounded`).
    """
    if len(V) != lm.n_nominal:
        raise ValueError("the load model was built for another mesh of the part")
    d = without_rigid_motion(V, d)
    target = np.einsum("ij,ij->i", lm.W @ d, lm.normals)  # (m,) normal displacement, mm
    if misfit > 0:
        x, reached = least_energy_hold(lm, target, misfit)
    else:
        x, reached = _exact_hold(lm, target), 0.0
    load = _load_of(lm, x, target)
    load.misfit_allowed, load.misfit, load.misfit_source = float(misfit), reached, misfit_source
    if lm.back is not None and lm.modes is not None:
        X = lm.model.X[lm.nodes]
        load.departure = beyond_modes(X, lm.normals, lm.modes, lm.back, target)
        load.modes = lm.modes.shape[1]
        load.absorbed_width = lm.absorbed_width
    if lm.thickness is not None and lm.thickness.nnz:
        change = np.einsum("ij,ij->i", lm.thickness @ d, lm.normals)
        load.thickness_change = float(np.abs(change).max())
    return load


def _exact_hold(lm: LoadModel, target: np.ndarray) -> np.ndarray:
    """(N,) the degrees of freedom of least strain energy with the held nodes' normal
    displacements ``target`` (m,) mm: they are eliminated, the free degrees of freedom
    (:func:`_held_basis`) minimise the strain energy, a symmetric positive definite system
    (a rigid motion left free is held by pinning one degree of freedom, which changes no
    energy: :func:`_pinned_out`)."""
    model = lm.model
    vd = model.vertex_dofs[lm.nodes]  # (m, 3)
    x0 = np.zeros(model.n_dofs)
    x0[vd] = target[:, None] * lm.normals
    B = _held_basis(lm)
    keep = _pinned_out(B.T @ _free_rigid_motions(lm))
    B = B[:, keep]
    A = (B.T @ model.K @ B).tocsc()
    try:
        lu = spla.splu(
            A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError as e:
        raise ValueError(f"the fixture's load cannot be solved ({e})") from None
    return x0 + B @ lu.solve(-(B.T @ (model.K @ x0)))


def least_energy_hold(lm: LoadModel, target: np.ndarray, misfit: float) -> tuple[np.ndarray, float]:
    """(N,) the degrees of freedom of least strain energy whose normal displacements at the
    held nodes differ from ``target`` (m,) mm by at most ``misfit`` mm root mean square,
    and the misfit reached, mm.

    The state minimises ``x' K x / 2 + w |n . x - target|^2 / 2`` for the multiplier ``w``
    (N/mm, a spring at each held node) at which the misfit is the one allowed: the misfit
    falls as ``w`` grows (to zero, the exact hold, as ``w`` grows without bound), so ``w``
    is searched for (:func:`_hold_search`), each solve refactorising one pattern
    (:class:`~qifreport.registration.linalg.SPDSolver`). A target within ``misfit`` of a
    rigid motion is held with almost no energy; one the search does not bracket within
    :data:`HOLD_SOLVES` solves is held exactly.
    """
    model = lm.model
    Bf, normal = _hold_basis(lm)
    Kr = (Bf.T @ model.K @ Bf).tocsc()
    springs = sp.diags(normal.astype(np.float64)).tocsc()
    rhs = np.zeros(Bf.shape[1])
    rhs[normal] = target
    solver = SPDSolver()

    def solve(w: float) -> tuple[np.ndarray, float]:
        z = solver.factor(Kr + w * springs)(w * rhs)
        return z, float(np.sqrt(np.mean((z[normal] - target) ** 2)))

    stiffness = float(np.median(Kr.diagonal()[normal]))  # a held node's own, N/mm
    found = _hold_search(solve, misfit, 1e-3 * stiffness)
    if found is None:
        return _exact_hold(lm, target), 0.0
    z, reached = found
    return Bf @ z, reached


def _hold_search(solve, misfit: float, w0: float) -> tuple[np.ndarray, float] | None:
    """The solution ``solve(w) -> (z, misfit reached)`` of the largest misfit within
    ``misfit`` found (None: none within :data:`HOLD_SOLVES` solves).

    From ``w0`` N/mm, steps in log w as if the misfit fell as ``1 / w`` (its rate where the
    fitted field is nearly held; 1 to 3 decades a step) until the allowed misfit is
    bracketed, then by false position on the log misfit against log w, each step kept
    within the bracket's middle 80 % (bisection's guarantee); it stops at a misfit within
    :data:`HOLD_REACH` below the allowed one. Below ``w0`` by twelve decades, a misfit still
    within the allowance is taken: the target is nearly a rigid motion. A spring too weak
    for the factorisation (the model not held in floating point) is raised a decade."""
    aim = np.log(misfit * (1.0 - 0.5 * HOLD_REACH))
    lo = hi = None  # (log w, log misfit): one beyond the allowance, one within
    best = None
    lw = np.log(w0)
    for _ in range(HOLD_SOLVES):
        try:
            z, r = solve(float(np.exp(lw)))
        except NotPositiveDefinite:  # springs too weak to hold the model in floating point
            if lo is not None or hi is not None:
                break
            lw += np.log(10.0)
            continue
        lr = np.log(max(r, 1e-300))
        if r <= misfit:
            hi, best = (lw, lr), (z, r)
            if r >= (1.0 - HOLD_REACH) * misfit or lw < np.log(w0) - 12 * np.log(10.0):
                break
        else:
            lo = (lw, lr)
        if lo is None or hi is None:
            step = lr - aim
            lw += np.sign(step) * float(np.clip(abs(step), np.log(10.0), 3 * np.log(10.0)))
            continue
        t = (aim - lo[1]) / (hi[1] - lo[1]) if hi[1] != lo[1] else 0.5
        lw = lo[0] + float(np.clip(t, 0.1, 0.9)) * (hi[0] - lo[0])
    return best


def _hold_basis(lm: LoadModel) -> tuple[sp.csr_matrix, np.ndarray]:
    """(N, N - r) every degree of freedom, a held node's as its two tangential directions
    (:func:`_held_basis`) and its normal, the r rigid motions the normals leave free pinned
    out (:func:`_pinned_out`), and (N - r,) bool: the columns that are the held nodes'
    normals, in the order of ``lm.nodes``."""
    n, m = lm.model.n_dofs, len(lm.nodes)
    vd = lm.model.vertex_dofs[lm.nodes]  # (m, 3)
    normals = sp.csr_matrix(
        (lm.normals.ravel(), (vd.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m)
    )
    B = sp.hstack([_held_basis(lm), normals]).tocsr()
    normal = np.zeros(B.shape[1], dtype=bool)
    normal[-m:] = True
    keep = _pinned_out(B.T @ _free_rigid_motions(lm))
    if normal[keep].sum() != m:  # a rigid motion free of the normals moves none of them
        raise ValueError("the fixture's load cannot be solved (a held normal pinned)")
    return B[:, keep], normal[keep]


def _pinned_out(rigid: np.ndarray) -> np.ndarray:
    """(k,) the columns of the free basis kept when the rigid motions ``rigid`` (k, r) it
    leaves free are held by pinning one column each: the energy and the load do not change
    along a rigid motion, and the rows pivoted out of ``rigid`` make it nonsingular."""
    keep = np.ones(rigid.shape[0], dtype=bool)
    if rigid.shape[1]:
        from scipy.linalg import qr

        _, _, piv = qr(rigid.T, mode="economic", pivoting=True)
        keep[piv[: rigid.shape[1]]] = False
    return np.flatnonzero(keep)


def _load_of(lm: LoadModel, x: np.ndarray, target: np.ndarray) -> FixtureLoad:
    """The :class:`FixtureLoad` of the solved degrees of freedom ``x`` (N,) mm holding the
    normal displacements ``target`` (m,) mm."""
    model = lm.model
    Kx = model.K @ x
    energy = 0.5 * float(x @ Kx)
    f = Kx[model.vertex_dofs[lm.nodes]]  # (m, 3): the force on the part at each held node
    X = model.X[lm.nodes]
    pads = cKDTree(X).query_ball_point(X, PAD_RADIUS)
    pad = np.array([np.linalg.norm(f[p].sum(axis=0)) for p in pads])
    corr = float(np.abs(target).max()) if len(target) else 0.0
    mat = model.material
    return FixtureLoad(
        established=True,
        energy=energy,
        max_correction=corr,
        equivalent_force=2.0 * energy / corr if corr > 0 else 0.0,
        total_reaction=float(np.abs(np.einsum("ij,ij->i", f, lm.normals)).sum()),
        peak_pad_force=float(pad.max()) if len(pad) else 0.0,
        peak_stress=float(vertex_von_mises(model, x).max()),
        yield_strength=mat.yield_strength,
        material=mat.name,
        material_source=lm.material_source,
        model=lm.description,
        held_nodes=len(lm.nodes),
        pad_forces=pad,
    )


_PAIRS = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))


def vertex_von_mises(model: ElasticModel, x: np.ndarray) -> np.ndarray:
    """(n,) the von Mises stress, MPa, at each vertex of ``model`` under the degrees of
    freedom ``x`` (N,) mm: each tetrahedron's stress at its corners (its own quadratic
    field), the tensors averaged over the tetrahedra at a vertex."""
    X, T = model.X, model.T
    P = X[T]  # (k, 4, 3)
    J = np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1))  # (k, 3, 3) columns: edges from 0
    Jinv = np.linalg.inv(J)  # rows: gradients of lambda_1..3
    G = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)  # (k, 4, 3)
    uc = x[model.vertex_dofs[T]]  # (k, 4, 3)
    if model.order == 2:
        pairs = np.stack([T[:, [a, b]] for a, b in _PAIRS], axis=1)
        ue = x[model.edge_dofs[model.edge_index(pairs)]]  # (k, 6, 3)
    lam, mu = model.material.lame
    acc = np.zeros((len(X), 3, 3))
    cnt = np.zeros(len(X))
    for j in range(4):  # corner j: lambda = e_j
        if model.order == 2:
            w = np.full(4, -1.0)
            w[j] = 3.0
            grad = np.einsum("k,qki,qkl->qil", w, uc, G)  # du_i/dx_l
            for e, (a, b) in enumerate(_PAIRS):
                if j in (a, b):
                    other = b if j == a else a
                    grad += 4.0 * np.einsum("qi,ql->qil", ue[:, e], G[:, other])
        else:
            grad = np.einsum("qki,qkl->qil", uc, G)
        eps = 0.5 * (grad + np.transpose(grad, (0, 2, 1)))
        tr = np.trace(eps, axis1=1, axis2=2)
        sig = 2.0 * mu * eps + lam * tr[:, None, None] * np.eye(3)
        np.add.at(acc, T[:, j], sig)
        np.add.at(cnt, T[:, j], 1.0)
    s = acc / np.maximum(cnt, 1.0)[:, None, None]
    dev = s - np.trace(s, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("qij,qij->q", dev, dev))
