"""Size (scale) error of a part, from its trim-edge deviations.

A part made 2 % too large lies on its nominal surface after a best fit that slides it along
the surface: its normal deviations stay small and a profile check passes. Its outline does
not: a scale ``s`` about a centre ``c`` moves the edge at rim vertex ``v`` (outward in-plane
normal ``b``) by ``(s - 1) (v - c) . b``, up to ``(s - 1) L`` at the farthest rim point
(``L`` the rim's half-extent, 85 mm on the 170 mm shell: 1.7 mm at 2 %).

:func:`size_error` fits the trim-edge deviations ``e`` of
:func:`qifreport.metrology.deviation.edges.
edge_deviation` (seen rim vertices, weighted by their rim length) with the linearised
similarity

    e_i = k (v_i - c) . b_i + t . b_i + theta (n0 x (v_i - c)) . b_i,

``k = s - 1`` the scale, ``t`` an in-plane translation (along the rim's two principal axes
``u1, u2``) and ``theta`` a rotation about the rim's mean normal ``n0``. The translation and
rotation are the in-plane rigid slide a normal-deviation registration leaves free (on the
gently curved shell the registered nominal and the scan can sit a millimetre apart along
the part); they are fitted, not judged. The fit is robust (Huber, then Tukey's biweight, on
a MAD scale), so a few rim stretches spoiled by dropouts do not carry it. A second fit with
one scale per principal axis (``k1, k2``) is reported for anisotropic shrinkage.

The spread of ``k`` is a delete-one-block jackknife over 12 blocks of the seen rim (cut by
angle about ``c``): the residuals along a rim are correlated (the fixture's in-plane error
varies smoothly), so the textbook standard error would be too small.

Decision rule. ``D = |k| L``, the largest edge displacement the scale error produces;
``U = 2 sigma_k L`` its expanded uncertainty; ``limit = fraction x tolerance`` (default
``fraction = 1``: the outline may be off by the edge tolerance):

* ``"no rim"``: the nominal has no open rim and no trim crease; the size is not checked.
* ``"not established"``: the rim is seen over less than ``min_seen`` of its length (or at
  fewer than 8 vertices): no scale is fitted;
* ``"size error"`` (:attr:`SizeEstimate.flagged`): ``D > limit + U``: beyond the limit by
  more than the uncertainty (non-conformance proved, as in ISO 14253-1);
* ``"conforming"``: ``D <= limit`` and ``U <= tolerance``;
* ``"not established"`` otherwise: ``D`` within ``U`` above the limit, or an uncertainty
  larger than the tolerance (the seen rim cannot tell a size error of the tolerance's
  order from none, e.g. only one side seen).
* ``"not established"``, the rim *too sparse* (:func:`density_rule`): the seen strips hold
  fewer points per mm^2 than the toleranced surfaces' least density
  (:func:`~qifreport.metrology.acceptance.coverage.min_scan_density`); each edge is read
  only to about a point spacing, and a sparse rim's outermost points, fewer than the
  estimate's order statistics assume, read the edge inside the true one (a conforming shell
  at 15 % of its scan read -0.82 mm). The size is then not measured, as a zone scanned too
  sparsely is.

A uniform offset of the whole outline (trimmed 1 mm long all round) reads as a scale too;
both mean that the outline lies outside the nominal's.

Measured (``bench/size_detect.py``: the real inspection of the simulated 170 x 110 mm shell,
edge tolerance 0.5 mm, so a limit of 0.5 mm at ``L`` of about 80 mm, i.e. 0.6 %): true to size
at compliance amplitudes 1 % and 2 % of the diagonal, scanner seeds 1..5, ``|D|`` 0.22 to
0.34 mm, never flagged (0.16 mm below the limit; the analytic free state is itself 0.3 % and
0.5 % smaller than the nominal: its normal field is no isometry); 2 % too large ``D`` +1.45
to +1.59 mm and 2 % too small -2.03 to -2.14 mm, flagged in every seed (0.74 and 1.38 mm
beyond ``limit + U``); also flagged or conforming as they should through a pose search, a
3-degree pose error left to the ICP and a scan with one short edge cut off. The estimate
reads a scale error about 12 % large on the curved shell (the fixture's in-plane response);
it varies by 0.0002 between scanner seeds, and ``U`` is 0.1 to 0.25 mm. On the STEP panel
(a closed solid, crease mode) scanned from above: 1.0038, 1.0226 and 0.9848 at 1.0, 1.02 and
0.98.

All lengths are mm.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from qifreport.metrology.acceptance.statistics import json_float
from qifreport.metrology.deviation.edge_statistics import EdgeDeviation, EdgeSegment, rim_segments
from qifreport.metrology.deviation.rim import RimFrames

__all__ = [
    "DEFAULT_FRACTION",
    "DEFAULT_MIN_SEEN",
    "SizeEstimate",
    "density_rule",
    "size_error",
]

log = logging.getLogger(__name__)

#: the limit on |s - 1| L, as a fraction of the edge tolerance
DEFAULT_FRACTION = 1.0
#: the size is not established when less than this share of the rim length is seen
DEFAULT_MIN_SEEN = 0.25
#: jackknife blocks of the seen rim
_BLOCKS = 12
#: robust weights: Huber's and Tukey's tuning constants (in robust scales)
_HUBER, _TUKEY = 1.345, 4.685
_IRLS_ITER = 30


@dataclass
class SizeEstimate:
    """The part's scale against the nominal, from the rim (mm).

    Attributes
    ----------
    status : ``"conforming"``, ``"size error"``, ``"not established"`` or ``"no rim"``
        (module docstring).
    scale : ``s``, the scan's size over the nominal's (1.02: 2 % too large); NaN if no fit.
    scale_sd : jackknife standard deviation of ``s``.
    scale_axes : (2,) one scale per principal axis of the rim (``u1``: the longer).
    half_extent : ``L``, mm: the largest ``(v - c) . b`` over the rim (corners excluded).
    half_extents : (2,) the rim's half-extents along ``u1, u2``, mm.
    size_deviation : ``(s - 1) L``, mm, signed: the edge displacement at the farthest rim
        point.
    translation : (3,) fitted in-plane slide of the scan against the nominal, mm.
    rotation : fitted rotation about the rim's normal, rad.
    residual_scale : robust scale (MAD) of the fit's residuals, mm.
    n_used : seen rim vertices in the fit (non-zero final weight).
    seen_fraction : share of the rim length seen.
    tolerance : edge tolerance, mm.  fraction : the rule's fraction of it.
    min_seen : the rule's least seen share.
    center : (3,) ``c``, mm.  axes : (3, 3) rows ``u1, u2, n0``.
    seated : (k,) edge deviation after removing the fitted in-plane slide (scale kept), mm;
        NaN where not seen. Per rim vertex of :attr:`EdgeDeviation.rim`.
    residual : (k,) edge deviation minus the whole fit, mm (local trim errors).
    seated_segments : rim stretches where ``|seated| > tolerance``.
    density : points per mm^2 in the rim strips (:func:`rim_density`); NaN: not counted.
    min_density : the density rule's least points per mm^2 (:func:`density_rule`); NaN: no
        rule.
    """

    status: str
    scale: float
    scale_sd: float
    scale_axes: np.ndarray
    half_extent: float
    half_extents: np.ndarray
    size_deviation: float
    translation: np.ndarray
    rotation: float
    residual_scale: float
    n_used: int
    seen_fraction: float
    tolerance: float
    fraction: float
    min_seen: float
    center: np.ndarray
    axes: np.ndarray
    seated: np.ndarray
    residual: np.ndarray
    seated_segments: list[EdgeSegment] = field(default_factory=list)
    density: float = float("nan")
    min_density: float = float("nan")

    @property
    def too_sparse(self) -> bool:
        """True when the seen rim holds fewer points per mm^2 than the density rule's least."""
        return bool(self.density < self.min_density)

    @property
    def flagged(self) -> bool:
        """True for a size error (the rule's ``"size error"``)."""
        return self.status == "size error"

    @property
    def established(self) -> bool:
        """True when the rule could decide (``"conforming"`` or ``"size error"``)."""
        return self.status in ("conforming", "size error")

    @property
    def limit(self) -> float:
        """The threshold on ``|s - 1| L``, mm."""
        return self.fraction * self.tolerance

    @property
    def uncertainty(self) -> float:
        """``U = 2 sigma L``, mm: the expanded uncertainty of :attr:`size_deviation`."""
        return 2.0 * self.scale_sd * self.half_extent

    def to_dict(self) -> dict:
        """JSON-ready summary (NaN -> None)."""
        return {
            "status": self.status,
            "flagged": self.flagged,
            "scale": json_float(self.scale),
            "scale_sd": json_float(self.scale_sd),
            "scale_axes": [json_float(x) for x in self.scale_axes],
            "half_extent_mm": json_float(self.half_extent),
            "half_extents_mm": [json_float(x) for x in self.half_extents],
            "size_deviation_mm": json_float(self.size_deviation),
            "uncertainty_mm": json_float(self.uncertainty),
            "limit_mm": json_float(self.limit),
            "translation_mm": [json_float(x) for x in self.translation],
            "rotation_rad": json_float(self.rotation),
            "residual_scale_mm": json_float(self.residual_scale),
            "n_used": int(self.n_used),
            "seen_fraction": json_float(self.seen_fraction),
            "tolerance_mm": json_float(self.tolerance),
            "fraction": json_float(self.fraction),
            "min_seen": json_float(self.min_seen),
            "n_seated_segments": len(self.seated_segments),
            "seated_segments": [s.to_dict() for s in self.seated_segments[:50]],
            "points_per_mm2": json_float(self.density),
            "min_points_per_mm2": json_float(self.min_density),
        }

    def reasons(self) -> list[str]:
        """One-line findings (why the size is what the status says)."""
        if self.status == "no rim":
            return ["size not checked: the nominal has no open rim and no trim crease"]
        if not np.isfinite(self.scale):
            return [
                f"size not established: the rim is seen over {100 * self.seen_fraction:.0f} % "
                "of its length, too little to fit a scale"
            ]
        head = (
            f"scale {self.scale:.4f} +/- {self.scale_sd:.4f} (edge displacement "
            f"{self.size_deviation:+.2f} +/- {self.uncertainty:.2f} mm at "
            f"{self.half_extent:.0f} mm from the centre, limit {self.limit:.2g} mm)"
        )
        if self.status == "size error":
            return [f"size error: {head}"]
        if self.status == "conforming":
            return [f"size conforming: {head}"]
        U = self.uncertainty
        if self.too_sparse:
            why = (
                f"scan too sparse at the rim: {self.density:.2f} points/mm^2 < "
                f"{self.min_density:.2f}, each edge read to about "
                f"{1.0 / np.sqrt(self.density):.1f} mm"
            )
        elif self.seen_fraction < self.min_seen:
            why = f"rim seen over {100 * self.seen_fraction:.0f} % < {100 * self.min_seen:.0f} %"
        elif U > self.tolerance:
            why = f"uncertainty +/-{U:.2f} mm exceeds the {self.tolerance:.2g} mm tolerance"
        else:
            why = f"beyond the limit by less than the uncertainty +/-{U:.2f} mm"
        return [f"size not established ({why}): {head}"]


