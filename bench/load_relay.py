"""The floor of bench_load: contact_reconstruction's ROS work without its reconstruction.

For each patch it takes every ``<patch>/taxels`` message and publishes a ``<patch>/contact``
ContactState stamped like the node's (latency = now − the frame's receive stamp), with the
same QoS, the same executor (rclpy's EventsExecutor, spun by ``spin_until_shutdown``) and the
same ``/diagnostics`` frame counts; it solves nothing. What bench_load measures with it is
the cost of taking and publishing 24 × 50 messages a second over DDS on this machine, the
part of a frame no reconstruction code can remove.

    python bench/load_relay.py patch00 patch01 …
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import benchkit  # noqa: F401  (the package from this tree)


def main(patches: list[str]) -> None:
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.msg import ContactState, TaxelArray
    from tactile_contact.ros.common import seconds_from_stamp
    from tactile_contact.ros.contact_reconstruction import OUTPUT_QOS, QUIET_EVENTS
    from tactile_contact.ros.topics import patch_topic

    rclpy.init()
    node = Node("contact_relay")
    frames = dict.fromkeys(patches, 0)
    clock = node.get_clock()

    def relay(name: str, pub: Any) -> Callable[[TaxelArray], None]:
        def on_taxels(msg: TaxelArray) -> None:
            frames[name] += 1
            now = clock.now().nanoseconds * 1e-9
            out = ContactState(header=msg.header, patch=name, in_contact=True, solver="relay")
            out.latency = now - seconds_from_stamp(msg.header.stamp)
            pub.publish(out)

        return on_taxels

    # the node's QoS (its default queue_depth 1: only the newest frame waits)
    input_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
    for name in patches:
        pub = node.create_publisher(
            ContactState, patch_topic(name, "contact"), OUTPUT_QOS, event_callbacks=QUIET_EVENTS
        )
        node.create_subscription(
            TaxelArray, patch_topic(name, "taxels"), relay(name, pub), input_qos
        )
    serve(node, frames)


def serve(node: Any, frames: dict[str, int]) -> None:
    """Report each patch's frame count on /diagnostics every second (as the reconstruction
    does, so the bench reads both alike) and spin ``node`` until shutdown, then clean up.
    Shared with load_relay_batches.py."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor

    from tactile_contact.ros.common import spin_until_shutdown

    diag = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
    clock = node.get_clock()

    def report() -> None:
        msg = DiagnosticArray()
        msg.header.stamp = clock.now().to_msg()
        msg.status = [
            DiagnosticStatus(
                name=f"contact_reconstruction: {name}",
                values=[KeyValue(key="frames", value=str(n))],
            )
            for name, n in frames.items()
        ]
        diag.publish(msg)

    node.create_timer(1.0, report)
    executor = EventsExecutor()
    executor.add_node(node)
    try:
        spin_until_shutdown(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1:])
