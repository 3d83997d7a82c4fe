"""The compiled ΔC → δ conversion of every frame (ReadingModel.from_delta_c) against the sensor
model written out with numpy: the same taxels used, the same compressions bit for bit (NaN,
±inf, −0, below −C0, beyond full scale, a valid mask), and the same errors for bad shapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.sensor import delta_c_to_compression


@pytest.fixture(scope="module")
def readings(hexagon_bundle):
    return Reconstructor.from_bundle(hexagon_bundle[0]).readings


def reference(rm, dc, valid):
    p = rm._params
    dc = np.asarray(dc, dtype=np.float64)
    c0 = rm._rest_c
    ok = np.isfinite(dc) & (dc > -c0) & (np.abs(dc) <= rm.full_scale)
    if valid is not None:
        ok &= valid
    safe = np.where(ok, dc, 0.0)
    return delta_c_to_compression(safe, p["thickness"], p["epsilon_r"], p["area"]), ok


SPECIAL = [np.nan, np.inf, -np.inf, -0.0, 0.0, -1e-12, 5e-13, -5e-13, 1e-9]


@given(
    seed=st.integers(0, 2**31 - 1),
    scale=st.floats(-16.0, -11.5),
    masked=st.booleans(),
    specials=st.lists(st.sampled_from(SPECIAL), max_size=8),
)
def test_compiled_conversion_equals_the_sensor_model(readings, seed, scale, masked, specials):
    rng = np.random.default_rng(seed)
    k = readings.n_taxels
    dc = rng.normal(0.0, 10**scale, k)
    dc[rng.integers(0, k, len(specials))] = specials
    valid = rng.random(k) > 0.2 if masked else None
    want, ok_want = reference(readings, dc, valid)
    got, ok = readings.from_delta_c(dc, valid)
    assert np.array_equal(ok, ok_want)
    # The formula where used (sensor.delta_c_to_compression is the same expression); 0 else.
    assert np.allclose(got[ok], want[ok], rtol=1e-15, atol=0.0) and np.all(got[~ok] == 0.0)


def test_bad_shapes_are_named(readings):
    k = readings.n_taxels
    with pytest.raises(ValueError, match=rf"delta_c must have shape \({k},\)"):
        readings.from_delta_c(np.zeros(k + 1), None)
    with pytest.raises(ValueError, match=rf"valid must have shape \({k},\)"):
        readings.from_delta_c(np.zeros(k), np.ones(3, bool))
