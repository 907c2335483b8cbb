"""The scan's range noise on a wall thinner than a neighbourhood (NIST CTC 03: 1.9 mm
walls at 0.9 mm spacing: read as 0.91 mm on a 10 um scan, the free state not established).

Two parallel 60 x 40 mm skins 1.9 mm apart, each on a 0.9 mm grid with 10 um range noise:
mixed, the neighbours of a point straddle both skins and the quadric's residual is the
wall; kept apart by their B-rep face (``labels``), the estimate is the noise.
"""

from __future__ import annotations

import numpy as np

from qifreport.metrology.acceptance.resolution import range_noise

SIGMA = 0.01  # mm


def _wall():
    rng = np.random.default_rng(4)
    u, v = np.meshgrid(np.arange(0, 60, 0.9), np.arange(0, 40, 0.9))
    skins = []
    for z in (0.0, 1.9):
        P = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, z)])
        P[:, 2] += rng.normal(0, SIGMA, len(P))
        skins.append(P)
    labels = np.repeat([0, 1], [len(skins[0]), len(skins[1])])
    return np.vstack(skins), labels


def test_noise_is_read_per_face_not_across_the_wall():
    P, labels = _wall()
    mixed = range_noise(P)
    apart = range_noise(P, labels=labels)
    assert mixed > 10 * SIGMA  # the wall, not the noise
    assert 0.7 * SIGMA < apart < 1.3 * SIGMA
