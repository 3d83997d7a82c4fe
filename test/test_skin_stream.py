"""The ROS-free data path of skin_driver: patch gathering, staleness, health, replay, errors.

Times are driven by hand (``now`` is the monotonic clock the stream waits on, frame
timestamps the receive times), so every rule is checked deterministically.
"""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from tactile_contact.canbus import baseline as bl
from tactile_contact.canbus import codec
from tactile_contact.canbus.stream import BusErrorPolicy, ReplayBus, SkinStream
from tactile_contact.model.layout import load_layout
from tactile_contact.model.sensor import value_count_farad

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"
P = 0.02  # period [s]
M = 6


def make_stream(**kw: object) -> SkinStream:
    args = {
        "period_s": P,
        "max_wait_s": 0.02,
        "module_timeout_s": 0.1,
        "baseline": bl.BaselineConfig(calibration_samples=2),
    }
    args.update(kw)
    return SkinStream(load_layout(LAYOUT).patches, **args)  # type: ignore[arg-type]


def frames(k: int, tri: int, value: int = 240, t0: float = 100.0) -> list[can.Message]:
    """Frames A and B of triangle ``tri`` in period k, all channels at ``value``."""
    return codec.reading_messages(0, tri, [value] * 12, timestamp=t0 + k * P + tri * 1e-4)


def feed_period(s: SkinStream, k: int, tris: range | list[int] = range(M), value: int = 240):
    out = []
    for tri in tris:
        for m in frames(k, tri, value):
            out += s.feed(m, now=k * P + tri * 1e-4)
    return out


def fresh_modules(frame: object) -> list[int]:
    st = np.frombuffer(frame.status, np.uint8)  # type: ignore[attr-defined]
    return [i for i in range(M) if not st[12 * i] & bl.STATUS_STALE]


def test_one_message_per_period_with_delta_c_after_calibration() -> None:
    s = make_stream()
    out = [f for k in range(3) for f in feed_period(s, k)]
    assert len(out) == 3 and all(fresh_modules(f) == list(range(M)) for f in out)
    (f,) = feed_period(s, 3, value=236)
    assert f.patch == "hexagon" and f.frame_id == "skin_hexagon"
    assert f.stamp == pytest.approx(100.0 + 3 * P + 5e-4)  # completing frame of the last module
    se = load_layout(LAYOUT).patch("hexagon").sensor
    q = float(value_count_farad(se.farad_per_count, se.shift))
    np.testing.assert_allclose(f.delta_c, 4 * q, rtol=1e-6)
    assert f.raw == bytes([236] * 12 * M)
    assert f.taxel_ids[:13] == [*range(12), 0x10]


def test_stamp_is_the_newest_reading_of_the_message_even_after_a_clock_step() -> None:
    s = make_stream()
    (a,) = feed_period(s, 0)
    out = []
    for tri in range(M):  # the receive clock stepped back by 50 s
        for m in codec.reading_messages(0, tri, [240] * 12, timestamp=50.0 + tri * 1e-4):
            out += s.feed(m, now=P)
    assert [f.stamp for f in out] == [pytest.approx(50.0005)]
    assert a.stamp == pytest.approx(100.0005)


def test_max_wait_publishes_with_stale_modules_and_loses_nothing() -> None:
    s = make_stream()
    feed_period(s, 0)
    assert feed_period(s, 1, tris=[0, 1, 2]) == []
    assert s.poll(now=1 * P + 0.019) == []  # max wait not reached yet
    (split,) = s.poll(now=1 * P + 0.021)
    assert fresh_modules(split) == [0, 1, 2]
    st = np.frombuffer(split.status, np.uint8)
    assert np.all(st[36:] & bl.STATUS_STALE)
    rest = feed_period(s, 1, tris=[3, 4, 5])
    assert rest == []  # 3..5 now pending; 0..2 of period 2 will publish them
    (second,) = s.feed(frames(2, 0)[0], now=2 * P) + s.feed(frames(2, 0)[1], now=2 * P)
    assert fresh_modules(second) == [3, 4, 5]


def test_second_reading_of_a_module_publishes_the_pending_one_first() -> None:
    s = make_stream(max_wait_s=10.0)
    feed_period(s, 0)
    feed_period(s, 1, tris=[0, 1])
    # module 0 again, stamped only 1 ms later: same-module repeat forces the publication
    msgs = codec.reading_messages(0, 0, [200] * 12, timestamp=100.0 + P + 1e-3)
    out = s.feed(msgs[0], now=0.03) + s.feed(msgs[1], now=0.03)
    assert len(out) == 1 and fresh_modules(out[0]) == [0, 1]
    assert out[0].raw[:12] == bytes([240] * 12)