def _robust_fit(A: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted robust least squares: Huber from least squares, then Tukey's biweight.

    Returns the coefficients and the final robust weights (without ``w``).
    """
    rw = np.ones(len(y))

    def solve(weights: np.ndarray) -> np.ndarray:
        s = np.sqrt(weights)
        x, *_ = np.linalg.lstsq(A * s[:, None], y * s, rcond=1e-10)
        return x

    x = solve(w)
    for kind in ("huber", "tukey"):
        for _ in range(_IRLS_ITER):
            r = y - A @ x
            sigma = 1.4826 * np.median(np.abs(r - np.median(r)))
            sigma = max(sigma, 1e-6)
            a = np.abs(r) / sigma
            if kind == "huber":
                rw = np.minimum(1.0, _HUBER / np.maximum(a, 1e-12))
            else:
                rw = np.where(a < _TUKEY, (1.0 - (a / _TUKEY) ** 2) ** 2, 0.0)
            if np.count_nonzero(rw) < A.shape[1] + 1:
                break
            x_new = solve(w * rw)
            done = np.max(np.abs(x_new - x)) < 1e-9
            x = x_new
            if done:
                break
    return x, rw


def _blocks(angle: np.ndarray, n: int) -> np.ndarray:
    """Block label (0..n-1) of each point: contiguous runs of equal count by angle."""
    order = np.argsort(angle, kind="stable")
    lab = np.empty(len(angle), dtype=np.int64)
    lab[order] = np.arange(len(angle)) * n // max(len(angle), 1)
    return lab


def _blank(edges: EdgeDeviation, tol: float, fraction: float, min_seen: float) -> SizeEstimate:
    """The estimate of a rim without a fit (``"no rim"``; every value NaN)."""
    k = len(edges.rim.vertices)
    nan3 = np.full(3, np.nan)
    return SizeEstimate(
        status="no rim",
        scale=float("nan"),
        scale_sd=float("nan"),
        scale_axes=np.full(2, np.nan),
        half_extent=float("nan"),
        half_extents=np.full(2, np.nan),
        size_deviation=float("nan"),
        translation=nan3,
        rotation=float("nan"),
        residual_scale=float("nan"),
        n_used=0,
        seen_fraction=edges.seen_fraction,
        tolerance=tol,
        fraction=float(fraction),
        min_seen=float(min_seen),
        center=nan3,
        axes=np.full((3, 3), np.nan),
        seated=np.full(k, np.nan),
        residual=np.full(k, np.nan),
    )


def _rim_axes(rim: RimFrames) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rim's length-weighted centre (3,), principal axes (3, 3) (rows: longest,
    second, normal), each rim vertex about the centre (k, 3), mm, and the fit's design
    matrix (k, 4): each vertex's outward deviation per unit scale, translation along the
    two in-plane axes and rotation about the normal."""
    X, wl, B = rim.position, rim.length, rim.outward
    c = (X * wl[:, None]).sum(axis=0) / max(float(wl.sum()), 1e-300)
    R = X - c
    cov = (R * wl[:, None]).T @ R
    _, evecs = np.linalg.eigh(cov)
    axes = evecs[:, ::-1].T  # rows u1 (longest), u2, n0
    A = np.c_[
        np.einsum("ij,ij->i", R, B),
        B @ axes[0],
        B @ axes[1],
        np.einsum("ij,ij->i", np.cross(axes[2], R), B),
    ]
    return c, axes, R, A


def _jackknife_sd(A: np.ndarray, y: np.ndarray, w: np.ndarray, angle: np.ndarray) -> float:
    """The standard deviation of the scale (the fit's first coefficient) by the jackknife
    over :data:`_BLOCKS` angular blocks of the seen rim (``angle`` (k,), rad); inf with
    fewer than two blocks."""
    lab = _blocks(angle, _BLOCKS)
    ks = []
    for b in range(_BLOCKS):
        m = lab != b
        if m.sum() >= 8:
            ks.append(_robust_fit(A[m], y[m], w[m])[0][0])
    ks = np.asarray(ks)
    nb = len(ks)
    return float(np.sqrt((nb - 1) / nb * np.sum((ks - ks.mean()) ** 2))) if nb > 1 else np.inf


def size_error(
    edges: EdgeDeviation,
    *,
    tolerance: float | None = None,
    fraction: float = DEFAULT_FRACTION,
    min_seen: float = DEFAULT_MIN_SEEN,
) -> SizeEstimate:
    """Estimate the part's scale from its trim-edge deviations and apply the size rule.

    Parameters
    ----------
    edges : :func:`qifreport.metrology.deviation.edges.edge_deviation` of the scan against the
        (registered) nominal; its rim positions and outward normals are the fit's geometry.
    tolerance : edge tolerance, mm; default ``edges.tolerance``.
    fraction : the limit on ``|s - 1| L`` is ``fraction x tolerance`` (the rule, module
        docstring: a size error beyond ``limit + U``, conforming up to ``limit``).
    min_seen : the size is not established below this seen share of the rim length.

    Returns
    -------
    :class:`SizeEstimate` (the rule is in the module docstring).
    """
    tol = float(edges.tolerance if tolerance is None else tolerance)
    rim = edges.rim
    k = len(rim.vertices)
    blank = _blank(edges, tol, fraction, min_seen)
    if rim.empty:
        return blank
    c, axes, R, A = _rim_axes(rim)
    inner = ~rim.corner
    half = float(A[inner, 0].max()) if inner.any() else float(A[:, 0].max())
    halves = np.abs(R @ axes[:2].T).max(axis=0)
    blank.status = "not established"
    blank.center, blank.axes = c, axes
    blank.half_extent, blank.half_extents = half, halves
    seen = edges.seen
    if seen.sum() < 8:
        log.info("size: %d seen rim vertices, no fit", int(seen.sum()))
        return blank
    y = edges.deviation[seen]
    w = rim.length[seen]
    x, rw = _robust_fit(A[seen], y, w)
    # anisotropic: one scale per principal axis
    A2 = np.c_[(R @ axes[0]) * A[:, 1], (R @ axes[1]) * A[:, 2], A[:, 1:]]
    x2, _ = _robust_fit(A2[seen], y, w)
    sd = _jackknife_sd(A[seen], y, w, np.arctan2(R[seen] @ axes[1], R[seen] @ axes[0]))
    res = y - A[seen] @ x
    seated = np.full(k, np.nan)
    seated[seen] = y - A[seen][:, 1:] @ x[1:]
    residual = np.full(k, np.nan)
    residual[seen] = res
    kk = float(x[0])
    est = SizeEstimate(
        status="not established",
        scale=1.0 + kk,
        scale_sd=sd,
        scale_axes=1.0 + x2[:2],
        half_extent=half,
        half_extents=halves,
        size_deviation=kk * half,
        translation=x[1] * axes[0] + x[2] * axes[1],
        rotation=float(x[3]),
        residual_scale=float(1.4826 * np.median(np.abs(res - np.median(res)))),
        n_used=int(np.count_nonzero(rw)),
        seen_fraction=edges.seen_fraction,
        tolerance=tol,
        fraction=float(fraction),
        min_seen=float(min_seen),
        center=c,
        axes=axes,
        seated=seated,
        residual=residual,
        seated_segments=rim_segments(rim, seated, tol),
    )
    est.status = _size_rule(est, kk, fraction)
    log.info("size: %s", est.reasons()[0])
    return est


def rim_density(edges: EdgeDeviation) -> float:
    """The scan's points per mm^2 along the rim: the strips' points (``2 radius`` along the
    rim by ``radius`` deep) over the whole rim but its corners, rim-length weighted, a strip
    left unseen counting its points too (none where the coarse edge was not found): the seen
    strips alone are the densest ones on a sparse scan. NaN without a rim."""
    inner = ~edges.rim.corner
    w = edges.rim.length[inner]
    if len(w) == 0 or not w.sum() > 0:
        return float("nan")
    n = edges.points[inner].astype(np.float64)
    return float(np.average(n, weights=w) / (2.0 * edges.radius**2))


def density_rule(size: SizeEstimate, edges: EdgeDeviation, min_density: float) -> SizeEstimate:
    """``size`` with the rim's density rule (module docstring): its strips' points per mm^2
    (:func:`rim_density`) against ``min_density``
    (:func:`~qifreport.metrology.acceptance.coverage.min_scan_density` of the region
    criterion's area); a decided size on a rim below it is ``"not established"``. The
    estimate is changed in place and returned."""
    size.density = rim_density(edges)
    size.min_density = float(min_density)
    if size.too_sparse and size.status in ("conforming", "size error"):
        size.status = "not established"
        log.info("size: %s", size.reasons()[0])
    return size


def _size_rule(est: SizeEstimate, kk: float, fraction: float) -> str:
    """The size rule (module docstring) on an estimate of scale ``1 + kk``: ``"size
    error"`` beyond the limit ``fraction x tolerance`` by more than the uncertainty,
    ``"conforming"`` within the limit with the uncertainty within the tolerance, else
    ``"not established"`` (as with too little of the rim seen)."""
    if est.seen_fraction < est.min_seen:
        return "not established"
    half, tol = est.half_extent, est.tolerance
    D, U, limit = abs(kk) * half, 2.0 * est.scale_sd * half, fraction * tol
    if D > limit + U:
        return "size error"
    if D <= limit and U <= tol:
        return "conforming"
    return "not established"
