"""Sensor model: counts ↔ ΔC ↔ compression, against closed forms and the plate formula."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from tactile_contact.model.sensor import (
    EPSILON_0,
    SensorParams,
    compression_in_range,
    compression_to_delta_c,
    counts_to_delta_c,
    delta_c_in_range,
    delta_c_to_compression,
    delta_c_to_counts,
    module_value,
    quantize_counts,
    rest_capacitance,
    value_count_farad,
)

H = 2e-3
ER = 4.37
A = np.pi * 2e-3**2


def test_rest_capacitance_matches_design_value() -> None:
    # DESIGN.md §6: C0 ≈ 0.24 pF for the research parameters.
    assert rest_capacitance(H, ER, A) == pytest.approx(0.243e-12, rel=0.01)


def test_one_count_is_about_ten_micrometres() -> None:
    # DESIGN.md §2: one 8-bit count (0.32 fF · 2**2) is about 10 µm of compression.
    dc = value_count_farad(0.32e-15, 2)
    assert dc == pytest.approx(1.28e-15)
    assert delta_c_to_compression(dc, H, ER, A) == pytest.approx(10.5e-6, rel=0.02)


def test_compression_matches_plate_capacitance_difference() -> None:
    # Independent reference: C(h_c) − C(h_n) of a parallel plate with gap h_c = h − δ.
    for delta in (-50e-6, -1e-6, 1e-6, 0.3e-3, 1.9e-3):
        ref = EPSILON_0 * ER * A * (1 / (H - delta) - 1 / H)
        assert compression_to_delta_c(delta, H, ER, A) == pytest.approx(ref, rel=1e-12)
        assert delta_c_to_compression(ref, H, ER, A) == pytest.approx(delta, rel=1e-9)


def test_negative_values_are_not_clipped() -> None:
    d = delta_c_to_compression(np.array([-2e-15, 0.0, 2e-15]), H, ER, A)
    assert d[0] < 0 < d[2] and d[1] == 0.0
    assert d[0] == pytest.approx(-d[2], rel=0.05)


def test_impossible_values_raise_with_value_and_limit() -> None:
    with pytest.raises(ValueError, match="not below the thickness"):
        compression_to_delta_c([0.0, H], H, ER, A)
    c0 = rest_capacitance(H, ER, A)
    with pytest.raises(ValueError, match="-C0"):
        delta_c_to_compression(-c0, H, ER, A)
    assert list(compression_in_range([0.0, H, 3 * H], H)) == [True, False, False]
    assert list(delta_c_in_range([-2 * c0, -c0, 0.0], H, ER, A)) == [False, False, True]
    with pytest.raises(ValueError, match="thickness"):
        delta_c_to_compression(1e-15, -H, ER, A)
    with pytest.raises(ValueError, match="finite"):
        delta_c_to_compression(np.nan, H, ER, A)
    with pytest.raises(ValueError, match="shift"):
        counts_to_delta_c(200, 240, 0.32e-15, 16)


def test_counts_sign_convention() -> None:
    # Lower value than baseline = more capacitance = compression.
    dc = counts_to_delta_c([230, 240, 250], 240.0, 0.32e-15, 2)
    assert np.allclose(dc, [12.8e-15, 0.0, -12.8e-15])


def test_module_value_reproduces_firmware_shift_and_clipping() -> None:
    v, oor = module_value([0, 3, 4, -1, -4, -5, 4000, -100], no_load=240, shift=2)
    # noLoad − (cdc >> 2) with arithmetic (floor) shift, clipped to 0..255.
    assert list(v) == [240, 240, 239, 241, 241, 242, 0, 255]
    assert list(oor) == [False] * 6 + [True, True]
    q, sat = quantize_counts([-3.2, 0.4, 12.6, 254.6, 300])
    assert list(q) == [0, 0, 13, 255, 255]
    assert list(sat) == [True, True, False, True, True]


@given(
    counts=st.lists(st.integers(0, 255), min_size=1, max_size=12),
    baseline=st.floats(200, 250),
    gain=st.floats(0.1e-15, 1e-15),
    shift=st.integers(0, 4),
)
def test_counts_to_compression_round_trip(counts, baseline, gain, shift) -> None:
    dc = counts_to_delta_c(counts, baseline, gain, shift)
    back = delta_c_to_counts(dc, baseline, gain, shift)
    assert np.allclose(back, counts, rtol=0, atol=1e-9)
    assume(np.all(delta_c_in_range(dc, H, ER, A)))
    delta = delta_c_to_compression(dc, H, ER, A)
    assert np.all(delta < H)
    dc2 = compression_to_delta_c(delta, H, ER, A)
    assert np.allclose(dc2, dc, rtol=1e-9, atol=1e-24)


@given(
    delta=st.floats(-5e-3, 1.99e-3),
    h=st.floats(1e-3, 5e-3),
    er=st.floats(1.0, 10.0),
    r=st.floats(0.5e-3, 3e-3),
)
def test_compression_round_trip(delta, h, er, r) -> None:
    delta = min(delta, 0.99 * h)
    area = np.pi * r * r
    dc = compression_to_delta_c(delta, h, er, area)
    assert delta_c_to_compression(dc, h, er, area) == pytest.approx(delta, rel=1e-9, abs=1e-15)


def test_sensor_params_bundle() -> None:
    p = SensorParams()
    assert p.rest_capacitance == pytest.approx(rest_capacitance(H, ER, A))
    assert p.value_count_farad == pytest.approx(1.28e-15)
    dc = p.counts_to_delta_c([235], 240)
    assert p.compression_to_delta_c(p.delta_c_to_compression(dc)) == pytest.approx(dc)
    with pytest.raises(ValueError, match="no_load"):
        SensorParams(no_load=300)


def test_per_taxel_parameters_broadcast() -> None:
    h = np.array([1e-3, 2e-3, 3e-3])
    area = np.array([1e-5, 1.2e-5, 2e-5])
    delta = np.array([1e-4, -2e-5, 5e-4])
    dc = compression_to_delta_c(delta, h, ER, area)
    for k in range(3):  # element by element against the scalar form
        assert dc[k] == pytest.approx(compression_to_delta_c(delta[k], h[k], ER, area[k]))
    assert np.allclose(delta_c_to_compression(dc, h, ER, area), delta)
    gains = counts_to_delta_c([230, 230], 240, [0.24e-15, 0.32e-15], [2, 3])
    assert np.allclose(gains, [10 * 4 * 0.24e-15, 10 * 8 * 0.32e-15])