def test_a_reading_of_a_later_period_does_not_join_the_pending_ones() -> None:
    s = make_stream(max_wait_s=10.0)
    feed_period(s, 0)
    feed_period(s, 1, tris=[4, 5])
    out = feed_period(s, 2, tris=[0])  # 0.75 period after the pending readings or more
    assert len(out) == 1 and fresh_modules(out[0]) == [4, 5]


def test_silent_module_is_not_waited_for_after_the_timeout() -> None:
    s = make_stream(max_wait_s=10.0)
    for k in range(2):
        feed_period(s, k)
    quiet = [0, 1, 2, 4, 5]
    k = 2
    # within the timeout the patch waits for module 3, then the repeat rule publishes
    while k * P < 1 * P + 0.1:
        feed_period(s, k, tris=quiet)
        k += 1
    feed_period(s, k, tris=quiet)  # publishes what waited for module 3
    out = feed_period(s, k + 1, tris=quiet)
    assert len(out) == 1 and fresh_modules(out[0]) == quiet  # published at once, 3 stale
    diag = {d.name: d for d in s.diagnostics(now=(k + 1) * P)}
    m3 = diag["patch hexagon module board 0 triangle 3"]
    assert m3.level == 2 and m3.values["stale"] is True
    # it comes back: waited for again, and its gap is counted as missed periods
    back = feed_period(s, k + 2)
    assert len(back) == 1 and fresh_modules(back[0]) == list(range(M))
    m3 = {d.name: d for d in s.diagnostics(now=(k + 2) * P)}[m3.name]
    assert m3.level == 0 and m3.values["missed_periods"] == k + 2 - 1 - 1


def test_never_heard_modules_are_stale_not_saturated() -> None:
    s = make_stream(module_timeout_s=0.01)
    feed_period(s, 0, tris=[0])
    (f,) = s.poll(now=1.0)
    st = np.frombuffer(f.status, np.uint8)
    assert np.all(st[12:] & bl.STATUS_STALE) and not np.any(st[12:] & bl.STATUS_SATURATED)
    names = {d.name: d for d in s.diagnostics(now=1.0)}
    assert names["patch hexagon"].values["never_heard_modules"] == "0/1 0/2 0/3 0/4 0/5"


def test_bad_frames_are_counted_per_reason() -> None:
    s = make_stream()
    bad = [
        can.Message(arbitration_id=0x400, data=b"\x40\x01", is_extended_id=False),  # truncated
        can.Message(arbitration_id=0x401, data=bytes(8), is_extended_id=False),  # bad type
        can.Message(arbitration_id=0x4F0, data=b"\x40" + bytes(7), is_extended_id=False),
        can.Message(arbitration_id=0x300, data=b"\x40" + bytes(7), is_extended_id=False),
        can.Message(arbitration_id=0x400, is_remote_frame=True, is_extended_id=False),
        can.Message(arbitration_id=0x400, data=b"\x40" + bytes(11), is_extended_id=False),
        can.Message(arbitration_id=0x400, data=b"\x40" + bytes(11), is_fd=True),
        can.Message(arbitration_id=0x400, data=b"\x40" + bytes(7), is_extended_id=True),
        can.Message(arbitration_id=0x020, is_error_frame=True, is_extended_id=False),
    ]
    for m in bad:
        assert s.feed(m, now=0.0) == []
    assert s.last_error is not None
    values = s.diagnostics(now=0.0)[0].values
    assert values["rejected"] == len(bad)
    kinds = ("truncated", "bad_type", "unexpected_module", "unknown_id", "remote", "oversized")
    for reason in (*kinds, "fd", "extended", "error_frames"):
        assert values[f"rejected_{reason}"] == 1, reason


def test_tare_and_board_ranges() -> None:
    s = make_stream()
    assert s.tare() == ([], ["hexagon"])
    feed_period(s, 0)
    assert s.tare() == (["hexagon"], [])
    assert s.board_ranges() == {0: (0, 5, 2, 240)}
    assert s.can_filters() == [{"can_id": 0x400, "can_mask": 0x700, "extended": False}]


def test_replay_bus_filters_paces_and_finishes(tmp_path: Path) -> None:
    log = tmp_path / "x.log"
    with can.Logger(str(log)) as w:
        for k in range(5):
            for m in frames(k, 0, t0=0.0):
                w.on_message_received(m)
            w.on_message_received(
                can.Message(arbitration_id=0x123, data=b"", is_extended_id=False, timestamp=k * P)
            )
    bus = ReplayBus(str(log), can_filters=make_stream().can_filters())
    import time

    t0 = time.monotonic()
    got = [bus.recv(0.01) for _ in range(10)]
    assert time.monotonic() - t0 >= 3 * P  # paced by the recorded timestamps
    assert all(m is not None and m.arbitration_id == 0x400 for m in got)
    assert bus.recv(0.01) is None and bus.finished
    bus.shutdown()


