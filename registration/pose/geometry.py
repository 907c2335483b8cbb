"""Small rigid-pose geometry shared by the pose search
(:mod:`qifreport.registration.pose.prealign`).

Conventions: all lengths in mm; a pose ``R, t`` maps scan points into the model frame,
``P_model = P @ R.T + t``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pose_distance", "principal_axes", "rotation_angle_deg", "scan_displacement"]


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (degrees) of the rotation ``R``."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def pose_distance(
    R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray, at: np.ndarray
) -> tuple[float, float]:
    """Rotation difference (degrees) and displacement of the point ``at`` (mm) between poses."""
    return rotation_angle_deg(R1 @ R2.T), float(np.linalg.norm((R1 - R2) @ at + t1 - t2))


def scan_displacement(
    R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray, S: np.ndarray
) -> float:
    """RMS distance (mm) between the points ``S`` placed by pose 1 and by pose 2."""
    D = S @ (R1 - R2).T + (t1 - t2)
    return float(np.sqrt(np.mean(np.sum(D * D, axis=1))))


def principal_axes(X: np.ndarray, w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroid and principal axes of a point set.

    Parameters
    ----------
    X : (n, 3) points, mm.
    w : (n,) non-negative weights (default all ones), e.g. vertex areas.

    Returns
    -------
    c : (3,) weighted centroid, mm.  U : (3, 3) principal axes as columns, largest variance
    first, right-handed (``U[:, 2] = U[:, 0] x U[:, 1]``).
    """
    w = np.ones(len(X)) if w is None else w
    w = w / w.sum()
    c = w @ X
    C = ((X - c) * w[:, None]).T @ (X - c)
    _, U = np.linalg.eigh(C)
    U = U[:, ::-1].copy()
    U[:, 2] = np.cross(U[:, 0], U[:, 1])
    return c, U
