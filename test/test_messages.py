"""The package's own messages build, import and travel over real DDS."""

from __future__ import annotations

import math

import pytest

pytestmark = pytest.mark.ros


def _examples() -> list[object]:
    from geometry_msgs.msg import Point

    from tactile_contact.msg import Contact, ContactState, GridGeometry, TaxelArray

    taxels = TaxelArray(
        patch="hexagon",
        taxel_ids=[0, 1, 0x10B],
        delta_c=[1e-15, -2.5e-16, 0.0],
        raw=[240, 241, 255],
        status=[0, 0, TaxelArray.STATUS_SATURATED],
    )
    taxels.header.frame_id = "skin_hexagon"
    taxels.header.stamp.sec = 12
    contact = ContactState(
        patch="hexagon",
        in_contact=True,
        total_force=1.25,
        center_of_pressure=Point(x=0.01, y=-0.02, z=0.0),
        contact_area=3.0e-5,
        peak_pressure=4.2e4,
        solver="nnls",
        solver_success=True,
        solver_iterations=7,
        residual_norm=1e-6,
        solve_time=2e-4,
        latency=1e-3,
        taxels_used=72,
        taxels_active=9,
        contacts=[
            Contact(force=0.75, center=Point(x=0.0, y=-0.02, z=0.0), radius=2e-3, profile="hertz"),
            Contact(force=0.5, center=Point(x=0.025, y=-0.02, z=0.0), radius=1e-3, profile="punch"),
        ],
    )
    grid = GridGeometry(
        patch="hexagon",
        grid="traction",
        origin_x=-0.01,
        origin_y=-0.04,
        cell_size_x=0.002,
        cell_size_y=0.002,
        width=3,
        height=2,
        mask=[1, 1, 0, 1, 1, 1],
    )
    return [taxels, contact, grid]


def test_status_flags_are_distinct_bits() -> None:
    from tactile_contact.msg import TaxelArray

    flags = [getattr(TaxelArray, n) for n in dir(TaxelArray) if n.startswith("STATUS_")]
    nonzero = [f for f in flags if f]
    assert len(nonzero) == 8
    assert all(f & (f - 1) == 0 for f in nonzero), "each flag is one bit"
    assert len(set(nonzero)) == len(nonzero)


@pytest.mark.parametrize("index", [0, 1, 2], ids=["TaxelArray", "ContactState", "GridGeometry"])
def test_publish_and_receive_each_message(ros_context: object, index: int) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from test.rosutil import spin_until

    sent = _examples()[index]
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    talker = Node("talker", context=ros_context)
    listener = Node("listener", context=ros_context)
    received: list[object] = []
    listener.create_subscription(type(sent), "probe", received.append, qos)
    pub = talker.create_publisher(type(sent), "probe", qos)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(talker)
    executor.add_node(listener)
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 10.0)
        pub.publish(sent)
        assert spin_until(executor, lambda: bool(received), 10.0), "no message arrived"
    finally:
        executor.shutdown()
        talker.destroy_node()
        listener.destroy_node()
    got = received[0]
    for field in type(sent).get_fields_and_field_types():
        a, b = getattr(sent, field), getattr(got, field)
        if isinstance(a, float):
            assert math.isclose(a, b, rel_tol=0, abs_tol=0), field
        elif isinstance(a, list) and a and not isinstance(a[0], int | float):
            assert a == list(b), field  # nested messages compare field by field
        elif hasattr(a, "tolist") or isinstance(a, list):
            assert list(a) == pytest.approx(list(b), rel=1e-7), field  # float32 arrays
        else:
            assert a == b, field
