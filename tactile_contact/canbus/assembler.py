"""Period assembly: a triangle's frames A and B of one period → one 12-channel reading.

:class:`PeriodAssembler` is fed every received CAN frame (python-can ``Message`` or raw
id/bytes) and returns a :class:`SkinReading` when a frame completes one. Frames that
:mod:`tactile_contact.canbus.codec` refuses, duplicates, orphans and lost periods are counted
(bus-wide
and per module) and never raise. Pure Python, no bus is opened, no ROS import.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import can
import numpy as np
from numpy.typing import NDArray

from tactile_contact.canbus.codec import (
    CHANNEL_BITS,
    CLASS_SKIN,
    DEFAULT_ID_CLASSES,
    ERROR_FLAGS_MASK,
    FRAME_A,
    FRAME_B,
    OOR_SHIFT,
    BadFrameType,
    BadStatus,
    CodecError,
    NotDataFrame,
    OversizedFrame,
    TruncatedFrame,
    UnknownId,
    checked_byte,
    decode_frame,
)


@dataclass(slots=True)
class SkinReading:
    """A triangle's complete reading of one period.

    Attributes:
        board, triangle: module address; id_class: class of the id it came with.
        values: (12,) uint8 channel values [8-bit counts], channel order as sent.
        oor_mask: 12-bit out-of-range mask (bit k = channel k).
        error_flags: module status bits (ERROR_I2C, ERROR_NOT_CONNECTED).
        timestamp: receive time [s] of the frame that completed the reading.
    """

    board: int
    triangle: int
    values: NDArray[np.uint8]
    oor_mask: int
    error_flags: int
    timestamp: float
    id_class: int = CLASS_SKIN

    @property
    def out_of_range(self) -> NDArray[np.bool_]:
        """(12,) True where the module flagged the channel out of range."""
        return (self.oor_mask & CHANNEL_BITS) != 0

    @property
    def key(self) -> tuple[int, int]:
        """(board, triangle)."""
        return self.board, self.triangle


@dataclass(slots=True)
class ModuleCounters:
    """Per-triangle counters (monotonic; for diagnostics)."""

    frames_a: int = 0
    frames_b: int = 0
    readings: int = 0
    incomplete: int = 0
    """Periods lost: a frame A never completed (replaced by a newer A or too old for its B)."""
    duplicates: int = 0
    """Identical frame repeated within the duplicate window (ignored)."""
    orphan_b: int = 0
    """Frames B dropped because no frame A of the same period came."""
    reordered: int = 0
    """Readings completed from B then A."""
    error_readings: int = 0
    """Readings whose module status reported an error flag."""
    last_timestamp: float | None = None
    """Receive time [s] of the last complete reading (None before the first)."""
    last_error_flags: int = 0


@dataclass(slots=True)
class AssemblerCounters:
    """Bus-wide counters (monotonic). ``rejected`` sums the frames that were not skin data."""

    frames: int = 0
    readings: int = 0
    truncated: int = 0
    """DLC below 8."""
    oversized: int = 0
    """More than 8 data bytes in a classic frame."""
    unknown_id: int = 0
    """Standard ids outside the accepted classes (another device's traffic, or garbage)."""
    bad_type: int = 0
    bad_status: int = 0
    error_frames: int = 0
    remote: int = 0
    extended: int = 0
    fd: int = 0
    """CAN FD frames (skin modules send classic frames)."""
    unexpected_module: int = 0
    """Valid skin frames of a (board, triangle) not in the configured module set."""
    duplicates: int = 0
    incomplete: int = 0
    orphan_b: int = 0
    reordered: int = 0

    #: The kinds of rejected frames, each a counter (and a ``rejected_<kind>`` diagnostic).
    REJECT_KINDS = (
        "truncated",
        "oversized",
        "unknown_id",
        "bad_type",
        "bad_status",
        "error_frames",
        "remote",
        "extended",
        "fd",
        "unexpected_module",
    )

    @property
    def not_data(self) -> int:
        """Error, remote, extended-id and CAN FD frames."""
        return self.error_frames + self.remote + self.extended + self.fd

    @property
    def rejected(self) -> int:
        return sum(getattr(self, k) for k in self.REJECT_KINDS)


@dataclass(slots=True)
class _Pending:
    a: bytes | None = None
    ta: float = 0.0
    b: bytes | None = None
    b_oor: int = 0
    b_flags: int = 0
    tb: float = 0.0
    a_dup: bool = False  # the pending half repeats one of the last reading (see _suspect)
    b_dup: bool = False
    done_a: bytes | None = None  # frames of the last completed reading (duplicate check)
    done_b: bytes | None = None
    done_t: float = 0.0
    counters: ModuleCounters = field(default_factory=ModuleCounters)


class PeriodAssembler:
    """Reassemble each triangle's 12 channels per period from its frames A and B.

    Feed every received frame to :meth:`feed` (python-can message) or :meth:`feed_raw`; a
    complete :class:`SkinReading` is returned when the frame completes one, else None. Nothing
    raises for a bad frame: it is counted in :attr:`counters` (bus-wide) and per module, and the
    latest rejection is kept in :attr:`last_error` for throttled logging.

    Pairing rules per triangle (timestamps are receive times [s]):

    - A then B within ``pair_window_s``: complete (the normal case).
    - A while an A is pending: identical bytes within ``duplicate_window_s`` is a duplicate
      (ignored); otherwise the pending period is incomplete and the new A replaces it. A frame
      identical to one of the last completed reading, within the window, waits like any
      other half: paired, it is a reading; dropped unpaired, it counts as a duplicate.
    - B with the pending A older than ``pair_window_s``: that A is dropped (incomplete) and the B
      waits as if it came first.
    - B without A: kept for ``pair_window_s``; an A arriving within it completes the reading
      (reordered); otherwise the B is dropped as an orphan when the next frame of that triangle
      arrives.

    Args:
        id_classes: accepted id classes (4 periodic skin, 3 older firmware).
        modules: (board, triangle) pairs to accept; None accepts all.
        pair_window_s: largest A–B gap of one period [s]; set it below half the period.
        duplicate_window_s: identical frames closer than this [s] are duplicates.
        strict_status: reject frames B with reserved status bits set.
    """

    def __init__(
        self,
        id_classes: Iterable[int] = DEFAULT_ID_CLASSES,
        modules: Iterable[tuple[int, int]] | None = None,
        pair_window_s: float = 0.010,
        duplicate_window_s: float = 0.005,
        strict_status: bool = False,
    ) -> None:
        self.id_classes = tuple(sorted({checked_byte("id_class", c, 0, 7) for c in id_classes}))
        self._class_set = frozenset(self.id_classes)
        if not self.id_classes:
            raise ValueError("id_classes must name at least one class")
        for name, v in (
            ("pair_window_s", pair_window_s),
            ("duplicate_window_s", duplicate_window_s),
        ):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        self.pair_window_s = float(pair_window_s)
        self.duplicate_window_s = float(duplicate_window_s)
        self.strict_status = strict_status
        self._modules: frozenset[int] | None = None
        if modules is not None:
            self._modules = frozenset(
                (checked_byte("board", b, 0, 15) << 4) | checked_byte("triangle", t, 0, 15)
                for b, t in modules
            )
        self._state: dict[int, _Pending] = {}
        self.counters = AssemblerCounters()
        self.last_error: CodecError | None = None

    # -- counters -------------------------------------------------------------------------
    def module_counters(self) -> dict[tuple[int, int], ModuleCounters]:
        """Counters of every triangle seen so far (or configured), keyed by (board, triangle)."""
        return {(k >> 4, k & 0xF): st.counters for k, st in sorted(self._state.items())}

    def silent_modules(self, now: float, timeout_s: float) -> list[tuple[int, int]]:
        """Configured or seen triangles with no complete reading for more than ``timeout_s``."""
        keys = set(self._state) | set(self._modules or ())
        out = []
        for k in sorted(keys):
            st = self._state.get(k)
            last = st.counters.last_timestamp if st is not None else None
            if last is None or now - last > timeout_s:
                out.append((k >> 4, k & 0xF))
        return out

    def reset(self) -> None:
        """Forget pending half-periods (counters are kept)."""
        for st in self._state.values():
            st.a = st.b = None

    # -- input ----------------------------------------------------------------------------
    def feed(self, msg: can.Message) -> SkinReading | None:
        """Process one python-can message; the completed reading or None."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            return self._reject_not_data(msg)
        return self.feed_raw(msg.arbitration_id, msg.data, msg.timestamp)

    def feed_many(self, msgs: Iterable[can.Message]) -> list[SkinReading]:
        """Process messages in order; the readings they completed."""
        out = []
        for m in msgs:
            r = self.feed(m)
            if r is not None:
                out.append(r)
        return out

    def _reject_not_data(self, msg: can.Message) -> None:
        c = self.counters
        c.frames += 1
        if msg.is_error_frame:
            c.error_frames += 1
            kind = "error frame"
        elif msg.is_remote_frame:
            c.remote += 1
            kind = "remote frame"
        elif msg.is_fd:
            c.fd += 1
            kind = "CAN FD frame"
        else:
            c.extended += 1
            kind = "extended-id frame"
        self.last_error = NotDataFrame(
            f"{kind}, skin data are classic standard frames", msg.arbitration_id, msg.dlc
        )
        return None

    def feed_raw(
        self, can_id: int, data: bytes | bytearray, timestamp: float = 0.0
    ) -> SkinReading | None:
        """Process one standard data frame given as id, data and receive time [s]."""
        c = self.counters
        c.frames += 1
        # Fast path for well-formed frames; anything else goes through decode_frame, whose
        # exception names what is wrong.
        kind = data[0] if len(data) == 8 else -1
        if not (
            0 <= can_id <= 0x7FF
            and (can_id >> 8) in self._class_set
            and (
                kind == FRAME_A or (kind == FRAME_B and not (self.strict_status and data[7] & 0xC))
            )
        ):
            try:
                decode_frame(can_id, data, timestamp, self.id_classes, self.strict_status)
            except TruncatedFrame as exc:
                c.truncated += 1
                self.last_error = exc
            except OversizedFrame as exc:
                c.oversized += 1
                self.last_error = exc
            except UnknownId as exc:
                c.unknown_id += 1
                self.last_error = exc
            except BadFrameType as exc:
                c.bad_type += 1
                self.last_error = exc
            except BadStatus as exc:
                c.bad_status += 1
                self.last_error = exc
            return None
        key = can_id & 0xFF
        if self._modules is not None and key not in self._modules:
            c.unexpected_module += 1
            self.last_error = UnknownId("module not configured", can_id, len(data))
            return None
        st = self._state.get(key)
        if st is None:
            st = self._state[key] = _Pending()
        t = timestamp if math.isfinite(timestamp) else 0.0
        if kind == FRAME_A:
            return self._pair_a(st, key, can_id >> 8, bytes(data[1:8]), t)
        status = (data[6] << 8) | data[7]
        return self._pair_b(
            st,
            key,
            can_id >> 8,
            bytes(data[1:6]),
            status >> OOR_SHIFT,
            status & ERROR_FLAGS_MASK,
            t,
        )

    # -- pairing --------------------------------------------------------------------------
    # A frame identical to one of the reading just completed, within the duplicate window, is
    # most likely a duplicate, but it may be the next period of an unchanged reading whose
    # receive times were squeezed together (an adapter or a host catching up). It is kept as
    # a pending half like any other, marked suspect: if its partner comes it was a reading;
    # if it is dropped unpaired it was a duplicate, and is counted as one (not as a lost half).
    def _suspect(self, st: _Pending, v: bytes, done: bytes | None, t: float) -> bool:
        return (
            st.a is None
            and st.b is None
            and v == done
            and abs(t - st.done_t) <= self.duplicate_window_s
        )

    def _drop_a(self, st: _Pending) -> None:
        """The pending A is dropped unpaired: a lost period, or a duplicate if suspect."""
        kind = "duplicates" if st.a_dup else "incomplete"
        setattr(st.counters, kind, getattr(st.counters, kind) + 1)
        setattr(self.counters, kind, getattr(self.counters, kind) + 1)
        st.a = None

    def _drop_b(self, st: _Pending) -> None:
        """The pending B is dropped unpaired: an orphan, or a duplicate if suspect."""
        kind = "duplicates" if st.b_dup else "orphan_b"
        setattr(st.counters, kind, getattr(st.counters, kind) + 1)
        setattr(self.counters, kind, getattr(self.counters, kind) + 1)
        st.b = None

    def _pair_a(self, st: _Pending, key: int, cls: int, va: bytes, t: float) -> SkinReading | None:
        mc, c = st.counters, self.counters
        mc.frames_a += 1
        suspect = self._suspect(st, va, st.done_a, t)
        if st.a is not None:
            if st.a == va and abs(t - st.ta) <= self.duplicate_window_s:
                mc.duplicates += 1
                c.duplicates += 1
                return None
            self._drop_a(st)
        if st.b is not None:
            if abs(t - st.tb) <= self.pair_window_s:
                mc.reordered += 1
                c.reordered += 1
                return self._complete(st, key, cls, va, t)
            self._drop_b(st)
        st.a, st.ta, st.a_dup = va, t, suspect
        return None

    def _pair_b(
        self, st: _Pending, key: int, cls: int, vb: bytes, oor: int, flags: int, t: float
    ) -> SkinReading | None:
        mc, c = st.counters, self.counters
        mc.frames_b += 1
        suspect = self._suspect(st, vb, st.done_b, t)
        if st.a is not None:
            if abs(t - st.ta) <= self.pair_window_s:
                st.b, st.b_oor, st.b_flags = vb, oor, flags
                return self._complete(st, key, cls, st.a, t)
            self._drop_a(st)
        if st.b is not None:
            if st.b == vb and abs(t - st.tb) <= self.duplicate_window_s:
                mc.duplicates += 1
                c.duplicates += 1
                return None
            self._drop_b(st)
        st.b, st.b_oor, st.b_flags, st.tb, st.b_dup = vb, oor, flags, t, suspect
        return None

    def _complete(self, st: _Pending, key: int, cls: int, a: bytes, t: float) -> SkinReading:
        assert st.b is not None
        values = np.frombuffer(a + st.b, dtype=np.uint8).copy()
        r = SkinReading(key >> 4, key & 0xF, values, st.b_oor, st.b_flags, t, cls)
        st.done_a, st.done_b, st.done_t = a, st.b, t
        st.a = st.b = None
        mc = st.counters
        mc.readings += 1
        mc.last_timestamp = t
        mc.last_error_flags = r.error_flags
        if r.error_flags:
            mc.error_readings += 1
        self.counters.readings += 1
        return r
