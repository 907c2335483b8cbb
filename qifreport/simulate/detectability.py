"""Defect detectability of a reported deviation field (paper Section 8.3.2, Eqs. 18-19).

A defect is detectable when the deviation the pipeline reports near it stands out from the
deviation it reports everywhere else. With fixed radii ``R_d`` and ``R_b`` around the true
defect centre ``x0`` the scored vertices are split into a defect neighbourhood and a
background,

    D = {i scored : |v_i - x0| <= R_d},    B = {i scored : |v_i - x0| > R_b},

and

    a_hat = max_{i in D} |e_i|,    b = Q_0.95{|e_i| : i in B},    rho = a_hat / b.

The radii are fixed rather than scaled with the defect width: a window growing with sigma
takes its maximum over more vertices (so ``a_hat`` grows even without a defect) and moves
the background to a quieter part of the surface, which flatters the widest defects.
``rho >= 3`` is the paper's convention for a *reliably separable* defect.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "detectability",
    "Detectability",
]


@dataclass(frozen=True)
class Detectability:
    """Detectability of one defect in one reported deviation field (lengths in mm).

    Attributes
    ----------
    a_hat : recovered amplitude, the largest ``|e_i|`` over the defect neighbourhood D, mm.
        NaN when D is empty.
    recovery : ``a_hat / a``, the recovered fraction of the true amplitude (1.0 = 100 %).
    background : ``b``, the 95th percentile (linear interpolation) of ``|e_i|`` over the
        background B, mm. NaN when B is empty.
    rho : detectability ``a_hat / b`` (dimensionless); ``inf`` when ``b == 0 < a_hat``,
        NaN when D or B is empty.
    localisation_mm : distance from the vertex of the recovered peak (the arg max over D) to
        the true centre ``x0``, mm. NaN when D is empty.
    n_defect, n_background : number of scored vertices in D and in B.
    """

    a_hat: float
    recovery: float
    background: float
    rho: float
    localisation_mm: float
    n_defect: int
    n_background: int

    @property
    def separable(self) -> bool:
        """``rho >= 3``: the paper's reliably separable defect (False when rho is NaN)."""
        return bool(self.rho >= 3.0)

    def to_dict(self) -> dict:
        return asdict(self)


def detectability(
    e: np.ndarray,
    V: np.ndarray,
    x0: np.ndarray,
    scored: np.ndarray | None,
    a: float,
    R_d: float = 12.0,
    R_b: float = 60.0,
) -> Detectability:
    """Recovered amplitude, background and detectability ratio of a defect (paper Eqs. 18-19).

    Parameters
    ----------
    e : (n,) float, the deviation reported at each vertex, mm (signed or not: its absolute
        value is used, since a defect may be proud or sunk while the background is
        two-sided). NaN marks a vertex that was not scored.
    V : (n, 3) float, vertex positions, mm, in the same frame as ``x0``.
    x0 : (3,) float, the true defect centre, mm.
    scored : (n,) bool, the scored set C (vertices surviving the coverage mask and the
        boundary exclusion), or None. The set actually used is ``scored & isfinite(e)``,
        so with None the scored set is simply where ``e`` is finite.
    a : true defect amplitude, mm (> 0; its magnitude is used for a sunk defect).
    R_d : radius of the defect neighbourhood, mm (paper: 12 mm, beyond the widest defect).
    R_b : inner radius of the background, mm (paper: 60 mm, well beyond the defect's skirt);
        must be >= ``R_d``.

    Returns
    -------
    Detectability
        Empty D or empty B does not raise: the quantities that need the empty set are NaN
        (``a_hat``, ``recovery``, ``localisation_mm`` for D; ``background`` for B; ``rho``
        for either) and the counts say which set was empty.

    Raises
    ------
    ValueError
        Mismatched shapes, a zero amplitude, or radii that are not ``0 < R_d <= R_b``.
    """
    e = np.asarray(e, dtype=np.float64)
    V = np.asarray(V, dtype=np.float64)
    x0 = np.asarray(x0, dtype=np.float64).reshape(-1)
    if e.ndim != 1:
        raise ValueError(f"e must be (n,), got shape {e.shape}")
    if V.shape != (len(e), 3):
        raise ValueError(f"V must be ({len(e)}, 3), got shape {V.shape}")
    if x0.shape != (3,):
        raise ValueError(f"x0 must be (3,), got shape {x0.shape}")
    if not np.isfinite(a) or a == 0:
        raise ValueError("the true amplitude a must be finite and non-zero")
    if not 0 < R_d <= R_b:
        raise ValueError(f"need 0 < R_d <= R_b, got R_d={R_d}, R_b={R_b}")
    ok = np.isfinite(e)
    if scored is not None:
        scored = np.asarray(scored, dtype=bool)
        if scored.shape != e.shape:
            raise ValueError(f"scored must be ({len(e)},), got shape {scored.shape}")
        ok &= scored
    r = np.linalg.norm(V - x0, axis=1)
    absdev = np.abs(e)
    D = np.flatnonzero(ok & (r <= R_d))
    B = ok & (r > R_b)
    n_d, n_b = len(D), int(B.sum())

    nan = float("nan")
    if n_d:
        k = D[int(np.argmax(absdev[D]))]
        a_hat, loc = float(absdev[k]), float(r[k])
    else:
        a_hat, loc = nan, nan
    b = float(np.percentile(absdev[B], 95)) if n_b else nan
    if np.isnan(a_hat) or np.isnan(b):
        rho = nan
    elif b > 0:
        rho = a_hat / b
    else:
        rho = float("inf") if a_hat > 0 else nan
    return Detectability(
        a_hat=a_hat,
        recovery=a_hat / abs(float(a)),
        background=b,
        rho=rho,
        localisation_mm=loc,
        n_defect=n_d,
        n_background=n_b,
    )
