"""The one-page trend report of a batch (:mod:`qifreport.reports.trend`): complete, one page,
legible.

A synthetic batch summary (the frame ``qifreport batch`` writes) is drawn; the PDF is checked
with poppler-utils: ``pdfinfo`` (one page, its size), ``pdftotext`` (the counts, the pass rate
and the statistics as computed here from the frame, the tolerance labels) and ``pdftoppm``
(the points are at their place in their colour, the tolerance line is a horizontal line at
the tolerance, the errored scans are marked). Long (2000 scans), short (3 scans) and wide
(8 characteristics) batches must still give one page.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from qifreport.reports.kit import fmt_mm
from qifreport.reports.trend import (
    MAX_CHARTS,
    ChartGeometry,
    TrendCharacteristic,
    TrendLayout,
    plan_trend,
    seq_ticks,
    write_trend_pdf,
)
from tests.consumers import poppler_tool as _tool

DPI = 100
CREATED = datetime(2025, 3, 4, 5, 6, 7, tzinfo=timezone.utc)
SHA = "0123456789abcdef" + "f" * 48
CHARS = [
    TrendCharacteristic("T1", "surface profile 1 mm |A|B|C| [-0.5, +0.5] (pmi #1444)", 1.0),
    TrendCharacteristic("general", "general profile tolerance 0.6 mm", 0.6),
]


def batch_frame(
    n: int,
    chars: list[TrendCharacteristic] = CHARS,
    *,
    seed: int = 0,
    fail_at: tuple[int, ...] = (),
    error_at: tuple[int, ...] = (),
    ne_at: tuple[int, ...] = (),
) -> pd.DataFrame:
    """A batch summary of ``n`` scans: profile values well inside the tolerance, except the
    scans ``fail_at`` (1-based) whose first characteristic is 1.3 to 1.6 times its tolerance
    (FAIL), the scans ``error_at`` (ERROR, no values) and ``ne_at`` (NOT ESTABLISHED)."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(1, n + 1):
        row: dict = {
            "seq": s,
            "scan": f"scan_{s:04d}.ply",
            "serial": f"SN-{1000 + s}",
            "verdict": "PASS",
            "decided_by": "",
            "error": "",
            "rms_mm": 0.05 + 0.01 * rng.random(),
            "p999_mm": 0.2,
        }
        for j, ch in enumerate(chars):
            v = ch.tolerance_mm * (0.35 + 0.25 * rng.random())
            status = "PASS"
            if s in fail_at and j == 0:
                v = ch.tolerance_mm * (1.3 + 0.3 * rng.random())
                status = "FAIL"
            if s in ne_at:
                status = "NOT ESTABLISHED"
            row[f"profile_{ch.key}_mm"] = v
            row[f"status_{ch.key}"] = status
        if s in fail_at:
            row["verdict"] = "FAIL"
            row["decided_by"] = (
                f"{chars[0].key}: region criterion, a region of 41.2 mm^2 exceeds 25 mm^2"
            )
        if s in ne_at:
            row["verdict"] = "NOT ESTABLISHED"
            row["decided_by"] = "registration not trusted: the pose search is ambiguous"
        if s in error_at:
            row.update(
                verdict="ERROR",
                error="ValueError: scan has no points inside the bounding box of the nominal",
                rms_mm=np.nan,
                p999_mm=np.nan,
            )
            for ch in chars:
                row[f"profile_{ch.key}_mm"] = np.nan
                row[f"status_{ch.key}"] = ""
        rows.append(row)
    return pd.DataFrame(rows)


@dataclass
class Out:
    lay: TrendLayout
    text: str  # pdftotext -layout
    img: np.ndarray  # RGB 0..1 at DPI
    info: dict  # pdfinfo fields
    pdf: Path


def _render(
    d: Path, name: str, df: pd.DataFrame, chars=CHARS, page: str = "A4", part: str = "bracket-7731"
) -> Out:
    """Write the trend report, read its text and rasterize it."""
    pdf = d / f"{name}.pdf"
    write_trend_pdf(pdf, df, chars, part_name=part, created=CREATED, nominal_sha256=SHA, page=page)
    lay = plan_trend(df, chars, part_name=part, created=CREATED, nominal_sha256=SHA, page=page)
    info = subprocess.run(
        [_tool("pdfinfo"), str(pdf)], check=True, capture_output=True, text=True
    ).stdout
    fields = dict(line.split(":", 1) for line in info.splitlines() if ":" in line)
    fields = {k.strip(): v.strip() for k, v in fields.items()}
    text = subprocess.run(
        [_tool("pdftotext"), "-layout", str(pdf), "-"], check=True, capture_output=True, text=True
    ).stdout
    subprocess.run(
        [_tool("pdftoppm"), "-r", str(DPI), "-png", "-singlefile", str(pdf), str(d / name)],
        check=True,
    )
    img = np.asarray(Image.open(d / f"{name}.png").convert("RGB"), dtype=float) / 255.0
    return Out(lay, text, img, fields, pdf)


