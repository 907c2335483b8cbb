"""Datum targets (issue 21's clamps from the PMI): the sample panel carries its RPS points as
AP242 datum targets written by :mod:`qifreport.step.write`; our Part 21 reader and OCCT's
own XDE reader agree on where each is; ``--clamps pmi`` holds the part at them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from OCP.IFSelect import IFSelect_ReturnStatus
from OCP.STEPCAFControl import STEPCAFControl_Reader
from OCP.TCollection import TCollection_ExtendedString
from OCP.TDF import TDF_LabelSequence
from OCP.TDocStd import TDocStd_Document
from OCP.XCAFApp import XCAFApp_Application
from OCP.XCAFDoc import XCAFDoc_Datum, XCAFDoc_DocumentTool

from qifreport.errors import InputError
from qifreport.registration.restraint.clamps import parse_clamps
from qifreport.restraint import clamps_from_pmi
from qifreport.step.semantic import read_pmi_text
from qifreport.step.write import PMISpecDatum, PMISpecTarget, write_step_with_pmi
from samples.make_step_sample import build_part, sample_spec

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).parent / "qifreport"
PANEL = ROOT / "samples" / "panel.step"
CSV = ROOT / "samples" / "panel_clamps.csv"


def xde_targets(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Name -> (position, axis) of every datum target as OCCT's XDE reads the file."""
    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)
    reader = STEPCAFControl_Reader()
    reader.SetGDTMode(True)
    assert reader.ReadFile(str(path)) == IFSelect_ReturnStatus.IFSelect_RetDone
    assert reader.Transfer(doc)
    dimtol = XCAFDoc_DocumentTool.DimTolTool_s(doc.Main())
    labels = TDF_LabelSequence()
    dimtol.GetDatumLabels(labels)
    out = {}
    for i in range(1, labels.Length() + 1):
        # FindAttribute does not fill its argument in OCP 7.9; Set_s returns the existing one
        obj = XCAFDoc_Datum.Set_s(labels.Value(i)).GetObject()
        if not obj.IsDatumTarget():
            continue
        ax = obj.GetDatumTargetAxis()
        p, d = ax.Location(), ax.Direction()
        name = f"{obj.GetName().ToCString()}{obj.GetDatumTargetNumber()}"
        out[name] = (np.array([p.X(), p.Y(), p.Z()]), np.array([d.X(), d.Y(), d.Z()]))
    return out


def test_the_panel_targets_are_its_clamps_for_both_readers():
    ours = {t.name: t for d in read_pmi_text(PANEL).datums for t in d.target_details}
    occt = xde_targets(PANEL)
    csv = {c.name: c for c in parse_clamps(CSV.read_text(encoding="utf-8"))}
    assert sorted(ours) == sorted(occt) == sorted(csv) == ["A1", "A2", "A3", "A4", "B1", "C1", "C2"]
    for name, t in ours.items():
        assert t.kind == "point" and len(t.face_step_ids) == 1
        np.testing.assert_allclose(t.position, occt[name][0], atol=1e-9)
        np.testing.assert_allclose(t.direction, occt[name][1], atol=1e-9)
        np.testing.assert_allclose(t.position, csv[name].position, atol=1e-9)
    # each on its datum's own feature face
    datums = {d.label: d for d in read_pmi_text(PANEL).datums}
    for name, t in ours.items():
        assert set(t.face_step_ids) <= set(datums[name[0]].face_step_ids)


