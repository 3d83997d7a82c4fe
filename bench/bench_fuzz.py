"""Garbage CAN frames of every kind through the real skin_driver node: counted by kind against
what was sent, nothing lost, nothing non-finite published (the figures of issue 17).

A simulated hexagon patch (6 modules, 50 Hz) on a python-can virtual bus, with garbage frames
of every kind mixed in (:mod:`tactile_contact.canbus.fuzz`: random ids, lengths 0–8 and CAN FD
lengths up to 64, oversized classic frames, bad frame types, unknown modules, remote,
extended-id and error frames, duplicated and out-of-order halves). The driver runs with
``bus_filter`` off, so every frame reaches it. Printed and checked (exit 1 if any fails):

- crashes: the receive thread alive, ``internal_errors`` 0;
- NaN / inf published: 0 (every ΔC of every TaxelArray checked);
- complete valid readings lost: 0 (every (period, module) reading appears once, fresh);
- every kind of bad frame counted in /diagnostics, by kind, equal to what was sent.

    python bench/bench_fuzz.py [--garbage 100000] [--periods 500]
"""

from __future__ import annotations

import argparse
import random
import sys
import threading
import time

import numpy as np
from benchkit import LAYOUT

from tactile_contact.canbus.fuzz import ODD_KINDS, REJECTED_KINDS, hostile_batches

PERIOD_S = 0.02


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--garbage", type=int, default=100_000, help="garbage frames in all")
    ap.add_argument("--periods", type=int, default=500, help="valid periods (20 ms each)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()

    import can
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.skin_driver import SkinDriver
    from tactile_contact.sim.simulator import simulator_for_patch

    patch = load_layout(LAYOUT).patches[0]
    served = [(m.board, m.triangle) for m in patch.modules]
    sim = simulator_for_patch(patch, period_s=PERIOD_S, noise_cdc=1.0, seed=args.seed)
    periods = [sim.period(None, k * PERIOD_S) for k in range(args.periods)]
    per_period = max(1, -(-args.garbage // (args.periods - 1)))
    traffic = hostile_batches(
        [p.messages for p in periods[:-1]], served, per_period, random.Random(args.seed)
    )
    # The last period is clean: a half repeating the last reading is judged a duplicate when
    # its module's next frame comes.
    traffic.batches.append(list(periods[-1].messages))
    traffic.counts["valid"] += len(periods[-1].messages)
    truths = {k: p.truth.values.tobytes() for k, p in enumerate(periods)}

    ctx = Context()
    rclpy.init(context=ctx)
    channel = "bench_fuzz"
    overrides = {
        "interface": "virtual",
        "channel": channel,
        "layout": str(LAYOUT),
        "period_ms": 20,
        "max_wait_ms": 20.0,
        "calibration_samples": 5,
        "bus_filter": False,
        "diagnostics_period_s": 0.5,
    }
    driver = SkinDriver(
        context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()]
    )
    listener = Node("fuzz_listener", context=ctx)
    taxels: list[TaxelArray] = []
    diags: list[DiagnosticArray] = []
    deep = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
    listener.create_subscription(TaxelArray, f"{patch.name}/taxels", taxels.append, deep)
    listener.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 50)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(driver)
    executor.add_node(listener)
    stop = threading.Event()
    spinner = threading.Thread(
        target=lambda: [executor.spin_once(timeout_sec=0.01) for _ in iter(stop.is_set, True)]
    )
    spinner.start()
    time.sleep(1.0)  # discovery

    tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    t0 = time.monotonic()
    for k, batch in enumerate(traffic.batches):
        for m in batch:
            tx.send(m)
        time.sleep(max(0.0, t0 + (k + 1) * PERIOD_S - time.monotonic()))
    sent_s = time.monotonic() - t0
    tx.shutdown()

    def frames_counted() -> dict[str, str]:
        for d in reversed(diags):
            for s in d.status:
                if s.name.endswith(": frames"):
                    return {kv.key: kv.value for kv in s.values}
        return {}

    deadline = time.monotonic() + 30.0
    while frames_counted().get("frames") != str(traffic.frames) and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)
    counted = frames_counted()
    bus = next(
        {kv.key: kv.value for kv in s.values}
        for s in diags[-1].status
        if s.name.endswith("CAN bus")
    )
    alive = all(link.thread is not None and link.thread.is_alive() for link in driver._links)
    stop.set()
    spinner.join(5.0)
    executor.shutdown()
    driver.destroy_node()
    listener.destroy_node()
    rclpy.try_shutdown(context=ctx)

    nonfinite = sum(int(np.count_nonzero(~np.isfinite(np.asarray(m.delta_c)))) for m in taxels)
    seen: dict[tuple[int, int], list[bytes]] = {}
    for m in taxels:
        k = round((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9) / PERIOD_S)
        st = np.frombuffer(bytes(m.status), np.uint8)
        for i in range(len(served)):
            if not st[12 * i] & TaxelArray.STATUS_STALE:
                seen.setdefault((k, i), []).append(bytes(m.raw)[12 * i : 12 * i + 12])
    lost = repeated = wrong = 0
    for k in range(args.periods):
        for i in range(len(served)):
            got = seen.get((k, i), [])
            lost += not got
            repeated += len(got) > 1
            wrong += bool(got) and got[0] != truths[k][12 * i : 12 * i + 12]
    print(
        f"fuzz: {traffic.frames} frames ({traffic.garbage} garbage, "
        f"{traffic.counts['valid']} valid) in {args.periods} periods, sent in {sent_s:.1f} s "
        f"({traffic.frames / sent_s:.0f} frames/s)"
    )
    print(f"{'kind':>20} | {'sent':>7} | {'counted':>7}")
    ok = True
    for kind in (*REJECTED_KINDS, *ODD_KINDS):
        key = f"rejected_{kind}" if kind in REJECTED_KINDS else kind
        n = int(counted.get(key, -1))
        ok &= n == traffic.counts[kind]
        print(f"{kind:>20} | {traffic.counts[kind]:7d} | {n:7d}")
    readings = len(served) * args.periods
    print(
        f"crashes: receive thread alive {alive}, internal errors {bus['internal_errors']}; "
        f"NaN/inf published: {nonfinite} in {len(taxels)} messages; "
        f"complete valid readings lost: {lost} of {readings} (repeated {repeated}, "
        f"wrong values {wrong}); incomplete periods {counted.get('incomplete_periods')}, "
        f"orphan B {counted.get('orphan_b')}"
    )
    ok &= alive and bus["internal_errors"] == "0" and nonfinite == 0
    ok &= lost == 0 and repeated == 0 and wrong == 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
