"""Reconstruction workers under load: CPU per patch-frame by kind (idle, held, sliding) beside
the batched relay's, throughput at saturation with 1 and 2 workers, memory per worker.

No CAN and no driver here (bench_load measures the whole chain): a source process publishes
the TaxelBatch messages a driver would, made before timing from the skin simulator's readings
(8-bit module values with 0.6 CDC counts of noise; ΔC as the driver computes it, from a
baseline that is the mean of 100 unloaded readings), a group of patches per message, the
groups spread over the 20 ms period. The
consumers are real ``contact_reconstruction`` processes (``input: batches``, ``worker_index``
of ``worker_count``) or bench/load_relay_batches.py (the same ROS work, nothing solved); a probe
takes ``contacts``. Every phase waits until its consumers serve, warms up, then measures over a
window: patch-frames offered (the batches' rows the source published in it, by its own
record: a probe subscribing to them took CPU from the workers; a batch the middleware lost is
now counted as skipped) and summarised (the ContactArray rows), skipped (the window's
readings that no summary carries, by patch and stamp, its last batches' summaries waited for),
the consumers' process CPU, the source's and probe's beside it
(CPU per patch-frame: their CPU time over the rows summarised), the latency of each row (the
reading's stamp, set when the source sends it as a driver sets the CAN receive time → the
ContactArray published: one DDS hop, the queue, the solve; the driver's assembly and batch
window come on top), each consumer's memory; ``--profile S``: py-spy on the first consumer.

- ``kinds``: the relay, then one worker with every patch idle, held still, sliding (the
  scenes of tactile_contact.sim.scenes), 24 patches of 72 taxels at 50 Hz: CPU per
  patch-frame of each kind beside the relay's. The 24 patches are on 4 CAN buses of 6 (a
  72-taxel patch is 12 CAN frames a reading: 24 patches at 50 Hz are 14 400 frames/s, more
  than one 1 Mbit/s bus carries), one batch a bus a period (``--group 6``: as a driver a bus
  sends them), so two workers each take two whole buses (the split keeps buses whole) and
  each batch reaches one of them;
- ``scale``: scene (a), 24 sliding patches at 50 Hz, two workers;
- ``saturation``: the sliding scene offered at ``--rate`` (above what one core solves, and
  two: at 200 Hz two workers kept up), one worker then two: patch-frames summarised per
  second, and their ratio (bounded here by the source and probe sharing the two cores);
- ``robot``: the whole robot (config/icub_robot.yaml, bundles in out/robot/bundles, built at
  the start when missing: ≈ 90 s of CPU), scene (b) (typical), one batch a bus: the relay,
  one worker, two workers (latency, CPU, memory per worker).

With ``--idle-every K`` (default 5; 1: off) ``kinds`` and ``robot`` also run the idle scene
and scene (b) with the source's readings through the driver's idle gate
(tactile_contact.canbus.idle_gate, skin_driver ``idle_every: K``): an untouched patch's
reading sent every K periods, a touched one's every period. Their CPU is also given per
patch-frame of the skin (every patch every period, sent or held back), with the gate's own
time (measured in the source, as the driver would spend it) beside it.

A markdown table of every phase closes the output.

    python bench/bench_workers.py [--phases kinds scale saturation robot] [--seconds 20]
                                  [--warmup 5] [--quick] [--rate 300] [--group 6] [--profile S]
                                  [--idle-every 5] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from benchkit import ROOT
from benchkit.skins import PERIOD_MS, multi_patch_layout
from benchkit.timing import profile

from tactile_contact.canbus.stream import PatchFrame

OUT = ROOT / "out" / "bench_workers"
ROBOT = ROOT / "config" / "icub_robot.yaml"
ROBOT_BUNDLES = ROOT / "out" / "robot" / "bundles"


# -- the source ---------------------------------------------------------------------------------
def readings(layout: Path, scene: str, seconds: float) -> tuple[list, list[list]]:
    """Per patch (name, frame, ids, status) and per period per patch (ΔC [F] float32, raw);
    kept in out/bench_workers for the next run of the same layout file and scene (simulating
    34 patches takes longer than a measured phase)."""
    import hashlib

    key = hashlib.sha1(layout.read_bytes() + f"{scene} {seconds}".encode()).hexdigest()[:12]
    cache = OUT / f"readings_{layout.stem}_{scene}_{key}.pkl"
    if cache.exists():
        return pickle.loads(cache.read_bytes())
    fixed, per_period = simulate(layout, scene, seconds)
    OUT.mkdir(parents=True, exist_ok=True)
    cache.write_bytes(pickle.dumps((fixed, per_period)))
    return fixed, per_period


def simulate(layout: Path, scene: str, seconds: float) -> tuple[list, list[list]]:
    """:func:`readings` made: the skin simulator's periods, ΔC from a calibrated baseline."""
    from tactile_contact.model.layout import load_layout
    from tactile_contact.model.modules import taxel_id
    from tactile_contact.msg import TaxelArray
    from tactile_contact.sim.scenes import scene_indentations
    from tactile_contact.sim.simulator import simulator_for_patch

    patches = list(load_layout(layout).patches)
    scenes = scene_indentations(patches, scene)
    period_s = PERIOD_MS * 1e-3
    count = int(seconds / period_s)
    fixed, per_period = [], [[] for _ in range(count)]
    for k, p in enumerate(patches):
        ids = np.array([taxel_id(m.board, m.triangle, c) for m in p.modules for c in range(12)])
        status = np.where(p.valid_mask(), 0, TaxelArray.STATUS_DISABLED).astype(np.uint8)
        fixed.append((p.name, p.frame_id, ids.astype(np.uint16), status))
        sim = simulator_for_patch(
            p, fine_cell=5e-4, realtime=True, period_s=period_s, noise_cdc=0.6, seed=k
        )
        count_farad = p.sensor.farad_per_count * 2**p.sensor.shift
        # the driver's baseline: the mean of unloaded readings (its calibration)
        baseline = np.mean([sim.period(None, -1.0).truth.values for _ in range(100)], axis=0)
        for j in range(count):
            ind, t = scenes[p.name].at(j * period_s)
            values = sim.period(ind, t).truth.values
            dc = ((baseline - values.astype(np.float64)) * count_farad).astype(np.float32)
            per_period[j].append((dc, values))
    return fixed, per_period


