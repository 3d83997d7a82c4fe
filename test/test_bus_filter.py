"""A worker takes only its own buses' batches (workers.bus_filter, issue 25).

Real DDS: two ContactReconstructionNodes, workers 0 and 1 of 2 over a two-bus version of
config/robot_skin.yaml (the forearm on bus ``arm``, the palm on ``hand``: the split keeps each
bus whole, so each worker serves one patch), and a publisher of TaxelBatch bytes in the same
process. The other bus's batches never reach a worker (its ``batches`` count, the batches it
read, leaves them out); its own, those naming no bus and those of a driver of both buses
(``arm,hand`` and ``hand,arm``) do, and every reading is summarised exactly once. What an
expression passes is decided by the middleware, so the strings are checked through Fast DDS
here; the pure rules (when there is no filter) below.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.ros.workers import bus_filter

ROOT = Path(__file__).resolve().parents[1]


def test_no_filter_when_every_bus_is_served_or_a_name_cannot_be_written() -> None:
    assert bus_filter({"a", "b"}, ["a", "b"]) is None
    assert bus_filter({"a"}, ["a"]) is None
    assert bus_filter(set(), ["a", "b"]) is None
    for odd in ("it's", "a,b", "a+b", ")(", "a b", "a%b"):
        assert bus_filter({odd}, [odd, "c"]) is None, odd
    assert bus_filter({"can_0", "robot/left-arm.1:x"}, ["can_0", "robot/left-arm.1:x", "c"])
    text = bus_filter({"b", "a"}, ["a", "b", "c"])
    assert text is not None and text.startswith("bus = '' OR bus = 'a' OR")
    assert "'b'" in text and "'c'" not in text


@pytest.fixture(scope="module")
def two_buses(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("bus_filter")
    spec = yaml.safe_load((ROOT / "config" / "robot_skin.yaml").read_text())
    for patch, bus in zip(spec["patches"], ("arm", "hand"), strict=True):
        patch["bus"] = bus
    layout = out / "two_buses.yaml"
    layout.write_text(yaml.safe_dump(spec))
    build_layout(layout, out / "bundles", jobs=2)
    return layout, out / "bundles"


def _batch(stamp: int, bus: str, patches: list) -> bytes:
    """One TaxelBatch of ``patches`` (layout patches) naming ``bus``, every reading zero."""
    from tactile_contact.model.modules import taxel_id
    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.cdr import write_taxel_batch

    ids = [
        np.array([taxel_id(m.board, m.triangle, c) for m in p.modules for c in range(12)], "u2")
        for p in patches
    ]
    return write_taxel_batch(
        stamp,
        bus,
        [p.name for p in patches],
        [p.frame_id for p in patches],
        [stamp] * len(patches),
        ids,
        [np.zeros(len(i), np.float32) for i in ids],
        [np.zeros(len(i), np.uint8) for i in ids],
        [np.where(p.valid_mask(), 0, TaxelArray.STATUS_DISABLED).astype(np.uint8) for p in patches],
    )


@pytest.mark.ros
def test_each_worker_reads_only_its_buses_batches(
    ros_context: object, two_buses: tuple[Path, Path]
) -> None:
    from rclpy.experimental import EventsExecutor

    from tactile_contact.model.layout import load_layout
    from tactile_contact.ros import contact_batches
    from test.rosutil import batch_probe, reconstruction_workers

    layout, bundles = two_buses
    forearm, palm = load_layout(layout).patches
    workers = reconstruction_workers(
        ros_context, 2, bundles_dir=str(bundles), layout=str(layout), input="batches"
    )
    other, pub, rows = batch_probe(ros_context, "bus_filter_probe")
    executor = EventsExecutor(context=ros_context)
    for node in (*workers, other):
        executor.add_node(node)
    try:
        # the split keeps each bus with one worker; each filters to its own
        assert [sorted(w.pipelines) for w in workers] == [["forearm"], ["palm"]]
        assert all(w.batches.sub.is_cft_enabled for w in workers)
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() < 2 or not all(w.link.serving for w in workers):
            assert time.monotonic() < deadline, "the workers did not come up"
            executor.spin_once(timeout_sec=0.1)
        while other.count_publishers(contact_batches.CONTACTS_TOPIC) < 2:
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.1)
        sent = {"arm": [forearm], "hand": [palm], "": [forearm, palm]}
        sent.update({"arm,hand": [forearm, palm], "hand,arm": [palm, forearm]})
        expected: list[tuple[str, int]] = []
        stamp = time.time_ns()
        for _ in range(5):
            for bus, patches in sent.items():
                stamp += 1_000_000
                pub.publish(_batch(stamp, bus, patches))
                expected += [(p.name, stamp) for p in patches]
                end = time.monotonic() + 0.02
                while time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.005)
        end = time.monotonic() + 30.0
        while not set(expected) <= set(rows) and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(20):  # (anything late)
            executor.spin_once(timeout_sec=0.01)
        assert sorted(rows) == sorted(expected)  # every reading once, by one worker
        # another bus's batches never reached a worker: 4 of the 5 kinds each, 5 times
        assert [w.batches.batches for w in workers] == [20, 20]
    finally:
        executor.shutdown()
        for node in (*workers, other):
            node.destroy_node()
