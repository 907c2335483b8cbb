"""What a set of clamps holds, before it holds anything.

A restrained inspection (ISO 10579) is only as good as its clamp set. Each restrained
direction ``e`` at a clamp point ``p`` holds the rigid motions ``(t, w)`` (translation mm,
rotation rad about the part's centre ``o``) whose displacement there has a component along
``e``: ``e . t + ((p - o) x e) . w``. Stacked, with the rotation scaled by the part's radius
``R`` (so a unit rotation column moves the farthest point by 1 mm), they form the set's
rigid-motion matrix ``A`` (k, 6). Its singular values say how well the six rigid motions are
held:

* rank below 6: a rigid motion is free (the part slides or turns in the fixture);
* the smallest singular value ``s``: a misreading of ``d`` mm at one clamp moves the part
  by up to ``d / s`` mm at its radius. A set whose six directions are nearly dependent
  (six normals of a shallow shell: each sees an in-plane slide only through its surface's
  tilt) holds the part in a place its clamp readings barely decide;
* how many directions: exactly six is a **kinematic (locating) set** (3-2-1): it places the
  part and removes no flex, so the part is judged in its free shape, located. More than six
  (N-2-1) **over-constrain** the part: the hold bends it to its clamps, which is what removes
  the flex. A clamp's pad holds its mean position along its direction and lets the surface
  turn under it (:func:`qifreport.registration.restraint.restrained.clamp_pads`): one
  constraint per direction, whatever its radius.

:func:`classify_clamp_set` makes that statement (:class:`ClampSet`); the restraint's set-up
refuses a set whose smallest singular value is below :data:`WEAKEST_HOLD`, naming the
motions it holds weakly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WEAKEST_HOLD", "ClampSet", "classify_clamp_set", "rigid_motion_matrix"]

#: the smallest singular value of a clamp set's scaled rigid-motion matrix it is accepted
#: with: a clamp misread by 0.1 mm then moves the part by at most 1 mm at its radius (a
#: the sample panel's and the hat bracket's sets have 0.75-0.89, six normals of the sample
#: shell 0.02)
WEAKEST_HOLD = 0.1

#: the axes' names, for the weakly held motions
_AXES = "xyz"


@dataclass(frozen=True)
class ClampSet:
    """What a clamp set holds (:func:`classify_clamp_set`).

    Attributes
    ----------
    directions : restrained directions (one per clamp and axis it restrains), each a
        constraint.
    pad_radius : the clamps' contact radius, mm (each holds its mean position, not its tilt).
    rank : rigid motions held (6: all).
    singular : (6,) the scaled rigid-motion matrix's singular values, largest first.
    weak : the weakly held motions (singular value below :data:`WEAKEST_HOLD`), in words.
    """

    directions: int
    pad_radius: float
    rank: int
    singular: tuple[float, ...]
    weak: tuple[str, ...]

    @property
    def weakest(self) -> float:
        """The smallest singular value: a clamp misread by d mm moves the part by d / it."""
        return float(self.singular[-1]) if self.singular else 0.0

    @property
    def kind(self) -> str:
        """``"under-constrained"``, ``"kinematic"`` (locating, removes no flex) or
        ``"over-constrained"`` (N-2-1 restraint: bends the part to its clamps)."""
        if self.rank < 6:
            return "under-constrained"
        return "kinematic" if self.directions <= 6 else "over-constrained"

    @property
    def removes_flex(self) -> bool:
        """Whether holding the part can change its shape (an over-constrained set)."""
        return self.kind == "over-constrained"

    @property
    def ill_conditioned(self) -> bool:
        """Every rigid motion held, one of them too weakly to place the part."""
        return self.rank == 6 and self.weakest < WEAKEST_HOLD

    def describe(self) -> str:
        """One line, e.g. ``over-constrained (N-2-1): 7 directions ...``."""
        pads = f"contacts of {self.pad_radius:g} mm radius holding their mean position"
        what = {
            "under-constrained": f"under-constrained: holds {self.rank} of the 6 rigid motions",
            "kinematic": "kinematic locating set (3-2-1): places the part and removes no "
            "flex; the part is judged in its free shape, located",
            "over-constrained": "over-constrained (N-2-1): bends the part to its clamps",
        }[self.kind]
        return (
            f"{what}; {self.directions} restrained direction(s), {pads}; a clamp misread by "
            f"0.1 mm moves the part by up to {0.1 / max(self.weakest, 1e-12):.2g} mm"
        )

    def refusal(self) -> str | None:
        """Why the set cannot hold the part (None: it can)."""
        if self.rank < 6:
            return (
                f"the clamps leave {6 - self.rank} rigid motion(s) of the part free: a "
                "restrained inspection needs them to hold all six (3-2-1: e.g. three along "
                "the normal, two along one in-plane axis, one along the other)"
            )
        if self.ill_conditioned:
            return (
                f"the clamps hold {' and '.join(self.weak)} too weakly: a clamp misread by "
                f"0.1 mm moves the part by up to {0.1 / self.weakest:.2g} mm (their "
                f"directions are nearly dependent); add a clamp along the weak motion"
            )
        return None

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "directions": self.directions,
            "pad_radius_mm": self.pad_radius,
            "rigid_motions_held": self.rank,
            "singular_values": [round(float(s), 6) for s in self.singular],
            "weakly_held": list(self.weak),
            "removes_flex": self.removes_flex,
            "motion_per_mm_misread": round(1.0 / max(self.weakest, 1e-12), 4),
        }


def rigid_motion_matrix(
    points: np.ndarray, directions: np.ndarray, X: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The scaled rigid-motion matrix of restrained directions (module docstring).

    Parameters
    ----------
    points : (k, 3) mm, where each direction is restrained.
    directions : (k, 3) unit directions.
    X : (n, 3) mm, the part's points (its centre and radius).

    Returns
    -------
    A : (k, 6), columns translation x, y, z (per mm) and rotation about x, y, z (per R mm at
        the radius).
    centre : (3,) mm.  radius : R, mm.
    """
    centre = X.mean(axis=0)
    radius = max(float(np.linalg.norm(X - centre, axis=1).max()), 1e-12)
    c = (points - centre) / radius
    return np.hstack([directions, np.cross(c, directions)]), centre, radius


