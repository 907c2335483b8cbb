"""Can the measurement resolve the tolerance? The scan's range noise and the fit's residual
held against each tolerance zone.

A band can only be judged when the measurement scatter is small against it. The rule is
the common 4:1 test-accuracy ratio (the expanded measurement uncertainty ``U = 2 sigma`` at
most a quarter of the tolerance zone's width, in the spirit of ISO 14253-1's decision rules):

    2 * sigma <= zone width / 4,   sigma = max(range noise, robust fit residual)

Above it a PASS is not claimed (the inspection is *not established*, with the figures); a
FAIL stays a FAIL. ``range noise`` is measured on the scan itself (:func:`range_noise`: local
quadric fits, which remove the surface's own curvature); the robust residual is the virtual
fixture's (or, without one, the rigid alignment's) robust scale of the point-to-surface
distances, which also catches noise the local fits smooth over.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["RESOLUTION_RATIO", "Resolution", "range_noise", "resolution"]

#: the largest expanded uncertainty (2 sigma), as a fraction of a zone's width, that still
#: resolves the zone (4:1)
RESOLUTION_RATIO = 0.25


def range_noise(
    P: np.ndarray,
    k: int = 20,
    n_sample: int = 3000,
    seed: int = 0,
    tree: cKDTree | None = None,
    labels: np.ndarray | None = None,
) -> float:
    """Robust estimate of a scan's range noise, mm.

    At ``n_sample`` points (a seeded random subset) a quadric ``z = a x^2 + b xy + c y^2 +
    d x + e y + f`` is fitted to the ``k`` nearest neighbours in their principal frame; the
    residual RMS, corrected for the fit's 6 degrees of freedom, estimates the noise along
    the normal. The median over the samples is returned (edges and small features, where the
    quadric does not hold, are outvoted).

    With ``labels`` (the B-rep face of each point's closest triangle, a STEP nominal) the
    neighbours are taken among the points of the same face: on a wall thinner than the
    neighbourhood (NIST CTC 03: 1.9 mm walls at 0.9 mm spacing) the other skin is another
    face, and mixing it read the noise as 0.9 mm on a 10 um scan.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  k : neighbours per fit (>= 10).
    n_sample : fits made (all points when fewer).  seed : of the subset.
    tree : a k-d tree of ``P`` to reuse (without ``labels``).
    labels : (m,) int, or None.

    Returns
    -------
    float
        Noise sigma, mm (0.0 for fewer than ``k`` points).
    """
    P = np.asarray(P, dtype=np.float64)
    if labels is None:
        s = _noise_samples(P, k, n_sample, np.random.default_rng(seed), tree)
        return float(np.median(s)) if len(s) else 0.0
    labels = np.asarray(labels)
    rng = np.random.default_rng(seed)
    found = []
    for lab in np.unique(labels):
        Q = P[labels == lab]
        if len(Q) < max(k, 10):
            continue
        share = max(1, int(round(n_sample * len(Q) / len(P))))
        found.append(_noise_samples(Q, k, share, rng, None))
    s = np.concatenate(found) if found else np.zeros(0)
    return float(np.median(s)) if len(s) else 0.0


def _noise_samples(
    P: np.ndarray, k: int, n_sample: int, rng: np.random.Generator, tree: cKDTree | None
) -> np.ndarray:
    """The per-sample noise sigmas of :func:`range_noise` (empty for fewer than ``k``)."""
    m = len(P)
    if m < max(k, 10):
        return np.zeros(0)
    idx = rng.choice(m, size=min(n_sample, m), replace=False) if m > n_sample else np.arange(m)
    tree = cKDTree(P) if tree is None else tree
    _, nb = tree.query(P[idx], k=k)
    X = P[nb] - P[nb].mean(axis=1, keepdims=True)  # (s, k, 3)
    # principal frame of each neighbourhood: the smallest axis is the local normal
    _, _, Vt = np.linalg.svd(X, full_matrices=False)
    L = np.einsum("skj,sij->ski", X, Vt)  # coordinates (u, v, w) in that frame
    u, v, w = L[..., 0], L[..., 1], L[..., 2]
    A = np.stack([u * u, u * v, v * v, u, v, np.ones_like(u)], axis=-1)  # (s, k, 6)
    AtA = np.einsum("ski,skj->sij", A, A)
    Atw = np.einsum("ski,sk->si", A, w)
    AtA += 1e-12 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] * np.eye(6)
    coef = np.linalg.solve(AtA, Atw[..., None])[..., 0]
    r = w - np.einsum("ski,si->sk", A, coef)
    return np.sqrt((r * r).sum(axis=1) / (k - 6))


@dataclass
class Resolution:
    """The measurement scatter against the tolerance zones.

    Attributes
    ----------
    range_noise : the scan's range noise (:func:`range_noise`), mm.
    fit_residual : the registration's robust residual, mm.
    sigma : ``max(range_noise, fit_residual)``, mm.
    unresolved : ``(zone key, zone width mm)`` of each zone the rule says is not resolved.
    """

    range_noise: float
    fit_residual: float
    sigma: float
    unresolved: list[tuple[str, float]]

    @property
    def ok(self) -> bool:
        return not self.unresolved

    def warnings(self) -> list[str]:
        """One line per unresolved zone."""
        return [
            f"measurement scatter sigma {self.sigma:.3f} mm (range noise {self.range_noise:.3f},"
            f" fit residual {self.fit_residual:.3f}) cannot resolve {key}'s {width:g} mm zone: "
            f"2 sigma = {2 * self.sigma:.3f} mm exceeds a quarter of it "
            f"({RESOLUTION_RATIO * width:.3f} mm)"
            for key, width in self.unresolved
        ]

    def to_dict(self) -> dict:
        return {
            "range_noise_mm": self.range_noise,
            "fit_residual_mm": self.fit_residual,
            "sigma_mm": self.sigma,
            "rule": "2 sigma <= zone width / 4",
            "unresolved": [{"key": k, "width_mm": w} for k, w in self.unresolved],
        }


def resolution(noise: float, residual: float, zones: list[tuple[str, float]]) -> Resolution:
    """Apply the rule of this module.

    Parameters
    ----------
    noise : range noise, mm.  residual : robust fit residual, mm.
    zones : ``(key, width mm)`` of every zone judged.
    """
    sigma = max(float(noise), float(residual))
    bad = [(k, float(w)) for k, w in zones if 2.0 * sigma > RESOLUTION_RATIO * float(w)]
    return Resolution(float(noise), float(residual), sigma, bad)
