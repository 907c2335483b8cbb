"""A projected tolerance zone (ASME Y14.5 (P), ISO 1101 (P)): an axis's position judged
over a stated height beyond the feature, where the mating part sits, not inside the hole.

A hole tilted about its mouth by ``theta`` reads ``2 theta depth`` inside itself and
``2 theta h`` over a projected height ``h`` beyond the mouth: a bolt's shank leans by the
second. The zone starts at an **open end** of the feature, one beyond which there is no
material (a blind hole's bottom is not one: the part's winding number there is 1). STEP's
``PROJECTED_ZONE_DEFINITION`` names the end only as a shape aspect, which exporters leave
unplaced, so on a through hole both ends are candidates: the characteristic is decided only
when both agree (both within the zone: the larger value, PASS; both beyond: the smaller,
FAIL); otherwise it is not measured, both readings named.
"""

from __future__ import annotations

import re

import numpy as np

from qifreport.metrology.gdt.characteristic_types import Unmeasurable
from qifreport.metrology.gdt.datums import DatumFeature
from qifreport.metrology.gdt.measured_surface import MeasuredSurface

__all__ = ["projected_height", "projected_axis"]

_HEIGHT = re.compile(r"^projected(?:\s+([0-9.eE+-]+)\s*mm)?$")


def projected_height(modifiers: list[str]) -> float | None:
    """The projected zone's height, mm, among a characteristic's ``modifiers`` (None: no
    projected zone).

    Raises
    ------
    Unmeasurable
        A projected zone whose height the drawing does not give.
    """
    for m in modifiers:
        hit = _HEIGHT.match(m.strip())
        if hit is None:
            continue
        if hit.group(1) is None or not float(hit.group(1)) > 0:
            raise Unmeasurable(f"projected tolerance zone ({m}) without a height")
        return float(hit.group(1))
    return None


def _open_ends(feat: DatumFeature, surf: MeasuredSurface, faces) -> list[tuple[float, float]]:
    """``(z, outward sign)`` of each end of the feature's nominal length (``z`` along its
    axis from its origin, mm) beyond which there is no material."""
    import igl

    z = (surf.V[np.unique(surf.F[surf.triangles_on(faces)])] - feat.origin) @ feat.direction
    step = max(0.5 * (feat.radius or 0.0), 0.5)
    ends = [(float(z.min()), -1.0), (float(z.max()), 1.0)]
    probes = np.array([feat.origin + (e + s * step) * feat.direction for e, s in ends])
    w = igl.fast_winding_number(
        np.ascontiguousarray(surf.V, dtype=np.float64),
        np.ascontiguousarray(surf.F, dtype=np.int64),
        probes,
    )
    return [end for end, wn in zip(ends, np.abs(w), strict=True) if wn < 0.5]


def _offset_at(o: np.ndarray, a: np.ndarray, feat: DatumFeature, z: float) -> float:
    """How far the measured axis ``(o, a)`` lies from the true axis where it crosses the
    true axis's station ``z`` (mm)."""
    d = feat.direction
    t = (z - (o - feat.origin) @ d) / max(float(a @ d), 1e-9)
    p = o + t * a - feat.origin
    return float(np.linalg.norm(p - (p @ d) * d))


def projected_axis(
    o: np.ndarray,
    a: np.ndarray,
    feat: DatumFeature,
    surf: MeasuredSurface,
    faces,
    height: float,
    zone: float,
    measured: tuple[float, float],
) -> tuple[float, str, float]:
    """The position of the measured axis ``(o, a)`` over the projected zone of ``height``
    mm beyond the feature's open end, diametral, against the ``zone`` (mm, the tolerance
    with its bonus), how it was read, and the lever by which the axis's uncertainty grows
    out there (the projected end's distance from the middle of the ``measured`` stations
    ``(z0, z1)`` over their half-length, at least 1).

    Raises
    ------
    Unmeasurable
        No open end; or two open ends (a through hole) that disagree about the zone.
    """
    ends = _open_ends(feat, surf, faces)
    if not ends:
        raise Unmeasurable("projected tolerance zone on a feature with no open end")
    reads = [
        2 * max(_offset_at(o, a, feat, z), _offset_at(o, a, feat, z + s * height)) for z, s in ends
    ]
    mid = 0.5 * (measured[0] + measured[1])
    half = max(0.5 * abs(measured[1] - measured[0]), 1e-6)
    lever = max(max(abs(z + s * height - mid) for z, s in ends) / half, 1.0)
    how = f"axis (least squares) from true position over the projected {height:g} mm"
    if len(reads) == 1:
        return reads[0], f"{how} beyond its open end", lever
    lo, hi = min(reads), max(reads)
    if hi <= zone:
        return hi, f"{how} beyond either end (the larger, {lo:.4f} at the other)", lever
    if lo > zone:
        return lo, f"{how} beyond either end (the smaller, {hi:.4f} at the other)", lever
    raise Unmeasurable(
        f"projected tolerance zone: the drawing does not place it at either end of the through "
        f"feature, and they disagree ({reads[0]:.4f} and {reads[1]:.4f} mm against {zone:.4f})"
    )