def _words(pdf: Path, height: float) -> list[tuple[str, float, float]]:
    """Every word of the page with the centre of its box (page points, origin bottom-left)."""
    html = subprocess.run(
        [_tool("pdftotext"), "-bbox", str(pdf), "-"], check=True, capture_output=True, text=True
    ).stdout
    out = []
    for m in re.finditer(
        r'<word xMin="([\d.]+)" yMin="([\d.]+)" xMax="([\d.]+)" '
        r'yMax="([\d.]+)">([^<]*)</word>',
        html,
    ):
        x0, y0, x1, y1 = (float(m.group(k)) for k in range(1, 5))
        out.append((m.group(5), (x0 + x1) / 2, height - (y0 + y1) / 2))
    return out


def _px(lay: TrendLayout, x: float, y: float) -> tuple[int, int]:
    """Pixel (row, column) of page point (x, y) (origin bottom-left)."""
    k = DPI / 72.0
    return int(round((lay.height - y) * k)), int(round(x * k))


def _patch(img: np.ndarray, rc: tuple[int, int], r: int = 1) -> np.ndarray:
    i, j = rc
    return img[i - r : i + r + 1, j - r : j + r + 1].reshape(-1, 3)


def _is_red(p: np.ndarray) -> np.ndarray:
    return (p[..., 0] > 0.55) & (p[..., 0] - np.maximum(p[..., 1], p[..., 2]) > 0.35)


def _is_green(p: np.ndarray) -> np.ndarray:
    return (p[..., 1] > 0.5) & (p[..., 1] - np.maximum(p[..., 0], p[..., 2]) > 0.2)


def _is_grey(p: np.ndarray) -> np.ndarray:
    return (np.ptp(p, axis=-1) < 0.06) & (p.mean(axis=-1) < 0.8) & (p.mean(axis=-1) > 0.3)


N = 25
FAILS, ERRORS, NES = (6, 13, 21), (17,), (9,)


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    df = batch_frame(N, fail_at=FAILS, error_at=ERRORS, ne_at=NES)
    d = tmp_path_factory.mktemp("trend")
    return df, _render(d, "batch", df)


def test_one_page_and_header_numbers(batch):
    df, out = batch
    text, info = out.text, out.info
    assert info["Pages"] == "1"
    w, h = (float(v) for v in re.findall(r"[\d.]+", info["Page size"])[:2])
    assert (round(w), round(h)) == (595, 842)
    assert "bracket-7731" in text
    assert SHA[:16] in text and SHA[:17] not in text
    assert "2025-03-04 05:06:07 UTC" in text
    counts = df["verdict"].value_counts()
    n_pass, n_fail = int(counts.get("PASS", 0)), int(counts.get("FAIL", 0))
    n_ne, n_err = int(counts.get("NOT ESTABLISHED", 0)), int(counts.get("ERROR", 0))
    assert (n_pass, n_fail, n_ne, n_err) == (20, 3, 1, 1)
    for word, k in (
        ("PASS", n_pass),
        ("FAIL", n_fail),
        ("NOT ESTABLISHED", n_ne),
        ("ERROR", n_err),
    ):
        assert re.search(rf"\b{word} {k}\b", text), word
    judged = n_pass + n_fail + n_ne
    rate = 100.0 * n_pass / judged
    assert f"{rate:.1f} %" in text  # 83.3 %: the errored scan is not counted
    assert f"{n_pass} PASS of {judged} scans with a verdict" in text
    assert f"{n_err} errored" in text
    assert re.search(rf"\b{N}\b \(sequence 1 to {N}\)", text)


def test_chart_statistics_and_labels(batch):
    df, out = batch
    lay, text = out.lay, out.text
    assert [g.key for g in lay.charts] == ["T1", "general"] and not lay.omitted
    for ch in CHARS:
        v = df[f"profile_{ch.key}_mm"].to_numpy(float)
        v = v[np.isfinite(v)]
        mean, sigma = v.mean(), v.std(ddof=1)
        cpk = (ch.tolerance_mm - mean) / (3 * sigma)
        # a capability index from 25 values, with its 95 % interval (Bissell)
        half = 1.96 * np.sqrt(1 / (9 * len(v)) + cpk**2 / (2 * (len(v) - 1)))
        shown = (
            f"Cpk {cpk:.2f} [{cpk - half:.2f}, {cpk + half:.2f}]" if len(v) >= 25 else "Cpk: n < 25"
        )
        n_pass = int((df[f"status_{ch.key}"] == "PASS").sum())
        n_judged = int(df[f"status_{ch.key}"].isin(["PASS", "FAIL", "NOT ESTABLISHED"]).sum())
        line = (
            f"n {len(v)}   mean {fmt_mm(mean)}   \u03c3 {fmt_mm(sigma)}   max "
            f"{fmt_mm(v.max())} mm   {shown}   PASS {n_pass} of {n_judged}"
        )
        assert " ".join(line.split()) in " ".join(text.split()), line
        assert ch.key in text and ch.description[:30] in text
    # the tolerance labels beside their lines
    assert len(re.findall(r"\btol\b", text)) >= 2
    for ch in CHARS:
        assert fmt_mm(ch.tolerance_mm) in text
    # the table of the scans that did not pass, with their reasons
    assert "Scans that did not pass (5" in text
    for s in FAILS + ERRORS + NES:
        assert f"SN-{1000 + s}" in text
    assert "region criterion" in text and "ValueError" in text


