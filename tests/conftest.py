"""Shared fixtures: the reference material in ../shared and generated inspection cases."""

from __future__ import annotations

import contextlib
import fcntl
import os
import pickle
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
#: the NIST MBE PMI STEP files in ../shared/step/nist (read-only, never copied here)
NIST = [
    "nist_ctc_01_asme1_ap242-e1.stp",
    "nist_ctc_02_asme1_ap242-e2.stp",
    "nist_ctc_03_asme1_ap242-e2.stp",
    "nist_ctc_04_asme1_ap242-e1.stp",
    "nist_ctc_05_asme1_ap242-e1.stp",
    "nist_ftc_06_asme1_ap242-e1.stp",
    "nist_ftc_08_asme1_ap242-e1.stp",
]


def shared_file(rel: str) -> Path:
    """Path of a file in ../shared; fails under CI (CI=true) and skips elsewhere if missing."""
    p = SHARED / rel
    if not p.exists():
        msg = f"reference file missing: {p}"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return p


@pytest.fixture(scope="session", autouse=True)
def qifreport_cache(tmp_path_factory):
    """One per-part cache directory for the session (``$QIFREPORT_CACHE``, inherited by the
    CLI subprocesses): the tests never write the user's cache, and a part prepared by one
    test is loaded by the next, as in production. Under pytest-xdist the workers share it
    (beside their own temporary folders): a part one prepares, the other loads; entries are
    written to a temporary file and renamed, so concurrent builders are harmless."""
    d = shared_session_dir(tmp_path_factory, "qifreport-cache")
    old = os.environ.get("QIFREPORT_CACHE")
    os.environ["QIFREPORT_CACHE"] = str(d)
    yield d
    if old is None:
        os.environ.pop("QIFREPORT_CACHE", None)
    else:
        os.environ["QIFREPORT_CACHE"] = old


@pytest.fixture(scope="session")
def nist_nominal(qifreport_cache):
    """name -> ``load_nominal(step/nist/name, None)``: each NIST part read and meshed once
    per suite run (real OCP, real gmsh), kept pickled beside the session's part cache
    (shared by the xdist workers, written to a temporary file and renamed) and unpickled
    afresh for every caller, so no test sees another's changes."""
    from qifreport.nominal import load_nominal

    def get(name: str):
        path = qifreport_cache / f"nominal-{name}.pickle"
        if path.is_file():
            return pickle.loads(path.read_bytes())
        loaded = load_nominal(shared_file(f"step/nist/{name}"), None)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(pickle.dumps(loaded, protocol=pickle.HIGHEST_PROTOCOL))
        os.replace(tmp, path)
        return pickle.loads(path.read_bytes())

    return get


@pytest.fixture(scope="session")
def shell():
    from qifreport.simulate.shapes import thin_shell

    return thin_shell()


@pytest.fixture(scope="session")
def shell_case(shell):
    """The shell, analytic free state at 2 % of the diagonal, 3 views, 0.02 mm noise."""
    from qifreport.simulate.cases import make_case

    V, F = shell
    return make_case(V, F, generator="analytic", amplitude=0.02, seed=1)


@pytest.fixture(scope="session")
def shell_case_defect(shell):
    """The same free state and scanner with a 1.0 mm / sigma 7 mm Gaussian bump."""
    from qifreport.simulate.cases import make_case

    V, F = shell
    return make_case(V, F, generator="analytic", amplitude=0.02, defect=(1.0, 7.0), seed=1)


def assert_valid_summary(doc: dict) -> None:
    """Fail, listing every violation, unless ``doc`` is a valid ``qifreport --json`` summary
    (``schemas/summary-1.schema.json``, :func:`qifreport.summary.validate_summary`)."""
    from qifreport.summary import validate_summary

    errors = validate_summary(doc)
    assert not errors, "summary violates schemas/summary-1.schema.json:\n" + "\n".join(errors)


