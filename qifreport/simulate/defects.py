"""Localized form defects injected into a free state (paper Section 8.3.2, Eq. 16)."""

from __future__ import annotations

import numpy as np

__all__ = [
    "gaussian_bump",
]


def gaussian_bump(
    V: np.ndarray, normals: np.ndarray, center: np.ndarray, amplitude: float, sigma: float
) -> np.ndarray:
    """Gaussian bump along the surface normal: ``delta(x) = a exp(-|x - x0|^2 / sigma^2) n(x)``.

    Width convention of the paper's Eq. (16): the exponent is ``r^2 / sigma^2``, NOT
    ``r^2 / (2 sigma^2)``, so the bump falls to ``exp(-1) a`` (37 %) at ``r = sigma`` and
    ``sigma`` here is sqrt(2) times the standard deviation of a normal distribution.

    Parameters
    ----------
    V : (n, 3) float, mm (the configuration the defect is placed in, e.g. the free state).
    normals : (n, 3) unit vertex normals of that configuration.
    center : (3,) defect centre ``x0``, mm (distance is Euclidean in 3D).
    amplitude : peak height ``a``, mm; positive = material proud along the normal,
        negative = a sink.
    sigma : width, mm (> 0).

    Returns
    -------
    delta : (n, 3) displacement, mm; add it to ``V``.
    """
    if sigma <= 0:
        raise ValueError("sigma must be positive")
    V = np.asarray(V, dtype=np.float64)
    r2 = np.sum((V - np.asarray(center, dtype=np.float64)) ** 2, axis=1)
    return amplitude * np.exp(-r2 / sigma**2)[:, None] * np.asarray(normals, dtype=np.float64)
