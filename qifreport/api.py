"""The Python API: one inspection from a notebook or a script.

The command line is a layer over the same pipeline (:mod:`qifreport.pipeline`); here the
inspection is a value, and its outputs are written when asked::

    import qifreport

    report = qifreport.inspect("part.step", "scan.ply")
    report.verdict                      # "PASS", "FAIL", "NOT ESTABLISHED", ...
    report.characteristics()            # pandas DataFrame, one row per drawing item
    report.deviation_mesh()             # trimesh.Trimesh, vertex attribute "deviation" (mm)
    report.write_qif("out/part.qif")    # QIF 3.0 results, validated before it is published
    report.write_pdf("out/part.pdf")

Options are :class:`~qifreport.options.InspectOptions`' fields, by keyword (the command
line's long options with ``_`` for ``-``: ``tolerance=0.5``, ``restraint="free"``,
``clamps="clamps.csv"``); nothing is written unless a ``write_*`` method is called.

Public API
----------
:func:`inspect`, :class:`Report`, :func:`read_part`, :func:`read_scan`, :func:`plan`
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import InputError

if TYPE_CHECKING:
    import pandas
    import trimesh

    from qifreport.metrology.model import Drawing, Part
    from qifreport.metrology.results import InspectionResult

    from .options import InspectJob
    from .pipeline import Inspected

__all__ = ["Report", "inspect", "plan", "read_part", "read_scan"]

#: path options: a ``str`` given for them is taken as a path
_PATH_OPTIONS = ("cache_dir", "clamps", "scanner")


def _options(kwargs: dict[str, Any]):
    """:class:`~qifreport.options.InspectOptions` from keyword ``kwargs`` (TypeError naming
    an unknown one; the default cache unless ``cache_dir`` is given, None for none)."""
    from .cache import default_cache_dir
    from .options import InspectOptions

    fields = {f.name for f in dataclasses.fields(InspectOptions)}
    unknown = sorted(set(kwargs) - fields)
    if unknown:
        raise TypeError(
            f"unknown option(s) {', '.join(unknown)}; the options are: {', '.join(sorted(fields))}"
        )
    values = dict(kwargs)
    values.setdefault("cache_dir", default_cache_dir())
    for k in _PATH_OPTIONS:  # ("clamps": "pmi" is the drawing's datum targets, as on the CLI)
        if isinstance(values.get(k), str):
            values[k] = Path(values[k])
    options = InspectOptions(**values)
    options.check()
    return options


def inspect(
    part: str | Path,
    scan: str | Path | np.ndarray,
    *,
    serial: str | None = None,
    progress: bool = False,
    **options: Any,
) -> Report:
    """Inspect one free-state ``scan`` of ``part`` as ``qifreport part scan`` does.

    Parameters
    ----------
    part : the nominal: a STEP file (AP242 with semantic PMI) or a mesh (STL, PLY, OBJ, OFF;
        give ``tolerance``).
    scan : a scan file (PLY, STL, OBJ, OFF, XYZ/CSV, NPY, E57) or an (m, 3) array of points,
        mm (``scan_units`` for another unit).
    serial : the part's serial number (in every output).
    progress : a progress bar on stderr.
    **options : :class:`~qifreport.options.InspectOptions` fields (``tolerance``,
        ``restraint``, ``clamps``, ``material``, ``scanner``, ``decision_rule``, ...);
        ``cache_dir`` defaults to the user cache (None: no cache).

    Returns
    -------
    The :class:`Report`; its ``verdict`` and ``exit_code`` are the command line's.

    Raises
    ------
    qifreport.errors.InputError
        An input that cannot be inspected (the message names the problem).
    TypeError
        An unknown option.
    """
    from .options import InspectJob
    from .pipeline import check_job, inspect_job

    opts = _options(options)
    with tempfile.TemporaryDirectory(prefix="qifreport-") as tmp:
        scan_path = _scan_file(scan, Path(tmp))
        job = InspectJob(
            nominal=Path(part),
            scan=scan_path,
            out=Path(tmp),
            options=dataclasses.replace(opts, no_qif=True, no_pdf=True, html=False),
            serial=serial,
        )
        check_job(job)
        done = inspect_job(job, progress=progress)
    if isinstance(scan, np.ndarray):  # the temporary file is gone: name the array
        job = dataclasses.replace(job, scan=Path("<array>"))
    return Report(done, dataclasses.replace(job, options=opts, out=Path(".")))


def _scan_file(scan: str | Path | np.ndarray, tmp: Path) -> Path:
    """The scan as a file: ``scan`` itself, or an array saved as NPY in ``tmp``."""
    if not isinstance(scan, np.ndarray):
        return Path(scan)
    P = np.asarray(scan, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"a scan array must be (m, 3) points, got shape {P.shape}")
    path = tmp / "scan.npy"
    np.save(path, P)
    return path


@dataclass
class Report:
    """One inspection (:func:`inspect`): its verdict, its items and its outputs on demand."""

    inspected: Inspected
    job: InspectJob

    @property
    def result(self) -> InspectionResult:
        """The full inspection result (:class:`qifreport.metrology.results.InspectionResult`)."""
        return self.inspected.result

    @property
    def verdict(self) -> str:
        """``"PASS"``, ``"FAIL"``, ``"NOT ESTABLISHED"`` or ``"NOT MEASURED"``."""
        return self.result.verdict

    @property
    def exit_code(self) -> int:
        """The command line's exit code for it: 0 pass, 1 fail, 3 not established."""
        from .pipeline import exit_code

        return exit_code(self.result)

    def summary(self) -> dict:
        """The JSON summary (``schemas/summary-1.schema.json``; no ``qif`` block until a QIF
        is written), as plain Python values."""
        from .jsonio import finite, json_default
        from .pipeline import summary_document

        i = self.inspected
        doc = summary_document(
            i.result, i.state.part, self.job, i.digests, i.scan_report, (i.started, i.finished)
        )
        return json.loads(json.dumps(finite(doc), default=json_default, allow_nan=False))

    def text(self) -> str:
        """The summary the command line prints."""
        from .console import summary

        return summary(self.result)

    def characteristics(self) -> pandas.DataFrame:
        """One row per drawing item: the surface tolerance zones (``source`` ``zone``) and the
        feature characteristics (``characteristic``), with ``key``, ``kind``, ``status``,
        ``value_mm`` (a zone's largest absolute deviation, a characteristic's measured
        value), ``lower_mm`` and ``upper_mm`` (its limits), ``U_mm`` (expanded
        uncertainty, k = 2), ``description`` and ``reason``."""
        import pandas as pd

        doc = self.summary()
        rows = [_zone_row(z) for z in doc.get("tolerances", [])]
        rows += [_characteristic_row(c) for c in doc.get("characteristics", [])]
        cols = ["source", "key", "kind", "status", "value_mm", "lower_mm", "upper_mm", "U_mm"]
        return pd.DataFrame(rows, columns=[*cols, "description", "reason"])

    def deviation_mesh(self) -> trimesh.Trimesh:
        """The nominal as the fixture registered it, its vertex attribute ``deviation`` the
        signed deviation at each vertex, mm (NaN: not scored)."""
        import trimesh

        r = self.result
        mesh = trimesh.Trimesh(r.V_registered, self.inspected.state.part.F, process=False)
        mesh.vertex_attributes["deviation"] = np.asarray(r.deviation, dtype=np.float64)
        return mesh

    def write_qif(self, path: str | Path) -> dict:
        """Write the QIF 3.0 results document (and the part's plan beside it, for a STEP
        part); returns its validation (``valid``, ``message``)."""
        written = self._write(Path(path), "qif")
        return written or {}

    def write_pdf(self, path: str | Path, *, page: str | None = None) -> None:
        """Write the one-page report (``page``: ``"A4"`` or ``"Letter"``)."""
        self._write(Path(path), "pdf", page=page)

    def write_html(self, path: str | Path) -> None:
        """Write the interactive deviation map."""
        self._write(Path(path), "html")

    def write_json(self, path: str | Path) -> None:
        """Write the JSON summary."""
        self._write(Path(path), "json")

    def _write(self, path: Path, kind: str, page: str | None = None) -> dict | None:
        from .atomic_io import atomic_write_many

        o = self.job.options
        opts = dataclasses.replace(
            o,
            no_qif=kind != "qif",
            no_pdf=kind != "pdf",
            html=kind == "html",
            page=page or o.page,
        )
        job = dataclasses.replace(
            self.job, out=path.parent, stem=path.stem, options=opts, json=kind == "json"
        )
        paths = {kind: path}
        outputs, qif_state = self.inspected.writers(job, paths)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_many(outputs)
        return qif_state


