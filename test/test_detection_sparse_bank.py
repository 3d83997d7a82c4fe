"""The detector's sparse bank (tactile_contact.inverse.detection): its statistics are the dense
matched-filter product's, on the banks of real patches (the default hexagon and the imported
iCub forearm V2), before and after the noise changes, and on random sparse banks.

The reference is the dense product written out here in float64: z = (r/σ²)/‖r/σ‖ · δ per
filter. The bank's weights are float32, so each statistic may differ from it by float32
rounding of its terms: at most 2⁻²³ Σ|w δ| (the tolerance used)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tactile_contact.inverse.detection import ContactDetector
from tactile_contact.inverse.filter_bank import patch_detector
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.round_contact import (
    DEFAULT_RADII,
    FAMILIES,
    TABLE_STEP,
    RoundTables,
    radial_responses,
)
from tactile_contact.model.layout import load_layout
from tactile_contact.offline.build import grids_for

ROOT = Path(__file__).resolve().parents[1]
EPS32 = 2.0**-23


def dense_filters(responses: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(M, K) float64 matched filters of ``responses`` for noise ``sigma`` (the reference)."""
    w = responses / sigma**2
    return w / np.sqrt(np.sum(w * responses, axis=1))[:, None]


def mismatch(det: ContactDetector, sigma: np.ndarray, delta: np.ndarray) -> float:
    """Largest |sparse − dense| over the bank's statistics on ``delta``, in units of the
    float32 rounding bound of each (≤ 1: equal to float32 rounding)."""
    f = dense_filters(det._responses, sigma)
    ref = f @ delta
    bound = EPS32 * (np.abs(f) @ np.abs(delta)) + 1e-300
    return float(np.max(np.abs(det.statistics(delta) - ref) / bound))


def best_tolerance(f: np.ndarray, delta: np.ndarray) -> float:
    """How far the bank's largest statistic may be from the float64 reference's: float32
    rounding of K + 1 terms (a small bank's dense product reads δ in float32 and sums in
    float32, as before the sparse bank)."""
    return (f.shape[1] + 2) * EPS32 * float((np.abs(f) @ np.abs(delta)).max()) + 1e-12


def forearm_detector() -> tuple[ContactDetector, np.ndarray]:
    """The imported iCub forearm V2's detector (its round tables computed as the bundle build
    does, its taxels and traction cell from config/icub/left_forearm_V2.yaml), with a
    non-uniform noise [m]."""
    patch = load_layout(ROOT / "config" / "icub" / "left_forearm_V2.yaml").patches[0]
    e, radii = patch.elastomer, np.asarray(DEFAULT_RADII)
    resp = radial_responses(
        patch.layer_thickness,
        e.young,
        e.poisson,
        [patch.footprint],
        [(f, float(a)) for f in range(len(FAMILIES)) for a in radii],
        model=patch.model.kind,
        psi=patch.model.psi,
    )
    table = patch.model.gain * resp[:, 0].reshape((len(FAMILIES), len(radii), -1))
    tables = RoundTables(radii, TABLE_STEP, table)
    xy = patch.taxel_xy()
    sigma = np.random.default_rng(3).uniform(0.5e-6, 2e-6, len(xy))
    return patch_detector(tables, xy, grids_for(patch)[0].cell_size, sigma), sigma


@pytest.fixture(scope="module", params=["hexagon", "forearm V2"])
def bank(request, hexagon_bundle) -> tuple[ContactDetector, np.ndarray]:
    if request.param == "hexagon":
        recon = Reconstructor.from_bundle(hexagon_bundle[0])
        return recon.detector, recon.default_noise.copy()
    return forearm_detector()


def frames(det: ContactDetector, sigma: np.ndarray) -> list[np.ndarray]:
    """White noise at every taxel; a press read on a count lattice (most taxels 0, a few
    negative on its bulge); a frame that reads nothing."""
    rng = np.random.default_rng(7)
    white = rng.standard_normal(len(sigma)) * sigma
    k = len(det.centres) // 2
    press = det._responses[k] * (12 * np.median(sigma) / np.abs(det._responses[k]).max())
    counts = np.rint(press / (2 * sigma)) * 2 * sigma
    assert 0 < np.count_nonzero(counts) < len(sigma) // 2
    return [white, counts, np.zeros(len(sigma))]


def test_the_bank_is_sparse_and_holds_every_non_zero_response(bank):
    det, _ = bank
    nonzero = det._responses != 0
    # The premise: each filter reads only the taxels within its kernel's reach.
    assert nonzero.sum(axis=1).max() <= 40 < det._responses.shape[1]
    held = np.zeros_like(nonzero)
    for m in range(len(det._responses)):
        a, b = det._row_ptr[m], det._row_ptr[m + 1]
        held[m, det._row_cols[a:b]] = True
    np.testing.assert_array_equal(held, nonzero)
    by_taxel = np.zeros_like(nonzero)
    for k in range(det._responses.shape[1]):
        a, b = det._col_ptr[k], det._col_ptr[k + 1]
        by_taxel[det._col_rows[a:b], k] = True
    np.testing.assert_array_equal(by_taxel, nonzero)


