"""The trend page's colours (RGB 0..1), beside the house colours of
:mod:`qifreport.reports.kit`."""

from __future__ import annotations

from ..kit import FAIL_BG, FAIL_INK
from ..render import GREEN_ZERO

#: point colours by the characteristic's verdict on the scan
POINT_COLORS = {"PASS": GREEN_ZERO, "FAIL": FAIL_BG, "NOT ESTABLISHED": (0.62, 0.62, 0.62)}
#: points of a basic dimension (a value without a verdict)
BASIC_COLOR = (0.22, 0.22, 0.22)
#: the tolerance (upper limit) line, a dimension's limits, and the mean line
TOL_COLOR = FAIL_INK
MEAN_COLOR = (0.18, 0.33, 0.62)
#: a dimension's nominal
NOMINAL_COLOR = (0.35, 0.35, 0.35)
#: the line joining the points, and the marks of scans that errored
JOIN_COLOR = (0.70, 0.70, 0.70)
ERROR_COLOR = (0.45, 0.45, 0.45)
#: the rolling pass rate
ROLL_COLOR = (0.50, 0.63, 0.86)
