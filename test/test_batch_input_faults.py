"""contact_reconstruction taking ``taxel_batches`` (``input: batches``, no worker) over real
DDS: stamps that jump and malformed batches.

A frame stamped far ahead (a bogus stamp) used to become the patch's newest, and every frame
after it was skipped as older, with no word, until the clock passed it (2038 here); a clock
stepped back by X s dropped X s of frames the same way. Now a frame more than CLOCK_STEP_NS
before the newest is a clock step: taken, counted, warned; only frames a little older (out of
a queue) are skipped, and counted. A node that is no worker reports its batches (bad ones,
clock steps) on /diagnostics too: it said them in its log only.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros]

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.fixture(scope="module")
def bundles(hexagon_bundle: tuple) -> Path:
    return Path(hexagon_bundle[0]).parent


def _batch(stamp: int, patch: object, counts: np.ndarray) -> bytes:
    """A TaxelBatch of one patch read as ``counts`` (whole counts, one a taxel)."""
    from tactile_contact.ros.cdr import write_taxel_batch

    ids = patch.taxel_ids().astype(np.uint16)
    farad = patch.sensor.farad_per_count * 2**patch.sensor.shift
    n = len(ids)
    return write_taxel_batch(
        stamp,
        "",
        [patch.name],
        [patch.frame_id],
        [stamp],
        [ids],
        [(counts * farad).astype(np.float32)],
        [np.zeros(n, np.uint8)],
        [np.zeros(n, np.uint8)],
    )


def test_a_bogus_stamp_or_a_clock_step_drops_nothing_after_it(
    ros_context: object, bundles: Path
) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import TaxelBatch
    from tactile_contact.ros import contact_batches
    from tactile_contact.ros.common import DIAGNOSTICS_QOS
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode
    from test.rosutil import batch_probe

    patch = load_layout(LAYOUT).patches[0]
    node = ContactReconstructionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(bundles)),
            Parameter("input", value="batches"),
            Parameter("diagnostics_period", value=0.1),
        ],
    )
    probe, pub, rows = batch_probe(ros_context, "batch_faults_probe")
    diags: list = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, DIAGNOSTICS_QOS)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    rng = np.random.default_rng(5)
    n = len(patch.taxel_ids())

    def send(stamp: int, expect: bool) -> None:
        """One batch; wait for its row (``expect``) or for the node to have taken it."""
        taken = node.batches.batches
        pub.publish(_batch(stamp, patch, rng.integers(-1, 2, n).astype(float)))
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if (patch.name, stamp) in rows if expect else node.batches.batches > taken:
                return
        raise AssertionError(f"batch stamped {stamp} not {'solved' if expect else 'taken'}")

    try:
        deadline = time.monotonic() + 30.0
        while pub.get_subscription_count() < 1 or probe.count_publishers("contacts") < 1:
            assert time.monotonic() < deadline, "the node did not come up"
            executor.spin_once(timeout_sec=0.1)
        now = time.time_ns()
        period = 20_000_000
        for j in range(3):
            send(now + j * period, expect=True)
        send((2**31 - 1) * 10**9, expect=True)  # a bogus stamp (2038)...
        for j in range(3, 6):  # ... and the frames after it are solved
            send(now + j * period, expect=True)
        assert node.batches.clock_steps == 1
        send(now + 5 * period - 3 * period, expect=False)  # older, out of a queue: skipped
        assert node.batches.stale_frames == 1
        assert (patch.name, now + 2 * period) in rows  # (the one solved before, not again)
        for j in range(3):  # a clock stepped back by 10 s: taken from the first frame on
            send(now - 10 * 10**9 + j * period, expect=True)
        assert node.batches.clock_steps == 2
        # A bag of 10 frames (0.2 s) played in a loop: its second pass is older than the
        # first by less than a second; after STALE_RUN of them in a row, a step, and the
        # rest of the pass taken (every frame after the first pass was skipped before).
        start = now + 60 * 10**9
        for j in range(10):
            send(start + j * period, expect=True)
        stale = node.batches.stale_frames
        for j in range(10):
            send(start + j * period, expect=j >= contact_batches.STALE_RUN)
        assert node.batches.stale_frames == stale + contact_batches.STALE_RUN
        assert node.batches.clock_steps == 3
        bad = bytearray(_batch(now + 6 * period, patch, np.zeros(n)))
        pub.publish(TaxelBatch())  # (no patches: fine, nothing to solve)
        pub.publish(bytes(bad[: len(bad) // 2]))  # truncated: a bad batch
        deadline = time.monotonic() + 10.0
        while node.batches.bad_batches < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert node.batches.bad_batches == 1
        diags.clear()

        def batches_status() -> object | None:
            for array in diags:
                for s in array.status:
                    if s.name == "contact_reconstruction: batches":
                        return s
            return None

        deadline = time.monotonic() + 10.0
        while batches_status() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        status = batches_status()
        assert status is not None, "no batches status on /diagnostics"
        values = {kv.key: kv.value for kv in status.values}
        assert status.level[0] == 1
        assert "last bad batch" in status.message and "clock step" in status.message
        assert values["clock_steps"] == "3"
        assert values["stale_frames"] == str(1 + contact_batches.STALE_RUN)
        assert values["bad_batches"] == "1"
    finally:
        executor.shutdown()
        probe.destroy_node()
        node.destroy_node()
