"""ROBOSKIN / iCub skin CAN codec: frames ↔ arrays, host commands (DESIGN.md §6).

Pure bytes ↔ numbers. python-can is used only for its ``Message`` container; no bus is opened.

Data frames (classic CAN, 11-bit id ``class<<8 | board<<4 | triangle``, class 4 "periodic
skin" or class 3 on older firmware), two per triangle per period, 8 bytes each:

- frame A: ``data[0] = 0x40``, ``data[1..7]`` = channels 0..6;
- frame B: ``data[0] = 0xC0``, ``data[1..5]`` = channels 7..11, ``data[6..7]`` = a big-endian
  16-bit status word: bit 0 I²C read error, bit 1 no acknowledge to the configuration
  (not connected), bits 4..15 out-of-range flag of channels 0..11.

Decoding raises one :class:`CodecError` subclass per way a frame can be wrong, naming the id,
DLC, byte index and value. :class:`PeriodAssembler` (below) catches them,
counts them and never lets them escape.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

import can
import numpy as np
from numpy.typing import NDArray

FRAME_A = 0x40
FRAME_B = 0xC0
CLASS_SKIN = 4
CLASS_ANALOG_SENSOR = 3
CLASS_POLLING = 2
DEFAULT_ID_CLASSES: tuple[int, ...] = (CLASS_SKIN, CLASS_ANALOG_SENSOR)

CHANNELS = 12
CHANNELS_A = 7
CHANNELS_B = 5

ERROR_I2C = 0x1
"""Status bit 0: the module could not read its converter (no I²C acknowledge)."""
ERROR_NOT_CONNECTED = 0x2
"""Status bit 1: the converter did not acknowledge the configuration (not connected)."""
ERROR_FLAGS_MASK = 0xF
OOR_SHIFT = 4
OOR_MASK_ALL = (1 << CHANNELS) - 1
_CHANNEL_BITS = 1 << np.arange(CHANNELS)

CMD_SET_TXMODE = 0x07
CMD_SET_BRD_CFG = 0x4D
CMD_SET_TRIANG_CFG = 0x50


class CodecError(ValueError):
    """A CAN frame that is not a valid skin data frame.

    Attributes:
        can_id: arbitration id of the frame.
        dlc: its data length.
        byte: index of the offending data byte, or None when the fault is not one byte's.
        value: the offending value (byte value, id, or length).
    """

    def __init__(
        self, reason: str, can_id: int, dlc: int, byte: int | None = None, value: int | None = None
    ) -> None:
        where = f" (data[{byte}] = 0x{value:02X})" if byte is not None and value is not None else ""
        super().__init__(f"CAN id 0x{can_id:03X} dlc {dlc}: {reason}{where}")
        self.can_id = can_id
        self.dlc = dlc
        self.byte = byte
        self.value = value


class TruncatedFrame(CodecError):
    """DLC below 8 (the frame lacks channels or the status word)."""


class UnknownId(CodecError):
    """Id outside the accepted skin classes (or extended / remote / error frame)."""


class BadFrameType(CodecError):
    """data[0] is neither 0x40 (frame A) nor 0xC0 (frame B)."""


class BadStatus(CodecError):
    """Frame B status word has bits set that the protocol leaves reserved (bits 2..3)."""


def skin_id(board: int, triangle: int, id_class: int = CLASS_SKIN) -> int:
    """Arbitration id of a triangle's data frames: ``class<<8 | board<<4 | triangle``."""
    b = _byte("board", board, 0, 15)
    t = _byte("triangle", triangle, 0, 15)
    return (_byte("id_class", id_class, 0, 7) << 8) | (b << 4) | t


def parse_id(
    can_id: int, id_classes: tuple[int, ...] = DEFAULT_ID_CLASSES, dlc: int = 8
) -> tuple[int, int, int]:
    """(id_class, board, triangle) of a skin data id; UnknownId if its class is not accepted."""
    if not 0 <= can_id <= 0x7FF:
        raise UnknownId("not a standard 11-bit id", can_id, dlc, value=can_id)
    cls = can_id >> 8
    if cls not in id_classes:
        raise UnknownId(f"class {cls} not in accepted classes {list(id_classes)}", can_id, dlc)
    return cls, (can_id >> 4) & 0xF, can_id & 0xF


