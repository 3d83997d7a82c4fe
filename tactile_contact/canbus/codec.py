"""ROBOSKIN / iCub skin CAN codec: frames ↔ arrays, host commands (DESIGN.md §6).

Pure bytes ↔ numbers. python-can is used only for its ``Message`` container; no bus is opened.

Data frames (classic CAN, 11-bit id ``class<<8 | board<<4 | triangle``, class 4 "periodic
skin" or class 3 on older firmware), two per triangle per period, 8 bytes each:

- frame A: ``data[0] = 0x40``, ``data[1..7]`` = channels 0..6;
- frame B: ``data[0] = 0xC0``, ``data[1..5]`` = channels 7..11, ``data[6..7]`` = a big-endian
  16-bit status word: bit 0 I²C read error, bit 1 no acknowledge to the configuration
  (not connected), bits 4..15 out-of-range flag of channels 0..11.

Decoding raises one :class:`CodecError` subclass per way a frame can be wrong (and nothing
else, for any id and any bytes), naming the id,
DLC, byte index and value. :class:`tactile_contact.canbus.assembler.PeriodAssembler`
catches them, counts them and never lets them escape.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import NamedTuple

import can
import numpy as np

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
CHANNEL_BITS = 1 << np.arange(CHANNELS)

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


class OversizedFrame(CodecError):
    """More than 8 data bytes: not a classic CAN frame (skin frames have exactly 8)."""


class UnknownId(CodecError):
    """Id outside the accepted skin classes."""


class NotDataFrame(CodecError):
    """An error, remote, extended-id or CAN FD frame (skin data are classic standard frames)."""


class BadFrameType(CodecError):
    """data[0] is neither 0x40 (frame A) nor 0xC0 (frame B)."""


class BadStatus(CodecError):
    """Frame B status word has bits set that the protocol leaves reserved (bits 2..3)."""


def skin_id(board: int, triangle: int, id_class: int = CLASS_SKIN) -> int:
    """Arbitration id of a triangle's data frames: ``class<<8 | board<<4 | triangle``."""
    b = checked_byte("board", board, 0, 15)
    t = checked_byte("triangle", triangle, 0, 15)
    return (checked_byte("id_class", id_class, 0, 7) << 8) | (b << 4) | t


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
    if dlc > 8:
        raise OversizedFrame(f"{dlc} data bytes, classic frames have at most 8", can_id, dlc)
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


def checked_byte(name: str, v: object, lo: int = 0, hi: int = 255) -> int:
    """``v`` as an int within lo..hi (bools and non-integers rejected)."""
    try:
        i = operator.index(v)  # type: ignore[arg-type]
    except TypeError:
        i = None
    if i is None or isinstance(v, bool) or not lo <= i <= hi:
        raise ValueError(f"{name} must be an int within {lo}..{hi}, got {v!r}")
    return i


def _command_id(board: int) -> int:
    return (CLASS_POLLING << 8) | checked_byte("board", board, 0, 15)


def set_board_config(board: int, skin_type: int, period_ms: int, no_load: int) -> HostCommand:
    """SET_BRD_CFG ``[0x4D, skinType, period_ms, noLoad]`` (skinType 0..15, period 1..255 ms)."""
    return HostCommand(
        _command_id(board),
        bytes(
            (
                CMD_SET_BRD_CFG,
                checked_byte("skin_type", skin_type, 0, 15),
                checked_byte("period_ms", period_ms, 1, 255),
                checked_byte("no_load", no_load),
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
    first = checked_byte("first", first, 0, 15)
    last = checked_byte("last", last, 0, 15)
    if last < first:
        raise ValueError(f"last triangle {last} is before first {first}")
    off = checked_byte("cdc_offset", cdc_offset, 0, 0xFFFF)
    return HostCommand(
        _command_id(board),
        bytes(
            (
                CMD_SET_TRIANG_CFG,
                first,
                last,
                checked_byte("shift", shift, 0, 15),
                1 if enabled else 0,
                off & 0xFF,
                off >> 8,
            )
        ),
    )


def set_tx_mode(board: int, transmit: bool) -> HostCommand:
    """SET_TXMODE: ``[0x07, 0]`` starts transmission, ``[0x07, 1]`` stops it."""
    return HostCommand(_command_id(board), bytes((CMD_SET_TXMODE, 0 if transmit else 1)))
