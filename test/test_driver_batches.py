"""skin_driver's batches: a bus's readings in one TaxelBatch, per-patch topics on demand.

The Batcher is checked alone (when a batch goes out); then the real node on a python-can
virtual bus, fed two patches' frames by the simulator (a smooth analytic bump, as in
test_driver_node: the driver is under test, not the physics): every reading appears in
exactly one batch, the batches carry what the per-patch TaxelArray carries for the same
reading, and no TaxelArray is published before something subscribes to it.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.model.layout import load_layout
from tactile_contact.model.sensor import SensorParams
from tactile_contact.sim.simulator import SkinSimulator
from test.rosutil import spin_until

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "robot_skin.yaml"  # forearm (board 0) and palm (boards 1, 2)
PERIOD_S = 0.02


def _frame(patch: str) -> Any:
    from tactile_contact.canbus.stream import PatchFrame

    return PatchFrame(patch, f"f_{patch}", 1.0, [1, 2], np.zeros(2, np.float32), b"\0\0", b"\0\0")


def test_a_batch_goes_out_when_every_patch_has_a_reading_or_its_window_ends() -> None:
    from tactile_contact.canbus.batcher import Batcher

    b = Batcher(["a", "b", "c"], window_s=0.002)
    assert b.add(_frame("a"), now=10.0) == [] and b.due == pytest.approx(10.002)
    assert b.add(_frame("b"), now=10.001) == []  # the window runs from the first reading
    assert b.due == pytest.approx(10.002)
    out = b.add(_frame("c"), now=10.0015)  # every patch: at once
    assert [[f.patch for f in batch] for batch in out] == [["a", "b", "c"]]
    assert not b.pending and b.due == float("inf")
    b.add(_frame("a"), now=11.0)
    out = b.add(_frame("a"), now=11.001)  # a second reading of a: the first goes out first
    assert [[f.patch for f in batch] for batch in out] == [["a"]]
    assert list(b.pending) == ["a"] and b.due == pytest.approx(11.003)
    assert [f.patch for f in b.take()] == ["a"]
    now = Batcher(["a", "b"], window_s=0.0)  # no window: each reading at once
    assert [[f.patch for f in batch] for batch in now.add(_frame("b"), now=1.0)] == [["b"]]


def test_with_buses_a_complete_bus_goes_out_unless_another_is_due_within_the_window() -> None:
    """One driver of three buses, one patch each, 20 ms periods: can0 and can1 complete 1 ms
    apart, can2 10 ms later. Until a bus's period is known each goes out as it completes; then
    can0 waits for can1 (due within the window) and not for can2; a bus that misses its
    period holds the batch until it is due, and no longer after that."""
    from tactile_contact.canbus.batcher import Batcher

    b = Batcher(["a", "b", "c"], 0.002, {"can0": ["a"], "can1": ["b"], "can2": ["c"]})

    def sent(patch: str, ms: float) -> list[list[str]]:
        return [[f.patch for f in batch] for batch in b.add(_frame(patch), now=ms * 1e-3)]

    for k in (0, 1):  # the periods learnt: each bus alone, at once
        assert sent("a", 20 * k) == [["a"]]
        assert sent("b", 20 * k + 1) == [["b"]]
        assert sent("c", 20 * k + 10) == [["c"]]
    assert b.expected("can1") == pytest.approx(0.041)
    assert sent("a", 40) == []  # can1 is due at 41, within the window
    assert sent("b", 41) == [["a", "b"]]  # both complete; can2 not before 50
    assert sent("c", 50) == [["c"]]
    assert sent("a", 60) == [] and b.due == pytest.approx(0.062)  # can1 late: held till due
    assert [f.patch for f in b.take()] == ["a"]
    assert sent("c", 70) == [["c"]]
    assert sent("a", 80) == [["a"]]  # can1 overdue by more than the window: not waited for
    alone = Batcher(["a", "b"], 0.002)  # no buses named: the window, as before
    assert alone.add(_frame("a"), now=1.0) == [] and alone.due == pytest.approx(1.002)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from("abcde"), st.floats(0.0, 0.004)), max_size=60),
    st.sampled_from([0.0, 0.001, 0.002, 0.005]),
    st.booleans(),
)
def test_every_reading_goes_out_once_within_its_window(events, window, by_bus) -> None:
    """Any order and timing of readings, the buses known or not, taken at the due time as the
    driver's receive loop does: every reading goes out exactly once, in the order it came, no
    batch holds a patch twice, and none goes out later than its first reading's window."""
    from tactile_contact.canbus.batcher import Batcher

    groups = {"can0": ["a", "b"], "can1": ["c"], "can2": ["d", "e"]} if by_bus else None
    b = Batcher(list("abcde"), window, groups)
    sent: list[tuple[float, list]] = []
    now = 0.0
    for k, (patch, dt) in enumerate(events):
        now += dt
        if b.pending and now >= b.due:
            sent.append((b.due, b.take()))
        sent.extend((now, batch) for batch in b.add(_frame_at(patch, now, k), now))
    if b.pending:
        sent.append((b.due, b.take()))
    order = [f.frame_id for _, batch in sent for f in batch]
    assert order == [str(k) for k in range(len(events))]
    for at, batch in sent:
        assert len({f.patch for f in batch}) == len(batch)
        assert at <= min(f.stamp for f in batch) + window + 1e-12


