"""The one-page PDF report: complete, one page, legible, and the same numbers as the QIF file.

Real inspections (the shell passing at 0.5 mm, the shell with a 1 mm bump failing at 0.3 mm,
the STEP panel with two PMI profile tolerances) are written as PDF and QIF; the PDF is
rasterized with ``pdftoppm`` and its text extracted with ``pdftotext`` (poppler-utils) and
checked against the result and against what :func:`qifreport.qif.reader.read_results` reads back
from the QIF file, at the precision the page prints. A synthetic stress case (40 regions, 25
tolerances) must still give one page with the lists summarised.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import re
import subprocess
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from qifreport.qif.profile_characteristics import profile_value
from qifreport.qif.reader import read_results
from qifreport.qif.writer import Provenance, build_qif, write_qif
from qifreport.reports.callouts import MAX_PER_VIEW
from qifreport.reports.pdf import (
    fmt_area,
    fmt_mm,
    fmt_pct,
    fmt_smm,
    map_points,
    plan_layout,
    write_report,
)
from tests.conftest import ROOT
from tests.consumers import poppler_tool as _tool

DPI = 60


def _prov(name: str, nominal: str, scan: str) -> Provenance:
    t = datetime(2025, 1, 2, 3, 4, 5, tzinfo=timezone.utc)
    return Provenance(
        part_name=name,
        nominal_path=nominal,
        scan_path=scan,
        nominal_sha256="ab" * 32,
        scan_sha256="cd" * 32,
        started=t,
        finished=t + timedelta(seconds=9),
        author="Ada Auditor",
        organization="Test Lab",
        operator="Op One",
        serial_number="SN-0001",
    )


@dataclasses.dataclass
class Out:
    res: object
    prov: Provenance
    pdf: Path
    qif: Path
    text: str
    png: Path
    timings: dict


def _produce(d: Path, name: str, res, prov: Provenance, page: str = "A4") -> Out:
    pdf, qif = d / f"{name}.pdf", d / f"{name}.qif"
    timings = write_report(pdf, res, prov, page=page, qif_name=qif.name)
    write_qif(qif, build_qif(res, prov))
    subprocess.run(
        [_tool("pdftoppm"), "-r", str(DPI), "-png", "-singlefile", str(pdf), str(d / name)],
        check=True,
    )
    text = subprocess.run(
        [_tool("pdftotext"), "-layout", str(pdf), "-"], check=True, capture_output=True, text=True
    ).stdout
    return Out(res, prov, pdf, qif, text, d / f"{name}.png", timings)


@pytest.fixture(scope="module")
def panel_nominal():
    """The STEP panel's part and drawing as the CLI reads them (default max edge:
    diagonal / 60)."""
    from qifreport.nominal import load_nominal

    return load_nominal(ROOT / "samples/panel.step", None, None)


@pytest.fixture(scope="module")
def results(shell, shell_case, shell_case_defect, panel_nominal):
    """name -> (InspectionResult, Provenance): a passing shell, a failing shell and the STEP
    panel (two PMI profile tolerances, two PMI items not scored), inspected as the CLI does."""
    from qifreport.metrology.inspection import InspectionInputs, InspectionParams, inspect
    from qifreport.registration.pointcloud import read_scan

    V, F = shell
    out = {}
    res = inspect(V, F, shell_case.P, InspectionParams(tolerance=0.5))
    out["pass"] = (res, _prov("shell", "shell.ply", "shell_scan.npy"))
    res = inspect(V, F, shell_case_defect.P, InspectionParams(tolerance=0.3))
    out["fail"] = (res, _prov("shell", "shell.ply", "shell_defect.npy"))
    part, drawing = panel_nominal
    P = read_scan(ROOT / "samples/panel_scan_defect.ply").points
    res = inspect(
        part.V,
        part.F,
        P,
        InspectionParams(tolerance=None),
        InspectionInputs(
            face_id=part.face_id, zones=drawing.zones, not_evaluated=drawing.not_evaluated
        ),
    )
    prov = _prov("panel", "samples/panel.step", "samples/panel_scan_defect.ply")
    out["panel"] = (res, dataclasses.replace(prov, face_step_ids=part.face_step_ids))
    return out


@pytest.fixture(scope="module")
def reports(tmp_path_factory, results):
    """name -> Out: the PDF and QIF of each result, the PDF rasterized and its text."""
    _tool("pdftoppm")
    _tool("pdftotext")
    d = tmp_path_factory.mktemp("pdf")
    return {name: _produce(d, name, res, prov) for name, (res, prov) in results.items()}


CASES = ["pass", "fail", "panel"]


def _pdfinfo(pdf: Path) -> dict[str, str]:
    txt = subprocess.run(
        [_tool("pdfinfo"), str(pdf)], check=True, capture_output=True, text=True
    ).stdout
    return {
        k.strip(): v.strip() for k, v in (ln.split(":", 1) for ln in txt.splitlines() if ":" in ln)
    }


def _tokens(text: str) -> set[str]:
    return set(text.split())


def _pixels(png: Path, box, page_h: float) -> np.ndarray:
    """RGB pixels (int) of a page box (points, origin bottom-left) in the rasterized page."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    s = DPI / 72.0
    x0, x1 = int(np.ceil(box.x * s)) + 1, int(np.floor((box.x + box.w) * s)) - 1
    y0, y1 = int(np.ceil((page_h - box.top) * s)) + 1, int(np.floor((page_h - box.y) * s)) - 1
    return img[y0:y1, x0:x1].reshape(-1, 3)


