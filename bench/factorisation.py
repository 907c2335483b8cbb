"""Sparse factorisation of GB-CICP's full-step matrix: SuperLU's orders against CHOLMOD.

One factorisation of ``diag(a w) + lambda Q + eps M`` (the Hessian bending energy ``Q``,
the vertex areas ``a``, data weights ``w`` on part of the vertices) and one solve of three
right-hand sides, on the fandisk (28,910 vertices) and on ``bench/scale.py``'s sheet
(201k vertices), by each path of :class:`qifreport.registration.linalg.SPDSolver`:
SuperLU with its minimum-degree order, SuperLU on the nested-dissection order
(:func:`qifreport.registration.ordering.nested_dissection`, timed apart), and CHOLMOD when
scikit-sparse is installed, in its default order and in METIS's (the mesh's: a solver given
the vertices). CPU seconds (``time.process_time``, one BLAS thread), best of
``--repeats``, with the factors' nonzeros: robust to other load on the machine. A sequence
of factorisations (GB-CICP's passes) pays the nested-dissection order, or CHOLMOD's
analysis, once: each is printed on its own line.

    python bench/factorisation.py [--parts fandisk,sheet] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

from qifreport.registration.linalg import SPDSolver, have_cholmod  # noqa: E402
from qifreport.registration.mesh import bending_operator  # noqa: E402
from qifreport.registration.ordering import nested_dissection  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def part(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The nominal ``(V, F)`` (mm) of a benchmark part."""
    if name == "fandisk":
        from qifreport.simulate.shapes import fandisk

        return fandisk(ROOT.parent / "shared/meshes/fandisk.off")
    if name == "sheet":
        sys.path.insert(0, str(ROOT / "bench"))
        from scale import build  # the 600 mm part of bench/scale.py

        V, F, _, _ = build(200_000, 1_000)
        return V, F
    raise SystemExit(f"unknown part {name!r}")


def fill(A: sp.csc_matrix, perm: np.ndarray | None) -> int:
    """Nonzeros of SuperLU's L + U in symmetric mode (minimum degree, or ``perm``)."""
    if perm is None:
        lu = spla.splu(
            A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    else:
        lu = spla.splu(
            sp.csc_matrix(A[perm][:, perm]),
            permc_spec="NATURAL",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    return lu.L.nnz + lu.U.nnz


def cholmod_fill(A: sp.csc_matrix, order: np.ndarray) -> int:
    """Nonzeros of CHOLMOD's ``L`` of ``A`` in the given order."""
    from sksparse.cholmod import analyze

    Ap = sp.csc_matrix(A[order][:, order])
    return analyze(Ap, ordering_method="natural").cholesky(Ap).L().nnz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="fandisk,sheet")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    head = f"{'part':8s} {'vertices':>9s} {'path':18s} {'factor s':>9s} {'solve ms':>9s}"
    print(f"{head} {'nnz':>7s}")
    for name in args.parts.split(","):
        V, F = part(name)
        ops = bending_operator(V, F, "hessian")
        n = len(V)
        w = np.where(V[:, 0] < np.median(V[:, 0]), 1.0, 0.3) * ops.area
        lam = 4.0 * float(np.median(ops.area)) ** 2
        A = (sp.diags(w) + lam * ops.Q + 1e-9 * lam * ops.M).tocsc()
        b = np.random.default_rng(0).normal(size=(n, 3))
        t0 = time.process_time()
        perm = nested_dissection(V, A)
        t_order = time.process_time() - t0
        paths = [("superlu (mmd)", "superlu", None), ("superlu (nd)", "superlu", V)]
        if have_cholmod():
            # its default order (AMD unless AMD fills much), and METIS's, which a solver
            # given the mesh's vertices takes (the product's bending systems)
            paths += [("cholmod (default)", "cholmod", None), ("cholmod (mesh)", "cholmod", V)]
        for label, backend, points in paths:
            t_fac, t_sol = [], []
            for _ in range(args.repeats):
                solver = SPDSolver(backend, points=points)
                if backend == "cholmod" or points is not None:
                    t0 = time.process_time()
                    solver.factor(A)  # the order / CHOLMOD's analysis: once per sequence
                    t_first = time.process_time() - t0
                t0 = time.process_time()
                solve = solver.factor(A)
                t_fac.append(time.process_time() - t0)
                t0 = time.process_time()
                x = solve(b)
                t_sol.append(time.process_time() - t0)
            resid = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
            if resid > 1e-8:
                raise SystemExit(f"{name} {label}: residual {resid:.1e}")
            nnz = f"{cholmod_fill(A, solver.order) / 1e6:6.1f}M" if backend == "cholmod" else ""
            if backend == "superlu":
                nnz = f"{fill(A, perm if points is not None else None) / 1e6:6.1f}M"
            print(
                f"{name:8s} {n:9d} {label:18s} {min(t_fac):9.2f} {1e3 * min(t_sol):9.0f} {nnz:>7s}"
            )
            if backend == "cholmod":  # its analysis (order, symbolic) with its first factor
                print(f"{name:8s} {n:9d} {'  first, analysed':18s} {t_first:9.2f}")
        print(f"{name:8s} {n:9d} {'(nd order)':18s} {t_order:9.2f}")


if __name__ == "__main__":
    main()