def classify_clamp_set(
    points: np.ndarray,
    directions: np.ndarray,
    X: np.ndarray,
    pad_radius: float,
) -> ClampSet:
    """What the restrained directions hold.

    Parameters
    ----------
    points, directions : (k, 3) each restrained direction's clamp point (mm) and unit vector.
    X : (n, 3) mm, the part's points.
    pad_radius : the clamps' contact radius, mm (reported).
    """
    A, _, _ = rigid_motion_matrix(points, directions, X)
    sv, vt = np.linalg.svd(A, full_matrices=False)[1:] if len(A) else (np.zeros(0), None)
    s = np.concatenate([sv, np.zeros(max(0, 6 - len(sv)))])[:6]
    rank = int(np.sum(s > 1e-9 * max(float(s[0]), 1e-300)))
    weak: tuple[str, ...] = ()
    if rank == 6 and s[-1] < WEAKEST_HOLD:
        weak = tuple(_motion_words(v) for v, x in zip(vt, sv, strict=True) if x < WEAKEST_HOLD)
    return ClampSet(
        directions=len(points),
        pad_radius=float(pad_radius),
        rank=rank,
        singular=tuple(float(x) for x in s),
        weak=weak,
    )


def _motion_words(v: np.ndarray) -> str:
    """A rigid motion (6,) (translation, scaled rotation) in words: its larger part."""
    t, w = v[:3], v[3:]
    part, name = (
        (t, "a slide along") if np.linalg.norm(t) >= np.linalg.norm(w) else (w, "a turn about")
    )
    u = part / np.linalg.norm(part)
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) > 0.9:
        return f"{name} {_AXES[k]}"
    return f"{name} ({', '.join(f'{x:.2f}' for x in u)})"
