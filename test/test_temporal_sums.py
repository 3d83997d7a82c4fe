"""The idle windows' kept sums (inverse/temporal.py, _temporal_kernels.held_step_sums): the
idle scan reads the sums of each idle window's newest frames, kept as frames join the window
instead of added up from the ring every frame (issue 25). They must stay the ring's sums
(made independently by numpy here) through every way the window changes — frames joining,
the ring wrapping, a change starting a new window, a light press found in the window and the
frames before it dropped, a reset — and the scan's answer must be the one it gives on the
ring itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse import _temporal_kernels as kern
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.indenters import HertzSphere

NOISE = 0.5  # converter noise [counts RMS] (test/conftest.py's fusion_setup reads it)


def ring_sums(buf: np.ndarray, n: int, head: int, windows: np.ndarray) -> np.ndarray:
    """numpy: each window's sum of the newest min(w, n) frames of the ring."""
    h = buf.shape[0]
    return np.array([buf[(head - 1 - np.arange(min(int(w), n))) % h].sum(axis=0) for w in windows])


@pytest.mark.parametrize("window, windows", [(8, (4, 8)), (50, (4, 8, 16, 32)), (5, (2, 3, 5))])
def test_kept_sums_follow_the_ring_as_it_fills_and_wraps(window: int, windows: tuple) -> None:
    rng = np.random.default_rng(window)
    k = 9
    buf, total, state = np.zeros((window, k)), np.zeros(k), np.zeros(kern.STATE_SIZE)
    state[kern.SCALE2], state[kern.SCALE_MEMORY] = 1.0, 50.0
    ok, sigma = np.ones(k, dtype=bool), np.ones(k)
    nbr = np.arange(k)[:, None]
    inf = np.full(k, np.inf)
    w = np.array(windows)
    wsum, spare = np.zeros((len(w), k)), np.zeros(k)
    x = rng.normal(0.0, 1.0, k)
    buf[0], total[:] = x, x
    state[kern.N], state[kern.HEAD] = 1.0, 1.0 % window
    kern.window_sums(buf, state, w, wsum)
    for _ in range(4 * window + 3):
        d = rng.normal(0.0, 1.0, k)
        code = kern.held_step_sums(
            d, ok, ok, sigma, buf, total, state, nbr, inf, np.zeros((k, 0)), np.full(2, np.inf),
            wsum, w, spare,
        )  # fmt: skip
        assert code == 0
        want = ring_sums(buf, int(state[kern.N]), int(state[kern.HEAD]), w)
        np.testing.assert_allclose(wsum, want, rtol=1e-12, atol=1e-12)
        # the scan on the kept sums answers what it answers on the ring
        limit = np.full(k, 0.5)
        assert kern.idle_scan_sums(wsum, state, ok, sigma, nbr, limit, w, True) == (
            kern.idle_scan(buf, state, ok, sigma, nbr, limit, w, True)
        )


def test_kept_sums_through_presses_changes_and_a_reset(fusion_setup) -> None:
    """A real bundle's fusion (the hexagon): idle, a press too light for one frame held (the
    scan finds it, the frames before it are dropped), a firm press (a change: a new window),
    its release, idle again, a reset; after every frame the kept sums are the ring's."""
    bundle, alone, truth, sigma = fusion_setup
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    f = r.fusion
    rng = np.random.default_rng(5)
    where = (alone.taxel_xy[31] + alone.taxel_xy[35]) / 2
    light = truth.compression(HertzSphere(3e-3), 0.4, where)
    firm = truth.compression(HertzSphere(6e-3), 1.5, alone.taxel_xy[0])
    scene = [0 * light] * 40 + [light] * 30 + [firm] * 20 + [0 * light] * 80
    seen = {"held": 0, "solved": 0, "fused": 0}
    found_light = False
    for j, clean in enumerate(scene):
        c = alone.readings.counts(clean)
        dc = np.rint(c + rng.normal(0.0, NOISE, len(c))) * alone.readings.lsb
        res = r.solve(dc, noise=sigma)
        found_light |= 40 <= j < 70 and res.in_contact
        seen[f.last] += 1
        n, head = int(f._state[kern.N]), int(f._state[kern.HEAD])
        np.testing.assert_allclose(
            f._wsum, ring_sums(f._buf, n, head, f._idle_windows), rtol=1e-9, atol=1e-18
        )
        if f.holding:
            args = (f._ok, np.ascontiguousarray(sigma, dtype=float), f._nbr, f._trigger_limit)
            assert kern.idle_scan_sums(f._wsum, f._state, *args, f._idle_windows, True) == (
                kern.idle_scan(f._buf, f._state, *args, f._idle_windows, True)
            )
        if j == len(scene) - 10:
            f.reset()
            assert not f._wsum.any()
    assert found_light and seen["held"] > 60 and seen["solved"] >= 2 and f.counts.screened > 0
