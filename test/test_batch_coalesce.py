"""A worker behind its input takes the batches already waiting in the same callback and
publishes their rows in one ContactArray (contact_batches.COALESCE_BUDGET_S, issue 25).

Real DDS: a real ContactReconstructionNode (``input: batches``) serving config/robot_skin.yaml
(a forearm and a palm), a publisher of TaxelBatch bytes and a listener of ``contacts`` in the
same process, spun by rclpy's EventsExecutor as run_node spins the node. The batches are
published while nothing spins, so they wait in the worker's queue as they do behind a busy
worker; then the executor runs. Every patch-frame arrives exactly once, in fewer
ContactArrays than batches, no ContactArray carries a patch twice (two frames of one patch
go out in two), and batches sent one at a time still go out one ContactArray each.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros]

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "robot_skin.yaml"


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("coalesce_bundles")
    build_layout(LAYOUT, out, jobs=2)
    return out


def _batch(stamp: int, patches: list, rng: np.random.Generator) -> bytes:
    """One TaxelBatch of ``patches`` (layout patches): 8-bit noise of ±1 count a reading."""
    from tactile_contact.model.modules import taxel_id
    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.cdr import write_taxel_batch

    ids, dc, status = [], [], []
    for patch in patches:
        ids.append(
            np.array(
                [taxel_id(m.board, m.triangle, c) for m in patch.modules for c in range(12)],
                np.uint16,
            )
        )
        farad = patch.sensor.farad_per_count * 2**patch.sensor.shift
        dc.append((rng.integers(-1, 2, len(ids[-1])) * farad).astype(np.float32))
        valid = patch.valid_mask()
        status.append(np.where(valid, 0, TaxelArray.STATUS_DISABLED).astype(np.uint8))
    return write_taxel_batch(
        stamp,
        "",
        [p.name for p in patches],
        [p.frame_id for p in patches],
        [stamp] * len(patches),
        ids,
        dc,
        [np.zeros(len(i), np.uint8) for i in ids],
        status,
    )


def test_waiting_batches_go_out_in_one_contact_array_each_frame_once(
    ros_context: object, bundles: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import ContactArray, TaxelBatch
    from tactile_contact.ros import contact_batches
    from tactile_contact.ros.cdr import read_contact_array
    from tactile_contact.ros.common import SENSOR_QOS
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    # (the first frames of a patch are solved on their own, milliseconds on a loaded
    # machine: the budget is lifted so that what waits is taken whatever the machine)
    monkeypatch.setattr(contact_batches, "COALESCE_BUDGET_S", 60.0)
    forearm, palm = load_layout(LAYOUT).patches
    node = ContactReconstructionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(bundles)),
            Parameter("layout", value=str(LAYOUT)),
            Parameter("input", value="batches"),
        ],
    )
    other = Node("coalesce_probe", context=ros_context)
    pub = other.create_publisher(TaxelBatch, contact_batches.BATCHES_TOPIC, SENSOR_QOS)
    arrays: list = []
    other.create_subscription(
        ContactArray,
        contact_batches.CONTACTS_TOPIC,
        lambda data: arrays.append(read_contact_array(data)[1]),
        QoSProfile(depth=64, reliability=ReliabilityPolicy.BEST_EFFORT),  # (none lost here)
        raw=True,
    )
    executor = EventsExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(other)
    rng = np.random.default_rng(3)
    try:
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() < 1 or not node.link.serving:
            assert time.monotonic() < deadline, "the worker did not come up"
            executor.spin_once(timeout_sec=0.1)
        while other.count_publishers(contact_batches.CONTACTS_TOPIC) < 1:
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.1)

        def run(sent: list[tuple[str, int]]) -> list:
            """Spin until every row of ``sent`` arrived (or 30 s); the arrays received."""
            arrays.clear()
            end = time.monotonic() + 30.0
            while sum(len(a.patches) for a in arrays) < len(sent) and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
            return list(arrays)

        # One at a time: one ContactArray a batch, as before.
        sent = []
        got = []
        for j in range(4):
            stamp = 2_000_000_000 + j * 20_000_000
            pub.publish(_batch(stamp, [forearm, palm], rng))
            sent += [(forearm.name, stamp), (palm.name, stamp)]
            got += run(sent[-2:])
        assert len(got) == 4 and node.batches.coalesced == 0
        # Six batches waiting (a bus each: the forearm's, the palm's, alternating), then
        # two more of both patches: taken in the callbacks of the first.
        sent = []
        for j in range(6):
            stamp = 3_000_000_000 + j * 10_000_000
            patch = (forearm, palm)[j % 2]
            pub.publish(_batch(stamp, [patch], rng))
            sent.append((patch.name, stamp))
        for j in range(2):
            stamp = 4_000_000_000 + j * 20_000_000
            pub.publish(_batch(stamp, [forearm, palm], rng))
            sent += [(forearm.name, stamp), (palm.name, stamp)]
        time.sleep(1.0)  # (delivered into the worker's queue, nothing spun)
        got = run(sent)
        rows = [(n, s) for a in got for n, s in zip(a.patches, a.stamps_ns, strict=True)]
        assert sorted(rows) == sorted(sent)  # every patch-frame exactly once
        assert all(len(set(a.patches)) == len(a.patches) for a in got)  # a patch once an array
        assert len(got) < 8 and node.batches.coalesced >= 4
        assert node.batches.values()["batches_coalesced"] == node.batches.coalesced
    finally:
        executor.shutdown()
        other.destroy_node()
        node.destroy_node()