def test_points_colours_and_tolerance_line(batch):
    df, out = batch
    lay, img = out.lay, out.img
    geo: ChartGeometry = lay.charts[0]  # T1: three values above the tolerance
    tol = CHARS[0].tolerance_mm
    v = df["profile_T1_mm"].to_numpy(float)
    red = green = 0
    for s in range(1, N + 1):
        if not np.isfinite(v[s - 1]):
            continue
        p = _patch(img, _px(lay, float(geo.x(s)), float(geo.y(v[s - 1]))))
        if s in FAILS:
            assert v[s - 1] > tol and _is_red(p).sum() >= 5, s
            red += 1
        elif s in NES:
            assert _is_grey(p).sum() >= 5 and not _is_green(p).any(), s
        else:
            assert _is_green(p).sum() >= 5 and not _is_red(p).any(), s
            green += 1
    assert red == len(FAILS) and green == N - len(FAILS) - len(ERRORS) - len(NES)
    # no red point below the tolerance line: the passing points are green, not red
    k = DPI / 72.0
    top_row = _px(lay, 0, float(geo.y(tol)))[0] + 3
    bottom_row = _px(lay, 0, geo.plot.y)[0] - 1
    c0, c1 = int(geo.plot.x * k) + 2, int((geo.plot.x + geo.plot.w) * k) - 2
    assert not _is_red(img[top_row:bottom_row, c0:c1]).any()
    # the tolerance line: a horizontal run of its colour across the plot, at the tolerance
    row = _px(lay, 0, float(geo.y(tol)))[0]
    band = img[row - 2 : row + 3, c0:c1]
    runs = _is_red(band).mean(axis=1)
    assert runs.max() > 0.9, runs
    # ... and nowhere else in the plot so long (no such line at the wrong height)
    rows = _is_red(img[_px(lay, 0, geo.plot.top)[0] + 2 : bottom_row, c0:c1]).mean(axis=1)
    assert np.flatnonzero(rows > 0.9).size <= 3
    # the errored scan: a grey cross in the strip below zero, no point above it
    for s in ERRORS:
        x = float(geo.x(s))
        cross = _patch(img, _px(lay, x, geo.plot.y + 3.5), 2)
        assert (cross.mean(axis=1) < 0.7).sum() >= 3
        column = img[
            _px(lay, 0, geo.y_low + 3)[0] : _px(lay, 0, geo.plot.top - 2)[0], _px(lay, x, 0)[1]
        ]
        assert not (_is_green(column).any() or _is_red(column).any())


def test_axes_match_the_geometry(batch):
    """The printed tick and tolerance labels sit where the points are drawn from: the page
    reads the values the frame holds."""
    df, out = batch
    lay = out.lay
    words = _words(out.pdf, lay.height)
    for geo, ch in zip(lay.charts, CHARS, strict=True):
        pa = geo.plot
        yticks = [
            (float(w), y)
            for w, x, y in words
            if re.fullmatch(r"\d+\.\d+", w) and pa.x - 25 < x < pa.x and pa.y - 2 < y < pa.top + 2
        ]
        assert len(yticks) >= 3, ch.key
        for v, y in yticks:
            assert abs(y - float(geo.y(v))) < 2.0, (ch.key, v)
        # the ticks name the scans' serial numbers (SN-1000 + sequence here)
        xticks = [
            (int(w[3:]) - 1000, x)
            for w, x, y in words
            if re.fullmatch(r"SN-\d+", w)
            and pa.x - 5 < x < pa.x + pa.w + 5
            and pa.y - 10 < y < pa.y
        ]
        assert [t for t, _ in xticks] == [1, 5, 10, 15, 20, 25]
        for t, x in xticks:
            assert abs(x - float(geo.x(t))) < 1.0
        # the tolerance label right of the frame, at the line
        label = [
            (x, y)
            for w, x, y in words
            if w == fmt_mm(ch.tolerance_mm)
            and pa.x + pa.w < x < pa.x + pa.w + 30
            and pa.y < y < pa.top
        ]
        assert len(label) == 1 and abs(label[0][1] - float(geo.y(ch.tolerance_mm))) < 6.0
    # the final cumulative pass rate printed at the end of its curve
    geo = lay.pass_rate
    v = df["verdict"]
    rate = 100.0 * (v == "PASS").sum() / v.isin(["PASS", "FAIL", "NOT ESTABLISHED"]).sum()
    end = [
        (x, y)
        for w, x, y in words
        if w == f"{rate:.1f}"
        and geo.plot.x + geo.plot.w < x < geo.plot.x + geo.plot.w + 20
        and geo.plot.y < y < geo.plot.top
    ]
    assert len(end) == 1 and abs(end[0][1] - float(geo.y(rate))) < 2.0


