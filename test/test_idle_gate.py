"""The driver's idle gate (canbus.idle_gate): an untouched patch's readings every ``every``
periods, a touched one's every period.

Alone: its rules on any sequence of readings (hypothesis) and on a simulated 8-bit skin (the
skin simulator's frames through the driver's own SkinStream: an idle patch at the
simulator's noise is held back, a press goes out every period). Then the real driver node on
a python-can virtual bus with ``idle_every: 5``: the untouched patch's readings reach the
batches one period in five, the pressed one's every period.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.canbus.baseline import STATUS_CONTACT, STATUS_STALE
from tactile_contact.canbus.idle_gate import RELEASE_READINGS, IdleGate
from tactile_contact.canbus.stream import PatchFrame

COUNT = 1e-14  # ΔC of one 8-bit count in these tests [F]


def _frame(patch: str, counts: list[float], status: list[int] | None = None) -> PatchFrame:
    n = len(counts)
    return PatchFrame(
        patch,
        patch,
        0.0,
        list(range(n)),
        (np.asarray(counts) * COUNT).astype(np.float32),
        bytes(n),
        bytes(status or [0] * n),
    )


def test_every_one_sends_every_reading() -> None:
    gate = IdleGate(1, 2.0, {"a": COUNT})
    assert all(gate.passes(_frame("a", [0.0, 0.0])) for _ in range(20))
    assert gate.passed == 20 and gate.held == 0


def test_an_untouched_patch_goes_out_every_nth_period_a_press_every_period() -> None:
    gate = IdleGate(5, 2.0, {"a": COUNT})
    quiet = [gate.passes(_frame("a", [0.5, -0.75 if k % 2 else 0.75])) for k in range(11)]
    assert quiet == [True, False, False, False, False] * 2 + [True]
    # a press: at once, every period, whatever came before
    assert all(gate.passes(_frame("a", [2.5, 0.0])) for _ in range(4))
    # its release goes out, so do the readings after it until the running mean has settled
    # (1.87 counts → 1.40 → 1.05 → 0.79, within half of idle_counts) and the first three
    # settled ones (RELEASE_READINGS: a release survives lost batches), then every fifth again
    after = [gate.passes(_frame("a", [0.0, 0.0])) for _ in range(15)]
    assert after == [True] * 5 + [False] * 4 + [True] + [False] * 4 + [True]


def test_a_light_press_goes_out_once_its_running_mean_shows_it() -> None:
    """Readings within idle_counts (3) on every taxel: noise of ±2 counts is held back, a
    steady 2 counts goes out from its 5th reading on (the mean past 1.5), 3 counts from its
    3rd; its release, once the mean has settled again, goes out too."""
    gate = IdleGate(50, 3.0, {"a": COUNT})
    assert gate.passes(_frame("a", [0.0, 0.0]))
    noise = [gate.passes(_frame("a", [2.0 if k % 2 else -2.0, 0.0])) for k in range(20)]
    assert not any(noise)
    two = [gate.passes(_frame("a", [0.0, 2.0])) for _ in range(8)]
    assert two == [False] * 4 + [True] * 4
    gate.forget()
    assert gate.passes(_frame("a", [0.0, 0.0]))
    three = [gate.passes(_frame("a", [3.0, 0.0])) for _ in range(4)]
    assert three == [False, False, True, True]
    after = [gate.passes(_frame("a", [0.0, 0.0])) for _ in range(8)]
    assert after[:2] == [True, True] and after[-1] is False and sum(after) <= 4


def test_contact_flags_status_changes_and_nan_always_go_out() -> None:
    gate = IdleGate(10, 2.0, {"a": COUNT, "b": COUNT})
    assert gate.passes(_frame("a", [0.0, 0.0]))
    assert not gate.passes(_frame("a", [0.0, 0.0]))
    assert gate.passes(_frame("a", [0.0, 0.0], [0, STATUS_CONTACT]))  # flagged in contact
    # the first three quiet after it (its release)
    assert all(gate.passes(_frame("a", [0.0, 0.0], [0, STATUS_STALE])) for _ in range(3))
    assert not gate.passes(_frame("a", [0.0, 0.0], [0, STATUS_STALE]))
    assert gate.passes(_frame("a", [0.0, 0.0]))  # its status changed back
    assert gate.passes(_frame("a", [0.0, float("nan")]))  # a NaN reading is never quiet
    assert gate.passes(_frame("b", [0.0, 0.0]))  # each patch on its own
    assert gate.passes(_frame("c", [0.0, 0.0])) and gate.passes(_frame("c", [0.0, 0.0]))
    gate.forget()  # (a tare) the next reading of each patch goes out
    assert gate.passes(_frame("b", [0.0, 0.0]))


def test_a_reading_made_before_a_tare_changes_nothing_when_it_comes_after() -> None:
    """Readings carry their stream's tare count: the first made after a tare goes out even
    when a reading made before it (a batch window, a receive thread) reached the gate
    first, and one made before that comes later goes out without resetting the patch."""
    gate = IdleGate(10, 3.0, {"a": COUNT})

    def tared(counts: list[float], tares: int) -> PatchFrame:
        return dataclasses.replace(_frame("a", counts), tares=tares)

    assert gate.passes(tared([1.4, 0.0], 0))
    assert not gate.passes(tared([1.4, 0.0], 0))
    assert gate.passes(tared([0.0, 0.0], 1))  # the tared state, at once
    assert not gate.passes(tared([0.0, 0.0], 1))
    assert gate.passes(tared([1.4, 0.0], 0))  # late, from before the tare: out, unused
    # the keep-alive: the tenth of the tared state's readings after its last sent
    assert not any(gate.passes(tared([0.0, 0.0], 1)) for _ in range(8))
    assert gate.passes(tared([0.0, 0.0], 1))


def test_skin_stream_readings_carry_its_tare_count() -> None:
    from tactile_contact.canbus.stream import SkinStream
    from tactile_contact.model.layout import load_layout
    from tactile_contact.sim.simulator import simulator_for_patch
    from test.test_driver_batches import ROOT

    patch = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0]
    stream = SkinStream([patch], period_s=0.02)
    sim = simulator_for_patch(patch, period_s=0.02, seed=3)
    tares = []
    for k in range(60):
        if k == 50:
            assert stream.tare()[0] == [patch.name]
        for m in sim.period(None, k * 0.02).messages:
            tares += [f.tares for f in stream.feed(m, k * 0.02)]
    assert len(tares) > 40 and tares[0] == 0 and tares[-1] == 1 and sorted(tares) == tares


def test_bad_settings_are_refused_with_their_name() -> None:
    with pytest.raises(ValueError, match="every"):
        IdleGate(0, 2.0, {})
    with pytest.raises(ValueError, match="idle_counts"):
        IdleGate(2, float("nan"), {})
    with pytest.raises(ValueError, match="patch a"):
        IdleGate(2, 2.0, {"a": 0.0})


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 8),
    st.lists(
        st.tuples(
            st.sampled_from("ab"),
            st.lists(st.floats(-4.0, 4.0), min_size=3, max_size=3),
            st.sampled_from([0, 0, 0, STATUS_CONTACT, STATUS_STALE]),
        ),
        max_size=80,
    ),
)
def test_rules_on_any_sequence(every: int, readings: list) -> None:
    """Whatever the readings: a touched one always goes out; so do the RELEASE_READINGS
    after a touched one, and the first after a status change; of untouched ones with the same
    status, at most every−1 in a row are held back; and passed + held counts every reading."""
    gate = IdleGate(every, 2.0, {"a": COUNT, "b": COUNT})
    last: dict[str, tuple[bool, bytes]] = {}
    since_touched = {"a": RELEASE_READINGS + 1, "b": RELEASE_READINGS + 1}
    held_run = {"a": 0, "b": 0}
    for patch, counts, flag in readings:
        f = _frame(patch, counts, [flag, 0, 0])
        touched = flag == STATUS_CONTACT or max(abs(c) for c in counts) > 2.0
        sent = gate.passes(f)
        before = last.get(patch)
        if touched or before is None or before[1] != f.status:
            assert sent
        if since_touched[patch] < RELEASE_READINGS:
            assert sent, "a release reading held back"
        since_touched[patch] = 0 if touched else since_touched[patch] + 1
        if sent:
            held_run[patch] = 0
            last[patch] = (touched, f.status)
        else:
            held_run[patch] += 1
            assert held_run[patch] <= every - 1
    assert gate.passed + gate.held == len(readings)


class _ReferenceGate:
    """The module docstring's rules written plainly, one taxel at a time in float32 (the
    reference the compiled gate is checked against)."""

    def __init__(self, every: int, counts: float) -> None:
        self.every, self.limit = every, np.float32(counts * COUNT)
        self.state: dict[str, dict] = {}

    def passes(self, f: PatchFrame) -> bool:
        s = self.state.get(f.patch)
        if s is None:
            s = self.state[f.patch] = {"mean": [np.float32(0)] * len(f.delta_c), "release": 1,
                                       "status": b"", "since": 0}  # fmt: skip
        gain, half = np.float32(0.25), self.limit * np.float32(0.5)
        s["mean"] = [
            m + gain * (np.float32(v) - m) for m, v in zip(s["mean"], f.delta_c, strict=True)
        ]
        settled = all(-half <= m <= half for m in s["mean"])
        if not all(np.isfinite(m) for m in s["mean"]):
            s["mean"] = [np.float32(0)] * len(f.delta_c)
        within = all(-self.limit <= v <= self.limit for v in f.delta_c)
        contact = any(b & STATUS_CONTACT for b in f.status)
        quiet = settled and within and not contact
        if (not s["release"] and s["since"] + 1 < self.every and quiet
                and f.status == s["status"]):  # fmt: skip
            s["since"] += 1
            return False
        s["release"] = max(s["release"] - 1, 0) if quiet else RELEASE_READINGS
        s["status"], s["since"] = f.status, 0
        return True


@settings(max_examples=300, deadline=None)
@given(
    st.integers(2, 6),
    st.lists(
        st.tuples(
            st.sampled_from("ab"),
            st.lists(
                st.one_of(
                    st.floats(-1.5, 1.5, width=32),
                    st.floats(-4.0, 4.0, width=32),
                    st.just(float("nan")),
                ),
                min_size=2,
                max_size=2,
            ),
            st.sampled_from([0, 0, 0, STATUS_CONTACT, STATUS_STALE]),
            st.integers(1, 12),  # held this many periods: the running mean settles on it
        ),
        max_size=20,
    ),
)
def test_the_compiled_gate_decides_as_the_rules_written_plainly(every: int, runs: list) -> None:
    gate, ref = IdleGate(every, 2.0, {"a": COUNT, "b": COUNT}), _ReferenceGate(every, 2.0)
    for patch, counts, flag, repeat in runs:
        f = _frame(patch, counts, [flag, 0])
        for _ in range(repeat):
            assert gate.passes(f) == ref.passes(f)


def test_on_a_simulated_skin_idle_patches_are_held_and_a_press_goes_out() -> None:
    """The skin simulator's 8-bit frames (0.5 count of noise: 2 CDC counts at shift 2) through
    the driver's SkinStream: after calibration an untouched hexagon's readings go out one in
    five; one pressed at 1 N goes out every period while pressed."""
    from tactile_contact.canbus.stream import SkinStream
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.layout import load_layout
    from tactile_contact.sim.simulator import Indentation, simulator_for_patch
    from test.test_driver_batches import ROOT

    patch = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0]
    count = patch.sensor.farad_per_count * 2.0**patch.sensor.shift
    gate = IdleGate(5, 3.0, {patch.name: count})
    stream = SkinStream([patch], period_s=0.02)
    sim = simulator_for_patch(patch, period_s=0.02, noise_cdc=2.0, seed=3)
    at = tuple(patch.taxel_xy()[0])
    press = Indentation.press(HertzSphere(0.006), 1.0, at, start_s=3.0, ramp_s=0.1, hold_s=2.0)
    sent: list[tuple[float, bool]] = []
    for k in range(250):
        t = k * 0.02
        for m in sim.period(press, t).messages:
            for frame in stream.feed(m, t):
                sent.append((t, gate.passes(frame)))
    idle = [s for t, s in sent if 1.0 <= t < 2.9]  # calibrated, untouched
    pressed = [s for t, s in sent if 3.1 <= t < 5.0]
    assert len(idle) > 80 and 0.18 <= np.mean(idle) <= 0.22
    assert len(pressed) > 80 and all(pressed)


@pytest.mark.ros
def test_the_driver_sends_an_untouched_patch_every_fifth_period(ros_context: object) -> None:
    """skin_driver with ``idle_every: 5`` on a virtual bus, the two patches of robot_skin.yaml,
    the palm pressed from 0.4 s on and the forearm untouched: in the batches the palm's
    readings follow each other period by period, the forearm's five periods apart (never
    more), and the driver counts what it held back."""
    from rclpy.executors import SingleThreadedExecutor

    from tactile_contact.model.layout import load_layout
    from tactile_contact.sim.simulator import Indentation
    from test.rosutil import spin_until
    from test.test_driver_batches import LAYOUT, PERIOD_S, _driver_and_batches, _simulator, sending

    channel = "idle_gate"
    params = {"interface": "virtual", "channel": channel, "layout": str(LAYOUT)}
    params |= {"period_ms": 20, "calibration_samples": 2, "batch_window_ms": 5.0}
    params |= {"idle_every": 5}
    node, listener, batches = _driver_and_batches(ros_context, params, "idle_listener")
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(listener)
    layout = load_layout(LAYOUT)
    sims = {p.name: _simulator(p, k) for k, p in enumerate(layout.patches)}
    palm = next(p for p in layout.patches if p.name == "palm")
    touch: dict[str, Any] = {
        "palm": Indentation.press(
            None, 1.0, tuple(palm.taxel_xy()[0]), start_s=0.4, ramp_s=0.1, hold_s=60.0
        )
    }
    stack = contextlib.ExitStack()
    try:
        assert spin_until(
            executor, lambda: listener.count_publishers("taxel_batches") > 0, timeout_s=10.0
        )
        stack.enter_context(sending(channel, sims, touch))
        stamps: dict[str, list[int]] = {"palm": [], "forearm": []}

        def enough() -> bool:
            stamps["palm"] = [
                s
                for b in batches
                for n, s in zip(b.patches, b.stamps_ns, strict=True)
                if n == "palm"
            ]
            return len(stamps["palm"]) >= 80

        assert spin_until(executor, enough, timeout_s=20.0)
        for b in batches:
            for n, s in zip(b.patches, b.stamps_ns, strict=True):
                if n == "forearm":
                    stamps["forearm"].append(s)
        period_ns = PERIOD_S * 1e9
        palm_gaps = np.diff(stamps["palm"][-50:]) / period_ns
        forearm_gaps = np.diff(stamps["forearm"][-10:]) / period_ns
        # (stamps are the virtual bus's send times: a loaded machine delays one by up to half
        # a period; a period held back shows as a gap of 2, a keep-alive off by one as 4 or 6)
        assert np.all(palm_gaps < 1.9), palm_gaps  # pressed: every period
        assert np.all((forearm_gaps > 4.0) & (forearm_gaps < 6.0)), forearm_gaps
        assert abs(forearm_gaps.mean() - 5.0) < 0.25, forearm_gaps
        assert node._gate is not None and node._gate.held >= 4 * 9
    finally:
        stack.close()
        executor.shutdown()
        node.destroy_node()
        listener.destroy_node()


def test_a_float64_reading_just_above_the_limit_is_not_rounded_onto_it() -> None:
    """Readings of another type are compared as they are (a float32 cast put 2 counts plus a
    hair on the limit, held back; NumPy's comparison let it through)."""
    gate = IdleGate(5, 2.0, {"a": COUNT})
    quiet = PatchFrame("a", "a", 0.0, [0, 1], np.zeros(2, np.float64), b"", bytes(2))
    for _ in range(4):
        gate.passes(quiet)  # first sent, then the release, then held
    limit = float(np.float32(2.0 * COUNT))
    above = dataclasses.replace(quiet, delta_c=np.array([np.nextafter(limit, 1.0), 0.0]))
    assert gate.passes(above)
