"""The node's noise tracker and the detector's filters for the noise it hands out (issue 25).

``ContactDetector.set_noise`` keeps its filters for a uniform multiple c of the noise they were
built for (each statistic times 1/c), each taxel within its ``tolerance`` of it, and rebuilds
them otherwise; ``NoiseTracker`` hands out the noise it learnt and, as that tolerance, how far
its own estimates wander. Checked on the default patch's real bundle (built by the session
fixture) and a real Reconstructor: the rescaled statistics against the matched filter computed
from its definition in float64; the same noise gives the same results bit for bit, whatever
noise came in between; on stationary 8-bit noise the detector given the tracker's levels and
tolerance builds its filters once, and its statistics stay within that tolerance of the exact
ones; a taxel whose noise doubles makes it rebuild; the tracker's mean of δ² against the
exponential mean written out.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse.detection import NoiseTracker
from tactile_contact.inverse.reconstruction import Reconstructor


@pytest.fixture(scope="module")
def recon_path(hexagon_bundle: tuple) -> object:
    return hexagon_bundle[0]


def _matched(responses: np.ndarray, sigma: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Every bank contact's z = Σ r δ/σ² / √(Σ r²/σ²), float64 (the definition)."""
    w = responses / sigma**2
    return (w @ delta) / np.sqrt((w * responses).sum(axis=1))


def _idle_counts(rng: np.random.Generator, frames: int, k: int, level: float) -> np.ndarray:
    """8-bit readings [counts] of an unloaded patch: rest offsets within ±½ count, Gaussian
    noise of ``level`` counts, rounded, less a baseline of the first 100 frames (the driver's)."""
    counts = np.rint(rng.uniform(-0.5, 0.5, k) + level * rng.standard_normal((frames, k)))
    return counts - counts[:100].mean(axis=0)


@pytest.mark.parametrize("factor", [0.5, 1.37, 3.0])
def test_a_uniform_multiple_rescales_the_statistic_as_a_rebuild_would(recon_path, factor):
    det = Reconstructor.from_bundle(recon_path).detector
    sigma = det.sigma.copy()
    det.set_noise(factor * sigma)
    assert det.rebuilds == 1, "a uniform multiple must not rebuild the filters"
    rng = np.random.default_rng(3)
    for _ in range(20):
        delta = rng.standard_normal(len(sigma)) * sigma * factor + 2e-6 * rng.random()
        z, share, i = det.statistic(delta)
        ref = _matched(det._responses, factor * sigma, delta)
        assert z == pytest.approx(ref.max(), rel=1e-5, abs=1e-5)
        assert ref[i] == pytest.approx(ref.max(), rel=1e-5, abs=1e-5)
        energy = float(np.sum((delta / (factor * sigma)) ** 2))
        assert share == pytest.approx(max(z, 0.0) ** 2 / energy if z > 0 else 0.0, rel=1e-9)


def test_a_non_uniform_noise_rebuilds_the_filters(recon_path):
    det = Reconstructor.from_bundle(recon_path).detector
    sigma = det.sigma.copy()
    sigma[3] *= 1.5
    det.set_noise(sigma)
    assert det.rebuilds == 2
    delta = np.random.default_rng(4).standard_normal(len(sigma)) * sigma
    assert det.statistic(delta)[0] == pytest.approx(
        _matched(det._responses, sigma, delta).max(), rel=1e-5, abs=1e-5
    )


def test_the_same_noise_gives_the_same_results_bit_for_bit(recon_path):
    """Two reconstructors on the same frames at the same noise; one of them sees other noise
    levels (uniform multiples and not) in between: at the same noise their results agree
    exactly."""
    plain = Reconstructor.from_bundle(recon_path)
    moved = Reconstructor.from_bundle(recon_path)
    sigma = plain.default_noise * 1.3
    rng = np.random.default_rng(5)
    counts = _idle_counts(rng, 200, plain.n_taxels, 0.6)
    # A press in some frames: 3 counts at a taxel and its ring reading less (a contact).
    counts[150:, 10] += 3.0
    readings = plain.readings
    for i, c in enumerate(counts):
        delta = readings.from_counts(c)
        if i % 7 == 3:
            moved.solve_deflection(delta, noise=sigma * 2.0)  # a uniform multiple
        if i % 11 == 5:
            moved.solve_deflection(delta, noise=sigma * rng.uniform(0.9, 1.1, len(sigma)))
        a = plain.solve_deflection(delta, noise=sigma)
        b = moved.solve_deflection(delta, noise=sigma)
        assert a.in_contact == b.in_contact
        assert a.total_force == b.total_force
        assert tuple(a.cop) == tuple(b.cop)
    assert moved.detector.rebuilds > 2


