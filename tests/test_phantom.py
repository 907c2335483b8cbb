"""No phantom deviation: mesh nominals scanned at their own vertices read their noise, their
rim where it is; a solid's trim edges are reported, not judged.

Every point lies on the nominal mesh (5 um noise along the vertex normal), so every scored
vertex must read within 4 sigma of zero. A plane fitted to the points about a vertex reads
a curved surface's sag inside its ball as deviation (0.025 mm on the 40 mm bumpy sphere,
up to 0.14 mm beside the fandisk's creases); the fit of the points' own distances to the
mesh does not.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.metrology.deviation.local_planes import nominal_referenced
from qifreport.metrology.deviation.part_class import SHEET, SOLID, part_class
from qifreport.metrology.stages.deviation import vertex_deviation
from qifreport.registration.mesh import (
    crease_band,
    load_mesh,
    median_edge_length,
    vertex_normals,
)
from qifreport.simulate.shapes import bumpy_sphere, fandisk
from tests.conftest import shared_file

NOISE = 0.005
ROOT = Path(__file__).resolve().parents[1]


def own_vertices(V: np.ndarray, F: np.ndarray, seed: int = 0) -> np.ndarray:
    """The vertices moved along their normals by Gaussian noise of ``NOISE`` mm."""
    rng = np.random.default_rng(seed)
    return V + rng.normal(0.0, NOISE, len(V))[:, None] * vertex_normals(V, F)


@pytest.mark.parametrize("shape", ["bumpy sphere", "fandisk"])
def test_mesh_nominal_at_its_own_vertices_reads_its_noise(shape):
    if shape == "fandisk":
        V, F = fandisk(str(shared_file("meshes/fandisk.off")))
    else:
        V, F = bumpy_sphere()
    P = own_vertices(V, F)
    N = vertex_normals(V, F)
    scored = ~crease_band(V, F, 1.5 * median_edge_length(V, F), 45.0)
    dev, var = vertex_deviation(V, F, P, N, None)
    d = dev[scored]
    assert np.isfinite(d).mean() > 0.99
    assert np.nanmax(np.abs(d)) <= 4 * NOISE
    assert np.sqrt(np.nanmean(d**2)) < NOISE
    assert np.all(np.isfinite(var[scored][np.isfinite(d)]))
    # the plane fit this replaces: the curvature's sag, several sigma
    plane = nominal_referenced(V, F, P, normals=N)[scored]
    assert np.nanmax(np.abs(plane)) > 8 * NOISE


def _own_vertex_run(
    tmp_path, V: np.ndarray, F: np.ndarray, tolerance: float = 0.5
) -> tuple[int, dict]:
    """``qifreport NOMINAL SCAN --tolerance T`` on the mesh and a scan of its own vertices:
    the exit code and the JSON summary."""
    nominal = tmp_path / "nominal.ply"
    trimesh.Trimesh(V, F, process=False).export(nominal)
    scan = tmp_path / "scan.xyz"
    np.savetxt(scan, own_vertices(V, F), fmt="%.6f")
    out = tmp_path / "out"
    exe = Path(sys.executable).parent / "qifreport"
    args = [nominal, scan, "--tolerance", tolerance, "--out", out, "--json", "--no-pdf"]
    args.append("--no-cache")
    r = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True)
    return r.returncode, json.loads((out / "nominal.json").read_text())


def test_shell_at_its_own_vertices_passes_with_its_rim_where_it_is(tmp_path):
    """The open shell: PASS, every vertex within 4 sigma; the trim edge at the mesh's rim
    (the outermost row of points is the rim: no spacing added) and the size 1."""
    V, F = load_mesh(ROOT / "samples" / "shell_nominal.ply")
    rc, doc = _own_vertex_run(tmp_path, V, F)
    assert (rc, doc["verdict"]) == (0, "PASS"), doc["warnings"]
    assert doc["vertex_deviation"]["max_abs"] <= 4 * NOISE
    edges = doc["edges"]
    assert edges["status"] == "measured" and edges["seen_fraction"] > 0.5, edges
    st = edges["statistics_mm"]
    assert max(abs(st["median"]), abs(st["p05"]), abs(st["p95"])) < 0.05, st
    assert doc["size"]["status"] == "conforming"
    assert abs(doc["size"]["scale"] - 1.0) < 0.001
    assert abs(doc["size"]["size_deviation_mm"]) < 0.05


def test_organic_mesh_at_its_own_vertices_passes(tmp_path):
    """A smooth closed surface without rim or crease: PASS, every vertex within 4 sigma."""
    V, F = bumpy_sphere()
    rc, doc = _own_vertex_run(tmp_path, V, F)
    assert (rc, doc["verdict"]) == (0, "PASS"), doc["warnings"]
    assert doc["vertex_deviation"]["n"] == len(V)
    assert doc["vertex_deviation"]["max_abs"] <= 4 * NOISE
    assert doc["edges"]["status"] == "no rim"


def _box(size: tuple[float, float, float], levels: int = 2) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.box(extents=size)
    for _ in range(levels):
        m = m.subdivide()
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def test_points_past_a_crease_do_not_score_the_face_below():
    """A block whose real +x face stands 1 mm outside the nominal's, scanned on its top face
    only (0.6 mm spacing, the mesh's edge): the top face's points past the nominal's crease
    are closest to the +x face, +0 to +1 mm off it, and scored its vertices up to 1.2 mm
    below the crease at +1.0 mm (23 vertices outside the crease band) before the rule. They
    lie on the top face's plane, so they measure neither face: the +x face is not measured,
    the top face reads its noise."""
    V, F = _box((20.0, 20.0, 10.0), levels=5)
    rng = np.random.default_rng(0)
    grid = np.arange(-10.0, 11.0 + 1e-9, 0.6), np.arange(-10.0, 10.0 + 1e-9, 0.6)
    x, y = np.meshgrid(*grid)
    P = np.c_[x.ravel(), y.ravel(), 5.0 + rng.normal(0.0, NOISE, x.size)]
    dev, _ = vertex_deviation(V, F, P, vertex_normals(V, F), None)
    away = ~crease_band(V, F, 1.5 * median_edge_length(V, F), 45.0)
    side = away & np.isclose(V[:, 0], 10.0)
    top = away & np.isclose(V[:, 2], 5.0)
    assert side.sum() > 500 and np.nanmax(np.abs(dev[side]), initial=0.0) <= 4 * NOISE
    assert np.isfinite(dev[top]).all() and np.abs(dev[top]).max() <= 4 * NOISE


def test_part_class_from_the_geometry():
    """An open mesh and a thin closed slab are sheets (their trim edges judged); a block
    and the fandisk are solids (reported, not judged)."""
    shell = part_class(*load_mesh(ROOT / "samples" / "shell_nominal.ply"), solid=False)
    assert (shell.kind, shell.open_rim, shell.judges_trim_edges) == (SHEET, True, True)
    slab = part_class(*_box((120.0, 80.0, 1.8)), solid=True)
    assert slab.kind == SHEET and slab.thin_area > 0.9
    assert slab.wall == pytest.approx(1.8, abs=0.01)
    block = part_class(*_box((120.0, 80.0, 40.0)), solid=True)
    assert block.kind == SOLID and block.thin_area < 0.1 and not block.judges_trim_edges
    disk = part_class(*fandisk(str(shared_file("meshes/fandisk.off"))), solid=False)
    assert disk.kind == SOLID


def test_machined_solid_trim_edges_are_reported_not_judged(tmp_path):
    """The fandisk (a closed solid) at its own vertices against a 0.05 mm tolerance: its
    trim creases read a size that is not established (judged, the verdict would be NOT
    ESTABLISHED, exit 3); on a solid it is a note, and the part PASSes."""
    V, F = fandisk(str(shared_file("meshes/fandisk.off")))
    rc, doc = _own_vertex_run(tmp_path, V, F, tolerance=0.05)
    assert (rc, doc["verdict"]) == (0, "PASS"), doc["warnings"]
    assert doc["vertex_deviation"]["max_abs"] <= 4 * NOISE
    edges = doc["edges"]
    assert edges["status"] == "measured" and edges["judged"] is False
    assert edges["part_class"]["kind"] == SOLID
    assert doc["size"]["status"] == "not established"  # what a judged size would decide
    assert not any("size" in w for w in doc["warnings"])
