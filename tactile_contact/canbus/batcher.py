"""Readings of one bus gathered into batches: one TaxelBatch message per bus period.

ROS-free; the driver node (:mod:`tactile_contact.ros.skin_driver`) publishes each batch.
"""

from __future__ import annotations

import math

from tactile_contact.canbus.stream import PatchFrame


class Batcher:
    """Readings of a bus gathered into batches (one TaxelBatch each).

    A batch opens with the first reading not yet published and is due ``window_s`` later, or
    as soon as every patch has a reading in it; a second reading of a patch already in it
    sends the batch first (a batch holds one reading per patch).
    """

    def __init__(self, names: list[str], window_s: float) -> None:
        self.names = frozenset(names)
        self.window_s = window_s
        self.pending: dict[str, PatchFrame] = {}
        self.due = math.inf  # monotonic time the open batch goes out

    def add(self, frame: PatchFrame, now: float) -> list[list[PatchFrame]]:
        """Add a reading; the batches that are due because of it (0, 1 or 2)."""
        out = []
        if frame.patch in self.pending:
            out.append(self.take())
        if not self.pending:
            self.due = now + self.window_s
        self.pending[frame.patch] = frame
        if len(self.pending) == len(self.names) or self.window_s <= 0.0:
            out.append(self.take())
        return out

    def take(self) -> list[PatchFrame]:
        """The open batch (emptied)."""
        frames = list(self.pending.values())
        self.pending.clear()
        self.due = math.inf
        return frames