def _green(px: np.ndarray) -> np.ndarray:
    r, g, b = px.T
    return (g > r + 25) & (g > b + 8)


def _red(px: np.ndarray) -> np.ndarray:
    r, g, b = px.T
    return (r > 120) & (r > g + 50) & (r > b + 50)


def _blue(px: np.ndarray) -> np.ndarray:
    r, g, b = px.T
    return (b > 100) & (b > r + 50) & (b > g + 30)


# ------------------------------------------------------------------------------- the page


@pytest.mark.parametrize("case", CASES)
def test_one_page_verdict_and_fonts(reports, case):
    o = reports[case]
    info = _pdfinfo(o.pdf)
    assert info["Pages"] == "1"
    assert info["Page size"].startswith("595.276 x 841.89")  # A4
    verdict = "PASS" if o.res.passed else "FAIL"
    assert {"pass": "PASS", "fail": "FAIL", "panel": "FAIL"}[case] == verdict
    assert verdict in _tokens(o.text)
    other = "FAIL" if verdict == "PASS" else "PASS"
    if verdict == "PASS":  # the word FAIL only where the page says what the free state gave
        assert other not in _tokens(re.sub(r"free\s+state\s+FAIL", "", o.text))
    assert read_results(o.qif).status == verdict
    # title block: part, files with their digest, operator, organization, units, software
    for s in (
        "shell" if case != "panel" else "panel",
        Path(o.prov.nominal_path).name,
        Path(o.prov.scan_path).name,
        "abababababababab",
        "cdcdcdcdcdcdcdcd",
        "Op One",
        "Test Lab",
        "SN-0001",
        "qifreport",
        "2025-01-02 03:04:05 UTC",
        "mm²",
        f"is in {o.qif.name} (QIF 3.0",
    ):
        assert s in o.text, s
    # every font embedded (DejaVu, no base-14 font)
    fonts = subprocess.run(
        [_tool("pdffonts"), str(o.pdf)], check=True, capture_output=True, text=True
    ).stdout.splitlines()[2:]
    assert fonts
    for line in fonts:
        assert "DejaVuSans" in line and " yes " in line, line
    # a PNG of one page was produced
    assert o.png.is_file() and not list(o.png.parent.glob(f"{case}-*.png"))


@pytest.mark.parametrize("case", CASES)
def test_nothing_outside_the_page(reports, case):
    """Every word lies inside the page's margins (nothing cut by the page edge)."""
    o = reports[case]
    _assert_words_inside(o.pdf)


def _words(pdf: Path) -> tuple[float, float, list[tuple[str, float, float, float, float]]]:
    """The page's width and height and its words ``(text, x0, y0, x1, y1)``, points, y down
    from the top of the page (``pdftotext -bbox``)."""
    import html

    xml = subprocess.run(
        [_tool("pdftotext"), "-bbox", str(pdf), "-"], check=True, capture_output=True, text=True
    ).stdout
    page = re.search(r'<page width="([\d.]+)" height="([\d.]+)"', xml)
    W, H = float(page.group(1)), float(page.group(2))
    words = re.findall(
        r'<word xMin="([\d.-]+)" yMin="([\d.-]+)" xMax="([\d.-]+)" yMax="([\d.-]+)">(.*?)</word>',
        xml,
    )
    return W, H, [(html.unescape(t), *map(float, b)) for *b, t in words]


def _assert_words_inside(pdf: Path) -> None:
    W, H, words = _words(pdf)
    assert len(words) > 200
    for _, x0, y0, x1, y1 in words:
        assert 20 <= x0 and x1 <= W - 20 and 20 <= y0 and y1 <= H - 20, (x0, y0, x1, y1)


SIGNED = re.compile(r"^[+-]\d+\.\d{3}$")  # a deviation as the page prints it (fmt_smm)


def _map_words(pdf: Path, lay) -> list[tuple[int, str, float, float, float, float]]:
    """The words drawn on the map pictures: ``(map index, text, x0, y0, x1, y1)``, page
    points with y up (as the layout's boxes)."""
    _, H, words = _words(pdf)
    out = []
    for t, x0, y0, x1, y1 in words:
        cx, cy = 0.5 * (x0 + x1), H - 0.5 * (y0 + y1)
        for k, b in enumerate(lay.maps):
            if b.x < cx < b.x + b.w and b.y < cy < b.top:
                out.append((k, t, x0, H - y1, x1, H - y0))
    return out


