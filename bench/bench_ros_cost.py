"""Where a patch message's ROS work goes: the relays of bench_load taken apart, side by side.

bench_load's relay (bench/load_relay.py) is contact_reconstruction's ROS work without its
reconstruction: it takes every ``<patch>/taxels`` and publishes a ``<patch>/contact`` for it;
bench/load_relay_batches.py is the same for the batched node (``input: batches``: one
TaxelBatch in, one ContactArray out, per batch). Here each runs alone, fed by a light
publisher (no CAN, no driver: pre-built messages of 72-taxel patches, 24 patches at 50 Hz,
spread over the 20 ms period as in bench_load; for the batched relay, batches of k patches at
50·24/k Hz), with a probe subscribed to its output, and is measured:

- CPU per message taken, per thread of the relay (the executor's thread, which takes,
  converts, runs the callback and publishes; Fast DDS's receive threads);
- py-spy with native frames (``--native``, blocking: it stops the process at each sample) over
  the executor's thread, its samples sorted into what they were doing: taking a message
  (rmw take, CDR → C struct → Python message), the callback's Python (message construction,
  clock), publishing (Python message → C struct → CDR, the DataWriter), the executor's own
  work, the garbage collector;
- the same for each relay variant given (``--variants``), in the same run, side by side.

    python bench/bench_ros_cost.py [--seconds 20] [--patches 24] [--variants legacy ...]
                                   [--profile S] [--perf S] [--quick] [--out FILE]
"""

from __future__ import annotations

import argparse
import array
import collections
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from benchkit import ROOT

OUT = ROOT / "out" / "bench_ros_cost"
PERIOD_S = 0.02
TAXELS = 72

#: variant → (command line of the relay (patch names appended), patches per batch; 0: none)
VARIANTS = {
    "legacy": ([str(ROOT / "bench" / "load_relay.py")], 0),
    "batches-1": ([str(ROOT / "bench" / "load_relay_batches.py")], 1),
    "batches-3": ([str(ROOT / "bench" / "load_relay_batches.py")], 3),
    "batches-8": ([str(ROOT / "bench" / "load_relay_batches.py")], 8),
    "batches-24": ([str(ROOT / "bench" / "load_relay_batches.py")], 24),
}

#: native/Python frame name fragments → what the executor's thread was doing (first match wins)
CATEGORIES = (
    ("gc", ("gc_collect",)),
    (
        "publish",
        (
            "rmw_publish",
            "__rmw_publish",
            "convert_from_py",
            "publish (",
            "Publisher.publish",
            "DataWriter",
            "serialize",
        ),
    ),
    ("take", ("take", "convert_to_py", "deserialize")),
    ("callback", ("on_taxels", "relay", "ContactState", "Header", "Clock.now", "now")),
    ("wait", ("epoll", "wait", "poll", "sem_timedwait", "futex")),
)


# -- the publisher process ----------------------------------------------------------------------
def publisher_process(n: int, per_batch: int) -> None:
    """Publish n patches' readings at 50 Hz until SIGINT: as TaxelArray per patch, spread
    over the period (``per_batch`` 0), or as TaxelBatch messages of ``per_batch`` patches."""
    import rclpy
    from rclpy.node import Node

    from tactile_contact.msg import TaxelArray, TaxelBatch
    from tactile_contact.ros.cdr import write_taxel_batch
    from tactile_contact.ros.common import SENSOR_QOS, stamp_from_seconds

    rclpy.init()
    node = Node("cost_source")
    if per_batch:
        batch_pub = node.create_publisher(TaxelBatch, "taxel_batches", SENSOR_QOS)
        ids = np.arange(TAXELS, dtype=np.uint16)
        dc = np.full(TAXELS, 1e-14, np.float32)
        raw = np.full(TAXELS, 230, np.uint8)
        st = np.zeros(TAXELS, np.uint8)
        groups = [list(range(k, min(k + per_batch, n))) for k in range(0, n, per_batch)]
        print("READY", flush=True)
        sys.stdin.readline()  # GO
        t0 = time.monotonic()
        j = 0
        try:
            while rclpy.ok():
                delay = t0 + j * PERIOD_S / len(groups) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                g = groups[j % len(groups)]
                now = time.time_ns()
                batch_pub.publish(
                    write_taxel_batch(
                        now,
                        "",
                        [f"patch{k:02d}" for k in g],
                        [f"skin_patch{k:02d}" for k in g],
                        [now] * len(g),
                        [ids] * len(g),
                        [dc] * len(g),
                        [raw] * len(g),
                        [st] * len(g),
                    )
                )
                j += 1
        except KeyboardInterrupt:
            pass
        node.destroy_node()
        rclpy.try_shutdown()
        return
    pubs = [node.create_publisher(TaxelArray, f"patch{k:02d}/taxels", SENSOR_QOS) for k in range(n)]
    msgs = []
    for k in range(n):
        m = TaxelArray(patch=f"patch{k:02d}")
        m.header.frame_id = f"skin_patch{k:02d}"
        m.taxel_ids = array.array("H", range(TAXELS))
        m.delta_c = array.array("f", [1e-14] * TAXELS)
        m.raw = array.array("B", [230] * TAXELS)
        m.status = array.array("B", [0] * TAXELS)
        msgs.append(m)
    print("READY", flush=True)
    sys.stdin.readline()  # GO
    t0 = time.monotonic()
    j = 0
    try:
        while rclpy.ok():
            delay = t0 + j * PERIOD_S / n - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            k = j % n
            msgs[k].header.stamp = stamp_from_seconds(time.time())
            pubs[k].publish(msgs[k])
            j += 1
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()