def test_bus_error_policy_asks_for_a_reconnect_after_consecutive_errors() -> None:
    p = BusErrorPolicy(reconnect_after=3)
    assert [p.error(OSError("down")) for _ in range(2)] == [False, False]
    p.ok()
    assert [p.error(can.CanOperationError("x")) for _ in range(3)] == [False, False, True]
    v = p.values()
    assert v["bus_errors"] == 5 and v["bus_errors_in_window"] == 5
    assert p.values()["bus_errors_in_window"] == 0
    assert "CanOperationError" in v["last_bus_error"]


@pytest.mark.parametrize("bad", [{"max_wait_s": 0.0}, {"period_s": float("nan")}])
def test_invalid_arguments_are_rejected(bad: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        make_stream(**bad)


# -- On a virtual bus fed by the simulator (ported from the former driver-core tests) ----------
_MIXED = {
    "schema_version": 1,
    "patches": [
        {
            "name": "palm",
            "frame_id": "palm_skin",
            "modules": [
                {"type": "roboskin12", "board": 1, "triangle": 0, "position": [0.0, 0.0]},
                {
                    "type": "roboskin12",
                    "board": 1,
                    "triangle": 1,
                    # Beside the first, as triangles 4 and 3 of the hexagon patch tile.
                    "position": [0.0, -0.019321],
                    "rotation_deg": 60,
                },
                {"type": "icub_v2_10pad", "board": 2, "triangle": 3, "position": [0.04, 0.0]},
            ],
        }
    ],
}


def _mixed_patch():  # two ROBOSKIN triangles and an iCub 10-pad one (thermal pads disabled)
    from tactile_contact.model.layout import parse_layout

    return parse_layout(_MIXED).patches[0]


def test_delta_c_through_a_virtual_bus_matches_the_simulated_truth() -> None:
    import uuid

    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.sensor import SensorParams
    from tactile_contact.sim.simulator import Indentation, simulator_for_patch

    patch = _mixed_patch()
    sim = simulator_for_patch(patch, seed=4, noise_cdc=1.0, rest_spread_cdc=6, period_s=0.05)
    xy = patch.channel_xy()
    ind = Indentation.press(
        HertzSphere(6e-3), 1.5, tuple(xy[3]), start_s=1.5, ramp_s=0.2, hold_s=2.0
    )
    s = SkinStream([patch], baseline=bl.BaselineConfig(calibration_samples=20), period_s=0.05)
    channel = f"stream-{uuid.uuid4().hex}"
    outs, truths = [], []
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
        can.Bus(interface="virtual", channel=channel) as rx,
    ):
        for p in sim.periods(ind, 3.5):
            for m in p.messages:
                tx.send(m)
            truths.append(p.truth)
            while (m := rx.recv(timeout=0.0)) is not None:
                outs += s.feed(m, now=m.timestamp)
    assert len(outs) == len(truths) == 70
    assert all(o.patch == "palm" and o.frame_id == "palm_skin" for o in outs)
    assert outs[0].taxel_ids[0] == (1 << 8) and outs[0].taxel_ids[-1] == (2 << 8 | 3 << 4 | 11)
    lsb = SensorParams().value_count_farad
    for o, tr in zip(outs[25:], truths[25:], strict=True):
        st = np.frombuffer(o.status, np.uint8)
        assert o.stamp == pytest.approx(tr.t, abs=0.005)
        ok = (st & bl.STATUS_DISABLED) == 0
        # Noise 1 CDC count + rest offsets learnt by calibration: within 1.5 counts.
        assert np.all(np.abs(o.delta_c[ok] - tr.delta_c[ok]) <= 1.5 * lsb)
    hold = outs[50]
    st = np.frombuffer(hold.status, np.uint8)
    assert st[3] & bl.STATUS_CONTACT and hold.delta_c[3] > 3 * lsb
    pads = [24 + 6, 24 + 10]
    assert np.all(st[pads] & bl.STATUS_DISABLED) and np.all(hold.delta_c[pads] == 0)