def batch_plan(
    layout: Path, group: str, window_ms: float = 2.0
) -> list[tuple[float, list[int], list[float], str]]:
    """When each batch of a period goes out and what it holds: (its time in the period, as a
    fraction of it; the patches' indices; each reading's age when it goes out, as a fraction;
    its bus field: the buses of its patches, comma-separated, as the driver writes it).

    ``group``: a number k (k patches a batch, spread evenly over the period); ``bus`` (one
    batch a bus, the buses spread evenly: one driver a bus); ``one-driver`` (the buses at
    random phases, seeded, as free-running boards put them, and one driver reading every bus:
    its Batcher, :func:`driver_batches`, sends a bus that completes at once unless another is
    due within ``window_ms``); ``one-driver-window`` (the same buses, a Batcher that does not
    know them: the readings completed within ``window_ms`` of a batch's first go out in it
    when the window ends); ``period`` (every patch in one batch: buses in step)."""
    from tactile_contact.model.layout import load_layout

    patches = load_layout(layout).patches
    buses: dict[str, list[int]] = {}
    for k, p in enumerate(patches):
        buses.setdefault(p.bus, []).append(k)

    def named(plan: list[tuple[float, list[int], list[float]]]) -> list:
        """Each batch with its bus field: its patches' buses in the layout's order."""
        out = []
        for at, g, ages in plan:
            on = {patches[k].bus for k in g}
            out.append((at, g, ages, ",".join(b for b in buses if b in on)))
        return out

    if group == "period":
        return named([(0.0, list(range(len(patches))), [0.0] * len(patches))])
    if group in ("one-driver", "one-driver-window"):
        rng = np.random.default_rng(7)
        phases = sorted(zip(rng.uniform(0.0, 1.0, len(buses)), buses.values(), strict=True))
        return named(driver_batches(phases, window_ms / PERIOD_MS, group == "one-driver"))
    if group == "bus":
        groups = list(buses.values())
    else:
        k = int(group)
        groups = [list(range(i, min(i + k, len(patches)))) for i in range(0, len(patches), k)]
    return named([(i / len(groups), g, [0.0] * len(g)) for i, g in enumerate(groups)])