def test_stationary_noise_builds_the_filters_once(recon_path):
    recon = Reconstructor.from_bundle(recon_path)
    det, readings = recon.detector, recon.readings
    tracker = NoiseTracker(recon.default_noise / np.sqrt(2.0), start=recon.default_noise)
    rng = np.random.default_rng(6)
    counts = _idle_counts(rng, 20000, recon.n_taxels, 0.6)
    delta = readings.from_counts(counts)
    ok = np.ones(recon.n_taxels, dtype=bool)
    handed = tracker.sigma
    levels = 0
    for d in delta:
        tracker.update(d, ok, False)
        if tracker.sigma is not handed:
            handed = tracker.sigma
            levels += 1
            assert np.all(handed >= tracker.floor)
            det.tolerance = tracker.tolerance
            det.set_noise(handed)
            if levels % 40 == 0:  # the statistic against the exact one, within the tolerance
                z = det.statistic(d)[0]
                ref = _matched(det._responses, handed, d).max()
                assert abs(z - ref) <= np.max(tracker.tolerance) * abs(ref) + 1e-4
    assert levels >= 20000 // 50 - 5  # (a frame with a reading beyond 6 σ is not learnt)
    assert det.rebuilds == 1
    # It learnt the noise: the level settled above the sensor model's (0.6 count against
    # ≈ 0.41), and each taxel's own.
    assert np.median(tracker.sigma / recon.default_noise) > 1.2
    assert np.std(tracker.sigma / np.median(tracker.sigma)) > 0.01


def test_a_taxel_whose_noise_doubles_rebuilds_the_filters(recon_path):
    recon = Reconstructor.from_bundle(recon_path)
    det = recon.detector
    tracker = NoiseTracker(recon.default_noise / np.sqrt(2.0), start=recon.default_noise)
    rng = np.random.default_rng(7)
    counts = _idle_counts(rng, 6000, recon.n_taxels, 0.6)
    counts[3000:, 9] = np.rint(1.2 * rng.standard_normal(3000))
    delta = recon.readings.from_counts(counts)
    ok = np.ones(recon.n_taxels, dtype=bool)

    def run(frames: np.ndarray) -> None:
        for d in frames:
            handed = tracker.sigma
            tracker.update(d, ok, False)
            if tracker.sigma is not handed:
                det.tolerance = tracker.tolerance
                det.set_noise(tracker.sigma)

    run(delta[:3000])
    before = det.rebuilds
    run(delta[3000:])
    assert det.rebuilds > before
    # The filters in use are for noise within the tolerance of the learnt (taxel 9's too).
    built = det._built / det._z_scale
    assert np.all(np.abs(built / tracker.sigma - 1.0) <= tracker.tolerance + 1e-12)
    assert tracker.sigma[9] / np.median(tracker.sigma) > 1.5


def test_the_tracker_is_the_exponential_mean_written_out():
    rng = np.random.default_rng(8)
    k, alpha = 30, 1.0 / 500
    floor = np.full(k, 1e-7)
    tracker = NoiseTracker(floor, start=2e-6)
    var = np.full(k, 4e-12)
    for i in range(400):
        d = rng.standard_normal(k) * 2.5e-6
        valid = np.ones(k, dtype=bool)
        if i % 5 == 0:
            valid[i % k] = False
        if i % 97 == 0:
            d[1] = 1e-3  # a spike: the frame is skipped
        used = tracker.sigma  # (the level its spike test reads this frame)
        tracker.update(d, valid, False)
        if not np.any(np.abs(d[valid]) > 6.0 * used[valid]):
            var[valid] += alpha * (d[valid] ** 2 - var[valid])
    np.testing.assert_allclose(tracker._var, var, rtol=1e-12)
    tracker.update(np.full(k, 1e-3), np.ones(k, dtype=bool), True)  # in contact: nothing
    np.testing.assert_allclose(tracker._var, var, rtol=1e-12)