def test_pass_rate_chart_ends_at_the_pass_rate(batch):
    df, out = batch
    lay, img = out.lay, out.img
    geo = lay.pass_rate
    v = df["verdict"].to_numpy()
    judged = np.isin(v, ["PASS", "FAIL", "NOT ESTABLISHED"])
    rate = 100.0 * np.cumsum(v == "PASS") / np.maximum(np.cumsum(judged), 1)
    for s in (1, 12, N):  # the cumulative curve passes through its values (dark ink)
        p = _patch(img, _px(lay, float(geo.x(s)), float(geo.y(rate[s - 1]))), 1)
        assert (p.mean(axis=1) < 0.45).sum() >= 2, s
    # the failures marked red along the bottom
    for s in FAILS:
        p = _patch(img, _px(lay, float(geo.x(s)), geo.plot.y + 3.5), 1)
        assert _is_red(p).any(), s


def test_letter_page(tmp_path):
    df = batch_frame(12, fail_at=(3,))
    out = _render(tmp_path, "letter", df, page="Letter")
    lay, text, info = out.lay, out.text, out.info
    assert info["Pages"] == "1"
    assert [round(float(x)) for x in re.findall(r"[\d.]+", info["Page size"])[:2]] == [612, 792]
    assert f"{100 * 11 / 12:.1f} %" in text
    assert lay.failures.y > 30


def test_long_batch(tmp_path):
    """2000 scans: one page, sensible ticks, no point labels (its speed: bench/io_speed.py)."""
    n = 2000
    fails = tuple(range(37, n, 97))
    df = batch_frame(n, fail_at=fails, error_at=(5, 1500), ne_at=(700,), seed=3)
    out = _render(tmp_path, "long", df)
    lay, text, img, info = out.lay, out.text, out.img, out.info
    assert info["Pages"] == "1"
    rate = 100.0 * (n - len(fails) - 3) / (n - 2)
    assert f"{rate:.1f} %" in text
    assert f"+{len(fails) + 3 - 7} more" in text  # the table is cut to 8 rows
    for geo in (lay.charts[0], lay.pass_rate):  # labels neither crowded nor sparse
        ticks = seq_ticks(n, geo.plot.w)
        assert 3 <= len(ticks) <= 15 and ticks[0] == 1 and ticks[-1] == n
        assert np.diff(geo.x(np.array(ticks))).min() >= 30.0
        assert all(re.search(rf"\bSN-{1000 + t}\b", text) for t in ticks)  # serial numbers
    # no number for every scan: the text stays short
    assert len(re.findall(r"\d+", text)) < 300
    # failing points (1.3 to 1.6 times the tolerance) are red above the tolerance line
    geo = lay.charts[0]
    above = img[
        _px(lay, 0, geo.plot.top)[0] + 1 : _px(lay, 0, float(geo.y(1.25)))[0],
        int(geo.plot.x * DPI / 72) + 1 : int((geo.plot.x + geo.plot.w) * DPI / 72) - 1,
    ]
    assert _is_red(above).sum() >= len(fails)


def test_three_scans(tmp_path):
    df = batch_frame(3, fail_at=(2,))
    out = _render(tmp_path, "three", df)
    lay, text, img, info = out.lay, out.text, out.img, out.info
    assert info["Pages"] == "1"
    assert seq_ticks(3, lay.charts[0].plot.w) == [1, 2, 3]
    assert re.search(r"\bSN-1001\s+SN-1002\s+SN-1003\b", text)  # each scan's serial number
    assert "50.0 %" not in text and f"{100 * 2 / 3:.1f} %" in text
    geo = lay.charts[0]
    v = df["profile_T1_mm"].to_numpy(float)
    assert _is_red(_patch(img, _px(lay, float(geo.x(2)), float(geo.y(v[1]))))).sum() >= 5
    assert _is_green(_patch(img, _px(lay, float(geo.x(3)), float(geo.y(v[2]))))).sum() >= 5


def test_many_characteristics_shows_the_smallest_margins(tmp_path):
    chars = [
        TrendCharacteristic(f"T{k}", f"surface profile {0.2 * k:g} mm", 0.2 * k)
        for k in range(1, 9)
    ]
    df = batch_frame(15, chars, seed=5)
    # T7 and T3 close to their tolerance: they must be charted
    df.loc[4, "profile_T7_mm"] = 0.99 * 1.4
    df.loc[6, "profile_T3_mm"] = 0.98 * 0.6
    df.loc[2, "profile_T5_mm"] = 0.97 * 1.0
    out = _render(tmp_path, "wide", df, chars)
    lay, text, info = out.lay, out.text, out.info
    assert info["Pages"] == "1"
    shown = [g.key for g in lay.charts]
    assert len(shown) == MAX_CHARTS and {"T3", "T5", "T7"} <= set(shown)
    assert shown == [c.key for c in chars if c.key in shown]  # the caller's order
    assert len(lay.omitted) == 2 and set(lay.omitted).isdisjoint(shown)
    assert "+ 2 more characteristics not charted" in text
    for key in lay.omitted:
        assert key in text