@dataclass(frozen=True, slots=True)
class SkinFrame:
    """One decoded data frame.

    Attributes:
        id_class, board, triangle: from the id.
        kind: FRAME_A (0x40) or FRAME_B (0xC0).
        values: channel values [8-bit counts]: channels 0..6 (A) or 7..11 (B).
        oor_mask: 12-bit out-of-range mask, bit k = channel k (0 for frame A).
        error_flags: status bits 0..3 (ERROR_I2C, ERROR_NOT_CONNECTED; 0 for frame A).
        timestamp: receive time [s].
    """

    id_class: int
    board: int
    triangle: int
    kind: int
    values: bytes
    oor_mask: int
    error_flags: int
    timestamp: float


def decode_frame(
    can_id: int,
    data: bytes | bytearray,
    timestamp: float = 0.0,
    id_classes: tuple[int, ...] = DEFAULT_ID_CLASSES,
    strict_status: bool = False,
) -> SkinFrame:
    """Decode one skin data frame; raises a :class:`CodecError` subclass if it is not one.

    ``strict_status`` also rejects frame B with reserved status bits (2..3) set.
    """
    dlc = len(data)
    cls, board, triangle = parse_id(can_id, id_classes, dlc)
    if dlc < 8:
        raise TruncatedFrame(f"{dlc} data bytes, skin frames have 8", can_id, dlc, value=dlc)
    kind = data[0]
    if kind == FRAME_A:
        return SkinFrame(cls, board, triangle, FRAME_A, bytes(data[1:8]), 0, 0, timestamp)
    if kind == FRAME_B:
        status = (data[6] << 8) | data[7]
        if strict_status and status & 0xC:
            raise BadStatus("reserved status bits 2..3 set", can_id, dlc, 7, data[7])
        return SkinFrame(
            cls,
            board,
            triangle,
            FRAME_B,
            bytes(data[1:6]),
            status >> OOR_SHIFT,
            status & ERROR_FLAGS_MASK,
            timestamp,
        )
    raise BadFrameType("frame type is neither 0x40 (A) nor 0xC0 (B)", can_id, dlc, 0, kind)


def _check_values(values: object, n: int, name: str) -> bytes:
    try:
        b = bytes(values)  # type: ignore[call-overload]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be {n} integers within 0..255, got {values!r}") from exc
    if len(b) != n:
        raise ValueError(f"{name} must hold {n} values, got {len(b)}")
    return b


def encode_frame_a(values: object) -> bytes:
    """Data of frame A from channels 0..6 (7 values 0..255)."""
    return bytes((FRAME_A,)) + _check_values(values, CHANNELS_A, "frame A values")


def encode_frame_b(values: object, oor_mask: int = 0, error_flags: int = 0) -> bytes:
    """Data of frame B from channels 7..11, the 12-bit out-of-range mask and the error bits."""
    if not 0 <= oor_mask <= OOR_MASK_ALL:
        raise ValueError(f"oor_mask must be within 0..0x{OOR_MASK_ALL:X}, got {oor_mask!r}")
    if not 0 <= error_flags <= ERROR_FLAGS_MASK:
        raise ValueError(f"error_flags must be within 0..0xF, got {error_flags!r}")
    status = (oor_mask << OOR_SHIFT) | error_flags
    body = _check_values(values, CHANNELS_B, "frame B values")
    return bytes((FRAME_B,)) + body + bytes((status >> 8, status & 0xFF))


def encode_reading(
    board: int,
    triangle: int,
    values: object,
    oor_mask: int = 0,
    error_flags: int = 0,
    id_class: int = CLASS_SKIN,
) -> tuple[tuple[int, bytes], tuple[int, bytes]]:
    """((id, data A), (id, data B)) of a triangle's 12 channel values [counts]."""
    v = _check_values(values, CHANNELS, "values")
    cid = skin_id(board, triangle, id_class)
    return (cid, encode_frame_a(v[:CHANNELS_A])), (
        cid,
        encode_frame_b(v[CHANNELS_A:], oor_mask, error_flags),
    )