@pytest.mark.parametrize("case", CASES)
def test_statistics_equal_result_and_qif(reports, case):
    o = reports[case]
    res, tok = o.res, _tokens(o.text)
    q = read_results(o.qif)
    v, a = res.vertex_stats, res.acceptance
    # the page prints the result's numbers, and the QIF carries the same at that precision
    pairs = [
        (fmt_mm(v.rms), fmt_mm(q.stats.rms)),
        (fmt_mm(v.p95), fmt_mm(q.stats.p95)),
        (fmt_mm(v.p99), fmt_mm(q.stats.p99)),
        (fmt_mm(v.p999), fmt_mm(q.stats.p999)),
        (fmt_smm(v.max_pos), fmt_smm(q.stats.max_pos)),
        (fmt_smm(v.min_neg), fmt_smm(q.stats.min_neg)),
        (fmt_smm(v.mean), fmt_smm(q.stats.mean)),
        (fmt_pct(v.frac_beyond), fmt_pct(q.stats.frac_beyond)),
        (fmt_pct(a.in_tolerance_fraction), fmt_pct(q.acceptance.in_tolerance_fraction)),
        (fmt_pct(a.coverage), fmt_pct(q.acceptance.coverage)),
        (fmt_area(a.scored_area), fmt_area(q.acceptance.scored_area)),
        (fmt_mm(res.point_stats.rms), fmt_mm(q.point_stats.rms)),
        (fmt_mm(res.point_stats.p999), fmt_mm(q.point_stats.p999)),
        (fmt_mm(res.rigid.rms), fmt_mm(q.attributes["rigid_rms_mm"])),
    ]
    if res.fit is not None:
        pairs.append((fmt_mm(res.fit.scale), fmt_mm(q.attributes["fit_residual_scale_mm"])))
    for printed, from_qif in pairs:
        assert printed == from_qif
        assert printed in tok, printed
    # region count and the regions listed (area, peak) as in the QIF
    m = re.search(r"Out-of-tolerance regions, whole part \((\d+);", o.text)
    assert m and int(m.group(1)) == len(a.regions) == q.attributes["region_count"]
    lay = plan_layout(res, o.prov)
    for k, r in enumerate(a.regions[: lay.regions_listed], start=1):
        assert fmt_area(r.area) == fmt_area(q.attributes[f"region_{k}_area_mm2"])
        assert fmt_area(r.area) in tok and fmt_smm(r.peak) in tok
    if len(a.regions) > lay.regions_listed:
        assert f"+ {len(a.regions) - lay.regions_listed} more regions" in o.text
    # per tolerance: key, profile value, in-band share and verdict as in the QIF
    for z in res.zones:
        c = q.characteristic(z.zone.key)
        # a surface not measured (too little scored, or its datum frame not established)
        # prints n/m
        # prints n/m (the text extraction may join it to the cell before)
        not_measured = c.document.status in ("NOT_MEASURED", "NOT_ANALYZED")
        printed_status = "n/m" if not_measured else c.document.status
        rows = [ln for ln in o.text.splitlines() if ln.split()[:1] == [z.zone.key]]
        row = next(
            (
                ln
                for ln in rows
                if (printed_status in ln if not_measured else printed_status in ln.split())
            ),
            None,
        )
        assert row is not None, (printed_status, rows)  # the tolerance table's row
        cells = row.split()
        assert fmt_mm(profile_value(z)) == fmt_mm(c.document.attributes["profile_value_mm"])
        assert fmt_mm(profile_value(z)) in cells
        assert fmt_pct(c.document.attributes["in_tolerance_area_fraction"]) in cells
    # two or three tolerances: each has its own column of the statistics table
    if 2 <= len(res.zones) <= 3:
        lines = o.text.splitlines()
        for label, key, fmt in (
            ("P95 of |dev|, mm", "p95", fmt_mm),
            ("P99 of |dev|, mm", "p99", fmt_mm),
            ("Mean, mm", "mean", fmt_smm),
            ("Beyond ±τ, %", "frac_beyond", fmt_pct),
        ):
            row = next(ln for ln in lines if label in ln).split(label, 1)[1].split()
            for z in res.zones:
                c = q.characteristic(z.zone.key)
                qv = c.document.attributes[f"{key}_mm" if fmt is not fmt_pct else key]
                assert fmt(getattr(z.stats, key)) == fmt(qv)
                assert fmt(qv) in row, (label, z.zone.key, row)
    # PMI listed but not scored, with its count
    if res.not_evaluated:
        assert f"PMI not scored ({len(res.not_evaluated)})" in o.text
        assert all(n.name in o.text for n in res.not_evaluated)


def test_failing_reasons_and_criteria(reports):
    o = reports["fail"]
    assert "region criterion: whole part" in o.text
    assert "region of 183.9 mm²" in o.text or "region of" in o.text
    assert "> limit" in o.text
    # the panel's injected defect (0.45 mm proud, sigma 6 mm, on the crown's outer skin)
    # fails the functional skin's 0.5 mm profile T2 by the region criterion
    panel = reports["panel"]
    assert "region criterion:" in panel.text and "T2" in panel.text
    assert [z.acceptance.passed for z in panel.res.zones] == [True, False]


def test_map_colours(reports):
    """The failing parts' maps show in-band (green) and out-of-band colours (red proud on the
    shell's bump and on the panel's); the passing part's none (it has no vertex
    outside its band)."""
    for case, want in (("fail", _red), ("panel", _red), ("pass", None)):
        o = reports[case]
        res = o.res
        lay = plan_layout(res, o.prov)
        px = np.concatenate([_pixels(o.png, b, lay.height) for b in lay.maps])
        n_green, n_out = int(_green(px).sum()), int((_red(px) | _blue(px)).sum())
        assert n_green > 100, (case, n_green)
        if want is not None:
            assert want(px).sum() >= 5, case
        else:
            lo, hi = res.bands.lower, res.bands.upper
            d = res.deviation
            scored = np.isfinite(d)
            assert not res.acceptance.regions
            assert np.all((d[scored] >= lo[scored]) & (d[scored] <= hi[scored]))
            assert n_out == 0, (case, n_out)


def test_letter_page(reports, tmp_path):
    o = reports["fail"]
    out = _produce(tmp_path, "letter", o.res, o.prov, page="Letter")
    info = _pdfinfo(out.pdf)
    assert info["Pages"] == "1"
    assert info["Page size"].startswith("612 x 792")
    assert "FAIL" in _tokens(out.text)
    _assert_words_inside(out.pdf)
    with pytest.raises(ValueError, match="A4"):
        write_report(tmp_path / "x.pdf", o.res, o.prov, page="A3")


