"""Semantic PMI of STEP AP242 files, read from the Part 21 text (no OpenCASCADE).

OCCT's XDE reader loses or corrupts part of the semantic PMI of real files: magnitudes stored
as complex instances ``(LENGTH_MEASURE_WITH_UNIT() MEASURE_REPRESENTATION_ITEM()
MEASURE_WITH_UNIT(...))`` come back as 0.0, per-measure units (an inch tolerance in a
millimetre file) are left unconverted, and datum-to-face links that go through
ITEM_IDENTIFIED_REPRESENTATION_USAGE, PLACED_DATUM_TARGET_FEATURE or
COMPOSITE_GROUP_SHAPE_ASPECT are dropped. This module walks the instance graph of
:class:`qifreport.step.p21.P21Model` directly, following the AP242 edition 1 and 2 (and the older
AP214/AP203e2 ``DATUM_REFERENCE``) structures.

* **Geometric tolerances** (simple subtypes or complex instances) give their magnitude,
  characteristic, modifiers, zone form, unequal disposition, maximum, unit-basis and datum
  reference frame (DATUM_SYSTEM / DATUM_REFERENCE_COMPARTMENT / COMMON_DATUM_LIST /
  DATUM_REFERENCE_ELEMENT, or DATUM_REFERENCE / REFERENCED_MODIFIED_DATUM).
* **Dimensions** (DIMENSIONAL_SIZE, ANGULAR_SIZE, DIMENSIONAL_LOCATION, ANGULAR_LOCATION and
  their ``_WITH_PATH`` / ``DIRECTED_`` forms) give their nominal or limits from
  DIMENSIONAL_CHARACTERISTIC_REPRESENTATION and their tolerance from PLUS_MINUS_TOLERANCE.
* **Datums** give their label, datum features and target names.
* **A restraint note** (ISO 10579-NR, "part restrained"), from the file's text
  (:mod:`.notes`), and **the material** (a ``MATERIAL_DESIGNATION`` or a note's
  ``MATERIAL:`` line, :mod:`.material`).

This module reads those items, each kind by its own reader: datums (:mod:`.datums`),
geometric tolerances (:mod:`.tolerances`) and dimensions (:mod:`.dimensions`). They stand on
layers that each do one thing: attribute access and navigation (:mod:`.instance_graph`),
units and measures converted to mm and degrees (:mod:`.units`), the faces each item applies
to (:mod:`.face_links`, :mod:`.aspect_faces`), helped, for non-face geometry, by a small
B-rep geometry kernel (:mod:`.brep_geometry`).

Nothing is guessed: a value that cannot be established is ``None`` and a problem string says
why. Entry points: :func:`read_pmi_text` (a path) and :func:`pmi_from_model` (a parsed model).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from .dimensions import DimensionReader
from .material import material_note
from .notes import restraint_note
from .p21 import P21Model, Ref
from .pmi import PMI, Dimension, GeometricTolerance
from .product import product_identity
from .tolerances import ToleranceReader
from .units import Measure, Unit, length_name

log = logging.getLogger(__name__)

__all__ = ["Measure", "Unit", "pmi_from_model", "read_pmi_text"]


class _Reader(ToleranceReader, DimensionReader):
    """Resolution state for one model (caches units, measures and face sets).

    Units and measures come from :class:`~qifreport.step.units.MeasureReader`, faces from
    :class:`~qifreport.step.face_links.FaceLinker` and
    :class:`~qifreport.step.aspect_faces.AspectFaceLinker`, datums, geometric tolerances and
    dimensions from :class:`~qifreport.step.datums.DatumReader`,
    :class:`~qifreport.step.tolerances.ToleranceReader` and
    :class:`~qifreport.step.dimensions.DimensionReader`; this layer finds what refers to
    nothing they read.
    """

    def unread_references(
        self, tolerances: list[GeometricTolerance], dimensions: list[Dimension]
    ) -> list[str]:
        """Values and tolerances of dimensions, and tolerance relationships, whose target
        was not read as a dimension or tolerance: listed with the entity id and why."""
        dims = {d.step_id for d in dimensions}
        tols = {t.step_id for t in tolerances}
        out = []
        for etype, index, known, what in (
            ("DIMENSIONAL_CHARACTERISTIC_REPRESENTATION", 0, dims, "dimension"),
            ("PLUS_MINUS_TOLERANCE", 1, dims, "dimension"),
            ("GEOMETRIC_TOLERANCE_RELATIONSHIP", 2, tols, "geometric tolerance"),
            ("GEOMETRIC_TOLERANCE_RELATIONSHIP", 3, tols, "geometric tolerance"),
        ):
            for ent in self.m.by_type(etype):
                p = ent.part(etype) or ()
                target = p[index] if len(p) > index else None
                if not isinstance(target, Ref):
                    out.append(f"#{ent.id}: {etype} without a {what}")
                elif target.id not in known:
                    types = "+".join(self.types(target)) or "missing entity"
                    out.append(
                        f"#{ent.id}: {etype} refers to #{target.id} ({types}), "
                        f"not a {what} that could be read"
                    )
        return list(dict.fromkeys(out))


def pmi_from_model(model: P21Model) -> PMI:
    """Semantic PMI of a parsed Part 21 model.

    Parameters
    ----------
    model : P21Model
        The file, as returned by :meth:`P21Model.read`.

    Returns
    -------
    PMI
        Tolerances, dimensions and datums in file-id order, lengths in mm, angles in degrees.
    """
    t0 = time.perf_counter()
    r = _Reader(model)
    r.context_units()
    tolerances = r.tolerances()
    t1 = time.perf_counter()
    dimensions = r.dimensions()
    datums = r.datums()
    unread = r.unread_references(tolerances, dimensions)
    t2 = time.perf_counter()
    pmi = PMI(
        schema=model.schema,
        length_unit=length_name(r.context_length),
        length_scale=r.context_length.scale or 1.0,
        tolerances=tolerances,
        dimensions=dimensions,
        datums=datums,
        problems=list(dict.fromkeys(r.problems + unread)),
        restraint=restraint_note(model),
        material=material_note(model),
        product=product_identity(model),
    )
    log.debug(
        "semantic PMI: %d tolerances (%.3f s), %d dimensions and %d datums (%.3f s)",
        len(tolerances), t1 - t0, len(dimensions), len(datums), t2 - t1,
    )  # fmt: skip
    return pmi


def read_pmi_text(path: str | Path) -> PMI:
    """Read the semantic PMI of a STEP AP242 file from its Part 21 text.

    Parameters
    ----------
    path : str or Path
        The ``.stp`` / ``.step`` file.

    Returns
    -------
    PMI
        See :class:`qifreport.step.pmi.PMI`.

    Raises
    ------
    OSError
        When the file cannot be read.
    step.p21.P21Error
        When it is not a Part 21 file.
    """
    t0 = time.perf_counter()
    model = P21Model.read(path)
    t1 = time.perf_counter()
    pmi = pmi_from_model(model)
    log.debug(
        "read_pmi_text %s: split %.3f s, PMI %.3f s, total %.3f s",
        Path(path).name, t1 - t0, time.perf_counter() - t1, time.perf_counter() - t0,
    )  # fmt: skip
    return pmi
