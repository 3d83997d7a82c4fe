"""The driver's idle gate (skin_driver ``idle_every``): how late it lets a press through, how
many idle readings it sends, and what it costs per reading beside the driver's own work.

The simulated default hexagon (point taxels, 8-bit readings, Gaussian CDC noise) goes through
the driver's SkinStream (module frames → patch readings, baseline, ΔC) and an IdleGate, as in
skin_driver. Each press of the accuracy protocol (4 indenters × the forces × 6 places: over
a taxel, between two, between three, on two modules) starts after two whole keep-alive
cycles of idle readings at a random phase of the keep-alive; the figure is the number of
periods from its start to its first reading the gate sends (0 or 1: at once; ``every``: only
the keep-alive found it). Idle readings: the share of those two cycles' readings that went
out (1/every when noise never crosses the thresholds). Cost: the gate's time per reading
beside SkinStream.feed's for the same readings (the driver's per-reading work before it;
their ratio in the same run).

    python bench/bench_idle_gate.py [--every 10] [--noise 0.5 0.7] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from benchkit.protocol import FORCES, INDENTERS, positions

from tactile_contact.canbus.idle_gate import IdleGate
from tactile_contact.canbus.stream import SkinStream
from tactile_contact.model.layout import load_layout
from tactile_contact.sim.simulator import Indentation, simulator_for_patch

ROOT = Path(__file__).resolve().parents[1]
PERIOD_S = 0.02
IDLE_COUNTS = 3.0  # skin_driver's default


def run(every: int, noise: float, seed: int = 1) -> dict:
    """Every press of the protocol at ``noise`` counts [8-bit] through a gate at ``every``."""
    patch = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0]
    count = patch.sensor.farad_per_count * 2.0**patch.sensor.shift
    cdc = noise * 2.0**patch.sensor.shift  # (the simulator's noise is in CDC counts)
    places = positions(patch.taxel_xy(), (4, 2), patch.taxel_ids())
    rng = np.random.default_rng(seed)
    delays: dict[float, list[int]] = {}
    idle: list[bool] = []
    feed_s = gate_s = 0.0
    readings = 0
    for force in FORCES:
        for ind in INDENTERS.values():
            for _, centre in places:
                sim = simulator_for_patch(
                    patch, period_s=PERIOD_S, noise_cdc=cdc, seed=int(rng.integers(1 << 30))
                )
                stream = SkinStream([patch], period_s=PERIOD_S)
                gate = IdleGate(every, IDLE_COUNTS, {patch.name: count})
                # idle readings counted over two whole keep-alive cycles after calibration
                # (0.4 s), then the press at a random phase of the keep-alive
                idle_end = 0.5 + 2 * every * PERIOD_S
                onset = idle_end + 0.1 + rng.uniform(0.0, every) * PERIOD_S
                press = Indentation.press(
                    ind, force, tuple(centre), start_s=onset, ramp_s=0.01, hold_s=2.0
                )
                first = None
                for k in range(int((onset + 0.5) / PERIOD_S)):
                    t = k * PERIOD_S
                    messages = sim.period(press, t).messages
                    t0 = time.perf_counter()
                    frames = [f for m in messages for f in stream.feed(m, t)]
                    t1 = time.perf_counter()
                    sent = [gate.passes(f) for f in frames]
                    t2 = time.perf_counter()
                    feed_s, gate_s, readings = feed_s + t1 - t0, gate_s + t2 - t1, readings + 1
                    for s in sent:
                        if 0.5 <= t < idle_end - 1e-9:
                            idle.append(s)
                        if s and t >= onset and first is None:
                            first = round((t - onset) / PERIOD_S)
                delays.setdefault(force, []).append(every if first is None else first)
    return {
        "delays": delays,
        "idle_sent": float(np.mean(idle)),
        "feed_us": feed_s / readings * 1e6,
        "gate_us": gate_s / readings * 1e6,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--every", type=int, default=10, help="skin_driver idle_every")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.5, 0.7], help="[8-bit counts]")
    ap.add_argument("--out", type=Path, help="also write idle_gate.md here")
    args = ap.parse_args()
    lines = [
        f"idle_every {args.every}, idle_counts {IDLE_COUNTS:g}; the default hexagon (72 taxels),"
        f" {len(INDENTERS)} indenters × 6 places a force; periods from a press's start to its "
        "first reading sent",
        "",
    ]
    for noise in args.noise:
        r = run(args.every, noise)
        lines += [
            f"### noise {noise:g} count",
            "",
            f"idle readings sent: {r['idle_sent']:.1%} (1/idle_every = {1 / args.every:.1%}); "
            f"per reading: the gate {r['gate_us']:.1f} µs, SkinStream.feed {r['feed_us']:.1f} µs "
            f"(×{r['gate_us'] / r['feed_us']:.2f})",
            "",
            "| force N | at once (≤ 1) | within 5 | median | worst |",
            "|---|---|---|---|---|",
        ]
        for force, d in r["delays"].items():
            a = np.asarray(d)
            lines.append(
                f"| {force:g} | {np.mean(a <= 1):.0%} | {np.mean(a <= 5):.0%} | "
                f"{np.median(a):.0f} | {a.max()} |"
            )
        lines.append("")
        print("\n".join(lines[-(len(r["delays"]) + 6) :]), flush=True)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        cmd = " ".join(["python bench/bench_idle_gate.py", *sys.argv[1:]])
        text = f"# The driver's idle gate (bench/bench_idle_gate.py)\n\n`{cmd}`\n\n"
        (args.out / "idle_gate.md").write_text(text + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
