"""The trim-edge stage: the scan's deviation along the nominal's trim edges and the size
error read from it (:func:`trim_edge_stage`), where the fixture lets the size be read
(:func:`measures_size`)."""

from __future__ import annotations

from qifreport.metrology.acceptance.coverage import min_scan_density
from qifreport.metrology.deviation.edges import EdgeDeviation, edge_deviation
from qifreport.metrology.deviation.part_class import part_class
from qifreport.metrology.deviation.size import SizeEstimate, density_rule, size_error
from qifreport.metrology.params import InspectionParams
from qifreport.registration.deformable.methods import method_spec
from qifreport.registration.deformable.result import DeformResult

from .context import JudgeContext, Registered
from .held import HeldNominal

__all__ = ["measures_size", "trim_edge_stage"]


def measures_size(fit: DeformResult | None) -> bool:
    """Whether the size is read from the trim edges on the nominal as the fixture ``fit``
    holds it (None: the free state): on a fixture that moves the nominal along its normals
    only (GB-CICP) or not at all; the baselines move it along the surface too, and so
    absorb or make up a size error at the rim."""
    return fit is None or method_spec(fit.method).moves_along_normals_only


def trim_edge_stage(
    reg: Registered, nominal: HeldNominal, ctx: JudgeContext, params: InspectionParams
) -> tuple[EdgeDeviation, SizeEstimate]:
    """The trim-edge deviation of the seated scan ``reg`` along the nominal as held
    (``nominal``, :func:`~qifreport.metrology.stages.held.held_nominal`), and the size
    error read from it (:func:`edge_deviation`, :func:`size_error`): against the general
    half-width, along a solid's sharp creases (``ctx.solid``) or the mesh's open rim; the
    part's class (:func:`part_class`, of the nominal as prepared) says whether they are
    judged; a size read from a rim scanned more sparsely than the toleranced surfaces need
    (the region criterion's area, ``params.max_region_area``) is not established
    (:func:`density_rule`)."""
    edges = edge_deviation(
        nominal.V,
        reg.F,
        reg.P,
        ctx.general_half,
        normals=nominal.normals,
        trim_edges="crease" if ctx.solid else "auto",
        tree=reg.scan_tree,
    )
    prepared = ctx.prepared
    edges.part = part_class(prepared.V, prepared.F, solid=ctx.solid, normals=prepared.ops.normals)
    least = min_scan_density(params.max_region_area)
    return edges, density_rule(size_error(edges), edges, least)
