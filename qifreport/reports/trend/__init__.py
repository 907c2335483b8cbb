"""The one-page trend report of a batch: how the value of each characteristic runs over scans.

``qifreport batch`` inspects many scans of one part; its summary table (one row per scan, in
batch order) is drawn here on one page, A4 or US Letter, in the house style of the per-scan
report (:mod:`qifreport.reports.kit`: DejaVu Sans embedded, the same colours, number formats
and tables). The characteristics (:class:`TrendCharacteristic`) are the toleranced surfaces
(their profile value, mm) and the drawing's feature characteristics: geometric tolerances
(flatness, position ...: a zone width, mm, one-sided like a profile) and dimensions (a size,
mm, or an angle, degrees, between a lower and an upper limit). Top to bottom:

1. **Header** -- part, nominal SHA-256 (first 16 hex digits), creation time (UTC), number of
   scans and the count of each verdict (PASS, FAIL, NOT ESTABLISHED, ERROR); on the right the
   **pass rate**, PASS over the scans that produced a verdict, with the number that errored.
2. **Legend** of the run charts.
3. **Run charts**, one per characteristic (up to :data:`MAX_CHARTS`): the value of every
   scan against its sequence number, coloured by that characteristic's verdict on the scan
   (green PASS, red FAIL, grey NOT ESTABLISHED, dark for a basic dimension, which has none;
   without a verdict, by the value against the limits), joined by a thin line where the
   scans are at least a point apart (denser, the line would only grey the cloud of points);
   the limits and the mean as horizontal lines labelled on the right: for a profile or a
   geometric tolerance the tolerance (the upper limit; the lower limit of a zone width is 0,
   the axis starts there), for a dimension its lower and upper limits (``LSL``, ``USL``) about
   its nominal (a thin line, ``nom``) on an axis around them; scans that errored as grey
   crosses in a strip below the axis; values far beyond the rest as triangles at the top
   (or bottom) edge. Above each chart one line of statistics: n, mean, sigma, max (and min
   for a dimension), the capability -- the one-sided Cpk = (tolerance - mean) / (3 sigma) of
   a tolerance, Cp = (USL - LSL) / (6 sigma) and Cpk = min(USL - mean, mean - LSL) / (3 sigma)
   of a dimension -- and the pass count. With more characteristics than fit, the most
   critical are drawn, those with the smallest margin (the room between the worst value and
   its limit, relative to the tolerance: a tolerance's width, half a dimension's tolerance
   range), and the others named.
4. **Pass rate** against sequence (cumulative, and rolling for long batches) with the
   failed and errored scans marked below it, beside the **table of the scans that did not
   pass** (failed, not established or errored: sequence, serial or scan, verdict, deciding
   criterion or error), cut to :data:`MAX_FAILURE_ROWS` with the rest counted.
5. Definitions and a footer.

Nothing is labelled per point and the axis ticks are chosen from the page space, so the page
reads the same for 3 scans and for 2000. :func:`plan_trend` returns where everything goes
(used by :func:`write_trend_pdf`, and by the tests to find the points on a rasterized page).

The statistics (mean, sigma, Cp, Cpk, pass rates) are computed by
:mod:`qifreport.metrology.spc`, the axes and marks of the charts drawn with
:mod:`qifreport.reports.charts`. The package's modules, by responsibility: ``data`` (the
summary's columns and their statistics), ``layout`` (where everything goes, the charts'
scales), ``run_chart`` and ``pass_rate`` (drawing each chart), ``page`` (the header, legend,
table and footer, and the public functions), ``colors``.
"""

from __future__ import annotations

from qifreport.metrology.spc import CharacteristicStats

from ..charts import ChartGeometry, seq_ticks
from ..failures import MAX_FAILURE_ROWS
from .data import VERDICTS, TrendCharacteristic, characteristic_stats
from .layout import MAX_CHARTS, TrendLayout
from .page import plan_trend, write_trend_pdf

__all__ = [
    "TrendCharacteristic",
    "TrendLayout",
    "ChartGeometry",
    "plan_trend",
    "write_trend_pdf",
    "characteristic_stats",
    "CharacteristicStats",
    "seq_ticks",
    "MAX_CHARTS",
    "MAX_FAILURE_ROWS",
    "VERDICTS",
]