@pytest.mark.parametrize("page", ["A4", "Letter"])
def test_stress_many_regions_and_tolerances(reports, tmp_path, page):
    """40 regions and 25 tolerances (and 9 PMI items not scored) still fit one page: the
    lists are cut and the cut is stated."""
    from qifreport.metrology.acceptance.bands import NotEvaluated
    from qifreport.metrology.acceptance.criteria import Region

    base = reports["panel"].res
    res = copy.copy(base)
    rng = np.random.default_rng(0)
    regs = list(base.acceptance.regions)
    for c in rng.choice(len(base.V), 40 - len(regs), replace=False):
        idx = np.argsort(np.linalg.norm(base.V - base.V[c], axis=1))[:10]
        regs.append(
            Region(
                vertices=np.sort(idx),
                area=float(rng.uniform(0.5, 30)),
                peak=float(rng.uniform(0.3, 1.5)),
                peak_vertex=int(c),
                centroid=base.V[idx].mean(axis=0),
                sign=1,
            )
        )
    res.acceptance = dataclasses.replace(base.acceptance, regions=regs)
    res.zones = [
        dataclasses.replace(
            base.zones[k % len(base.zones)],
            zone=dataclasses.replace(
                base.zones[k % len(base.zones)].zone,
                key=f"T{k + 1}",
                step_id=5000 + k,
                name=f"a_rather_long_profile_tolerance_name_{k}",
            ),
        )
        for k in range(25)
    ]
    res.not_evaluated = [
        NotEvaluated("flatness", f"flat_{i}", 7000 + i, "feature tolerance") for i in range(9)
    ]
    prov = dataclasses.replace(
        reports["panel"].prov,
        part_name="p" * 120,
        organization="An Extremely Long Organization Name " * 4,
    )
    out = _produce(tmp_path, "stress", res, prov, page=page)
    assert _pdfinfo(out.pdf)["Pages"] == "1"
    assert re.search(r"\+ \d+ more regions", out.text)
    # none of the 25 passes (copies of the defect panel's n/m and FAIL): every one is listed
    assert all(re.search(rf"\bT{k}\b", out.text) for k in range(1, 26))
    assert "more tolerances not listed" not in out.text
    assert re.search(r"\+ \d+ more reasons", out.text)
    assert "Out-of-tolerance regions, whole part (40;" in out.text
    assert "Tolerances (25)" in out.text
    _assert_words_inside(out.pdf)
    lay = plan_layout(res, prov, page=page)
    assert lay.regions_listed >= 2 and lay.tolerances_listed >= 2
    assert min(b.h for b in lay.maps) >= 100
    # the deviation callouts stay few and never overlap
    values = [w for w in _map_words(out.pdf, lay) if SIGNED.match(w[1])]
    assert values
    for k in range(len(lay.maps)):
        assert sum(w[0] == k for w in values) <= MAX_PER_VIEW
    for i, a in enumerate(values):
        for b in values[i + 1 :]:
            assert a[4] <= b[2] or b[4] <= a[2] or a[5] <= b[3] or b[5] <= a[3], (a, b)


def test_region_callout_at_the_worst_point(reports, tmp_path):
    """The failing shell's map calls out region 1's worst deviation beside its number, once,
    with the result's (and the QIF's) value at that vertex and its sign, the label near the
    point on the map that shows it and a leader line drawn from the point to the label."""
    o = reports["fail"]
    res = o.res
    lay = plan_layout(res, o.prov)
    r1 = res.acceptance.regions[0]
    v = r1.peak_vertex
    if r1.peak_location is not None:
        # found on the scan points: its worst point is the point's, shown at the region's
        # vertex nearest it (a proud point off the surface is the part's material)
        idx = np.asarray(r1.vertices, dtype=np.int64)
        near = np.linalg.norm(res.V_registered[idx] - np.asarray(r1.peak_location), axis=1)
        v = int(idx[np.argmin(near)])
    value = fmt_smm(r1.peak)
    assert value == fmt_smm(read_results(o.qif).acceptance.regions[0].peak)
    assert r1.peak >= res.deviation[r1.peak_vertex] - 1e-9
    assert r1.sign == 1 and res.deviation[v] > res.bands.upper[v] and value.startswith("+")
    words = _map_words(o.pdf, lay)
    hits = [w for w in words if w[1] == value]
    assert len(hits) == 1, (value, [w[1] for w in words])  # called out once, on a map
    k, _, x0, y0, x1, y1 = hits[0]
    # the region's number right before the value, on the same line
    assert any(
        w[0] == k and w[1] == "1" and 0 <= x0 - w[4] < 6 and abs(w[3] - y0) < 3 for w in words
    ), words
    # the label is beside the worst point, as map k projects it
    px, py = map_points(res, lay, k, res.V_registered[v][None])[0]
    gap = math.hypot(max(x0 - px, 0, px - x1), max(y0 - py, 0, py - y1))
    assert 2.0 < gap < 70.0, gap
    # the raster: a dark dot on the point and a leader line from it toward the label
    img, pt_to_px = _raster(o.pdf, tmp_path / "callout", dpi=150)
    lx0, lx1 = x0 - 14.0, x1 + 1.0  # the label: the number's circle and the value
    cx, cy = 0.5 * (lx0 + lx1), 0.5 * (y0 + y1)
    assert _dark_near(img, *pt_to_px(px, py), 2), "no dot on the worst point"
    along = [
        (px + t * (cx - px), py + t * (cy - py))
        for t in np.linspace(0.0, 1.0, 41)[1:]
        if math.hypot(t * (cx - px), t * (cy - py)) > 3.0
    ]
    along = [(x, y) for x, y in along if not (lx0 - 2 < x < lx1 + 2 and y0 - 3 < y < y1 + 3)]
    assert len(along) >= 3, along
    dark = [_dark_near(img, *pt_to_px(x, y), 1) for x, y in along]
    assert np.mean(dark) > 0.9, dark