def _zone_row(z: dict) -> dict:
    dev, acc = z.get("deviation") or {}, z.get("acceptance") or {}
    return {
        "source": "zone",
        "key": z.get("key"),
        "kind": z.get("kind"),
        "status": z.get("verdict"),
        "value_mm": dev.get("max_abs"),
        "lower_mm": z.get("lower_mm"),
        "upper_mm": z.get("upper_mm"),
        "U_mm": acc.get("uncertainty_max_mm"),
        "description": z.get("description"),
        "reason": "; ".join(acc.get("reasons") or []),
    }


def _characteristic_row(c: dict) -> dict:
    tol = c.get("tolerance_mm")
    lower = c.get("lower_limit")
    upper = c.get("upper_limit") if c.get("upper_limit") is not None else tol
    return {
        "source": "characteristic",
        "key": c.get("key"),
        "kind": c.get("kind"),
        "status": c.get("status"),
        "value_mm": c.get("value"),
        "lower_mm": lower,
        "upper_mm": upper,
        "U_mm": c.get("uncertainty"),
        "description": c.get("name"),
        "reason": c.get("reason") or "",
    }


def read_part(part: str | Path, **options: Any) -> tuple[Part, Drawing]:
    """Read a nominal as an inspection does: its mesh (``Part``: ``V`` (n, 3) mm, ``F``,
    ``face_id``, ``info``) and its drawing (``Drawing``: tolerance zones, characteristics,
    datums, restraint). ``options``: ``tolerance``, ``max_edge``, ``deflection``, ``mesher``,
    ``solid``, ``accept_tolerance_as_read``."""
    from .nominal import load_nominal

    allowed = {"tolerance", "max_edge", "deflection", "mesher", "solid", "accept_tolerance_as_read"}
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise TypeError(
            f"unknown option(s) {', '.join(unknown)}; read_part takes {sorted(allowed)}"
        )
    return load_nominal(
        Path(part),
        options.pop("tolerance", None),
        options.pop("max_edge", None),
        options.pop("deflection", None),
        **options,
    )


def read_scan(scan: str | Path, units: str | None = None) -> np.ndarray:
    """A scan file's points, (m, 3) mm (``units``: the file's unit, ``"mm"``, ``"in"`` or
    ``"m"``; None: the format's own), exact duplicates removed."""
    from qifreport.registration.pointcloud import read_scan as read

    return read(Path(scan), units=units).points


def plan(part: str | Path, out: str | Path) -> Path:
    """Write the STEP ``part``'s QIF 3.0 measurement plan: ``out`` a file, or a folder
    (``<stem>_plan.qif`` in it). Returns its path."""
    from qifreport.qif.plan import plan_file_name

    from .plan_command import write_plan

    out = Path(out)
    if out.is_dir() or out.suffix.lower() != ".qif":
        out.mkdir(parents=True, exist_ok=True)
        out = out / plan_file_name(Path(part).stem)
    return write_plan(Path(part), out).path