def _frame_at(patch: str, stamp: float, k: int) -> Any:
    from tactile_contact.canbus.stream import PatchFrame

    return PatchFrame(patch, str(k), stamp, [1], np.zeros(1, np.float32), b"\0", b"\0")


class _Bump:
    """Compression [m] = 200 µm · exp(−r²/2σ²), σ = 5 mm, around the patch's first taxel."""

    def __init__(self, xy: np.ndarray) -> None:
        self.xy = xy

    def compression(self, indenter: Any, force: float, center_xy: Any) -> np.ndarray:
        r2 = np.sum((self.xy - np.asarray(center_xy)) ** 2, axis=1)
        return force * 200e-6 * np.exp(-r2 / (2 * 0.005**2))


def _simulator(patch: Any, seed: int) -> SkinSimulator:
    el, se = patch.elastomer, patch.sensor
    sensor = SensorParams(
        thickness=el.thickness,
        epsilon_r=se.epsilon_r,
        area=se.area,
        farad_per_count=se.farad_per_count,
        shift=se.shift,
        no_load=se.no_load,
    )
    return SkinSimulator(
        [(m.board, m.triangle) for m in patch.modules],
        _Bump(patch.channel_xy()),
        sensor=sensor,
        taxel_mask=patch.valid_mask(),
        noise_cdc=1.0,
        period_s=PERIOD_S,
        seed=seed,
    )


def _two_bus_layout(tmp_path: Path) -> Path:
    """robot_skin.yaml with the forearm on can0 and the palm on can1, its first module at
    board 0: the forearm's address on the other bus (ids repeat from bus to bus)."""
    import yaml

    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0]["bus"] = "can0"
    doc["patches"][1]["bus"] = "can1"
    doc["patches"][1]["modules"][0]["board"] = 0
    path = tmp_path / "two_buses.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@contextlib.contextmanager
def sending(channel: str, sims: dict[str, SkinSimulator], touch: dict[str, Any]) -> Iterator[None]:
    """A thread sending every simulator's frames of a period together (as a board sends its
    triangles) on the virtual bus ``channel`` every PERIOD_S, ``touch`` pressing the patches
    it names (the others untouched), until the block ends."""
    bus = can.Bus(interface="virtual", channel=channel)
    stop = threading.Event()

    def send() -> None:
        k = 0
        t0 = time.monotonic()
        while not stop.is_set():
            for name, sim in sims.items():
                for m in sim.period(touch.get(name), k * PERIOD_S).messages:
                    bus.send(m)
            k += 1
            stop.wait(max(0.0, t0 + k * PERIOD_S - time.monotonic()))

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        yield
    finally:
        stop.set()
        sender.join(2.0)
        bus.shutdown()