def test_points_of_interest_on_the_passing_shell(reports):
    """The passing shell has no region and no region callout, but its largest proud and
    largest sunk deviation called out (``max``/``min``, the statistics' values, at the
    vertices where they are); no more than MAX_PER_VIEW values on any map."""
    o = reports["pass"]
    res = o.res
    assert not res.acceptance.regions
    lay = plan_layout(res, o.prov)
    words = _map_words(o.pdf, lay)
    values = [(w[0], w[1]) for w in words if SIGNED.match(w[1])]
    q = read_results(o.qif)
    dev = res.deviation
    want = {
        "max": fmt_smm(dev[np.nanargmax(dev)]),
        "min": fmt_smm(dev[np.nanargmin(dev)]),
    }
    assert want == {"max": fmt_smm(q.stats.max_pos), "min": fmt_smm(q.stats.min_neg)}
    assert want["max"].startswith("+") and want["min"].startswith("-")
    assert sorted(t for _, t in values) == sorted(want.values()), values
    for tag, value in want.items():  # the tag right before its value
        (k, _, x0, y0, x1, y1), *rest = [w for w in words if w[1] == value]
        assert not rest
        assert any(w[0] == k and w[1] == tag and 0 <= x0 - w[4] < 5 for w in words), tag
    assert not any(w[1].isdigit() and int(w[1]) < 10 for w in words)  # no region number


def test_label_placer_keeps_labels_apart():
    """Many labels around crowded points: each placed label inside the picture, none over
    another, over a named point or over another label's leader, and no leader through
    another label (segments checked by sampling, not by the placer's own test)."""
    from qifreport.reports.callouts import LabelPlacer
    from qifreport.reports.kit import Box

    rng = np.random.default_rng(3)
    box = Box(50.0, 60.0, 300.0, 200.0)
    pts = np.c_[rng.uniform(80, 320, 40), rng.uniform(90, 230, 40)]
    placer = LabelPlacer(box, [tuple(p) for p in pts])
    rects, leaders = [], []
    for (ax, ay), w in zip(pts, rng.uniform(10, 40, len(pts)), strict=True):
        spot = placer.place(ax, ay, w, 10.0, extent=rng.uniform(0, 20))
        if spot is not None:
            px, py = spot
            rects.append((px - w / 2, py - 5.0, px + w / 2, py + 5.0))
            leaders.append((ax, ay, px, py))
    assert len(rects) >= 15, len(rects)

    def inside(x, y, r, pad=0.0):
        return r[0] - pad < x < r[2] + pad and r[1] - pad < y < r[3] + pad

    for i, r in enumerate(rects):
        assert box.x <= r[0] and r[2] <= box.x + box.w and box.y <= r[1] and r[3] <= box.top
        assert not any(inside(x, y, r) for x, y in pts)
        for j, (ax, ay, px, py) in enumerate(leaders):
            if i == j:
                continue
            q = rects[j]
            assert q[2] <= r[0] or r[2] <= q[0] or q[3] <= r[1] or r[3] <= q[1], (r, q)
            ts = np.linspace(0, 1, 200)
            xs, ys = ax + ts * (px - ax), ay + ts * (py - ay)
            own = [inside(x, y, rects[j]) for x, y in zip(xs, ys, strict=True)]
            hits = [inside(x, y, r) for x, y, o in zip(xs, ys, own, strict=True) if not o]
            assert not any(hits), (i, j)


def _raster(pdf: Path, stem: Path, dpi: int):
    """The page at ``dpi`` as an (h, w, 3) int array, and the map from page points (y up)
    to its pixels."""
    from PIL import Image

    subprocess.run(
        [_tool("pdftoppm"), "-r", str(dpi), "-png", "-singlefile", str(pdf), str(stem)],
        check=True,
    )
    img = np.asarray(Image.open(f"{stem}.png").convert("RGB")).astype(int)
    H = _words(pdf)[1]
    s = dpi / 72.0
    return img, lambda x, y: (x * s, (H - y) * s)


def _dark_near(img: np.ndarray, x: float, y: float, r: int) -> bool:
    """Whether a dark (ink) pixel lies within ``r`` pixels of ``(x, y)``."""
    ix, iy = int(round(x)), int(round(y))
    patch = img[max(iy - r, 0) : iy + r + 1, max(ix - r, 0) : ix + r + 1].reshape(-1, 3)
    return bool((patch.max(axis=1) < 90).any())


def test_write_time(reports):
    """Layout + rendering + writing of a 16k-triangle shell takes well under the 5 s that
    the 100k-triangle benchmark (bench/pdf.py) must meet."""
    t = reports["fail"].timings
    assert sum(t.values()) < 5.0, t


# ---------------------------------------------------------------------------- rendering


