"""The deviation stage: the scan points' and the vertices' deviations from the held nominal
(:func:`deviation_stage`), the free state's among them (:func:`free_state_deviation`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from qifreport.metrology.acceptance.coverage import unseen_neighbour_edges
from qifreport.metrology.deviation.closest import beyond_rim, closest_points
from qifreport.metrology.deviation.hygiene import MeshHygiene
from qifreport.metrology.deviation.residual_fit import residual_referenced
from qifreport.metrology.deviation.rim import beyond_crease, split_at_creases
from qifreport.metrology.deviation.surface import point_faces, surface_distance
from qifreport.metrology.prepared import PreparedPart
from qifreport.registration.deformable.result import orient_scan_normals
from qifreport.registration.mesh import face_normals

from .context import JudgeContext, Registered
from .held import HeldNominal

__all__ = ["Deviations", "deviation_stage", "free_state_deviation", "vertex_deviation"]


@dataclass(frozen=True)
class Deviations:
    """The scan's deviations from the held nominal (:func:`deviation_stage`); ``n``
    vertices, ``m`` scan points, mm.

    Attributes
    ----------
    closest : (m, 3) each point's closest point on the held nominal.
    face : (m,) that point's triangle (-1: none).
    point : (m,) each point's signed distance to the nominal surface (the curved B-rep
        surface for a STEP nominal).
    vertex : (n,) each vertex's nominal-referenced deviation, NaN where unscored (the rim
        and crease bands).  variance : (n,) its variance, mm^2.
    free, free_variance : (n,) the free state's, for the free-state zones of a held part;
        None otherwise.
    near_crease : (n,) bool the crease band's vertices outside the rim band (or, for a
        B-rep's free state, the crease vertices not all of whose faces were seen); None:
        no crease band.
    excluded : (n,) bool every unscored band's vertices.
    beyond_rim : (m,) bool the points beyond the rim of the held nominal.
    hygiene : the mesh hygiene with this inspection's rim band.
    """

    closest: np.ndarray
    face: np.ndarray
    point: np.ndarray
    vertex: np.ndarray
    variance: np.ndarray
    free: np.ndarray | None
    free_variance: np.ndarray | None
    near_crease: np.ndarray | None
    excluded: np.ndarray
    beyond_rim: np.ndarray
    hygiene: MeshHygiene


def deviation_stage(
    reg: Registered,
    nominal: HeldNominal,
    ctx: JudgeContext,
    *,
    free_deviation: tuple[np.ndarray, np.ndarray] | None = None,
    free: Registered | None = None,
) -> Deviations:
    """The scan points' and the vertices' deviations from the held nominal, and the free
    state's for the free-state zones of a held part, with the unscored bands left out
    (:class:`Deviations`).

    Parameters
    ----------
    reg : the seated scan.  nominal : :func:`.held.held_nominal`.  ctx : the judgement's context.
    free_deviation : the free state's (n,) vertex deviation, mm, and its variance, mm^2,
        when it was judged already; None: measured here when needed.
    free : the free state's registration when ``reg`` holds the scan otherwise (restrained).
    """
    F, Pm, face_id = reg.F, reg.P, ctx.face_id
    C, cface, pdev = closest_points(nominal.V, F, Pm)
    if face_id is not None:  # a B-rep nominal: the points' distances to its curved surface
        pdev = surface_distance(nominal.V, F, C, cface, pdev, face_id, nominal.corner_normals, Pm)
    dev, var = vertex_deviation(
        nominal.V,
        F,
        Pm,
        nominal.normals,
        face_id,
        closest=(C, cface, pdev),
        scan_normals=_mesh_scan_normals(reg, nominal.V, nominal.normals, face_id),
        residual=pdev if face_id is not None else None,
        crease_angle=ctx.prepared.settings["crease_angle"],
    )
    dev_free = var_free = None
    if nominal.held and any(z.free_state for z in ctx.bands.zones):
        if free_deviation is not None:
            dev_free, var_free = free_deviation[0].copy(), free_deviation[1]
        else:
            dev_free, var_free = free_state_deviation(reg if free is None else free, ctx)
    dev, dev_free, near_crease, excluded = _unscored(dev, dev_free, F, nominal, ctx)
    return Deviations(
        closest=C,
        face=cface,
        point=pdev,
        vertex=dev,
        variance=var,
        free=dev_free,
        free_variance=var_free,
        near_crease=near_crease,
        excluded=excluded,
        beyond_rim=beyond_rim(nominal.V, F, C, cface),
        hygiene=_rim_hygiene(ctx.prepared),
    )


def free_state_deviation(free: Registered, ctx: JudgeContext) -> tuple[np.ndarray, np.ndarray]:
    """The free state's (n,) vertex deviation, mm, and its variance, mm^2: the scan
    ``free`` on the nominal where the rigid alignment put it (:func:`vertex_deviation`)."""
    normals = ctx.prepared.ops.normals
    return vertex_deviation(
        free.V,
        free.F,
        free.P,
        normals,
        ctx.face_id,
        scan_normals=_mesh_scan_normals(free, free.V, normals, ctx.face_id),
        brep_normals=ctx.brep_normals,
        crease_angle=ctx.prepared.settings["crease_angle"],
    )


def _mesh_scan_normals(
    reg: Registered, V: np.ndarray, normals: np.ndarray, face_id: np.ndarray | None
) -> np.ndarray | None:
    """The scan's outward normals (m, 3) for a mesh nominal's vertex fit
    (:func:`~qifreport.registration.deformable.result.orient_scan_normals` against the
    nominal ``V`` (n, 3) mm with its unit ``normals``); None for a B-rep nominal
    (``face_id``), whose faces keep the points apart."""
    if face_id is not None:
        return None
    return orient_scan_normals(reg.P, reg.scan_normals, V, normals, sheets=reg.sheets)


def vertex_deviation(
    V: np.ndarray,
    F: np.ndarray,
    P: np.ndarray,
    normals: np.ndarray,
    face_id: np.ndarray | None,
    *,
    closest: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    scan_normals: np.ndarray | None = None,
    residual: np.ndarray | None = None,
    brep_normals: np.ndarray | None = None,
    crease_angle: float = 45.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Nominal-referenced deviation (n,) mm of every vertex of ``(V, F)`` from scan ``P``,
    and its variance (n,) mm^2 from the scan points' scatter about the local fit (for
    :func:`qifreport.metrology.acceptance.decision.vertex_uncertainty`).

    Each point's signed distance to the nominal *surface* is fitted about each vertex by
    :func:`~qifreport.metrology.deviation.residual_fit.residual_referenced`, a vertex using
    only the points on its own faces. The distance is the point's to the closest triangle
    (``closest`` from :func:`~qifreport.metrology.deviation.closest.closest_points`, computed
    when not given). A STEP nominal (``face_id``, its B-rep faces): less the triangle's chord
    height there (:func:`~qifreport.metrology.deviation.surface.surface_distance`, with the
    B-rep's corner normals ``brep_normals`` (f, 3, 3)); ``residual`` (m,): those distances
    when the caller has them. A mesh nominal (``face_id`` None): the triangles are the
    nominal surface (no chord correction); its faces are the smooth patches between its
    creases sharper than ``crease_angle`` degrees
    (:func:`~qifreport.metrology.deviation.rim.split_at_creases`), a point counts for a vertex
    only where its outward normal (``scan_normals`` (m, 3), oriented; default its closest
    triangle's) lies within 60 degrees of the vertex's: not a thin wall's far skin, nor the
    side of material the nominal does not have (a rib, reported as added material); the
    points beyond the open rim are left out, and so are the points nearer the extension of
    a neighbouring patch across a crease than their own patch
    (:func:`~qifreport.metrology.deviation.rim.beyond_crease`: a neighbouring face's points
    past a crease the nominal sits inside of, read against the face below them). A plane
    fitted to the points would read a curved surface's sag inside its ball as deviation
    (``r^2 / 4R``: 0.025 mm for a 2 mm ball on a 40 mm radius); the points' own distances
    do not.
    """
    C, cface, pdev = closest_points(V, F, P) if closest is None else closest
    if face_id is None:  # a mesh nominal: the triangles are the surface
        labels = split_at_creases(V, F, crease_angle)[3]
        off = beyond_rim(V, F, C, cface) | beyond_crease(V, F, labels, P, cface, pdev)
        residual = np.where(off, np.nan, pdev)
        return residual_referenced(
            V,
            F,
            P,
            residual,
            normals,
            point_faces(cface, labels),
            labels,
            variance=True,
            point_normals=face_normals(V, F)[np.maximum(cface, 0)]
            if scan_normals is None
            else scan_normals,
        )
    if residual is None:
        residual = surface_distance(V, F, C, cface, pdev, face_id, brep_normals, P)
    return residual_referenced(
        V, F, P, residual, normals, point_faces(cface, face_id), face_id, variance=True
    )