def _driver_and_batches(ros_context: object, params: dict, name: str) -> tuple[Any, Any, list]:
    """A SkinDriver with ``params``, and a node ``name`` collecting its TaxelBatches (read)."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from tactile_contact.msg import TaxelBatch
    from tactile_contact.ros.cdr import read_taxel_batch
    from tactile_contact.ros.common import SENSOR_QOS
    from tactile_contact.ros.skin_driver import SkinDriver

    node = SkinDriver(
        context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
    )
    listener = Node(name, context=ros_context)
    batches: list[Any] = []
    listener.create_subscription(
        TaxelBatch,
        "taxel_batches",
        lambda data: batches.append(read_taxel_batch(data)),
        SENSOR_QOS,
        raw=True,
    )
    return node, listener, batches


@pytest.mark.ros
def test_every_reading_is_in_one_batch_and_taxel_arrays_only_for_subscribers(
    ros_context: object,
) -> None:
    from rclpy.executors import SingleThreadedExecutor

    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.common import SENSOR_QOS
    from tactile_contact.sim.simulator import Indentation

    channel = "driver_batches"
    params = {"interface": "virtual", "channel": channel, "layout": str(LAYOUT)}
    params |= {"period_ms": 20, "calibration_samples": 2, "batch_window_ms": 5.0}
    node, listener, batches = _driver_and_batches(ros_context, params, "batch_listener")
    stack = contextlib.ExitStack()
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(listener)
    layout = load_layout(LAYOUT)
    sims = {p.name: _simulator(p, k) for k, p in enumerate(layout.patches)}
    touch = {
        p.name: Indentation.press(None, 1.0, tuple(p.taxel_xy()[0]), start_s=0.2, ramp_s=0.1)
        for p in layout.patches
    }
    try:
        assert spin_until(
            executor, lambda: listener.count_publishers("taxel_batches") > 0, timeout_s=10.0
        )
        stack.enter_context(sending(channel, sims, touch))
        assert spin_until(executor, lambda: len(batches) >= 40, timeout_s=20.0)
        # 1. every reading once: no patch twice in a batch, and per patch one reading a period
        sizes = {p.name: 12 * len(p.modules) for p in layout.patches}
        for b in batches:
            assert len(set(b.patches)) == len(b.patches)
            assert np.diff(b.offsets).tolist() == [sizes[name] for name in b.patches]
        stamps: dict[str, list[int]] = {name: [] for name in sims}
        for b in batches:
            for name, stamp in zip(b.patches, b.stamps_ns, strict=True):
                stamps[name].append(stamp)
        for name, got in stamps.items():
            assert got == sorted(set(got)), f"{name}: a reading repeated or out of order"
        together = sum(len(b.patches) == 2 for b in batches)
        assert together >= 0.8 * len(batches), "the two patches' readings travel together"
        # 2. no TaxelArray while nobody subscribes
        assert node._published_patch_messages == 0
        arrays: list[Any] = []
        listener.create_subscription(TaxelArray, "palm/taxels", arrays.append, SENSOR_QOS)
        n = len(batches)
        assert spin_until(executor, lambda: len(arrays) >= 10, timeout_s=10.0)
        assert node._published_patch_messages >= 10
        # 3. a TaxelArray and the batch of the same reading carry the same values
        spin_until(executor, lambda: len(batches) > n + 20, timeout_s=5.0)
        by_stamp = {}
        for b in batches:
            for i, name in enumerate(b.patches):
                if name == "palm":
                    a, c = b.offsets[i], b.offsets[i + 1]
                    by_stamp[b.stamps_ns[i]] = (b.taxel_ids[a:c], b.delta_c[a:c], b.status[a:c])
        matched = 0
        for m in arrays:
            key = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            if key in by_stamp:
                ids, dc, st = by_stamp[key]
                assert list(m.taxel_ids) == ids.tolist()
                assert list(m.delta_c) == dc.tolist()
                assert list(m.status) == st.tolist()
                matched += 1
        assert matched >= 5
    finally:
        stack.close()
        executor.shutdown()
        node.destroy_node()
        listener.destroy_node()


@pytest.mark.ros
def test_a_layout_on_several_buses_needs_the_bus_named(ros_context: object, tmp_path: Path) -> None:
    """One driver serves one bus: a layout with several is refused at configure unless its
    bus is named, and then it serves that bus's patches only."""
    from rclpy.parameter import Parameter

    from tactile_contact.ros.skin_driver import SkinDriver

    path = _two_bus_layout(tmp_path)
    assert load_layout(path).buses() == ("can0", "can1")

    def driver(**extra: object) -> Any:
        params = {"interface": "virtual", "channel": "two_buses", "layout": str(path), **extra}
        return SkinDriver(
            context=ros_context,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
        )

    refused = driver()
    assert not refused._links  # configure failed (logged: set its bus parameter)
    refused.destroy_node()
    served = driver(bus="can1")
    assert len(served._links) == 1 and list(served._pubs) == ["palm"]
    assert served._batch_bus == "can1"  # (its batches name their bus: workers filter on it)
    served.destroy_node()
    served = driver(buses=["can0"])  # one bus given as a list: named all the same
    assert len(served._links) == 1 and served._batch_bus == "can0"
    served.destroy_node()


