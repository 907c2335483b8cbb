"""qifreport: dimensional inspection of flexible parts by virtual fixturing.

The import root of the whole product. Its sub-packages, in the one direction data flows:

* :mod:`qifreport.step` -- the STEP nominal with its semantic PMI, tessellated with face ids;
* :mod:`qifreport.registration` -- mesh layer, pose search, rigid ICP, GB-CICP and baselines;
* :mod:`qifreport.metrology` -- deviations, statistics, tolerance zones, acceptance;
* :mod:`qifreport.qif` -- QIF 3.0 results and statistics documents, reader and validation;

and the application layer on top of them, in this package: the command line
(:mod:`qifreport.cli`), one inspection from files to outputs (:mod:`qifreport.pipeline`),
many scans (:mod:`qifreport.batch`), the per-part cache (:mod:`qifreport.cache`) and the
reports (:mod:`qifreport.reports`). :mod:`qifreport.errors` and :mod:`qifreport.atomic_io`
are the foundation every layer may use; :mod:`qifreport.simulate` is the test and benchmark
simulator, never imported by the product.


The Python API (:mod:`qifreport.api`) is imported on first use, so that ``import qifreport``
and ``qifreport --help`` stay light: :func:`inspect`, :class:`Report`, :func:`read_part`,
:func:`read_scan`, :func:`plan`.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["Report", "__version__", "inspect", "plan", "read_part", "read_scan"]

_API = ("Report", "inspect", "plan", "read_part", "read_scan")


def __getattr__(name: str):
    if name in _API:  # the application's facade, loaded on first use (as lazy_loader does)
        import importlib

        return getattr(importlib.import_module("qifreport.api"), name)
    raise AttributeError(f"module 'qifreport' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
