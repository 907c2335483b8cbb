"""The domain model: the :class:`Scan` read from each format, its spacing and density, and
the :class:`Part` and :class:`Drawing` of a STEP nominal and of a mesh nominal."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.errors import InputError
from qifreport.metrology.model import Drawing, Part
from qifreport.nominal import load_nominal
from qifreport.registration.pointcloud import read_scan
from qifreport.registration.scan import Scan
from qifreport.simulate.scanner import ScanSpec, virtual_scan
from qifreport.simulate.shapes import thin_shell
from tests.conftest import ROOT

SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"


def grid(pitch: float = 0.5, n: int = 40) -> np.ndarray:
    """(n^2, 3) points on a square grid of ``pitch`` mm in the plane z = 1, mm."""
    x, y = np.meshgrid(np.arange(n) * pitch, np.arange(n) * pitch, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.ones(n * n)])


@pytest.mark.parametrize("suffix, fmt", [(".ply", "ply"), (".xyz", "text"), (".npy", "npy")])
def test_each_format_reads_the_same_scan(tmp_path, suffix, fmt):
    """A PLY, an XYZ and an NPY file of the same points read as the same :class:`Scan`:
    the points, their file, its format and unit, how many points it held, no normals."""
    P = grid()
    f = tmp_path / f"scan{suffix}"
    if suffix == ".ply":
        trimesh.PointCloud(P).export(f)
    elif suffix == ".xyz":
        np.savetxt(f, P, fmt="%.17g")
    else:
        np.save(f, P)
    scan = read_scan(f)
    assert isinstance(scan, Scan)
    np.testing.assert_array_equal(scan.points, P)
    assert scan.n == scan.points_read == len(P)
    assert (scan.format, scan.units, scan.source, scan.name) == (fmt, "mm", f, f.name)
    assert scan.normals is None


def test_units_and_duplicates_are_recorded(tmp_path):
    """A scan in inches is read in mm and says it was in inches; the points the file held
    count the duplicates removed."""
    P = grid()
    f = tmp_path / "scan.xyz"
    np.savetxt(f, np.vstack([P, P[:7]]) / 25.4, fmt="%.17g")
    scan = read_scan(f, units="in")
    assert scan.units == "in" and scan.n == len(P) and scan.points_read == len(P) + 7
    np.testing.assert_allclose(scan.points, P, rtol=0, atol=1e-12)


def test_density_of_a_half_millimetre_grid():
    """Points 0.5 mm apart on a (gently curved) sheet: 0.5 mm spacing, 4 points per mm^2."""
    P = grid(0.5, 120)
    P[:, 2] = 0.002 * (P[:, 0] - 30.0) ** 2  # a 1.8 mm sag over 60 mm
    scan = Scan(P)
    assert scan.format == "memory" and scan.points_read == scan.n == len(P)
    assert scan.spacing == pytest.approx(0.5, rel=0.02)
    assert scan.density == pytest.approx(4.0, rel=0.02)


def test_a_simulated_scan_is_a_scan_and_its_truth():
    """The virtual scanner's points are a :class:`Scan` (no normals: the true ones are kept
    beside it, for scoring only)."""
    V, F = thin_shell(60.0, 40.0, 2.0)
    sim = virtual_scan(V, F, ScanSpec(views=1, seed=2))
    assert isinstance(sim.scan, Scan) and sim.scan.format == "simulated"
    assert sim.scan.normals is None and sim.P is sim.scan.points
    assert sim.true_normals.shape == sim.P.shape == (sim.scan.n, 3)


def test_part_and_drawing_of_the_step_panel(tmp_path):
    """samples/panel.step: the part's mesh on its B-rep faces, in the file's unit; the
    drawing's zones from its PMI (the general zone last) and as many characteristics as
    ``qifreport plan`` lists."""
    step = SAMPLES / "panel.step"
    part, drawing = load_nominal(step, None)
    assert isinstance(part, Part) and isinstance(drawing, Drawing)
    assert part.source == step and part.units == "mm" and part.material is None
    assert part.is_solid and part.n_faces == part.info["b_rep_faces"] > 1
    assert part.face_id.shape == (len(part.F),) and part.face_id.max() < part.n_faces
    assert part.brep_normals.shape == (len(part.F), 3, 3)
    assert drawing.source == "pmi" and drawing.plan is not None
    pmi = [z for z in drawing.zones if z.step_id is not None]
    assert pmi and all(z.source == "pmi" and z.faces is not None for z in pmi)
    assert drawing.zones[-1].key == "general"
    r = subprocess.run(
        [str(EXE), "plan", str(step), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    listed = int(re.search(r"\((\d+) characteristics", r.stdout).group(1))
    zones = [z for z in drawing.zones if z.faces is not None or z.step_id is not None]
    assert len(drawing.plan.specs) + len(zones) == listed


def test_part_and_drawing_of_a_mesh_nominal():
    """samples/shell_nominal.ply with a 0.5 mm tolerance: a mesh without B-rep faces, and a
    drawing of one general zone, the operator's; without a tolerance it is refused."""
    mesh = SAMPLES / "shell_nominal.ply"
    part, drawing = load_nominal(mesh, 0.5)
    assert part.name == "shell_nominal" and part.source == mesh and part.units == "mm"
    assert part.face_id is None and part.brep_normals is None and part.n_faces == 0
    assert not part.is_solid and part.info["format"] == "mesh"
    assert drawing.source == "operator" and drawing.plan is None
    assert drawing.not_evaluated == [] and drawing.datums == []
    (zone,) = drawing.zones
    assert zone.key == "general" and zone.half_width == 0.5 and zone.source == "general"
    with pytest.raises(InputError, match="--tolerance"):
        load_nominal(mesh, None)