def driver_batches(
    phases: list[tuple[float, list[int]]], window: float, by_bus: bool
) -> list[tuple[float, list[int], list[float]]]:
    """What the driver's Batcher sends in a period (:func:`batch_plan`'s terms, times as
    fractions of the period) when each bus's patches complete at its phase: a few periods
    are run through it (its receive timeout takes a batch at its due time) and the fourth
    period's batches kept. ``by_bus``: the Batcher knows each bus's patches (it sends a bus
    that completes alone at once); else it waits the window out."""
    from tactile_contact.canbus.batcher import Batcher

    names = [str(k) for _, m in phases for k in m]
    groups = {str(i): [str(k) for k in m] for i, (_, m) in enumerate(phases)} if by_bus else None
    b = Batcher(names, window, groups)
    sent: list[tuple[float, list]] = []
    for period in range(5):
        for phase, members in phases:
            t = period + phase
            if b.pending and t >= b.due:
                sent.append((b.due, b.take()))
            for k in members:
                frame = PatchFrame(str(k), "", t, [], np.zeros(0, np.float32), b"", b"")
                sent.extend((t, batch) for batch in b.add(frame, t))
    return [
        (at - 3, [int(f.patch) for f in batch], [at - f.stamp for f in batch])
        for at, batch in sent
        if 3 <= at < 4
    ]


def source_process(
    layout: Path, scene: str, rate_hz: float, group: str, sent_to: Path, idle_every: int = 1
) -> None:
    """Publish the scene's batches (as :func:`batch_plan` arranges them) at ``rate_hz``
    periods a second until SIGINT; READY when made, sending on GO. Then what it sent goes to
    ``sent_to`` (pickle: per batch its publication time [ns since the epoch], patch names,
    stamps [ns] and how many patches it held before the idle gate; then the gate's time [s]
    and calls): what was offered, counted without a subscriber of its own competing with the
    workers for the cores.

    ``idle_every`` > 1: each reading goes through the driver's IdleGate (skin_driver
    ``idle_every``, ``idle_counts`` 3) and the batch carries those it lets through, as the
    driver's would; a batch left empty is not sent."""
    import rclpy
    from rclpy.node import Node

    from tactile_contact.msg import TaxelBatch
    from tactile_contact.ros.cdr import write_taxel_batch
    from tactile_contact.ros.common import SENSOR_QOS

    fixed, per_period = readings(layout, scene, 4.0)
    plan = batch_plan(layout, group)
    gate = None
    if idle_every > 1:
        from tactile_contact.canbus.idle_gate import IdleGate
        from tactile_contact.model.layout import load_layout

        counts = {
            p.name: p.sensor.farad_per_count * 2.0**p.sensor.shift
            for p in load_layout(layout).patches
        }
        gate = IdleGate(idle_every, 3.0, counts)  # (skin_driver's idle_counts default)
    statuses = [f[3].tobytes() for f in fixed]
    gate_s, gate_calls = 0.0, 0
    rclpy.init()
    node = Node("workers_source")
    pub = node.create_publisher(TaxelBatch, "taxel_batches", SENSOR_QOS)
    print("READY", flush=True)
    sys.stdin.readline()  # GO
    period_s = 1.0 / rate_hz
    t0 = time.monotonic()
    j = 0
    sent: list[tuple[int, list[int], list[int], int]] = []
    try:
        while rclpy.ok():
            period, g = divmod(j, len(plan))
            at, members, ages, bus = plan[g]
            delay = t0 + (period + at) * period_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            rows = per_period[period % len(per_period)]
            j += 1
            offered = len(members)
            if gate is not None:
                frames = [
                    (k, PatchFrame(fixed[k][0], "", 0.0, [], rows[k][0], b"", statuses[k]))
                    for k in members
                ]
                t = time.perf_counter()
                passing = [k for k, f in frames if gate.passes(f)]
                gate_s += time.perf_counter() - t
                gate_calls += len(frames)
                members, ages = passing, [ages[members.index(k)] for k in passing]
                if not members:
                    sent.append((time.time_ns(), [], [], offered))
                    continue
            now = time.time_ns()
            stamps = [now - round(a * period_s * 1e9) for a in ages]
            pub.publish(
                write_taxel_batch(
                    now,
                    bus,
                    [fixed[k][0] for k in members],
                    [fixed[k][1] for k in members],
                    stamps,
                    [fixed[k][2] for k in members],
                    [rows[k][0] for k in members],
                    [rows[k][1] for k in members],
                    [fixed[k][3] for k in members],
                )
            )
            sent.append((now, members, stamps, offered))
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()
    names = [f[0] for f in fixed]
    record = [(t, [names[k] for k in m], st, n) for t, m, st, n in sent]
    sent_to.write_bytes(pickle.dumps((record, gate_s, gate_calls), protocol=5))