def test_targets_round_trip_and_bad_targets_are_refused(tmp_path):
    shape = build_part()
    datums, tolerances = sample_spec(shape)
    a = datums[0]
    moved = PMISpecDatum(
        "A", a.faces, [PMISpecTarget(7, (-70.5, 10.25, 0.0), (0.0, 0.0, -1.0), a.faces[0])]
    )
    path = tmp_path / "one.step"
    write_step_with_pmi(shape, path, tolerances, [moved, *datums[1:]], "t")
    (t,) = [t for d in read_pmi_text(path).datums if d.label == "A" for t in d.target_details]
    assert t.name == "A7" and t.position == pytest.approx([-70.5, 10.25, 0.0])
    twice = PMISpecDatum("A", a.faces, [a.targets[0], a.targets[0]])
    with pytest.raises(ValueError, match="target numbers"):
        write_step_with_pmi(shape, tmp_path / "bad.step", tolerances, [twice, *datums[1:]], "t")
    nowhere = PMISpecDatum("A", a.faces, [PMISpecTarget(1, (0, 0, 0), (0, 0, 0), a.faces[0])])
    with pytest.raises(ValueError, match="zero direction"):
        write_step_with_pmi(shape, tmp_path / "bad.step", tolerances, [nowhere, *datums[1:]], "t")
    assert not (tmp_path / "bad.step").exists()


def test_clamps_from_the_pmi_follow_the_datum_precedence(tmp_path):
    clamps = {c.name: c for c in clamps_from_pmi(PANEL, 20.0)}
    # A is the primary datum of every tolerance naming datums: its targets hold the normal;
    # B's and C's are locators along their axes, as samples/panel_clamps.csv states them
    assert {k: c.directions for k, c in clamps.items()} == {
        "A1": "n", "A2": "n", "A3": "n", "A4": "n", "B1": "x", "C1": "y", "C2": "y",
    }  # fmt: skip
    assert all(c.max_force == 20.0 for c in clamps.values())
    assert clamps["B1"].source.startswith("PMI datum target B1")
    assert "drawing's note" not in clamps["B1"].source  # the operator's limit
    # without the operator's, the limit the drawing's restraint note states per target
    # ("RESTRAINT FORCE AT MOST 20 N PER TARGET"), named where each clamp comes from;
    # the operator's own limit replaces it
    from_note = clamps_from_pmi(PANEL)
    assert [c.max_force for c in from_note] == [20.0] * 7
    assert all("limit from the drawing's note 'FORCE AT MOST 20 N'" in c.source for c in from_note)
    assert {c.max_force for c in clamps_from_pmi(PANEL, 15.0)} == {15.0}
    with pytest.raises(InputError, match="has no placed datum target"):
        clamps_from_pmi(_no_targets(tmp_path))
    with pytest.raises(InputError, match="is a mesh"):
        clamps_from_pmi(ROOT / "samples" / "shell_nominal.ply")


def _no_targets(tmp_path: Path) -> Path:
    """A STEP file of the sample panel without datum targets."""
    shape = build_part()
    datums, tolerances = sample_spec(shape)
    plain = [PMISpecDatum(d.label, d.faces) for d in datums]
    path = tmp_path / "plain.step"
    write_step_with_pmi(shape, path, tolerances, plain, "plain")
    return path


def test_restrained_at_the_datum_targets_from_the_command_line(tmp_path):
    scan = ROOT / "samples" / "panel_scan_warped.ply"
    out = subprocess.run(
        [os.fsencode(EXE), PANEL, scan, "--clamps", "pmi", "--material", "abs",
         "--out", tmp_path, "--json", "--no-pdf", "--no-cache"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    rep = json.loads((tmp_path / "panel.json").read_text())
    r = rep["registration"]["restraint"]
    assert [c["name"] for c in r["clamps"]] == ["A1", "A2", "A3", "A4", "B1", "C1", "C2"]
    assert all(c["source"].startswith("PMI datum target") for c in r["clamps"])
    # no --max-clamp-force: the drawing's 20 N per target, and the forces within it
    assert all(c["max_force_N"] == 20.0 for c in r["clamps"])
    assert all(c["force_N"] is not None and c["force_N"] <= 20.0 for c in r["clamps"])
    # the same hold as the clamps file's: held within 15 um rms of nominal
    assert rep["vertex_deviation"]["rms"] < 0.015
