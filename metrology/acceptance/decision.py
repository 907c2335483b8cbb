"""Decision rules: how the measurement uncertainty enters a conformance decision.

A measured deviation is an estimate. Near a zone limit it cannot say on which side the
surface lies: a machined face whose drawing puts the zone entirely on one side of nominal
(NIST CTC 02: ``2.5 UZ 0`` and ``2.5 UZ 2.5``) is perfect *on* the limit, and a scan of it
reads half its points a few micrometres outside. ISO 14253-1:2017 gives the rule: with the
expanded uncertainty ``U`` (k = 2) of each measured value,

* **conformance is proven** when the value lies inside the zone reduced by ``U`` on each side;
* **non-conformance is proven** when it lies outside the zone enlarged by ``U``;
* in between neither is proven (the *uncertainty range*).

Applied to the area and region criteria (:mod:`qifreport.metrology.acceptance.criteria`): a surface
is *proven in* when both criteria hold with every vertex's band reduced by its ``U``, and
*proven out* when one fails with every band enlarged by it. The rules (``--decision-rule``):

``iso14253`` (default)
    PASS when proven in, FAIL when proven out, otherwise the zone is NOT ESTABLISHED (exit
    3): neither supplier nor customer can claim the result (ISO 14253-1, 5.2 and 5.3).
``guarded-acceptance``
    PASS only when proven in, FAIL otherwise (ASME B89.7.3.1 guarded acceptance: the
    consumer's risk is kept low; a supplier's final inspection).
``guarded-rejection``
    FAIL only when proven out, PASS otherwise (guarded rejection: the producer's risk is kept
    low; a customer's incoming inspection proving a part bad).
``simple``
    The measured values against the limits themselves, ``U`` not used (ASME B89.7.3.1
    simple acceptance, shared risk; it relies on the 4:1 ratio that
    :mod:`qifreport.metrology.acceptance.resolution` checks).

A surface's decision rests on all its values at once: a face of 2,000 vertices (or 20,000
scan points) on its limit has about 2.3 % of them beyond their k = 2 band by chance, and
neighbouring values share their points, so the chance excursions cluster into regions
larger than the region limit (NIST CTC 02's perfect T2 and T4 faces on their unilateral
zones: 3 % of the vertices, regions of 50-150 mm^2, "proven" out). The proofs therefore
enlarge or reduce each band by ``U`` at coverage factor :data:`PROOF_COVERAGE` = 4 (the
one-sided risk of one value 3e-5, about a Bonferroni bound over a face's values at the
single-value risk of k = 2); the ``U`` the outputs state is the k = 2 one.

``U`` of a vertex's deviation is twice its standard deviation from the local fit that
measured it: the scatter of its ``N`` scan points about that fit (pooled with the median
scatter of its B-rep face, or of the part for a mesh nominal, so a vertex of few points is
not trusted on their word alone) over ``N``,
more at a scan edge where the fit extrapolates
(:func:`qifreport.metrology.deviation.residual_fit.residual_referenced`). It is the random (type A)
part of the uncertainty; a scanner's own systematic error is not in it
and can be added with ``--scanner-uncertainty`` (its expanded value, mm, combined in
quadrature).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "DECISION_RULES",
    "DEFAULT_DECISION_RULE",
    "PROOF_COVERAGE",
    "decide",
    "vertex_uncertainty",
]

#: the decision rules, by name (module docstring)
DECISION_RULES = ("iso14253", "guarded-acceptance", "guarded-rejection", "simple")
DEFAULT_DECISION_RULE = "iso14253"
#: coverage factor of a proof on a surface: its thousands of values are judged at once
#: (module docstring); the ``U`` stated in the outputs stays at k = 2
PROOF_COVERAGE = 4.0


def decide(rule: str, passed: bool, proven_in: bool, proven_out: bool) -> str:
    """``"PASS"``, ``"FAIL"`` or ``"UNCERTAIN"`` for one surface under ``rule``.

    Parameters
    ----------
    rule : one of :data:`DECISION_RULES`.
    passed : the criteria hold on the measured values themselves (the simple reading).
    proven_in : they hold with every band reduced by its expanded uncertainty.
    proven_out : they fail with every band enlarged by it.
    """
    if rule == "simple":
        return "PASS" if passed else "FAIL"
    if rule == "guarded-acceptance":
        return "PASS" if proven_in else "FAIL"
    if rule == "guarded-rejection":
        return "FAIL" if proven_out else "PASS"
    if rule == "iso14253":
        if proven_in:
            return "PASS"
        return "FAIL" if proven_out else "UNCERTAIN"
    raise ValueError(f"unknown decision rule {rule!r} (one of {', '.join(DECISION_RULES)})")


def vertex_uncertainty(variance: np.ndarray, systematic: float | np.ndarray = 0.0) -> np.ndarray:
    """Expanded uncertainty ``U`` (n,) mm (k = 2) of each vertex's measured deviation.

    Parameters
    ----------
    variance : (n,) mm^2, the variance of each vertex's deviation from the scatter of the
        scan points it was fitted to (NaN where unscored;
        :func:`qifreport.metrology.deviation.residual_fit.residual_referenced` with
        ``variance=True``).
    systematic : an expanded uncertainty common to every vertex, mm (a scanner's stated
        accuracy), or one per vertex (n,) (with a restrained hold's model uncertainty),
        combined in quadrature.

    Returns
    -------
    (n,) float, mm: ``sqrt(4 variance + systematic^2)``; NaN where ``variance`` is.
    """
    var = np.asarray(variance, dtype=np.float64)
    return np.sqrt(4.0 * var + np.asarray(systematic, dtype=np.float64) ** 2)
