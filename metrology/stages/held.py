"""The judgement's first stage: the nominal as the fixture holds it (:func:`held_nominal`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.metrology.deviation.surface import follow_triangles
from qifreport.metrology.params import InspectionParams
from qifreport.registration.deformable.bending_basis import BendingBasis
from qifreport.registration.deformable.result import DeformResult
from qifreport.registration.mesh import vertex_normals

from .context import JudgeContext, Registered

__all__ = ["HeldNominal", "held_nominal"]


@dataclass(frozen=True)
class HeldNominal:
    """The nominal as the judgement holds it (:func:`held_nominal`).

    Attributes
    ----------
    V : (n, 3) its vertices, mm: the virtual fixture's, or the nominal's (free state).
    normals : (n, 3) unit vertex normals of ``V``.
    corner_normals : (f, 3, 3) the B-rep's corner normals turned with each triangle the
        fixture bent; None: a mesh nominal.
    basis : the bending basis reported (the fixture's, else the context's).
    held : the part is held (a virtual fixture, or clamps), not in its free state.
    to_creases : the free state of a B-rep nominal, scored up to its creases (no crease
        band: :func:`.deviation.vertex_deviation` keeps each vertex to its own faces' points).
    """

    V: np.ndarray
    normals: np.ndarray
    corner_normals: np.ndarray | None
    basis: BendingBasis | None
    held: bool
    to_creases: bool


def held_nominal(
    reg: Registered,
    fit: DeformResult | None,
    ctx: JudgeContext,
    params: InspectionParams,
    *,
    restrained: bool = False,
) -> HeldNominal:
    """The nominal as the fixture ``fit`` holds it (None: where the rigid alignment put
    it); ``restrained``: the scan ``reg`` is held at its clamps (:class:`HeldNominal`)."""
    V_reg = reg.V if fit is None else fit.V
    corners = ctx.brep_normals
    if corners is not None and fit is not None:  # turned with each triangle the fit bent
        corners = follow_triangles(corners, reg.V, V_reg, reg.F)
    return HeldNominal(
        V=V_reg,
        normals=ctx.prepared.ops.normals if fit is None else vertex_normals(V_reg, reg.F),
        corner_normals=corners,
        basis=ctx.basis if fit is None else fit.basis,
        held=fit is not None or restrained,
        # the free state of a B-rep nominal is scored up to its creases: the face-aware
        # measure (:func:`.deviation.vertex_deviation`) fits each vertex to the points of
        # its own faces and leaves a crease vertex unscored unless all its faces were seen.
        # A fixtured nominal keeps the band: there the displacement field is least
        # determined
        to_creases=fit is None and ctx.face_id is not None and params.edge_band is None,
    )