@pytest.mark.ros
def test_one_driver_serves_several_buses_in_one_stream(ros_context: object, tmp_path: Path) -> None:
    """``buses``: one driver reads two buses (the same board address on both, at different
    phases of the period), each reading lands in one batch of the one taxel_batches stream,
    /diagnostics names each bus, and a bus that fails is reopened while the other goes on."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from tactile_contact.ros.common import DIAGNOSTICS_QOS
    from tactile_contact.sim.simulator import Indentation

    path = _two_bus_layout(tmp_path)
    layout = load_layout(path)
    channels = {"can0": "several_a", "can1": "several_b"}
    params = {"interface": "virtual", "layout": str(path), "buses": list(channels)}
    params |= {"channels": list(channels.values()), "period_ms": 20, "calibration_samples": 2}
    params |= {"batch_window_ms": 2.0, "reconnect_interval_s": 0.2, "diagnostics_period_s": 0.2}
    node, listener, batches = _driver_and_batches(ros_context, params, "several_listener")
    assert [link.name for link in node._links] == ["can0", "can1"]
    arrays: list[Any] = []
    listener.create_subscription(DiagnosticArray, "/diagnostics", arrays.append, DIAGNOSTICS_QOS)

    def latest() -> dict[str, dict[str, str]]:
        """The latest /diagnostics, name (without the node's) → key → value."""
        return {
            s.name.split(": ", 1)[1]: {kv.key: kv.value for kv in s.values}
            | {"_level": str(s.level[0])}
            for s in (arrays[-1].status if arrays else [])
        }

    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(listener)
    sims = {p.name: _simulator(p, k) for k, p in enumerate(layout.patches)}
    touch = {
        p.name: Indentation.press(None, 1.0, tuple(p.taxel_xy()[0]), start_s=0.2, ramp_s=0.1)
        for p in layout.patches
    }
    senders = {
        p.name: can.Bus(interface="virtual", channel=channels[p.bus]) for p in layout.patches
    }
    stop = threading.Event()

    def send(name: str, phase_s: float) -> None:
        k = 0
        t0 = time.monotonic() + phase_s
        while not stop.is_set():
            stop.wait(max(0.0, t0 + k * PERIOD_S - time.monotonic()))
            for m in sims[name].period(touch[name], k * PERIOD_S).messages:
                senders[name].send(m)
            k += 1

    threads = [
        threading.Thread(target=send, args=(name, 0.01 * k), daemon=True)
        for k, name in enumerate(sims)
    ]
    try:
        assert spin_until(
            executor, lambda: listener.count_publishers("taxel_batches") > 0, timeout_s=10.0
        )
        for t in threads:
            t.start()
        assert spin_until(executor, lambda: len(batches) >= 40, timeout_s=20.0)
        stamps: dict[str, list[int]] = {name: [] for name in sims}
        for b in batches:
            assert len(set(b.patches)) == len(b.patches)
            # the bus field names the buses of the batch's own patches, in the links' order
            on = {layout.patch(name).bus for name in b.patches}
            assert b.bus == ",".join(bus for bus in ("can0", "can1") if bus in on), b
            for name, stamp in zip(b.patches, b.stamps_ns, strict=True):
                stamps[name].append(stamp)
        for name, got in stamps.items():
            assert len(got) >= 15, f"{name}: {len(got)} readings in {len(batches)} batches"
            assert got == sorted(set(got)), f"{name}: a reading repeated or out of order"
        assert spin_until(executor, lambda: "CAN bus can1" in latest(), timeout_s=5.0)
        now_diag = latest()
        for bus, channel in channels.items():
            status = now_diag[f"CAN bus {bus}"]
            assert status["bus"] == f"virtual:{channel}" and status["_level"] == "0", status
            assert int(now_diag[f"frames {bus}"]["readings"]) > 0
        # the second bus fails: reported and reopened, the first bus's readings go on
        node._links[1].bus.shutdown()
        assert spin_until(
            executor,
            lambda: latest().get("CAN bus can1", {}).get("reconnects") == "1",
            timeout_s=5.0,
        ), latest().get("CAN bus can1")
        assert latest()["CAN bus can0"]["reconnects"] == "0"
        n = len(batches)
        assert spin_until(executor, lambda: len(batches) >= n + 20, timeout_s=5.0)
        assert {name for b in batches[n:] for name in b.patches} == set(sims)
        assert set(node.published()) == set(sims) and node.bus_opened
    finally:
        stop.set()
        for t in threads:
            if t.is_alive():
                t.join(2.0)
        executor.shutdown()
        node.destroy_node()
        listener.destroy_node()
        for bus in senders.values():
            bus.shutdown()


def test_a_stamp_a_message_cannot_carry_is_replaced_not_the_batch_lost() -> None:
    """A frame stamped past int32 seconds (a garbage CAN timestamp; any time after 2038)
    made write_taxel_batch raise after the batcher had taken the batch: every patch in it
    lost. Such a stamp becomes the host's clock; a negative one 0, as before."""
    import time

    from tactile_contact.ros.cdr import write_taxel_batch
    from tactile_contact.ros.skin_driver import _stamp_s

    assert _stamp_s(1.7e9) == 1.7e9 and _stamp_s(-3.0) == 0.0
    for bad in (2.0**31 + 5.0, float("inf"), float("nan"), 1e300):
        s = _stamp_s(bad)
        assert abs(s - time.time()) < 60.0
        ids = np.arange(2, dtype=np.uint16)
        write_taxel_batch(
            1, "", ["a"], ["f"], [round(s * 1e9)], [ids], [ids * 0.0], [b"\0\0"], [b"\0\0"]
        )
