"""Regression against a recorded session: replaying the shipped bag's taxel arrays into a fresh
contact_reconstruction node reproduces the summaries recorded live.

The bag (test/data/hexagon_session, MCAP) was recorded with
``make test-data`` (``tactile-contact bringup --simulate --no-follow --record …``): simulator →
driver → reconstruction on the default patch, every frame solved on its own, topics taxels,
contact and contact_truth. If the reconstruction changes on purpose, re-record it with the
same command.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from test.rosutil import spin_until

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "test" / "data" / "hexagon_session"
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


def _stamp(header: object) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec  # type: ignore[attr-defined]


def test_shipped_bag_is_small_and_complete() -> None:
    from tactile_contact.ros.bag import read_messages

    size = sum(p.stat().st_size for p in BAG.rglob("*") if p.is_file())
    assert size < 400_000, f"shipped bag is {size} bytes"
    topics = {t for t, _, _ in read_messages(BAG)}
    assert topics == {"/hexagon/taxels", "/hexagon/contact", "/hexagon/contact_truth"}


def test_replay_reproduces_the_recorded_summaries(ros_context: object, tmp_path: Path) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.msg import ContactState
    from tactile_contact.offline.build import build_layout
    from tactile_contact.ros.bag import BagPlayer, read_messages
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    build_layout(LAYOUT, tmp_path)
    recorded = {_stamp(m.header): m for t, _, m in read_messages(BAG, ["/hexagon/contact"])}
    n_taxels = len(read_messages(BAG, ["/hexagon/taxels"]))
    assert len(recorded) >= 0.9 * n_taxels, "the live run summarised (almost) every frame"

    node = ContactReconstructionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(tmp_path)),
            Parameter("queue_depth", value=1000),  # a replay must process every frame
            # The shipped bag's summaries were recorded by a node that solved every frame on
            # its own (--no-follow); a following or fusing node's answers depend on the frames
            # before, and the live run skipped frames this replay solves.
            Parameter("follow_contacts", value=False),
            Parameter("fuse_frames", value=False),
        ],
    )
    probe = Node("replay_probe", context=ros_context)
    got: dict[int, ContactState] = {}
    probe.create_subscription(
        ContactState,
        "/hexagon/contact",
        lambda m: got.__setitem__(_stamp(m.header), m),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    player = BagPlayer(probe, BAG, topics=["/hexagon/taxels"], rate=3.0)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    # Both hops matched before the first frame goes out, or its summary is lost.
    assert spin_until(
        executor,
        lambda: (
            player.publishers["/hexagon/taxels"].get_subscription_count() > 0
            and node.pipelines["hexagon"].pub_contact.get_subscription_count() > 0
        ),
    )
    thread = threading.Thread(target=player.play, daemon=True)
    thread.start()
    assert spin_until(executor, lambda: not thread.is_alive(), timeout_s=60.0)
    # On a busy machine the node is far behind when the player ends (39 of 140 frames taken at
    # 3x), and the deep queue holds the rest: wait for a summary of every frame played, not
    # for as many as were recorded (the live run skipped 11 frames the replay does summarise,
    # so that count came 10 short), for as long as summaries keep coming.
    seen = -1
    while len(got) > seen and len(got) < player.published:
        seen = len(got)
        spin_until(executor, lambda: len(got) >= player.published, timeout_s=3.0)
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()

    common = sorted(set(got) & set(recorded))
    assert len(common) >= 0.95 * len(recorded), (len(common), len(recorded))
    # Worst disagreement of presses of 1 N and more, and of lighter ones (their fit leans more
    # on the learnt per-taxel weights).
    worst = {k: {"force": 0.0, "cop": 0.0, "area": 0.0, "peak": 0.0} for k in ("firm", "light")}

    # The node's per-taxel noise level, learnt from frames without contact, starts from the
    # frames each run saw first (the live run's began before the recording did); it sets the
    # detection threshold and the round fit's acceptance, so a frame at either edge may take
    # the other path or profile family (measured: 37 of 254 frames). At most 25 %
    # may; the others must agree.
    def path(m: ContactState) -> tuple:
        return (m.in_contact, m.solver, [k.profile for k in m.contacts])

    differ = [s for s in common if path(got[s]) != path(recorded[s])]
    assert len(differ) <= 0.25 * len(common), (len(differ), len(common))
    for stamp in common:
        a, b = got[stamp], recorded[stamp]
        if stamp in differ:
            continue
        assert [k.profile for k in a.contacts] == [k.profile for k in b.contacts], stamp
        # Same matrices, same inputs; the learnt noise level also weighs the fit: equal to
        # about 0.1 % at 1 N and more. Lighter presses read a count or two on a few taxels, and
        # the weights move their fit further (2026-11-26 recording: 1.3 % in force, 28 µm in
        # CoP and 9 % in peak pressure for a 0.65 N press).
        w = worst["firm" if b.total_force >= 1.0 else "light"]
        scale = max(abs(b.total_force), 1e-3)
        w["force"] = max(w["force"], abs(a.total_force - b.total_force) / scale)
        w["cop"] = max(
            w["cop"],
            np.hypot(
                a.center_of_pressure.x - b.center_of_pressure.x,
                a.center_of_pressure.y - b.center_of_pressure.y,
            ),
        )
        w["area"] = max(w["area"], abs(a.contact_area - b.contact_area))
        w["peak"] = max(
            w["peak"], abs(a.peak_pressure - b.peak_pressure) / max(b.peak_pressure, 1.0)
        )
    firm, light = worst["firm"], worst["light"]
    # The peak pressure follows the fitted radius, which the posterior over an 8-bit frame's
    # quantisation valley leaves loosely pinned: 9 % measured on a 1 N+ press whose force agreed
    # to 0.01 %.
    assert firm["force"] <= 5e-3 and firm["cop"] <= 2e-5 and firm["peak"] <= 0.15, worst
    assert light["force"] <= 3e-2 and light["cop"] <= 6e-5 and light["peak"] <= 0.2, worst
    # At most about half a 2 mm cell flips at the threshold.
    assert max(firm["area"], light["area"]) <= 2e-6, worst
