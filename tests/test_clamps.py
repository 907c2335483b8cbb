"""The ``--clamps`` file (:func:`qifreport.registration.restraint.clamps.parse_clamps`): rows read
with
their source line, directions canonical, every malformed row refused naming its line."""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.registration.restraint.clamps import Clamp, parse_clamps

GOOD = """name, x, y, z, directions, max_force_N
# the 3-2-1 scheme of the sample panel
A1, 10, 10, 0, n, 50
A2, 190, 10, 0, N
A3, 100, 90, 0, n, 50
B1, 0, 50, 0, yx
C1, 100, 0, 0, z
"""


def test_a_clamps_file_is_read():
    clamps = parse_clamps(GOOD)
    assert [c.name for c in clamps] == ["A1", "A2", "A3", "B1", "C1"]
    assert clamps[0] == Clamp("A1", (10.0, 10.0, 0.0), "n", 50.0, "clamps file line 3")
    assert clamps[1].directions == "n" and clamps[1].max_force is None
    assert clamps[3].directions == "xy"  # canonical order
    axes = clamps[3].axes(np.array([0.0, 0.0, 1.0]))
    assert np.allclose(axes, [[1, 0, 0], [0, 1, 0]])
    assert np.allclose(clamps[0].axes(np.array([0.0, 0.0, 2.0])), [[0, 0, 1]])
    assert clamps[0].to_dict()["position_mm"] == [10.0, 10.0, 0.0]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("A1, 1, 2, 3\n", "line 1: 4 fields"),
        ("A1, 1, 2, 3, q\n", "line 1: directions 'q'"),
        ("A1, 1, 2, 3, xx\n", "line 1: directions 'xx'"),
        ("A1, 1, two, 3, n\n", "line 1: y is not a number"),
        ("A1, 1, 2, nan, n\n", "line 1: z is not finite"),
        ("A1, 1, 2, 3, n, -5\n", "line 1: max force must be positive"),
        ("A1, 1, 2, 3, n\nA1, 4, 5, 6, n\n", "line 2: clamp 'A1' named twice"),
        (", 1, 2, 3, n\n", "line 1: a clamp needs a name"),
        ("# nothing\n\n", "no clamp in it"),
    ],
)
def test_malformed_rows_are_refused_naming_the_line(text, message):
    with pytest.raises(ValueError, match=message):
        parse_clamps(text)
