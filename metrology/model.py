"""The nominal as the product speaks of it: the :class:`Part` and its :class:`Drawing`.

A nominal file gives two things an inspection needs, kept apart here: the part's geometry
(:class:`Part`: the inspection mesh in mm with its B-rep faces, the file's unit, the solid's
tetrahedra when asked for) and what its drawing asks of it (:class:`Drawing`: the tolerance
zones, the PMI items not evaluated, the datums, the plan of feature characteristics, and
where the tolerances came from). The third piece of an inspection's input, the scan, is
:class:`qifreport.registration.scan.Scan`.

Both are made by the application's ``qifreport.nominal.load_nominal`` (a STEP file through
:mod:`qifreport.step`, its semantic PMI turned into zones by
:func:`qifreport.metrology.acceptance.bands.zones_from_pmi` and into characteristics by
:func:`qifreport.metrology.gdt.pmi_plan.specs_from_pmi`; or a mesh file and the
operator's ``--tolerance``), and kept prepared in the per-part cache.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qifreport.metrology.acceptance.bands import NotEvaluated, ToleranceZone
from qifreport.metrology.gdt.pmi_plan import CharacteristicPlan

if TYPE_CHECKING:
    from qifreport.step.gmsh_mesh import SolidMesh

__all__ = [
    "Drawing",
    "MaterialStatement",
    "Part",
    "RestraintStatement",
]


@dataclass
class Part:
    """The nominal part: its inspection mesh in mm, its B-rep faces, its provenance.

    Attributes
    ----------
    V : (n, 3) float64 vertices of the inspection mesh, mm.
    F : (f, 3) int triangles.
    face_id : (f,) the B-rep face of each triangle (a STEP part), None for a mesh nominal.
    face_step_ids : (n_faces,) the STEP entity id of each B-rep face (-1 unknown), None for a
        mesh nominal.
    brep_normals : (f, 3, 3) the B-rep's outward unit normals at each triangle's corners
        (:func:`qifreport.step.normals.corner_normals_exact`), None for a mesh nominal.
    solid_mesh : the tetrahedra filling a STEP part's solid, for its elastic model (when
        asked for; not kept once the restraint basis is built from it).
    name : the part's name: the STEP product's (the file stem when it names none), a mesh
        file's stem.
    source : the file read.
    units : the file's length unit before conversion to mm: a STEP file's context unit
        (``"mm"``, ``"inch"``, ``"m"`` ...; None when the file states none), ``"mm"`` for a
        mesh (the formats state none: taken as mm).
    material : the part's material when the file names one; None: unknown (no reader
        takes it from the file).
    info : the provenance the outputs report (the JSON summary's ``nominal`` block):
        format, tessellation, PMI counts, solids, supplemental faces, timings.
    """

    V: np.ndarray
    F: np.ndarray
    face_id: np.ndarray | None = None
    face_step_ids: np.ndarray | None = None
    brep_normals: np.ndarray | None = None
    solid_mesh: SolidMesh | None = None
    name: str = ""
    source: Path | None = None
    units: str | None = "mm"
    material: str | None = None
    info: dict = field(default_factory=dict)

    @property
    def is_solid(self) -> bool:
        """The nominal is a B-rep solid (a STEP part with one or more solids): its trim edges
        are its sharp creases, and its mesh's open edges (sewing gaps) are no rim."""
        return bool(self.info.get("solids"))

    @property
    def n_faces(self) -> int:
        """The number of B-rep faces (0 for a mesh nominal)."""
        return 0 if self.face_step_ids is None else len(self.face_step_ids)


@dataclass(frozen=True)
class RestraintStatement:
    """What the drawing states about restraint (ASME Y14.5: tolerances apply in the free
    state unless the drawing says otherwise; ISO 10579: a non-rigid part's drawing says
    "ISO 10579-NR" and states the restraint).

    Attributes
    ----------
    stated : the drawing states a restrained condition.
    text : the statement (the note around it, at most 400 characters); empty when none.
    source : where it was read: ``"drawing note"`` (a note of the STEP file,
        :func:`qifreport.step.notes.restraint_note`), ``"drawing"`` (a STEP file that
        states none) or ``"none"`` (a mesh nominal: no drawing).
    targets : the datum targets the statement holds the part at, each placed in the file
        (:meth:`qifreport.step.pmi.PMI.held_targets`): the part is then held there, not in
        a virtual fixture; ``()``: the statement names none, or names one the file does
        not place (``unplaced``).
    unplaced : targets the statement names that the file does not place.
    """

    stated: bool = False
    text: str = ""
    source: str = "none"
    targets: tuple[str, ...] = ()
    unplaced: tuple[str, ...] = ()

    @property
    def at_targets(self) -> bool:
        """The drawing holds the part at datum targets the file places."""
        return self.stated and bool(self.targets) and not self.unplaced


@dataclass(frozen=True)
class MaterialStatement:
    """The part's material as the drawing states it.

    Attributes
    ----------
    text : the designation as written (``'ABS, UNFILLED'``).
    preset : the elastic preset it names
        (:func:`qifreport.registration.restraint.designation.preset_of`: a key of
        :data:`qifreport.registration.restraint.elastic.MATERIALS`), None: none.
    source : where it was read: ``"material designation"`` (an AP242 entity) or
        ``"drawing note"`` (:func:`qifreport.step.material.material_note`).
    """

    text: str
    preset: str | None = None
    source: str = "drawing note"

    def describe(self) -> str:
        """Where the material came from, for the reports: ``drawing (note): ABS``."""
        return f"drawing ({self.source}): {self.text}"


@dataclass
class Drawing:
    """What the part's drawing asks of it: tolerance zones, characteristics, datums.

    Attributes
    ----------
    zones : the surface-profile zones, in file order, the general zone last
        (:func:`qifreport.metrology.acceptance.bands.zones_from_pmi`; a mesh nominal: the
        one general zone of the operator's tolerance).
    not_evaluated : the PMI items that are not scored, each with the reason.
    datums : the datum labels of the PMI, in file order, each once.
    plan : the drawing's feature characteristics (geometric tolerances and dimensions,
        their datums, frames and modifiers), None for a mesh nominal.
    source : where the tolerances came from: ``"pmi"``, a STEP file's semantic PMI (its
        general zone's own ``source`` says whether a whole-part profile of the PMI, the
        ``--tolerance`` or the default set it); ``"operator"``, the ``--tolerance`` given
        with a mesh nominal, which carries none.
    restraint : what the drawing states about restraint (:class:`RestraintStatement`).
    material : the part's material as the drawing states it (:class:`MaterialStatement`),
        None when it states none (a mesh nominal: no drawing).
    warnings : exporter quirks the reader put right (bounds in reverse order), one line
        each naming the item (:meth:`qifreport.step.pmi.PMI.reader_warnings`): every output
        says them.
    """

    zones: list[ToleranceZone]
    not_evaluated: list[NotEvaluated] = field(default_factory=list)
    datums: list[str] = field(default_factory=list)
    plan: CharacteristicPlan | None = None
    source: str = "pmi"
    restraint: RestraintStatement = field(default_factory=RestraintStatement)
    material: MaterialStatement | None = None
    warnings: list[str] = field(default_factory=list)
