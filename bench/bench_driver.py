"""CPU of the skin_driver node at 16 triangles × 100 Hz against python-can receiving alone.

Live, on a python-can ``virtual`` bus fed at 16 triangles × 2 frames × 100 Hz = 3200 frames/s
by a sender thread in the same process: (a) baseline: a thread doing nothing but
``bus.recv()``; (b) the real ``skin_driver`` node (receive thread + executor) publishing
``<patch>/taxels``. For each: CPU share of the whole process (process CPU time / wall time)
and of the receiving thread alone (from /proc/self/task/<tid>/stat), and their ratios b/a.
The node must publish at the frame rate. The decode cost per frame without a bus (codec,
SkinStream) is bench/bench_codec.py's.

    python bench/bench_driver.py [--seconds S]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import can
import numpy as np
import yaml

from tactile_contact.canbus import codec

N_TRIANGLES = 16
RATE_HZ = 100.0
CHANNEL = "bench-driver"


def layout_file(directory: Path) -> Path:
    """A patch of 16 roboskin12 triangles on board 0 (a 4 × 4 block, 40 mm apart)."""
    modules = [
        {
            "type": "roboskin12",
            "board": 0,
            "triangle": k,
            "position": [0.04 * (k % 4), 0.04 * (k // 4)],
        }
        for k in range(N_TRIANGLES)
    ]
    doc = {
        "schema_version": 1,
        "patches": [{"name": "bench", "frame_id": "skin_bench", "modules": modules}],
    }
    path = directory / "bench_layout.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def period_frames(k: int, rng: np.random.Generator, t0: float) -> list[can.Message]:
    """The 32 frames of period k (values around the 240 no-load value)."""
    out = []
    for tri in range(N_TRIANGLES):
        values = (240 - rng.integers(0, 3, 12)).astype(np.uint8).tobytes()
        out += codec.reading_messages(0, tri, values, timestamp=t0 + k / RATE_HZ)
    return out


def thread_cpu_s(tid: int) -> float:
    """utime + stime [s] of one thread of this process (Linux /proc)."""
    fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Sender:
    """Writes 16 triangles × 100 Hz onto the virtual channel until stopped."""

    def __init__(self) -> None:
        self.bus = can.Bus(interface="virtual", channel=CHANNEL)
        self.stop = threading.Event()
        self.sent = 0
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        rng = np.random.default_rng(1)
        t0 = time.monotonic()
        k = 0
        while not self.stop.is_set():
            for m in period_frames(k, rng, 0.0):
                self.bus.send(m)
            self.sent += 1
            k += 1
            self.stop.wait(max(0.0, t0 + k / RATE_HZ - time.monotonic()))

    def __enter__(self) -> Sender:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()
        self.bus.shutdown()


def measure(seconds: float, rx_tid: int) -> tuple[float, float]:
    """(process CPU share, receiving-thread CPU share) over ``seconds`` of wall time."""
    w0, p0, t0 = time.monotonic(), time.process_time(), thread_cpu_s(rx_tid)
    time.sleep(seconds)
    wall = time.monotonic() - w0
    return (time.process_time() - p0) / wall, (thread_cpu_s(rx_tid) - t0) / wall


def python_can_alone(seconds: float) -> dict[str, float]:
    rx = can.Bus(interface="virtual", channel=CHANNEL)
    count = 0
    stop = threading.Event()

    def loop() -> None:
        nonlocal count
        while not stop.is_set():
            if rx.recv(0.02) is not None:
                count += 1

    th = threading.Thread(target=loop, daemon=True)
    with Sender():
        th.start()
        time.sleep(0.5)  # settle
        n0 = count
        proc, thread = measure(seconds, th.native_id)
        frames = count - n0
    stop.set()
    th.join()
    rx.shutdown()
    return {"proc": proc, "thread": thread, "rate": frames / seconds}


def driver_node(seconds: float, path: Path) -> dict[str, float]:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tactile_contact.ros.skin_driver import SkinDriver

    ctx = Context()
    rclpy.init(context=ctx)
    params = {
        "interface": "virtual",
        "channel": CHANNEL,
        "layout": str(path),
        "period_ms": 10,
        "max_wait_ms": 10.0,
        "pair_window_ms": 4.0,  # (below the 10 ms period: SkinStream refuses one as long)
    }
    node = SkinDriver(
        context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
    )
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    try:
        with Sender():
            time.sleep(0.5)
            p0 = node._links[0].stream._patches[0].published
            proc, thread = measure(seconds, node._links[0].thread.native_id)
            published = node._links[0].stream._patches[0].published - p0
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return {"proc": proc, "thread": thread, "rate": published / seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="measurement time per case [s]")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = layout_file(Path(tmp))
        alone = python_can_alone(args.seconds)
        node = driver_node(args.seconds, path)
    frames_per_s = N_TRIANGLES * 2 * RATE_HZ
    print(f"16 triangles x {RATE_HZ:.0f} Hz = {frames_per_s:.0f} frames/s, {os.cpu_count()} cores")
    print("\nlive on a virtual bus      process CPU   rx-thread CPU   output rate")
    for label, r, unit in (
        ("python-can recv alone", alone, "frames/s"),
        ("skin_driver node     ", node, f"msgs/s (expect {RATE_HZ:.0f})"),
    ):
        print(
            f"  {label}      {100 * r['proc']:6.1f} %     {100 * r['thread']:6.1f} %"
            f"      {r['rate']:7.1f} {unit}"
        )
    print(
        f"  ratio node / python-can    {node['proc'] / alone['proc']:6.2f} x    "
        f"{node['thread'] / max(alone['thread'], 1e-9):6.2f} x"
    )
    print("(process CPU includes the sender thread that generates the frames in both cases)")


if __name__ == "__main__":
    main()
