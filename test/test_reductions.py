"""inverse/reductions.py against numpy: the same values bit for bit (the fit's χ² test, its
posterior's noise and the followed state read them, so a last-bit change would move results)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactile_contact.inverse.reductions import median, norm

FINITE = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, allow_subnormal=True)


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, st.integers(1, 241), elements=FINITE))
def test_median_is_numpys_bit_for_bit(x: np.ndarray) -> None:
    before = x.copy()
    assert median(x) == float(np.median(x))
    np.testing.assert_array_equal(x, before)  # (partition works on a copy)


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, st.integers(0, 241), elements=FINITE))
def test_norm_is_numpys_bit_for_bit(x: np.ndarray) -> None:
    assert norm(x) == float(np.linalg.norm(x))


def test_median_of_readings_with_ties_and_of_nothing() -> None:
    # 8-bit readings' noise: whole counts repeated, an even number of taxels
    s = np.repeat([4.3e-6, 4.3e-6, 6.1e-6, 9.0e-6], 60)
    assert median(s) == float(np.median(s)) == (4.3e-6 + 6.1e-6) / 2.0
    assert median(np.array([2.5])) == 2.5
    assert math.isnan(median(np.array([])))
