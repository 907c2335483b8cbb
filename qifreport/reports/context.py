"""What every block of the inspection page reads: the result, its provenance, the page and
the facts derived once for the whole page (bands, colour scale, the chosen views).

The blocks (:mod:`~qifreport.reports.header`, :mod:`~qifreport.reports.maps`,
:mod:`~qifreport.reports.stats`, :mod:`~qifreport.reports.tables`,
:mod:`~qifreport.reports.registration`, :mod:`~qifreport.reports.notes`) are functions of a
:class:`ReportContext`; :mod:`qifreport.reports.pdf` lays them out and draws them.
"""

from __future__ import annotations

import math

import numpy as np

from qifreport.metrology.inspection import InspectionResult
from qifreport.qif.writer import Provenance

from .kit import ReportPage
from .render import color_scale
from .views import ViewSpec, camera_frame, choose_views

__all__ = ["ReportContext", "clamp_markers", "distinct_bands", "map_views", "vertex_bands"]


def vertex_bands(res: InspectionResult) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex band ``(lower, upper)`` of the combined map, mm.

    Parameters
    ----------
    res : the inspection result.

    Returns
    -------
    lower, upper : (n,) arrays, mm; without per-zone bands, ``-tolerance`` and ``+tolerance``.
    """
    n = len(res.V)
    if res.bands is not None:
        return np.asarray(res.bands.lower, float), np.asarray(res.bands.upper, float)
    tol = np.broadcast_to(np.asarray(res.acceptance.tolerance, dtype=float), (n,))
    return -tol, tol.copy()


def distinct_bands(res: InspectionResult) -> list[tuple[float, float, list[str]]]:
    """Distinct bands ``(lower, upper, zone keys)`` in zone order, mm.

    Parameters
    ----------
    res : the inspection result.

    Returns
    -------
    list of (float, float, list of str)
        One entry per distinct band (limits equal within 1e-9 mm share one); without zones,
        the whole part's band under the key ``"part"``.
    """
    out: list[tuple[float, float, list[str]]] = []
    for z in res.zones:
        for b in out:
            if math.isclose(b[0], z.zone.lower, abs_tol=1e-9) and math.isclose(
                b[1], z.zone.upper, abs_tol=1e-9
            ):
                b[2].append(z.zone.key)
                break
        else:
            out.append((z.zone.lower, z.zone.upper, [z.zone.key]))
    if not out:
        lo, hi = vertex_bands(res)
        out.append((float(np.nanmin(lo)), float(np.nanmax(hi)), ["part"]))
    return out


def map_views(res: InspectionResult) -> list[ViewSpec]:
    """The views of the deviation map, A, B, C in order (two or three,
    :func:`~qifreport.reports.views.choose_views` on the registered nominal and its
    regions): the PDF's maps and the HTML viewer's view buttons."""
    return choose_views(res.V_registered, res.F, res.deviation, res.acceptance.regions, n_views=3)


def clamp_markers(res: InspectionResult) -> list[tuple[str, tuple]]:
    """The clamps of a restrained inspection for the maps: ``(label, (x, y, z) mm)``, each
    named with its force (N) when the material was stated and it bears 0.01 N or more (the
    page's clamp-force table is on the map); empty for an inspection not held at clamps."""
    r = res.restraint
    if r is None:
        return []
    return [
        (f"{c.name} {f:.2g} N" if r.forces_known and f >= 0.01 else c.name, c.position)
        for c, f in zip(r.clamps, r.force, strict=True)
    ]


class ReportContext(ReportPage):
    """The inspection page's inputs and the facts derived from them once.

    Attributes
    ----------
    res : the inspection result.  prov : its provenance (as written to the QIF file).
    chain_floor : measured chain floor, mm, or None (not measured).
    qif_name : the QIF results file named in the footer, or None.
    lower, upper : per-vertex band, mm (:func:`vertex_bands`).
    scale : colour-scale limit, mm (symmetric about 0).
    bands : the distinct bands (:func:`distinct_bands`).
    views : the chosen camera directions.
    spans : per view, the extent of the registered nominal across and up the picture, mm.
    Page geometry (``page``, ``W``, ``H``, ``M``, ``MT``, ``CW``):
    :class:`~qifreport.reports.kit.ReportPage`.
    """

    def __init__(
        self,
        res: InspectionResult,
        prov: Provenance,
        page: str,
        chain_floor: float | None,
        qif_name: str | None,
    ):
        super().__init__(page)
        self.res, self.prov = res, prov
        self.chain_floor = chain_floor
        self.qif_name = qif_name
        self.lower, self.upper = vertex_bands(res)
        self.scale = color_scale(res.deviation, self.lower, self.upper)
        self.bands = distinct_bands(res)
        self.views = map_views(res)
        Vr = np.asarray(res.V_registered, dtype=float)
        self.spans = []
        for v in self.views:
            r, u, _ = camera_frame(v)
            self.spans.append((max(float(np.ptp(Vr @ r)), 1e-6), max(float(np.ptp(Vr @ u)), 1e-6)))
