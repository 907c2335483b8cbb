"""sort_within_groups is np.lexsort((x, group)), exactly, including its hard cases."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from qifreport.metrology.groups import sort_within_groups


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 400).flatmap(
        lambda n: st.tuples(
            arrays(np.int64, n, elements=st.integers(-5, 40)),
            arrays(np.float64, n, elements=st.floats(-1e3, 1e3, allow_nan=False)),
        )
    )
)
def test_equals_lexsort(case: tuple[np.ndarray, np.ndarray]) -> None:
    group, x = case
    np.testing.assert_array_equal(sort_within_groups(group, x), np.lexsort((x, group)))


def test_values_the_key_cannot_separate() -> None:
    """Residuals a femtometre apart on a 2 mm range, in large groups, in reverse order: the
    key rounds them together and the result is still lexsort's."""
    rng = np.random.default_rng(1)
    group = np.repeat(np.arange(50_000, 50_200), 30)
    x = rng.normal(0, 0.02, len(group))
    x[::30] = 1.0
    x[1::30] = -1.0  # the range: 2 mm
    x[2::30] = 0.0
    x[3::30] = 1e-12  # 1e-12 apart: one key at groups ~5e4, reversed below
    x = x[::-1].copy()
    group = group[::-1].copy()
    np.testing.assert_array_equal(sort_within_groups(group, x), np.lexsort((x, group)))


def test_large_random_and_special_values() -> None:
    rng = np.random.default_rng(2)
    group = np.sort(rng.integers(0, 36_000, 700_000))
    x = np.round(rng.normal(0, 0.02, len(group)), 4)  # many exact ties
    np.testing.assert_array_equal(sort_within_groups(group, x), np.lexsort((x, group)))
    x[5] = np.nan
    np.testing.assert_array_equal(sort_within_groups(group, x), np.lexsort((x, group)))
    far = group.copy()
    far[0] = -(2**40)
    np.testing.assert_array_equal(sort_within_groups(far, x), np.lexsort((x, far)))
