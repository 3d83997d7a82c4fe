"""Skin CAN codec: every byte of both frames, ids, flags, faults, period assembly, fuzzing."""

from __future__ import annotations

import random

import can
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_contact.canbus.assembler import PeriodAssembler
from tactile_contact.canbus.codec import (
    ERROR_I2C,
    ERROR_NOT_CONNECTED,
    FRAME_A,
    FRAME_B,
    BadFrameType,
    BadStatus,
    CodecError,
    TruncatedFrame,
    UnknownId,
    decode_frame,
    encode_frame_a,
    encode_frame_b,
    encode_reading,
    parse_id,
    reading_messages,
    set_board_config,
    set_triangle_config,
    set_tx_mode,
    skin_id,
)


@pytest.mark.parametrize("id_class", [4, 3])
def test_ids_of_both_classes(id_class: int) -> None:
    for board in range(16):
        for tri in range(16):
            cid = skin_id(board, tri, id_class)
            assert cid == (id_class << 8) | (board << 4) | tri
            assert parse_id(cid) == (id_class, board, tri)
    assert skin_id(3, 5) == 0x435
    assert skin_id(3, 5, 3) == 0x335


@pytest.mark.parametrize("id_class", [4, 3])
@pytest.mark.parametrize("pos", range(1, 8))
def test_every_byte_of_frame_a(id_class: int, pos: int) -> None:
    data = bytearray([FRAME_A, 0, 0, 0, 0, 0, 0, 0])
    data[pos] = 0xA5
    f = decode_frame(skin_id(7, 9, id_class), bytes(data), 1.5)
    assert (f.id_class, f.board, f.triangle, f.kind) == (id_class, 7, 9, FRAME_A)
    expect = [0] * 7
    expect[pos - 1] = 0xA5  # data[1..7] = channels 0..6
    assert list(f.values) == expect
    assert (f.oor_mask, f.error_flags, f.timestamp) == (0, 0, 1.5)


@pytest.mark.parametrize("id_class", [4, 3])
@pytest.mark.parametrize("pos", range(1, 6))
def test_channel_bytes_of_frame_b(id_class: int, pos: int) -> None:
    data = bytearray([FRAME_B, 0, 0, 0, 0, 0, 0, 0])
    data[pos] = 0x5A
    f = decode_frame(skin_id(15, 0, id_class), bytes(data))
    expect = [0] * 5
    expect[pos - 1] = 0x5A  # data[1..5] = channels 7..11
    assert list(f.values) == expect and f.kind == FRAME_B
    assert (f.oor_mask, f.error_flags) == (0, 0)


@pytest.mark.parametrize("bit", range(16))
def test_status_word_bits_of_frame_b(bit: int) -> None:
    # data[6..7] is a big-endian word: bits 4..15 = out-of-range of channels 0..11,
    # bit 0 = I²C error, bit 1 = not connected, bits 2..3 reserved.
    word = 1 << bit
    data = bytes([FRAME_B, 1, 2, 3, 4, 5, word >> 8, word & 0xFF])
    f = decode_frame(0x400, data)
    if bit >= 4:
        assert f.oor_mask == 1 << (bit - 4) and f.error_flags == 0
    else:
        assert f.oor_mask == 0 and f.error_flags == word
    if bit in (2, 3):
        with pytest.raises(BadStatus) as info:
            decode_frame(0x400, data, strict_status=True)
        assert info.value.byte == 7
    assert ERROR_I2C == 1 and ERROR_NOT_CONNECTED == 2


@pytest.mark.parametrize("dlc", range(8))
def test_truncated_frames(dlc: int) -> None:
    data = bytes([FRAME_A, 1, 2, 3, 4, 5, 6, 7][:dlc])
    with pytest.raises(TruncatedFrame) as info:
        decode_frame(0x412, data)
    e = info.value
    assert (e.can_id, e.dlc, e.value) == (0x412, dlc, dlc)
    assert "0x412" in str(e) and f"dlc {dlc}" in str(e)
    assert isinstance(e, CodecError) and isinstance(e, ValueError)


@pytest.mark.parametrize("cid", [0x000, 0x123, 0x200, 0x212, 0x512, 0x7FF, 0x800, 0x1FFFFFFF])
def test_unknown_ids(cid: int) -> None:
    with pytest.raises(UnknownId) as info:
        decode_frame(cid, bytes([FRAME_A] + [0] * 7))
    assert info.value.can_id == cid
    # Class 3 is configurable.
    with pytest.raises(UnknownId):
        decode_frame(0x312, bytes([FRAME_A] + [0] * 7), id_classes=(4,))