def test_silent_module_among_garbage_keeps_the_good_modules_published() -> None:
    import random

    from tactile_contact.sim.simulator import simulator_for_patch

    patch = _mixed_patch()
    sim = simulator_for_patch(patch, seed=5, period_s=0.05)
    s = SkinStream(
        [patch],
        baseline=bl.BaselineConfig(calibration_samples=5),
        period_s=0.05,
        max_wait_s=0.03,
        module_timeout_s=0.1,
    )
    rng = random.Random(9)
    outs, n_periods = [], 0
    for p in sim.periods(None, 3.0):
        n_periods += 1
        for m in p.messages:
            if not (1.0 <= p.t < 2.0 and (m.arbitration_id & 0xFF) == 0x23):  # b2t3 silent
                outs += s.feed(m, now=p.t)
            for _ in range(3):
                cid = rng.choice([0x000, 0x123, 0x412, 0x455, 0x7FF])
                data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
                g = can.Message(arbitration_id=cid, data=data, is_extended_id=False, timestamp=p.t)
                outs += s.feed(g, now=p.t)
        outs += s.poll(p.t + 0.04)
    # One publication per period: no complete reading lost, the good modules never held up.
    # No module reading lost nor published twice; the good modules are never held up. The
    # returning module's first reading comes after its patch was published, so it goes alone.
    stale = [np.frombuffer(o.status, np.uint8) & bl.STATUS_STALE for o in outs]
    assert sum(int(np.sum(st[::12] == 0)) for st in stale) == 3 * n_periods - 20
    assert len(outs) == n_periods + 1 == 61
    during = [st for o, st in zip(outs, stale, strict=True) if 1.01 < o.stamp < 1.99]
    after = [st for o, st in zip(outs, stale, strict=True) if o.stamp > 2.01]
    assert len(during) >= 18 and len(after) >= 18
    assert all(np.all(st[24:]) and not np.any(st[:24]) for st in during)
    assert all(not np.any(st) for st in after)
    c = s.assembler.counters
    assert c.rejected > 0 and c.readings == 3 * n_periods - 20


def test_out_of_range_and_module_error_reach_the_status() -> None:
    s = make_stream()
    feed_period(s, 0)
    out = []
    for tri in range(M):
        kw = {"oor_mask": 0x1, "error_flags": codec.ERROR_I2C} if tri == 2 else {}
        msgs = codec.reading_messages(0, tri, [240] * 12, timestamp=100.0 + P + tri * 1e-4, **kw)
        for m in msgs:
            out += s.feed(m, now=P + tri * 1e-4)
    (f,) = out
    st = np.frombuffer(f.status, np.uint8)
    assert st[24] & bl.STATUS_OUT_OF_RANGE and not st[25] & bl.STATUS_OUT_OF_RANGE
    assert not np.any(st[:24] & bl.STATUS_OUT_OF_RANGE)


def test_a_module_in_two_patches_is_rejected() -> None:
    p = load_layout(LAYOUT).patches[0]
    with pytest.raises(ValueError, match="two patches"):
        SkinStream([p, p])


@pytest.mark.parametrize("lost", [0, 1])
def test_a_period_lost_to_a_half_received_pair_is_one_drop(lost: int) -> None:
    """Frame A (or B) of module 2 lost in period 3: one reading lost, one drop — the gap in
    the readings and the incomplete pair (or orphan B) are the same period."""
    s = make_stream(max_wait_s=10.0)
    for k in range(8):
        for tri in range(M):
            for j, m in enumerate(frames(k, tri)):
                if not (k == 3 and tri == 2 and j == lost):
                    s.feed(m, now=k * P + tri * 1e-4)
    v = {d.name: d for d in s.diagnostics(now=8 * P)}[
        "patch hexagon module board 0 triangle 2"
    ].values
    assert v["missed_periods"] == 1
    assert v["incomplete_periods"] + v["orphan_b"] == 1
    assert v["drops"] == 1


def test_a_pair_window_as_long_as_the_period_is_refused() -> None:
    """A 100 Hz skin (period_ms 10) left with the default 10 ms pair window would pair a frame
    A whose B was lost with the next period's B."""
    with pytest.raises(ValueError, match=r"pair_window_s 10 ms must be below the period \(10 ms"):
        make_stream(period_s=0.01, pair_window_s=0.01)
    make_stream(period_s=0.01, pair_window_s=0.004)


def test_readings_pending_at_a_pause_are_dropped_not_published_with_the_next_period() -> None:
    """The driver deactivated with half a period read: without drop_pending the next period's
    first reading published those old readings (old stamps) in a message of their own."""
    s = make_stream(max_wait_s=10.0)
    feed_period(s, 0)
    feed_period(s, 1, tris=[0, 1, 2])  # pending: modules 0..2 of period 1
    assert s.drop_pending() == 3
    out = feed_period(s, 3)  # after the pause: one message, every module of period 3
    assert len(out) == 1 and fresh_modules(out[0]) == list(range(M))
    assert out[0].stamp == pytest.approx(100.0 + 3 * P + 5e-4)
    assert s.drop_pending() == 0
