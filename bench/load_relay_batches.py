"""The floor of bench_load with batches: contact_reconstruction's ROS work (``input:
batches``) without its reconstruction.

It takes every ``taxel_batches`` message raw (TaxelBatch bytes, read with
tactile_contact.ros.cdr as the node reads them), makes for each patch of the batch it serves
the row the node makes (name, frame, stamp, state, force, centre of pressure; latency = now −
the reading's receive stamp), and publishes one ``contacts`` ContactArray per batch, written
as bytes, with the node's QoS and executor (rclpy's EventsExecutor, ``spin_until_shutdown``),
its heartbeat and its ``/diagnostics`` frame counts; it solves nothing. What bench_load
measures with it is the ROS work per patch-frame the batched node cannot go below.

    python bench/load_relay_batches.py patch00 patch01 …
"""

from __future__ import annotations

import sys
import time

import benchkit  # noqa: F401  (the package from this tree)
from load_relay import serve


def main(patches: list[str]) -> None:
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.msg import ContactArray, TaxelBatch
    from tactile_contact.ros.cdr import ContactRows, read_taxel_batch, write_contact_array
    from tactile_contact.ros.contact_batches import BATCH_DEPTH, BATCHES_TOPIC, CONTACTS_TOPIC
    from tactile_contact.ros.patch_pipeline import OUTPUT_QOS, QUIET_EVENTS
    from tactile_contact.ros.worker_link import WorkerLink

    rclpy.init()
    node = Node("contact_relay")
    frames = dict.fromkeys(patches, 0)
    mine = frozenset(patches)
    link = WorkerLink(node, patches, -1, 0, lambda: sum(frames.values()))
    pub = node.create_publisher(
        ContactArray, CONTACTS_TOPIC, OUTPUT_QOS, event_callbacks=QUIET_EVENTS
    )

    def on_batch(data: bytes) -> None:
        view = read_taxel_batch(data)
        rows = ContactRows()
        for i, name in enumerate(view.patches):
            if name not in mine:
                continue
            frames[name] += 1
            a, b = view.offsets[i], view.offsets[i + 1]
            _ = view.delta_c[a:b], view.status[a:b]  # (the node's slices of the arrays)
            rows.patches.append(name)
            rows.frame_ids.append(view.frame_ids[i])
            rows.stamps_ns.append(view.stamps_ns[i])
            rows.states.append(ContactArray.CONTACT)
            rows.total_force.append(0.0)
            rows.cop_x.append(0.0)
            rows.cop_y.append(0.0)
        if rows.patches:
            now = time.time_ns()
            rows.latency = [(now - s) * 1e-9 for s in rows.stamps_ns]
            pub.publish(write_contact_array(max(rows.stamps_ns), link.me.worker, rows))

    qos = QoSProfile(depth=BATCH_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
    node.create_subscription(TaxelBatch, BATCHES_TOPIC, on_batch, qos, raw=True)
    serve(node, frames)


if __name__ == "__main__":
    main(sys.argv[1:])
