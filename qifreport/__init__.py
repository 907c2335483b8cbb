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
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
