"""Big and odd scans (issue 19, item 9 and two reader defects): exact duplicates removed on
reading, text headers read by column name, a file's real format named when its suffix lies,
degenerate (collinear) scans refused, dense scans voxel-thinned on the nominal's grid and
reported in the JSON ``scan_input`` block, and a batch manifest naming one scan twice.

Every file is written in ``tmp_path``; the CLI runs as a subprocess, as a user runs it.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qifreport.batch.plan import plan
from qifreport.errors import InputError
from qifreport.nominal import load_nominal
from qifreport.pipeline import scan_input
from qifreport.registration.mesh import load_mesh
from qifreport.registration.pointcloud import (
    read_scan,
    unique_points,
    validate_scan,
)
from qifreport.registration.thinning import (
    MIN_POINTS_PER_VOXEL,
    nominal_spacing,
    thin_scan,
)
from qifreport.summary import validate_summary
from tests.conftest import ROOT
from tests.test_fuzz_readers import encode, grid_mesh

SAMPLES = ROOT / "samples"
NOMINAL = SAMPLES / "shell_nominal.ply"
EXE = Path(sys.executable).parent / "qifreport"


def _refused(path: Path, *words: str) -> str:
    """The one-line InputError ``read_scan(path)`` raises; it names the file and ``words``."""
    with pytest.raises(InputError) as exc:
        read_scan(path)
    msg = str(exc.value)
    assert "\n" not in msg and path.name in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def _write_ply(path: Path, P: np.ndarray) -> None:
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(P)}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    path.write_bytes(head.encode() + np.ascontiguousarray(P, dtype="<f4").tobytes())


# ------------------------------------------------------------------------------------------
# exact duplicates


@pytest.mark.parametrize("fmt", ["stl-binary", "stl-ascii"])
def test_stl_scan_is_its_distinct_vertices(tmp_path, fmt):
    """An STL repeats every vertex once per triangle (600 corners of 121 vertices): the
    scan is the 121 distinct points, the first of each in file order."""
    V, F = grid_mesh()
    f = tmp_path / "scan.stl"
    f.write_bytes(encode(fmt, V, F))
    scan = read_scan(f)
    P, n_read = scan.points, scan.points_read
    assert n_read == 3 * len(F) == 600
    assert len(P) == len(V) == 121
    order = np.unique(F.ravel(), return_index=True)[1]  # first corner naming each vertex
    want = V[F.ravel()[np.sort(order)]]
    np.testing.assert_allclose(P, want, rtol=0, atol=1e-5)


def test_unique_points_keeps_first_occurrences_in_order():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(5000, 3))
    base[0] = [0.0, 1.0, 2.0]
    idx = rng.integers(0, len(base), 20000)
    P = base[idx].copy()
    P[-1] = [-0.0, 1.0, 2.0]  # equal to [0, 1, 2]
    Q, removed = unique_points(P)
    _, first = np.unique(P + 0.0, axis=0, return_index=True)
    np.testing.assert_array_equal(Q, P[np.sort(first)])
    assert removed == len(P) - len(Q)
    R = rng.normal(size=(1000, 3))
    same, none = unique_points(R)
    assert none == 0 and same is R  # no copy when nothing repeats


def test_too_few_distinct_points_is_refused(tmp_path):
    f = tmp_path / "few.xyz"
    P = np.repeat(np.random.default_rng(0).normal(size=(40, 3)), 5, axis=0)  # 200 rows
    np.savetxt(f, P)
    _refused(f, "only 40 distinct points", "200 read")


# ------------------------------------------------------------------------------------------
# text headers


def test_csv_header_names_the_columns(tmp_path):
    """``id,x,y,z``: the coordinates by name, not the first three columns."""
    V = grid_mesh()[0]
    rows3 = V.tolist()  # floats: repr() prints them exactly
    f = tmp_path / "scan.csv"
    rows = "\n".join(f"{k},{x!r},{y!r},{z!r}" for k, (x, y, z) in enumerate(rows3))
    f.write_text("id,x,y,z\n" + rows + "\n")
    np.testing.assert_array_equal(read_scan(f).points, V)
    # any order, any case, with units; whitespace-separated XYZ too
    g = tmp_path / "scan2.csv"
    rows = "\n".join(f"{z!r},7,{x!r},{y!r}" for x, y, z in rows3)
    g.write_text('# exported\n Z (mm),Flag,X_mm,"Y [mm]"\n' + rows + "\n")
    np.testing.assert_array_equal(read_scan(g).points, V)
    h = tmp_path / "scan.xyz"
    h.write_text("nx x y z\n" + "\n".join(f"0 {x!r} {y!r} {z!r}" for x, y, z in rows3) + "\n")
    np.testing.assert_array_equal(read_scan(h).points, V)


def test_header_without_xyz_is_refused_naming_the_columns(tmp_path):
    f = tmp_path / "scan.csv"
    f.write_text("id,a,b,c\n" + "\n".join(f"{k},1,2,{k}" for k in range(200)) + "\n")
    msg = _refused(f, "x, y, z", "'id'", "'a'", "'c'")
    assert "columns" in msg
    g = tmp_path / "twice.csv"
    g.write_text("x,y,z,x\n" + "\n".join(f"{k},1,{k},2" for k in range(200)) + "\n")
    _refused(g, "x twice")


# ------------------------------------------------------------------------------------------
# the format actually found


def test_ply_named_npy_names_the_format(tmp_path):
    V, F = grid_mesh()
    f = tmp_path / "scan.npy"
    f.write_bytes(encode("ply-binary-points", V, F))
    msg = _refused(f, "looks like a PLY file", "NumPy .npy")
    assert "pickle" not in msg
    g = tmp_path / "mesh.ply"
    g.write_bytes(encode("stl-binary", V, F))
    _refused(g, "looks like an STL file, not PLY")
    h = tmp_path / "points.xyz"
    h.write_bytes(encode("npy", V, F))
    _refused(h, "looks like a NumPy .npy file")
    k = tmp_path / "junk.npy"
    k.write_bytes(b"0 0 0\n" * 200)
    assert "pickle" not in _refused(k, "not a NumPy .npy file")


# ------------------------------------------------------------------------------------------
# degenerate scans


def test_collinear_points_are_refused_a_plane_is_not():
    t = np.linspace(0.0, 100.0, 1000)
    rng = np.random.default_rng(0)
    line = np.column_stack([t, 0.5 * t, 2.0 + 0 * t]) + rng.normal(0, 1e-3, (1000, 3))
    with pytest.raises(InputError, match="lie on a line"):
        validate_scan(line, "line.xyz")
    u, v = np.meshgrid(np.linspace(0, 100, 40), np.linspace(0, 60, 30))
    plane = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    assert validate_scan(plane).shape == (1200, 3)  # a flat panel is a valid scan


def test_collinear_scan_exits_2_with_one_line_and_no_output(tmp_path):
    """Issue 19: a 1,000-point collinear scan went through to FAIL with reports."""
    t = np.linspace(-80.0, 80.0, 1000)
    f = tmp_path / "line.xyz"
    np.savetxt(f, np.column_stack([t, 0.3 * t, 10.0 + 0 * t]))
    out = tmp_path / "out"
    r = subprocess.run(
        [EXE, NOMINAL, f, "--tolerance", "0.5", "--out", out, "--json", "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and "line.xyz" in r.stderr and "line" in r.stderr
    assert not out.exists() or not any(out.iterdir())


# ------------------------------------------------------------------------------------------
# thinning


def test_thin_scan_keeps_one_measured_point_per_cell():
    rng = np.random.default_rng(1)
    P = rng.uniform(0.0, 10.0, (200_000, 3))
    P[:, 2] *= 0.01  # a 10 x 10 mm sheet, 0.1 mm thick
    Q, rep = thin_scan(P, 0.5, points_read=210_000)
    g = 0.5 / np.sqrt(MIN_POINTS_PER_VOXEL)  # the kept grid: finer than the nominal's
    assert rep.grid_mm == 0.5 and rep.voxel_mm == pytest.approx(g, rel=1e-15)
    assert rep.points_used == len(Q) and rep.duplicates_removed == 10_000
    assert rep.points_per_voxel >= MIN_POINTS_PER_VOXEL
    cells = np.floor((Q - P.min(axis=0)) / g).astype(int)
    n = int(np.ceil(10.0 / g))
    assert len(np.unique(cells, axis=0)) == len(Q) == n * n  # one point per occupied cell
    idx = np.flatnonzero((P[:, None, :] == Q[None, :3, :]).all(axis=2).any(axis=1))
    assert len(idx) == 3  # the kept points are scan points, in scan order
    np.testing.assert_array_equal(Q[:3], P[np.sort(idx)])
    # the point nearest its cell's centroid
    c0 = cells[0]
    members = P[(np.floor((P - P.min(axis=0)) / g).astype(int) == c0).all(axis=1)]
    d = np.linalg.norm(members - members.mean(axis=0), axis=1)
    np.testing.assert_array_equal(Q[0], members[np.argmin(d)])
    # deterministic; a far outlier takes the exact ranking path and changes nothing else
    np.testing.assert_array_equal(thin_scan(P, 0.5)[0], Q)
    R, _ = thin_scan(np.vstack([P, [[1e30, 5.0, 0.05]]]), 0.5)  # same grid origin
    np.testing.assert_array_equal(R[:-1], Q)
    # not dense enough: untouched
    S, rep = thin_scan(P[:200], 0.5)
    assert len(S) == 200 and rep.voxel_mm is None and not rep.thinned


def test_a_denser_scan_never_uses_fewer_points():
    """No cliff: the points an inspection uses grow with the scan's density up to the
    threshold, stay about level past it (the finer grid keeps about what the scan had), and
    stop growing at about MIN_POINTS_PER_VOXEL per cell of the nominal's grid. A rule
    thinning to the nominal's grid itself at the threshold keeps a third fewer there."""
    rng = np.random.default_rng(2)
    used = []
    sizes = [400, 600, 800, 1000, 1200, 1500, 2000, 3000, 6000, 20_000, 60_000]
    for n in sizes:
        P = rng.uniform(0.0, 10.0, (n, 3))
        P[:, 2] *= 0.01
        used.append(thin_scan(P, 0.5)[1].points_used)
    cells = 20 * 20  # the nominal grid's cells on the sheet
    for a, b in zip(used, used[1:], strict=False):
        assert b >= 0.9 * a, used
    assert used[-1] <= MIN_POINTS_PER_VOXEL * cells * 1.2, used
    assert max(used) <= 1.05 * used[-1], used