def shared_session_dir(tmp_path_factory, name: str) -> Path:
    """A folder for the session's generated material: under pytest-xdist the one both
    workers share (beside their own temporary folders), else the session's own."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        d = tmp_path_factory.getbasetemp().parent / name
        d.mkdir(exist_ok=True)
        return d
    return tmp_path_factory.mktemp(name)


@contextlib.contextmanager
def held_lock(d: Path):
    """Hold an exclusive lock on ``d`` (its ``.lock`` file) while the block runs: the
    worker that comes second waits, then finds the first one's work done."""
    with open(d / ".lock", "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def qif_xsd(tmp_path_factory) -> Path:
    """``QIFDocument.xsd`` of a session copy of the official QIF 3.0 XSDs whose xmldsig import
    points to a local file (:func:`tests.consumers.local_xsd_copy`), made once and shared by
    the xdist workers."""
    from tests.consumers import local_xsd_copy

    d = shared_session_dir(tmp_path_factory, "qif-xsd")
    with held_lock(d):
        done = d / ".copied"
        if done.is_file():
            return d / "copy" / "QIFApplications" / "QIFDocument.xsd"
        root = local_xsd_copy(d / "copy")
        done.touch()
        return root


@pytest.fixture(scope="session")
def pyxb_qif(tmp_path_factory, qif_xsd):
    """The PyXB binding of ``qif_xsd`` (:func:`tests.consumers.pyxb_binding`), generated
    once per session (about 12 s) into a folder the xdist workers share, and imported in
    each (about 8 s the first time, less from the compiled files the first import left)."""
    from tests.consumers import pyxb_binding

    d = shared_session_dir(tmp_path_factory, "pyxb-qif")
    with held_lock(d):
        return pyxb_binding(d, qif_xsd)


@pytest.fixture(scope="session")
def fandisk_cli_runs(tmp_path_factory) -> dict:
    """``qifreport`` on the deformed fandisk (bend + twist at 2 %, 2 views, a 0.8 mm / sigma
    4 mm bump where the views see the part best, ``--tolerance 0.3``), once with the scan in
    the part frame (``framed``) and once at the paper's pose (120, 45, 10 degrees + a
    translation, ``posed``): name -> dict(rc, stdout, stderr, doc (the JSON summary), out
    (the output directory)), plus ``V`` and ``case``."""
    import json
    import subprocess
    import sys

    import numpy as np
    import trimesh
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from qifreport.simulate.cases import make_case
    from qifreport.simulate.scanner import ScanSpec
    from qifreport.simulate.shapes import fandisk

    V, F = fandisk(str(shared_file("meshes/fandisk.off")), diagonal=100.0, subdivide=1)
    kw = dict(
        generator="biharmonic",
        amplitude=0.02,
        modes={"bend": 1.0, "twist": 0.5},
        spec=ScanSpec(views=2, noise=0.02, dropout_radius=3.0, seed=0),
    )
    # the bump where the views see the part best: the measured vertex farthest from any
    # unmeasured one
    seen = np.zeros(len(V), dtype=bool)
    seen[make_case(V, F, **kw).measured_vertices()] = True
    depth, _ = cKDTree(V[~seen]).query(V[seen])
    site = int(np.flatnonzero(seen)[np.argmax(depth)])
    case = make_case(V, F, defect=(0.8, 4.0), defect_vertex=site, **kw)
    d = tmp_path_factory.mktemp("fandisk-cli")
    nominal = d / "fandisk.ply"
    trimesh.Trimesh(V, F, process=False).export(nominal)
    R = Rotation.from_euler("xyz", (120.0, 45.0, 10.0), degrees=True).as_matrix()
    exe = Path(sys.executable).parent / "qifreport"
    runs: dict = {"V": V, "case": case}
    for name, P in (("framed", case.P), ("posed", case.P @ R.T + [30.0, -20.0, 15.0])):
        scan = d / f"{name}.ply"
        trimesh.PointCloud(P).export(scan)
        out = d / name
        r = subprocess.run(
            [str(exe), nominal, scan, "--tolerance", "0.3", "--out", out, "--json", "--quiet"],
            capture_output=True,
            text=True,
        )
        doc = (
            json.loads((out / "fandisk.json").read_text())
            if (out / "fandisk.json").exists()
            else None
        )
        runs[name] = dict(rc=r.returncode, stdout=r.stdout, stderr=r.stderr, doc=doc, out=out)
    return runs
