"""What every stage of one judgement is given: the seated scan and the inspection's context.

:class:`Registered` is the scan seated rigidly on the nominal
(:func:`qifreport.metrology.inspection.seat_rigidly`), :class:`JudgeContext` what the
judgements of one inspection share besides it (the prepared part, its tolerance zones, its
drawing). Every stage of :mod:`qifreport.metrology.stages` takes them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from qifreport.metrology.acceptance.bands import BandField, NotEvaluated
from qifreport.metrology.acceptance.scan_area import scan_area
from qifreport.metrology.gdt.pmi_plan import CharacteristicPlan
from qifreport.metrology.prepared import PreparedPart
from qifreport.metrology.stages.rim_seat import RimSeat
from qifreport.registration.deformable.bending_basis import BendingBasis
from qifreport.registration.deformable.result import orient_scan_normals
from qifreport.registration.icp import RigidResult
from qifreport.registration.mesh import vertex_normals
from qifreport.registration.pose.prealign import PrealignResult
from qifreport.registration.restraint.fixture_load import LoadModel

__all__ = ["JudgeContext", "Registered"]


@dataclass
class Registered:
    """The scan seated rigidly on the nominal: what every judgement of one inspection shares."""

    V: np.ndarray
    F: np.ndarray
    P: np.ndarray
    rigid: RigidResult
    seat: PrealignResult
    scan_normals: np.ndarray
    sheets: np.ndarray
    diag: float
    rim_seat: RimSeat | None = None

    @functools.cached_property
    def scan_tree(self) -> cKDTree:
        """``cKDTree(P)``: built once for every judgement's searches of the seated scan."""
        return cKDTree(self.P)

    @functools.cached_property
    def scan_area(self) -> float:
        """The area the seated scan covers, mm^2 (:func:`scan_area` with the seated
        normals, each sheet turned outwards by
        :func:`~qifreport.registration.deformable.result.orient_scan_normals`: the two
        skins of a thin wall apart, and the sheets of one skin on one side, whatever side
        each was given first): the same points for every judgement, measured once."""
        out = orient_scan_normals(
            self.P, self.scan_normals, self.V, vertex_normals(self.V, self.F), sheets=self.sheets
        )
        return scan_area(self.P, normals=out)


@dataclass(frozen=True)
class JudgeContext:
    """What every judgement of one inspection shares besides the scan: the prepared part,
    its tolerance zones and its drawing.

    Attributes
    ----------
    prepared : the nominal's scan-independent state (operators, unscored bands, hygiene).
    bands : the tolerance zones laid on the nominal
    (:func:`~qifreport.metrology.acceptance.bands.lay_bands`).
    energy : the bending energy of the virtual fixture (``prepared.energy``), reported.
    face_id : (f,) B-rep face id of each triangle (a STEP nominal), for face-based zones;
        None: a mesh nominal.
    not_evaluated : PMI items listed in the result but not scored.
    solid : the nominal is a B-rep solid (a STEP part): its trim edges, for the size check,
        are its sharp creases, and open edges of its mesh (a B-rep's sewing gaps) are not a
        rim.
    basis : the nominal's GB-CICP bending basis, reported (a fixture's own replaces it).
    brep_normals : (f, 3, 3) the B-rep's normals at the triangle corners (a STEP nominal,
        :func:`qifreport.step.normals.corner_normals_exact`): the scan points' distances to
        the curved surface are read with them (NaN rows: the mesh's).
    plan : the drawing's feature characteristics and datums
        (:func:`qifreport.metrology.gdt.pmi_plan.specs_from_pmi`; a STEP nominal with
        ``brep_normals``): measured on the judged surface, and the profiles that name
        datums laid in their frame; None: none.
    fixture_load : the part's elastic model for the virtual fixture's load
        (:class:`qifreport.registration.restraint.fixture_load.LoadModel`), or why there is
        none (a sentence); None: none given.
    """

    prepared: PreparedPart
    bands: BandField
    energy: str
    face_id: np.ndarray | None = None
    not_evaluated: list[NotEvaluated] | None = None
    solid: bool = False
    basis: BendingBasis | None = None
    brep_normals: np.ndarray | None = None
    plan: CharacteristicPlan | None = None
    fixture_load: LoadModel | str | None = None

    @property
    def general_half(self) -> float:
        """The threshold of the whole-part tail fractions and of added material, mm: the
        general zone's half-width, or (all faces under PMI profiles) the widest zone's:
        "beyond every band" (per-zone fractions use their own band)."""
        general = [z for z in self.bands.zones if z.faces is None]
        return general[0].half_width if general else max(z.half_width for z in self.bands.zones)

    @property
    def drawing_decides(self) -> bool:
        """The part's drawing states its requirements (a PMI profile, a feature
        characteristic, or a PMI item it lists as not evaluated): qifreport's default band
        is none of them, so it is reported, not judged (a ``--tolerance`` band is)."""
        pmi = any(z.source == "pmi" for z in self.bands.zones)
        return bool(pmi or (self.plan is not None and self.plan.specs) or self.not_evaluated)
