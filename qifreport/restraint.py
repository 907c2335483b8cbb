"""The restrained condition of an inspection, from the options to the per-part basis.

ISO 10579 and ASME Y14.5 restraint notes inspect a non-rigid part held as its drawing says.
This module gathers what such an inspection needs before the first scan:

* the clamps (:func:`read_clamps_file`: the ``--clamps`` CSV, with ``--max-clamp-force``
  as the limit of the clamps that state none), checked against the nominal (each on its
  surface, together holding the part's six rigid motions);
* the material (``--material``: a preset or ``E=..,nu=..``; without it the held shape is
  solved all the same, with Poisson's ratio 0.3, but no force can be stated, nor checked);
* the part's elastic model: a STEP solid filled with tetrahedra by gmsh
  (:func:`qifreport.step.gmsh_mesh.gmsh_solid_mesh`), a mesh nominal (an open sheet)
  decimated and thickened by ``--thickness`` (:mod:`qifreport.registration.restraint.sheet_solid`);
* and from them the restraint basis (:func:`build_restraint`), the per-part cache's entry.

:class:`RestraintSpec` carries the choices (all JSON-able, for the cache key).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from qifreport.metrology.model import MaterialStatement
from qifreport.registration.mesh import face_normals
from qifreport.registration.restraint.clamp_set import ClampSet, classify_clamp_set
from qifreport.registration.restraint.clamps import Clamp, parse_clamps
from qifreport.registration.restraint.elastic import Material, elastic_model, material
from qifreport.registration.restraint.fixture_load import LoadModel, boundary_faces, load_model
from qifreport.registration.restraint.restrained import RestraintBasis, restraint_basis

from .errors import InputError

__all__ = [
    "OPERATOR_MATERIAL",
    "DEFAULT_PAD_RADIUS",
    "LoadSpec",
    "build_load_model",
    "with_drawing_material",
    "restraint_with_drawing_material",
    "RestraintSpec",
    "boundary_normals",
    "build_restraint",
    "clamp_set",
    "PMI_CLAMPS",
    "read_clamps",
    "sheet_model_mesh",
    "clamp_rows",
    "clamps_from_pmi",
    "drawing_clamps",
    "gravity_direction",
    "read_clamps_file",
    "with_limits",
]

log = logging.getLogger(__name__)

#: ``--clamps pmi``: the clamps are the STEP nominal's datum targets
PMI_CLAMPS = "pmi"

#: contact radius of a clamp or support, mm (an RPS pad of 10 mm diameter)
DEFAULT_PAD_RADIUS = 5.0

#: triangles of a mesh nominal's elastic model (its mesh decimated to this)
SHEET_MODEL_TRIANGLES = 3000

#: a STEP solid's tetrahedra: target edge as a share of the part's diagonal
SOLID_EDGE_SHARE = 1.0 / 40.0

#: how far a clamp may sit from the nominal surface: this share of the diagonal, at least
#: 1 mm (a clamp off the part is a file in another frame or another part's)
_ON_SURFACE_SHARE = 0.01

#: the material without ``--material``: the held shape does not depend on Young's modulus
UNSTATED = Material("unstated", 1.0, 0.3, 0.0)

#: where an operator's ``--material`` came from, in the reports (``material_source``)
OPERATOR_MATERIAL = "operator (--material)"


@dataclass(frozen=True)
class RestraintSpec:
    """How the part is held: clamps, material, wall thickness, contact size.

    Attributes
    ----------
    clamps : the clamps (:class:`qifreport.registration.restraint.clamps.Clamp`).
    source : where they came from (``"clamps file NAME"``, ``"PMI datum targets"``).
    material : the ``--material`` text, else the drawing's preset
        (:func:`restraint_with_drawing_material`); None when neither states one (no
        forces then). ``material_source`` says which.
    thickness : a mesh nominal's wall thickness, mm (``--thickness``).
    pad_radius : each clamp's contact radius, mm.
    gravity : the direction of gravity while held (``--gravity``), None: no weight.
    """

    clamps: tuple[Clamp, ...]
    source: str
    material: str | None = None
    thickness: float | None = None
    pad_radius: float = DEFAULT_PAD_RADIUS
    gravity: str | None = None
    material_source: str = OPERATOR_MATERIAL

    def key(self) -> dict:
        """JSON-able: what the restraint basis depends on (not the force limits: they are
        checked on each inspection, :func:`with_limits`)."""
        return {
            "clamps": [
                {k: v for k, v in c.to_dict().items() if k not in ("max_force_N", "source")}
                for c in self.clamps
            ],
            "source": self.source,
            "material": self.material,
            "thickness": self.thickness,
            "pad_radius": self.pad_radius,
            "gravity": None if self.gravity is None else gravity_direction(self.gravity).tolist(),
        }

    def elastic_material(self) -> Material:
        """The stated material (:class:`InputError` for one that is not), or :data:`UNSTATED`."""
        if self.material is None:
            return UNSTATED
        try:
            return material(self.material)
        except ValueError as exc:
            raise InputError(f"--material: {exc}") from None


def with_limits(basis: RestraintBasis, spec: RestraintSpec) -> RestraintBasis:
    """The basis with the clamps (force limits, sources) of ``spec``: a cached basis was
    built for clamps at the same places and directions, perhaps with other limits."""
    same = len(basis.clamps) == len(spec.clamps) and all(
        a.name == b.name and a.position == b.position and a.directions == b.directions
        for a, b in zip(basis.clamps, spec.clamps, strict=False)
    )
    if not same:
        raise ValueError("the restraint basis was built for other clamps")
    basis.clamps = list(spec.clamps)
    return basis


def read_clamps_file(path: Path, max_force: float | None = None) -> tuple[Clamp, ...]:
    """The clamps of a ``--clamps`` CSV
    (:func:`qifreport.registration.restraint.clamps.parse_clamps`),
    ``max_force`` (N) the limit of those that state none.

    Raises
    ------
    InputError
        A missing or unreadable file, or a malformed row (naming the line).
    """
    if max_force is not None and not (math.isfinite(max_force) and max_force > 0):
        raise InputError(f"--max-clamp-force must be a positive force in N, got {max_force}")
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"clamps file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"clamps file {path} cannot be read: {exc}") from None
    try:
        clamps = parse_clamps(text, source=f"clamps file {Path(path).name}")
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if max_force is not None:
        clamps = [
            c
            if c.max_force is not None
            else Clamp(c.name, c.position, c.directions, max_force, c.source)
            for c in clamps
        ]
    return tuple(clamps)


def _closest_normals(
    V: np.ndarray, F: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distances (c,) of ``points`` (c, 3) to the mesh and the unit normals (c, 3) of the
    triangles closest to them."""
    from qifreport.metrology.deviation.closest import closest_points

    C, tri, _ = closest_points(V, F, points)
    return np.linalg.norm(points - C, axis=1), face_normals(V, F)[tri]


