"""Determinism: two independent builds of a part's state, and two runs of the CLI, give
bit-identical numbers (no random Lanczos start, no arbitrary eigenvector sign or null-space
basis). The bounds are exact equality: the arbitrary choices showed as differences of
1e-13 (shell) to 1e-8 (panel) relative. Each child process has its own string-hash seed, so
an order taken from a set or from hashing would show too.

Run as a script (``python tests/test_determinism.py NOMINAL TOLERANCE OUT.npz``), this module
prepares a nominal and saves every number of the prepared state: the child of the
two-process comparison.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"
#: keys whose values are clock readings or file locations, not results
VOLATILE = ("seconds", "timing", "started", "finished", "created", "path")


def flatten(obj, name: str = "", out: dict | None = None) -> dict:
    """Every array and number reachable from ``obj`` (dataclasses, dicts, lists, sparse
    matrices, k-d trees), keyed by its access path; timings are left out."""
    out = {} if out is None else out
    if isinstance(obj, np.ndarray):
        if obj.dtype == object:
            for i, x in enumerate(obj.ravel()):
                flatten(x, f"{name}[{i}]", out)
        else:
            out[name] = obj
    elif sp.issparse(obj):
        c = sp.csr_matrix(obj)
        out[name + ".data"], out[name + ".indices"] = c.data, c.indices
        out[name + ".indptr"] = c.indptr
    elif isinstance(obj, bool | int | float | np.number):
        out[name] = np.asarray(obj)
    elif dataclasses.is_dataclass(obj):
        for f in dataclasses.fields(obj):
            if not any(v in f.name for v in VOLATILE):
                flatten(getattr(obj, f.name), f"{name}.{f.name}", out)
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            if not any(v in str(k) for v in VOLATILE):
                flatten(obj[k], f"{name}[{k}]", out)
    elif isinstance(obj, list | tuple):
        for i, x in enumerate(obj):
            flatten(x, f"{name}[{i}]", out)
    elif hasattr(obj, "data") and hasattr(obj, "query"):  # cKDTree: its points
        out[name + ".data"] = np.asarray(obj.data)
    return out


def json_numbers(doc, name: str = "", out: dict | None = None) -> dict:
    """Every number of a JSON document by its path, clock readings and paths left out."""
    out = {} if out is None else out
    if isinstance(doc, dict):
        for k, v in doc.items():
            if not any(s in k.lower() for s in VOLATILE):
                json_numbers(v, f"{name}/{k}", out)
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            json_numbers(v, f"{name}[{i}]", out)
    elif isinstance(doc, int | float) and not isinstance(doc, bool):
        out[name] = doc
    return out


def _run_pair(commands: list[list[str]], timeout: float = 600) -> None:
    """Run the commands concurrently, one BLAS thread each (two processes on the two cores
    of a test machine); fail with the output of any that fails."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    procs = [
        subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        for c in commands
    ]
    for p in procs:
        out, err = p.communicate(timeout=timeout)
        assert p.returncode == 0, err[-2000:] + out[-2000:]


def _small_basis(k: int = 24):
    from qifreport.registration.deformable.bending_basis import bending_basis
    from qifreport.registration.mesh import bending_operator
    from qifreport.simulate.shapes import thin_shell

    V, F = thin_shell(spacing=6.0)
    ops = bending_operator(V, F, "hessian")
    return ops, bending_basis(ops, k)


def test_canonical_modes_undo_signs_and_rotations():
    """The conventions do not depend on what the eigen-solver picked: flipped signs, a
    rotated null space and a rotated degenerate pair come back to the same basis."""
    from qifreport.registration.deformable.bending_basis import canonical_modes

    ops, B = _small_basis()
    assert B.mu[0] == 0.0 < B.mu[1]  # the constant (this coarse shell has no other null mode)
    # make the null space two-dimensional, modes 8, 9 a degenerate pair and 12-14 a triple:
    # their bases are then as arbitrary as the signs
    mu = B.mu.copy()
    mu[1] = 0.0
    mu[8:10], mu[12:15] = mu[8:10].mean(), mu[12:15].mean()
    mu0, Phi0 = canonical_modes(mu, B.Phi, ops.area)
    rng = np.random.default_rng(7)
    Phi = B.Phi * np.where(rng.random(len(mu)) < 0.5, -1.0, 1.0)
    for a, b in ((0, 2), (8, 10), (12, 15)):
        R, _ = np.linalg.qr(rng.standard_normal((b - a, b - a)))
        Phi[:, a:b] = Phi[:, a:b] @ R
    mu1, Phi1 = canonical_modes(mu, Phi, ops.area)
    np.testing.assert_array_equal(mu1, mu0)
    np.testing.assert_allclose(Phi1, Phi0, rtol=0, atol=1e-10 * np.abs(Phi0).max())
    # still M-orthonormal, and the constant is the first null mode
    np.testing.assert_allclose(Phi1.T @ (ops.M @ Phi1), np.eye(len(mu)), atol=1e-10)
    np.testing.assert_allclose(Phi1[:, 0], 1.0 / np.sqrt(ops.area.sum()), rtol=1e-10)