def test_outlier_clipped_to_the_top(tmp_path):
    df = batch_frame(30, fail_at=(8,))
    df.loc[7, "profile_T1_mm"] = 25.0  # a wild value: the chart keeps its scale
    out = _render(tmp_path, "outlier", df)
    lay, img, info = out.lay, out.img, out.info
    assert info["Pages"] == "1"
    geo = lay.charts[0]
    assert geo.top < 5.0
    p = _patch(img, _px(lay, float(geo.x(8)), geo.plot.top - 2.5), 1)
    assert _is_red(p).any()


def test_bad_page_size(tmp_path):
    with pytest.raises(ValueError):
        write_trend_pdf(
            tmp_path / "x.pdf", batch_frame(3), CHARS, part_name="p", created=CREATED, page="A3"
        )


@pytest.mark.parametrize(
    "case", ["no scans", "all errored", "no characteristics", "no tolerance, no columns"]
)
def test_degenerate_batches_still_one_page(tmp_path, case):
    chars = CHARS
    if case == "no scans":
        df = batch_frame(0, chars).reindex(
            columns=["seq", "scan", "serial", "verdict", "decided_by", "error"]
        )
    elif case == "all errored":
        df = batch_frame(4, error_at=(1, 2, 3, 4))
    elif case == "no characteristics":
        df, chars = batch_frame(5, fail_at=(2,)), []
    else:
        df = batch_frame(6)
        chars = [
            TrendCharacteristic("T1", "", float("nan")),
            TrendCharacteristic("zz", "not in the summary", 0.5),
        ]
    out = _render(tmp_path, "degenerate", df, chars)
    assert out.info["Pages"] == "1"
    assert [g.key for g in out.lay.charts] == [c.key for c in chars]
    if case in ("no scans", "all errored"):
        # no rate without a verdict: a dash
        assert re.search(r"\u2014\s+0 PASS of 0 scans with a verdict", out.text)
        assert not re.search(r"\d %", out.text)


# ------------------------------------------------------------------ feature characteristics
#
# The drawing's feature characteristics (issue 22) charted beside the profiles: a geometric
# tolerance one-sided like a profile (from 0 to its tolerance), a dimension two-sided (its
# lower and upper limits about its nominal), an angle in degrees, a basic dimension without
# limits or verdict.

FEATURE_CHARS = [
    CHARS[0],
    TrendCharacteristic(
        "G1", "flatness 0.2 mm (pmi #1541)", 0.2, kind="geometric", quantity="flatness"
    ),
    TrendCharacteristic(
        "D1",
        "diameter dimension 9.9 .. 10.1 mm |A| (pmi #77)",
        float("nan"),
        kind="dimension",
        lower=9.9,
        upper=10.1,
        nominal=10.0,
        quantity="diameter",
    ),
    TrendCharacteristic(
        "D2",
        "angular dimension 89.5 .. 90.5 deg (pmi #78)",
        float("nan"),
        kind="dimension",
        lower=89.5,
        upper=90.5,
        nominal=90.0,
        unit="deg",
        quantity="angle",
    ),
    TrendCharacteristic(
        "D3",
        "linear distance dimension basic (pmi #79)",
        float("nan"),
        kind="dimension",
        nominal=42.0,
        quantity="distance",
    ),
]
#: scans (1-based) where D1 is below its lower limit (FAIL) or above its upper one (FAIL)
D1_LOW, D1_HIGH = (4,), (11,)


def feature_frame(n: int = 16, seed: int = 11) -> pd.DataFrame:
    """A batch summary with the columns of ``qifreport batch`` for ``FEATURE_CHARS``:
    ``value_<key>_<unit>``, the limits, ``status_<key>``; D1 sits below the middle of its
    limits and leaves them at the scans ``D1_LOW`` and ``D1_HIGH``."""
    df = batch_frame(n, [CHARS[0]], seed=seed, error_at=(7,))
    rng = np.random.default_rng(seed)
    g1 = 0.2 * (0.2 + 0.5 * rng.random(n))
    d1 = 9.93 + 0.05 * rng.random(n)
    d1[[s - 1 for s in D1_LOW]] = 9.87
    d1[[s - 1 for s in D1_HIGH]] = 10.12
    d2 = 90.0 + 0.3 * rng.standard_normal(n)
    d3 = 42.0 + 0.02 * rng.standard_normal(n)
    df["value_G1_mm"], df["tolerance_G1_mm"], df["status_G1"] = g1, 0.2, "PASS"
    df["value_D1_mm"], df["lower_D1_mm"], df["upper_D1_mm"] = d1, 9.9, 10.1
    df["status_D1"] = np.where((d1 < 9.9) | (d1 > 10.1), "FAIL", "PASS")
    df["value_D2_deg"], df["lower_D2_deg"], df["upper_D2_deg"] = d2, 89.5, 90.5
    df["status_D2"] = np.where((d2 < 89.5) | (d2 > 90.5), "FAIL", "PASS")
    df["value_D3_mm"], df["status_D3"] = d3, "BASIC"
    failed = ((df["status_D1"] == "FAIL") | (df["status_D2"] == "FAIL")) & (
        df["verdict"] != "ERROR"
    )
    df.loc[failed, "verdict"] = "FAIL"
    df.loc[failed, "decided_by"] = "D1 or D2 beyond a limit"
    err = df["verdict"] == "ERROR"
    for col in ("value_G1_mm", "value_D1_mm", "value_D2_deg", "value_D3_mm"):
        df.loc[err, col] = np.nan
    for key in ("G1", "D1", "D2", "D3"):
        df.loc[err, f"status_{key}"] = ""
    return df


