"""Cost of each stage of the CAN data path (decode, period assembly, baseline, SkinStream)
against python-can receiving the same frames alone.

Load: 16 triangles × 100 Hz (3 200 frames/s), the issue's reference load. Everything runs in
one process on python-can's ``virtual`` bus; the baseline of the table is the cost of
``bus.recv()`` for the same frames, so the ratios say how much SkinStream adds to what any
python-can reader pays anyway. Correctness (every reading delivered, values exact) is checked
before the timings are printed.

Usage: .venv/bin/python bench/bench_codec.py [--quick] [--seconds S]
"""

from __future__ import annotations

import argparse
import time
import uuid

import can
import numpy as np
from benchkit.timing import best_of

from tactile_contact.canbus.assembler import PeriodAssembler
from tactile_contact.canbus.baseline import BaselineTracker
from tactile_contact.canbus.codec import decode_frame, reading_messages

TRIANGLES = 16
RATE_HZ = 100.0


def make_frames(seconds: float, seed: int = 0) -> tuple[list[can.Message], np.ndarray]:
    rng = np.random.default_rng(seed)
    n_periods = round(seconds * RATE_HZ)
    values = rng.integers(200, 250, size=(n_periods, TRIANGLES, 12), dtype=np.uint8)
    msgs: list[can.Message] = []
    for k in range(n_periods):
        t = k / RATE_HZ
        for tri in range(TRIANGLES):
            msgs += reading_messages(
                tri // 8, tri % 8, values[k, tri].tobytes(), timestamp=t + tri * 2.6e-4
            )
    return msgs, values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 s of traffic, 2 repeats")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated traffic [s]")
    args = ap.parse_args()
    seconds = 1.0 if args.quick else args.seconds
    repeats = 2 if args.quick else 5
    msgs, values = make_frames(seconds)
    n = len(msgs)

    # Correctness first: every reading comes back with its exact values.
    asm = PeriodAssembler()
    readings = asm.feed_many(msgs)
    assert len(readings) == values.shape[0] * TRIANGLES, len(readings)
    for i, r in enumerate(readings):
        k, tri = divmod(i, TRIANGLES)
        assert np.array_equal(r.values, values[k, tri])
    assert asm.counters.rejected == 0

    channel = f"bench-{uuid.uuid4().hex}"

    def received(consume=None) -> float:
        """Seconds to take every frame off a virtual bus (they are queued before the clock
        starts), passing each to ``consume`` if given (none: the receiving alone)."""
        with (
            can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
            can.Bus(interface="virtual", channel=channel) as rx,
        ):
            for m in msgs:
                tx.send(m)
            t0 = time.perf_counter()
            if consume is None:
                for _ in range(n):
                    rx.recv(timeout=1.0)
            else:
                for _ in range(n):
                    consume(rx.recv(timeout=1.0))
            return time.perf_counter() - t0

    def recv_and_assemble() -> float:
        a = PeriodAssembler()
        elapsed = received(a.feed)
        # Simulated stamps are kept (preserve_timestamps): bulk sending here is not paced, and
        # wall-clock stamps could put a scheduler pause between a frame A and its B.
        assert a.counters.readings == len(readings), a.counters
        return elapsed

    t_recv = min(received() for _ in range(repeats))
    t_recv_asm = min(recv_and_assemble() for _ in range(repeats))
    t_decode = best_of(
        lambda: [decode_frame(m.arbitration_id, m.data, m.timestamp) for m in msgs], repeats
    )
    t_assemble = best_of(lambda: PeriodAssembler().feed_many(msgs), repeats)

    # Baseline tracking of the whole bus as one patch, once per period.
    n_ch = TRIANGLES * 12
    xy = np.random.default_rng(1).uniform(0, 0.1, (n_ch, 2))
    raw = values.reshape(values.shape[0], n_ch)

    def track() -> None:
        tr = BaselineTracker(n_ch, positions=xy)
        for k in range(raw.shape[0]):
            tr.update(raw[k], k / RATE_HZ)

    t_base = best_of(track, repeats)
    periods = raw.shape[0]

    # The whole ROS-free data path (what the node calls per message): assemble, gather the
    # patch, baseline, publication arrays; one patch of the 16 triangles.
    from tactile_contact.canbus.stream import SkinStream
    from tactile_contact.model.layout import parse_layout

    patch = parse_layout(
        {
            "schema_version": 1,
            "patches": [
                {
                    "name": "bench",
                    "frame_id": "bench",
                    "modules": [
                        {
                            "type": "roboskin12",
                            "board": tri // 8,
                            "triangle": tri % 8,
                            "position": [0.03 * (tri % 4), 0.03 * (tri // 4)],
                        }
                        for tri in range(TRIANGLES)
                    ],
                }
            ],
        }
    ).patches[0]

    def driver_core() -> None:
        stream = SkinStream([patch], period_s=1.0 / RATE_HZ, pair_window_s=0.4 / RATE_HZ)
        pubs = 0
        for m in msgs:
            pubs += len(stream.feed(m, now=m.timestamp))
        assert pubs == periods, pubs

    t_core = best_of(driver_core, repeats)

    us = 1e6 / n
    rows = [
        ("virtual bus recv alone", t_recv * us, 1.0),
        ("decode_frame only", t_decode * us, t_decode / t_recv),
        ("decode + assemble (feed)", t_assemble * us, t_assemble / t_recv),
        ("recv + decode + assemble", t_recv_asm * us, t_recv_asm / t_recv),
        ("baseline update (per frame share)", t_base * us, t_base / t_recv),
        ("SkinStream.feed (all stages)", t_core * us, t_core / t_recv),
    ]
    print(
        f"{n} frames = {seconds:g} s of {TRIANGLES} triangles x {RATE_HZ:g} Hz; best of {repeats}"
    )
    print(f"{'stage':38s} {'us/frame':>10s} {'x recv':>8s}")
    for name, per, ratio in rows:
        print(f"{name:38s} {per:10.2f} {ratio:8.2f}")
    frames_per_s = TRIANGLES * RATE_HZ * 2
    cpu_recv = t_recv / seconds
    cpu_core = t_core / seconds
    print(f"baseline update: {t_base / periods * 1e6:.1f} us per period ({n_ch} channels)")
    total = 100 * (cpu_recv + cpu_core)
    print(
        f"CPU share of one core at {frames_per_s:.0f} frames/s: recv alone {100 * cpu_recv:.2f} %,"
        f" SkinStream {100 * cpu_core:.2f} %, total {total:.2f} % (ROS publishing not included)"
    )


if __name__ == "__main__":
    main()