# -- measuring ----------------------------------------------------------------------------------
def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds so far per thread name of ``pid`` (threads of one name summed)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, float] = collections.Counter()
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            comm = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
            fields = Path(f"/proc/{pid}/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        name = "executor" if tid == str(pid) else ("dds" if comm.startswith("dds.") else comm)
        out[name] += (int(fields[11]) + int(fields[12])) / tick
    return out


#: perf's on-CPU samples: what a sample inclusive of this symbol was doing (the first that
#: matches a frame of the stack, in this order); the rest is the executor, the callback's
#: Python and the kernel's scheduling.
PERF_PARTS = (
    ("Fast DDS receive thread", ("perform_listen_operation",)),
    ("take (rmw) + into Python objects", ("rcl_take", "convert_to_py")),
    (
        "publish (from Python objects, CDR, DataWriter, wake the reader)",
        ("rcl_publish", "convert_from_py"),
    ),
    ("garbage collector", ("gc_collect_main",)),
)


def perf_profile(pid: int, seconds: float, name: str) -> dict[str, float] | None:
    """perf's on-CPU samples of ``pid`` (every thread), the share of each PERF_PARTS (None
    where perf cannot sample: not installed or not permitted)."""
    perf = shutil.which("perf")
    if perf is None:
        return None
    data = OUT / f"{name}_perf.data"
    rec = subprocess.run(
        [
            perf,
            "record",
            "-e",
            "cpu-clock",
            "-F",
            "499",
            "-g",
            "--call-graph",
            "dwarf,16384",
            "-p",
            str(pid),
            "-o",
            str(data),
            "--",
            "sleep",
            str(seconds),
        ],
        capture_output=True,
        text=True,
    )
    if rec.returncode != 0:
        return None
    rep = subprocess.run(
        [perf, "script", "-i", str(data), "-F", "tid,ip,sym"],
        capture_output=True,
        text=True,
    )
    shares: collections.Counter[str] = collections.Counter()
    total = 0
    for sample in rep.stdout.split("\n\n"):
        lines = [line.strip() for line in sample.strip().splitlines()]
        if not lines:
            continue
        total += 1
        for part, keys in PERF_PARTS:
            if any(k in line for line in lines[1:] for k in keys):
                shares[part] += 1
                break
        else:
            shares["executor, callback Python, scheduling"] += 1
    return {k: v / total for k, v in shares.items()} if total else None


def native_profile(pid: int, seconds: float, name: str) -> tuple[collections.Counter, int]:
    """py-spy --native samples of the main thread → category → samples; and the total."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    out = OUT / f"{name}_native.txt"
    subprocess.run(
        [
            spy,
            "record",
            "-p",
            str(pid),
            "-d",
            str(int(seconds)),
            "-r",
            "100",
            "--native",
            "-f",
            "raw",
            "-o",
            str(out),
        ],
        check=True,
        capture_output=True,
    )
    cats: collections.Counter[str] = collections.Counter()
    total = 0
    for line in out.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = stack.split(";")
        n = int(count)
        if "MainThread" not in frames[0] and "main" not in stack[:200]:
            continue  # (only the executor's thread)
        total += n
        for cat, keys in CATEGORIES:
            if any(k in f for f in reversed(frames) for k in keys):
                cats[cat] += n
                break
        else:
            cats["executor / other"] += n
    return cats, total


def run_variant(name: str, n: int, seconds: float, profile_s: float, perf_s: float) -> dict:
    """One variant: publisher, relay and probe up; CPU per message; native profile."""
    import rclpy  # noqa: F401
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node

    from tactile_contact.msg import ContactArray, ContactState
    from tactile_contact.ros.cdr import read_contact_array
    from tactile_contact.ros.common import SENSOR_QOS

    command, per_batch = VARIANTS[name]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    names = [f"patch{k:02d}" for k in range(n)]
    relay = subprocess.Popen(
        [sys.executable, *command, *names],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    source = subprocess.Popen(
        [sys.executable, __file__, "--publisher-child", str(n), str(per_batch)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        env=env,
        text=True,
    )
    assert source.stdout is not None and source.stdin is not None
    assert source.stdout.readline().startswith("READY")
    probe = Node("cost_probe")
    got = collections.Counter()
    if per_batch:
        probe.create_subscription(
            ContactArray,
            "contacts",
            lambda data: got.update(read_contact_array(data)[1].patches),
            SENSOR_QOS,
            raw=True,
        )
        inputs = ["taxel_batches"]
    else:
        for p in names:
            probe.create_subscription(
                ContactState, f"{p}/contact", lambda m: got.update((m.patch,)), SENSOR_QOS
            )
        inputs = [f"{p}/taxels" for p in names]
    executor = EventsExecutor()
    executor.add_node(probe)
    deadline = time.monotonic() + 60
    while not all(probe.count_subscribers(t) for t in inputs):
        executor.spin_once(timeout_sec=0.1)
        assert time.monotonic() < deadline, "the relay did not subscribe in 60 s"
    for _ in range(10):
        executor.spin_once(timeout_sec=0.05)
    source.stdin.write("GO\n")
    source.stdin.flush()

    def spin(s: float) -> None:
        end = time.monotonic() + s
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)

    spin(3.0)
    c0, n0, w0 = thread_cpu(relay.pid), sum(got.values()), time.monotonic()
    spin(seconds)
    c1, n1, w1 = thread_cpu(relay.pid), sum(got.values()), time.monotonic()
    cats, total = native_profile(relay.pid, profile_s, name) if profile_s else ({}, 0)
    parts = perf_profile(relay.pid, perf_s, name) if perf_s else None
    for proc in (source, relay):
        proc.send_signal(signal.SIGINT)
    for proc in (source, relay):
        proc.wait(timeout=30)
    executor.shutdown()
    probe.destroy_node()
    messages = n1 - n0
    cpu = {k: c1[k] - c0.get(k, 0.0) for k in c1}
    return {
        "messages": messages,  # (patch-frames: each patch's summary counted once)
        "rate": messages / (w1 - w0),
        "per_message_us": {k: v / messages * 1e6 for k, v in cpu.items() if v > 0},
        "share": {k: v / total for k, v in cats.items()} if total else {},
        "samples": total,
        "perf": parts,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--profile", type=float, default=0.0, help="py-spy --native for S s")
    ap.add_argument("--perf", type=float, default=8.0, help="perf record (on-CPU) for S s")
    ap.add_argument("--out", type=Path, help="also write what is printed to this file")
    ap.add_argument("--patches", type=int, default=24)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument(
        "--quick", action="store_true", help="3 s a variant, perf 2 s, legacy and batches-3"
    )
    ap.add_argument("--publisher-child", type=int, nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.publisher_child:
        publisher_process(*args.publisher_child)
        return 0
    if args.quick:
        args.seconds, args.perf, args.profile = 3.0, 2.0, 0.0
        args.variants = [v for v in args.variants if v in ("legacy", "batches-3")]
    import rclpy

    OUT.mkdir(parents=True, exist_ok=True)
    rclpy.init()
    lines: list[str] = []

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    say(f"load average before: {os.getloadavg()[0]:.2f}")
    figures = {}
    for name in args.variants:
        r = run_variant(name, args.patches, args.seconds, args.profile, args.perf)
        per = r["per_message_us"]
        total = sum(per.values())
        figures[name] = total
        say(
            f"{name}: {r['rate']:.0f} patch-frames/s relayed; CPU per patch-frame "
            f"{total:.0f} µs = "
            + " + ".join(f"{k} {v:.0f}" for k, v in sorted(per.items(), key=lambda x: -x[1]))
        )
        if r["perf"]:
            say(
                "  on CPU (perf): "
                + "; ".join(
                    f"{k} {v:.0%} ({v * total:.0f} µs)"
                    for k, v in sorted(r["perf"].items(), key=lambda x: -x[1])
                )
            )
        if r["samples"]:
            say(
                f"  executor thread ({r['samples']} py-spy samples): "
                + ", ".join(
                    f"{k} {v:.0%}" for k, v in sorted(r["share"].items(), key=lambda x: -x[1])
                )
            )
    if "legacy" in figures:
        base = figures["legacy"]
        say(
            "against legacy (same run): "
            + ", ".join(f"{k} ×{v / base:.2f}" for k, v in figures.items() if k != "legacy")
        )
    say(f"load average after: {os.getloadavg()[0]:.2f}")
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
