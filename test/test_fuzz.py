"""Hostile CAN traffic at library level: the assembler and the stream never raise, count every
kind of bad frame, and lose no complete valid reading (hypothesis over seeds and mixes).

The node-level test (real driver over a virtual bus, /diagnostics) is in test_driver_faults.py.
"""

from __future__ import annotations

import random
from pathlib import Path

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.canbus.assembler import PeriodAssembler
from tactile_contact.canbus.codec import reading_messages
from tactile_contact.canbus.fuzz import ODD_KINDS, REJECTED_KINDS, hostile_batches
from tactile_contact.canbus.stream import SkinStream
from tactile_contact.model.layout import load_layout

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"
PERIOD_S = 0.02


def valid_periods(served: list[tuple[int, int]], n: int, seed: int) -> list[list[can.Message]]:
    """n periods of every served module, values encode (period, module) so they can be traced."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        frames = []
        for i, (b, t) in enumerate(served):
            values = rng.integers(1, 255, 12).astype(np.uint8)
            values[0], values[1] = k % 251 + 1, i + 1
            frames += reading_messages(b, t, values.tolist(), timestamp=k * PERIOD_S, gap_s=1e-4)
        out.append(frames)
    return out


@given(
    seed=st.integers(0, 2**32 - 1),
    garbage=st.integers(0, 60),
    kinds=st.lists(st.sampled_from(REJECTED_KINDS), min_size=1, unique=True),
    dup=st.floats(0.0, 0.5),
    swap=st.floats(0.0, 0.5),
)
@settings(max_examples=40)
def test_assembler_counts_every_kind_and_loses_no_reading(seed, garbage, kinds, dup, swap) -> None:
    served = [(0, 0), (0, 1), (2, 5), (15, 15)]
    periods = valid_periods(served, 13, seed)
    traffic = hostile_batches(
        periods[:-1],
        served,
        garbage,
        random.Random(seed),
        duplicate_fraction=dup,
        reorder_fraction=swap,
        kinds=kinds,
    )
    asm = PeriodAssembler(
        id_classes=(4,), modules=served, pair_window_s=0.01, duplicate_window_s=0.005
    )
    # A half that repeats the last reading waits for the module's next frame to be judged a
    # duplicate: the stream goes on with one clean period.
    got = [r for batch in [*traffic.batches, periods[-1]] for r in asm.feed_many(batch)]
    c = asm.counters
    assert c.frames == traffic.frames + len(periods[-1])
    for kind in (*REJECTED_KINDS, *ODD_KINDS):
        assert getattr(c, kind) == traffic.counts[kind], kind
    assert c.incomplete == 0 and c.orphan_b == 0
    expect = sorted(tuple(m.data[1:3]) for batch in periods for m in batch if m.data[0] == 0x40)
    assert sorted(tuple(r.values[:2]) for r in got) == expect
    assert len(got) == len(served) * len(periods)


def test_stream_under_10000_garbage_frames_publishes_every_reading_finite() -> None:
    """The library half of the fuzz figures: SkinStream fed 10 000 garbage frames."""
    patch = load_layout(LAYOUT).patch("hexagon")
    served = [(m.board, m.triangle) for m in patch.modules]
    periods = valid_periods(served, 100, 5)
    traffic = hostile_batches(periods, served, 100, random.Random(5))
    assert traffic.garbage == 10_000
    s = SkinStream([patch], period_s=PERIOD_S, max_wait_s=0.02)
    frames = []
    for k, batch in enumerate(traffic.batches):
        now = k * PERIOD_S
        for m in batch:
            frames += s.feed(m, now)
        frames += s.poll(now + 0.019)
    fresh = 0
    for f in frames:
        assert np.isfinite(f.delta_c).all()
        status = np.frombuffer(f.status, np.uint8).reshape(-1, 12)
        fresh += int(np.sum((status[:, 0] & 32) == 0))
    assert fresh == len(served) * len(periods), "a complete reading was lost or repeated"
    c = s.assembler.counters
    assert c.rejected == traffic.garbage
    values = s.diagnostics(1.0)[0].values
    for kind in REJECTED_KINDS:
        assert values[f"rejected_{kind}"] == traffic.counts[kind] > 0, kind