def _dimension_line(
    df: pd.DataFrame, key: str, unit: str, lo: float, hi: float, extremes: bool
) -> str:
    """The statistics line of a dimension's chart, computed here from the frame (spaces
    collapsed, as ``pdftotext`` reads them)."""
    v = df[f"value_{key}_{unit}"].to_numpy(float)
    v = v[np.isfinite(v)]
    m, s = v.mean(), v.std(ddof=1)
    n_pass = int((df[f"status_{key}"] == "PASS").sum())
    n_judged = int(df[f"status_{key}"].isin(["PASS", "FAIL", "NOT ESTABLISHED"]).sum())
    assert len(v) < 25  # a capability index is not stated from fewer values
    tail = f"Cp, Cpk: n < 25 PASS {n_pass} of {n_judged}"
    if extremes:
        return (
            f"n {len(v)} mean {fmt_mm(m)} \u03c3 {fmt_mm(s)} min {fmt_mm(v.min())} max "
            f"{fmt_mm(v.max())} {unit} {tail}"
        )
    return f"n {len(v)} mean {fmt_mm(m)} {unit} \u03c3 {fmt_mm(s)} {tail}"


def test_lone_dimension_chart(tmp_path):
    """A chart as wide as the page gives a dimension's smallest and largest values too."""
    df = feature_frame()
    out = _render(tmp_path, "lone", df, [FEATURE_CHARS[2]])
    assert [g.key for g in out.lay.charts] == ["D1"]
    line = _dimension_line(df, "D1", "mm", 9.9, 10.1, extremes=True)
    assert line in " ".join(out.text.split()), line


@pytest.fixture(scope="module")
def features(tmp_path_factory):
    df = feature_frame()
    return df, _render(tmp_path_factory.mktemp("features"), "features", df, FEATURE_CHARS)


def test_feature_charts_and_their_statistics(features):
    df, out = features
    lay, text = out.lay, out.text
    assert out.info["Pages"] == "1"
    assert [g.key for g in lay.charts] == ["T1", "G1", "D1", "D2", "D3"] and not lay.omitted
    flat = " ".join(text.split())
    assert "VALUE OF EACH CHARACTERISTIC BY SCAN" in flat
    assert "5 characteristics, values in mm, angles in degrees" in flat
    # a geometric tolerance: one-sided, as a profile
    v = df["value_G1_mm"].to_numpy(float)
    v = v[np.isfinite(v)]
    line = (
        f"n {len(v)} mean {fmt_mm(v.mean())} \u03c3 {fmt_mm(v.std(ddof=1))} max "
        f"{fmt_mm(v.max())} mm Cpk: n < 25 PASS 15 of 15"
    )
    assert line in flat, line
    # a dimension: two-sided, Cp and Cpk between its limits (its lower side decides Cpk);
    # two charts a row: no room for its extremes (test_lone_dimension_chart)
    for key, unit, lo, hi in (("D1", "mm", 9.9, 10.1), ("D2", "deg", 89.5, 90.5)):
        assert _dimension_line(df, key, unit, lo, hi, extremes=False) in flat, key
    v = df["value_D1_mm"].to_numpy(float)
    v = v[np.isfinite(v)]
    assert (v.mean() - 9.9) < (10.1 - v.mean())  # the lower side decides D1's Cpk
    v = df["value_D3_mm"].to_numpy(float)
    v = v[np.isfinite(v)]
    line = (
        f"n 15 mean {fmt_mm(v.mean())} mm \u03c3 {fmt_mm(v.std(ddof=1))} min "
        f"{fmt_mm(v.min())} max {fmt_mm(v.max())} basic, no verdict"
    )
    assert line in flat, line
    # the axis titles name the quantity and its unit
    for title in ("flatness, mm", "diameter, mm", "angle, deg", "distance, mm"):
        assert title in flat, title
    # the footer's definitions, whole
    assert "Cpk = min(USL \u2212 mean, mean \u2212 LSL) / (3\u03c3)" in flat
    assert "PASS / (PASS + FAIL + NOT ESTABLISHED)." in flat


