"""Typed options between the command line and the application services.

The command line (:mod:`qifreport.cli`) turns its arguments into these objects once; the
pipeline (:mod:`qifreport.pipeline`), the batch runner (:mod:`qifreport.batch`) and the
per-part cache (:mod:`qifreport.cache`) take nothing else. All lengths are mm, areas mm^2.

* :class:`InspectOptions` -- how every scan of a run is read, fixtured, judged and reported
  (the options ``qifreport NOMINAL SCAN`` and ``qifreport batch`` share);
* :class:`InspectJob` -- one scan: its files, its output names and the single-scan extras
  (``--json``, ``--serial``, ``--export-mesh``).
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from qifreport.errors import InputError
from qifreport.metrology.acceptance.coverage import DEFAULT_MIN_COVERAGE
from qifreport.metrology.acceptance.decision import DECISION_RULES, DEFAULT_DECISION_RULE
from qifreport.metrology.acceptance.scanner import (
    DEFAULT_SCANNER,
    ScannerProfile,
    ScannerProfileError,
    load_scanner,
)
from qifreport.metrology.model import Drawing
from qifreport.metrology.params import (
    CLAMPS,
    FREE,
    RESTRAINT_CONDITIONS,
    STATED_BY_DEFAULT,
    STATED_BY_DRAWING,
    STATED_BY_NOTE,
    STATED_BY_OPERATOR,
    VIRTUAL,
    InspectionParams,
    RestraintCondition,
)
from qifreport.registration.deformable.gbcicp import GBCICPParams

from .restraint import (
    DEFAULT_PAD_RADIUS,
    LoadSpec,
    RestraintSpec,
    drawing_clamps,
    gravity_direction,
    read_clamps,
)

__all__ = [
    "DEFAULT_NAME",
    "RESULT_OPTIONS",
    "InspectJob",
    "InspectOptions",
    "NominalOptions",
    "check_text",
    "output_name",
]

#: the options that change a scan's outputs (a batch record's digest covers them)
RESULT_OPTIONS = (
    "tolerance",
    "max_edge",
    "deflection",
    "mesher",
    "solid",
    "scan_units",
    "no_qif",
    "no_pdf",
    "html",
    "page",
    "author",
    "organization",
    "operator",
    "part_number",
    "revision",
    "temperature",
    "min_fraction",
    "max_region_area",
    "energy",
    "edge_band",
    "boundary_band",
    "band_limit",
    "passes",
    "prealign",
    "fail_on_added_material",
    "method",
    "seeds",
    "rigid_only",
    "always_fixture",
    "judge_free_state",
    "accept_tolerance_as_read",
    "min_coverage",
    "zone_min_coverage",
    "max_gap_area",
    "decision_rule",
    "scanner_uncertainty",
    "scanner",
    "fixture",
    "restraint",
    "clamps",
    "material",
    "thickness",
    "max_clamp_force",
    "pad_radius",
    "gravity",
    "max_restraint_force",
)


def check_text(flag: str, value: str | None) -> None:
    """Refuse a text option no report can carry: undecodable bytes (a non-UTF-8 argument),
    control characters, or more than 200 characters (:class:`~qifreport.errors.InputError`)."""
    if value is None:
        return
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise InputError(f"{flag} is not valid UTF-8 text") from None
    bad = [c for c in value if ord(c) < 32 or 127 <= ord(c) < 160]
    if bad:
        raise InputError(f"{flag} contains a control character ({ord(bad[0]):#04x})")
    if len(value) > 200:
        raise InputError(f"{flag} is longer than 200 characters ({len(value)})")


#: the outputs' default file stem: the part, and its serial number when there is one
DEFAULT_NAME = "{part}[_{serial}]"


def output_name(template: str, fields: dict[str, str]) -> str:
    """An output file stem from ``template`` and its ``fields`` (``part``, ``serial``,
    ``scan``): ``{field}`` is the field's value, characters a file name should not hold
    (anything but letters, digits, ``.``, ``_``, ``-`` and ``+``) as ``_``; a part in
    ``[...]`` is left out when a field in it is empty. :class:`InputError` for an unknown
    field, unbalanced brackets, or a name that is empty or only dots."""

    def fill(text: str) -> tuple[str, bool]:
        out, empty = "", False
        for m in re.finditer(r"\{([^{}]*)\}|[^{}]+|[{}]", text):
            if m.group(0) in "{}":
                raise InputError(f"--name {template!r}: an unmatched brace")
            if m.group(1) is None:
                out += m.group(0)
                continue
            if m.group(1) not in fields:
                raise InputError(
                    f"--name {template!r}: unknown field {{{m.group(1)}}} (fields: "
                    f"{', '.join('{' + k + '}' for k in fields)})"
                )
            value = re.sub(r"[^A-Za-z0-9._+-]", "_", fields[m.group(1)])
            empty |= value == ""
            out += value
        return out, empty

    if template.count("[") != template.count("]") or re.search(r"\[[^\]]*\[", template):
        raise InputError(f"--name {template!r}: unbalanced or nested [ ]")
    name = ""
    for m in re.finditer(r"\[([^\]]*)\]|[^\[\]]+", template):
        if m.group(1) is None:
            name += fill(m.group(0))[0]
        else:
            part, empty = fill(m.group(1))
            name += "" if empty else part
    if not name.strip(".") or "/" in name:
        raise InputError(f"--name {template!r} gives no file name ({name!r})")
    return name


@dataclass(frozen=True)
class NominalOptions:
    """How the nominal file is read (mm): ``--tolerance``, ``--max-edge``, ``--deflection``,
    ``--mesher``, ``--solid``; and how the part is held (``restraint``: the per-part
    restraint basis is built with it; ``fixture_load``: what the virtual fixture's load
    needs, its elastic model built with it)."""

    tolerance: float | None = None
    max_edge: float | None = None
    deflection: float | None = None
    accept_tolerance_as_read: bool = False
    mesher: str = "gmsh"
    solid: str | None = None
    restraint: RestraintSpec | None = None
    fixture_load: LoadSpec | None = None


@dataclass(frozen=True)
class InspectOptions:
    """The options of an inspection run (defaults: the command line's).

    Attributes
    ----------
    tolerance : general profile half-width, mm (None: the STEP part's PMI, else 0.5).
    max_edge, deflection : STEP tessellation, mm (None: from the part's size).
    mesher : STEP surface mesher, ``"gmsh"`` (default,
        :func:`qifreport.step.gmsh_mesh.gmsh_tessellate`) or ``"brepmesh"``
        (:func:`qifreport.step.tessellate.tessellate`).
    solid : STEP: the solid to inspect in a file with several, index or name.
    scan_units : ``"mm"``, ``"in"``, ``"m"`` or None (mm; E57 m).
    no_qif, no_pdf : leave out the QIF document / the PDF report.
    html : also write the interactive deviation map ``<stem>.html``
        (:mod:`qifreport.reports.html`).
    page : PDF paper size, ``"A4"`` or ``"Letter"``.
    author, organization, operator : QIF header and traceability fields.
    part_number, revision : the part's number and drawing revision (None: the STEP
        file's product's, :mod:`qifreport.step.product`).
    temperature : the part's temperature while scanned, deg C (None: the scanner
        profile's, else not stated); it enters the profile's thermal term.
    min_fraction : area criterion, in-tolerance fraction of the scored area (0, 1].
    max_region_area : region criterion, mm^2 (None: the metrology default).
    energy : ``"auto"``, ``"hessian"`` or ``"laplacian"``.
    edge_band, boundary_band : unscored bands along creases and the open rim, mm.
    band_limit : smoothing length of the first GB-CICP pass, mm (None: from the part).
    passes : GB-CICP passes (values below 1 run one pass).
    prealign : pose search, ``"auto"``, ``"always"`` or ``"never"``.
    fail_on_added_material : added material beyond the region limit fails the part.
    method : deformable method (:data:`qifreport.registration.deformable.methods.METHODS`).
    seeds : runs of the repeatability check (1: none).
    rigid_only : no virtual fixture.
    always_fixture : apply the virtual fixture even when the free state conforms.
    judge_free_state : held at clamps, judge the free state too, for the outputs.
    one_process : one CPU, no forked child processes. By default one command judges the
        free state, measures the trim edges and renders the reports in forked children
        beside its main work (:mod:`qifreport.forked`; the same results, bit for bit), each
        child holding a copy of the memory it changes.
    cache_dir : per-part cache directory (None: no cache).
    accept_tolerance_as_read : inspect with tolerances the plausibility check of
        :mod:`qifreport.step.plausibility` flags (default: refuse the part).
    min_coverage : least scored share of a toleranced surface
    (:mod:`qifreport.metrology.acceptance.coverage`).
    zone_min_coverage : ``((selector, fraction), ...)``: a tolerance's own least share; the
        selector is its key (``T2``), name, or STEP id (``#1452``).
    max_gap_area : largest unmeasured patch, mm^2 (None: 4 x the region criterion's area).
    decision_rule : how the measurement uncertainty enters each decision
        (:mod:`qifreport.metrology.acceptance.decision`).
    scanner_uncertainty : the scanner's stated expanded uncertainty, mm (0: none).
    scanner : the ``--scanner`` profile file (None: the default scanner class,
        :data:`~qifreport.metrology.acceptance.scanner.DEFAULT_SCANNER`).
    fixture : ``"auto"`` (restrained when clamps are known, else free), ``"restrained"``
        (ISO 10579: held at its clamps by its elastic model, :mod:`qifreport.restraint`) or
        ``"free"`` (the free state, then the virtual fixture ``method``).
    restraint : ``--restraint``: the condition the operator states, ``"free"``,
        ``"virtual"`` or ``"clamps"`` (None: the drawing's, :meth:`restraint_condition`).
    clamps : the ``--clamps`` CSV file.  material : ``--material`` (preset or values).
    thickness : a mesh nominal's wall thickness, mm.  max_clamp_force : the force limit
        of clamps that state none, N.  pad_radius : each clamp's contact radius, mm.
    gravity : the direction of gravity in the part frame while it is held (``-z``, ``+x``
        or ``x,y,z``; None: no weight): the held part sags under its own weight.
    max_restraint_force : the force a physical fixture may use to hold the part in the
        virtual fixture's shape, N (None: the default,
        :data:`qifreport.registration.restraint.fixture_load.DEFAULT_MAX_FORCE`).
    """

    tolerance: float | None = None
    max_edge: float | None = None
    deflection: float | None = None
    mesher: str = "gmsh"
    solid: str | None = None
    scan_units: str | None = None
    no_qif: bool = False
    no_pdf: bool = False
    html: bool = False
    page: str = "A4"
    author: str | None = None
    organization: str | None = None
    operator: str | None = None
    part_number: str | None = None
    revision: str | None = None
    temperature: float | None = None
    min_fraction: float = 0.95
    max_region_area: float | None = None
    energy: str = "auto"
    edge_band: float | None = None
    boundary_band: float | None = None
    band_limit: float | None = None
    passes: int = 12
    prealign: str = "auto"
    fail_on_added_material: bool = False
    method: str = "gbcicp"
    seeds: int = 1
    rigid_only: bool = False
    always_fixture: bool = False
    judge_free_state: bool = False
    one_process: bool = False
    cache_dir: Path | None = None
    accept_tolerance_as_read: bool = False
    min_coverage: float = DEFAULT_MIN_COVERAGE
    zone_min_coverage: tuple[tuple[str, float], ...] = ()
    max_gap_area: float | None = None
    decision_rule: str = DEFAULT_DECISION_RULE
    scanner_uncertainty: float = 0.0
    scanner: Path | None = None
    fixture: str = "auto"
    restraint: str | None = None
    clamps: Path | None = None
    material: str | None = None
    thickness: float | None = None
    max_clamp_force: float | None = None
    pad_radius: float = DEFAULT_PAD_RADIUS
    gravity: str | None = None
    max_restraint_force: float | None = None

    def check(self) -> None:
        """Refuse values no inspection can use (:class:`~qifreport.errors.InputError`)."""
        for what, v in (
            ("", self.min_coverage),
            *((f"{k}=", v) for k, v in self.zone_min_coverage),
        ):
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise InputError(
                    f"--min-coverage {what}{v}: the least scored share must be a fraction in "
                    "[0, 1] (0.7 means 70 %)"
                )
        if self.max_gap_area is not None and not (
            math.isfinite(self.max_gap_area) and self.max_gap_area >= 0
        ):
            raise InputError(f"--max-gap-area must be an area >= 0 mm^2, got {self.max_gap_area}")
        if not (math.isfinite(self.min_fraction) and 0.0 < self.min_fraction <= 1.0):
            raise InputError(
                f"--min-fraction must be a fraction in (0, 1], got "
                f"{self.min_fraction} (0.95 means 95 %)"
            )
        if self.max_region_area is not None and not (
            math.isfinite(self.max_region_area) and self.max_region_area >= 0
        ):
            raise InputError(
                f"--max-region-area must be an area >= 0 mm^2, got {self.max_region_area}"
            )
        if self.decision_rule not in DECISION_RULES:
            raise InputError(
                f"--decision-rule must be one of {', '.join(DECISION_RULES)}, got "
                f"{self.decision_rule!r}"
            )
        if not (math.isfinite(self.scanner_uncertainty) and self.scanner_uncertainty >= 0):
            raise InputError(
                f"--scanner-uncertainty must be a length >= 0 mm, got {self.scanner_uncertainty}"
            )
        self.scanner_profile()  # InputError for a profile that cannot be used
        if self.fixture not in ("auto", "restrained", "free"):
            raise InputError(f"--fixture must be auto, restrained or free, got {self.fixture!r}")
        if self.fixture == "restrained" and (self.rigid_only or self.always_fixture):
            flag = "--rigid-only" if self.rigid_only else "--always-fixture"
            raise InputError(f"--fixture restrained and {flag} exclude each other")
        self._check_restraint()
        for flag, v in (("--thickness", self.thickness), ("--pad-radius", self.pad_radius)):
            if v is not None and not (math.isfinite(v) and v > 0):
                raise InputError(f"{flag} must be a positive length in mm, got {v}")
        if self.max_clamp_force is not None and not (
            math.isfinite(self.max_clamp_force) and self.max_clamp_force > 0
        ):
            raise InputError(
                f"--max-clamp-force must be a positive force in N, got {self.max_clamp_force}"
            )
        if self.max_restraint_force is not None and not (
            math.isfinite(self.max_restraint_force) and self.max_restraint_force > 0
        ):
            raise InputError(
                "--max-restraint-force must be a positive force in N, got "
                f"{self.max_restraint_force}"
            )
        if self.material is not None:
            check_text("--material", self.material)
        if self.gravity is not None:
            gravity_direction(self.gravity)  # InputError for one that is not a direction
        if self.mesher not in ("gmsh", "brepmesh"):
            raise InputError(f"--mesher must be gmsh or brepmesh, got {self.mesher!r}")
        if self.seeds < 1:
            raise InputError(f"--seeds must be a number of runs >= 1, got {self.seeds}")
        lengths = (
            ("--tolerance", self.tolerance),
            ("--max-edge", self.max_edge),
            ("--deflection", self.deflection),
            ("--band-limit", self.band_limit),
        )
        for flag, v in lengths:
            if v is not None and not (math.isfinite(v) and v > 0):
                raise InputError(f"{flag} must be a positive length in mm, got {v}")
        for flag, v in (("--edge-band", self.edge_band), ("--boundary-band", self.boundary_band)):
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise InputError(f"{flag} must be a length >= 0 mm, got {v}")
        if self.passes < 1:
            raise InputError(
                "--passes must be 1 (a single pass: no two-pass guard, so never a PASS) or "
                f"more (the band-limited scheme), got {self.passes}"
            )
        for flag, v in (
            ("--author", self.author),
            ("--organization", self.organization),
            ("--operator", self.operator),
            ("--part-number", self.part_number),
            ("--revision", self.revision),
        ):
            check_text(flag, v)
        if self.temperature is not None and not (
            math.isfinite(self.temperature) and -100.0 <= self.temperature <= 400.0
        ):
            raise InputError(
                f"--temperature must be the part's temperature in deg C, got {self.temperature}"
            )

    def _check_restraint(self) -> None:
        """Refuse a ``--restraint`` that another option contradicts."""
        r = self.restraint
        if r is None:
            return
        if r not in RESTRAINT_CONDITIONS:
            raise InputError(
                f"--restraint must be one of {', '.join(RESTRAINT_CONDITIONS)}, got {r!r}"
            )
        implied = self._operator_flag()
        if implied is not None and implied[0] != r:
            raise InputError(f"--restraint {r} and {implied[1]} exclude each other")
        if r == CLAMPS and self.clamps is None:
            raise InputError(
                "--restraint clamps needs the clamps: --clamps FILE (CSV: name, x, y, z, "
                "directions[, max_force_N]) or --clamps pmi"
            )

    def _operator_flag(self) -> tuple[str, str] | None:
        """The condition another option of the operator states, and that option:
        ``--clamps`` or ``--fixture restrained`` (clamps), ``--rigid-only`` (free),
        ``--always-fixture`` or ``--fixture free`` (virtual); None: none does."""
        if (
            self.clamps is not None
            and self.fixture != "free"
            and not (self.rigid_only or self.always_fixture)
        ):
            return CLAMPS, f"--clamps {self.clamps}"
        if self.fixture == "restrained":
            return CLAMPS, "--fixture restrained"
        if self.rigid_only:
            return FREE, "--rigid-only"
        if self.always_fixture:
            return VIRTUAL, "--always-fixture"
        if self.fixture == "free":
            return VIRTUAL, "--fixture free"
        return None

    def restraint_condition(self, drawing: Drawing | None) -> RestraintCondition:
        """The condition the part is judged in and who stated it, decided here once: the
        operator's (``--restraint``, else ``--clamps``, ``--rigid-only``,
        ``--always-fixture`` or ``--fixture``); else the drawing's (a restraint note that
        holds the part at datum targets the file places: held there, as
        :meth:`restraint_spec` reads them; another restraint note: the virtual fixture; a
        STEP drawing that states none: the free state, ASME Y14.5 / ISO 10579);
        else, a mesh nominal having no drawing, the virtual fixture as the operator-level
        default."""
        if self.restraint is not None:
            return RestraintCondition(
                self.restraint, STATED_BY_OPERATOR, "--restraint " + self.restraint
            )
        flag = self._operator_flag()
        if flag is not None:
            return RestraintCondition(flag[0], STATED_BY_OPERATOR, flag[1])
        said = None if drawing is None else drawing.restraint
        if said is not None and said.at_targets:
            return RestraintCondition(CLAMPS, STATED_BY_NOTE, said.text)
        if said is not None and said.stated:
            text = said.text
            if said.unplaced:
                text += (
                    f" [the file does not place its target(s) {', '.join(said.unplaced)}: "
                    "held in the virtual fixture; --clamps FILE states where it is held]"
                )
            return RestraintCondition(VIRTUAL, STATED_BY_NOTE, text)
        if said is not None and said.source != "none":  # a drawing that states none
            return RestraintCondition(
                FREE,
                STATED_BY_DRAWING,
                "the drawing states no restraint: tolerances apply in the free state "
                "(ASME Y14.5, ISO 10579)",
            )
        return RestraintCondition(
            VIRTUAL,
            STATED_BY_DEFAULT,
            "no drawing (mesh nominal): the virtual fixture is the operator-level default "
            "(--restraint free|virtual|clamps states another)",
        )

    def inspection_params(self) -> InspectionParams:
        """The metrology parameters of these options."""
        g = GBCICPParams(passes=max(1, self.passes), band_limit=self.band_limit)
        params = InspectionParams(
            tolerance=self.tolerance,
            min_fraction=self.min_fraction,
            energy=self.energy,
            edge_band=self.edge_band,
            boundary_band=self.boundary_band,
            rigid_only=self.rigid_only,
            always_fixture=self.always_fixture,
            judge_free_state=self.judge_free_state,
            prealign=self.prealign,
            fail_on_added_material=self.fail_on_added_material,
            method=self.method,
            gbcicp=g,
            min_coverage=self.min_coverage,
            max_gap_area=self.max_gap_area,
            decision_rule=self.decision_rule,
            scanner_uncertainty=self.scanner_uncertainty,
            scanner=self.scanner_profile(),
            max_restraint_force=self.max_restraint_force,
        )
        if self.max_region_area is not None:
            params.max_region_area = self.max_region_area
        return params

    def scanner_profile(self) -> ScannerProfile:
        """The ``--scanner`` profile read (:class:`~qifreport.errors.InputError`, one line,
        for a file that cannot be used), or the default scanner class without one."""
        if self.scanner is None:
            profile = DEFAULT_SCANNER
        else:
            try:
                profile = load_scanner(self.scanner)
            except ScannerProfileError as exc:
                raise InputError(f"--scanner: {exc}") from None
        if self.temperature is not None:  # the operator's reading stands for the profile's
            profile = replace(profile, temperature=self.temperature)
        return profile

    def restraint_spec(self, nominal: Path | None = None) -> RestraintSpec | None:
        """How the part is held, when a restrained inspection may use it: the ``--clamps``
        file read, or with ``--clamps pmi`` the datum targets of the STEP ``nominal``
        (:class:`~qifreport.errors.InputError` for a bad one); None with ``--fixture free``,
        the rigid baseline, or no clamps."""
        if (
            self.fixture == "free"
            or self.rigid_only
            or self.always_fixture
            or self.restraint in (FREE, VIRTUAL)
        ):
            return None
        if self.clamps is None:
            if self.fixture == "restrained":
                raise InputError(
                    "--fixture restrained needs the clamps: --clamps FILE (CSV: name, x, y, "
                    "z, directions[, max_force_N])"
                )
            # (every other statement of the operator returned above)
            if nominal is None or self.restraint is not None:
                return None
            # the operator states nothing: the drawing's restraint note may hold the part
            # at its datum targets (restraint_condition reads the same note)
            found = drawing_clamps(nominal, self.max_clamp_force)
            if found is None:
                return None
            clamps, source = found
        else:
            clamps, source = read_clamps(self.clamps, nominal, self.max_clamp_force)
        return RestraintSpec(
            clamps=clamps,
            source=source,
            material=self.material,
            thickness=self.thickness,
            pad_radius=self.pad_radius,
            gravity=self.gravity,
        )

    def nominal_options(self, nominal: Path | None = None) -> NominalOptions:
        """How the nominal is read (and held, :meth:`restraint_spec`: ``nominal`` is the
        file, for ``--clamps pmi``)."""
        self.check()
        return NominalOptions(
            self.tolerance,
            self.max_edge,
            self.deflection,
            self.accept_tolerance_as_read,
            self.mesher,
            self.solid,
            restraint := self.restraint_spec(nominal),
            self.load_spec(restraint),
        )

    def load_spec(self, restraint: RestraintSpec | None) -> LoadSpec | None:
        """What the virtual fixture's load needs (the material, a mesh nominal's
        thickness) when a virtual fixture may be applied: not rigidly only, nor held at
        clamps (``restraint``)."""
        if self.rigid_only or restraint is not None:
            return None
        return LoadSpec(self.material, self.thickness)

    def result_options(self) -> dict:
        """The options that change a scan's outputs, by name (JSON-able)."""
        d = asdict(self)
        return {k: str(d[k]) if isinstance(d[k], Path) else d[k] for k in RESULT_OPTIONS}


@dataclass(frozen=True)
class InspectJob:
    """One scan to inspect and the outputs to write.

    Attributes
    ----------
    nominal, scan : the input files.  out : output directory.
    options : the run's :class:`InspectOptions`.
    stem : output file stem (default: from ``name``).
    name : the output file stem's template (:data:`DEFAULT_NAME`): ``{part}`` the
        nominal's stem, ``{serial}`` the serial number, ``{scan}`` the scan's stem; a part
        between ``[`` and ``]`` is left out when a field in it is empty (no serial).
    serial : serial number of the part.  json : also write ``<stem>.json``.
    export_mesh : also write the registered nominal as PLY there.
    force : overwrite existing outputs.
    """

    nominal: Path
    scan: Path
    out: Path = Path(".")
    options: InspectOptions = field(default_factory=InspectOptions)
    stem: str | None = None
    serial: str | None = None
    name: str = DEFAULT_NAME
    json: bool = False
    export_mesh: Path | None = None
    force: bool = False

    def check(self) -> None:
        """Refuse bad options and an output path that two outputs share."""
        self.options.check()
        check_text("--serial", self.serial)
        check_text("--name", self.name)
        seen: dict[Path, str] = {}
        for kind, path in self.output_paths().items():
            key = path.resolve()
            if key in seen:
                raise InputError(
                    f"the {kind} output and the {seen[key]} output are the same file: {path}"
                )
            seen[key] = kind

    @property
    def base(self) -> Path:
        """The outputs' path without a suffix: ``out / stem`` (``stem`` when given, else the
        ``name`` template filled: ``panel_SN-0042``)."""
        if self.stem is not None:
            return self.out / self.stem
        fields = {"part": self.nominal.stem, "serial": self.serial or "", "scan": self.scan.stem}
        return self.out / output_name(self.name, fields)

    def output_paths(self) -> dict[str, Path]:
        """The files this job writes: ``qif``, ``pdf``, ``html``, ``json``, ``mesh`` (those
        asked for)."""
        stem = self.base.name
        o = self.options
        out = {
            "qif": None if o.no_qif else self.out / f"{stem}.qif",
            "pdf": None if o.no_pdf else self.out / f"{stem}.pdf",
            "html": self.out / f"{stem}.html" if o.html else None,
            "json": self.out / f"{stem}.json" if self.json else None,
            "mesh": self.export_mesh,
        }
        return {k: v for k, v in out.items() if v is not None}
