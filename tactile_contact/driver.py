"""Driver core: CAN messages in, per-patch taxel arrays and diagnostics out (no ROS).

The ``skin_driver`` node is meant to be a thin adapter over :class:`SkinDriverCore`: it feeds
every received ``can.Message`` to :meth:`SkinDriverCore.on_message`, publishes each returned
:class:`PatchOutput` as a TaxelArray, calls :meth:`SkinDriverCore.poll` from a timer so that a
patch whose modules went silent is still published (flagged stale), and turns
:meth:`SkinDriverCore.diagnostics` into a DiagnosticArray.

Publication rule per patch: when every module of the patch has delivered a reading since the
last publication, or when a module delivers its next reading before the others did (a period
boundary passed: the missing modules are flagged stale), or from :meth:`poll` when the newest
reading is older than ``stale_after_s``.

Not thread-safe: call everything from one thread, or hold one lock around ``on_message``,
``poll``, ``tare`` and ``diagnostics`` when a service runs on another thread.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import can
import numpy as np
from numpy.typing import NDArray

from tactile_contact.baseline import BaselineConfig, BaselineTracker
from tactile_contact.codec import (
    CHANNELS,
    ERROR_I2C,
    ERROR_NOT_CONNECTED,
    PeriodAssembler,
    SkinReading,
    skin_id,
)
from tactile_contact.modules import taxel_id

if TYPE_CHECKING:
    from tactile_contact.layout import PatchLayout


class PatchBuffer:
    """Latest readings of a patch's modules as (12·M,) arrays in layout order.

    The driver puts every :class:`SkinReading` of the patch's modules here and, once per
    publication, takes the arrays (and which channels are fresh) for the baseline tracker.

    Args:
        modules: (board, triangle) of each module, in layout order.
        no_load: value the arrays hold before a module's first reading [counts].
    """

    def __init__(self, modules: Iterable[tuple[int, int]], no_load: int = 240) -> None:
        mods = [(int(b), int(t)) for b, t in modules]
        for b, t in mods:
            skin_id(b, t)  # validates the address
        if not mods or len(set(mods)) != len(mods):
            raise ValueError(f"modules must be a non-empty list of unique pairs, got {mods}")
        self.modules = mods
        self._slot = {m: i for i, m in enumerate(mods)}
        n = CHANNELS * len(mods)
        if not 0 <= no_load <= 255:
            raise ValueError(f"no_load must be within 0..255, got {no_load!r}")
        self.raw = np.full(n, no_load, dtype=np.uint8)
        self.fresh = np.zeros(n, dtype=bool)
        self.out_of_range = np.zeros(n, dtype=bool)
        self.module_error = np.zeros(n, dtype=bool)
        self.seen = np.zeros(len(mods), dtype=bool)
        self.stamp = 0.0  # newest receive time [s]; 0.0 until the first reading

    def slot(self, board: int, triangle: int) -> int | None:
        """Index of a module in this patch (None if it is not in it)."""
        return self._slot.get((board, triangle))

    def put(self, reading: SkinReading) -> bool:
        """Store a reading; False if its module is not in this patch."""
        i = self._slot.get((reading.board, reading.triangle))
        if i is None:
            return False
        sl = slice(CHANNELS * i, CHANNELS * (i + 1))
        self.raw[sl] = reading.values
        self.fresh[sl] = True
        self.out_of_range[sl] = reading.out_of_range
        self.module_error[sl] = reading.error_flags & (ERROR_I2C | ERROR_NOT_CONNECTED) != 0
        first = not self.seen.any()
        self.seen[i] = True
        self.stamp = reading.timestamp if first else max(self.stamp, reading.timestamp)
        return True

    @property
    def complete(self) -> bool:
        """Every module delivered a reading since the last :meth:`take`."""
        return bool(np.all(self.fresh[::CHANNELS]))

    def take(self) -> tuple[NDArray[np.uint8], NDArray[np.bool_], float]:
        """(raw copy, fresh copy, newest receive time [s]); clears the fresh flags."""
        out = self.raw.copy(), self.fresh.copy(), self.stamp
        self.fresh[:] = False
        return out


@dataclass(frozen=True)
class PatchOutput:
    """One publication of a patch (arrays in layout order, 12 channels per module).

    Attributes:
        patch, frame_id: from the layout.
        stamp: CAN receive time [s] of the newest reading included.
        taxel_ids: (N,) uint16 bus-unique ids (board << 8 | triangle << 4 | channel).
        delta_c: (N,) float64 capacitance change [F], positive = compression.
        raw: (N,) uint8 module values [counts].
        status: (N,) uint8 STATUS_* flags (tactile_contact.baseline).
        in_contact: some taxel of the patch is in contact.
        calibrated: every valid taxel has its baseline.
    """

    patch: str
    frame_id: str
    stamp: float
    taxel_ids: NDArray[np.uint16]
    delta_c: NDArray[np.float64]
    raw: NDArray[np.uint8]
    status: NDArray[np.uint8]
    in_contact: bool
    calibrated: bool


@dataclass
class _Patch:
    name: str
    frame_id: str
    modules: list[tuple[int, int]]
    buffer: PatchBuffer
    tracker: BaselineTracker
    taxel_ids: NDArray[np.uint16]
    published: int = 0


@dataclass
class _Rate:
    times: deque[float] = field(default_factory=lambda: deque(maxlen=256))


class SkinDriverCore:
    """Assembler + per-patch buffers + baseline trackers of one CAN bus.

    Args:
        patches: layout patches read from this bus (``layout.PatchLayout``).
        baseline: baseline parameters (shared by the patches).
        id_classes: accepted data id classes.
        pair_window_s, duplicate_window_s: see :class:`PeriodAssembler`.
        stale_after_s: :meth:`poll` publishes a patch whose newest reading is older than this
            [s] and reports modules silent for longer than this in diagnostics.
    """

    def __init__(
        self,
        patches: Sequence[PatchLayout],
        *,
        baseline: BaselineConfig | None = None,
        id_classes: Sequence[int] = (4, 3),
        pair_window_s: float = 0.010,
        duplicate_window_s: float = 0.005,
        stale_after_s: float = 0.2,
    ) -> None:
        if not patches:
            raise ValueError("patches must name at least one layout patch")
        if not (math.isfinite(stale_after_s) and stale_after_s > 0):
            raise ValueError(f"stale_after_s must be finite and > 0, got {stale_after_s!r}")
        self._patches: list[_Patch] = []
        self._owner: dict[tuple[int, int], _Patch] = {}
        for p in patches:
            mods = [(m.board, m.triangle) for m in p.modules]
            ids = np.array(
                [taxel_id(b, t, c) for b, t in mods for c in range(CHANNELS)], dtype=np.uint16
            )
            entry = _Patch(
                p.name,
                p.frame_id,
                mods,
                PatchBuffer(mods, no_load=p.sensor.no_load),
                BaselineTracker.from_patch(p, baseline),
                ids,
            )
            for m in mods:
                if m in self._owner:
                    raise ValueError(
                        f"module board {m[0]} triangle {m[1]} is in patches "
                        f"{self._owner[m].name!r} and {p.name!r}"
                    )
                self._owner[m] = entry
            self._patches.append(entry)
        self.assembler = PeriodAssembler(
            id_classes=id_classes,
            modules=list(self._owner),
            pair_window_s=pair_window_s,
            duplicate_window_s=duplicate_window_s,
        )
        self.stale_after_s = float(stale_after_s)
        self._rates: dict[tuple[int, int], _Rate] = {m: _Rate() for m in self._owner}
        self.bus_errors = 0

    @property
    def patch_names(self) -> list[str]:
        return [p.name for p in self._patches]

    # -- input ----------------------------------------------------------------------------
    def on_message(self, msg: can.Message) -> list[PatchOutput]:
        """Feed one received message; the patch publications it triggers (usually 0 or 1)."""
        reading = self.assembler.feed(msg)
        return [] if reading is None else self.on_reading(reading)

    def on_reading(self, reading: SkinReading) -> list[PatchOutput]:
        """Feed one complete module reading (e.g. from another assembler)."""
        p = self._owner.get(reading.key)
        if p is None:
            return []
        self._rates[reading.key].times.append(reading.timestamp)
        out = []
        i = p.buffer.slot(reading.board, reading.triangle)
        if i is not None and p.buffer.fresh[CHANNELS * i]:
            # This module's next period arrived before the others: publish what we have.
            out.append(self._publish(p))
        p.buffer.put(reading)
        if p.buffer.complete:
            out.append(self._publish(p))
        return out

    def on_bus_error(self) -> None:
        """Count a receive error reported by the bus (the node catches can.CanError)."""
        self.bus_errors += 1

    def poll(self, now: float) -> list[PatchOutput]:
        """Publish patches holding fresh readings older than ``stale_after_s`` at ``now`` [s]."""
        out = []
        for p in self._patches:
            if p.buffer.fresh.any() and now - p.buffer.stamp > self.stale_after_s:
                out.append(self._publish(p))
        return out

    def _publish(self, p: _Patch) -> PatchOutput:
        raw, fresh, stamp = p.buffer.take()
        r = p.tracker.update(
            raw,
            stamp,
            fresh=fresh,
            out_of_range=p.buffer.out_of_range,
            module_error=p.buffer.module_error,
        )
        p.published += 1
        return PatchOutput(
            p.name,
            p.frame_id,
            stamp,
            p.taxel_ids,
            r.delta_c,
            raw,
            r.status,
            bool(r.contact.any()),
            r.calibrated,
        )

    # -- services -------------------------------------------------------------------------
    def tare(self, patch: str | None = None) -> bool:
        """Tare one patch (or all); False if a named patch has no reading yet or is unknown."""
        ok = True
        for p in self._patches:
            if patch is None or p.name == patch:
                ok &= p.tracker.tare()
        return ok and (patch is None or patch in self.patch_names)

    def recalibrate(self) -> None:
        """Learn every baseline again from the next readings (skin unloaded)."""
        for p in self._patches:
            p.tracker.recalibrate()

    # -- diagnostics ----------------------------------------------------------------------
    def diagnostics(self, now: float) -> dict[str, Any]:
        """Plain-data health report at ``now`` [s] (receive-time clock).

        ``{"bus": {...counters...}, "modules": {"b<board>t<triangle>": {...}},
        "patches": {name: {"published", "calibrated", "bad_taxels": {taxel_id: [reasons]}}}}``;
        module entries hold the reading rate [Hz] over the last readings, the assembler
        counters, the last error flags and ``silent`` (no reading for ``stale_after_s``).
        """
        c = self.assembler.counters
        bus = {
            name: getattr(c, name)
            for name in (
                "frames",
                "readings",
                "truncated",
                "unknown_id",
                "bad_type",
                "bad_status",
                "not_data",
                "unexpected_module",
                "duplicates",
                "incomplete",
                "orphan_b",
                "reordered",
            )
        }
        bus["rejected"] = c.rejected
        bus["bus_errors"] = self.bus_errors
        counters = self.assembler.module_counters()
        modules = {}
        for m in self._owner:
            mc = counters.get(m)
            times = self._rates[m].times
            rate = 0.0
            if len(times) >= 2 and times[-1] > times[0]:
                rate = (len(times) - 1) / (times[-1] - times[0])
            last = mc.last_timestamp if mc is not None else None
            modules[f"b{m[0]}t{m[1]}"] = {
                "rate_hz": rate,
                "readings": mc.readings if mc else 0,
                "incomplete": mc.incomplete if mc else 0,
                "orphan_b": mc.orphan_b if mc else 0,
                "duplicates": mc.duplicates if mc else 0,
                "error_readings": mc.error_readings if mc else 0,
                "last_error_flags": mc.last_error_flags if mc else 0,
                "silent": last is None or now - last > self.stale_after_s,
            }
        patches = {}
        for p in self._patches:
            bad = p.tracker.bad_taxels()
            patches[p.name] = {
                "published": p.published,
                "calibrated": p.tracker.calibrated,
                "bad_taxels": {int(p.taxel_ids[i]): reasons for i, reasons in bad.items()},
            }
        return {"bus": bus, "modules": modules, "patches": patches}
