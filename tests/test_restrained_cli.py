"""The restrained condition from the command line (issue 21): the thin shell held at its rim
by its elastic model, a dent that the free virtual fixture bent the nominal into, a part
that needs more than its clamps may give, and the inputs a restrained run refuses.

The free states are made by the shell's own elasticity on a truth model that is not the
product's (:mod:`qifreport.simulate.physical`: the shell meshed at 6 mm, 2 mm PP with
Poisson's ratio 0.37 against the product's 0.42; the product
decimates the 8,436-vertex nominal to 3,000 triangles): corner A2 pressed 1 mm, A4 lifted
2 mm. Scanned as 40,000 points with 10 um noise; the dent (1.0 mm deep, sigma 20 mm) is
pressed into the free state after (no elasticity made it).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.registration.mesh import load_mesh, vertex_normals
from qifreport.registration.restraint.elastic import Material, elastic_model
from qifreport.registration.restraint.sheet_solid import sheet_solid
from qifreport.simulate.defects import gaussian_bump
from qifreport.simulate.physical import elastic_free_state
from qifreport.simulate.shapes import rim_clamps, thin_shell
from tests.conftest import assert_valid_summary

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).parent / "qifreport"
NOMINAL = ROOT / "samples" / "shell_nominal.ply"
LIFTS = {"A2": -1.0, "A4": 2.0}  # mm along the normal
TOL = "0.3"


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([os.fsencode(EXE), *map(str, args)], capture_output=True)


@pytest.fixture(scope="module")
def shell_case(tmp_path_factory):
    """The nominal, its clamps file, the dent's centre and scans (conforming, dented)."""
    tmp = tmp_path_factory.mktemp("restrained")
    V, F = load_mesh(NOMINAL)
    N = vertex_normals(V, F)
    clamps, normals = rim_clamps(V, N, inset=6.0)
    rows = ["name,x,y,z,directions,max_force_N"]
    rows += [
        f"{c.name},{c.position[0]:.4f},{c.position[1]:.4f},{c.position[2]:.4f},{c.directions},"
        for c in clamps
    ]
    (tmp / "clamps.csv").write_text("\n".join(rows) + "\n")
    # the truth: another mesh of the same shell, another Poisson's ratio, larger pads
    Vt, Ft = thin_shell(spacing=6.0)
    solid = sheet_solid(Vt, Ft, vertex_normals(Vt, Ft), 2.0)
    model = elastic_model(solid.X, solid.T, Material("truth", 1500.0, 0.37, 0.0))
    V_free = V + elastic_free_state(model, clamps, np.array(normals), LIFTS, V, pad_radius=5.0)
    centre = V_free[np.argmin(np.linalg.norm(V[:, :2], axis=1))]
    rng = np.random.default_rng(3)
    A = np.linalg.norm(
        np.cross(V_free[F[:, 1]] - V_free[F[:, 0]], V_free[F[:, 2]] - V_free[F[:, 0]]), axis=1
    )
    t = rng.choice(len(F), 40_000, p=A / A.sum())
    b = rng.dirichlet(np.ones(3), len(t))
    Nf = vertex_normals(V_free, F)
    P = np.einsum("ij,ijk->ik", b, V_free[F[t]])
    n = np.einsum("ij,ijk->ik", b, Nf[F[t]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    noise = rng.normal(0.0, 0.01, (len(P), 1)) * n
    scans = {}
    for name, depth in (("conforming", 0.0), ("dented", 1.0)):
        Q = P + (gaussian_bump(P, n, centre, -depth, 20.0) if depth else 0.0) + noise
        scans[name] = tmp / f"{name}.ply"
        trimesh.PointCloud(Q.astype(np.float32)).export(scans[name])
    return {
        "tmp": tmp,
        "clamps": tmp / "clamps.csv",
        "centre": V[np.argmin(np.linalg.norm(V[:, :2], axis=1))],
        "scans": scans,
        "cache": tmp / "cache",
    }


def inspect(case, scan: str, *extra) -> tuple[subprocess.CompletedProcess, dict | None]:
    out = case["tmp"] / f"out-{scan}-{len(extra)}"
    r = run(
        NOMINAL,
        case["scans"][scan],
        "--tolerance",
        TOL,
        "--clamps",
        case["clamps"],
        "--thickness",
        "2",
        "--material",
        "pp",
        "--out",
        out,
        "--json",
        "--quiet",
        "--force",
        "--cache",
        case["cache"],
        *extra,
    )
    doc = out / "shell_nominal.json"
    if not doc.exists():
        return r, None
    data = json.loads(doc.read_text())
    assert_valid_summary(data)
    return r, data


def test_restrained_the_dent_fails_where_it_is_and_the_part_passes(shell_case):
    """Issue 21's acceptance test: the 1.0 mm x sigma 20 mm dent FAILs restrained with its
    region within 5 mm of its centre; the same part without it PASSes."""
    r, doc = inspect(shell_case, "dented")
    assert r.returncode == 1, r.stdout.decode() + r.stderr.decode()
    fx = doc["registration"]["fixture"]
    assert fx["decision"] == "restrained"
    centre = shell_case["centre"]
    regions = doc["acceptance"]["regions"]
    near = min(np.linalg.norm(np.asarray(g["centroid"]) - centre) for g in regions)
    assert near < 5.0, regions[:3]
    assert min(g["peak"] for g in regions) == pytest.approx(-1.0, abs=0.15)
    clamps = doc["registration"]["restraint"]["clamps"]
    assert [c["name"] for c in clamps] == ["A1", "A2", "A3", "A4", "B1", "C1"]
    held = doc["registration"]["restraint"]["model"]["clamp_set"]
    assert (held["kind"], held["directions"], held["removes_flex"]) == ("over-constrained", 7, True)
    assert held["motion_per_mm_misread"] < 2.0 and b"clamp set: over-constrained" in r.stdout
    assert all(c["force_N"] is not None for c in clamps)
    assert b"restrained (ISO 10579)" in r.stdout
    # the auditor's page says how the part was held
    pdf = shell_case["tmp"] / "out-dented-0" / "shell_nominal.pdf"
    text = subprocess.run(["pdftotext", "-layout", pdf, "-"], capture_output=True, check=True)
    page = text.stdout.decode()
    assert "RESTRAINED INSPECTION (ISO 10579)" in page and "6 clamps, PP" in page, page[:400]
    r, doc = inspect(shell_case, "conforming")
    assert r.returncode == 0, r.stdout.decode() + r.stderr.decode()
    assert doc["vertex_deviation"]["max_abs"] < 0.15
    # the corners were 3 mm apart in twist: held, each clamp face pushes
    forces = [c["force_N"] for c in doc["registration"]["restraint"]["clamps"][:4]]
    assert min(forces) > 0.01


def test_a_part_beyond_its_clamp_force_is_not_restrainable(shell_case):
    """The conforming part needs about a newton per corner (measured in the test above);
    with a 0.01 N limit it FAILs as not restrainable, naming the clamp."""
    r, doc = inspect(shell_case, "conforming", "--max-clamp-force", "0.01")
    assert r.returncode == 1, r.stdout.decode() + r.stderr.decode()
    assert any(d.startswith("not restrainable within 0.01 N") for d in doc["decided_by"])
    assert doc["registration"]["restraint"]["not_restrainable"]
    assert b"OVER LIMIT" in r.stdout
    # the same limit without a material: the forces cannot be known, so neither can the
    # part's restrainability: never a PASS
    out = shell_case["tmp"] / "no-material"
    r = run(
        NOMINAL,
        shell_case["scans"]["conforming"],
        *("--tolerance", TOL, "--clamps", shell_case["clamps"], "--thickness", "2"),
        *("--max-clamp-force", "0.01", "--out", out, "--json", "--quiet", "--force"),
        *("--cache", shell_case["cache"]),
    )
    assert r.returncode == 3, r.stdout.decode() + r.stderr.decode()
    doc = json.loads((out / "shell_nominal.json").read_text())
    assert any("not the material" in d for d in doc["decided_by"]), doc["decided_by"]


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("--clamps", "missing.csv"), "clamps file not found"),
        (("--fixture", "restrained"), "--fixture restrained needs the clamps"),
        (("--clamps", "{bad}"), "line 2: directions 'q'"),
        (("--clamps", "{off}"), "from the part's surface"),
        (("--clamps", "{few}"), "rigid motion(s) of the part free"),
        (("--clamps", "{weak}"), "the clamps hold a slide along x and a slide along y too"),
        (("--clamps", "{ok}", "--material", "unobtainium"), "unknown material"),
        (("--clamps", "{ok}", "--material", "pp"), "needs its wall thickness"),
        (("--clamps", "{ok}", "--gravity", "up"), "--gravity must be an axis"),
        (("--clamps", "{ok}", "--gravity=-z"), "--gravity needs the part's weight"),
        (("--clamps", "pmi"), "is a mesh, it has no datum targets"),
    ],
)
def test_a_restrained_run_refuses_bad_input_with_one_line(shell_case, tmp_path, args, named):
    ok = shell_case["clamps"].read_text()
    files = {
        "bad": "name,x,y,z,directions\nA1,0,0,0,q\n",
        "off": ok + "Z9,0,0,500,n,\n",
        "few": "\n".join(ok.splitlines()[:5]) + "\n",
        # the four corners' normals and two more at the long sides' middles (vertices)
        "weak": "\n".join(ok.splitlines()[:5])
        + "\nN5,-0.7522,-48.9726,6.6927,n\nN6,-0.7522,48.9726,6.6338,n\n",
        "ok": ok,
    }
    resolved = []
    for a in args:
        if a.startswith("{"):
            p = tmp_path / f"{a[1:-1]}.csv"
            p.write_text(files[a[1:-1]])
            a = str(p)
        resolved.append(a)
    extra = [] if "--material" in resolved else ["--thickness", "2"]
    r = run(
        NOMINAL,
        shell_case["scans"]["conforming"],
        "--tolerance",
        TOL,
        "--out",
        tmp_path / "o",
        "--no-cache",
        *extra,
        *resolved,
    )
    err = r.stderr.decode().strip()
    assert r.returncode == 2, (r.returncode, err)
    assert len(err.splitlines()) == 1 and named in err, err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())
