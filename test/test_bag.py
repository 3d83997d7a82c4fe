"""rosbag2 recording and replay through rclpy with the rosbags library (real DDS, real files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from test.rosutil import spin_until

pytestmark = pytest.mark.ros


def _taxels(i: int) -> object:
    from tactile_contact.msg import TaxelArray

    msg = TaxelArray(
        patch="hexagon",
        taxel_ids=[0, 1, 2],
        delta_c=[1e-15 * i, -2e-16, 0.0],
        raw=[240, 239, 241],
        status=[0, 0, TaxelArray.STATUS_STUCK],
    )
    msg.header.frame_id = "skin_hexagon"
    msg.header.stamp.sec = 100 + i
    return msg


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_record_then_read_with_rosbags_then_replay(
    ros_context: object, tmp_path: Path, storage: str
) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.bag import BagPlayer, BagRecorder, read_messages

    bag = tmp_path / "bag"
    node = Node("bag_test", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(TaxelArray, "/hexagon/taxels", qos)
    recorder = BagRecorder(node, bag, {"/hexagon/taxels": TaxelArray}, storage=storage)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
    for i in range(10):
        pub.publish(_taxels(i))
        executor.spin_once(timeout_sec=0.01)
    assert spin_until(executor, lambda: recorder.counts["/hexagon/taxels"] == 10)
    recorder.close()

    stored = read_messages(bag)
    assert [m.header.stamp.sec for _, _, m in stored] == list(range(100, 110))
    assert np.allclose(stored[3][2].delta_c, np.float32([3e-15, -2e-16, 0.0]))
    assert list(stored[0][2].status) == [0, 0, TaxelArray.STATUS_STUCK]

    got: list[object] = []
    node.create_subscription(TaxelArray, "/replayed", got.append, qos)
    player = BagPlayer(node, bag, rate=0.0, remap={"/hexagon/taxels": "/replayed"})
    assert spin_until(
        executor, lambda: player.publishers["/hexagon/taxels"].get_subscription_count() > 0
    )
    assert player.play() == 10
    assert spin_until(executor, lambda: len(got) == 10)
    assert [m.header.stamp.sec for m in got] == list(range(100, 110))
    assert list(got[5].delta_c) == list(stored[5][2].delta_c)
    executor.shutdown()
    node.destroy_node()


def test_never_overwrites_a_bag(ros_context: object, tmp_path: Path) -> None:
    from rclpy.node import Node

    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.bag import BagError, BagRecorder

    (tmp_path / "bag").mkdir()
    node = Node("bag_test_2", context=ros_context)
    with pytest.raises(BagError, match="never overwritten"):
        BagRecorder(node, tmp_path / "bag", {"/t": TaxelArray})
    node.destroy_node()
