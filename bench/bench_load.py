"""Load over DDS, 24 patches at 50 Hz for ≥ 60 s: skin_driver and contact_reconstruction against
the same run with the node's ROS work alone (the relay, ``--baseline``): drops, latency, CPU.

The size of a full arm: 24 hexagon patches (144 modules, 14 400 CAN frames/s), each pressed by
its own sliding 12 mm sphere (one contact per patch, phases staggered), as separate processes
talking over DDS as on a robot:

- the driver process (bench/load_driver.py): ``skin_driver`` fed by a sender thread on a
  python-can virtual bus (frames precomputed by the simulator before timing; the sender's CPU
  is not counted). Each patch's frames arrive together, the patches spread evenly over the
  period (patch k at k/24 of it), as free-running modules on several buses deliver them;
  ``--burst`` sends every patch at the same instant (the worst case);
- the reconstruction process: ``contact_reconstruction`` (``scripts/contact_reconstruction``);
- this process: subscribes to every ``<patch>/contact`` and to ``/diagnostics``.

Printed: CAN frames in, module readings and patch messages out, frames dropped (CAN frames
sent but not counted by the driver, and taxel messages the reconstruction never received),
end-to-end latency CAN receive → ContactState published (the node's ``latency`` field:
stamp = receive time of the frame completing the reading; p50 / p99 / max), CPU of each node
(process CPU time / wall time, 100 % = one core; the driver without its sender thread).
Targets (issue 17): 0 dropped, p99 ≤ 5 ms, reconstruction ≤ 30 % of one core. With
``--profile S`` py-spy samples the reconstruction for S s and the hottest functions are
printed (self time and inclusive time).

Baseline (``--baseline``): the same run first with ``bench/load_relay.py`` in the
reconstruction's place (its ROS work alone: the same subscriptions, QoS and executor, a
ContactState published for every frame taken, nothing solved), then with the
reconstruction; the CPU per frame and the latency of the two side by side. The relay is the
floor no reconstruction code can go below on this machine and middleware.

    python bench/bench_load.py [--seconds 60] [--patches 24] [--profile 15] [--burst]
                               [--processes 2] [--baseline | --relay] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from benchkit import ROOT
from benchkit.skins import PERIOD_MS, multi_patch_layout
from benchkit.timing import cpu_seconds, profile

OUT = ROOT / "out" / "bench_load"


# -- the measuring process ----------------------------------------------------------------------
def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="measured time (≥ 60 s)")
    ap.add_argument("--patches", type=int, default=24)
    ap.add_argument("--contacts", type=int, default=-1, help="patches pressed (default: all)")
    ap.add_argument("--warmup", type=float, default=8.0)
    ap.add_argument("--profile", type=float, default=0.0, help="py-spy both nodes for S s")
    ap.add_argument("--out", type=Path, help="also write load.md (what is printed) here")
    ap.add_argument(
        "--driver-only", action="store_true", help="no reconstruction (the driver's own capacity)"
    )
    ap.add_argument(
        "--processes", type=int, default=1, help="reconstruction processes sharing the patches"
    )
    ap.add_argument(
        "--relay",
        action="store_true",
        help="bench/load_relay.py instead of the reconstruction (the ROS floor alone)",
    )
    ap.add_argument(
        "--baseline",
        action="store_true",
        help="run the relay first, then the reconstruction, and compare them",
    )
    ap.add_argument(
        "--burst",
        action="store_true",
        help="every patch's frames at the same instant (default: patches spread over the period)",
    )
    args = ap.parse_args()
    from tactile_contact.offline.build import build_layout

    n = args.patches
    k = n if args.contacts < 0 else min(args.contacts, n)
    OUT.mkdir(parents=True, exist_ok=True)
    layout = multi_patch_layout(n, OUT)
    bundles = OUT / f"bundles_{n}" if n != 24 else OUT / "bundles"
    t = time.monotonic()
    build_layout(layout, bundles, jobs=2)  # up-to-date bundles are kept
    print(f"bundles ready ({time.monotonic() - t:.0f} s)")
    report: list[str] = []

    def say(text: str) -> None:
        print(text)
        report.append(text)

    if args.baseline:
        phases = [("relay", True), ("reconstruction", False)]
    else:
        phases = [("relay" if args.relay else "reconstruction", args.relay)]
    figures = {}
    for label, relay in phases:
        if len(phases) > 1:
            say(f"--- {label} ---")
        figures[label] = run_phase(args, n, k, layout, bundles, relay, say)
    if args.baseline:
        compare(figures["relay"], figures["reconstruction"], say)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        cmd = " ".join(["python bench/bench_load.py", *sys.argv[1:]])
        name = (
            "load"
            + ("_burst" if args.burst else "")
            + (f"_{args.processes}p" if args.processes > 1 else "")
            + ("_relay" if args.relay and not args.baseline else "")
        )
        (args.out / f"{name}.md").write_text(
            f"# Load: 24 patches at 50 Hz over DDS (bench/bench_load.py)\n\n`{cmd}`\n\n```\n"
            + "\n".join(report)
            + "\n```\n"
        )
    return 0


def compare(relay: dict[str, float], recon: dict[str, float], say: Callable[[str], None]) -> None:
    """The reconstruction against the relay of the same run: what the solve adds."""
    say("--- the reconstruction against the relay (same machine, same run) ---")
    for key, unit in (("cpu_per_frame_us", "µs"), ("lat_p50", "ms"), ("lat_p99", "ms")):
        a, b = relay[key], recon[key]
        say(f"{key}: relay {a:.2f} {unit}, reconstruction {b:.2f} {unit} (×{b / a:.1f})")
    say(
        f"CPU: relay {relay['cpu']:.0%} of one core, reconstruction {recon['cpu']:.0%}; the "
        f"30 % target leaves {0.30 / recon['frames_per_s'] * 1e6 - relay['cpu_per_frame_us']:.0f}"
        " µs a frame "
        f"beyond the relay's ROS work"
    )


def run_phase(
    args: argparse.Namespace,
    n: int,
    k: int,
    layout: Path,
    bundles: Path,
    relay: bool,
    say: Callable[[str], None],
) -> dict[str, float]:
    """One measured run: the driver and the reconstruction (or the relay) as processes, this
    process listening; prints the figures via ``say`` and returns the main ones."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node

    from tactile_contact.msg import ContactState
    from tactile_contact.ros.common import SENSOR_QOS

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # --processes P: the patches dealt round-robin to P reconstruction processes (the node's
    # ``patches`` parameter, as a skin too large for one core is split on a robot).
    share = [
        [f"patch{j:02d}" for j in range(n)][i :: args.processes] for i in range(args.processes)
    ]
    recons = []
    for names in share:
        recon_cmd = [
            sys.executable,
            str(ROOT / "scripts" / "contact_reconstruction"),
            "--ros-args",
            "-p",
            f"bundles_dir:={bundles}",
            "-p",
            "diagnostics_period:=1.0",
            "-p",
            f"patches:=[{','.join(names)}]",
        ]
        if relay:
            recon_cmd = [sys.executable, str(ROOT / "bench" / "load_relay.py"), *names]
        if args.driver_only:  # a process that does nothing, so that the rest stays the same
            recon_cmd = [sys.executable, "-c", "import time; time.sleep(1e6)"]
        recons.append(
            subprocess.Popen(
                recon_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env
            )
        )
    driver = subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "bench" / "load_driver.py"),
            str(layout),
            str(n),
            "bench_load",
            str(k),
            "1" if args.burst else "0",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
        text=True,
    )
    assert driver.stdout is not None
    line = driver.stdout.readline()
    if not line.startswith("READY"):
        raise SystemExit(f"driver did not start: {line!r}")
    sender_tid = json.loads(line.split(" ", 1)[1])["sender_tid"]

    rclpy.init()
    probe = Node("load_probe")
    latency: list[float] = []
    contacts = collections.Counter()
    recon_frames: dict[str, int] = {}
    measuring = threading.Event()

    def on_contact(m: ContactState) -> None:
        if measuring.is_set():
            contacts[m.patch] += 1
            if m.in_contact:
                latency.append(m.latency)

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name.startswith("contact_reconstruction: "):
                values = {kv.key: kv.value for kv in s.values}
                if "frames" in values:
                    recon_frames[s.name.split(": ", 1)[1]] = int(values["frames"])

    for j in range(n):
        probe.create_subscription(ContactState, f"patch{j:02d}/contact", on_contact, SENSOR_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    # The probe is the measurement, not the system measured: the lighter executor leaves
    # more of the 2 cores to the nodes (the SingleThreadedExecutor takes ≈ 190 µs a message).
    executor = EventsExecutor()
    executor.add_node(probe)
    stop = threading.Event()
    spinner = threading.Thread(
        target=lambda: [executor.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set, True)]
    )
    spinner.start()
    deadline = time.monotonic() + 120.0
    while not args.driver_only and time.monotonic() < deadline:
        if all(probe.count_subscribers(f"patch{j:02d}/taxels") for j in range(n)):
            break
        time.sleep(0.1)
    else:
        if not args.driver_only:
            raise SystemExit("the reconstruction did not subscribe to every patch in 120 s")
    time.sleep(0.5)  # (the driver's side of the discovery)
    assert driver.stdin is not None
    driver.stdin.write("GO\n")
    driver.stdin.flush()
    time.sleep(args.warmup)  # calibration, numba warm-up
    measuring.set()
    load0 = os.getloadavg()[0]
    w0 = time.monotonic()
    d0 = cpu_seconds(driver.pid, sender_tid)
    r0 = [cpu_seconds(r.pid) for r in recons]
    taken0 = sum(recon_frames.values())  # (diagnostics come once a second: ±2 % over 60 s)
    time.sleep(args.seconds)
    taken = sum(recon_frames.values()) - taken0
    wall = time.monotonic() - w0
    d1 = cpu_seconds(driver.pid, sender_tid)
    r1 = [cpu_seconds(r.pid) for r in recons]
    measuring.clear()
    prof = (
        profile(recons[0].pid, args.profile, OUT / "recon_profile.txt")
        if args.profile and not args.driver_only
        else ""
    )
    dprof = (
        profile(driver.pid, args.profile, OUT / "driver_profile.txt", skip="send")
        if args.profile > 0
        else ""
    )
    driver.send_signal(signal.SIGUSR1)  # frames stop; the driver drains and publishes the rest
    time.sleep(3.0)  # and the reconstruction's diagnostics count what it received
    frames_seen = sum(recon_frames.values())
    driver.send_signal(signal.SIGINT)
    out, _ = driver.communicate(timeout=60)
    result = json.loads(out.strip().splitlines()[-1].split(" ", 1)[1])
    for recon in recons:
        recon.send_signal(signal.SIGINT if not args.driver_only else signal.SIGTERM)
    for recon in recons:
        recon.wait(timeout=30)
    stop.set()
    spinner.join(5.0)
    executor.shutdown()
    probe.destroy_node()
    rclpy.try_shutdown()

    lat = np.asarray(latency) * 1e3
    d_cpu = (d1 - d0) / wall
    r_each = [(b - a) / wall for a, b in zip(r0, r1, strict=True)]
    r_cpu = sum(r_each)
    dropped_can = result["sent"] - result["frames"]
    published = result["published"]
    dropped_dds = published - frames_seen if not args.driver_only else 0
    say(
        f"{n} patches at {1000 // PERIOD_MS} Hz, {k} of them pressed (one contact each), "
        f"{'all patches at once' if args.burst else 'patches spread over the period'}, "
        f"measured {wall:.0f} s (after {args.warmup:.0f} s warm-up); load average before: "
        f"{load0:.2f}"
    )
    say(
        f"CAN frames in: {result['sent']} sent, {result['frames']} received by the driver "
        f"(dropped {dropped_can}); rejected {result['rejected']}, incomplete periods "
        f"{result['incomplete']}, orphan B {result['orphan_b']}"
    )
    say(
        f"readings out: {result['readings']} module readings in {published} TaxelArray "
        f"messages ({result['stale_publications']} with a stale module); the reconstruction "
        f"received {frames_seen} (dropped {dropped_dds}); "
        f"{sum(contacts.values())} ContactState in the window"
    )
    if lat.size:
        say(
            f"latency CAN receive → contact published: p50 {np.percentile(lat, 50):.2f} ms, "
            f"p99 {np.percentile(lat, 99):.2f} ms, max {lat.max():.2f} ms "
            f"({lat.size} contacts)"
        )
    per_frame = r_cpu * wall / taken * 1e6 if taken else math.nan
    each = f" ({' + '.join(f'{c:.0%}' for c in r_each)} in {len(r_each)} processes)"
    say(
        f"CPU: driver {d_cpu:.0%} of one core (sender thread excluded), "
        f"{'relay' if relay else 'reconstruction'} {r_cpu:.0%}"
        f"{each if len(r_each) > 1 else ''}; {per_frame:.0f} µs of CPU per frame taken "
        f"({taken} in the window)"
    )
    ok_lat = lat.size > 0 and np.percentile(lat, 99) <= 5.0
    say(
        f"targets: 0 dropped {'met' if dropped_can == 0 and dropped_dds == 0 else 'MISSED'}; "
        f"p99 ≤ 5 ms {'met' if ok_lat else 'MISSED'}; reconstruction ≤ 30 % "
        f"{'met' if r_cpu <= 0.30 else 'MISSED'}"
    )
    if prof:
        say("reconstruction profile (py-spy, the first process):")
        say(prof)
    if dprof:
        say("driver profile (py-spy, the load generator's thread left out):")
        say(dprof)
    return {
        "cpu": r_cpu,
        "cpu_per_frame_us": per_frame,
        "frames_per_s": n * 1000 / PERIOD_MS,
        "lat_p50": float(np.percentile(lat, 50)) if lat.size else math.nan,
        "lat_p99": float(np.percentile(lat, 99)) if lat.size else math.nan,
    }


if __name__ == "__main__":
    sys.exit(main())
