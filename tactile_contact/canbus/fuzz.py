"""Hostile CAN traffic around a valid skin stream, with the count of every kind it holds.

For the fuzz test and ``bench/bench_fuzz.py``: :func:`hostile_batches` takes the valid frames
of each period (e.g. :class:`tactile_contact.sim.simulator.SkinSimulator` periods) and mixes in
garbage of every kind a skin driver must survive, each frame labelled, so the counts the
driver reports can be checked one kind at a time:

============================  =============================================================
kind                          frames
============================  =============================================================
``unknown_id``                random standard ids outside the skin class, 0–8 data bytes
``truncated``                 a served module's id with 0–7 data bytes
``oversized``                 a served module's id, classic frame with 9–64 data bytes
``fd``                        CAN FD frames (0–64 bytes) with skin ids
``bad_type``                  a served module's id, 8 bytes, data[0] neither 0x40 nor 0xC0
``unexpected_module``         valid frames A / B of a module that no patch has
``remote``                    remote frames (skin ids, DLC 0–8)
``extended``                  29-bit ids (with skin-like low bits), 0–8 bytes
``error_frames``              error frames of every SocketCAN error class
``duplicates``                a valid frame sent twice in a row
``reordered``                 a valid reading whose frame B comes before its frame A
============================  =============================================================

The valid frames keep their order within each module; garbage never imitates a valid frame
(it would be data, not garbage). Deterministic for a given ``random.Random``.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import can

from tactile_contact.canbus.codec import CLASS_SKIN, FRAME_A, FRAME_B

#: Kinds of garbage, each a counter of the assembler (``rejected_<kind>`` in /diagnostics).
REJECTED_KINDS = (
    "unknown_id",
    "truncated",
    "oversized",
    "fd",
    "bad_type",
    "unexpected_module",
    "remote",
    "extended",
    "error_frames",
)
#: Kinds that are valid data delivered oddly (counted, never rejected nor lost).
ODD_KINDS = ("duplicates", "reordered")
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
#: SocketCAN error classes (linux/can/error.h), bus-off included.
ERROR_CLASSES = (0x001, 0x002, 0x004, 0x008, 0x010, 0x020, 0x040, 0x080, 0x100, 0x200)


@dataclass
class HostileTraffic:
    """Batches of frames to send (one per period) and what they hold."""

    batches: list[list[can.Message]]
    counts: Counter[str] = field(default_factory=Counter)
    """Frames sent per kind (``valid`` for the stream's own frames, duplicates excluded)."""

    @property
    def garbage(self) -> int:
        return sum(self.counts[k] for k in REJECTED_KINDS)

    @property
    def frames(self) -> int:
        return sum(len(b) for b in self.batches)


def _rand_bytes(rng: random.Random, n: int) -> bytes:
    return rng.randbytes(n)


def _garbage(
    rng: random.Random, kind: str, served: Sequence[tuple[int, int]], t: float
) -> can.Message:
    b, tri = served[rng.randrange(len(served))]
    skin = (CLASS_SKIN << 8) | (b << 4) | tri
    std = {"is_extended_id": False, "timestamp": t}
    if kind == "unknown_id":
        cid = rng.randrange(0x800)
        while cid >> 8 == CLASS_SKIN:
            cid = rng.randrange(0x800)
        return can.Message(arbitration_id=cid, data=_rand_bytes(rng, rng.randrange(9)), **std)
    if kind == "truncated":
        data = bytes([rng.choice((FRAME_A, FRAME_B))]) + _rand_bytes(rng, 7)
        return can.Message(arbitration_id=skin, data=data[: rng.randrange(8)], **std)
    if kind == "oversized":
        data = bytes([rng.choice((FRAME_A, FRAME_B))]) + _rand_bytes(rng, rng.randrange(8, 64))
        return can.Message(arbitration_id=skin, data=data, **std)
    if kind == "fd":
        n = rng.choice(FD_LENGTHS)
        return can.Message(
            arbitration_id=skin,
            data=_rand_bytes(rng, n),
            is_fd=True,
            bitrate_switch=rng.random() < 0.5,
            **std,
        )
    if kind == "bad_type":
        first = rng.randrange(256)
        while first in (FRAME_A, FRAME_B):
            first = rng.randrange(256)
        return can.Message(arbitration_id=skin, data=bytes([first]) + _rand_bytes(rng, 7), **std)
    if kind == "unexpected_module":
        taken = set(served)
        while True:
            ob, ot = rng.randrange(16), rng.randrange(16)
            if (ob, ot) not in taken:
                break
        data = bytes([rng.choice((FRAME_A, FRAME_B))]) + _rand_bytes(rng, 7)
        return can.Message(arbitration_id=(CLASS_SKIN << 8) | (ob << 4) | ot, data=data, **std)
    if kind == "remote":
        return can.Message(arbitration_id=skin, is_remote_frame=True, dlc=rng.randrange(9), **std)
    if kind == "extended":
        cid = (rng.randrange(1 << 18) << 11) | skin
        return can.Message(
            arbitration_id=cid,
            data=_rand_bytes(rng, rng.randrange(9)),
            is_extended_id=True,
            timestamp=t,
        )
    if kind == "error_frames":
        cls = rng.choice(ERROR_CLASSES)
        return can.Message(
            arbitration_id=cls,
            data=_rand_bytes(rng, 8),
            is_error_frame=True,
            **std,
        )
    raise ValueError(f"unknown garbage kind {kind!r}")


def hostile_batches(
    periods: Iterable[Sequence[can.Message]],
    served: Sequence[tuple[int, int]],
    garbage_per_period: int,
    rng: random.Random,
    *,
    duplicate_fraction: float = 0.05,
    reorder_fraction: float = 0.05,
    kinds: Sequence[str] = REJECTED_KINDS,
) -> HostileTraffic:
    """Each period's valid frames with ``garbage_per_period`` garbage frames mixed in.

    Args:
        periods: per period, the valid frames (A then B per module) with their timestamps.
        served: (board, triangle) of every module the driver serves.
        garbage_per_period: garbage frames per period, kinds drawn uniformly from ``kinds``.
        duplicate_fraction: share of valid frames sent twice in a row.
        reorder_fraction: share of readings whose frame B is sent before frame A.
    """
    if not served:
        raise ValueError("served must name at least one module")
    out = HostileTraffic([])
    for frames in periods:
        frames = list(frames)
        t = frames[0].timestamp if frames else 0.0
        # Valid frames, pairwise (A, B) per module, possibly swapped or duplicated.
        valid: list[can.Message] = []
        by_id: dict[int, list[can.Message]] = {}
        for m in frames:
            by_id.setdefault(m.arbitration_id, []).append(m)
        for pair in by_id.values():
            if len(pair) == 2 and rng.random() < reorder_fraction:
                pair = pair[::-1]
                out.counts["reordered"] += 1
            for m in pair:
                valid.append(m)
                out.counts["valid"] += 1
                if rng.random() < duplicate_fraction:
                    valid.append(_copy(m))
                    out.counts["duplicates"] += 1
        junk = []
        for _ in range(garbage_per_period):
            kind = kinds[rng.randrange(len(kinds))]
            junk.append(_garbage(rng, kind, served, t))
            out.counts[kind] += 1
        # Interleave: the valid frames keep their relative order.
        cuts = sorted(rng.randrange(len(junk) + 1) for _ in valid)
        mixed = list(junk)
        for j, (m, c) in enumerate(zip(valid, cuts, strict=True)):
            mixed.insert(c + j, m)
        out.batches.append(mixed)
    return out


def _copy(m: can.Message) -> can.Message:
    return can.Message(
        arbitration_id=m.arbitration_id,
        data=bytes(m.data),
        is_extended_id=m.is_extended_id,
        timestamp=m.timestamp,
    )