@pytest.mark.parametrize("kind", [0x00, 0x41, 0x80, 0xC1, 0xFF])
def test_bad_frame_type_names_byte_and_value(kind: int) -> None:
    with pytest.raises(BadFrameType) as info:
        decode_frame(0x400, bytes([kind] + [0] * 7))
    assert (info.value.byte, info.value.value) == (0, kind)
    assert f"data[0] = 0x{kind:02X}" in str(info.value)


@given(
    board=st.integers(0, 15),
    tri=st.integers(0, 15),
    id_class=st.sampled_from([3, 4]),
    values=st.lists(st.integers(0, 255), min_size=12, max_size=12),
    oor=st.integers(0, 0xFFF),
    flags=st.integers(0, 0xF),
)
def test_encode_decode_round_trip(board, tri, id_class, values, oor, flags) -> None:
    (ida, da), (idb, db) = encode_reading(board, tri, values, oor, flags, id_class)
    fa = decode_frame(ida, da)
    fb = decode_frame(idb, db)
    assert list(fa.values) + list(fb.values) == values
    assert (fb.oor_mask, fb.error_flags) == (oor, flags)
    asm = PeriodAssembler()
    r = [asm.feed(m) for m in reading_messages(board, tri, values, oor, flags, id_class, 2.0)]
    assert r[0] is None and r[1] is not None
    got = r[1]
    assert got.values.dtype == np.uint8 and list(got.values) == values
    assert (got.board, got.triangle, got.oor_mask, got.error_flags) == (board, tri, oor, flags)
    assert list(np.flatnonzero(got.out_of_range)) == [k for k in range(12) if oor >> k & 1]


