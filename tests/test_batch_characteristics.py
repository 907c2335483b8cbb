"""``qifreport batch`` carries the drawing's feature characteristics (issue 22, item 6): the
summary table has each one's value, limits and status, the QIF Statistics document its typed
statistics, the trend PDF its run chart.

The batch is three scans of the STEP panel (its PMI: profiles T1, T2 and the flatness of
each flange underside, G1 and G2): the sample scan, its warped free state, and the sample
scan with a 0.45 mm dent in the right flange, which fails G2 (and only G2). Every number of
the summaries is checked against the per-scan outputs, read independently: the JSON
summary, and the QIF documents with plain lxml XPath.
"""

from __future__ import annotations

import json
import re
import statistics as pystats
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import trimesh
from lxml import etree
from PIL import Image

from qifreport.batch.summaries import summary_frame, trend_characteristics
from qifreport.batch.task import characteristic_columns
from qifreport.metrology.gdt.characteristic_types import CharacteristicResult, CharacteristicSpec
from qifreport.registration.pointcloud import read_scan
from qifreport.reports.trend import plan_trend
from tests.consumers import poppler_tool

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
NOMINAL = SAMPLES / "panel.step"
EXE = Path(sys.executable).parent / "qifreport"
NS = {"q": "http://qifstandards.org/xsd/qif3"}
SCANS = ["panel_dent", "panel_scan", "panel_scan_warped"]  # plan order (by name)


# ---------------------------------------------------------------------------- the table


def _spec(key: str, kind: str, **kw) -> CharacteristicSpec:
    return CharacteristicSpec(
        key=key, kind=kind, name=f"item {key}", step_id=7, faces=np.zeros(0), **kw
    )


def test_characteristic_columns():
    """Value, limits and status per key, in the summary's words; status only when not
    measured; a basic dimension's value without limits."""
    flat = _spec("G1", "flatness", tolerance=0.2)
    dia = _spec(
        "D1", "dimension", dim_type="diameter", nominal=10.0, lower_limit=9.9, upper_limit=10.1
    )
    ang = _spec(
        "D2",
        "dimension",
        dim_type="angular",
        unit="deg",
        nominal=90.0,
        lower_limit=89.5,
        upper_limit=90.5,
    )
    basic = _spec("D3", "dimension", dim_type="linear distance", nominal=42.0, basic=True)
    pos = _spec("G2", "position", tolerance=0.5)
    cols = {}
    for c in (
        CharacteristicResult(flat, value=0.12, status="PASS"),
        CharacteristicResult(dia, value=10.13, status="FAIL"),
        CharacteristicResult(ang, value=90.49, status="INDETERMINATE"),
        CharacteristicResult(basic, value=42.01, status="BASIC"),
        CharacteristicResult(pos, status="NOT_MEASURED", reason="not seen"),
    ):
        cols.update(characteristic_columns(c))
    assert cols == {
        "value_G1_mm": 0.12,
        "tolerance_G1_mm": 0.2,
        "status_G1": "PASS",
        "value_D1_mm": 10.13,
        "lower_D1_mm": 9.9,
        "upper_D1_mm": 10.1,
        "status_D1": "FAIL",
        "value_D2_deg": 90.49,
        "lower_D2_deg": 89.5,
        "upper_D2_deg": 90.5,
        "status_D2": "NOT ESTABLISHED",
        "value_D3_mm": 42.01,
        "status_D3": "BASIC",
        "status_G2": "NOT MEASURED",
    }


