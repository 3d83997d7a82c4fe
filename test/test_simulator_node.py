"""The real ``skin_simulator`` node: frames on a virtual bus, truth on ``<patch>/contact_truth``."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

pytestmark = pytest.mark.ros

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"


def make_node(ctx: Any, channel: str, **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from tactile_contact.ros.skin_simulator import SkinSimulatorNode

    values = {"layout": str(LAYOUT), "interface": "virtual", "channel": channel, **params}
    return SkinSimulatorNode(
        context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]
    )


def test_frames_and_truth_follow_the_scenario(ros_context: Any) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.canbus.assembler import PeriodAssembler
    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import ContactState
    from test.rosutil import spin_until

    rx = can.Bus(interface="virtual", channel="sim-node-1")
    listener = Node("listener", context=ros_context)
    truths: list[Any] = []
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
    listener.create_subscription(ContactState, "hexagon/contact_truth", truths.append, qos)
    node = make_node(
        ros_context,
        "sim-node-1",
        scenario="press",
        period_ms=20,
        cycle_s=2.0,
        force_n=3.0,
        start_delay_s=0.2,
    )
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(listener)
    frames: list[can.Message] = []
    try:
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            executor.spin_once(timeout_sec=0.01)
            while (m := rx.recv(0.0)) is not None:
                frames.append(m)
        assert spin_until(executor, lambda: len(truths) >= 60, 3.0)
    finally:
        executor.shutdown()
        node.destroy_node()
        listener.destroy_node()
        while (m := rx.recv(0.0)) is not None:  # frames sent while waiting for the truth
            frames.append(m)
        rx.shutdown()
    readings = PeriodAssembler().feed_many(frames)
    assert len(readings) >= 6 * 60
    assert {r.key for r in readings} == {(0, t) for t in range(6)}
    period_ends = np.array(sorted(r.timestamp for r in readings))
    patch = load_layout(LAYOUT).patch("hexagon")
    xy = patch.taxel_xy()
    center = xy[np.argmin(np.linalg.norm(xy - (xy.min(axis=0) + xy.max(axis=0)) / 2, axis=1))]
    forces = [t.total_force for t in truths]
    assert forces[:10] == [0.0] * 10 and max(forces) == pytest.approx(3.0)
    for t in truths:
        assert t.header.frame_id == "skin_hexagon" and t.patch == "hexagon"
        stamp = t.header.stamp.sec + t.header.stamp.nanosec * 1e-9
        gap = np.min(np.abs(period_ends - stamp))
        assert gap < 1e-6, "truth is stamped like the frame completing its period"
        if t.total_force > 0:
            assert t.in_contact and t.contact_area > 0
            assert (t.center_of_pressure.x, t.center_of_pressure.y) == pytest.approx(tuple(center))
            (k,) = t.contacts
            assert k.force == t.total_force and k.profile == "hertz"
            assert math.pi * k.radius**2 == pytest.approx(t.contact_area)
        else:
            assert not t.contacts


def test_bad_scenario_is_rejected(ros_context: Any) -> None:
    from rclpy.exceptions import InvalidParameterValueException

    with pytest.raises(InvalidParameterValueException, match="scenario"):
        make_node(ros_context, "sim-node-2", scenario="dance")


def test_driver_reads_the_simulator_and_stamps_match_the_truth(ros_context: Any) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import ContactState, TaxelArray
    from tactile_contact.ros.skin_driver import SkinDriver
    from test.rosutil import spin_until

    listener = Node("listener", context=ros_context)
    taxels: list[Any] = []
    truths: list[Any] = []
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
    listener.create_subscription(TaxelArray, "hexagon/taxels", taxels.append, qos)
    listener.create_subscription(ContactState, "hexagon/contact_truth", truths.append, qos)
    params = {"layout": str(LAYOUT), "interface": "virtual", "channel": "sim-node-3"}
    driver = SkinDriver(
        context=ros_context,
        parameter_overrides=[Parameter(k, value=v) for k, v in {**params, "period_ms": 20}.items()],
    )
    sim = make_node(
        ros_context,
        "sim-node-3",
        scenario="press",
        period_ms=20,
        cycle_s=2.0,
        start_delay_s=0.5,
        noise_cdc=1.0,
    )
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (listener, driver, sim):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: len(taxels) >= 60 and len(truths) >= 60, 5.0)
    finally:
        executor.shutdown()
        for n in (sim, driver, listener):
            n.destroy_node()

    def key(m: Any) -> int:
        return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec

    truth_stamps = {key(t) for t in truths}
    matched = [m for m in taxels if key(m) in truth_stamps]
    assert len(matched) >= 0.9 * min(len(taxels), len(truths)), "one taxel message per period"
    assert all(m.header.frame_id == t.header.frame_id for m in taxels[:1] for t in truths[:1])
    # calibrated during the start delay, the press then shows on the pressed taxel (≈ 50 counts
    # at 2 N with this layout; 10 is far above noise and quantisation)
    se = load_layout(LAYOUT).patch("hexagon").sensor
    quantum = se.farad_per_count * 2**se.shift
    pressed = [max(m.delta_c) for m in taxels if not any(s & 128 for s in m.status)]
    assert max(pressed) > 10 * quantum