def test_encoder_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="7 values"):
        encode_frame_a([1, 2, 3])
    with pytest.raises(ValueError, match=r"0\.\.255"):
        encode_frame_a([256, 0, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="oor_mask"):
        encode_frame_b([0] * 5, oor_mask=0x1000)
    with pytest.raises(ValueError, match="board"):
        skin_id(16, 0)


def _msg(cid: int, data: bytes, t: float) -> can.Message:
    return can.Message(arbitration_id=cid, data=data, is_extended_id=False, timestamp=t)


VALS = list(range(100, 112))


def _ab(t: float, values=VALS, board=1, tri=2) -> list[can.Message]:
    return reading_messages(board, tri, values, timestamp=t, gap_s=1e-4)


def test_duplicate_a_is_ignored_and_counted() -> None:
    asm = PeriodAssembler()
    a, b = _ab(0.0)
    out = asm.feed_many([a, _msg(a.arbitration_id, a.data, 1e-5), b])
    assert len(out) == 1 and list(out[0].values) == VALS
    mc = asm.module_counters()[(1, 2)]
    assert (mc.duplicates, mc.incomplete, mc.readings) == (1, 0, 1)
    assert asm.counters.duplicates == 1


def test_new_a_before_b_counts_an_incomplete_period() -> None:
    asm = PeriodAssembler()
    a0, _b0 = _ab(0.0, [1] * 12)
    a1, b1 = _ab(0.05, [2] * 12)
    out = asm.feed_many([a0, a1, b1])  # B of period 0 lost
    assert len(out) == 1 and list(out[0].values) == [2] * 12
    assert asm.counters.incomplete == 1
    assert out[0].timestamp == pytest.approx(0.05 + 1e-4)  # the completing frame's time


def test_b_without_a_is_an_orphan_and_never_mixes_periods() -> None:
    asm = PeriodAssembler(pair_window_s=0.01)
    _a0, b0 = _ab(0.0, [1] * 12)
    a1, b1 = _ab(0.05, [2] * 12)
    out = asm.feed_many([b0, a1, b1])  # A of period 0 lost
    assert len(out) == 1 and list(out[0].values) == [2] * 12
    assert asm.counters.orphan_b == 1 and asm.counters.reordered == 0


def test_out_of_order_b_then_a_completes() -> None:
    asm = PeriodAssembler()
    a, b = _ab(1.0)
    out = asm.feed_many([b, a])
    assert len(out) == 1 and list(out[0].values) == VALS
    assert asm.counters.reordered == 1


def test_stale_a_is_not_paired_with_a_later_b() -> None:
    asm = PeriodAssembler(pair_window_s=0.01)
    a0, _ = _ab(0.0, [1] * 12)
    _, b1 = _ab(0.05, [2] * 12)
    a2, b2 = _ab(0.10, [3] * 12)
    out = asm.feed_many([a0, b1, a2, b2])  # B0 and A1 lost: A0 + B1 must not pair
    assert [list(r.values) for r in out] == [[3] * 12]
    assert asm.counters.incomplete == 1 and asm.counters.orphan_b == 1


def test_interleaved_modules_and_error_flags() -> None:
    asm = PeriodAssembler()
    m1 = reading_messages(0, 0, [10] * 12, timestamp=0.0)
    m2 = reading_messages(0, 1, [20] * 12, error_flags=ERROR_NOT_CONNECTED, timestamp=0.0)
    out = asm.feed_many([m1[0], m2[0], m2[1], m1[1]])
    assert [(r.triangle, int(r.values[0])) for r in out] == [(1, 20), (0, 10)]
    assert asm.module_counters()[(0, 1)].error_readings == 1
    assert asm.silent_modules(now=10.0, timeout_s=1.0) == [(0, 0), (0, 1)]
    assert asm.silent_modules(now=0.5, timeout_s=1.0) == []


def test_non_data_frames_are_counted() -> None:
    asm = PeriodAssembler()
    bad = [
        can.Message(arbitration_id=0x412, data=b"\x40" * 8, is_extended_id=True),
        can.Message(arbitration_id=0x412, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(is_error_frame=True),
    ]
    assert asm.feed_many(bad) == []
    c = asm.counters
    assert (c.extended, c.remote, c.error_frames, c.fd) == (1, 1, 1, 0)
    assert c.not_data == 3 and c.rejected == 3


def test_module_filter() -> None:
    asm = PeriodAssembler(modules=[(1, 2)])
    assert asm.feed_many(_ab(0.0, board=3, tri=4)) == []
    assert asm.counters.unexpected_module == 2
    assert len(asm.feed_many(_ab(0.0))) == 1


def test_garbage_interleaved_with_good_frames() -> None:
    """10 000 random frames between good ones: no exception, all good readings, all counted."""
    rng = random.Random(1234)
    good_modules = [(b, t) for b in range(2) for t in range(8)]
    good_ids = {skin_id(b, t, c) for b, t in good_modules for c in (3, 4)}
    asm = PeriodAssembler(modules=good_modules)
    expected = {}
    stream: list[can.Message] = []
    n_garbage = 0
    period = 0.02
    n_periods = 40
    for k in range(n_periods):
        for b, t in good_modules:
            vals = [rng.randrange(256) for _ in range(12)]
            expected[(k, b, t)] = vals
            stream += reading_messages(b, t, vals, timestamp=k * period, gap_s=1e-4)
    out_stream: list[can.Message] = []
    for m in stream:
        out_stream.append(m)
        for _ in range(rng.choice((15, 16))):
            if n_garbage == 10_000:
                break
            while True:
                cid = rng.randrange(0x800) if rng.random() < 0.9 else rng.randrange(1 << 29)
                ext = cid > 0x7FF or rng.random() < 0.05
                if ext or cid not in good_ids:
                    break
            dlc = rng.randrange(9)
            data = bytes(rng.randrange(256) for _ in range(dlc))
            if rng.random() < 0.3 and dlc:
                data = bytes([rng.choice((FRAME_A, FRAME_B))]) + data[1:]
            kind = rng.random()
            out_stream.append(
                can.Message(
                    arbitration_id=cid,
                    data=data,
                    is_extended_id=ext,
                    is_remote_frame=kind < 0.02,
                    is_error_frame=0.02 <= kind < 0.04,
                    timestamp=m.timestamp,
                    check=False,
                )
            )
            n_garbage += 1
    assert n_garbage == 10_000
    got = asm.feed_many(out_stream)
    assert len(got) == len(expected)
    for r in got:
        k = round(r.timestamp / period)
        assert list(r.values) == expected[(k, r.board, r.triangle)]
    c = asm.counters
    assert c.rejected == n_garbage
    assert c.incomplete == c.orphan_b == c.duplicates == 0
    assert c.frames == len(out_stream)


def test_host_commands_bytes() -> None:
    c = set_board_config(5, skin_type=0, period_ms=50, no_load=240)
    assert c.can_id == 0x205 and c.data == bytes([0x4D, 0, 50, 240])
    c = set_triangle_config(5, 0, 15, shift=2, enabled=True, cdc_offset=0x2200)
    assert c.can_id == 0x205 and c.data == bytes([0x50, 0, 15, 2, 1, 0x00, 0x22])
    assert set_triangle_config(1, 3, 3, 2, False, 0x1234).data == bytes(
        [0x50, 3, 3, 2, 0, 0x34, 0x12]
    )
    assert set_tx_mode(15, True) == (0x20F, bytes([0x07, 0]))
    assert set_tx_mode(15, False).data == bytes([0x07, 1])
    m = set_tx_mode(2, True).to_message()
    assert (m.arbitration_id, bytes(m.data), m.is_extended_id) == (0x202, b"\x07\x00", False)
    with pytest.raises(ValueError, match="period_ms"):
        set_board_config(0, 0, 0, 240)
    with pytest.raises(ValueError, match="board"):
        set_tx_mode(16, True)
    with pytest.raises(ValueError, match="before first"):
        set_triangle_config(0, 5, 4, 2, True, 0)
    with pytest.raises(ValueError, match="cdc_offset"):
        set_triangle_config(0, 0, 1, 2, True, 0x10000)


@given(
    plan=st.lists(st.tuples(st.booleans(), st.booleans(), st.booleans()), min_size=1, max_size=40)
)
def test_assembler_never_mixes_periods(plan) -> None:
    """Random loss of A or B and swapped order within a period: every reading is one period's
    own A and B, and every period whose two frames arrived is delivered."""
    asm = PeriodAssembler(pair_window_s=0.01)
    stream = []
    complete = set()
    for k, (keep_a, keep_b, swap) in enumerate(plan):
        a, b = reading_messages(3, 7, [k] * 7 + [k + 100] * 5, timestamp=0.02 * k, gap_s=1e-4)
        frames = [f for f, keep in ((a, keep_a), (b, keep_b)) if keep]
        stream += frames[::-1] if swap else frames
        if keep_a and keep_b:
            complete.add(k)
    got = asm.feed_many(stream)
    for r in got:
        k = int(r.values[0])
        assert list(r.values) == [k] * 7 + [k + 100] * 5
    assert sorted(int(r.values[0]) for r in got) == sorted(complete)
    c = asm.counters
    assert c.readings == len(complete)


def test_decode_accepts_any_bytes_like() -> None:
    raw = bytes([FRAME_B, 1, 2, 3, 4, 5, 0x80, 0x02])
    for data in (raw, bytearray(raw), memoryview(raw)):
        f = decode_frame(0x401, data)
        assert list(f.values) == [1, 2, 3, 4, 5]
        assert (f.oor_mask, f.error_flags) == (0x800, ERROR_NOT_CONNECTED)
    asm = PeriodAssembler()
    asm.feed_raw(0x401, bytearray([FRAME_A] + [9] * 7), 0.0)
    r = asm.feed_raw(0x401, memoryview(raw), 0.0)
    assert r is not None and list(r.values) == [9] * 7 + [1, 2, 3, 4, 5]
    assert r.out_of_range[11] and r.error_flags == ERROR_NOT_CONNECTED


@given(
    can_id=st.integers(0, (1 << 29) - 1),
    data=st.binary(max_size=64),
    strict=st.booleans(),
    classes=st.sampled_from([(4,), (3, 4)]),
)
def test_any_bytes_decode_or_raise_only_the_codecs_error(can_id, data, strict, classes) -> None:
    """Classic and CAN FD lengths (0–64), any id: a SkinFrame or a CodecError, nothing else."""
    try:
        frame = decode_frame(can_id, data, id_classes=classes, strict_status=strict)
    except CodecError as e:
        assert str(e)  # the message names the problem
    else:
        assert len(data) == 8 and data[0] in (FRAME_A, FRAME_B)
        assert len(frame.values) == (7 if data[0] == FRAME_A else 5)


def test_unchanged_periods_squeezed_together_are_readings_not_duplicates() -> None:
    """An adapter or host catching up delivers periods 1 ms apart: an unchanged reading of
    the next period must not be taken for a duplicate of the last one (found by the load
    bench: 23 readings lost in 500 000). A true repeat still counts as a duplicate."""
    asm = PeriodAssembler(duplicate_window_s=0.005)
    values = [240] * 12
    msgs = []
    for k in range(5):
        msgs += reading_messages(1, 2, values, timestamp=0.001 * k, gap_s=1e-4)
    assert len(asm.feed_many(msgs)) == 5
    assert asm.counters.duplicates == 0
    a, b = reading_messages(1, 2, values, timestamp=1.0, gap_s=1e-4)
    a2, b2 = reading_messages(1, 2, [239] * 12, timestamp=1.02, gap_s=1e-4)
    a3, b3 = reading_messages(1, 2, [238] * 12, timestamp=1.04, gap_s=1e-4)
    got = asm.feed_many([a, b, b, a2, b2, a2, b3, a3])  # B repeated, then A repeated
    assert [int(r.values[0]) for r in got] == [240, 239, 238]
    assert asm.counters.duplicates == 2
    assert asm.counters.orphan_b == asm.counters.incomplete == 0