def test_trend_characteristics_of_a_part():
    """The trend charts every zone, then every feature characteristic the table has values
    of: a geometric tolerance one-sided, a dimension with its limits and nominal."""
    zone = SimpleNamespace(key="T1", upper=0.5, lower=-0.5, describe=lambda: "surface profile 1 mm")
    specs = [
        _spec("G1", "flatness", tolerance=0.2),
        _spec(
            "D1", "dimension", dim_type="diameter", nominal=10.0, lower_limit=9.9, upper_limit=10.1
        ),
        _spec(
            "D2",
            "dimension",
            dim_type="angular",
            unit="deg",
            nominal=90.0,
            lower_limit=89.5,
            upper_limit=90.5,
        ),
        _spec("G9", "flatness", tolerance=0.1),  # never measured: no column, no chart
    ]
    st = SimpleNamespace(drawing=SimpleNamespace(zones=[zone], plan=SimpleNamespace(specs=specs)))
    df = pd.DataFrame(
        {
            "profile_T1_mm": [0.3],
            "value_G1_mm": [0.1],
            "value_D1_mm": [10.0],
            "value_D2_deg": [90.1],
        }
    )
    chars = trend_characteristics(st, df)
    assert [(c.key, c.kind, c.value_column) for c in chars] == [
        ("T1", "profile", "profile_T1_mm"),
        ("G1", "geometric", "value_G1_mm"),
        ("D1", "dimension", "value_D1_mm"),
        ("D2", "dimension", "value_D2_deg"),
    ]
    g1, d1, d2 = chars[1:]
    assert (chars[0].tolerance_mm, g1.tolerance_mm, g1.quantity) == (1.0, 0.2, "flatness")
    assert (d1.lower, d1.upper, d1.nominal, d1.unit) == (9.9, 10.1, 10.0, "mm")
    assert (d2.unit, d2.limits()) == ("deg", [("USL", 90.5), ("LSL", 89.5)])
    assert g1.description == "flatness 0.2 mm (pmi #7)"
    assert d1.description == "diameter dimension 9.9 .. 10.1 mm (pmi #7)"


def test_summary_frame_orders_the_characteristic_columns():
    """Zones' columns, then the feature characteristics', as the rows list them; a status
    column empty (not NaN) where a scan has none."""
    base = {"seq": 1, "id": "a", "verdict": "PASS", "scan_sha256": "x"}
    rows = [
        {
            **base,
            "profile_T1_mm": 0.2,
            "status_T1": "PASS",
            "value_G1_mm": 0.1,
            "status_G1": "PASS",
        },
        {**base, "id": "b", "verdict": "ERROR"},
    ]
    df = summary_frame([{"row": r} for r in rows])
    cols = list(df.columns)
    assert cols.index("profile_T1_mm") < cols.index("value_G1_mm") < cols.index("scan_sha256")
    assert list(df["status_G1"]) == ["PASS", ""]


def test_summary_csv_cells_a_spreadsheet_would_run_are_text():
    """A serial number or scan id that starts like a formula (= + - @) is written with a
    leading apostrophe (CSV injection); numbers, negative ones included, are numbers."""
    import io

    import pandas as pd

    from qifreport.batch.summaries import csv_safe

    base = {"seq": 1, "verdict": "PASS", "scan_sha256": "x", "profile_T1_mm": -0.2}
    rows = [
        {**base, "id": '=HYPERLINK("http://x")', "serial": "@SUM(A1)"},
        {**base, "id": "b", "serial": "+1-555"},
        {**base, "id": "c", "serial": "SN-7"},
    ]
    text = csv_safe(summary_frame([{"row": r} for r in rows])).to_csv(index=False)
    back = pd.read_csv(io.StringIO(text), keep_default_na=False)
    assert list(back["id"]) == ['\'=HYPERLINK("http://x")', "b", "c"]
    assert list(back["serial"]) == ["'@SUM(A1)", "'+1-555", "SN-7"]
    assert list(back["profile_T1_mm"]) == [-0.2, -0.2, -0.2]


