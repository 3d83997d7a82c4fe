"""Stage 1 (tactile_contact.inverse.readings): ΔC → δ against the sensor model's own checked
conversion, what is excluded and why, the 8-bit lattice test, the noise a frame uses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_contact.inverse.readings import ReadingModel
from tactile_contact.model.sensor import (
    compression_to_delta_c,
    delta_c_to_compression,
    value_count_farad,
)

PARAMS = {
    "thickness": 2e-3,
    "epsilon_r": 4.37,
    "area": np.pi * (2e-3) ** 2,
    "farad_per_count": 0.32e-15,
    "shift": 2,
}
K = 12


@pytest.fixture(scope="module")
def model() -> ReadingModel:
    return ReadingModel(PARAMS, K)


def test_conversion_is_the_sensor_model(model):
    rng = np.random.default_rng(1)
    dc = rng.uniform(-30, 200, K) * model.lsb
    delta, ok = model.from_delta_c(dc, None)
    assert ok.all()
    expect = delta_c_to_compression(dc, PARAMS["thickness"], PARAMS["epsilon_r"], PARAMS["area"])
    np.testing.assert_allclose(delta, expect, rtol=1e-12)
    np.testing.assert_allclose(model.compression(dc), expect, rtol=1e-12)


def test_constants_from_the_layout(model):
    lsb = value_count_farad(PARAMS["farad_per_count"], PARAMS["shift"])
    assert model.lsb == pytest.approx(lsb)
    assert model.full_scale == pytest.approx(256 * lsb)
    one = delta_c_to_compression(np.array([lsb]), 2e-3, 4.37, PARAMS["area"])[0]
    assert model.count_sigma == pytest.approx(one / np.sqrt(6.0))
    assert np.all(model.default_noise == model.count_sigma) and model.default_noise.shape == (K,)


def test_excluded_readings_are_zero_and_not_used(model):
    dc = np.full(K, 10 * model.lsb)
    c0 = PARAMS["epsilon_r"] * 8.8541878128e-12 * PARAMS["area"] / PARAMS["thickness"]
    dc[1] = np.nan
    dc[2] = -c0  # no compression explains it
    dc[3] = 2 * model.full_scale  # no 8-bit reading gives it
    valid = np.ones(K, bool)
    valid[4] = False
    delta, ok = model.from_delta_c(dc, valid)
    assert list(np.flatnonzero(~ok)) == [1, 2, 3, 4]
    assert np.all(delta[~ok] == 0.0) and np.all(np.isfinite(delta))
    assert np.all(delta[ok] > 0)


def test_deflections_of_the_whole_layer_are_excluded(model):
    d = np.full(K, 1e-5)
    d[0] = PARAMS["thickness"]
    d[5] = np.inf
    delta, ok = model.from_deflection(d, None)
    assert list(np.flatnonzero(~ok)) == [0, 5] and np.all(delta[~ok] == 0)


@pytest.mark.parametrize(
    ("x", "valid", "match"),
    [
        (np.zeros(K + 1), None, rf"shape \({K},\)"),
        (np.zeros(K), np.ones(K - 1, bool), "valid must have shape"),
    ],
)
def test_wrong_shapes_name_the_shape(model, x, valid, match):
    with pytest.raises(ValueError, match=match):
        model.from_delta_c(x, valid)


def test_count_lattice(model):
    counts = np.zeros(K)
    counts[[2, 7]] = [3.0, -1.0]
    d = model.from_counts(counts)
    ok = np.ones(K, bool)
    assert model.on_count_lattice(d, ok)
    assert not model.on_count_lattice(d * 1.05, ok)
    assert not model.on_count_lattice(np.zeros(K), ok)  # nothing read: not "counts"
    # The lattice is that of the sensor model's ΔC: whole counts of lsb.
    dc = compression_to_delta_c(d, PARAMS["thickness"], PARAMS["epsilon_r"], PARAMS["area"])
    np.testing.assert_allclose(dc / model.lsb, counts, atol=1e-9)


@given(st.lists(st.floats(-50, 250), min_size=K, max_size=K))
def test_counts_round_trip(model_counts):
    model = ReadingModel(PARAMS, K)
    c = np.array(model_counts)
    np.testing.assert_allclose(model.counts(model.from_counts(c)), c, rtol=1e-9, atol=1e-9)


def test_noise_of_a_frame(model):
    assert model.noise(None) is model.default_noise
    a = model.noise(2e-6)
    assert a.shape == (K,) and np.all(a == 2e-6) and model.noise(2e-6) is a  # one array
    tracked = np.full(K, 3e-6)
    first = model.noise(tracked)
    assert model.noise(tracked) is first
    tracked[3] = 4e-6  # a caller that edits its array in place: read again
    assert model.noise(tracked)[3] == 4e-6
    for bad in (0.0, -1e-6, np.nan, np.full(K, np.inf)):
        with pytest.raises(ValueError, match="finite and > 0"):
            model.noise(bad)