@pytest.mark.parametrize(
    "nominal, scan",
    [("shell_nominal.ply", "shell_scan.ply"), ("panel.step", "panel_scan.ply")],
)
def test_samples_are_not_thinned(nominal, scan):
    """The normal-density samples keep every point: their results do not change."""
    part, _ = load_nominal(SAMPLES / nominal, 0.5)
    read = read_scan(SAMPLES / scan)
    Q, rep, _ = scan_input(read, part)
    assert Q is read.points and not rep.thinned
    assert rep.points_used == read.points_read == read.n
    assert rep.points_per_voxel < 0.9 * MIN_POINTS_PER_VOXEL  # a margin


def test_dense_scan_is_thinned_and_reported(tmp_path):
    """A 305k-point scan (eight jittered copies of every point of the shell sample) is
    thinned on the nominal's grid, reported in the JSON ``scan_input`` block, and passes as
    the sample does."""
    S = read_scan(SAMPLES / "shell_scan.ply").points
    rng = np.random.default_rng(5)
    P = np.repeat(S, 8, axis=0) + rng.normal(0.0, 0.01, (8 * len(S), 3))
    f = tmp_path / "dense.ply"
    _write_ply(f, P)
    out = tmp_path / "out"
    r = subprocess.run(
        [EXE, NOMINAL, f, "--tolerance", "0.5", "--out", out, "--json", "--quiet", "--no-pdf"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads((out / "shell_nominal.json").read_text())
    # the block conforms to the schema (other parts of the document are not this test's)
    assert not [e for e in validate_summary(doc) if "scan_input" in e]
    bad = {**doc, "scan_input": {**doc["scan_input"], "points_used": -1, "extra": 1}}
    assert len([e for e in validate_summary(bad) if "scan_input" in e]) == 2
    si = doc["scan_input"]
    V, F = load_mesh(NOMINAL)
    assert si["points_read"] == len(P) and si["duplicates_removed"] == 0
    h = nominal_spacing(V, F)
    assert si["grid_mm"] == pytest.approx(h, rel=1e-12)
    assert si["voxel_mm"] == pytest.approx(h / np.sqrt(MIN_POINTS_PER_VOXEL), rel=1e-12)
    assert si["points_per_voxel"] >= MIN_POINTS_PER_VOXEL
    assert len(S) // 2 < si["points_used"] < len(S) * 1.2  # about the sample's density


# ------------------------------------------------------------------------------------------
# a manifest naming one scan twice


def test_manifest_naming_one_scan_twice(tmp_path, caplog):
    """One scan cannot be two parts: two serial numbers (or nominals) for one scan file are
    refused naming the rows; a repeat that agrees is inspected once, with a warning."""
    scans = tmp_path / "scans"
    scans.mkdir()
    for name in ("a.ply", "b.ply"):
        (scans / name).write_bytes((SAMPLES / "shell_scan.ply").read_bytes())
    m = tmp_path / "two_serials.csv"
    m.write_text("scan,serial\nscans/a.ply,SN-1\nscans/b.ply,SN-2\nscans/a.ply,SN-3\n")
    with pytest.raises(InputError) as exc:
        plan(NOMINAL, [str(m)])
    msg = str(exc.value)
    assert "\n" not in msg and "a.ply" in msg and "'SN-1'" in msg and "'SN-3'" in msg
    assert "two_serials.csv line 2" in msg and "two_serials.csv line 4" in msg
    # the same row twice: inspected once, with a warning
    m2 = tmp_path / "repeated.csv"
    m2.write_text("scan,serial\nscans/a.ply,SN-1\nscans/b.ply,SN-2\nscans/a.ply,SN-1\n")
    with caplog.at_level(logging.WARNING, logger="qifreport.batch"):
        items = plan(NOMINAL, [str(m2)])
    assert [i.id for i in items] == ["SN-1", "SN-2"]
    assert "listed twice" in caplog.text and "repeated.csv line 4" in caplog.text
    # a folder, then the manifest that gives the serials: each scan once, with its serial
    items = plan(NOMINAL, [str(scans), str(m2)])
    assert [(i.scan.name, i.serial) for i in items] == [("a.ply", "SN-1"), ("b.ply", "SN-2")]
    # one scan against two nominals
    m3 = tmp_path / "two_nominals.csv"
    m3.write_text(f"scan,nominal\nscans/a.ply,{NOMINAL}\nscans/a.ply,other.ply\n")
    with pytest.raises(InputError, match="different nominals"):
        plan(NOMINAL, [str(m3)])
