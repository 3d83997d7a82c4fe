"""End-to-end latency and CPU share of driver + reconstruction for 1, 6 and 24 patches at
50 Hz, against rclpy publishing the same messages alone.

Each patch is a copy of the default hexagon (6 triangles, its own CAN addresses). One patch is
pressed by a sliding 12 mm sphere, the others are idle, as on a robot where one contact touches
a large skin. In one process and one run, side by side:

- ``publish only``: rclpy publishing the same messages (a TaxelArray and a ContactState per
  patch per period) with no computation, to a subscriber — the floor of any ROS pipeline;
- ``frames in``: sending precomputed module frames of every patch on a virtual CAN bus at
  50 Hz (the load generator; the physics is simulated before timing);
- ``pipeline``: simulators → skin_driver → contact_reconstruction → a summary subscriber.

Latency is CAN receive → ContactState published (the node's ``latency`` field: the stamp is
the receive time of the frame completing the reading). CPU share is process CPU time over wall
time (100 % = one core); pipeline minus frames-in is what the driver and reconstruction cost.

    python bench/bench_pipeline.py [--quick] [--seconds S]
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import threading
import time
from pathlib import Path

import can
import numpy as np
from benchkit.skins import PERIOD_MS, multi_patch_layout, patch_frames
from benchkit.timing import cpu_share


def precompute_frames(layout: Path, n: int, seconds: float) -> list[list[can.Message]]:
    """Module frames of every patch per period (all patches' frames in one list): patch 0
    pressed by a sliding 12 mm sphere, the others idle."""
    periods = patch_frames(layout, n, seconds, pressed=1)
    return [list(itertools.chain.from_iterable(p)) for p in periods]


class FrameSender:
    """Sends precomputed periods on a virtual bus at 50 Hz, stamped when sent (like a bus)."""

    def __init__(self, frames: list[list[can.Message]], channel: str) -> None:
        self.frames = frames
        self.bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0 = time.monotonic()
        for j, period in enumerate(itertools.cycle(self.frames)):
            if self._stop.wait(max(0.0, t0 + j * PERIOD_MS * 1e-3 - time.monotonic())):
                return
            now = time.time()
            for msg in period:
                msg.timestamp = now
                self.bus.send(msg)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.bus.shutdown()


def spin_for(executor: object, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)  # type: ignore[attr-defined]


def run_publish_only(n: int, seconds: float) -> float:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from tactile_contact.msg import ContactState, TaxelArray
    from tactile_contact.ros.common import SENSOR_QOS

    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("publish_only", context=ctx)
    sink = Node("sink", context=ctx)
    pubs = []
    for k in range(n):
        pubs.append(
            (
                node.create_publisher(TaxelArray, f"patch{k:02d}/taxels", SENSOR_QOS),
                node.create_publisher(ContactState, f"patch{k:02d}/contact", SENSOR_QOS),
            )
        )
        sink.create_subscription(ContactState, f"patch{k:02d}/contact", lambda m: None, SENSOR_QOS)
    taxels = TaxelArray(
        patch="p", taxel_ids=list(range(72)), delta_c=[1e-15] * 72, raw=[240] * 72, status=[0] * 72
    )
    contact = ContactState(patch="p", total_force=1.0)

    def tick() -> None:
        for pt, pc in pubs:
            pt.publish(taxels)
            pc.publish(contact)

    node.create_timer(PERIOD_MS * 1e-3, tick)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(sink)
    spin_for(ex, 0.5)
    share = cpu_share(lambda s: spin_for(ex, s), seconds)
    ex.shutdown()
    rclpy.try_shutdown(context=ctx)
    return share


def run_graph(
    n: int, layout: Path, bundles: Path, frames: list, seconds: float, full: bool
) -> dict:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from tactile_contact.msg import ContactState
    from tactile_contact.ros.common import SENSOR_QOS
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode
    from tactile_contact.ros.skin_driver import SkinDriver

    ctx = Context()
    rclpy.init(context=ctx)
    channel = f"bench_{time.monotonic_ns()}"
    nodes: list = []
    sender = FrameSender(frames, channel)
    latencies: list[float] = []
    if full:
        nodes.append(
            SkinDriver(
                context=ctx,
                parameter_overrides=[
                    Parameter("layout", value=str(layout)),
                    Parameter("interface", value="virtual"),
                    Parameter("channel", value=channel),
                    Parameter("period_ms", value=PERIOD_MS),
                    Parameter("max_wait_ms", value=float(PERIOD_MS)),
                ],
            )
        )
        nodes.append(
            ContactReconstructionNode(
                context=ctx, parameter_overrides=[Parameter("bundles_dir", value=str(bundles))]
            )
        )
        sink = Node("sink", context=ctx)
        for k in range(n):
            sink.create_subscription(
                ContactState,
                f"patch{k:02d}/contact",
                lambda m: latencies.append(m.latency) if m.in_contact else None,
                SENSOR_QOS,
            )
        nodes.append(sink)
    ex = SingleThreadedExecutor(context=ctx)
    for node in nodes:
        ex.add_node(node)
    sender.start()
    spin_for(ex, 1.5)  # calibration, start-up
    latencies.clear()
    share = cpu_share(lambda s: spin_for(ex, s), seconds)
    out = {"cpu": share}
    if full:
        recon = nodes[-2]
        frames = sum(p.stats.frames for p in recon.pipelines.values())
        solved = sum(p.stats.solved for p in recon.pipelines.values())
        out |= {"latency": np.asarray(latencies), "frames": frames, "solved": solved}
    sender.stop()
    ex.shutdown()
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 and 6 patches, 3 s each")
    ap.add_argument("--seconds", type=float, default=6.0)
    args = ap.parse_args()
    from tactile_contact.offline.build import build_layout

    counts = (1, 6) if args.quick else (1, 6, 24)
    seconds = 3.0 if args.quick else args.seconds
    tmp = Path(tempfile.mkdtemp(prefix="bench_pipeline_"))
    print(f"{PERIOD_MS} ms period (50 Hz), one patch pressed by a sliding sphere, the rest idle")
    header = (
        f"{'patches':>7} | {'publish only':>12} | {'frames in':>9} | {'pipeline':>8} | "
        f"{'driver+recon':>12} | {'ratio':>6} | {'latency med ms':>14} | {'p99 ms':>7} | frames"
    )
    print(header)
    for n in counts:
        layout = multi_patch_layout(n, tmp)
        bundles = tmp / f"bundles_{n}"
        build_layout(layout, bundles, jobs=2)
        pub = run_publish_only(n, seconds)
        frames = precompute_frames(layout, n, 6.0)
        sim = run_graph(n, layout, bundles, frames, seconds, full=False)["cpu"]
        full = run_graph(n, layout, bundles, frames, seconds, full=True)
        own = full["cpu"] - sim
        lat = full["latency"] * 1e3
        med = np.median(lat) if lat.size else float("nan")
        p99 = np.percentile(lat, 99) if lat.size else float("nan")
        print(
            f"{n:7d} | {pub * 100:11.1f}% | {sim * 100:8.1f}% | {full['cpu'] * 100:7.1f}% | "
            f"{own * 100:11.1f}% | {own / max(pub, 1e-9):6.1f} | {med:14.2f} | {p99:7.2f} | "
            f"{full['frames']} ({full['solved']} solved)"
        )


if __name__ == "__main__":
    main()
