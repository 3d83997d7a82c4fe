"""Which patch readings go out when most of the skin is untouched: send on change.

A robot's skin is mostly idle, and each reading a worker takes costs it a message's share of
the middleware whatever it holds (docs/bench/load.md: 90 µs an idle patch-frame all-in, of
which 34 are the relay's). :class:`IdleGate` lets a patch's readings through while anything
happens on it, and an untouched patch's only every ``every``-th period, as event-driven skins
do (a reading is sent when it changes beyond a threshold, and a keep-alive otherwise).

A reading is *quiet* when every taxel reads within ``idle_counts`` 8-bit counts of its baseline
(|ΔC| ≤ idle_counts · the patch's ΔC of one count), none is flagged in contact, and its status
flags are those of the patch's last reading sent. A reading goes out when

- it is not quiet (a press at once, at full rate, for as long as it lasts);
- the patch's last reading sent was not quiet (the first quiet one after a press: its release);
- or ``every`` periods have passed since the patch's last reading sent (the keep-alive).

What a worker loses with it: an idle patch's readings come ``every`` times less often, so a
press that stays within ``idle_counts`` on every taxel (found only by averaging many readings,
issue 26's light presses) is found ``every`` times later. A press beyond it is not delayed.
``every`` = 1 sends every reading (the default).

ROS-free; the driver (:mod:`tactile_contact.ros.skin_driver`) applies it to its batches.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from tactile_contact.canbus.baseline import STATUS_CONTACT
from tactile_contact.canbus.stream import PatchFrame


@dataclass
class _Last:
    """A patch's last reading sent: whether it was quiet, its status, periods since."""

    quiet: bool
    status: bytes
    since: int = 0


class IdleGate:
    """Send-on-change for patch readings (see the module docstring).

    Args:
        every: an untouched patch's readings go out every this many periods (1: all).
        idle_counts: a taxel within this many 8-bit counts of its baseline is untouched.
        count_farad: per patch, the ΔC of one 8-bit count [F] (farad_per_count · 2**shift);
            a patch not in it is never gated.
    """

    def __init__(self, every: int, idle_counts: float, count_farad: Mapping[str, float]) -> None:
        if not (isinstance(every, int) and every >= 1):
            raise ValueError(f"idle gate: every must be an int >= 1, got {every!r}")
        if not (math.isfinite(idle_counts) and idle_counts >= 0):
            raise ValueError(f"idle gate: idle_counts must be finite and >= 0, got {idle_counts}")
        for name, c in count_farad.items():
            if not (math.isfinite(c) and c > 0):
                raise ValueError(f"idle gate: patch {name}'s ΔC of one count must be > 0, got {c}")
        self.every = every
        self.idle_counts = float(idle_counts)
        # |ΔC| at or below this is untouched [F], per patch (float32: as ΔC is compared)
        self._limit = {n: np.float32(idle_counts * c) for n, c in count_farad.items()}
        self._last: dict[str, _Last] = {}
        #: Readings let through and held back since the start.
        self.passed = 0
        self.held = 0

    def quiet(self, frame: PatchFrame) -> bool:
        """Whether ``frame`` is untouched: every |ΔC| within the limit (NaN is not), no taxel
        in contact. (Its status against the last sent is :meth:`passes`'s to compare.)"""
        limit = self._limit.get(frame.patch)
        if limit is None:
            return False
        status = np.frombuffer(frame.status, dtype=np.uint8)
        return not (status & STATUS_CONTACT).any() and self._within(frame.delta_c, limit)

    @staticmethod
    def _within(delta_c: np.ndarray, limit: np.float32) -> bool:
        # Two reductions instead of |ΔC| ≤ limit taxel by taxel (a third of the time, which
        # the driver pays per reading); a NaN makes min and max NaN, and NaN is never within.
        return bool(-limit <= delta_c.min()) and bool(delta_c.max() <= limit)

    def passes(self, frame: PatchFrame) -> bool:
        """Whether ``frame`` goes out; called once per reading, in order, per patch."""
        if self.every == 1:
            self.passed += 1
            return True
        last = self._last.get(frame.patch)
        # Held back only while quiet with the status of the last sent, which was quiet (so
        # nothing in it was in contact: the status flags need no look of their own).
        if (
            last is not None
            and last.quiet
            and last.since + 1 < self.every
            and frame.status == last.status
            and frame.patch in self._limit
            and self._within(frame.delta_c, self._limit[frame.patch])
        ):
            last.since += 1
            self.held += 1
            return False
        self._last[frame.patch] = _Last(self.quiet(frame), bytes(frame.status))
        self.passed += 1
        return True

    def forget(self, patch: str | None = None) -> None:
        """Start ``patch`` (None: every patch) afresh: its next reading goes out (after a
        bus reopened, a tare: the worker must see the first reading of the new state)."""
        if patch is None:
            self._last.clear()
        else:
            self._last.pop(patch, None)