def test_colours_and_scale():
    from qifreport.reports.render import (
        BLUE_DARK,
        GREY,
        RED_DARK,
        color_scale,
        deviation_colors,
        nice_ceil,
    )

    dev = np.array([0.0, 0.2, -0.2, 0.6, -0.6, 5.0, -5.0, np.nan])
    col = deviation_colors(dev, -0.3, 0.3, 1.0)
    for k in (0, 1, 2):
        assert col[k, 1] > col[k, 0] and col[k, 1] > col[k, 2]  # green inside
    assert col[3, 0] > col[3, 1] + 0.2 and col[3, 0] > col[3, 2] + 0.2  # red: proud
    assert col[4, 2] > col[4, 0] + 0.2  # blue: sunk
    assert np.allclose(col[5], RED_DARK) and np.allclose(col[6], BLUE_DARK)  # saturated
    assert np.allclose(col[7], GREY)
    # the sign shows inside the band: the proud side is yellower than the sunk side
    assert col[1, 0] > col[2, 0]
    assert [nice_ceil(x) for x in (0.7, 1.0, 1.3, 2.2, 7.0, 0.031)] == [
        0.8,
        1.0,
        1.5,
        2.5,
        8.0,
        0.04,
    ]
    S = color_scale(np.array([0.01, -0.02]), np.full(2, -0.5), np.full(2, 0.5))
    assert S == 0.8  # 1.5 x the band: the band keeps a readable share of the bar


@pytest.mark.parametrize("backend", ["vtk", "matplotlib"])
def test_render_views_shows_the_region(results, backend):
    from qifreport.reports.render import render_views

    res = results["fail"][0]
    b = res.bands
    views = render_views(
        res.V_registered,
        res.F,
        res.deviation,
        b.lower,
        b.upper,
        res.acceptance.regions,
        size=[(300, 200), (160, 120), (160, 120)],
        backend=backend,
    )
    assert 2 <= len(views) <= 3
    assert views[0].name == "top (+z)"
    for v, size in zip(views, [(300, 200), (160, 120), (160, 120)], strict=False):
        assert v.image.shape == (size[1], size[0], 3) and v.image.dtype == np.uint8
        assert v.backend == backend
        px = v.image.reshape(-1, 3).astype(int)
        assert _green(px).sum() > 50 and _red(px).sum() > 3
    lab = views[0].labels
    assert [lb.number for lb in lab] == [1]
    # the anchor lies on the red region
    x, y = int(round(lab[0].x)), int(round(lab[0].y))
    patch = views[0].image[max(0, y - 2) : y + 3, max(0, x - 2) : x + 3].reshape(-1, 3).astype(int)
    assert _red(patch).any()


def test_fallback_when_vtk_cannot_render(results, monkeypatch, caplog):
    """No VTK (or no EGL): matplotlib draws the maps and a warning says so."""
    import qifreport.reports.render as render

    def broken(*args, **kwargs):
        raise RuntimeError("no EGL display")

    monkeypatch.setattr(render, "_render_vtk", broken)
    res = results["fail"][0]
    with caplog.at_level("WARNING", logger="qifreport.reports.render"):
        views = render.render_views(
            res.V_registered,
            res.F,
            res.deviation,
            res.bands.lower,
            res.bands.upper,
            res.acceptance.regions,
            size=(240, 160),
        )
    assert all(v.backend == "matplotlib" for v in views)
    assert "VTK offscreen rendering failed" in caplog.text and "no EGL display" in caplog.text
    px = views[0].image.reshape(-1, 3).astype(int)
    assert _green(px).sum() > 50 and _red(px).sum() > 3
    with pytest.raises(RuntimeError):
        render.render_views(
            res.V_registered,
            res.F,
            res.deviation,
            res.bands.lower,
            res.bands.upper,
            size=(64, 48),
            backend="vtk",
        )


# ------------------------------------------------------------------- the HTML viewer
# The same inspections as the PDF's, written as the interactive page (``--html``) and opened
# in real headless Chromium with software WebGL (tests/browser.py).

HTML_WINDOW = (1100, 700)


@pytest.fixture(scope="module")
def html_pages(tmp_path_factory, results, panel_nominal) -> dict[str, Path]:
    """name -> the HTML page of each result (the panel with its B-rep faces)."""
    from qifreport.reports.html import write_html

    d = tmp_path_factory.mktemp("html")
    pages = {}
    for name, (res, prov) in results.items():
        pages[name] = d / f"{name}.html"
        face_id = panel_nominal[0].face_id if name == "panel" else None
        write_html(pages[name], res, prov, face_id=face_id)
    return pages


def _viewer_json(page: Path) -> dict:
    return _viewer_json_text(page.read_text(encoding="utf-8"))


def _viewer_json_text(text: str) -> dict:
    m = re.search(r'<script type="application/json" id="viewer-data">(.*?)</script>', text, re.S)
    return json.loads(m.group(1))


def _typed(a: dict) -> np.ndarray:
    import base64

    kinds = {"u8": "<u1", "u16": "<u2", "u32": "<u4", "i16": "<i2", "i32": "<i4", "f32": "<f4"}
    return np.frombuffer(base64.b64decode(a["data"]), dtype=kinds[a["dtype"]])


