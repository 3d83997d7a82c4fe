"""Noise it did not expect (issue 26): a frame's own noise level, estimated when the caller
passes none, and the thresholds that hold the false-contact rate at it.

Unit checks on a hand-made square patch (a bank of Gaussian bumps; no bundle): the estimate
(:meth:`ContactDetector.frame_noise`, ``residual_noise``) is unbiased on white noise of a known
level within its χ² spread, and a contact does not inflate it; Student's t thresholds have the
normal thresholds' tail probability and reduce to them as the degrees of freedom grow; on white
noise three times the assumed level the estimated detection fires at no more than its stated
rate (the assumed level's fires on almost every frame). The skin's hull (``skin_hull``,
``on_skin``) against a hand-made square.

End to end, through ``Reconstructor.solve`` with no ``noise=`` on the default patch: 8-bit
whole counts of the ideal capacitor with Gaussian noise of 1 count before rounding (the
sensor model assumes ≈ 0.4 count), truth from the independent fine forward model
(:class:`tactile_contact.model.forward.ForwardModel`, 0.25 mm cells, Love kernel) read by 3 mm
electrodes (the bundle models 2 mm): idle frames read no contact; presses of 2–3 N clearly above
the noise (their ideal matched filter ≥ 10 σ) are seen, and every press seen is reported within
2× of its force.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm
from scipy.stats import t as student_t

from tactile_contact.inverse.contacts import SKIN_MARGIN, on_skin, skin_hull
from tactile_contact.inverse.detection import (
    ASSUMED,
    FAR_TAXELS,
    ContactDetector,
    FrameNoise,
)

#: The hand-made patch: 9 × 9 taxels at 5 mm, assumed noise 1 µm on each.
PITCH = 5.0e-3
SIGMA = 1.0e-6
FRAMES = 400
#: End to end: a press whose ideal matched filter reads this many σ of the true noise must be
#: seen (the t test of an estimated level asks ≈ 10 at the stated rate: those
#: nearer it may be missed).
CLEAR = 10.0


def _patch() -> tuple[np.ndarray, ContactDetector]:
    ax = np.arange(9) * PITCH
    xy = np.stack(np.meshgrid(ax, ax, indexing="ij"), axis=-1).reshape(-1, 2)
    lattice = np.arange(-1, 17) * PITCH / 2
    centres = np.stack(np.meshgrid(lattice, lattice, indexing="ij"), axis=-1).reshape(-1, 2)
    rows, where = [], []
    for width in (2.0e-3, 4.0e-3):
        dist2 = ((centres[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1)
        bump = np.exp(-dist2 / (2 * width**2)) * 1e-5  # [m per N]
        rows.append(np.where(bump > 1e-12, bump, 0.0))
        where.append(centres)
    return xy, ContactDetector(np.concatenate(rows), np.concatenate(where), SIGMA)


XY, DET = _patch()
ALL = np.ones(len(XY), dtype=bool)


def _estimates(level: float, rng: np.random.Generator, add: np.ndarray | None = None):
    """(scale², dof) of frame_noise over FRAMES frames of white noise at ``level`` × the
    assumed noise (plus ``add`` [m], a contact)."""
    out = []
    for _ in range(FRAMES):
        delta = rng.normal(size=len(XY)) * SIGMA * level
        if add is not None:
            delta = delta + add
        k = DET.detect_estimated(delta, False, ALL)[1]
        n = DET.frame_noise(delta, k, ALL)
        out.append((n.scale**2, n.dof))
    return np.array(out)


@settings(max_examples=8)
@given(level=st.floats(1.5, 4.0), seed=st.integers(0, 2**32 - 1))
def test_frame_noise_is_unbiased_on_white_noise_within_its_chi2_spread(level, seed):
    est = _estimates(level, np.random.default_rng(seed))
    assert np.all(est[:, 1] >= FAR_TAXELS)
    ratio = est[:, 0] / level**2  # χ²_dof / dof on white noise
    dof = float(np.mean(est[:, 1]))
    spread = math.sqrt(2.0 / dof)  # the χ² spread of one frame's estimate
    # The mean over FRAMES frames: within 4 standard errors of 1 (an unbiased estimate).
    assert abs(float(np.mean(ratio)) - 1.0) <= 4.0 * spread / math.sqrt(FRAMES)
    # One frame's scatter is the χ² spread of its degrees of freedom (not much wider).
    assert 0.7 * spread <= float(np.std(ratio)) <= 1.4 * spread


def test_a_contact_does_not_inflate_the_frame_noise():
    rng = np.random.default_rng(5)
    contact = DET._responses[int(np.argmin(np.hypot(*(DET.centres - 0.02).T)))] * 5.0  # 5 N
    est = _estimates(2.0, rng, contact)
    ratio = est[:, 0] / 4.0
    spread = math.sqrt(2.0 / float(np.mean(est[:, 1])))
    slack = 4.0 * spread / math.sqrt(FRAMES)
    # The contact, not the noise, picks the best filter here, so the correction for that
    # choice (far_bias, measured on white noise) leaves the estimate high by at most its
    # factor: a conservative error (a higher bar), never a lower one.
    assert 1.0 - slack <= float(np.mean(ratio)) <= 1.0 / DET.far_bias() + slack
    # The energy the best filter leaves over all taxels would read this contact as noise
    # (a bump between the bank's two widths): the far taxels do not.
    delta = contact + rng.normal(size=len(XY)) * SIGMA * 2.0
    z = DET.statistic(delta)[0]
    leftover = (float(np.sum((delta / SIGMA) ** 2)) - z * z) / (len(XY) - 1)
    assert leftover > 1.25 * 4.0


def test_residual_noise_of_the_true_contact_is_the_noise():
    rng = np.random.default_rng(6)
    contact = DET._responses[100] * 3.0
    ratios = []
    for _ in range(FRAMES):
        delta = contact + rng.normal(size=len(XY)) * SIGMA * 2.5
        n = DET.residual_noise(delta, contact, ALL)
        assert n.dof >= FAR_TAXELS
        ratios.append(n.scale**2 / 2.5**2 * DET.far_bias())  # without the selection factor
    spread = math.sqrt(2.0 / FAR_TAXELS)
    assert abs(float(np.mean(ratios)) - 1.0) <= 4.0 * spread / math.sqrt(FRAMES)


def test_noise_at_or_below_the_assumed_level_keeps_the_normal_thresholds():
    rng = np.random.default_rng(7)
    for level in (0.3, 0.5):
        for _ in range(50):
            delta = rng.normal(size=len(XY)) * SIGMA * level
            noise = DET.detect_estimated(delta, False, ALL)[2]
            assert noise == ASSUMED
    assert DET.thresholds(ASSUMED) == (DET.threshold, DET.refined_threshold)


@pytest.mark.parametrize("level", [1.0, 1.15, 1.3])
def test_estimated_detection_holds_its_rate_just_above_the_assumed_noise(level):
    # Where the estimate may fall below the assumed level by chance (a gate on the estimate
    # alone then took the normal thresholds: 1.5 false contacts per hour at 0.5 count).
    det = ContactDetector(DET._responses, DET.centres, SIGMA, per_hour=7200.0, frame_rate=50.0)
    rng = np.random.default_rng(9)
    n = 3000
    fired = sum(
        det.detect_estimated(rng.normal(size=len(XY)) * SIGMA * level, False, ALL)[0]
        for _ in range(n)
    )
    assert fired <= 0.02 * n + 4.0 * math.sqrt(0.02 * n)


@given(dof=st.integers(2, 10_000))
def test_t_thresholds_have_the_normal_thresholds_tail(dof):
    bank, refined = DET.thresholds(FrameNoise(2.0, dof))
    assert bank >= DET.threshold and refined >= DET.refined_threshold
    for t_thr, z_thr in ((bank, DET.threshold), (refined, DET.refined_threshold)):
        assert student_t.sf(t_thr, dof) == pytest.approx(norm.sf(z_thr), rel=1e-6)


@given(a=st.integers(2, 5000), b=st.integers(2, 5000))
def test_t_thresholds_fall_towards_the_normal_ones_as_dof_grows(a, b):
    lo, hi = sorted((a, b))
    assert DET.thresholds(FrameNoise(1.5, hi))[0] <= DET.thresholds(FrameNoise(1.5, lo))[0]


def test_t_thresholds_reduce_to_the_normal_ones():
    bank, refined = DET.thresholds(FrameNoise(1.5, 10**7))
    assert bank == pytest.approx(DET.threshold, rel=1e-4)
    assert refined == pytest.approx(DET.refined_threshold, rel=1e-4)
    small = DET.thresholds(FrameNoise(1.5, 20))[0]
    assert small > 1.3 * DET.threshold  # few degrees of freedom: a much higher bar


def test_estimated_detection_holds_its_rate_on_noise_three_times_the_assumed():
    # A detector stated at 2 % false frames for its bank test (so that a few thousand frames
    # measure it): per_hour / 2 / (3600 · frame_rate) = 0.02.
    det = ContactDetector(DET._responses, DET.centres, SIGMA, per_hour=7200.0, frame_rate=50.0)
    rng = np.random.default_rng(8)
    n, estimated, assumed = 3000, 0, 0
    for _ in range(n):
        delta = rng.normal(size=len(XY)) * SIGMA * 3.0
        estimated += det.detect_estimated(delta, False, ALL)[0]
        assumed += det.detect(delta, False)[0]
    # Bonferroni over the bank: at most the stated 2 % (binomial upper bound, 4σ).
    assert estimated <= 0.02 * n + 4.0 * math.sqrt(0.02 * n)
    assert assumed > 0.9 * n  # the assumed level reads noise as contact


def test_skin_hull_of_a_square():
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [5, 5], [3, 7]], dtype=float) * 1e-3
    hull = skin_hull(sq)
    assert hull is not None and len(hull) == 4
    m = SKIN_MARGIN
    assert on_skin(hull, (5e-3, 5e-3))
    assert on_skin(hull, (10e-3 + 0.99 * m, 5e-3))
    assert not on_skin(hull, (10e-3 + 1.01 * m, 5e-3))
    assert not on_skin(hull, (5e-3, -1.01 * m))
    assert on_skin(hull, (-0.99 * m, -0.99 * m))  # the corner grows mitred (each edge by m)
    assert not on_skin(hull, (5e-3, 5e-3), margin=-6e-3)  # 5 mm inside: not 6


@given(x=st.floats(-8e-3, 18e-3), y=st.floats(-8e-3, 18e-3), m=st.floats(0.0, 4e-3))
def test_on_skin_is_the_square_grown_by_the_margin(x, y, m):
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float) * 1e-3
    inside = -m <= x <= 10e-3 + m and -m <= y <= 10e-3 + m
    edge = min(abs(x + m), abs(x - 10e-3 - m), abs(y + m), abs(y - 10e-3 - m))
    if edge > 1e-12:  # not on the boundary itself (rounding)
        assert on_skin(skin_hull(sq), (x, y), margin=m) == inside


def test_no_hull_without_area():
    assert skin_hull(np.array([[0.0, 0.0], [1e-3, 0.0]])) is None
    assert skin_hull(np.array([[0.0, 0.0], [1e-3, 1e-3], [2e-3, 2e-3]])) is None
    assert on_skin(None, (1.0, 1.0))


# --- end to end -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def skin(hexagon_bundle):
    """(reconstructor, patch, truth, 1 count of ΔC [F]) of the default patch."""
    from tactile_contact.inverse.reconstruction import Reconstructor
    from tactile_contact.model.forward import ForwardModel
    from tactile_contact.model.sensor import value_count_farad

    folder, patch = hexagon_bundle
    recon = Reconstructor.from_bundle(folder)
    p = recon.params
    truth = ForwardModel(
        recon.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, taxel_radius=3e-3
    )
    lsb = float(value_count_farad(patch.sensor.farad_per_count, patch.sensor.shift))
    return recon, patch, truth, lsb


def _counts(patch, d: np.ndarray, lsb: float, rng: np.random.Generator | None) -> np.ndarray:
    """ΔC [F]: whole counts of the ideal capacitor of compressions d [m], 1 count of Gaussian
    noise before rounding (``rng`` None: the ideal capacitor's ΔC, neither)."""
    from tactile_contact.model.sensor import compression_to_delta_c

    e, s = patch.elastomer, patch.sensor
    dc = compression_to_delta_c(d, e.thickness, s.epsilon_r, s.area)
    if rng is None:
        return dc
    return np.rint(dc / lsb + rng.normal(0.0, 1.0, np.shape(d))) * lsb


@pytest.mark.slow
def test_idle_frames_of_one_count_noise_read_no_contact(skin):
    recon, patch, _, lsb = skin
    rng = np.random.default_rng(11)
    zero = np.zeros(recon.n_taxels)
    false = sum(recon.solve(_counts(patch, zero, lsb, rng)).in_contact for _ in range(300))
    # Before the estimate, the assumed ≈ 0.4 count read 1 count of noise as contact in most
    # frames; stated: 0.1 per hour (bench/bench_false_alarm.py counts 6·10⁵ frames).
    assert false == 0


@pytest.mark.slow
def test_presses_in_one_count_noise_within_twice_their_force(skin):
    from tactile_contact.model.indenters import FlatPunch, HertzSphere

    recon, patch, truth, lsb = skin
    xy = recon.taxel_xy
    # Module 4's taxels 3, 7, 11: over a taxel, between two, between three.
    t3, t7, t11 = xy[12 * 4 + 3], xy[12 * 4 + 7], xy[12 * 4 + 11]
    places = (t3, (t7 + t11) / 2, (t3 + t7 + t11) / 3)
    rng = np.random.default_rng(12)
    ratios, clear = {}, {}
    for ind in (HertzSphere(6e-3), HertzSphere(3e-3), FlatPunch(6e-3), FlatPunch(1.5e-3)):
        for force in (2.0, 3.0):
            for k, c in enumerate(places):
                d = truth.compression(ind, force, c)
                res = recon.solve(_counts(patch, d, lsb, rng))
                key = (repr(ind), force, k)
                ratios[key] = res.total_force / force if res.in_contact else 0.0
                # The ideal matched filter's statistic in the true noise (1 count and the
                # rounding): a press clearly above it must be seen.
                clear[key] = (
                    np.linalg.norm(_counts(patch, d, lsb, None) / lsb) / math.hypot(1.0, 12**-0.5)
                    >= CLEAR
                )
    seen = {k: v for k, v in ratios.items() if v > 0}
    assert all(ratios[k] > 0 for k in ratios if clear[k]), ratios
    assert sum(clear.values()) >= 12, clear  # the 12 mm cylinder: ≈ 4 counts a taxel
    r = np.array(list(seen.values()))
    assert np.all(r <= 2.0), seen  # issue 26: no press reported above 2× its force
    assert np.all(r >= 1.0 / 3.0), seen
    assert float(np.median(np.abs(r - 1.0))) <= 0.25, seen
