"""The driver process of bench_load: skin_driver fed by a frame sender thread on a python-can
virtual bus, until SIGINT.

Frames are precomputed (:func:`benchkit.skins.patch_frames`: the first K patches pressed, each
by its own sliding sphere, sweeps staggered) before timing. It prints ``READY {"sender_tid":
…}`` when the node is up, starts sending when a line comes on stdin (the parent's GO, once
every patch's taxel topic has its subscriber), stops sending on SIGUSR1, and prints ``RESULT
{…}`` (frames sent, the driver's counters) when it exits.

    python bench/load_driver.py LAYOUT N CHANNEL K BURST(0|1)
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
import threading
import time
from pathlib import Path

from benchkit.skins import PERIOD_MS, patch_frames


def driver_process(layout: Path, n: int, channel: str, pressed: int, burst: bool) -> None:
    """Run skin_driver with a frame sender until SIGINT; print READY and a final JSON line."""
    import can
    import rclpy
    from can.interfaces import virtual
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tactile_contact.ros.skin_driver import SkinDriver

    # 1 s unloaded then the sweep, cycled after; the patches' sweeps staggered by 0.17 s
    frames = patch_frames(layout, n, 5.0 + 4.0, pressed, stagger=0.17)
    rclpy.init()
    params = {
        "layout": str(layout),
        "interface": "virtual",
        "channel": channel,
        "period_ms": PERIOD_MS,
        "max_wait_ms": float(PERIOD_MS),
        "diagnostics_period_s": 1.0,
    }
    node = SkinDriver(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    stop = threading.Event()
    sent = [0]
    info: dict = {}

    # The load generator puts each frame straight into the receive queue of the driver's bus,
    # as the kernel does into a socket: VirtualBus.send deep-copies every frame for every
    # receiver, which at 14 400 frames/s cost the sender thread (and, through the GIL, the
    # driver sharing its process) a large share of a core. The frames are not modified by the
    # driver, so each precomputed one is reused every cycle with a new timestamp.
    receivers = [q for q in virtual.channels[channel] if q is not bus.queue]

    # Patch k's frames go out k/n of a period after patch 0's (``burst``: all at once). Why:
    # on a robot each patch's modules run on their own clocks, and the 14 400 frames/s of an
    # arm need several 1 Mbit/s buses (a frame takes 0.11-0.13 ms), so the patches' readings
    # arrive spread over the period; all 24 in the same instant is a worst case no bus makes,
    # and it queues the 24th patch behind 23 solves whatever their speed.
    slots = 1 if burst else n
    step = PERIOD_MS * 1e-3 / slots

    # Frames flow once the parent says GO (a line on stdin): when every patch's taxel topic
    # has its subscriber, so that none is lost to discovery and counted as dropped.
    go = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.readline(), go.set()), daemon=True).start()

    def send() -> None:
        info["sender_tid"] = threading.get_native_id()
        go.wait()
        t0 = time.monotonic()
        j = 0
        while not stop.wait(max(0.0, t0 + j * step - time.monotonic())):
            period, slot = divmod(j, slots)
            # after the first pass, skip the unloaded second: contact on every patch
            if period >= len(frames):
                period = 50 + (period - 50) % (len(frames) - 50)
            now = time.time()
            for patch in frames[period] if burst else [frames[period][slot]]:
                for msg in patch:
                    msg.timestamp = now  # stamped when sent, as a bus receive would be
                    for q in receivers:
                        q.put_nowait(msg)
                    sent[0] += 1
            j += 1

    sender = threading.Thread(target=send, name="sender", daemon=True)
    signal.signal(signal.SIGUSR1, lambda *_: stop.set())  # stop sending, keep the driver up
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    sender.start()
    time.sleep(0.1)
    print("READY " + json.dumps({"sender_tid": info["sender_tid"]}), flush=True)
    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        executor.spin()
    stop.set()
    sender.join(2.0)
    time.sleep(0.5)  # the driver drains what is queued
    stream = node._links[0].stream
    c = stream.assembler.counters
    result = {
        "sent": sent[0],
        "frames": c.frames,
        "readings": c.readings,
        "rejected": c.rejected,
        "incomplete": c.incomplete,
        "orphan_b": c.orphan_b,
        "published": sum(p.published for p in stream._patches),
        "stale_publications": sum(p.stale_publications for p in stream._patches),
    }
    node.destroy_node()
    bus.shutdown()
    rclpy.try_shutdown()
    print("RESULT " + json.dumps(result), flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 6:
        sys.exit("usage: python bench/load_driver.py LAYOUT N CHANNEL K BURST(0|1)")
    layout, n, channel, k, burst = sys.argv[1:6]
    driver_process(Path(layout), int(n), channel, int(k), burst == "1")
