"""Traceability a shop needs: outputs named after the part and its serial number, the part
number and revision (the STEP product's, or the operator's), the instrument and the part's
temperature in the PDF header, the JSON summary, the QIF and the batch table.

The real sample STEP read by OCP, real XSD validation, the PDF read by ``pdftotext``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from lxml import etree

from qifreport.errors import InputError
from qifreport.options import output_name
from qifreport.step.semantic import read_pmi_text
from tests.conftest import NIST, ROOT, shared_file
from tests.consumers import poppler_tool

EXE = Path(sys.executable).with_name("qifreport")
Q = "{http://qifstandards.org/xsd/qif3}"
PANEL = ROOT / "samples" / "panel.step"


def _run(*args) -> subprocess.CompletedProcess:
    r = subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True)
    assert r.returncode in (0, 1, 3), r.stderr[-2000:]
    return r


def test_the_step_product_names_the_part_and_its_revision():
    products = {n: read_pmi_text(shared_file(f"step/nist/{n}")).product for n in NIST}
    ctc04 = next(p for n, p in products.items() if n.startswith("nist_ctc_04"))
    assert (ctc04.number, ctc04.revision) == ("2012_CTC_04_ASME1_RD", "D")
    ftc08 = next(p for n, p in products.items() if n.startswith("nist_ftc_08"))
    assert (ftc08.number, ftc08.name, ftc08.revision) == ("nist_ftc_08_asme1_rc.prt", None, "C")
    panel = read_pmi_text(PANEL).product
    assert (panel.number, panel.revision) == ("curved_cover", None)


def test_output_names_from_the_template():
    f = {"part": "panel", "serial": "SN 42/7", "scan": "scan_3"}
    assert output_name("{part}[_{serial}]", f) == "panel_SN_42_7"  # a path cannot be smuggled
    assert output_name("{part}[_{serial}]", {**f, "serial": ""}) == "panel"
    assert output_name("{serial}-{scan}", f) == "SN_42_7-scan_3"
    for bad in ("{nope}", "{part", "[{serial}", "..", "[_{serial}]"):
        with pytest.raises(InputError, match="--name"):
            output_name(bad, {**f, "serial": ""})


@pytest.fixture(scope="module")
def two_serials(tmp_path_factory):
    """The panel scanned twice, serials SN-A and SN-B, into one folder."""
    out = tmp_path_factory.mktemp("trace")
    cache = tmp_path_factory.mktemp("cache")
    common = ["--out", out, "--cache", cache, "--json", "--quiet", "--revision", "C"]
    common += ["--operator", "Op One", "--organization", "Test Lab", "--temperature", "21.5"]
    for serial, scan in (("SN-A", "panel_scan.ply"), ("SN-B", "panel_scan_defect.ply")):
        _run(PANEL, ROOT / "samples" / scan, "--serial", serial, *common)
    return out


def test_two_serials_stand_side_by_side_with_their_fields(two_serials):
    out = two_serials
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "panel_SN-A.json",
        "panel_SN-A.pdf",
        "panel_SN-A.qif",
        "panel_SN-B.json",
        "panel_SN-B.pdf",
        "panel_SN-B.qif",
        "panel_plan.qif",
    ]
    for serial in ("SN-A", "SN-B"):
        doc = json.loads((out / f"panel_{serial}.json").read_text())
        t = doc["traceability"]
        assert (t["part_number"], t["part_number_source"], t["revision"]) == (
            "curved_cover",
            "step",
            "C",
        )
        assert (t["serial"], t["operator"], t["organization"]) == (serial, "Op One", "Test Lab")
        assert t["temperature_C"] == 21.5 and t["instrument"].startswith("mid-range")
        assert t["started"].endswith("+00:00") and t["started"] <= t["finished"]
        qif = etree.parse(str(out / f"panel_{serial}.qif")).getroot()
        part = qif.find(f".//{Q}Product/{Q}PartSet/{Q}Part")
        assert part.findtext(f"{Q}ModelNumber") == "curved_cover"
        assert part.findtext(f"{Q}Version") == "C"
        assert qif.findtext(f".//{Q}ActualComponent/{Q}SerialNumber") == serial
        attrs = {a.get("name"): a.get("value") for a in qif.iter(f"{Q}AttributeD1")}
        assert attrs["part_temperature_C"] == "21.5"
        text = subprocess.run(
            [poppler_tool("pdftotext"), "-layout", str(out / f"panel_{serial}.pdf"), "-"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        head = " ".join(text.split()[:120])
        assert "part number curved_cover revision C serial number " + serial in head
        assert "part at 21.5 °C" in head and "Op One" in head and "instrument mid-range" in head
        assert "RESTRAINED INSPECTION" in head


def test_the_batch_table_carries_the_fields(tmp_path):
    shell = ROOT / "samples" / "shell_nominal.ply"
    scans = tmp_path / "scans"
    scans.mkdir()
    for name in ("shell_scan.ply", "shell_scan_defect.ply"):
        (scans / name).write_bytes((ROOT / "samples" / name).read_bytes())
    r = subprocess.run(
        [str(EXE), "batch", shell, scans, "--out", tmp_path / "b", "--tolerance", "0.5"]
        + ["--part-number", "PN-7", "--revision", "B", "--operator", "Op", "--quiet"]
        + ["--no-pdf", "--no-cache"],
        capture_output=True,
        text=True,
    )
    assert r.returncode in (0, 1, 3), r.stderr[-2000:]
    df = pd.read_csv(tmp_path / "b" / "summary.csv", dtype=str, keep_default_na=False)
    assert list(df.part_number) == ["PN-7", "PN-7"] and list(df.revision) == ["B", "B"]
    assert all(len(s) == 25 and s.endswith("+00:00") for s in df.started)  # ISO 8601, UTC
    assert set(df.operator) == {"Op"} and all(df.instrument.str.startswith("mid-range"))
    # lengths to 0.1 um, not 17 digits
    for col in ("rms_mm", "max_abs_mm", "p95_mm"):
        assert all(len(v.split(".")[-1]) <= 4 for v in df[col]), df[col].tolist()