def reading_messages(
    board: int,
    triangle: int,
    values: object,
    oor_mask: int = 0,
    error_flags: int = 0,
    id_class: int = CLASS_SKIN,
    timestamp: float = 0.0,
    gap_s: float = 0.0,
) -> list[can.Message]:
    """Frames A and B as python-can messages (B stamped ``gap_s`` after A)."""
    (ida, da), (idb, db) = encode_reading(board, triangle, values, oor_mask, error_flags, id_class)
    return [
        can.Message(arbitration_id=ida, data=da, is_extended_id=False, timestamp=timestamp),
        can.Message(arbitration_id=idb, data=db, is_extended_id=False, timestamp=timestamp + gap_s),
    ]


class HostCommand(NamedTuple):
    """A host → board command: id ``0x200 | board`` and its data bytes."""

    can_id: int
    data: bytes

    def to_message(self) -> can.Message:
        """As a python-can message (standard id)."""
        return can.Message(arbitration_id=self.can_id, data=self.data, is_extended_id=False)


def _byte(name: str, v: object, lo: int = 0, hi: int = 255) -> int:
    """``v`` as an int within lo..hi (bools and non-integers rejected)."""
    try:
        i = operator.index(v)  # type: ignore[arg-type]
    except TypeError:
        i = None
    if i is None or isinstance(v, bool) or not lo <= i <= hi:
        raise ValueError(f"{name} must be an int within {lo}..{hi}, got {v!r}")
    return i


def _command_id(board: int) -> int:
    return (CLASS_POLLING << 8) | _byte("board", board, 0, 15)


def set_board_config(board: int, skin_type: int, period_ms: int, no_load: int) -> HostCommand:
    """SET_BRD_CFG ``[0x4D, skinType, period_ms, noLoad]`` (skinType 0..15, period 1..255 ms)."""
    return HostCommand(
        _command_id(board),
        bytes(
            (
                CMD_SET_BRD_CFG,
                _byte("skin_type", skin_type, 0, 15),
                _byte("period_ms", period_ms, 1, 255),
                _byte("no_load", no_load),
            )
        ),
    )


def set_triangle_config(
    board: int, first: int, last: int, shift: int, enabled: bool, cdc_offset: int
) -> HostCommand:
    """SET_TRIANG_CFG ``[0x50, first, last, shift, enabled, offLo, offHi]``.

    Triangles ``first..last`` (0..15) of the board; ``cdc_offset`` 0..65535 little-endian. The
    board recalibrates on receipt: send it while the skin is unloaded.
    """
    first = _byte("first", first, 0, 15)
    last = _byte("last", last, 0, 15)
    if last < first:
        raise ValueError(f"last triangle {last} is before first {first}")
    off = _byte("cdc_offset", cdc_offset, 0, 0xFFFF)
    return HostCommand(
        _command_id(board),
        bytes(
            (
                CMD_SET_TRIANG_CFG,
                first,
                last,
                _byte("shift", shift, 0, 15),
                1 if enabled else 0,
                off & 0xFF,
                off >> 8,
            )
        ),
    )


def set_tx_mode(board: int, transmit: bool) -> HostCommand:
    """SET_TXMODE: ``[0x07, 0]`` starts transmission, ``[0x07, 1]`` stops it."""
    return HostCommand(_command_id(board), bytes((CMD_SET_TXMODE, 0 if transmit else 1)))


# --------------------------------------------------------------------------------------------
# Period assembly: frames A + B of one triangle → one 12-channel reading.


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
        return (self.oor_mask & _CHANNEL_BITS) != 0

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
    unknown_id: int = 0
    bad_type: int = 0
    bad_status: int = 0
    not_data: int = 0
    """Extended-id, remote, error or CAN FD frames."""
    unexpected_module: int = 0
    """Valid skin frames of a (board, triangle) not in the configured module set."""
    duplicates: int = 0
    incomplete: int = 0
    orphan_b: int = 0
    reordered: int = 0

    @property
    def rejected(self) -> int:
        return (
            self.truncated
            + self.unknown_id
            + self.bad_type
            + self.bad_status
            + self.not_data
            + self.unexpected_module
        )