def test_html_is_one_offline_file(html_pages, results):
    """Nothing is fetched: no script or stylesheet from anywhere (every script inline), no
    link, no CSS import; the sample panel's page is far below 5 MB; the verdict is there."""
    for name, page in html_pages.items():
        text = page.read_text(encoding="utf-8")
        size = page.stat().st_size
        print(f"{name}: {size / 1e6:.2f} MB")
        assert size < (5e6 if name == "panel" else 2e6), (name, size)
        scripts = re.findall(r"<script\b[^>]*>", text, re.I)
        assert len(scripts) == 3 and not [s for s in scripts if "src" in s.lower()], scripts
        assert not re.search(r"<link\b", text, re.I)
        assert not re.search(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", text, re.I)
        assert not re.search(r"""url\(\s*["']?\s*(?:https?:)?//|@import""", text, re.I)
        assert "Three.js Authors" in text and "SPDX-License-Identifier: MIT" in text
        res = results[name][0]
        assert '<div class="verdict" style="background:' in text
        assert f">{res.verdict}</div>" in text


def test_html_escapes_what_the_files_name(results):
    """A part or file name is text on the page, never markup: no script can come in."""
    from qifreport.reports.html import html_page

    res, prov = results["fail"]
    evil = '</script><script>alert(1)</script><img src="http://x/y.png">&amp;'
    page = html_page(res, dataclasses.replace(prov, part_name=evil, scan_path=evil))
    assert "alert(1)" in page  # as text ...
    assert "<script>alert" not in page and "<img" not in page  # ... never as markup
    assert len(re.findall(r"<script\b", page)) == 3
    assert _viewer_json_text(page)["part"] == evil


def test_html_data_are_the_pdf_map(html_pages, results):
    """The page carries the PDF's map: the same deviations (float32), the PDF's colours under
    each vertex's band, every triangle in a zone's group, the regions numbered in the PDF's
    order, positions within half a quantisation step."""
    from qifreport.reports.render import GREY

    for name, page in html_pages.items():
        res = results[name][0]
        d = _viewer_json(page)
        V = np.asarray(res.V_registered)
        q = _typed(d["positions"]).reshape(-1, 3)
        X = np.asarray(d["frame"]["origin"]) + q * np.asarray(d["frame"]["step"])
        assert np.all(np.abs(X - V) <= 0.51 * np.asarray(d["frame"]["step"]))
        dev = _typed(d["deviation"])
        np.testing.assert_array_equal(dev, res.deviation.astype(np.float32))
        rgb = _typed(d["colors"]).reshape(-1, 3).astype(int)
        lo, hi = res.bands.lower, res.bands.upper
        nan = ~np.isfinite(res.deviation)
        assert np.all(rgb[nan] == np.round(np.asarray(GREY) * 255).astype(int))
        with np.errstate(invalid="ignore"):
            inside, proud = (res.deviation >= lo) & (res.deviation <= hi), res.deviation > hi
        r, g, b = rgb.T
        assert np.all(g[inside] > r[inside]) and np.all(r[proud] > g[proud] + 50)
        assert (proud.any() or name == "pass") and not (name == "pass" and proud.any())
        gov = _typed(d["governing"])
        np.testing.assert_array_equal(gov, res.bands.governing)
        tris = np.concatenate([_typed(z["index"]).reshape(-1, 3) for z in d["zones"]])
        assert _triangle_set(tris) == _triangle_set(res.F)
        assert [z["key"] for z in d["zones"]] == [z.key for z in res.bands.zones]
        regs = res.acceptance.regions
        assert [r["number"] for r in d["regions"]] == list(range(1, len(regs) + 1))
        for r, want in zip(d["regions"], regs, strict=True):
            assert r["area"] == want.area and r["peak"] == want.peak
            np.testing.assert_array_equal(_typed(r["vertices"]), np.asarray(want.vertices))
        assert d["points"]["shown"] == min(len(res.P), 20_000)


def _triangle_set(T: np.ndarray) -> set:
    return set(map(tuple, np.sort(np.asarray(T), axis=1).tolist()))


def _map_pixels(img: np.ndarray) -> np.ndarray:
    """The map of a page screenshot (right of the side panel)."""
    from qifreport.reports.html import PANEL_WIDTH_PX

    return img[:, PANEL_WIDTH_PX + 2 :]


def _part_mask(img: np.ndarray) -> np.ndarray:
    """The scored part's pixels: green, red or blue (the grey of the unscored rim is left
    out: the anti-aliased text and axes of the PDF's map are grey too)."""
    px = img.reshape(-1, 3)
    return (_green(px) | _red(px) | _blue(px)).reshape(img.shape[:2])


def _red_in_part(img: np.ndarray) -> tuple[float, np.ndarray]:
    """The red share of the part's pixels, and the red pixels' centroid as fractions of the
    part's bounding box (x right, y down)."""
    part = _part_mask(img)
    red = _red(img.reshape(-1, 3)).reshape(img.shape[:2])
    ys, xs = np.nonzero(part)
    ry, rx = np.nonzero(red)
    if len(rx) == 0:
        return 0.0, np.full(2, np.nan)
    frac = np.array([(rx.mean() - xs.min()) / np.ptp(xs), (ry.mean() - ys.min()) / np.ptp(ys)])
    return len(rx) / part.sum(), frac


def test_html_map_in_chromium(html_pages, reports, tmp_path):
    """Real Chromium draws the pages with WebGL: the failing shell green and red, the red
    region as large a share of the part and in the same place as on the PDF's map A (the
    page opens in the PDF's first view); the passing shell green, no red, no blue."""
    from PIL import Image

    from tests.browser import screenshot

    fail = _map_pixels(screenshot(html_pages["fail"], tmp_path / "fail.png", HTML_WINDOW))
    Image.fromarray(fail.astype(np.uint8)).save(tmp_path / "fail_map.png")
    px = fail.reshape(-1, 3)
    assert _green(px).sum() > 20_000, _green(px).sum()
    share, where = _red_in_part(fail)
    o = reports["fail"]
    lay = plan_layout(o.res, o.prov)
    box = lay.maps[0]
    pdf = np.asarray(Image.open(o.png).convert("RGB")).astype(int)
    s = DPI / 72.0
    pdf_map = pdf[
        int(np.ceil((lay.height - box.top) * s)) + 2 : int(np.floor((lay.height - box.y) * s)) - 2,
        int(np.ceil(box.x * s)) + 2 : int(np.floor((box.x + box.w) * s)) - 2,
    ]
    pdf_share, pdf_where = _red_in_part(pdf_map)
    print(f"red share {share:.4f} (PDF {pdf_share:.4f}) at {where} (PDF {pdf_where})")
    assert 0.002 < share < 0.05
    assert 0.5 < share / pdf_share < 2.0
    assert np.all(np.abs(where - pdf_where) < 0.03), (where, pdf_where)
    ok = _map_pixels(screenshot(html_pages["pass"], tmp_path / "pass.png", HTML_WINDOW))
    px = ok.reshape(-1, 3)
    assert _green(px).sum() > 20_000
    assert _red(px).sum() == 0 and _blue(px).sum() == 0, (_red(px).sum(), _blue(px).sum())


def _readout(dom: str) -> tuple[dict, str]:
    m = re.search(r'<div id="readout"([^>]*)>(.*?)</div><div id="msg"', dom, re.S)
    assert m, "no readout in the page"
    attrs = dict(re.findall(r'data-([a-z]+)="([^"]*)"', m.group(1)))
    return attrs, re.sub(r"<[^>]+>", " ", m.group(2))


def test_html_readout_in_chromium(html_pages, results, panel_nominal):
    """Picking the part (``#at=X,Y,Z``) reads out the vertex's own deviation, tolerance,
    region and B-rep face: on the failing shell's region 1 (its centroid, as the PDF prints
    it) the readout is region 1, out of tolerance, proud; on the panel's face the face and its
    STEP id."""
    from tests.browser import dump_dom

    res = results["fail"][0]
    reg = res.acceptance.regions[0]
    c = reg.centroid
    dom = dump_dom(html_pages["fail"], HTML_WINDOW, f"#at={c[0]:.3f},{c[1]:.3f},{c[2]:.3f}")
    assert 'data-status="drawn"' in dom
    attrs, text = _readout(dom)
    v = int(attrs["vertex"])
    assert float(attrs["deviation"]) == pytest.approx(float(res.deviation[v]), rel=1e-6)
    assert res.deviation[v] > res.bands.upper[v]
    assert attrs["region"] == "1" and v in set(reg.vertices.tolist())
    assert attrs["zone"] == res.bands.zones[res.bands.governing[v]].key == "general"
    assert "out of tolerance: proud" in text and re.search(r"region\s+1 \(", text)
    assert np.linalg.norm(res.V_registered[v, :2] - c[:2]) < 3.0  # picked where asked
    # the panel: the highest vertex inside one face, as seen from view A
    res, prov = results["panel"]
    page = html_pages["panel"]
    d = np.asarray(_viewer_json(page)["views"][0]["direction"])
    fid = panel_nominal[0].face_id
    F = np.asarray(res.F)
    n = len(res.V)
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1)
    np.minimum.at(lo, F.ravel(), np.repeat(fid, 3))
    np.maximum.at(hi, F.ravel(), np.repeat(fid, 3))
    inner = (lo == hi) & np.isfinite(res.deviation)
    height = np.where(inner, res.V_registered @ d, -np.inf)
    top = int(np.argmax(height))
    p = res.V_registered[top]
    dom = dump_dom(page, HTML_WINDOW, f"#at={p[0]:.4f},{p[1]:.4f},{p[2]:.4f}")
    attrs, text = _readout(dom)
    v = int(attrs["vertex"])
    assert attrs["face"] == str(lo[top]), (attrs, lo[top])
    assert f"B-rep face {lo[top]} (STEP #{prov.face_step_ids[lo[top]]})" in text
    assert float(attrs["deviation"]) == pytest.approx(float(res.deviation[v]), rel=1e-6)
    assert attrs["zone"] == res.bands.zones[res.bands.governing[v]].key
    assert attrs["zone"] in text and "in tolerance" in text