def test_each_taxel_alone_reads_its_column_of_the_dense_bank(bank):
    det, sigma = bank
    f = dense_filters(det._responses, sigma)
    for k in range(len(sigma)):
        e = np.zeros(len(sigma))
        e[k] = sigma[k]
        np.testing.assert_allclose(det.statistics(e), f[:, k] * sigma[k], rtol=EPS32, atol=0)


def test_statistics_equal_the_dense_product(bank):
    det, sigma = bank
    f = dense_filters(det._responses, sigma)
    for delta in frames(det, sigma):
        assert mismatch(det, sigma, delta) <= 1.0
        ref, tol = f @ delta, best_tolerance(f, delta)
        best, _, i = det.statistic(delta)
        assert abs(best - ref.max()) <= tol
        assert ref.max() - ref[i] <= 2 * tol  # the best (or one within rounding of it)
        # One filter alone (frame_noise, near_miss): the same sums, filter by filter.
        for m in (0, i, len(ref) // 3, len(ref) - 1):
            bound = EPS32 * float(np.abs(f[m]) @ np.abs(delta)) + 1e-12
            assert abs(det.filter_statistic(m, delta) - ref[m]) <= bound


def test_statistics_follow_set_noise(bank):
    det, sigma = bank
    try:
        # A uniform multiple keeps the filters (the statistics scaled) ...
        det.set_noise(1.7 * sigma)
        rebuilds = det.rebuilds
        for delta in frames(det, sigma):
            assert mismatch(det, 1.7 * sigma, delta) <= 1.0 + 1e-6
        # ... another noise rebuilds them.
        other = sigma * np.random.default_rng(11).uniform(0.5, 2.0, len(sigma))
        det.set_noise(other)
        assert det.rebuilds == rebuilds + 1
        for delta in frames(det, other):
            assert mismatch(det, other, delta) <= 1.0
            f = dense_filters(det._responses, other)
            assert abs(det.statistic(delta)[0] - (f @ delta).max()) <= best_tolerance(f, delta)
    finally:
        det.set_noise(sigma)


def test_a_dropped_entry_is_seen(bank):
    """The check above can fail: the bank with one taxel's weight in one filter missing (the
    largest of the column, as a wrong sparsity pattern would drop it) reads differently."""
    det, sigma = bank
    k = int(np.argmax(np.abs(det._responses).sum(axis=0)))
    a, b = det._col_ptr[k], det._col_ptr[k + 1]
    p = a + int(np.argmax(np.abs(det._col_vals[a:b])))
    e = np.zeros(len(sigma))
    e[k] = sigma[k]
    kept = det._col_vals[p]
    try:
        det._col_vals[p] = 0.0
        assert mismatch(det, sigma, e) > 1e3
    finally:
        det._col_vals[p] = kept
    assert mismatch(det, sigma, e) <= 1.0


@settings(max_examples=60, deadline=None)
@given(
    st.integers(2, 40),
    st.integers(2, 30),
    st.data(),
)
def test_random_sparse_banks_equal_the_dense_product(m, k, data):
    shape = (m, k)
    values = data.draw(arrays(np.float64, shape, elements=st.floats(0.01, 1.0)))
    mask = data.draw(arrays(np.bool_, shape))
    mask[np.arange(m), np.arange(m) % k] = True  # no filter without a taxel
    responses = np.where(mask, values, 0.0)
    sigma = data.draw(arrays(np.float64, k, elements=st.floats(0.5, 2.0)))
    delta = data.draw(arrays(np.float64, k, elements=st.floats(-3.0, 3.0)))
    delta[data.draw(arrays(np.bool_, k))] = 0.0
    det = ContactDetector(responses, np.zeros((m, 2)), sigma)
    assert mismatch(det, sigma, delta) <= 1.0
    f = dense_filters(responses, sigma)
    ref, tol = f @ delta, best_tolerance(f, delta)
    best, _, i = det.statistic(delta)
    assert abs(best - ref.max()) <= tol
    assert ref.max() - ref[i] <= 2 * tol


# The coarse copy's bound (ContactDetector.surely_quiet): above every statistic, always; close
# to the largest on noise; and its "quiet" only where detect finds nothing.


def coarse_bound(det: ContactDetector, delta: np.ndarray) -> float:
    from tactile_contact.inverse.detection import _coarse_bound

    return _coarse_bound(*det._coarse, np.asarray(delta, np.float64)) * det._z_scale


def window_means(det: ContactDetector, sigma: np.ndarray, n: int = 40) -> list[np.ndarray]:
    """White noise at the filters' level (a mean of frames scaled by √n, as the fusion hands
    it), some with a press added at a bank place, at a quarter to twice the threshold."""
    rng = np.random.default_rng(5)
    out = []
    for j in range(n):
        d = rng.standard_normal(len(sigma)) * sigma
        if j % 2:
            m = int(rng.integers(len(det.centres)))
            r = det._responses[m]
            z1 = float(dense_filters(det._responses[m : m + 1], sigma)[0] @ r)
            d = d + r * (det.threshold * (0.25 + 1.75 * j / n) / z1)
        out.append(d)
    return out


def test_the_coarse_bound_is_above_every_statistic_and_close(bank):
    det, sigma = bank
    other = sigma * np.random.default_rng(11).uniform(0.5, 2.0, len(sigma))
    # (1.7 σ: a uniform multiple, the filters kept; ``other``: the filters rebuilt)
    for sig in (sigma, 1.7 * sigma, other):
        det.set_noise(sig)
        try:
            f = dense_filters(det._responses, sig)
            for delta in window_means(det, sig) + frames(det, sig):
                ref = f @ delta
                bound = coarse_bound(det, delta)
                assert bound >= ref.max()  # (the margin covers float32 rounding too)
                if np.any(delta):
                    # half a 127th of the largest weight times Σ|δ| over its group (0.4 σ at
                    # most on the forearm whose σ spans 4×; 0.17 on the robot's banks)
                    assert bound - ref.max() <= 0.1 * det.threshold
        finally:
            det.set_noise(sigma)


def test_surely_quiet_only_where_detect_finds_nothing(bank):
    det, sigma = bank
    quiet = 0
    for delta in window_means(det, sigma):
        for scale_free in (False, True):
            if det.surely_quiet(delta, scale_free):
                quiet += 1
                assert not det.detect(delta, scale_free)[0]
            elif not scale_free:
                assert coarse_bound(det, delta) >= det.threshold
    assert quiet >= 10  # (noise alone and the light presses: the bound answers for them)
    strong = window_means(det, sigma)[-1]
    assert det.detect(strong, False)[0] and not det.surely_quiet(strong, False)


def test_a_dropped_coarse_taxel_is_seen(bank):
    """The checks above can fail: the coarse copy with one taxel's bytes set to 0 (as a wrong
    layout would drop them) reads below the bank's largest statistic on a frame at that
    taxel alone."""
    det, sigma = bank
    f = dense_filters(det._responses, sigma)
    k = int(np.argmax(np.abs(det._responses).sum(axis=0)))
    e = np.zeros(len(sigma))
    e[k] = sigma[k]
    coarse = det._coarse[4]
    slots = det._blk_at[det._row_cols == k]
    kept = coarse[slots].copy()
    try:
        coarse[slots] = 0
        assert coarse_bound(det, e) < (f @ e).max()
    finally:
        coarse[slots] = kept
    assert coarse_bound(det, e) >= (f @ e).max()


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 40), st.integers(2, 30), st.data())
def test_random_sparse_banks_coarse_bound(m, k, data):
    shape = (m, k)
    values = data.draw(arrays(np.float64, shape, elements=st.floats(-1.0, 1.0)))
    mask = data.draw(arrays(np.bool_, shape))
    mask[np.arange(m), np.arange(m) % k] = True
    values[np.arange(m), np.arange(m) % k] = 0.5
    responses = np.where(mask, values, 0.0)
    sigma = data.draw(arrays(np.float64, k, elements=st.floats(0.5, 2.0)))
    delta = data.draw(arrays(np.float64, k, elements=st.floats(-3.0, 3.0)))
    det = ContactDetector(responses, np.zeros((len(responses), 2)), sigma)
    f = dense_filters(det._responses, sigma)
    assert coarse_bound(det, delta) >= (f @ delta).max()


def test_the_best_of_a_mean_is_the_sparse_sums_best_bit_for_bit(bank):
    """A frame that reads something at most taxels: the filters the coarse bounds leave (those
    whose upper bound reaches the largest lower bound) summed exactly give the sparse sums'
    largest statistic and its index, the same numbers."""
    from tactile_contact.inverse.detection import _bank_best, _coarse_sums, _pruned_best

    det, sigma = bank
    n_m = len(det._responses)
    for delta in window_means(det, sigma):
        want = _bank_best(*det._bank, delta, n_m)
        low = _coarse_sums(*det._coarse, delta, det._upper)
        kept = int(np.count_nonzero(det._upper >= low))
        assert 1 <= kept < n_m // 10  # (the pruning prunes)
        got = _pruned_best(
            det._upper, low, det._blk_order, det._row_ptr, det._row_cols, det._row_vals, delta
        )
        assert got == (want[0], want[1])
        if det._small is None:  # (the path _best takes for such a frame)
            assert det._best(delta) == (want[0] * det._z_scale, int(want[1]))