# ---------------------------------------------------------------------------- the batch


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """The three scans' batch (two local workers) and its outputs."""
    d = tmp_path_factory.mktemp("panel_batch")
    scans = d / "scans_in"
    scans.mkdir()
    for name in ("panel_scan.ply", "panel_scan_warped.ply"):
        (scans / name).write_bytes((SAMPLES / name).read_bytes())
    # a dent in the right flange (x > 62.5 mm): 0.45 mm deep, sigma 3 mm, across the wall
    P = read_scan(SAMPLES / "panel_scan.ply").points
    right = P[:, 0] > 62.5
    r2 = (P[right, 0] - 71.0) ** 2 + (P[right, 1] - 10.0) ** 2
    P[right, 2] -= 0.45 * np.exp(-r2 / (2 * 3.0**2))
    trimesh.PointCloud(P).export(scans / "panel_dent.ply")
    out = d / "out"
    r = subprocess.run(
        [str(EXE), "batch", str(NOMINAL), str(scans), "--out", str(out), "--jobs", "2", "--quiet"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 1, r.stdout + r.stderr  # the dent fails
    assert "3 scans: 2 PASS, 1 FAIL, 0 NOT ESTABLISHED, 0 ERROR" in r.stdout, r.stdout
    df = pd.read_csv(out / "summary.csv", keep_default_na=False)
    assert list(df["id"]) == SCANS
    return SimpleNamespace(
        out=out,
        df=df.set_index("id"),
        json={n: json.loads((out / "scans" / f"{n}.json").read_text()) for n in SCANS},
        qif={n: _per_scan_qif(out / "scans" / f"{n}.qif") for n in SCANS},
    )


def _per_scan_qif(path: Path) -> dict[str, dict]:
    """The flatness measurements of a per-scan QIF by designator (plain XPath)."""
    root = etree.parse(str(path)).getroot()
    out = {}
    for m in root.xpath("//q:FlatnessCharacteristicMeasurement", namespaces=NS):
        (item_id,) = m.xpath("q:CharacteristicItemId/text()", namespaces=NS)
        (item,) = root.xpath(f"//*[@id='{item_id}']", namespaces=NS)
        (key,) = item.xpath("q:CharacteristicDesignator/q:Designator/text()", namespaces=NS)
        out[key] = dict(
            value=float(m.xpath("q:Value/text()", namespaces=NS)[0]),
            status=m.xpath("q:Status/q:CharacteristicStatusEnum/text()", namespaces=NS)[0],
        )
    return out


@pytest.mark.slow
def test_summary_table_has_the_characteristics(batch):
    df = batch.df
    cols = list(df.columns)
    for key in ("G1", "G2"):
        assert [c for c in cols if c.endswith(f"_{key}_mm") or c == f"status_{key}"] == [
            f"value_{key}_mm",
            f"tolerance_{key}_mm",
            f"status_{key}",
        ]
    assert cols.index("in_tolerance_T2_pct") < cols.index("value_G1_mm")  # zones first
    for name in SCANS:
        for c in batch.json[name]["characteristics"]:
            key = c["key"]
            # the table's lengths to 0.1 um (the JSON keeps every digit)
            assert df.loc[name, f"value_{key}_mm"] == pytest.approx(c["value"], abs=5.01e-5)
            assert df.loc[name, f"tolerance_{key}_mm"] == c["tolerance_mm"] == 0.2
            # the QIF's value (written to 4 decimals) and status
            q = batch.qif[name][key]
            assert df.loc[name, f"value_{key}_mm"] == pytest.approx(q["value"], abs=5.1e-5)
            assert df.loc[name, f"status_{key}"] == q["status"]
    # the dent fails G2 and only G2; the table says so
    assert df.loc["panel_dent", "value_G2_mm"] > 0.2 and df.loc["panel_dent", "status_G2"] == "FAIL"
    assert df.loc["panel_dent", "verdict"] == "FAIL"
    assert df.loc["panel_dent", "criterion"] == "G2:limit"
    assert (df["status_G1"] == "PASS").all()
    assert list(df["status_G2"]) == ["FAIL", "PASS", "PASS"]


@pytest.mark.slow
def test_statistics_document_has_the_characteristics(batch):
    from qifreport.qif.validate import validate

    stats = batch.out / "panel_statistics.qif"
    rep = validate(stats, strict=True, checks=True)
    assert rep.ran == ["lxml", "xmlschema", "dmsc"]
    assert not rep.errors(), rep.format()
    doc = etree.parse(str(stats)).getroot()
    blocks = {}
    for st in doc.xpath("//q:CharacteristicsStats/*", namespaces=NS):
        attrs = {a.get("name"): a.get("value") for a in st.find("q:Attributes", NS)}
        blocks[attrs["designator"]] = (etree.QName(st).localname, st, attrs)
    assert {k: v[0] for k, v in blocks.items()} == {
        "T1": "SurfaceProfileCharacteristicStats",
        "T2": "SurfaceProfileCharacteristicStats",
        "G1": "FlatnessCharacteristicStats",
        "G2": "FlatnessCharacteristicStats",
    }
    for key in ("G1", "G2"):
        _, st, attrs = blocks[key]
        values = [batch.qif[n][key]["value"] for n in SCANS]
        statuses = [batch.qif[n][key]["status"] for n in SCANS]
        vs = st.find("q:ValueStats", NS)

        def num(path: str, vs=vs) -> float:
            return float(vs.xpath(path, namespaces=NS)[0])

        mean, sd = pystats.fmean(values), pystats.stdev(values)
        assert num("q:Average/q:Value/text()") == pytest.approx(mean, rel=1e-12)
        assert num("q:StandardDeviation/q:Value/text()") == pytest.approx(sd, rel=1e-12)
        assert num("q:Cpk/q:Value/text()") == pytest.approx((0.2 - mean) / (3 * sd), rel=1e-12)
        assert not vs.xpath("q:Cp", namespaces=NS)
        assert (int(attrs["n_pass"]), int(attrs["n_fail"])) == (
            statuses.count("PASS"),
            statuses.count("FAIL"),
        )
        above = vs.xpath("q:NumberOutOfTolerance/q:Ids/q:Id/text()", namespaces=NS)
        assert len(above) == sum(v > 0.2 for v in values) == (1 if key == "G2" else 0)
        for mid in above:  # the dent's measurement, with its value
            (m,) = doc.xpath(f"//q:FlatnessCharacteristicMeasurement[@id='{mid}']", namespaces=NS)
            assert (
                float(m.findtext("q:Value", namespaces=NS)) == batch.qif["panel_dent"][key]["value"]
            )
        assert st.findtext("q:CapabilityCalculationMethod", namespaces=NS) == "THREE_SIGMA"


@pytest.mark.slow
def test_trend_report_charts_the_characteristics(batch):
    from qifreport.reports.trend import TrendCharacteristic

    pdf = batch.out / "panel_trend.pdf"
    info = subprocess.run([poppler_tool("pdfinfo"), pdf], capture_output=True, text=True).stdout
    assert re.search(r"^Pages:\s+1$", info, re.M), info
    text = subprocess.run(
        [poppler_tool("pdftotext"), pdf, "-"], capture_output=True, text=True
    ).stdout
    flat = " ".join(text.split())
    df = batch.df.reset_index()
    for key, pmi in (("G1", 1541), ("G2", 1546)):
        assert f"{key} \u2014 flatness 0.2 mm (pmi #{pmi})" in flat
        v = df[f"value_{key}_mm"].to_numpy(float)
        n_pass = int((df[f"status_{key}"] == "PASS").sum())
        line = (
            f"n 3 mean {v.mean():.3f} \u03c3 {v.std(ddof=1):.3f} max {v.max():.3f} mm "
            f"Cpk: n < 25 PASS {n_pass} of 3"  # no capability index from 3 scans
        )
        assert line in flat, line
    # the dent's G2 point: red, above G2's tolerance line, where the layout puts it
    chars = [
        TrendCharacteristic("T1", "", 1.0),
        TrendCharacteristic("T2", "", 0.5),
        TrendCharacteristic("G1", "", 0.2, kind="geometric", quantity="flatness"),
        TrendCharacteristic("G2", "", 0.2, kind="geometric", quantity="flatness"),
    ]
    lay = plan_trend(df, chars)
    png = batch.out / "trend"
    subprocess.run(
        [poppler_tool("pdftoppm"), "-r", "100", "-png", "-singlefile", str(pdf), str(png)],
        check=True,
    )
    img = np.asarray(Image.open(f"{png}.png").convert("RGB"), dtype=float) / 255.0
    geo = next(g for g in lay.charts if g.key == "G2")
    value = df.loc[df["id"] == "panel_dent", "value_G2_mm"].item()
    assert value > 0.2 and geo.y(value) > geo.y(0.2)
    k = 100 / 72
    row = int(round((lay.height - float(geo.y(value))) * k))
    col = int(round(float(geo.x(1)) * k))
    patch = img[row - 1 : row + 2, col - 1 : col + 2].reshape(-1, 3)
    red = (patch[:, 0] > 0.55) & (patch[:, 0] - np.maximum(patch[:, 1], patch[:, 2]) > 0.35)
    assert red.sum() >= 5
