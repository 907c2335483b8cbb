"""A wheel install, as a new user gets it: one top-level package, the JSON schema shipped,
the QIF XSDs not shipped, and the inspection running from the installed copy (outside the
repository) with ``QIFREPORT_XSD_DIR`` pointing at the official schemas."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.conftest import shared_file

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel, built from a copy of the tracked files (the build leaves the tree alone)."""
    src = tmp_path_factory.mktemp("src")
    files = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    for f in (f for f in files if (ROOT / f).is_file()):
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / f, src / f)
    d = tmp_path_factory.mktemp("wheel")
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(d), str(src)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    (whl,) = d.glob("qifreport-*.whl")
    return whl


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("site")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "-q",
            "--target",
            str(target),
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return target


def test_wheel_has_one_top_level_package_and_the_json_schema(wheel):
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        (top,) = [n for n in names if n.endswith(".dist-info/top_level.txt")]
        assert z.read(top).decode().split() == ["qifreport"]
    roots = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert roots == {"qifreport"}, roots
    assert "qifreport/schemas/summary-1.schema.json" in names
    # the HTML viewer's own script and style (package data of qifreport.reports)
    assert {"qifreport/reports/viewer.js", "qifreport/reports/viewer.css"} <= set(names)
    for sub in ("step", "registration", "metrology", "qif", "batch", "reports"):
        assert f"qifreport/{sub}/__init__.py" in names, sub
    assert not [n for n in names if n.endswith(".xsd")], "the QIF XSDs must never be shipped"


def _run(installed: Path, args: list[str], cwd: Path, **env) -> subprocess.CompletedProcess:
    e = {**os.environ, "PYTHONPATH": str(installed), **env}
    return subprocess.run(
        [sys.executable, *args], cwd=cwd, env=e, capture_output=True, text=True, timeout=900
    )


def test_installed_copy_inspects_the_sample_panel(installed, tmp_path):
    xsd = shared_file("qif/xsd")
    out = tmp_path / "out"
    r = _run(
        installed,
        [
            "-c",
            "import qifreport, qifreport.step; print(qifreport.__file__);"
            "print(qifreport.step.__file__)",
        ],
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr
    assert all(line.startswith(str(installed)) for line in r.stdout.split()), r.stdout
    r = _run(
        installed,
        [
            "-m",
            "qifreport",
            str(ROOT / "samples" / "panel.step"),
            str(ROOT / "samples" / "panel_scan.ply"),
            "--out",
            str(out),
            "--json",
            "--html",
            "--quiet",
        ],
        cwd=tmp_path,
        QIFREPORT_XSD_DIR=str(xsd),
    )
    assert r.returncode == 0, r.stdout + r.stderr
    doc = json.loads((out / "panel.json").read_text())
    assert doc["verdict"] == "PASS" and doc["qif"]["valid"] is True, doc["qif"]
    assert (out / "panel.pdf").stat().st_size > 10_000
    # the HTML viewer from the installed copy: its script and three.js inside, under 5 MB
    size = (out / "panel.html").stat().st_size
    print(f"panel.html: {size / 1e6:.2f} MB")
    page = (out / "panel.html").read_text(encoding="utf-8")
    assert 500_000 < size < 5_000_000 and "THREE.TrackballControls" in page
    assert "function pickAt" in page and 'id="viewer-data"' in page


def test_installed_copy_without_xsds_says_where_to_put_them(installed, tmp_path):
    """No XSDs: the QIF is written and called not validated, naming the folder to fill."""
    r = _run(
        installed,
        ["-c", "from qifreport.qif.validate import schema_dir; schema_dir()"],
        cwd=tmp_path,
        QIFREPORT_XSD_DIR="",
    )
    assert r.returncode != 0
    assert "SchemasUnavailable" in r.stderr and "QIFREPORT_XSD_DIR" in r.stderr
    assert str(installed / "qifreport" / "schemas" / "qif-3.0") in r.stderr, r.stderr


#: what trimesh needs, beyond itself, for the functions the product calls: name in the
#: product's source -> the distribution it needs at run time
TRIMESH_NEEDS = {"trimesh.proximity": "rtree"}


def _requirement_names(reqs: list[str]) -> set[str]:
    import re

    return {re.split(r"[<>=!~ ;\[]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}


def test_every_library_the_product_imports_is_declared_for_a_user_s_install():
    """Every third-party module the installed package imports is a runtime dependency (or
    an optional feature's extra: E57, CHOLMOD), and so is what trimesh needs for the
    functions the product calls: a plain install once crashed on FTC 08 with an internal
    error (``trimesh.proximity`` needs ``rtree``, then only a test dependency)."""
    import ast
    import importlib.metadata as md

    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    runtime = _requirement_names(project["dependencies"])
    extras = project["optional-dependencies"]
    declared = runtime | _requirement_names(extras["e57"] + extras["cholmod"])
    dists = md.packages_distributions()
    missing = set()
    for folder in ("step", "registration", "metrology", "qif", "qifreport"):
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text()
            for name, need in TRIMESH_NEEDS.items():
                if name in text and need not in runtime:
                    missing.add(f"{path.relative_to(ROOT)}: {name} needs {need}")
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, ast.Import):
                    tops = [a.name.split(".")[0] for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    tops = [node.module.split(".")[0]]
                else:
                    continue
                for top in tops:
                    if top in sys.stdlib_module_names or top == "qifreport":
                        continue
                    names = {d.lower().replace("_", "-") for d in dists.get(top, [top])}
                    if not names & declared:
                        missing.add(f"{path.relative_to(ROOT)}: {top} ({', '.join(names)})")
    assert not missing, sorted(missing)