def test_bending_basis_is_bit_identical_and_independent_of_the_lanczos_start():
    """Two builds in one process are bit-identical; an arbitrary random start of the
    eigen-solver gives the same modes to the solver's accuracy."""
    import scipy.sparse.linalg as spla

    from qifreport.registration.deformable.bending_basis import canonical_modes

    ops, B = _small_basis()
    _, again = _small_basis()
    np.testing.assert_array_equal(again.Phi, B.Phi)
    np.testing.assert_array_equal(again.mu, B.mu)
    shift = -1e-3 * B.mu[-1]
    mu, Phi = spla.eigsh(
        ops.Q, k=len(B.mu), M=ops.M, sigma=shift, v0=np.random.default_rng(3).random(len(B.Phi))
    )
    order = np.argsort(mu)
    mu, Phi = canonical_modes(mu[order], Phi[:, order], ops.area)
    np.testing.assert_allclose(mu, B.mu, rtol=1e-6, atol=1e-9 * B.mu[-1])
    np.testing.assert_allclose(Phi, B.Phi, rtol=0, atol=1e-7 * np.abs(B.Phi).max())


def _compare(a: dict, b: dict) -> list[str]:
    bad = sorted(set(a) ^ set(b))
    for k in sorted(set(a) & set(b)):
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if x.shape != y.shape or x.dtype != y.dtype or x.tobytes() != y.tobytes():
            d = np.max(np.abs(x - y)) if x.shape == y.shape and x.dtype.kind == "f" else "?"
            bad.append(f"{k} (max difference {d})")
    return bad


def test_prepared_state_is_bit_identical_in_two_processes(tmp_path):
    """The shell's prepared state (operators, bands, hygiene, bending basis, pose-search
    model) built by two independent processes: every array byte for byte equal."""
    outs = [tmp_path / f"state{i}.npz" for i in (1, 2)]
    nominal = str(SAMPLES / "shell_nominal.ply")
    _run_pair([[sys.executable, __file__, nominal, "0.5", str(o)] for o in outs])
    a, b = (dict(np.load(o)) for o in outs)
    assert any(k.endswith("basis.Phi") for k in a) and any("model" in k for k in a)
    assert not (bad := _compare(a, b)), f"{len(bad)} arrays differ: {bad[:10]}"


def test_cli_json_numbers_identical_in_two_runs(tmp_path):
    """Two CLI runs, each preparing the shell afresh (``--no-cache``): every number of the
    JSON summaries equal, timings and paths aside."""
    outs = [tmp_path / f"run{i}" for i in (1, 2)]
    for o in outs:  # existing folders: each run locks its own (not their common parent)
        o.mkdir()
    cmd = [str(EXE), str(SAMPLES / "shell_nominal.ply"), str(SAMPLES / "shell_scan.ply")]
    cmd += ["--tolerance", "0.5", "--json", "--no-qif", "--no-pdf", "--no-cache", "--quiet"]
    _run_pair([[*cmd, "--out", str(o)] for o in outs])
    a, b = (json_numbers(json.loads((o / "shell_nominal.json").read_text())) for o in outs)
    assert len(a) > 100
    # repr: exact (shortest round-trip) and NaN equal to NaN
    bad = [
        f"{k}: {a.get(k)!r} != {b.get(k)!r}"
        for k in sorted(set(a) | set(b))
        if repr(a.get(k)) != repr(b.get(k))
    ]
    assert not bad, f"{len(bad)} of {len(a)} numbers differ: {bad[:10]}"


def _dump_prepared(nominal: str, tolerance: float, out: str) -> None:
    """Prepare ``nominal`` as an inspection would and save every number of its state."""
    from qifreport.metrology.params import InspectionParams
    from qifreport.metrology.prepared import prepare_part
    from qifreport.nominal import load_nominal

    part, _ = load_nominal(Path(nominal), tolerance, None, None)
    state = prepare_part(part.V, part.F, InspectionParams())
    np.savez(out, **flatten(state, "prepared"))


if __name__ == "__main__":
    _dump_prepared(sys.argv[1], float(sys.argv[2]), sys.argv[3])