def test_notes_are_cut_to_the_room_above_the_sign_off():
    """Notes that do not fit (a part NOT MEASURED for many reasons: on the fandisk of the
    speed benchmark they ran 31 pt into the sign-off line) are cut to two lines each, then
    left out from the end, not-warnings first, and the cut is stated."""
    from qifreport.reports.notes import fit_notes, notes_height

    words = "the scan left an unmeasured patch of 1909.7 mm2 larger than the limit " * 4
    notes = [(f"Note {i}: {words}", i % 2 == 0) for i in range(12)]
    width = 500.0
    assert fit_notes(notes, width, 1e4) == notes  # room enough: untouched
    two = fit_notes(notes, width, notes_height(notes, width) - 10)
    assert len(two) == 12 and notes_height(two, width) <= notes_height(notes, width) - 10
    assert all(t.endswith("\u2026") for t, _ in two)
    cut = fit_notes(notes, width, 80.0)
    assert notes_height(cut, width) <= 80.0
    kept, last = cut[:-1], cut[-1][0]
    n = int(re.search(r"\+ (\d+) more notes?", last).group(1))
    assert n == 12 - len(kept) and n > 0
    assert all(w for _, w in kept)  # the warnings outlast the other notes
    assert [t.split(":")[0] for t, _ in kept] == sorted(
        (t.split(":")[0] for t, _ in kept), key=lambda s: int(s.split()[1])
    )  # in their order
