"""PDF report benchmark: time to produce the one-page report of a ~100k-triangle part.

The part is the thin shell (``registration.simulate.shapes.thin_shell``) at 0.6 mm spacing,
103,578 triangles, with a synthetic inspection result: a smooth in-band deviation field, a
proud bump and a sunk dent out of a 0.3 mm band, unscanned corners and scanner dropouts;
statistics, regions and the acceptance decision are computed by the product's own metrology
(:mod:`qifreport.metrology.acceptance.statistics`, :mod:`qifreport.metrology.acceptance.criteria`),
so the page carries
realistic content. No registration is run: only the report is timed. Printed: the time of each run
split into ``layout`` (measuring the page, choosing the views), ``render`` (the map pictures, VTK
offscreen) and ``draw`` (histogram, tables, writing the PDF), and the median of the runs. The first
run includes loading VTK and creating the EGL context.

    python bench/pdf.py [--runs 3] [--spacing 0.6] [--page A4] [--backend vtk] [--out DIR]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from qifreport.metrology.acceptance.bands import NotEvaluated, lay_bands, symmetric_zone
from qifreport.metrology.acceptance.criteria import evaluate
from qifreport.metrology.acceptance.statistics import deviation_statistics
from qifreport.metrology.inspection import InspectionParams, InspectionResult, ZoneResult
from qifreport.qif.writer import Provenance
from qifreport.registration.deformable.gbcicp import GBCICPParams, GBCICPResult
from qifreport.registration.icp import RigidResult
from qifreport.registration.mesh import vertex_areas, vertex_normals
from qifreport.reports.pdf import write_report
from qifreport.simulate.shapes import thin_shell


def synthetic_result(
    spacing: float = 0.6, tolerance: float = 0.3, seed: int = 0
) -> InspectionResult:
    """An :class:`InspectionResult` of the thin shell with a synthetic deviation field."""
    rng = np.random.default_rng(seed)
    V, F = thin_shell(spacing=spacing)
    n = len(V)
    x, y = V[:, 0], V[:, 1]
    dev = 0.06 * np.sin(x / 21.0) * np.cos(y / 17.0) + 0.01 * rng.standard_normal(n)
    dev += 0.9 * np.exp(-((x - 30) ** 2 + (y - 20) ** 2) / (2 * 7.0**2))  # proud bump
    dev -= 0.7 * np.exp(-((x + 45) ** 2 + (y + 12) ** 2) / (2 * 5.0**2))  # sunk dent
    corners = np.array(
        [[x.min(), y.min()], [x.min(), y.max()], [x.max(), y.min()], [x.max(), y.max()]]
    )
    d_corner = np.min(np.linalg.norm(V[:, None, :2] - corners[None], axis=2), axis=1)
    dev[d_corner < 12.0] = np.nan  # unscanned corners (clamps)
    for c in rng.choice(n, 6, replace=False):  # dropouts
        dev[np.linalg.norm(V[:, :2] - V[c, :2], axis=1) < 4.0] = np.nan

    zone = symmetric_zone(tolerance, "general")
    bands = lay_bands(F, n, None, [zone])
    area = vertex_areas(V, F)
    acc = evaluate(V, F, dev, bands.half_width, area=area, center=bands.center)
    vstats = deviation_statistics(dev, weights=area, threshold=tolerance)
    # scan points: every other scored vertex displaced by its deviation, with range noise
    N = vertex_normals(V, F)
    keep = np.flatnonzero(np.isfinite(dev))[::2]
    P = V[keep] + N[keep] * dev[keep, None]
    pdev = dev[keep] + 0.01 * rng.standard_normal(len(keep))
    pstats = deviation_statistics(pdev, threshold=tolerance)
    rigid = RigidResult(
        R=np.eye(3),
        t=np.zeros(3),
        rms=0.021,
        scale=0.012,
        inlier_fraction=0.995,
        iterations=14,
        converged=True,
    )
    fit = GBCICPResult(
        V=V,
        e=np.zeros_like(V),
        residual=dev,
        covered=np.isfinite(dev),
        flagged=np.abs(np.nan_to_num(dev)) > 3 * 0.012,
        held_out=np.zeros(n, bool),
        weights=np.ones(n),
        scale=0.012,
        passes=2,
        fallback=False,
        flagged_fraction=0.013,
        iterations=46,
        seconds=3.1,
        params=GBCICPParams(
            band_limit=1.8, band_limit_refit=0.9, band_limit_start=24.6, coverage_radius=1.8
        ),
    )
    scan_area = float(acc.scored_area) * 1.01
    return InspectionResult(
        V=V,
        F=F,
        V_registered=V,
        P=P,
        deviation=dev,
        point_deviation=pdev,
        vertex_stats=vstats,
        point_stats=pstats,
        acceptance=acc,
        rigid=rigid,
        fit=fit,
        params=InspectionParams(tolerance=tolerance),
        scan_area=scan_area,
        coverage_ceiling_ok=bool(acc.coverage <= scan_area / acc.nominal_area * 1.05),
        timings={},
        zones=[ZoneResult(zone=zone, stats=vstats, acceptance=acc)],
        not_evaluated=[
            NotEvaluated(
                "flatness", "flatness_base", 1234, "feature tolerance: needs a feature fit"
            )
        ],
        bands=bands,
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--spacing", type=float, default=0.6, help="shell spacing, mm")
    ap.add_argument("--page", default="A4")
    ap.add_argument("--backend", default=None, choices=[None, "vtk", "matplotlib"])
    ap.add_argument("--out", type=Path, default=None, help="keep the PDF in this directory")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    res = synthetic_result(args.spacing)
    t_build = time.perf_counter() - t0
    now = datetime.now(timezone.utc)
    prov = Provenance(
        part_name="shell_100k",
        nominal_path="shell_100k.ply",
        scan_path="shell_100k_scan.ply",
        nominal_sha256="0" * 64,
        scan_sha256="1" * 64,
        started=now,
        finished=now,
        operator="bench",
        organization="qifreport",
    )
    print(
        f"part: thin shell, {len(res.V)} vertices, {len(res.F)} triangles "
        f"(synthetic result built in {t_build:.2f} s, not timed); verdict "
        f"{'PASS' if res.passed else 'FAIL'}, {len(res.acceptance.regions)} regions"
    )
    with tempfile.TemporaryDirectory(prefix="qifreport-bench-") as tmp:
        out_dir = args.out or Path(tmp)
        out_dir.mkdir(parents=True, exist_ok=True)
        _runs(args, res, prov, out_dir)


def _runs(args: argparse.Namespace, res: InspectionResult, prov: Provenance, out_dir: Path) -> None:
    rows = []
    for k in range(args.runs):
        t = time.perf_counter()
        split = write_report(
            out_dir / "shell_100k.pdf", res, prov, page=args.page, backend=args.backend
        )
        total = time.perf_counter() - t
        rows.append({**split, "total": total})
        print(
            f"run {k + 1}: total {total:.3f} s = layout {split['layout']:.3f} + render "
            f"{split['render']:.3f} + draw {split['draw']:.3f}"
            + ("  (cold: first render in this process)" if k == 0 else "")
        )
    med = {key: statistics.median(r[key] for r in rows) for key in rows[0]}
    print(
        f"median of {args.runs}: {med['total']:.3f} s (layout {med['layout']:.3f}, render "
        f"{med['render']:.3f}, draw {med['draw']:.3f}); requirement < 5 s"
    )
    size = (out_dir / "shell_100k.pdf").stat().st_size / 1024
    print(f"PDF: {size:.0f} KiB" + (f", kept in {out_dir}" if args.out else ""))


if __name__ == "__main__":
    main()
