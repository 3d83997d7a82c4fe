"""Readings gathered into batches: one TaxelBatch message per bus period, or per period of
several buses when one driver serves them.

ROS-free; the driver node (:mod:`tactile_contact.ros.skin_driver`) publishes each batch.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from tactile_contact.canbus.stream import PatchFrame

#: Weight of the newest interval in a bus's period estimate (an exponential mean).
PERIOD_GAIN = 0.2


class Batcher:
    """Readings gathered into batches (one TaxelBatch each).

    A batch opens with the first reading not yet published and is due ``window_s`` later, or
    as soon as every patch has a reading in it; a second reading of a patch already in it
    sends the batch first (a batch holds one reading per patch).

    With ``groups`` (each bus's patches, for a driver of several buses) a batch also goes out
    as soon as every bus it holds a reading of is complete and no other bus is expected to
    complete before the batch is due: a bus's boards send every period, so when it completes
    next is known from when it completed before (an exponential mean of its intervals).
    Buses whose periods end together share a message, as within the window; a bus alone
    goes out at once instead of waiting the window out for buses that are not coming. A
    bus expected and late holds the batch at most until it is due.
    """

    def __init__(
        self,
        names: Iterable[str],
        window_s: float,
        groups: Mapping[str, Iterable[str]] | None = None,
    ) -> None:
        self.names = frozenset(names)
        self.window_s = window_s
        self.pending: dict[str, PatchFrame] = {}
        self.due = math.inf  # monotonic time the open batch goes out
        self.groups = {g: frozenset(p) & self.names for g, p in (groups or {}).items()}
        self._group_of = {p: g for g, ps in self.groups.items() for p in ps}
        self._completed_at: dict[str, float] = {}  # monotonic time a bus last completed [s]
        self._period: dict[str, float] = {}  # its period estimate [s]

    def add(self, frame: PatchFrame, now: float) -> list[list[PatchFrame]]:
        """Add a reading; the batches that are due because of it (0, 1 or 2)."""
        out = []
        if frame.patch in self.pending:
            out.append(self.take())
        if not self.pending:
            self.due = now + self.window_s
        self.pending[frame.patch] = frame
        g = self._group_of.get(frame.patch)
        # (a batch can become ready only when a bus in it completes: this reading's)
        completed = g is not None and self.groups[g] <= self.pending.keys()
        if completed:
            self._bus_completed(g, now)
        if (
            len(self.pending) == len(self.names)
            or self.window_s <= 0.0
            or (completed and self._ready(now))
        ):
            out.append(self.take())
        return out

    def take(self) -> list[PatchFrame]:
        """The open batch (emptied)."""
        frames = list(self.pending.values())
        self.pending.clear()
        self.due = math.inf
        return frames

    def expected(self, group: str) -> float | None:
        """Monotonic time [s] ``group`` is expected to complete next, or None (not yet seen
        complete twice)."""
        period = self._period.get(group)
        return None if period is None else self._completed_at[group] + period

    def _bus_completed(self, g: str, now: float) -> None:
        last = self._completed_at.get(g)
        self._completed_at[g] = now
        if last is None or now <= last:
            return
        dt = now - last
        old = self._period.get(g)
        # A missed period (a bus reopened, a board late) is an interval of two or more:
        # it restarts the estimate rather than dragging it.
        if old is None or not 0.5 * old < dt < 1.5 * old:
            self._period[g] = dt
        else:
            self._period[g] = old + PERIOD_GAIN * (dt - old)

    def _ready(self, now: float) -> bool:
        """Every bus the open batch holds is complete, and none other is expected before
        the batch is due (nor overdue by less than the window: it may be on its way)."""
        held = {self._group_of.get(p) for p in self.pending}  # (None: a patch of no bus)
        if None in held or any(not self.groups[g] <= self.pending.keys() for g in held):
            return False
        for g in self.groups.keys() - held:
            t = self.expected(g)
            if t is not None and now - self.window_s <= t <= self.due:
                return False
        return True
