"""The qifreport console script on the bundled samples and on bad inputs."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tests.conftest import assert_valid_summary

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"


def run(*args, cwd=None):
    return subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
def test_demo_sample_passes_with_outputs(tmp_path):
    mesh_out = tmp_path / "reg.ply"
    r = run(
        SAMPLES / "shell_nominal.ply",
        SAMPLES / "shell_scan.ply",
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--json",
        "--export-mesh",
        mesh_out,
        "--quiet",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "verdict: PASS" in r.stdout
    doc = json.loads((tmp_path / "shell_nominal.json").read_text())
    assert_valid_summary(doc)
    assert doc["verdict"] == "PASS"
    vd = doc["vertex_deviation"]
    assert vd["rms"] < 0.05 and vd["p999"] < 0.2  # compliance (~4 mm) removed
    assert doc["acceptance"]["area_ok"] and doc["acceptance"]["region_ok"]
    assert 0.5 < doc["coverage"]["coverage"] <= 1.0
    assert len(doc["inputs"]["scan"]["sha256"]) == 64
    m = trimesh.load(mesh_out, process=False)
    dev = np.asarray(m.metadata["_ply_raw"]["vertex"]["data"]["deviation"])
    assert len(dev) == len(m.vertices) == 8436
    assert np.isnan(dev).sum() > 0  # unscored vertices are NaN, not 0
    assert np.nanmax(np.abs(dev)) < 0.5


@pytest.mark.slow
def test_defect_sample_fails_by_region(tmp_path):
    r = run(
        SAMPLES / "shell_nominal.ply",
        SAMPLES / "shell_scan_defect.ply",
        "--tolerance",
        "0.5",
        "--out",
        tmp_path,
        "--json",
    )  # with the progress bar
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Error" not in r.stderr and "Traceback" not in r.stderr
    doc = json.loads((tmp_path / "shell_nominal.json").read_text())
    assert_valid_summary(doc)
    assert doc["verdict"] == "FAIL"
    acc = doc["acceptance"]
    assert acc["area_ok"] and not acc["region_ok"]
    assert acc["regions"][0]["area"] > 25.0
    assert 0.6 < acc["regions"][0]["peak"] < 1.1


def write_points(path, P):
    trimesh.PointCloud(P).export(path)


@pytest.fixture(scope="module")
def scan_points():
    return np.asarray(trimesh.load(SAMPLES / "shell_scan.ply", process=False).vertices)


def bad_inputs(tmp: Path, P: np.ndarray):
    nominal = SAMPLES / "shell_nominal.ply"
    corrupt = tmp / "corrupt.ply"
    corrupt.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 500\n"
        b"property float x\nend_header\n\x01\x02"
    )
    empty = tmp / "empty.xyz"
    empty.write_text("")
    nan = tmp / "nan.npy"
    Pn = P.copy()
    Pn[::100] = np.nan
    np.save(nan, Pn)
    inch = tmp / "inch.ply"
    write_points(inch, P * 25.4)
    far = tmp / "far.ply"
    write_points(far, P + [500.0, 0.0, 0.0])
    # a scan of another object: a hemisphere of the shell's extent, somewhere else
    rng = np.random.default_rng(0)
    d = rng.normal(size=(8000, 3))
    d[:, 2] = np.abs(d[:, 2])
    other = tmp / "other.ply"
    write_points(
        other,
        70.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
        + [400.0, -300.0, 250.0]
        + 0.02 * rng.standard_normal(d.shape),
    )
    return {
        "missing nominal": ([tmp / "nope.stl", SAMPLES / "shell_scan.ply"], "not found"),
        "missing scan": ([nominal, tmp / "nope.ply"], "not found"),
        "corrupt scan": ([nominal, corrupt], "cannot read scan"),
        "corrupt nominal": ([corrupt, SAMPLES / "shell_scan.ply"], "nominal"),
        "empty scan": ([nominal, empty], "empty"),
        "NaN scan": ([nominal, nan], "NaN"),
        "inch scan": ([nominal, inch], "units"),
        # the user vouches that scan and part share a frame: no pose search, no overlap
        "no overlap": ([nominal, far, "--prealign", "never"], "does not overlap"),
        # the pose search finds no placement of another object on the part
        "another part": ([nominal, other], "does not overlap"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "missing nominal",
        "missing scan",
        "corrupt scan",
        "corrupt nominal",
        "empty scan",
        "NaN scan",
        "inch scan",
        "no overlap",
        "another part",
    ],
)
def test_bad_input_one_line_exit_2_no_output(tmp_path, scan_points, case):
    args, expect = bad_inputs(tmp_path, scan_points)[case]
    out = tmp_path / "out"
    r = run(
        *args,
        "--tolerance",
        "0.5",
        "--out",
        out,
        "--json",
        "--export-mesh",
        out / "m.ply",
        "--quiet",
    )
    assert r.returncode == 2, (case, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qifreport: error:"), r.stderr
    assert expect in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())  # no partial output
    assert r.stdout == ""


def test_bad_tolerance_is_an_error():
    r = run(SAMPLES / "shell_nominal.ply", SAMPLES / "shell_scan.ply", "--tolerance", "-1")
    assert r.returncode == 2 and "tolerance" in r.stderr