def test_dimension_chart_limits_and_points(features):
    """Both limits of a dimension are red lines at their values around the nominal, labelled
    beside them; each value is a point at its height, red where beyond a limit, green
    within; a basic dimension's points are dark (no verdict)."""
    df, out = features
    lay, img = out.lay, out.img
    geo = next(g for g in lay.charts if g.key == "D1")
    assert geo.bottom < 9.87 and geo.top > 10.12  # the values beyond the limits are on scale
    k = DPI / 72.0
    c0, c1 = int(geo.plot.x * k) + 2, int((geo.plot.x + geo.plot.w) * k) - 2
    red_rows = []
    for limit in (9.9, 10.1):
        row = _px(lay, 0, float(geo.y(limit)))[0]
        runs = _is_red(img[row - 2 : row + 3, c0:c1]).mean(axis=1)
        assert runs.max() > 0.9, (limit, runs)
        red_rows.append(row)
    # no other long red line in the plot (the nominal and the mean are not red)
    rows = _is_red(img[_px(lay, 0, geo.plot.top)[0] + 2 : _px(lay, 0, geo.plot.y)[0], c0:c1])
    long = np.flatnonzero(rows.mean(axis=1) > 0.9) + _px(lay, 0, geo.plot.top)[0] + 2
    assert all(min(abs(r - x) for x in red_rows) <= 3 for r in long), (long, red_rows)
    # the nominal: a grey line at 10.0 between them
    row = _px(lay, 0, float(geo.y(10.0)))[0]
    band = img[row - 1 : row + 2, c0:c1]
    assert (_is_grey(band) | (band.mean(axis=-1) < 0.5)).any(axis=0).mean() > 0.4
    # the labels of the limits, right of the frame at their lines
    words = _words(out.pdf, lay.height)
    right = geo.plot.x + geo.plot.w
    beside = [
        (w, y)
        for w, x, y in words
        if right < x < right + 30 and geo.plot.y - 8 < y < geo.plot.top + 2
    ]
    for label, value in (("USL", 10.1), ("LSL", 9.9)):
        for word in (label, fmt_mm(value)):
            (y,) = [y for w, y in beside if w == word]
            assert abs(y - float(geo.y(value))) < 6.0, word
    # the points
    v = df["value_D1_mm"].to_numpy(float)
    for s in range(1, len(v) + 1):
        if not np.isfinite(v[s - 1]):
            continue
        p = _patch(img, _px(lay, float(geo.x(s)), float(geo.y(v[s - 1]))))
        if s in D1_LOW + D1_HIGH:
            assert _is_red(p).sum() >= 5, s
        else:
            assert _is_green(p).sum() >= 5 and not _is_red(p).any(), s
    # the basic dimension: dark points, neither green nor red
    geo = next(g for g in lay.charts if g.key == "D3")
    v = df["value_D3_mm"].to_numpy(float)
    for s in (1, 2, 3):
        p = _patch(img, _px(lay, float(geo.x(s)), float(geo.y(v[s - 1]))))
        assert (p.mean(axis=1) < 0.35).sum() >= 5 and not (_is_green(p).any() or _is_red(p).any())


def test_dimension_axis_matches_the_geometry(features):
    """The value ticks of a dimension's chart (not from 0) sit where the points are drawn."""
    _, out = features
    lay = out.lay
    words = _words(out.pdf, lay.height)
    for key in ("D1", "D2"):
        geo = next(g for g in lay.charts if g.key == key)
        pa = geo.plot
        ticks = [
            (float(w), y)
            for w, x, y in words
            if re.fullmatch(r"\d+\.\d+", w) and pa.x - 28 < x < pa.x and pa.y - 2 < y < pa.top + 2
        ]
        assert len(ticks) >= 3, key
        for v, y in ticks:
            assert geo.bottom <= v <= geo.top
            assert abs(y - float(geo.y(v))) < 2.0, (key, v)


def test_values_beyond_the_scale(tmp_path):
    """A dimension's wild values stay on the page: the chart keeps its limits' scale and
    draws them as triangles at the top or bottom edge."""
    df = feature_frame(12)
    df.loc[2, "value_D1_mm"], df.loc[2, "status_D1"] = 3.0, "FAIL"
    df.loc[5, "value_D1_mm"], df.loc[5, "status_D1"] = 25.0, "FAIL"
    out = _render(tmp_path, "wild", df, FEATURE_CHARS)
    lay, img = out.lay, out.img
    geo = next(g for g in lay.charts if g.key == "D1")
    assert 9.5 < geo.bottom < 9.9 and 10.1 < geo.top < 10.5
    low = _patch(img, _px(lay, float(geo.x(3)), geo.y_low + 2.0), 1)
    high = _patch(img, _px(lay, float(geo.x(6)), geo.plot.top - 2.5), 1)
    assert _is_red(low).any() and _is_red(high).any()
    assert "off the scale" in out.text
    # the legend stays on the page: its last word left of the right margin
    words = _words(out.pdf, lay.height)
    (x,) = [x for w, x, _ in words if w == "scale"]
    assert x < lay.width - 20


