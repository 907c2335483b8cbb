"""Shared fixtures: the reference material in ../shared and generated inspection cases."""

from __future__ import annotations

import os
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


@pytest.fixture(scope="session")
def shell():
    from registration.simulate.shapes import thin_shell

    return thin_shell()


@pytest.fixture(scope="session")
def shell_case(shell):
    """The shell, analytic free state at 2 % of the diagonal, 3 views, 0.02 mm noise."""
    from registration.simulate.cases import make_case

    V, F = shell
    return make_case(V, F, generator="analytic", amplitude=0.02, seed=1)


@pytest.fixture(scope="session")
def shell_case_defect(shell):
    """The same free state and scanner with a 1.0 mm / sigma 7 mm Gaussian bump."""
    from registration.simulate.cases import make_case

    V, F = shell
    return make_case(V, F, generator="analytic", amplitude=0.02, defect=(1.0, 7.0), seed=1)
