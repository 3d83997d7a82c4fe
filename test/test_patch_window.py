"""PatchPipeline's timing series (``Window``): the last values kept in a ring, and their
percentiles against numpy's ``np.percentile`` of the same values (linear method)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.ros  # (patch_pipeline imports rclpy)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=1, max_size=60),
    st.integers(1, 25),
)
def test_percentiles_are_numpys_of_the_values_kept(values, size):
    from tactile_contact.ros.patch_pipeline import Window

    w = Window(size)
    for x in values:
        w.append(x)
    kept = np.asarray(values[-size:])
    assert len(w) == len(kept)
    got = w.percentiles((50, 99))
    want = np.percentile(kept, (50, 99))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_an_empty_window_has_no_values():
    from tactile_contact.ros.patch_pipeline import Window

    assert len(Window(5)) == 0
