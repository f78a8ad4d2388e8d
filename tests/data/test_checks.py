"""The table checks' own helpers, against the library they stand in for."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivecal.data import _checks

#: Segment names as bench files give them: text (stripped later), numbers, missing values of each kind.
_NAMES = st.sampled_from(["d", "q", " d ", "", "spin", 1, 1.0, 2, None, float("nan"), np.nan, True])


@settings(max_examples=300, deadline=None)
@given(blocks=st.lists(st.tuples(_NAMES, st.integers(1, 4)), max_size=8))
def test_factorize_is_pandas_factorize(blocks):
    """Codes (-1 where missing) and distinct values in order of appearance, as pandas.factorize gives them."""
    values = np.empty(sum(n for _, n in blocks), dtype=object)
    values[:] = [x for x, n in blocks for _ in range(n)]
    codes, labels = _checks._factorize(values)
    want_codes, want_labels = pd.factorize(values, use_na_sentinel=True)
    np.testing.assert_array_equal(codes, want_codes)
    assert list(labels) == list(want_labels)


@pytest.mark.parametrize("values", [np.array([1.5, np.nan, 1.5, 2.0]), np.array(["a", "a", "b"]), np.array([3, 3, 1])])
def test_factorize_of_typed_columns(values):
    codes, labels = _checks._factorize(values)
    want_codes, want_labels = pd.factorize(values, use_na_sentinel=True)
    np.testing.assert_array_equal(codes, want_codes)
    assert list(labels) == list(want_labels)


def test_factorize_refuses_unhashable_values_as_pandas_does():
    for bad in ([[1], [1]], [np.zeros(0), "abc"], [np.zeros(2), np.zeros(2)]):
        values = np.empty(len(bad), dtype=object)
        values[:] = bad
        with pytest.raises(TypeError):
            _checks._factorize(values)
