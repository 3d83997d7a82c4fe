"""The batch messages as CDR bytes, read and written with numpy instead of rclpy's messages.

Why: rclpy turns every message taken into Python objects (a ``TaxelBatch`` of 24 patches:
48 strings, 24 ``Time`` objects, four arrays) and every message published back into C
structs, field by field. For the messages a reconstruction worker takes and publishes
every bus period, that conversion cost more than all the rest of its ROS work
(docs/bench/load.md, "Where the relay's time goes"). Subscribed with ``raw=True`` a message
arrives as its serialized bytes; this module reads ``TaxelBatch`` (and ``TaxelArray``) from
them into numpy arrays without a Python object per element, and writes a ``ContactArray``
as bytes that ``Publisher.publish`` sends unchanged.

The encoding is plain CDR (XCDR1, little-endian: the 4-byte encapsulation header
``00 01 00 00``, then each field aligned to its own size relative to the end of that
header; strings as a uint32 length counting a trailing NUL, sequences as a uint32 count).
test/test_cdr.py checks both directions against rclpy's own ``serialize_message`` and
``deserialize_message`` on random messages; a reader meeting anything else (big-endian data,
a short buffer, counts that do not fit) raises :class:`CdrError` naming the field.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

_HEADER_LE = b"\x00\x01\x00\x00"  # CDR, little-endian, no options
_U32 = struct.Struct("<I")
_TIME = struct.Struct("<iI")
_CONTACT = struct.Struct("<5d")  # force, center x y z, radius
# TaxelBatch's arrays: taxel_ids, delta_c, raw, status (dtype objects: a string is parsed
# again by every np.frombuffer)
_ARRAYS = tuple((np.dtype(t), np.dtype(t).itemsize) for t in ("<u2", "<f4", "u1", "u1"))


class CdrError(ValueError):
    """Bytes that are not the expected message (the text names the field and the offset)."""


class _Reader:
    """Reads CDR fields from ``buf`` in order (offsets relative to the end of the header)."""

    def __init__(self, buf: bytes | memoryview, what: str) -> None:
        self.buf = memoryview(buf)
        self.what = what
        if len(buf) < 4 or bytes(self.buf[:2]) != _HEADER_LE[:2]:
            kind = bytes(self.buf[:2]).hex() if len(buf) >= 2 else "nothing"
            raise CdrError(f"{what}: not little-endian CDR (encapsulation {kind})")
        self.pos = 4

    def _need(self, n: int, field: str) -> None:
        if n < 0 or self.pos + n > len(self.buf):
            raise CdrError(
                f"{self.what}.{field}: {n} bytes needed at offset {self.pos}, "
                f"{len(self.buf) - self.pos} left"
            )

    def align(self, n: int) -> None:
        self.pos += -(self.pos - 4) % n

    def u32(self, field: str) -> int:
        self.align(4)
        self._need(4, field)
        (v,) = _U32.unpack_from(self.buf, self.pos)
        self.pos += 4
        return v

    def time(self, field: str) -> tuple[int, int]:
        self.align(4)
        self._need(8, field)
        v = _TIME.unpack_from(self.buf, self.pos)
        self.pos += 8
        return v

    def string(self, field: str) -> str:
        n = self.u32(field)
        self._need(n, field)
        if n == 0:
            raise CdrError(f"{self.what}.{field}: string without its NUL at offset {self.pos}")
        s = bytes(self.buf[self.pos : self.pos + n - 1]).decode("utf-8")
        self.pos += n
        return s

    def strings(self, field: str) -> list[str]:
        return [self.string(f"{field}[{i}]") for i in range(self.u32(field))]

    def times_ns(self, field: str) -> list[int]:
        n = self.u32(field)
        self._need(8 * n, field)
        v = struct.unpack_from(f"<{2 * n}i", self.buf, self.pos)
        self.pos += 8 * n
        return [v[i] * 1_000_000_000 + v[i + 1] for i in range(0, 2 * n, 2)]

    def u32s(self, field: str) -> tuple[int, ...]:
        n = self.u32(field)
        self._need(4 * n, field)
        v = struct.unpack_from(f"<{n}I", self.buf, self.pos)
        self.pos += 4 * n
        return v

    def array(self, dtype: str, field: str) -> NDArray:
        n = self.u32(field)
        size = np.dtype(dtype).itemsize
        self.align(size)
        self._need(n * size, field)
        a = np.frombuffer(self.buf, dtype=dtype, count=n, offset=self.pos)
        self.pos += n * size
        return a


@dataclass(frozen=True)
class TaxelBatchView:
    """A ``TaxelBatch`` read from its bytes: lists of names, numpy arrays into the buffer.

    Attributes:
        stamp_ns: the message's header stamp [ns since the epoch].
        bus: the bus name.
        patches, frame_ids: per patch.
        stamps_ns: per patch, CAN receive time of its reading [ns since the epoch].
        offsets: P + 1 of them: patch i's taxels are ``[offsets[i], offsets[i + 1])``.
        taxel_ids (uint16), delta_c (float32, F), raw (uint8), status (uint8): (K,) each.
    """

    stamp_ns: int
    bus: str
    patches: list[str]
    frame_ids: list[str]
    stamps_ns: list[int]
    offsets: tuple[int, ...]
    taxel_ids: NDArray[np.uint16]
    delta_c: NDArray[np.float32]
    raw: NDArray[np.uint8]
    status: NDArray[np.uint8]


def _strings(buf: bytes, pos: int, n: int) -> tuple[list[str], int]:
    """n CDR strings from ``pos`` (4-aligned, header included): the strings, the end."""
    out = []
    for _ in range(n):
        pos += -pos % 4  # (pos counts the 4-byte header: alignment is the same)
        (size,) = _U32.unpack_from(buf, pos)
        if size == 0 or pos + 4 + size > len(buf):
            raise CdrError(f"string of {size} bytes at offset {pos}")
        out.append(buf[pos + 4 : pos + 3 + size].decode("utf-8"))
        pos += 4 + size
    return out, pos


#: The names of the batches read lately (TaxelBatch's header frame_id, bus, patches,
#: frame_ids), by their first _NAMES_KEY bytes: (the end of their bytes, those bytes, the
#: names). Why: a bus's batches carry the same names every period, and reading them again
#: (a dozen strings) was a third of read_taxel_batch (≈ 6 of 20 µs a 4-patch batch). A
#: batch's names come from here only when its bytes up to their end are those bytes.
_NAMES_KEY = 64
_NAMES_MAX = 64
_NAMES: dict[bytes, tuple[int, bytes, tuple[str, str, int, list[str], list[str]]]] = {}


def _batch_names(buf: bytes) -> tuple[str, str, int, list[str], list[str], int]:
    """A TaxelBatch's (header frame_id, bus, patch count, patches, frame_ids, the offset
    after them), as read from ``buf`` (the lists the caller's own)."""
    key = buf[12 : 12 + _NAMES_KEY] if type(buf) is bytes else None
    hit = _NAMES.get(key) if key is not None else None
    if hit is not None and buf[12 : hit[0]] == hit[1]:
        frame_id, bus, n, patches, frame_ids = hit[2]
        return frame_id, bus, n, list(patches), list(frame_ids), hit[0]
    u32 = _U32.unpack_from
    (frame_id, bus), pos = _strings(buf, 12, 2)
    (n,) = u32(buf, pos + -pos % 4)
    patches, pos = _strings(buf, pos + -pos % 4 + 4, n)
    (m,) = u32(buf, pos + -pos % 4)
    frame_ids, pos = _strings(buf, pos + -pos % 4 + 4, m)
    if key is not None:
        if len(_NAMES) >= _NAMES_MAX:
            _NAMES.clear()  # (more buses than that, or names that change: read each time)
        _NAMES[key] = (pos, buf[12:pos], (frame_id, bus, n, list(patches), list(frame_ids)))
    return frame_id, bus, n, patches, frame_ids, pos


def read_taxel_batch(buf: bytes) -> TaxelBatchView:
    """A ``tactile_contact/TaxelBatch`` from its serialized bytes (checks every count).

    One flat function: a method call per field cost more than the fields' reading here.
    """
    if buf[:2] != _HEADER_LE[:2]:
        raise CdrError(f"TaxelBatch: not little-endian CDR (encapsulation {buf[:2].hex()!r})")
    u32 = _U32.unpack_from
    try:
        sec, nsec = _TIME.unpack_from(buf, 4)
        frame_id, bus, n, patches, frame_ids, pos = _batch_names(buf)
        pos += -pos % 4
        (m,) = u32(buf, pos)
        t = struct.unpack_from(f"<{2 * m}i", buf, pos + 4)
        stamps = [t[i] * 1_000_000_000 + t[i + 1] for i in range(0, 2 * m, 2)]
        pos += 4 + 8 * m
        (m,) = u32(buf, pos)
        offsets = struct.unpack_from(f"<{m}I", buf, pos + 4)
        pos += 4 + 4 * m
        arrays = []
        for dtype, size in _ARRAYS:
            pos += -pos % 4
            (m,) = u32(buf, pos)
            pos += 4 + -(pos + 4) % size
            arrays.append(np.frombuffer(buf, dtype=dtype, count=m, offset=pos))
            pos += m * size
    except (struct.error, ValueError) as exc:  # (frombuffer: "buffer is smaller than ...")
        raise CdrError(f"TaxelBatch: truncated or malformed ({exc})") from None
    ids, delta_c, raw, status = arrays
    k = len(ids)
    cuts = len(offsets) == n + 1 or len(offsets) == n == 0  # (an empty batch: [] or [0])
    if not (len(frame_ids) == len(stamps) == n and cuts):
        raise CdrError(
            f"TaxelBatch: {n} patches but {len(frame_ids)} frame_ids, {len(stamps)} stamps, "
            f"{len(offsets)} offsets (patches + 1 expected)"
        )
    if not (len(delta_c) == len(raw) == len(status) == k):
        raise CdrError(
            f"TaxelBatch: array lengths differ: taxel_ids {k}, delta_c {len(delta_c)}, "
            f"raw {len(raw)}, status {len(status)}"
        )
    # (Python on a few dozen ints: each numpy call costs more than the whole check)
    if n and (offsets[0] != 0 or offsets[-1] != k or any(map(int.__gt__, offsets, offsets[1:]))):
        raise CdrError(f"TaxelBatch: offsets {list(offsets[:8])}… do not cut {k} taxels")
    del frame_id
    return TaxelBatchView(
        sec * 1_000_000_000 + nsec, bus, patches, frame_ids, stamps, offsets, *arrays
    )


@dataclass(frozen=True)
class TaxelArrayView:
    """A ``TaxelArray`` read from its bytes (the arrays point into the buffer)."""

    stamp_ns: int
    frame_id: str
    patch: str
    taxel_ids: NDArray[np.uint16]
    delta_c: NDArray[np.float32]
    raw: NDArray[np.uint8]
    status: NDArray[np.uint8]


def read_taxel_array(buf: bytes | memoryview) -> TaxelArrayView:
    """A ``tactile_contact/TaxelArray`` from its serialized bytes."""
    r = _Reader(buf, "TaxelArray")
    sec, nsec = r.time("header.stamp")
    frame_id = r.string("header.frame_id")
    patch = r.string("patch")
    ids = r.array("<u2", "taxel_ids")
    delta_c = r.array("<f4", "delta_c")
    raw = r.array("u1", "raw")
    status = r.array("u1", "status")
    return TaxelArrayView(sec * 1_000_000_000 + nsec, frame_id, patch, ids, delta_c, raw, status)


@dataclass
class ContactRows:
    """What one ``ContactArray`` carries, as lists (see msg/ContactArray.msg).

    Per patch: ``patches``, ``frame_ids``, ``stamps_ns`` [ns since the epoch], ``states``
    (ContactArray.IDLE, CONTACT, HELD, FAILED), ``total_force`` [N], ``cop_x``, ``cop_y`` [m],
    ``latency`` [s]. Per contact: ``force`` [N], ``center`` (x, y, z) [m], ``radius`` [m],
    ``profile``, ``contact_patch`` (index into the patches).
    """

    patches: list[str] = field(default_factory=list)
    frame_ids: list[str] = field(default_factory=list)
    stamps_ns: list[int] = field(default_factory=list)
    states: list[int] = field(default_factory=list)
    total_force: list[float] = field(default_factory=list)
    cop_x: list[float] = field(default_factory=list)
    cop_y: list[float] = field(default_factory=list)
    latency: list[float] = field(default_factory=list)
    force: list[float] = field(default_factory=list)
    center: list[tuple[float, float, float]] = field(default_factory=list)
    radius: list[float] = field(default_factory=list)
    profile: list[str] = field(default_factory=list)
    contact_patch: list[int] = field(default_factory=list)


def write_contact_array(stamp_ns: int, worker: str, rows: ContactRows) -> bytes:
    """A ``tactile_contact/ContactArray`` as serialized bytes (header frame_id empty).

    Raises:
        ValueError: the per-patch or per-contact lists differ in length, or hold NaN or inf
            (nothing that cannot be published is written).
    """
    p, c = len(rows.patches), len(rows.profile)
    per_patch = (rows.frame_ids, rows.stamps_ns, rows.states, rows.total_force, rows.cop_x)
    per_patch += (rows.cop_y, rows.latency)
    per_contact = (rows.force, rows.center, rows.radius, rows.contact_patch)
    if any(len(a) != p for a in per_patch) or any(len(a) != c for a in per_contact):
        raise ValueError(
            f"ContactArray: {p} patches and {c} contacts, but per-patch lengths "
            f"{[len(a) for a in per_patch]} and per-contact {[len(a) for a in per_contact]}"
        )
    floats = [*rows.total_force, *rows.cop_x, *rows.cop_y, *rows.latency, *rows.force]
    floats += [*rows.radius, *(x for xyz in rows.center for x in xyz)]
    if not all(map(math.isfinite, floats)):
        raise ValueError("ContactArray: non-finite value(s); not published")
    # One flat function (see read_taxel_batch); `out` includes the 4-byte header, which keeps
    # every alignment as it is relative to the header's end.
    out = bytearray(_HEADER_LE)
    out += _TIME.pack(*divmod(stamp_ns, 1_000_000_000))
    _put_strings(out, ("", worker))  # header.frame_id, worker
    for items in (rows.patches, rows.frame_ids):
        out += b"\x00" * (-len(out) % 4)
        out += _U32.pack(len(items))
        _put_strings(out, items)
    out += b"\x00" * (-len(out) % 4)
    flat = [x for t in rows.stamps_ns for x in divmod(t, 1_000_000_000)]
    out += struct.pack(f"<I{len(flat)}i", p, *flat)
    out += struct.pack(f"<I{p}B", p, *rows.states)
    for values in (rows.total_force, rows.cop_x, rows.cop_y, rows.latency):
        out += b"\x00" * (-len(out) % 4)
        out += _U32.pack(p)
        if p:
            out += b"\x00" * (-(len(out) - 4) % 8)
            out += struct.pack(f"<{p}d", *values)
    out += b"\x00" * (-len(out) % 4)
    out += _U32.pack(c)
    for k in range(c):
        out += b"\x00" * (-(len(out) - 4) % 8)
        out += _CONTACT.pack(rows.force[k], *rows.center[k], rows.radius[k])
        _put_strings(out, (rows.profile[k],))
    out += b"\x00" * (-len(out) % 4)
    out += struct.pack(f"<I{c}I", c, *rows.contact_patch)
    return bytes(out)


def _put_strings(out: bytearray, items: Sequence[str]) -> None:
    """Append CDR strings (each 4-aligned, its length counting a trailing NUL)."""
    for s in items:
        b = s.encode("utf-8")
        out += b"\x00" * (-len(out) % 4)
        out += _U32.pack(len(b) + 1)
        out += b
        out += b"\x00"


def write_taxel_batch(
    stamp_ns: int,
    bus: str,
    patches: Sequence[str],
    frame_ids: Sequence[str],
    stamps_ns: Sequence[int],
    taxel_ids: Sequence[NDArray],
    delta_c: Sequence[NDArray],
    raw: Sequence[NDArray],
    status: Sequence[NDArray],
) -> bytes:
    """A ``tactile_contact/TaxelBatch`` as serialized bytes, from per-patch arrays (header
    frame_id empty; the arrays are concatenated, the offsets made from their lengths).

    Raises:
        ValueError: the per-patch sequences differ in length, or a patch's arrays do.
    """
    n = len(patches)
    if not (len(frame_ids) == len(stamps_ns) == len(taxel_ids) == n):
        raise ValueError(
            f"TaxelBatch: {n} patches but {len(frame_ids)} frame_ids, {len(stamps_ns)} stamps, "
            f"{len(taxel_ids)} taxel arrays"
        )
    sizes = [len(a) for a in taxel_ids]
    for name, arrays in (("delta_c", delta_c), ("raw", raw), ("status", status)):
        if [len(a) for a in arrays] != sizes:
            raise ValueError(f"TaxelBatch: {name} lengths {[len(a) for a in arrays]} != {sizes}")
    offsets = [0]
    for k in sizes:
        offsets.append(offsets[-1] + k)
    out = bytearray(_HEADER_LE)
    out += _TIME.pack(*divmod(stamp_ns, 1_000_000_000))
    _put_strings(out, ("", bus))  # header.frame_id, bus
    for items in (patches, frame_ids):
        out += b"\x00" * (-len(out) % 4)
        out += _U32.pack(len(items))
        _put_strings(out, items)
    out += b"\x00" * (-len(out) % 4)
    flat = [x for t in stamps_ns for x in divmod(t, 1_000_000_000)]
    out += struct.pack(f"<I{len(flat)}i", n, *flat)
    out += struct.pack(f"<I{len(offsets)}I", len(offsets), *offsets)
    k = offsets[-1]
    for arrays, dtype in ((taxel_ids, "<u2"), (delta_c, "<f4"), (raw, "u1"), (status, "u1")):
        out += b"\x00" * (-len(out) % 4)
        out += _U32.pack(k)
        for a in arrays:
            if isinstance(a, (bytes, bytearray)) and dtype == "u1":
                out += a  # (the driver's raw values and flags: bytes already)
            else:
                out += np.ascontiguousarray(a, dtype=dtype).tobytes()
    return bytes(out)


def read_contact_array(buf: bytes) -> tuple[str, ContactRows]:
    """A ``tactile_contact/ContactArray`` from its bytes: (worker, its rows) — for listeners
    that take many of them (a load benchmark's probe) without rclpy's message objects."""
    if buf[:2] != _HEADER_LE[:2]:
        raise CdrError(f"ContactArray: not little-endian CDR (encapsulation {buf[:2].hex()!r})")
    u32 = _U32.unpack_from
    rows = ContactRows()
    try:
        (_, worker), pos = _strings(buf, 12, 2)  # header.frame_id, worker
        for items in (rows.patches, rows.frame_ids):
            (n,) = u32(buf, pos + -pos % 4)
            got, pos = _strings(buf, pos + -pos % 4 + 4, n)
            items += got
        pos += -pos % 4
        (n,) = u32(buf, pos)
        t = struct.unpack_from(f"<{2 * n}i", buf, pos + 4)
        rows.stamps_ns = [t[i] * 1_000_000_000 + t[i + 1] for i in range(0, 2 * n, 2)]
        pos += 4 + 8 * n
        (n,) = u32(buf, pos)
        rows.states = list(buf[pos + 4 : pos + 4 + n])
        pos += 4 + n
        for name in ("total_force", "cop_x", "cop_y", "latency"):
            pos += -pos % 4
            (n,) = u32(buf, pos)
            pos += 4
            if n:
                pos += -(pos - 4) % 8
            setattr(rows, name, list(struct.unpack_from(f"<{n}d", buf, pos)))
            pos += 8 * n
        pos += -pos % 4
        (c,) = u32(buf, pos)
        pos += 4
        for _ in range(c):
            pos += -(pos - 4) % 8
            force, x, y, z, radius = _CONTACT.unpack_from(buf, pos)
            (profile,), pos = _strings(buf, pos + 40, 1)
            rows.force.append(force)
            rows.center.append((x, y, z))
            rows.radius.append(radius)
            rows.profile.append(profile)
        pos += -pos % 4
        (c,) = u32(buf, pos)
        rows.contact_patch = list(struct.unpack_from(f"<{c}I", buf, pos + 4))
    except struct.error as exc:
        raise CdrError(f"ContactArray: truncated or malformed ({exc})") from None
    return worker, rows
