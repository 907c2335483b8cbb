"""The architecture contract: one import root, the layering of pyproject's
``[tool.importlinter]`` (checked by import-linter, a tool we did not write), no cycles, no
cross-module imports of private names.

import-linter reads a package from the file system, so it is run on a copy of the sources
laid out as a wheel installs them (``step/`` -> ``qifreport/step/`` ...: the package-dir
mapping of pyproject.toml).
"""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: package -> folder, from pyproject's package-dir
PACKAGE_DIR = PYPROJECT["tool"]["setuptools"]["package-dir"]
CONTRACTS = {c["id"]: c for c in PYPROJECT["tool"]["importlinter"]["contracts"]}
#: the foundation modules every layer may import
FOUNDATION = {
    "qifreport",
    "qifreport.errors",
    "qifreport.atomic_io",
    "qifreport.jsonio",
    "qifreport.schemas",
    "qifreport.kinds",
}
LIBRARY = {"qifreport.step", "qifreport.registration", "qifreport.metrology", "qifreport.qif"}


def lint_imports_exe() -> str:
    exe = Path(sys.executable).with_name("lint-imports")
    if not exe.exists():
        msg = "lint-imports (import-linter) is not installed: make install-dev (make test does)"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return str(exe)


def installed_tree(dest: Path) -> Path:
    """Copy the Python sources into ``dest`` as the wheel lays them out; returns ``dest``."""
    for pkg, folder in sorted(PACKAGE_DIR.items(), key=lambda kv: kv[0].count(".")):
        target = dest.joinpath(*pkg.split("."))
        src = ROOT / folder
        for f in src.rglob("*.py"):
            rel = f.relative_to(src)
            if any(part in ("__pycache__",) for part in rel.parts):
                continue
            # a mapped sub-package's own files come from its own folder
            if pkg == "qifreport" and rel.parts[0] in {
                p.split(".")[1] for p in PACKAGE_DIR if p.count(".") == 1
            }:
                continue
            out = target / rel
            out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, out)
    return dest


def run_lint(tree: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run(
        [lint_imports_exe(), str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    return installed_tree(tmp_path_factory.mktemp("installed"))


def test_contracts_hold(tree):
    r = run_lint(tree)
    assert r.returncode == 0, r.stdout + r.stderr
    kept = r.stdout.count("KEPT")
    assert kept == len(CONTRACTS), r.stdout


@pytest.mark.parametrize(
    "victim, bad_import, contract",
    [
        ("qifreport/step/p21.py", "import qifreport.cli", "library-below-app"),
        (
            "qifreport/registration/icp.py",
            "import qifreport.metrology.acceptance.statistics",
            "library-layers",
        ),
        (
            "qifreport/metrology/acceptance/bands.py",
            "import qifreport.qif.writer",
            "library-layers",
        ),
        (
            "qifreport/registration/deformable/rbffem.py",
            "import qifreport.simulate.deform",
            "no-simulator-in-production",
        ),
        ("qifreport/options.py", "import qifreport.nominal", "app-layers"),
        ("qifreport/errors.py", "import qifreport.step.p21", "foundation"),
        ("qifreport/kinds.py", "import qifreport.metrology.gdt.geometric", "foundation"),
        ("qifreport/batch/plan.py", "import qifreport.batch.run", "acyclic"),
        (
            "qifreport/metrology/acceptance/criteria.py",
            "import qifreport.metrology.judgement",
            "metrology-stages",
        ),
        (
            "qifreport/metrology/gdt/form.py",
            "import qifreport.metrology.restraint.held",
            "metrology-stages",
        ),
        (
            "qifreport/metrology/stages/deviation.py",
            "import qifreport.metrology.stages.readings",
            "judgement-stages",
        ),
        (
            "qifreport/metrology/stages/acceptance.py",
            "import qifreport.metrology.judgement",
            "metrology-stages",
        ),
        (
            "qifreport/registration/mesh.py",
            "import qifreport.registration.deformable.gbcicp",
            "registration-parts",
        ),
        (
            "qifreport/registration/scan.py",
            "import qifreport.registration.pointcloud",
            "registration-parts",
        ),
        (
            "qifreport/metrology/model.py",
            "import qifreport.metrology.judgement",
            "metrology-stages",
        ),
    ],
)
def test_a_bad_import_breaks_the_contract(tmp_path, victim, bad_import, contract):
    """Each contract fails on a deliberately added bad import, naming itself."""
    tree = installed_tree(tmp_path / "t")
    f = tree / victim
    f.write_text(f.read_text() + f"\n\ndef _probe():\n    {bad_import}\n")
    r = run_lint(tree)
    assert r.returncode != 0, r.stdout
    said = " ".join(r.stdout.split())  # the report wraps long contract names
    assert " ".join(CONTRACTS[contract]["name"].split()) in said, r.stdout
    assert "BROKEN" in r.stdout, r.stdout


def _app_modules() -> set[str]:
    """The top-level modules and packages of the application layer (qifreport/)."""
    mapped = {p.split(".")[1] for p in PACKAGE_DIR if p.count(".") == 1}
    out = set()
    for p in (ROOT / "qifreport").iterdir():
        name = p.stem if p.suffix == ".py" else p.name
        if name.startswith("__") or name in mapped:
            continue
        if p.suffix == ".py" or (p / "__init__.py").is_file():
            out.add(f"qifreport.{name}")
    return out - FOUNDATION


def test_every_application_module_is_under_contract():
    """A new module of qifreport/ must be named in the contracts (else nothing checks it)."""
    app = _app_modules()
    forbidden = set(CONTRACTS["library-below-app"]["forbidden_modules"])
    assert app <= forbidden, f"not in library-below-app: {sorted(app - forbidden)}"
    layered = {m.strip() for layer in CONTRACTS["app-layers"]["layers"] for m in layer.split("|")}
    assert app - {"qifreport.simulate"} <= layered, sorted(app - layered)


def test_one_top_level_package_and_no_private_cross_imports():
    """Only ``qifreport`` is importable from the installed layout, and no module imports
    another module's private ``_name``."""
    assert {p.split(".")[0] for p in PACKAGE_DIR} == {"qifreport"}
    offenders = []
    for folder in set(PACKAGE_DIR.values()) | {"tests", "bench", "samples"}:
        for f in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(f.read_text())):
                if isinstance(node, ast.ImportFrom) and (node.module or node.level):
                    for a in node.names:
                        if a.name.startswith("_") and not a.name.startswith("__"):
                            offenders.append(f"{f.relative_to(ROOT)}:{node.lineno} {a.name}")
    assert not offenders, offenders


def test_ruff_check_and_format_are_clean():
    """The style rules hold in CI too: ``ruff check`` and ``ruff format --check``."""
    ruff = Path(sys.executable).with_name("ruff")
    if not ruff.exists():
        msg = "ruff is not installed: make install-dev (make test does)"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    for args in (["check", "."], ["format", "--check", "."]):
        r = subprocess.run([str(ruff), *args], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout + r.stderr