def test_most_critical_feature_characteristics_charted(tmp_path):
    """Beyond the page's room the characteristics with the smallest margin are charted: a
    dimension's margin is its worst value's room to the nearer limit relative to half its
    tolerance range, a tolerance's relative to the tolerance."""
    chars = [
        TrendCharacteristic(
            f"G{k}", f"flatness {0.2 * k:g} mm", 0.2 * k, kind="geometric", quantity="flatness"
        )
        for k in range(1, 7)
    ] + [
        TrendCharacteristic(
            f"D{k}",
            f"diameter {10 * k} +/-0.1",
            float("nan"),
            kind="dimension",
            lower=10.0 * k - 0.1,
            upper=10.0 * k + 0.1,
            nominal=10.0 * k,
            quantity="diameter",
        )
        for k in (1, 2)
    ]
    rng = np.random.default_rng(3)
    df = batch_frame(10, [], seed=3)
    for ch in chars:
        if ch.kind == "geometric":  # margins 0.7 to 0.9
            df[f"value_{ch.key}_mm"] = ch.tolerance_mm * (0.1 + 0.2 * rng.random(10))
        else:  # within 0.005 of the nominal: margins above 0.95
            df[f"value_{ch.key}_mm"] = ch.nominal + 0.005 * rng.uniform(-1, 1, 10)
        df[f"status_{ch.key}"] = "PASS"
    df.loc[3, "value_D2_mm"] = 19.915  # 0.015 from its lower limit: margin 0.15
    df.loc[3, "value_G4_mm"] = 0.78  # 0.02 below 0.8: margin 0.025
    out = _render(tmp_path, "critical", df, chars)
    shown = [g.key for g in out.lay.charts]
    assert len(shown) == MAX_CHARTS and {"G4", "D2"} <= set(shown)
    assert "D1" in out.lay.omitted  # the most room of all
    assert "smallest margin to their limits" in " ".join(out.text.split())


def test_dimension_stats_by_hand():
    from qifreport.metrology import spc

    v = np.array([9.92, 9.94, 9.97, 9.89, np.nan])
    st = spc.dimension_stats(v, np.array(["PASS", "PASS", "PASS", "FAIL", ""]), 9.9, 10.1, 10.0)
    m, s = np.nanmean(v), np.nanstd(v, ddof=1)
    assert (st.n, st.n_pass, st.n_judged) == (4, 3, 4)
    assert st.cp == pytest.approx(0.2 / (6 * s)) and st.cpk == pytest.approx((m - 9.9) / (3 * s))
    assert (st.min, st.max) == (9.89, 9.97)
    assert st.margin == pytest.approx((9.89 - 9.9) / 0.1)  # beyond the lower limit: < 0
    # one limit: its side only, no Cp; the margin relative to the nominal's distance to it
    st = spc.dimension_stats(v, v.astype(str), None, 10.1, 10.0)
    assert np.isnan(st.cp) and st.cpk == pytest.approx((10.1 - m) / (3 * s))
    assert st.margin == pytest.approx((10.1 - 9.97) / 0.1)
    # no limit (basic): no index, never critical
    st = spc.dimension_stats(v, v.astype(str), None, None, 10.0)
    assert np.isnan(st.cp) and np.isnan(st.cpk) and st.margin == np.inf
    # a one-sided tolerance has min too, and no Cp
    st = spc.characteristic_stats(v, v.astype(str), 10.0)
    assert st.min == 9.89 and np.isnan(st.cp)
    assert spc.capability(1.0, 0.0, 5, 0.0, 2.0) == pytest.approx((np.nan, np.nan), nan_ok=True)


def test_a_capability_index_is_stated_from_25_values_with_its_interval():
    from qifreport.metrology import spc
    from qifreport.reports.trend.run_chart import capability_text

    rng = np.random.default_rng(2)
    few = rng.normal(0.1, 0.02, 2)  # the batch of two that once printed Cpk 1736.06
    st = spc.characteristic_stats(few, np.array(["PASS"] * 2), 0.5)
    assert np.isfinite(st.cpk) and capability_text(st, False) == "Cpk: n < 25"
    v = rng.normal(0.1, 0.02, 30)
    st = spc.characteristic_stats(v, np.array(["PASS"] * 30), 0.5)
    cpk = (0.5 - v.mean()) / (3 * v.std(ddof=1))
    half = 1.96 * np.sqrt(1 / (9 * 30) + cpk**2 / (2 * 29))
    assert st.cpk_interval() == pytest.approx((cpk - half, cpk + half))
    assert capability_text(st, False) == f"Cpk {cpk:.2f} [{cpk - half:.2f}, {cpk + half:.2f}]"
    # the interval of a Cpk near 6 from 30 scans is some +/-1.5 wide: the bound is real
    assert 1.0 < half < 2.0