def _unscored(
    dev: np.ndarray,
    dev_free: np.ndarray | None,
    F: np.ndarray,
    nominal: HeldNominal,
    ctx: JudgeContext,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """``dev`` and ``dev_free`` (n,) with the rim band's and the crease band's vertices
    unscored (NaN, copies), the crease band's vertices outside the rim band (each excluded
    vertex is counted once, rim first; a B-rep's free state: the crease vertices not all of
    whose faces were seen), and every excluded vertex, (n,) bool."""
    near_rim = ctx.prepared.near_rim
    near_crease = None if nominal.to_creases else ctx.prepared.near_crease
    if near_crease is not None:
        near_crease = near_crease & ~near_rim
    unscored = near_rim if near_crease is None else near_rim | near_crease
    dev = dev.copy()
    dev[unscored] = np.nan
    if dev_free is not None:
        dev_free = dev_free.copy()
        dev_free[unscored] = np.nan
    if nominal.to_creases:
        near_crease = unseen_neighbour_edges(F, ctx.face_id, dev)
    excluded = near_rim if near_crease is None else near_rim | near_crease
    return dev, dev_free, near_crease, excluded


def _rim_hygiene(prepared: PreparedPart) -> MeshHygiene:
    """The part's mesh hygiene (a copy) with this inspection's rim band."""
    ops, near_rim = prepared.ops, prepared.near_rim
    hygiene = replace(prepared.hygiene)
    hygiene.boundary_band = prepared.rim_band
    hygiene.boundary_excluded_area = float(ops.area[near_rim].sum())
    hygiene.boundary_excluded_fraction = hygiene.boundary_excluded_area / max(
        float(ops.area.sum()), 1e-300
    )
    return hygiene
