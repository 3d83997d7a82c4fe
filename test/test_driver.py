"""Driver core on a python-can virtual bus fed by the simulator: ΔC vs truth, faults."""

from __future__ import annotations

import math
import random
import uuid

import can
import numpy as np
import pytest

from tactile_contact.baseline import STATUS_CONTACT, STATUS_DISABLED, STATUS_STALE, BaselineConfig
from tactile_contact.sensor import SensorParams

layout_mod = pytest.importorskip("tactile_contact.layout")
pytest.importorskip("tactile_contact.forward")

from tactile_contact.codec import ERROR_I2C, PeriodAssembler, reading_messages  # noqa: E402
from tactile_contact.driver import PatchBuffer, SkinDriverCore  # noqa: E402
from tactile_contact.indenters import HertzSphere  # noqa: E402
from tactile_contact.simulator import Indentation, simulator_for_patch  # noqa: E402

LAYOUT = {
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
                    "position": [0.0115, 0.0066],
                    "rotation_deg": 180,
                },
                {"type": "icub_v2_10pad", "board": 2, "triangle": 3, "position": [0.04, 0.0]},
            ],
        }
    ],
}


def _patch():
    return layout_mod.parse_layout(LAYOUT).patches[0]


def _run_bus(periods, core, drop=None):
    """Send periods on a virtual bus, receive them, feed the core; (outputs, truths)."""
    channel = f"drv-{uuid.uuid4().hex}"
    outs = []
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
        can.Bus(interface="virtual", channel=channel) as rx,
    ):
        truths = []
        for p in periods:
            msgs = [m for m in p.messages if drop is None or not drop(p.t, m)]
            for m in msgs:
                tx.send(m)
            truths.append(p.truth)
            while (m := rx.recv(timeout=0.0)) is not None:
                outs += core.on_message(m)
    return outs, truths


def test_published_delta_c_matches_simulated_truth() -> None:
    patch = _patch()
    sim = simulator_for_patch(patch, seed=4, noise_cdc=1.0, rest_spread_cdc=6, period_s=0.05)
    xy = patch.channel_xy()
    ind = Indentation.press(
        HertzSphere(6e-3), 1.5, tuple(xy[3]), start_s=1.5, ramp_s=0.2, hold_s=2.0
    )
    core = SkinDriverCore([patch], baseline=BaselineConfig(calibration_samples=20))
    outs, truths = _run_bus(sim.periods(ind, 3.5), core)
    assert len(outs) == len(truths) == 70
    assert all(o.patch == "palm" and o.frame_id == "palm_skin" for o in outs)
    assert outs[0].taxel_ids[0] == (1 << 8) and outs[0].taxel_ids[-1] == (2 << 8 | 3 << 4 | 11)
    lsb = SensorParams().value_count_farad
    for o, tr in zip(outs[25:], truths[25:], strict=True):
        assert o.stamp == pytest.approx(tr.t, abs=0.005)
        ok = (o.status & STATUS_DISABLED) == 0
        # Noise 1 CDC count + rest offsets learnt by calibration: within 1.5 counts.
        assert np.all(np.abs(o.delta_c[ok] - tr.delta_c[ok]) <= 1.5 * lsb)
    hold = outs[50]
    assert hold.in_contact and hold.status[3] & STATUS_CONTACT and hold.delta_c[3] > 3 * lsb
    pads = [24 + 6, 24 + 10]
    assert np.all(hold.status[pads] & STATUS_DISABLED) and np.all(hold.delta_c[pads] == 0)


def test_silent_module_garbage_and_bus_errors() -> None:
    patch = _patch()
    sim = simulator_for_patch(patch, seed=5, period_s=0.05)
    core = SkinDriverCore([patch], baseline=BaselineConfig(calibration_samples=5))

    def silent(t, m):  # board 2 triangle 3 is silent between 1 s and 2 s
        return 1.0 <= t < 2.0 and (m.arbitration_id & 0xFF) == 0x23

    channel = f"drv-{uuid.uuid4().hex}"
    rng = random.Random(9)
    outs = []
    n_garbage = 0
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
        can.Bus(interface="virtual", channel=channel) as rx,
    ):
        for p in sim.periods(None, 3.0):
            for m in p.messages:
                if not silent(p.t, m):
                    tx.send(m)
                for _ in range(3):
                    cid = rng.choice([0x000, 0x123, 0x412, 0x455, 0x7FF])
                    data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
                    tx.send(
                        can.Message(
                            arbitration_id=cid, data=data, is_extended_id=False, timestamp=p.t
                        )
                    )
                    n_garbage += 1
            core.on_bus_error()
            while (m := rx.recv(timeout=0.0)) is not None:
                outs += core.on_message(m)
            outs += core.poll(p.t + 0.04)
            if abs(p.t - 1.5) < 1e-9:
                diag = core.diagnostics(p.t + 0.04)
                assert diag["modules"]["b2t3"]["silent"]
                assert not diag["modules"]["b1t0"]["silent"]
    during = [o for o in outs if 1.2 < o.stamp < 1.9]
    after = [o for o in outs if o.stamp > 2.3]
    assert len(during) >= 12 and len(after) >= 12  # the good modules keep being published
    assert all(np.all(o.status[24:] & STATUS_STALE) for o in during)
    assert all(not np.any(o.status[:24] & STATUS_STALE) for o in during)
    assert all(not np.any(o.status & STATUS_STALE) for o in after)
    d = core.diagnostics(3.0)
    assert d["bus"]["bus_errors"] == 60
    assert d["bus"]["rejected"] >= n_garbage - 10  # garbage that looks like a frame A/B pair
    assert 19.0 < d["modules"]["b1t0"]["rate_hz"] < 21.0
    assert d["patches"]["palm"]["calibrated"] and d["patches"]["palm"]["published"] == len(outs)
    assert core.tare("palm") and not core.tare("nope")


def test_duplicate_module_in_two_patches_is_rejected() -> None:
    p = _patch()
    with pytest.raises(ValueError, match="in patches"):
        SkinDriverCore([p, p])
    assert math.isfinite(SkinDriverCore([p]).stale_after_s)


_VALS = list(range(100, 112))


def test_patch_buffer() -> None:
    buf = PatchBuffer([(0, 1), (2, 3)])
    assert not buf.complete and list(buf.raw[:3]) == [240] * 3
    asm = PeriodAssembler()
    (r1,) = asm.feed_many(
        reading_messages(2, 3, _VALS, oor_mask=0x1, error_flags=ERROR_I2C, timestamp=1.0)
    )
    assert buf.put(r1) and not buf.complete
    (r0,) = asm.feed_many(reading_messages(0, 1, [7] * 12, timestamp=0.5))
    assert buf.put(r0) and buf.complete
    (r9,) = asm.feed_many(reading_messages(9, 9, [7] * 12))
    assert not buf.put(r9)
    raw, fresh, stamp = buf.take()
    assert list(raw[12:]) == _VALS and list(raw[:12]) == [7] * 12 and fresh.all()
    assert stamp == pytest.approx(1.0) and not buf.complete and not buf.fresh.any()
    assert buf.out_of_range[12] and not buf.out_of_range[13]
    assert buf.module_error[12:].all() and not buf.module_error[:12].any()
    with pytest.raises(ValueError, match="unique"):
        PatchBuffer([(0, 1), (0, 1)])
