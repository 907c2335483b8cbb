"""The batch's summaries: ``summary.csv`` / ``summary.parquet`` (one row per scan), and per
nominal the QIF Statistics document and the trend PDF.

Every toleranced characteristic is carried by all three: the toleranced surfaces (profile
zones) and the drawing's feature characteristics (geometric tolerances and dimensions) --
their columns in the table (:func:`qifreport.batch.task.summary_row`), their statistics in
the QIF (:mod:`qifreport.qif.statistics`), their run charts in the PDF
(:func:`trend_characteristics`).
"""

from __future__ import annotations

import logging
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from qifreport import __version__
from qifreport.atomic_io import atomic_write_many
from qifreport.kinds import kind_label
from qifreport.metrology.gdt.characteristic_types import CharacteristicSpec

from ..cache import PartState
from ..pipeline import qif_writer
from .plan import ScanItem, safe_id

__all__ = [
    "COLUMNS",
    "FORMULA_STARTS",
    "csv_safe",
    "summary_frame",
    "trend_characteristics",
    "write_summaries",
]

log = logging.getLogger("qifreport.batch")

#: column order of the summary table (per-tolerance columns follow -- each toleranced
#: surface's, then each feature characteristic's, as the rows list them -- then TAIL)
COLUMNS = (
    "seq",
    "id",
    "started",
    "serial",
    "part_number",
    "revision",
    "scan",
    "nominal",
    "verdict",
    "criterion",
    "error",
    "rms_mm",
    "max_abs_mm",
    "p95_mm",
    "p999_mm",
    "mean_mm",
    "tail_above",
    "tail_below",
    "tail_beyond",
    "in_tolerance_pct",
    "coverage_pct",
    "regions",
    "largest_region_mm2",
    "rigid_rms_mm",
    "fit_residual_mm",
    "flagged_fraction",
)
TAIL = (
    "decided_by",
    "operator",
    "instrument",
    "temperature_C",
    "seconds",
    "worker",
    "peak_rss_mib",
    "scan_sha256",
)
#: decimals of the summary's values: lengths to 0.1 um (below any scanner's resolution),
#: areas to 0.01 mm^2, percentages to 0.001 %; other numbers keep 6 significant digits
DECIMALS = (("_mm", 4), ("_mm2", 2), ("_pct", 3), ("seconds", 2), ("_mib", 1))


def summary_frame(records: list[dict]):
    """The summary table (pandas DataFrame), one row per scan in plan order."""
    import pandas as pd

    df = pd.DataFrame(
        [
            {
                **r["row"],
                "worker": r.get("worker", ""),
                "peak_rss_mib": r.get("peak_rss_mib", np.nan),
            }
            for r in records
        ]
    )
    first = [c for c in COLUMNS if c in df.columns]
    zones = [c for c in df.columns if c not in first and c not in TAIL]
    df = df[first + zones + [c for c in TAIL if c in df.columns]]
    for col in ("serial", "criterion", "decided_by", "error", "part_number", "revision"):
        if col in df:
            df[col] = df[col].fillna("")
    status = [c for c in df.columns if c.startswith("status_")]
    df[status] = df[status].fillna("")
    return rounded(df)


def rounded(df):
    """The table's numbers to the decimals their unit calls for (:data:`DECIMALS`)."""
    from pandas.api.types import is_float_dtype

    out = df.copy()
    for col in out.columns:
        if not is_float_dtype(out[col]):
            continue
        places = next((n for suffix, n in DECIMALS if col.endswith(suffix)), None)
        if places is not None:
            out[col] = out[col].round(places)
        else:
            out[col] = [float(f"{v:.6g}") if np.isfinite(v) else v for v in out[col]]
    return out


#: a CSV text cell starting with one of these is a formula to a spreadsheet (CSV injection:
#: ``=HYPERLINK(...)`` in a serial number or a file name)
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def csv_safe(df):
    """The table with every text cell a spreadsheet would run as a formula (it starts with
    one of :data:`FORMULA_STARTS`) prefixed with an apostrophe, which spreadsheets show as
    text; numbers, a negative one included, are left as they are."""
    from pandas.api.types import is_numeric_dtype

    out = df.copy()
    for col in out.columns:
        if not is_numeric_dtype(out[col]):
            out[col] = [
                "'" + v if isinstance(v, str) and v.startswith(FORMULA_STARTS) else v
                for v in out[col]
            ]
    return out