# -- a phase ------------------------------------------------------------------------------------
def cpu_seconds(pid: int) -> float:
    import psutil

    t = psutil.Process(pid).cpu_times()
    return t.user + t.system


def memory(pid: int) -> tuple[float, float]:
    """(resident, unique) memory of ``pid`` [MB]."""
    import psutil

    m = psutil.Process(pid).memory_full_info()
    return m.rss / 1e6, m.uss / 1e6


def run_phase(
    layout: Path,
    bundles: Path,
    scene: str,
    consumers: str,
    workers: int,
    rate_hz: float,
    group: int | str,
    seconds: float,
    warmup: float = 5.0,
    profile_s: float = 0.0,
    tree: Path | None = None,
    idle_every: int = 1,
) -> dict:
    """One measured run: the source, ``workers`` workers (or the relay when ``consumers`` is
    "relay"), a probe; patch-frames offered and summarised, CPU, latency, memory, and with
    ``profile_s`` py-spy on the first consumer after the window. ``tree``: the workers run the
    package found there (an older version unpacked, e.g. ``git archive``) instead of this one.
    ``idle_every``: the source gates its readings as skin_driver's ``idle_every`` does; the
    skin's patch-frames (every patch every period, sent or not) are counted beside them."""
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import ContactArray, ReconstructionWorker
    from tactile_contact.ros.cdr import read_contact_array
    from tactile_contact.ros.worker_link import HEARTBEAT_QOS, TOPIC

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    worker_env = env if tree is None else dict(env, PYTHONPATH=str(tree))
    names = [p.name for p in load_layout(layout).patches]
    procs = []
    if consumers == "relay":
        procs.append(
            subprocess.Popen(
                [sys.executable, str(ROOT / "bench" / "load_relay_batches.py"), *names],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=env,
            )
        )
    else:
        # Another tree's package runs as a module: this tree's script may import what that tree
        # does not have (a worker that died at its first import left the bench waiting 300 s).
        exe = (
            ["-m", "tactile_contact.ros.contact_reconstruction"]
            if tree
            else [str(ROOT / "scripts" / "contact_reconstruction")]
        )
        for i in range(workers):
            args = [*exe, "--ros-args", "-p", f"bundles_dir:={bundles}", "-p", f"layout:={layout}"]
            args += ["-p", "input:=batches", "-p", f"worker_index:={i}"]
            args += ["-p", f"worker_count:={workers}"]
            procs.append(
                subprocess.Popen(
                    [sys.executable, *args],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    env=worker_env,
                )
            )
    sent_file = OUT / f"sent_{os.getpid()}.pkl"
    sent_file.unlink(missing_ok=True)
    source = subprocess.Popen(
        [
            *(sys.executable, __file__, "--source-child", str(layout), scene, str(rate_hz)),
            *(str(group), str(sent_file), str(idle_every)),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        env=env,
        text=True,
    )
    assert source.stdout is not None and source.stdin is not None
    assert source.stdout.readline().startswith("READY")
    probe = Node("workers_probe")
    lock = threading.Lock()
    rows: collections.Counter[str] = collections.Counter()
    offered: collections.Counter[str] = collections.Counter()
    states: collections.Counter[int] = collections.Counter()
    latency: list[float] = []
    serving: dict[str, int] = {}
    measuring = threading.Event()

    # Skipped: the readings offered in the window that no summary carries, matched by
    # (patch, stamp); summaries that come after the window still count for its readings (a
    # count difference read a batch at the window's edge, 4-6 rows, as skipped).
    offered_keys: set[tuple[str, int]] = set()
    summarised_keys: set[tuple[str, int]] = set()
    started = threading.Event()  # (set with the window, never cleared: a summary before it
    # cannot carry a reading offered in it, so the warm-up's are not read)

    def on_contacts(data: bytes) -> None:
        if not started.is_set():
            return
        _, r = read_contact_array(data)
        with lock:
            summarised_keys.update(zip(r.patches, r.stamps_ns, strict=True))
            if measuring.is_set():
                rows.update(r.patches)
                states.update(r.states)
                latency.extend(r.latency)

    def on_worker(m: ReconstructionWorker) -> None:
        with lock:
            serving[m.worker] = len(m.patches)

    # (best effort as the workers publish, but a deep queue: with sensor data's 5 a probe
    # thread held up ≈ 15 ms by a busy machine dropped summaries the workers had published)
    deep = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)
    probe.create_subscription(ContactArray, "contacts", on_contacts, deep, raw=True)
    probe.create_subscription(ReconstructionWorker, TOPIC, on_worker, HEARTBEAT_QOS)
    executor = EventsExecutor()
    executor.add_node(probe)
    stop = threading.Event()
    spinner = threading.Thread(
        target=lambda: [executor.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set, True)]
    )
    spinner.start()

    def ready() -> bool:
        with lock:
            up = sum(1 for n in serving.values() if n > 0)
        return up >= len(procs) and probe.count_subscribers("taxel_batches") >= len(procs)

    deadline = time.monotonic() + 300.0
    while not ready():
        dead = [p.args for p in procs if p.poll() is not None]
        if dead or time.monotonic() > deadline:
            for p in (source, *procs):  # (none left running on the domain)
                p.kill()
            if dead:
                raise SystemExit(f"the {consumers}: {dead[0]} ended before serving (run it alone)")
            raise SystemExit(f"the {consumers} did not come up in 300 s")
        time.sleep(0.2)
    source.stdin.write("GO\n")
    source.stdin.flush()
    time.sleep(warmup)  # numba, caches, the fusion's windows
    c0 = [cpu_seconds(p.pid) for p in procs]
    h0 = (cpu_seconds(source.pid), cpu_seconds(os.getpid()))
    started.set()
    measuring.set()
    w0, w0_ns = time.monotonic(), time.time_ns()
    time.sleep(seconds)
    measuring.clear()
    wall, w1_ns = time.monotonic() - w0, time.time_ns()
    c1 = [cpu_seconds(p.pid) for p in procs]
    harness = (
        (cpu_seconds(source.pid) - h0[0]) / wall,
        (cpu_seconds(os.getpid()) - h0[1]) / wall,
    )
    mem = [memory(p.pid) for p in procs]
    prof = profile(procs[0].pid, profile_s, OUT / f"profile_{consumers}.txt") if profile_s else ""
    time.sleep(0.2)  # (summaries of the window's last batches)
    for p in (source, *procs):
        p.send_signal(signal.SIGINT)
    for p in (source, *procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
    # offered: what the source published within the window, by its own record
    record, gate_s, gate_calls = pickle.loads(sent_file.read_bytes())
    skin_frames = 0  # every patch every period in the window, sent or held back by the gate
    for t, patches, stamps, before in record:
        if w0_ns <= t < w1_ns:
            offered.update(patches)
            offered_keys.update(zip(patches, stamps, strict=True))
            skin_frames += before
    sent_file.unlink()
    with lock:
        got, sent = sum(rows.values()), sum(offered.values())
        skipped = len(offered_keys - summarised_keys)
        lat = np.asarray(latency) * 1e3
        kinds = {ContactArray.IDLE: "idle", ContactArray.CONTACT: "solved in contact"}
        kinds.update({ContactArray.HELD: "held", ContactArray.FAILED: "failed"})
        share = {kinds.get(k, str(k)): n / max(got, 1) for k, n in states.items()}
    stop.set()
    spinner.join(5.0)
    executor.shutdown()
    probe.destroy_node()
    cpu = [(b - a) / wall for a, b in zip(c0, c1, strict=True)]
    return {
        "consumers": consumers,
        "workers": len(procs),
        "patches": len(names),
        "scene": scene,
        "rate_hz": rate_hz,
        "cpu": cpu,
        "harness_cpu": harness,
        "offered_per_s": sent / wall,
        "frames_per_s": got / wall,
        "skipped": skipped,
        "skipped_share": skipped / max(len(offered_keys), 1),
        "states": share,
        "cpu_per_frame_us": sum(cpu) * wall / max(got, 1) * 1e6,
        "idle_every": idle_every,
        "skin_frames_per_s": skin_frames / wall,
        # the consumers' CPU over every patch-frame of the skin (the gated ones too)
        "cpu_per_skin_frame_us": sum(cpu) * wall / max(skin_frames, 1) * 1e6,
        "gate_us": gate_s / max(gate_calls, 1) * 1e6,
        "lat_p50": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "lat_p99": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        "lat_max": float(lat.max()) if lat.size else float("nan"),
        "rss_mb": [m[0] for m in mem],
        "uss_mb": [m[1] for m in mem],
        "profile": prof,
    }


def table(results: dict[str, dict]) -> list[str]:
    """The phases as one markdown table (CPU per patch-frame also as a ratio to the relay's of
    the same layout and run)."""
    relay = {
        r["patches"]: r["cpu_per_frame_us"]
        for r in results.values()
        if r["workers"] == 1 and r["consumers"] == "relay"
    }
    out = [
        "| phase | patches | scene | workers | offered /s | summarised /s | skipped | "
        "latency p50 / p99 / max ms | CPU (of a core) | µs a patch-frame | × relay | "
        "resident / unique MB a worker |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, r in results.items():
        base = relay.get(r["patches"])
        ratio = f"×{r['cpu_per_frame_us'] / base:.2f}" if base else "-"
        mem = ", ".join(f"{a:.0f} / {b:.0f}" for a, b in zip(r["rss_mb"], r["uss_mb"], strict=True))
        out.append(
            f"| {key} | {r['patches']} | {r['scene']} | "
            f"{'relay' if r['consumers'] == 'relay' else r['workers']} | "
            f"{r['offered_per_s']:.0f} | {r['frames_per_s']:.0f} | "
            f"{r['skipped']} ({r['skipped_share']:.1%}) | "
            f"{r['lat_p50']:.2f} / {r['lat_p99']:.2f} / {r['lat_max']:.1f} | "
            f"{' + '.join(f'{c:.0%}' for c in r['cpu'])} | {r['cpu_per_frame_us']:.0f} | "
            f"{ratio} | {mem} |"
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--phases",
        nargs="+",
        default=["kinds", "scale", "saturation", "robot"],
        choices=["kinds", "scale", "saturation", "robot"],
    )
    ap.add_argument("--seconds", type=float, default=20.0, help="measured time of a phase")
    ap.add_argument("--warmup", type=float, default=5.0, help="before the window of a phase")
    ap.add_argument("--quick", action="store_true", help="3 s phases after 3 s of warm-up")
    ap.add_argument(
        "--rate",
        type=float,
        default=300.0,
        help="saturation: periods a second (at 200 two workers kept up with 6 a batch)",
    )
    ap.add_argument(
        "--group",
        type=int,
        default=6,
        help="patches per batch (24-patch skin; 6: one a bus, as a driver a bus sends them)",
    )
    ap.add_argument(
        "--robot-batches",
        choices=("bus", "one-driver", "one-driver-window", "period"),
        default="bus",
        help="the whole robot's batches: one a bus, the buses spread evenly (a driver a bus); "
        "as one driver of every bus sends them (drivers:=one: the buses at random phases, a "
        "2 ms batch window; -window: a Batcher that does not know the buses, the stop-42 "
        "one); or every patch in one a period (buses in step)",
    )
    ap.add_argument("--profile", type=float, default=0.0, help="py-spy a worker S s a phase")
    ap.add_argument("--out", type=Path, help="also write workers.md and workers.json here")
    ap.add_argument(
        "--before",
        type=Path,
        help="also run each 1-worker phase (kinds, robot) with the package in this folder "
        "(e.g. `git archive <commit> tactile_contact | tar -x -C DIR`), just before this "
        "tree's: before and after in the same run",
    )
    ap.add_argument(
        "--after",
        type=Path,
        help="the workers of the phases not marked 'before' run the package in this folder "
        "instead of this tree's (e.g. one commit's files, while others edit the working tree)",
    )
    ap.add_argument(
        "--buses",
        type=int,
        default=4,
        help="CAN buses of the 24-patch skin (1: one bus, every worker takes every batch)",
    )
    ap.add_argument(
        "--idle-every",
        type=int,
        default=5,
        help="kinds: also the idle scene with the driver's idle gate (skin_driver idle_every)",
    )
    ap.add_argument("--source-child", nargs=6, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.source_child:
        layout, scene, rate, group, sent_to, every = args.source_child
        source_process(Path(layout), scene, float(rate), group, Path(sent_to), int(every))
        return 0
    if args.quick:
        args.seconds, args.warmup = 3.0, 3.0
    import rclpy

    from tactile_contact.offline.build import build_layout

    OUT.mkdir(parents=True, exist_ok=True)
    layout24 = multi_patch_layout(24, OUT, buses=args.buses)
    bundles24 = ROOT / "out" / "bench_load" / "bundles"  # (bench_load's: the same 24 patches)
    build_layout(layout24, bundles24, jobs=2)
    rclpy.init()
    lines: list[str] = []
    results: dict[str, dict] = {}

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    def phase(key: str, *a: object, tree: Path | None = None, idle_every: int = 1) -> dict:
        tree = tree or args.after
        r = run_phase(*a, args.warmup, args.profile, tree, idle_every)  # type: ignore[arg-type]
        results[key] = r
        say(
            f"{key}: {r['offered_per_s']:.0f} patch-frames/s offered, {r['frames_per_s']:.0f} "
            f"summarised, {r['skipped']} skipped ({r['skipped_share']:.1%}); CPU "
            f"{' + '.join(f'{c:.0%}' for c in r['cpu'])} of a core (source "
            f"{r['harness_cpu'][0]:.0%}, probe {r['harness_cpu'][1]:.0%}), "
            f"{r['cpu_per_frame_us']:.0f} µs a patch-frame; latency p50 {r['lat_p50']:.2f} ms, "
            f"p99 {r['lat_p99']:.2f} ms, max {r['lat_max']:.1f} ms; rows "
            + ", ".join(f"{k} {v:.0%}" for k, v in r["states"].items())
            + f"; memory {', '.join(f'{m:.0f}' for m in r['rss_mb'])} MB resident "
            f"({', '.join(f'{m:.0f}' for m in r['uss_mb'])} MB unique)"
        )
        if r["profile"]:
            say(r["profile"])
        return r

    say(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores")
    rate, n, g = 1000.0 / PERIOD_MS, args.seconds, args.group
    if "kinds" in args.phases or "scale" in args.phases:
        say(f"-- 24 patches of 72 taxels on {args.buses} buses at 50 Hz, {g} a batch --")
        relay = phase("relay, 24 patches", layout24, bundles24, "sliding", "relay", 1, rate, g, n)
    if "kinds" in args.phases:
        for scene in ("idle", "held", "sliding"):
            if args.before:
                a = (layout24, bundles24, scene, "workers", 1, rate, g, n)
                phase(f"{scene}, 1 worker, before", *a, tree=args.before)
            r = phase(f"{scene}, 1 worker", layout24, bundles24, scene, "workers", 1, rate, g, n)
            say(
                f"   {scene}: {r['cpu_per_frame_us']:.0f} µs a patch-frame all-in, "
                f"×{r['cpu_per_frame_us'] / relay['cpu_per_frame_us']:.2f} the relay's "
                f"{relay['cpu_per_frame_us']:.0f} µs"
            )
        if args.idle_every > 1:
            k = args.idle_every
            a = (layout24, bundles24, "idle", "workers", 1, rate, g, n)
            r = phase(f"idle, 1 worker, idle_every {k}", *a, idle_every=k)
            total = r["cpu_per_skin_frame_us"] + r["gate_us"]
            say(
                f"   idle, the driver's gate at {k}: {r['skin_frames_per_s']:.0f} patch-frames/s "
                f"of the skin, {r['offered_per_s']:.0f} sent; {total:.1f} µs a patch-frame of "
                f"the skin all-in (worker {r['cpu_per_skin_frame_us']:.1f} + the gate "
                f"{r['gate_us']:.1f} in the driver), "
                f"×{total / relay['cpu_per_frame_us']:.2f} the relay's"
            )
    if "scale" in args.phases:
        phase("(a) sliding, 2 workers", layout24, bundles24, "sliding", "workers", 2, rate, g, n)
    if "saturation" in args.phases:
        say(
            f"-- saturation: 24 sliding patches on {args.buses} buses offered at "
            f"{args.rate:.0f} Hz, {g} a batch --"
        )
        one = phase(
            "saturation, 1 worker", layout24, bundles24, "sliding", "workers", 1, args.rate, g, n
        )
        two = phase(
            "saturation, 2 workers", layout24, bundles24, "sliding", "workers", 2, args.rate, g, n
        )
        say(
            f"   throughput 2 workers / 1 worker: ×{two['frames_per_s'] / one['frames_per_s']:.2f}"
            f" ({one['frames_per_s']:.0f} → {two['frames_per_s']:.0f} patch-frames/s)"
        )
    if "robot" in args.phases:
        build_layout(ROBOT, ROBOT_BUNDLES, jobs=2)
        rb = args.robot_batches
        plan = batch_plan(ROBOT, rb)
        say(
            f"-- the whole robot (34 patches, 3928 taxels, 7 buses), batches: {rb} "
            f"({len(plan)} a period, of {', '.join(str(len(m)) for _, m, *_ in plan)} patches) --"
        )
        phase("relay, robot", ROBOT, ROBOT_BUNDLES, "typical", "relay", 1, rate, rb, n)
        if args.before:
            a = (ROBOT, ROBOT_BUNDLES, "typical", "workers", 1, rate, rb, n)
            phase("(b) typical, 1 worker, before", *a, tree=args.before)
        if args.idle_every > 1:
            k = args.idle_every
            a = (ROBOT, ROBOT_BUNDLES, "typical", "workers", 1, rate, rb, n)
            r = phase(f"(b) typical, 1 worker, idle_every {k}", *a, idle_every=k)
            say(
                f"   (b) with the driver's gate at {k}: {r['offered_per_s']:.0f} of "
                f"{r['skin_frames_per_s']:.0f} patch-frames/s sent; the worker "
                f"{r['cpu'][0]:.0%} of a core, {r['cpu_per_skin_frame_us']:.1f} µs a "
                f"patch-frame of the skin (+ the gate {r['gate_us']:.1f} in the driver)"
            )
        for w in (1, 2):
            phase(
                f"(b) typical, {w} worker(s)",
                ROBOT,
                ROBOT_BUNDLES,
                "typical",
                "workers",
                w,
                rate,
                rb,
                n,
            )
    say(f"load average after: {os.getloadavg()[0]:.2f}")
    say("")
    for line in table(results):
        say(line)
    rclpy.try_shutdown()
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        cmd = " ".join(["python bench/bench_workers.py", *sys.argv[1:]])
        (args.out / "workers.md").write_text(
            f"# Reconstruction workers under load (bench/bench_workers.py)\n\n`{cmd}`\n\n```\n"
            + "\n".join(lines)
            + "\n```\n"
        )
        (args.out / "workers.json").write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