@dataclass(slots=True)
class _Pending:
    a: bytes | None = None
    ta: float = 0.0
    b: bytes | None = None
    b_oor: int = 0
    b_flags: int = 0
    tb: float = 0.0
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
      (ignored); otherwise the pending period is incomplete and the new A replaces it.
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
        self.id_classes = tuple(sorted({_byte("id_class", c, 0, 7) for c in id_classes}))
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
                (_byte("board", b, 0, 15) << 4) | _byte("triangle", t, 0, 15) for b, t in modules
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
            return self._reject_not_data(msg.arbitration_id, msg.dlc)
        return self.feed_raw(msg.arbitration_id, msg.data, msg.timestamp)

    def feed_many(self, msgs: Iterable[can.Message]) -> list[SkinReading]:
        """Process messages in order; the readings they completed."""
        out = []
        for m in msgs:
            r = self.feed(m)
            if r is not None:
                out.append(r)
        return out

    def _reject_not_data(self, can_id: int, dlc: int) -> None:
        self.counters.frames += 1
        self.counters.not_data += 1
        self.last_error = UnknownId("not a standard data frame", can_id, dlc)
        return None

    def feed_raw(
        self, can_id: int, data: bytes | bytearray, timestamp: float = 0.0
    ) -> SkinReading | None:
        """Process one standard data frame given as id, data and receive time [s]."""
        c = self.counters
        c.frames += 1
        # Fast path for well-formed frames; anything else goes through decode_frame, whose
        # exception names what is wrong.
        kind = data[0] if len(data) >= 8 else -1
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
    def _pair_a(self, st: _Pending, key: int, cls: int, va: bytes, t: float) -> SkinReading | None:
        mc, c = st.counters, self.counters
        mc.frames_a += 1
        if st.a is not None:
            if st.a == va and abs(t - st.ta) <= self.duplicate_window_s:
                mc.duplicates += 1
                c.duplicates += 1
                return None
            mc.incomplete += 1
            c.incomplete += 1
        if st.b is not None:
            if abs(t - st.tb) <= self.pair_window_s:
                mc.reordered += 1
                c.reordered += 1
                return self._complete(st, key, cls, va, t)
            mc.orphan_b += 1
            c.orphan_b += 1
            st.b = None
        st.a, st.ta = va, t
        return None

    def _pair_b(
        self, st: _Pending, key: int, cls: int, vb: bytes, oor: int, flags: int, t: float
    ) -> SkinReading | None:
        mc, c = st.counters, self.counters
        mc.frames_b += 1
        if st.a is not None:
            if abs(t - st.ta) <= self.pair_window_s:
                st.b, st.b_oor, st.b_flags = vb, oor, flags
                return self._complete(st, key, cls, st.a, t)
            mc.incomplete += 1
            c.incomplete += 1
            st.a = None
        if st.b is not None:
            if st.b == vb and abs(t - st.tb) <= self.duplicate_window_s:
                mc.duplicates += 1
                c.duplicates += 1
                return None
            mc.orphan_b += 1
            c.orphan_b += 1
        st.b, st.b_oor, st.b_flags, st.tb = vb, oor, flags, t
        return None

    def _complete(self, st: _Pending, key: int, cls: int, a: bytes, t: float) -> SkinReading:
        assert st.b is not None
        values = np.frombuffer(a + st.b, dtype=np.uint8).copy()
        r = SkinReading(key >> 4, key & 0xF, values, st.b_oor, st.b_flags, t, cls)
        st.a = st.b = None
        mc = st.counters
        mc.readings += 1
        mc.last_timestamp = t
        mc.last_error_flags = r.error_flags
        if r.error_flags:
            mc.error_readings += 1
        self.counters.readings += 1
        return r
