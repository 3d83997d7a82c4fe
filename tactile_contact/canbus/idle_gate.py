"""Which patch readings go out when most of the skin is untouched: send on change.

A robot's skin is mostly idle, and each reading a worker takes costs it a message's share of
the middleware whatever it holds (docs/bench/load.md). :class:`IdleGate` lets a patch's
readings through while anything happens on it, and an untouched patch's only every
``every``-th period, as event-driven skins do (a reading is sent when it changes beyond a
threshold, and a keep-alive otherwise).

A reading is *quiet* when, on every taxel,

- it is within ``idle_counts`` 8-bit counts of its baseline (|ΔC| ≤ idle_counts · the patch's
  ΔC of one count), and
- the running mean of the patch's readings (an exponential mean, gain :data:`MEAN_GAIN` a
  reading) is within half of that,

no taxel is flagged in contact, and its status flags are those of the patch's last reading
sent. The running mean is what catches a light press: one reading 2–3 counts above its
baseline on a taxel is within the noise of one reading (at 0.5 count of noise and 8-bit
rounding, 2 counts is crossed by noise in one taxel reading of 2 700), but the mean of the
last few is not (a steady 2 counts crosses 1.5 after 5 readings, 3 counts after 3; the mean of
0.5-count noise has σ ≈ 0.2 count).

A reading goes out when

- it is not quiet (a press at once, at full rate, for as long as it lasts);
- it is one of the first :data:`RELEASE_READINGS` quiet ones after a reading that was not (the
  release: the batches are best-effort, and a release lost would leave the worker on the
  press until the keep-alive);
- it is the patch's first since a tare (:attr:`PatchFrame.tares` grew: the worker must see the
  new state; a reading made before the tare that comes later goes out and changes nothing);
- or ``every`` periods have passed since the patch's last reading sent (the keep-alive).

What a worker loses with it: a press within the thresholds on every taxel (below ≈ 1.5 counts
on the mean) reaches it ``every`` times less often, and one that crosses only the mean's
threshold a few readings late. ``every`` = 1 sends every reading (the default).

ROS-free; the driver (:mod:`tactile_contact.ros.skin_driver`) applies it to its batches.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numba
import numpy as np

from tactile_contact.canbus.baseline import STATUS_CONTACT
from tactile_contact.canbus.stream import PatchFrame

#: Weight of the newest reading in a taxel's running mean: the mean of about the last
#: 2/MEAN_GAIN − 1 = 7 readings (its noise is √(g/(2−g)) ≈ 0.38 of one reading's).
MEAN_GAIN = np.float32(0.25)
#: Quiet readings sent after one that was not: a release survives the loss of all but one.
RELEASE_READINGS = 3


#: What :func:`_step` found: the running mean within half the limit on every taxel, the
#: reading within the limit on every taxel (NaN is never within).
SETTLED, WITHIN = 1, 2


@numba.njit(cache=True, nogil=True)
def _step(dc, mean, limit):  # pragma: no cover - compiled
    """mean += MEAN_GAIN · (dc − mean) in place (float32, in NumPy's order of operations), and
    SETTLED | WITHIN as they hold; a non-finite mean is reset to 0 (a NaN reading goes out and
    must not stay in the mean). One pass instead of seven NumPy calls: the driver pays this
    per reading (5.4 µs → ≈ 0.5 µs on 72 taxels)."""
    gain = MEAN_GAIN  # (a global: frozen into the kernel; its file's cache follows it)
    half = limit * np.float32(0.5)
    settled, within, bad = True, True, False
    for i in range(dc.shape[0]):
        m = mean[i] + gain * (dc[i] - mean[i])
        mean[i] = m
        if not (-half <= m <= half):
            settled = False
            if not math.isfinite(m):
                bad = True
        if not (-limit <= dc[i] <= limit):
            within = False
    if bad:
        mean[:] = 0.0
    return (SETTLED if settled else 0) | (WITHIN if within else 0)


@dataclass
class _State:
    """A patch's running mean [F] (float32); the quiet readings still to send
    (:data:`RELEASE_READINGS` after one that was not; 1 at first: the first reading always
    goes out), the status flags of the last reading sent, periods since, and the tares its
    readings were made after."""

    mean: np.ndarray
    tares: int
    release: int = 1
    status: bytes = b""
    since: int = 0


class IdleGate:
    """Send-on-change for patch readings (see the module docstring).

    Args:
        every: an untouched patch's readings go out every this many periods (1: all).
        idle_counts: a taxel within this many 8-bit counts of its baseline is untouched (its
            running mean within half of it).
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
        # |ΔC| and |mean ΔC| at or below these are untouched [F], per patch (float32: as ΔC)
        self._limit = {n: np.float32(idle_counts * c) for n, c in count_farad.items()}
        self._state: dict[str, _State] = {}
        if every > 1:  # compiled (or read from numba's cache) now, not at the first reading
            _step(np.zeros(1, np.float32), np.zeros(1, np.float32), np.float32(1.0))
        #: Readings let through and held back since the start.
        self.passed = 0
        self.held = 0

    def passes(self, frame: PatchFrame) -> bool:
        """Whether ``frame`` goes out; called once per reading, in order, per patch."""
        limit = self._limit.get(frame.patch)
        if self.every == 1 or limit is None:
            self.passed += 1
            return True
        dc = frame.delta_c
        st = self._state.get(frame.patch)
        if st is None or st.mean.shape != dc.shape or frame.tares > st.tares:
            zeros = np.zeros(dc.shape, np.float32)
            st = self._state[frame.patch] = _State(zeros, frame.tares)
        elif frame.tares < st.tares:
            self.passed += 1  # made before a tare whose readings were seen already
            return True
        # (float32 from the driver; another type is compared as it is, as NumPy did: a cast
        # would round a value just above the limit onto it)
        found = _step(dc, st.mean, limit)
        settled, within = bool(found & SETTLED), bool(found & WITHIN)
        # Held back only while quiet with the status of the last sent, which was quiet (so
        # nothing in it was in contact: the status flags need no look of their own).
        if (
            not st.release
            and st.since + 1 < self.every
            and settled
            and within
            and frame.status == st.status
        ):
            st.since += 1
            self.held += 1
            return False
        status = np.frombuffer(frame.status, dtype=np.uint8)
        quiet = settled and within and not (status & STATUS_CONTACT).any()
        st.release = max(st.release - 1, 0) if quiet else RELEASE_READINGS
        st.status, st.since = bytes(frame.status), 0
        self.passed += 1
        return True

    def forget(self, patch: str | None = None) -> None:
        """Start ``patch`` (None: every patch) afresh: its next reading goes out. (A tare
        needs no call: its readings carry it, :attr:`PatchFrame.tares`.)"""
        if patch is None:
            self._state.clear()
        else:
            self._state.pop(patch, None)