def sheet_model_mesh(
    V: np.ndarray, F: np.ndarray, triangles: int = SHEET_MODEL_TRIANGLES
) -> tuple[np.ndarray, np.ndarray]:
    """A mesh nominal decimated to about ``triangles`` triangles for its elastic model
    (igl's edge collapses; the nominal itself when it has no more)."""
    if len(F) <= triangles:
        return V, F
    import igl

    U, G, _, _ = igl.decimate(
        np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64), triangles
    )
    return np.ascontiguousarray(U), np.ascontiguousarray(G, dtype=np.int64)


def boundary_normals(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(n, 3) the outward unit normals at the boundary vertices of tetrahedra ``T`` (k, 4)
    over ``X`` (n, 3) (area-weighted over their boundary faces; zero rows inside)."""
    f, n = boundary_faces(X, T)
    out = np.zeros_like(np.asarray(X, dtype=np.float64))
    for k in range(3):
        np.add.at(out, f[:, k], n)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def build_restraint(
    V: np.ndarray,
    F: np.ndarray,
    spec: RestraintSpec,
    *,
    solid: tuple[np.ndarray, np.ndarray] | None = None,
) -> RestraintBasis:
    """The part's restraint basis: its elastic model solved once per clamp direction.

    Parameters
    ----------
    V : (n, 3) mm, F : (f, 3) the nominal's inspection mesh.
    spec : the clamps and material.
    solid : ``(X, T)`` the tetrahedra of a STEP solid (mm); None for a mesh nominal, whose
        sheet is thickened by ``spec.thickness``.

    Returns
    -------
    RestraintBasis
        :class:`qifreport.registration.restraint.restrained.RestraintBasis`; its ``model`` the
        model's provenance for the reports (material, mesh, seconds).

    Raises
    ------
    InputError
        A clamp off the part's surface, clamps that leave a rigid motion free, a mesh
        nominal without ``--thickness``, a material that is not one.
    """
    t0 = time.perf_counter()
    clamps = list(spec.clamps)
    mat = spec.elastic_material()
    normals = _held_normals(V, F, clamps)
    held = clamp_set(V, clamps, normals, spec.pad_radius)
    X, T, kind = _elastic_solid(V, F, spec, solid)
    model = elastic_model(X, T, mat)
    load = _gravity_load(spec, mat, model)
    try:
        basis = restraint_basis(
            model,
            clamps,
            normals,
            V,
            F,
            pad_radius=spec.pad_radius,
            surface=np.linalg.norm(sn := boundary_normals(X, T), axis=1) > 0,
            surface_normals=sn,
            load=load,
        )
    except ValueError as exc:
        raise InputError(f"the clamps cannot hold the part: {exc}") from None
    basis.forces_known = spec.material is not None
    info = {
        "model": kind,
        **basis.model,
        "material": None if spec.material is None else mat.to_dict(),
        "material_source": None if spec.material is None else spec.material_source,
        "pad_radius_mm": spec.pad_radius,
        "clamps_source": spec.source,
        "clamp_set": {**held.to_dict(), "statement": held.describe()},
        "gravity": None if load is None else gravity_direction(spec.gravity).tolist(),
        "seconds": time.perf_counter() - t0,
    }
    basis.model = info
    log.info(
        "elastic model (%s): %d vertices, %d tetrahedra, %d clamp directions in %.1f s",
        kind,
        len(X),
        len(T),
        len(basis.owner),
        info["seconds"],
    )
    return basis


def _held_normals(V: np.ndarray, F: np.ndarray, clamps: list) -> np.ndarray:
    """(c, 3) the surface normal at each clamp; InputError for a clamp off the part's
    surface."""
    pos = np.array([c.position for c in clamps], dtype=np.float64)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    dist, normals = _closest_normals(V, F, pos)
    limit = max(1.0, _ON_SURFACE_SHARE * diag)
    for c, d in zip(clamps, dist, strict=True):
        if d > limit:
            raise InputError(
                f"clamp {c.name} ({', '.join(f'{x:g}' for x in c.position)}) is {d:.3g} mm "
                f"from the part's surface (at most {limit:.3g} mm): its file is in another "
                "frame, or names another part's point"
            )
    return normals


def clamp_set(V: np.ndarray, clamps: list, normals: np.ndarray, pad_radius: float) -> ClampSet:
    """What ``clamps`` hold of the part ``V`` (n, 3) mm, their surface ``normals`` (c, 3) and
    pads of ``pad_radius`` mm (:func:`classify_clamp_set`).

    Raises
    ------
    InputError
        A set that leaves a rigid motion free or holds one too weakly to place the part
        (naming it).
    """
    pos = np.array([c.position for c in clamps], dtype=np.float64)
    rows = [(p, e) for c, p, n in zip(clamps, pos, normals, strict=True) for e in c.axes(n)]
    cs = classify_clamp_set(
        np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), V, pad_radius
    )
    why = cs.refusal()
    if why is not None:
        raise InputError(why)
    return cs


def _elastic_solid(
    V: np.ndarray,
    F: np.ndarray,
    spec: RestraintSpec,
    solid: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, str]:
    """The tetrahedra ``(X, T)`` of the elastic model and what they are: the STEP solid's,
    or a mesh nominal's sheet thickened by ``spec.thickness`` (InputError without one)."""
    if solid is not None:
        X, T = solid
        return X, T, "STEP solid, gmsh tetrahedra"
    if spec.thickness is None:
        raise InputError(
            "a mesh nominal's restrained inspection needs its wall thickness: "
            "--thickness MM (or --fixture free)"
        )
    if not (math.isfinite(spec.thickness) and spec.thickness > 0):
        raise InputError(f"--thickness must be a positive length in mm, got {spec.thickness}")
    from qifreport.registration.mesh import vertex_normals
    from qifreport.registration.restraint.sheet_solid import sheet_solid

    U, G = sheet_model_mesh(V, F)
    sheet = sheet_solid(U, G, vertex_normals(U, G), spec.thickness)
    return sheet.X, sheet.T, f"sheet {spec.thickness:g} mm thick, {len(G)} triangles thickened"


def _gravity_load(spec: RestraintSpec, mat: Material, model) -> np.ndarray | None:
    """The part's own weight as a load on ``model`` when ``--gravity`` is given (None
    otherwise; InputError without a material's density)."""
    if spec.gravity is None:
        return None
    if spec.material is None or mat.density <= 0:
        raise InputError(
            "--gravity needs the part's weight: --material with a density (a preset, "
            "or E=..,nu=..,density=..)"
        )
    return model.gravity(gravity_direction(spec.gravity))


def gravity_direction(text: str) -> np.ndarray:
    """(3,) the unit direction of ``--gravity``: an axis (``-z``, ``+x``, ``y``) or
    ``x,y,z`` components (:class:`InputError` for anything else)."""
    t = text.strip().lower().replace(" ", "")
    axes = {"x": 0, "y": 1, "z": 2}
    if t.lstrip("+-") in axes and len(t) <= 2:
        d = np.zeros(3)
        d[axes[t[-1]]] = -1.0 if t.startswith("-") else 1.0
        return d
    try:
        d = np.array([float(x) for x in t.split(",")], dtype=np.float64)
    except ValueError:
        d = np.zeros(0)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
        raise InputError(
            f"--gravity must be an axis (-z, +x, ...) or a direction x,y,z, got {text!r}"
        )
    return d / np.linalg.norm(d)


def _primary_datum(pmi) -> str | None:
    """The datum most tolerances name first (their primary), else the first datum."""
    firsts = [t.datums[0].label for t in pmi.tolerances if getattr(t, "datums", None)]
    if firsts:
        return max(set(firsts), key=firsts.count)
    return pmi.datums[0].label if pmi.datums else None


def read_clamps(
    clamps: Path | str, nominal: Path | None, max_force: float | None = None
) -> tuple[tuple[Clamp, ...], str]:
    """The clamps a ``--clamps`` argument names, and their source for the reports: with
    ``pmi`` the datum targets of the STEP ``nominal`` (:func:`clamps_from_pmi`), else the
    CSV file (:func:`read_clamps_file`); ``max_force`` (N) the limit of those stating none.

    Raises
    ------
    InputError
        As those two; ``pmi`` without a nominal.
    """
    if str(clamps) == PMI_CLAMPS:
        if nominal is None:
            raise InputError("--clamps pmi needs the STEP nominal whose datum targets hold it")
        return clamps_from_pmi(nominal, max_force), "PMI datum targets"
    return read_clamps_file(Path(clamps), max_force), f"clamps file {Path(clamps).name}"


def clamps_from_pmi(
    path: Path, max_force: float | None = None, only: tuple[str, ...] | None = None
) -> tuple[Clamp, ...]:
    """The clamps of a STEP nominal's datum targets (``--clamps pmi``): each placed target
    is a contact at its placement. The primary datum's targets are the supports and clamps
    (restraining along the surface normal, ``n``); the others are locators restraining
    their axis (``x``, ``y`` or ``z`` when it is one, else ``n``). Each one's force limit:
    ``max_force`` (N, ``--max-clamp-force``), else the one the drawing's restraint note
    states per contact (:attr:`qifreport.step.pmi.RestraintNote.force_limit`: "RESTRAINT
    FORCE AT MOST 20 N PER TARGET"), else none. ``only``: the targets of these names
    (the drawing's restraint note's, :func:`drawing_clamps`); None: every placed one.

    Raises
    ------
    InputError
        Not a STEP file, an unreadable one, or no placed datum target (naming the datums
        there are).
    """
    if Path(path).suffix.lower() not in (".stp", ".step", ".p21"):
        raise InputError(f"--clamps pmi: {Path(path).name} is a mesh, it has no datum targets")
    pmi = _read_pmi(path, "--clamps pmi")
    return _target_clamps(pmi, Path(path).name, max_force, only)


def drawing_clamps(
    path: Path, max_force: float | None = None
) -> tuple[tuple[Clamp, ...], str] | None:
    """The clamps a STEP drawing's restraint note holds the part at, and their source for
    the reports: the placed datum targets it names (:meth:`qifreport.step.pmi.PMI.held_targets`,
    "HELD ... AT TARGETS A1-A4, ... B1, C1-C2"), each as :func:`clamps_from_pmi` makes it;
    None for a mesh, a note that names no target or one the file does not place (the
    part is then judged as :meth:`qifreport.options.InspectOptions.restraint_condition`
    says), or a file that cannot be read (reading the nominal says why)."""
    from qifreport.step.p21 import P21Error
    from qifreport.step.semantic import read_pmi_text

    if Path(path).suffix.lower() not in (".stp", ".step", ".p21"):
        return None
    try:
        pmi = read_pmi_text(path)
    except (OSError, P21Error, ValueError):
        return None
    held, unplaced = pmi.held_targets()
    if not held or unplaced:
        return None
    clamps = _target_clamps(pmi, Path(path).name, max_force, held)
    note = pmi.restraint
    return clamps, f"the drawing's restraint note (#{note.step_id}): datum targets " + ", ".join(
        held
    )


def _read_pmi(path: Path, flag: str):
    """The semantic PMI of a STEP file (:class:`InputError` naming ``flag`` when it cannot
    be read)."""
    from qifreport.step.p21 import P21Error
    from qifreport.step.semantic import read_pmi_text

    try:
        return read_pmi_text(path)
    except (OSError, P21Error) as exc:
        raise InputError(f"{flag}: {Path(path).name} cannot be read: {exc}") from None


def _target_clamps(
    pmi, name: str, max_force: float | None, only: tuple[str, ...] | None
) -> tuple[Clamp, ...]:
    """The clamps of the placed datum targets of ``pmi`` (:func:`clamps_from_pmi`)."""
    if max_force is not None and not (math.isfinite(max_force) and max_force > 0):
        raise InputError(f"--max-clamp-force must be a positive force in N, got {max_force}")
    stated = ""
    note = pmi.restraint
    if max_force is None and note is not None and note.force_limit is not None:
        max_force = note.force_limit
        stated = f"; limit from the drawing's note '{note.force_text}' (#{note.step_id})"
    primary = _primary_datum(pmi)
    clamps = []
    for d in pmi.datums:
        for t in d.target_details:
            if t.position is None or t.direction is None:
                continue
            if only is not None and t.name not in only:
                continue
            axis = np.abs(np.asarray(t.direction, dtype=float))
            if d.label == primary or axis.max() < 0.999:
                directions = "n"
            else:
                directions = "xyz"[int(np.argmax(axis))]
            clamps.append(
                Clamp(
                    t.name,
                    tuple(float(x) for x in t.position),
                    directions,
                    max_force,
                    f"PMI datum target {t.name} (#{t.step_id}, {t.kind or 'target'}){stated}",
                )
            )
    if not clamps:
        labels = ", ".join(d.label for d in pmi.datums) or "none"
        raise InputError(
            f"--clamps pmi: {name} has no placed datum target (datums: {labels}); "
            "give the clamps as --clamps FILE"
        )
    return tuple(clamps)


def clamp_rows(part, clamps: tuple[Clamp, ...]) -> list[dict]:
    """One row per clamp for ``qifreport pmi --clamps``: where it sits on a STEP part.

    Parameters
    ----------
    part : a :class:`qifreport.step.reader.StepPart`.  clamps : from :func:`read_clamps_file`.

    Returns
    -------
    rows : name, x, y, z (mm), directions, max_force_N (None: no limit), source, face (its
    index, the B-rep face it sits on), face_step_id, datum (the datum whose feature holds that
    face, or ""), off_surface_mm (its distance from the part's surface).
    """
    from qifreport.metrology.deviation.closest import closest_points
    from qifreport.step.tessellate import tessellate

    m = tessellate(part.shape, part.faces)
    pos = np.array([c.position for c in clamps], dtype=np.float64).reshape(-1, 3)
    C, tri, _ = closest_points(m.V, m.F, pos)
    datum_of: dict[int, str] = {}
    for d in getattr(part.pmi, "datums", None) or []:
        for f in part.faces_of(d.face_step_ids):
            datum_of.setdefault(f, d.label)
    rows = []
    for c, q, t in zip(clamps, C, tri, strict=True):
        face = int(m.face_id[t])
        rows.append(
            {
                "name": c.name,
                "x": c.position[0],
                "y": c.position[1],
                "z": c.position[2],
                "directions": c.directions,
                "max_force_N": c.max_force,
                "source": c.source,
                "face": face,
                "face_step_id": int(part.face_step_ids[face]),
                "datum": datum_of.get(face, ""),
                "off_surface_mm": float(np.linalg.norm(q - np.asarray(c.position))),
            }
        )
    return rows


@dataclass(frozen=True)
class LoadSpec:
    """What the virtual fixture's load needs of the part (:func:`build_load_model`): its
    material (``--material``, else the drawing's: :func:`with_drawing_material`) and, for a
    mesh nominal, its wall thickness (``--thickness``); ``material_source`` says where the
    material came from."""

    material: str | None = None
    thickness: float | None = None
    material_source: str = OPERATOR_MATERIAL

    def key(self) -> dict:
        """JSON-able, for the cache key."""
        return {
            "material": self.material,
            "thickness": self.thickness,
            "material_source": self.material_source,
        }


def with_drawing_material(spec: LoadSpec, stated: MaterialStatement | None) -> LoadSpec | str:
    """``spec`` with the drawing's material when the operator states none: the preset it
    names, or why the load cannot be established (a material that names no preset is
    never replaced by a near one). An operator's ``--material`` overrides the drawing's."""
    if spec.material is not None or stated is None:
        return spec
    if stated.preset is None:
        return (
            f"material '{stated.text}' has no preset ({stated.source}; --material names "
            "one or states its values)"
        )
    return _with_drawing_preset(spec, stated)


def restraint_with_drawing_material(
    spec: RestraintSpec, stated: MaterialStatement | None
) -> RestraintSpec:
    """``spec`` with the drawing's material when the operator states none and the drawing's
    names a preset (the held shape is solved all the same without one; its forces are then
    not known, and a force limit not checked: the verdict says so)."""
    if spec.material is not None or stated is None or stated.preset is None:
        return spec
    return _with_drawing_preset(spec, stated)


def _with_drawing_preset(spec, stated: MaterialStatement):
    """``spec`` (a :class:`LoadSpec` or :class:`RestraintSpec`) with the preset the drawing's
    material names, its source said."""
    return replace(
        spec,
        material=stated.preset,
        material_source=f"drawing ({stated.source} '{stated.text}')",
    )


def build_load_model(
    V: np.ndarray,
    F: np.ndarray,
    spec: LoadSpec,
    *,
    solid: tuple[np.ndarray, np.ndarray] | None = None,
    step: bool = False,
    modes: bool = True,
) -> LoadModel | str:
    """The part's elastic model for the virtual fixture's load
    (:func:`qifreport.registration.restraint.fixture_load.load_model`), or why there is none
    (a sentence naming what is needed: the load is then reported as not established).

    Parameters
    ----------
    V : (n, 3) mm, F : (f, 3) the nominal's inspection mesh.  spec : material, thickness.
    solid : ``(X, T)`` a STEP solid's tetrahedra (mm); None for a mesh nominal, thickened
        by ``spec.thickness``.  step : the nominal is a STEP part (for the reason only).
    modes : with the part's compliant modes (False: the load alone).

    Raises
    ------
    InputError
        A material that is not one.
    """
    if spec.material is None:
        return "the part's material is not stated (--material)" + (
            "" if step or spec.thickness is not None else " nor its wall thickness (--thickness)"
        )
    mat = RestraintSpec((), "", material=spec.material).elastic_material()
    if solid is None and step:
        return "the STEP part has no solid to fill with tetrahedra"
    if solid is None and spec.thickness is None:
        return "a mesh nominal's elastic model needs its wall thickness (--thickness)"
    t0 = time.perf_counter()
    shell = RestraintSpec((), "", thickness=spec.thickness)
    X, T, kind = _elastic_solid(V, F, shell, solid)
    try:
        lm = load_model(
            elastic_model(X, T, mat),
            V,
            F,
            kind,
            material_source=spec.material_source,
            modes=modes,
        )
    except ValueError as exc:
        return f"the elastic model cannot take the fixture's displacement: {exc}"
    log.info(
        "fixture-load model (%s): %d vertices, %d held, %.1f s",
        kind,
        len(X),
        len(lm.nodes),
        time.perf_counter() - t0,
    )
    return lm
