"""FrameFusion(defer=True): the re-solves no change asks for wait for catch_up (issue 25's tail).

The node publishes every patch's frame first and runs the fusion's scheduled re-solves after
(tactile_contact.ros.contact_batches.CATCH_UP_BUDGET_S). What must hold: a deferred fusion
caught up after every frame goes through the same states as one that re-solves inside the
frame — the same results, one frame later, the same counts of solves — and a change is still
solved in its own frame. Presses from the independent fine forward model, read as 8-bit counts
with converter noise (as test_temporal.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.temporal import DEFER_FROM
from tactile_contact.model.indenters import HertzSphere

NOISE = 0.5  # converter noise [counts RMS]


@pytest.fixture(scope="module")
def setup(fusion_setup):
    """The hexagon, its fine-model truth and one frame's noise (test/conftest.py)."""
    return fusion_setup


def _frames(r, truth, rng) -> list[np.ndarray]:
    """ΔC [F] of a scene: 20 idle frames, a 1.5 N press held 60 frames, a 0.4 N press
    between two taxels held 30 (too light for one frame), released for 10."""
    xy = r.taxel_xy
    scenes = [
        (np.zeros(r.n_taxels), 20),
        (truth.compression(HertzSphere(6e-3), 1.5, xy[30]), 60),
        (np.zeros(r.n_taxels), 10),
        (truth.compression(HertzSphere(3e-3), 0.4, (xy[31] + xy[35]) / 2), 30),
        (np.zeros(r.n_taxels), 10),
    ]
    out = []
    for d, n in scenes:
        c = r.readings.counts(d)
        out += list(np.rint(c + rng.normal(0.0, NOISE, (n, len(c)))) * r.readings.lsb)
    return out


def _same(a, b) -> bool:
    if a.in_contact != b.in_contact:
        return False
    if not a.in_contact:
        return True
    return a.total_force == b.total_force and a.cop == b.cop and a.frames == b.frames


def test_a_deferred_fusion_caught_up_is_the_inline_one_a_frame_later(setup):
    bundle, _, truth, sigma = setup
    frames = _frames(Reconstructor.from_bundle(bundle), truth, np.random.default_rng(4))
    inline = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    late = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    late.fusion.defer = True
    deferred = 0
    previous = None
    for dc in frames:
        a = inline.solve(dc, noise=sigma)
        b = late.solve(dc, noise=sigma)
        if inline.fusion.last == "fused" and late.fusion.last == "held":
            # deferred: this frame republishes the last result; the re-solve waits (a window
            # short enough is re-solved in its frame)
            assert late.fusion.pending and b is previous
            assert late.fusion.frames >= DEFER_FROM or not previous.in_contact
        else:
            assert late.fusion.last == inline.fusion.last
            assert _same(a, b)
        deferred += late.fusion.catch_up()
        assert not late.fusion.pending and _same(inline.fusion.result, late.fusion.result)
        previous = late.fusion.result
    ci, cl = inline.fusion.counts, late.fusion.counts
    assert ci.fused > 5 and cl.fused == ci.fused and cl.solved == ci.solved
    assert 5 < cl.deferred == deferred and cl.screened == ci.screened
    assert cl.changes == ci.changes


def test_a_change_drops_the_deferred_resolve_and_is_solved_at_once(setup):
    bundle, r0, truth, sigma = setup
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    r.fusion.defer = True
    rng = np.random.default_rng(9)
    ind, where = HertzSphere(6e-3), r0.taxel_xy[30]
    for force in (1.5, 3.0):
        c = r.readings.counts(truth.compression(ind, force, where))
        frames = np.rint(c + rng.normal(0.0, NOISE, (DEFER_FROM, len(c)))) * r.readings.lsb
        res = r.solve(frames[0], noise=sigma)
        assert r.fusion.last == "solved" and res.frames == 1
        for dc in frames[1:-1]:  # the short windows: re-solved in their frames
            r.solve(dc, noise=sigma)
            assert not r.fusion.pending
        r.solve(frames[-1], noise=sigma)  # the window of DEFER_FROM is due: deferred
        assert r.fusion.pending and r.fusion.last == "held"
    # (the 3 N frame changed the scene: solved in its frame, the old window's re-solve gone)
    assert r.fusion.counts.solved == 2 and r.fusion.counts.deferred == 0
    assert r.fusion.catch_up() and r.fusion.result.frames == DEFER_FROM
    assert abs(r.fusion.result.total_force / 3.0 - 1) < 0.3
    assert not r.fusion.catch_up()


def test_the_fusion_keeps_the_frame_the_solve_converted(setup):
    """The node's noise tracker learns from the δ the solve converted (FrameFusion.context)
    instead of converting the readings again: the same arrays, bit for bit, excluded taxels
    too."""
    bundle, r0, truth, sigma = setup
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    rng = np.random.default_rng(2)
    valid = np.ones(r.n_taxels, bool)
    valid[[3, 40]] = False
    for dc in _frames(r0, truth, rng)[:30]:
        r.solve(dc, valid, noise=sigma)
        d, ok = r.readings.from_delta_c(dc, valid)
        seen = r.fusion.context
        assert np.array_equal(seen.delta, d) and np.array_equal(seen.ok, ok)