def write_summaries(
    out: Path, items: list[ScanItem], records: list[dict], states: dict, page: str, changed: bool
) -> list[Path]:
    """``summary.csv``, ``summary.parquet`` and, per nominal, the statistics QIF and the
    trend PDF (rewritten when a scan was inspected in this run or a file is missing)."""
    df = summary_frame(records)
    files = [out / "summary.csv", out / "summary.parquet"]
    per_part = []
    for nom, st in states.items():
        stem = safe_id(nom.stem)
        part_files = (out / f"{stem}_statistics.qif", out / f"{stem}_trend.pdf")
        if isinstance(st, str) or not any(r["ok"] and r["nominal"] == str(nom) for r in records):
            for f in part_files:  # no scan of this part inspected: no statistics, no trend
                if f.is_file():
                    f.unlink()
                    log.warning("removed %s: no scan of %s was inspected", f, nom.name)
            continue
        per_part.append((nom, st, *part_files))
        files += per_part[-1][2:]
    safe = csv_safe(df)
    if not changed and all(f.is_file() for f in files) and _same_rows(files[0], safe):
        return files
    writers = [
        (files[0], lambda p: safe.to_csv(p, index=False)),
        (files[1], lambda p: df.to_parquet(p, index=False)),
    ]
    for nom, st, qif_path, pdf_path in per_part:
        recs = [r for r in records if r["nominal"] == str(nom)]
        sub = df[df["nominal"] == nom.name].reset_index(drop=True)
        writers.append((qif_path, _statistics_writer(out, recs, st, nom.stem, qif_path)))
        writers.append((pdf_path, _trend_writer(sub, st, nom.stem, page)))
    atomic_write_many(writers)
    return files


def _same_rows(csv_path: Path, df) -> bool:
    """Does the existing ``summary.csv`` list the same scans, in order, with the same
    digests and verdicts (a re-run over a subset or a new order rewrites it)?"""
    import pandas as pd

    try:
        old = pd.read_csv(csv_path, keep_default_na=False, dtype=str)
    except (OSError, ValueError):
        return False
    cols = ["id", "scan_sha256", "verdict"]
    if any(c not in old.columns for c in cols) or len(old) != len(df):
        return False
    return all(list(old[c]) == [str(v) for v in df[c]] for c in cols)


def _statistics_writer(out: Path, recs: list[dict], st: PartState, part_name: str, target: Path):
    """The writer of the statistics document: validated before it is published, as the
    results documents are (:func:`qifreport.pipeline.qif_writer`)."""

    def write(p: Path) -> None:
        from qifreport.qif.reader import read_results
        from qifreport.qif.statistics import build_statistics

        # each scan's results document (not the part's plan written beside them)
        names = [f"{r['id']}.qif" for r in recs if r["ok"] and f"{r['id']}.qif" in r["outputs"]]
        results = [read_results(out / "scans" / n) for n in names]
        tree = build_statistics(
            results,
            part_name=part_name,
            created=datetime.now(timezone.utc),
            nominal_sha256=st.nominal_sha256,
            sources=[f"scans/{n}" for n in names],
            software_version=__version__,
        )
        state: dict = {}
        qif_writer(tree, state)(p)
        if state["valid"] is None:
            log.warning("%s written, %s", target, state["message"])

    return write


def _spec_description(s: CharacteristicSpec) -> str:
    """One line for a feature characteristic, e.g. ``flatness 0.2 mm (pmi #1541)``,
    ``diameter dimension 9.9 .. 10.1 mm |A|B| (pmi #77)``."""
    what = kind_label(s.kind) if s.kind != "dimension" else f"{s.dim_type} dimension"
    frame = f" |{'|'.join(s.datums)}|" if s.datums else ""
    return f"{what} {s.limits_text()}{frame} (pmi #{s.step_id})"


def trend_characteristics(st: PartState, df) -> list:
    """The characteristics the trend report charts: each toleranced surface, then each
    feature characteristic of the drawing, that the summary ``df`` has values of.

    Parameters
    ----------
    st : the prepared part (its zones, and its plan of feature characteristics).
    df : the summary table of its scans.

    Returns
    -------
    list of qifreport.reports.trend.TrendCharacteristic
        A zone as a profile (its tolerance the zone's width); a geometric tolerance with a
        tolerance one-sided like it (``value_<key>_mm``); a dimension with its limits and
        nominal (``value_<key>_<unit>``; a basic one without limits).
    """
    from qifreport.reports.trend import TrendCharacteristic

    chars = [
        TrendCharacteristic(z.key, z.describe(), float(z.upper - z.lower))
        for z in st.drawing.zones
        if f"profile_{z.key}_mm" in df
    ]
    plan = st.drawing.plan
    for s in plan.specs if plan is not None else []:
        column = f"value_{s.key}_{s.unit}"
        if column not in df:  # never measured
            continue
        quantity = kind_label(s.kind) if s.kind != "dimension" else s.dim_type
        if s.kind == "dimension":
            chars.append(
                TrendCharacteristic(
                    s.key,
                    _spec_description(s),
                    float("nan"),
                    kind="dimension",
                    lower=s.lower_limit,
                    upper=s.upper_limit,
                    nominal=s.nominal,
                    unit=s.unit,
                    quantity=quantity or "dimension",
                    column=column,
                )
            )
        elif s.tolerance is not None:
            chars.append(
                TrendCharacteristic(
                    s.key,
                    _spec_description(s),
                    float(s.tolerance),
                    kind="geometric",
                    quantity=quantity,
                    column=column,
                )
            )
    return chars


def _trend_writer(df, st: PartState, part_name: str, page: str):
    def write(p: Path) -> None:
        from qifreport.reports.trend import write_trend_pdf

        chars = trend_characteristics(st, df)
        write_trend_pdf(
            p,
            df,
            chars,
            part_name=part_name,
            created=datetime.now(timezone.utc),
            nominal_sha256=st.nominal_sha256,
            page=page,
        )

    return write
