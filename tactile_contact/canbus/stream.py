"""The ROS-free half of ``skin_driver``: patch readings and their health (bus opening and log
replay are :mod:`tactile_contact.canbus.bus`, re-exported here).

:class:`SkinStream` turns received CAN messages into per-patch readings: the codec's
:class:`~tactile_contact.canbus.assembler.PeriodAssembler` pairs frames A and B into module
readings,
each patch gathers its modules' readings, and when every *live* module of the patch has a new
reading (or ``max_wait_s`` has passed since the first one) the patch's
:class:`~tactile_contact.canbus.baseline.BaselineTracker` turns the raw values into ΔC [F] and a
:class:`PatchFrame` comes out. A module that delivers a second reading before its patch was
published forces the publication first, so no complete reading is ever overwritten. Modules
without a new reading are flagged STALE, never left out; a module silent for longer than
``module_timeout_s`` is no longer waited for, its channels are flagged STALE and DEAD with ΔC 0
(no reading to use) and it is reported silent; when it speaks again its channels are
re-baselined (a module that rebooted may have another offset) and it is reported back.
Error frames drive :class:`~tactile_contact.canbus.bus_health.ControllerState` (bus-off and
friends).
Changes of state (module silent / back, controller state) are queued in :attr:`SkinStream.events`
for the node to log and report at once.

Times: ``stamp`` values are the messages' receive times (python-can ``timestamp``, s);
``now`` arguments are a monotonic clock [s] used only for waiting and rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import can
import numpy as np
from numpy.typing import NDArray

from tactile_contact.canbus import assembler, codec
from tactile_contact.canbus import baseline as bl
from tactile_contact.canbus.bus import ReplayBus, bus_kwargs, close_bus, open_bus
from tactile_contact.canbus.bus_health import BUS_OFF, ERROR_ACTIVE, BusErrorPolicy, ControllerState
from tactile_contact.model.layout import PatchLayout
from tactile_contact.model.modules import CHANNELS_PER_MODULE, taxel_id

__all__ = [
    "BusErrorPolicy",
    "DiagStatus",
    "PatchFrame",
    "ReplayBus",
    "SkinStream",
    "bus_kwargs",
    "close_bus",
    "open_bus",
]

SKIN_MASK = 0x700
#: Readings more than this fraction of a period apart belong to different periods.
COHERENCE = 0.75
#: Longest time [s] between recounts of a patch's live modules.
LIVE_RECHECK_S = 0.005
#: Longest time [s] between checks for modules that fell silent (a silent module is reported
#: at most this long after its timeout).
SILENCE_CHECK_S = 0.01


@dataclass(frozen=True)
class PatchFrame:
    """One patch reading, ready to become a TaxelArray (arrays in layout channel order)."""

    patch: str
    frame_id: str
    stamp: float  # receive time [s] of the frame completing the newest module reading
    taxel_ids: list[int]
    delta_c: NDArray[np.float32]  # [F]
    raw: bytes
    status: bytes
    #: Tares of its stream before this reading was made: a reading made before a tare may
    #: still be on its way out after it (in a batch window, a receive thread), and whoever
    #: compares readings over time (the driver's idle gate) must tell it from the new state.
    tares: int = 0


@dataclass(frozen=True)
class DiagStatus:
    """A ROS-free DiagnosticStatus: level 0 OK, 1 WARN, 2 ERROR, 3 STALE."""

    name: str
    level: int
    message: str
    values: dict[str, object]
    hardware_id: str = ""


@dataclass
class _ModuleState:
    board: int
    triangle: int
    fresh: bool = False
    last_seen: float = -math.inf  # monotonic [s]
    last_stamp: float = -math.inf  # receive time [s]
    missed_periods: int = 0
    readings_at_report: int = 0
    report_time: float = math.nan
    silent: bool = False  # reported silent (no reading for longer than the module timeout)
    silent_since: float = math.nan  # monotonic time of its last reading before the silence [s]
    returns: int = 0  # times it came back after a silence (each one re-baselines it)
    rebaselining: bool = False
    rate_hz: float = 0.0  # readings per second over the last diagnostics window


@dataclass
class _PatchState:
    layout: PatchLayout
    tracker: bl.BaselineTracker
    modules: list[_ModuleState]
    taxel_ids: list[int]
    raw: NDArray[np.uint8]
    oor: NDArray[np.bool_]
    err: NDArray[np.bool_]
    seen: NDArray[np.bool_]
    all_seen: bool = False  # every module heard at least once (seen all True)
    n_fresh: int = 0
    n_live: int = 0
    live_checked: float = -math.inf  # monotonic [s]
    first_pending: float = math.inf  # monotonic time of the first pending reading [s]
    oldest_pending_stamp: float = math.inf  # receive time of the oldest pending reading [s]
    newest_stamp: float = -math.inf  # receive time of the newest pending reading [s]
    published: int = 0
    stale_publications: int = 0
    last_bad: dict[int, list[str]] = field(default_factory=dict)


class SkinStream:
    """Module frames in, patch readings out (see the module docstring).

    Args:
        patches: the patch layouts to serve (their modules must have distinct addresses).
        id_classes: accepted id classes (``codec.CLASS_SKIN`` and optionally class 3).
        baseline: baseline tracking parameters.
        farad_per_count: gain of one CDC count [F]; None = each patch's layout value.
        max_wait_s: longest wait from a patch's first new module reading to its publication.
        module_timeout_s: a module silent this long is not waited for.
        period_s: nominal module period (gaps longer than 1.5 periods count missed periods).
        pair_window_s, duplicate_window_s, strict_status: passed to the assembler.
    """

    def __init__(
        self,
        patches: Sequence[PatchLayout],
        *,
        id_classes: Sequence[int] = (codec.CLASS_SKIN,),
        baseline: bl.BaselineConfig | None = None,
        farad_per_count: float | None = None,
        max_wait_s: float = 0.05,
        module_timeout_s: float = 0.5,
        period_s: float = 0.05,
        pair_window_s: float = 0.010,
        duplicate_window_s: float = 0.005,
        strict_status: bool = False,
    ) -> None:
        for name, v in (
            ("max_wait_s", max_wait_s),
            ("module_timeout_s", module_timeout_s),
            ("period_s", period_s),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if not patches:
            raise ValueError("patches must name at least one patch")
        if pair_window_s >= period_s:
            # A frame A waits this long for its B: the next period's B (one period later)
            # must fall outside it, or a lost B pairs its A with the next period's.
            raise ValueError(
                f"pair_window_s {pair_window_s * 1e3:g} ms must be below the period "
                f"({period_s * 1e3:g} ms; half of it leaves room for jitter): frames of the "
                "next period would be paired with this one's (skin_driver: pair_window_ms "
                "below period_ms)"
            )
        self.max_wait_s = max_wait_s
        self.module_timeout_s = module_timeout_s
        self.period_s = period_s
        self.id_classes = tuple(id_classes)
        #: Tares so far (:attr:`PatchFrame.tares` of the readings made now).
        self.tares = 0
        self._patches: list[_PatchState] = []
        self._where: dict[tuple[int, int], tuple[_PatchState, int]] = {}
        for pl in patches:
            st = self._patch_state(pl, baseline, farad_per_count)
            for i, m in enumerate(st.modules):
                key = (m.board, m.triangle)
                if key in self._where:
                    raise ValueError(f"module board {key[0]} triangle {key[1]} in two patches")
                self._where[key] = (st, i)
            self._patches.append(st)
        self.assembler = assembler.PeriodAssembler(
            id_classes=self.id_classes,
            modules=list(self._where),
            pair_window_s=pair_window_s,
            duplicate_window_s=duplicate_window_s,
            strict_status=strict_status,
        )
        self.last_error: codec.CodecError | None = None
        self.controller = ControllerState()
        #: (diagnostic level, kind, text) of state changes since the caller last emptied the
        #: list; ``kind`` groups repeats (``controller``, ``module b/t``) for rate limiting.
        self.events: list[tuple[int, str, str]] = []
        self._report_time = math.nan
        self._silence_checked = -math.inf  # monotonic time of the last silence check [s]
        self._start: float | None = None  # monotonic time of the first reading [s]

    @staticmethod
    def _patch_state(
        pl: PatchLayout, config: bl.BaselineConfig | None, farad_per_count: float | None
    ) -> _PatchState:
        n = CHANNELS_PER_MODULE * len(pl.modules)
        tracker = bl.BaselineTracker(
            n,
            valid=pl.valid_mask(),
            module_index=np.repeat(np.arange(len(pl.modules)), CHANNELS_PER_MODULE),
            positions=pl.channel_xy(),
            farad_per_count=farad_per_count or pl.sensor.farad_per_count,
            shift=pl.sensor.shift,
            config=config,
        )
        ids = [
            taxel_id(m.board, m.triangle, c) for m in pl.modules for c in range(CHANNELS_PER_MODULE)
        ]
        return _PatchState(
            layout=pl,
            tracker=tracker,
            modules=[_ModuleState(m.board, m.triangle) for m in pl.modules],
            taxel_ids=ids,
            raw=np.zeros(n, dtype=np.uint8),
            oor=np.zeros(n, dtype=bool),
            err=np.zeros(n, dtype=bool),
            seen=np.zeros(n, dtype=bool),
        )

    def can_filters(self) -> list[dict]:
        """python-can receive filters keeping only the accepted skin id classes."""
        return [
            {"can_id": c << 8, "can_mask": SKIN_MASK, "extended": False} for c in self.id_classes
        ]

    def board_ranges(self) -> dict[int, tuple[int, int, int, int]]:
        """Per board: (first triangle, last triangle, shift, no_load) for the host commands."""
        out: dict[int, tuple[int, int, int, int]] = {}
        for st in self._patches:
            s = st.layout.sensor
            for m in st.modules:
                lo, hi, _, _ = out.get(m.board, (m.triangle, m.triangle, 0, 0))
                out[m.board] = (min(lo, m.triangle), max(hi, m.triangle), s.shift, s.no_load)
        return out

    # -- data path ------------------------------------------------------------------------
    def feed(self, msg: can.Message, now: float) -> list[PatchFrame]:
        """Process one received message; the patch readings it completed (0, 1 or 2)."""
        a = self.assembler
        reading = a.feed(msg)
        if a.last_error is not None:
            self.last_error, a.last_error = a.last_error, None
        if msg.is_error_frame or self.controller.state == BUS_OFF:
            self._controller(msg, now)
        if reading is None:
            return []
        st, i = self._where[reading.key]
        out: list[PatchFrame] = []
        m = st.modules[i]
        # A second reading of a module, or a reading of a later period than those pending,
        # publishes the pending ones first: a message never mixes periods nor drops a reading.
        if m.fresh or reading.timestamp - st.oldest_pending_stamp > COHERENCE * self.period_s:
            out.append(self._emit(st))
        if math.isfinite(m.last_stamp):
            gap = reading.timestamp - m.last_stamp
            if gap > 1.5 * self.period_s:
                m.missed_periods += max(round(gap / self.period_s) - 1, 0)
        sl = slice(CHANNELS_PER_MODULE * i, CHANNELS_PER_MODULE * (i + 1))
        if self._start is None:
            self._start = now
        was_live = self._live(m, now)
        if not was_live and math.isfinite(m.last_seen):
            self._module_back(st, m, sl, now)
        elif m.silent:  # never heard until now
            m.silent = False
            self.events.append(
                (
                    0,
                    f"module {m.board}/{m.triangle}",
                    f"patch {st.layout.name}: module board {m.board} triangle {m.triangle} "
                    "heard for the first time",
                )
            )
        st.raw[sl] = reading.values
        st.oor[sl] = reading.out_of_range if reading.oor_mask else False
        st.err[sl] = bool(reading.error_flags)
        st.seen[sl] = True
        m.fresh, m.last_seen, m.last_stamp = True, now, reading.timestamp
        st.n_fresh += 1
        st.first_pending = min(st.first_pending, now)
        st.oldest_pending_stamp = min(st.oldest_pending_stamp, reading.timestamp)
        st.newest_stamp = max(st.newest_stamp, reading.timestamp)
        # Fresh modules are always live, so "every live module is fresh" is a count test. The
        # live count is refreshed when a module comes back and otherwise every LIVE_RECHECK_S.
        if not was_live or now - st.live_checked >= LIVE_RECHECK_S:
            st.n_live = sum(self._live(mm, now) for mm in st.modules)
            st.live_checked = now
        if st.n_fresh >= st.n_live:
            out.append(self._emit(st))
        return out

    def _controller(self, msg: can.Message, now: float) -> None:
        if msg.is_error_frame:
            changed = self.controller.error_frame(msg, now)
            if changed is not None:
                level = 2 if changed == BUS_OFF else (0 if changed == ERROR_ACTIVE else 1)
                self.events.append(
                    (
                        level,
                        "controller",
                        f"CAN controller {changed} (error frame, class 0x{msg.arbitration_id:03X})",
                    )
                )
        elif not msg.is_remote_frame and self.controller.data_frame(now) is not None:
            self.events.append(
                (0, "controller", "CAN controller back from bus-off: data frames again")
            )

    def _module_back(self, st: _PatchState, m: _ModuleState, sl: slice, now: float) -> None:
        """A module heard again after more than the timeout: re-baseline its channels."""
        mask = np.zeros(st.tracker.n, dtype=bool)
        mask[sl] = True
        st.tracker.recalibrate(mask)
        m.returns += 1
        m.rebaselining = True
        m.silent = False
        self.events.append(
            (
                0,
                f"module {m.board}/{m.triangle}",
                f"patch {st.layout.name}: module board {m.board} triangle {m.triangle} back "
                f"after {now - m.last_seen:.2f} s of silence; re-baselining its taxels",
            )
        )

    def _check_silence(self, now: float) -> None:
        """Report modules that fell silent (once each) since the last check."""
        self._silence_checked = now
        for st in self._patches:
            for m in st.modules:
                if not m.silent and not self._live(m, now) and self._start is not None:
                    m.silent = True
                    m.silent_since = m.last_seen
                    heard = (
                        f"no reading for {now - m.last_seen:.2f} s"
                        if math.isfinite(m.last_seen)
                        else "never heard"
                    )
                    self.events.append(
                        (
                            2,
                            f"module {m.board}/{m.triangle}",
                            f"patch {st.layout.name}: module board {m.board} triangle "
                            f"{m.triangle} silent ({heard}); its taxels are flagged invalid",
                        )
                    )

    def _live(self, m: _ModuleState, now: float) -> bool:
        """Waited for: heard within the timeout, or never heard yet but the stream is young."""
        if math.isfinite(m.last_seen):
            return now - m.last_seen <= self.module_timeout_s
        return self._start is not None and now - self._start <= self.module_timeout_s

    def poll(self, now: float) -> list[PatchFrame]:
        """Patch readings whose max wait has passed (call at least every few ms); also notices
        modules that fell silent (:attr:`events`)."""
        if now - self._silence_checked >= SILENCE_CHECK_S:
            self._check_silence(now)
        return [self._emit(st) for st in self._patches if now - st.first_pending >= self.max_wait_s]

    def _emit(self, st: _PatchState) -> PatchFrame:
        # Runs for every patch reading: the masks that are usually all True or all False are
        # passed as None (the tracker's defaults) and the rare cases are tested in Python.
        flags = [m.fresh for m in st.modules]
        all_fresh = all(flags)
        fresh = None if all_fresh else np.repeat(flags, CHANNELS_PER_MODULE)
        res = st.tracker.update(
            st.raw,
            st.newest_stamp,
            fresh=fresh,
            out_of_range=st.oor if np.count_nonzero(st.oor) else None,
            module_error=st.err if np.count_nonzero(st.err) else None,
        )
        status = res.status
        if not st.all_seen:
            st.all_seen = np.count_nonzero(st.seen) == len(st.seen)
            status = status.copy()
            status[~st.seen] &= np.uint8(~bl.STATUS_SATURATED & 0xFF)  # never heard: no value
        delta_c = res.delta_c
        silent = [m.silent for m in st.modules]
        if any(silent):  # no reading for longer than the timeout: nothing to use
            gone = np.repeat(silent, CHANNELS_PER_MODULE)
            status = status.copy()
            status[gone] |= np.uint8(bl.STATUS_STALE | bl.STATUS_DEAD)
            delta_c = np.where(gone, 0.0, delta_c)
        if any(m.rebaselining for m in st.modules):
            cal_mask = st.tracker.calibrated_mask.reshape(-1, CHANNELS_PER_MODULE)
            for m, cal in zip(st.modules, cal_mask, strict=True):
                if m.rebaselining and cal.all():
                    m.rebaselining = False
        for m in st.modules:
            m.fresh = False
        st.n_fresh = 0
        st.first_pending = math.inf
        st.oldest_pending_stamp = math.inf
        stamp, st.newest_stamp = st.newest_stamp, -math.inf  # per message: a clock step heals
        st.published += 1
        if not all_fresh:
            st.stale_publications += 1
        return PatchFrame(
            patch=st.layout.name,
            frame_id=st.layout.frame_id,
            stamp=stamp,
            taxel_ids=st.taxel_ids,
            delta_c=delta_c.astype(np.float32),
            raw=st.raw.tobytes(),
            status=status.tobytes(),
            tares=self.tares,
        )

    def drop_pending(self) -> int:
        """Forget the module readings waiting for their patch's message (how many): after a
        pause (the driver deactivated) they would come out with the next period's, with old
        stamps. The assembler's half pairs are its own (:meth:`PeriodAssembler.reset`)."""
        dropped = 0
        for st in self._patches:
            for m in st.modules:
                dropped += m.fresh
                m.fresh = False
            st.n_fresh = 0
            st.first_pending = st.oldest_pending_stamp = math.inf
            st.newest_stamp = -math.inf
        return dropped

    def tare(self) -> tuple[list[str], list[str]]:
        """Tare every patch: (patches tared, patches with a module not heard yet — their
        other modules tared); readings made from now on carry the new count in
        :attr:`PatchFrame.tares`."""
        done, missing = [], []
        for st in self._patches:
            (done if st.tracker.tare() else missing).append(st.layout.name)
        self.tares += 1
        return done, missing

    # -- health ---------------------------------------------------------------------------
    def publications(self) -> list[tuple[str, int, int]]:
        """Per patch: (name, readings published, of them with a module stale or silent)."""
        return [(st.layout.name, st.published, st.stale_publications) for st in self._patches]

    def diagnostics(self, now: float, window: bool = True) -> list[DiagStatus]:
        """Bus-wide frame counters, then one status per patch and per module.

        Rates are over the time since the previous call with ``window`` True (monotonic
        ``now`` [s]); an extra report (``window`` False, e.g. on a state change) repeats them.
        """
        c = self.assembler.counters
        rejected = {f"rejected_{k}": getattr(c, k) for k in c.REJECT_KINDS}
        frames = {
            "frames": c.frames,
            "readings": c.readings,
            "rejected": c.rejected,
            **rejected,
            "duplicates": c.duplicates,
            "incomplete_periods": c.incomplete,
            "orphan_b": c.orphan_b,
            "reordered": c.reordered,
        }
        out = [
            DiagStatus(
                "frames",
                0,
                f"{c.frames} frames, {c.rejected} rejected" if c.frames else "no frames yet",
                frames,
            )
        ]
        per_module = self.assembler.module_counters()
        self._check_silence(now)
        dt = now - self._report_time
        if window:
            self._report_time = now
        for st in self._patches:
            out.append(self._patch_status(st))
            for m in st.modules:
                out.append(
                    self._module_status(
                        st, m, per_module.get((m.board, m.triangle)), now, dt if window else None
                    )
                )
        return out

    def _patch_status(self, st: _PatchState) -> DiagStatus:
        st.last_bad = st.tracker.bad_taxels()
        bad = {st.taxel_ids[i]: why for i, why in st.last_bad.items()}
        kinds: dict[str, list[str]] = {"stuck": [], "dead": [], "saturated": [], "out_of_range": []}
        for tid, reasons in sorted(bad.items()):
            for r in reasons:
                for k in kinds:
                    if r.startswith(k.replace("_", " ")):
                        kinds[k].append(f"0x{tid:03X}")
        never = [f"{m.board}/{m.triangle}" for m in st.modules if not math.isfinite(m.last_seen)]
        silent = [f"{m.board}/{m.triangle}" for m in st.modules if m.silent]
        again = [f"{m.board}/{m.triangle}" for m in st.modules if m.rebaselining]
        level = 1 if bad or silent else 0
        parts = []
        if silent:
            parts.append(f"silent modules (board/triangle) {' '.join(silent)}: taxels invalid")
        if bad:
            parts.append(f"{len(bad)} bad taxels")
        if again:
            parts.append(f"re-baselining modules {' '.join(again)}")
        elif not st.tracker.calibrated:
            parts.append("calibrating")
        msg = ", ".join(parts) if parts else "ok"
        values: dict[str, object] = {
            "published": st.published,
            "published_with_stale_modules": st.stale_publications,
            "calibrated": st.tracker.calibrated,
            "bad_taxels": len(bad),
            **{f"{k}_taxels": " ".join(v) for k, v in kinds.items()},
            "never_heard_modules": " ".join(never),
            "silent_modules": " ".join(silent),
            "rebaselining_modules": " ".join(again),
        }
        return DiagStatus(f"patch {st.layout.name}", level, msg, values, st.layout.frame_id)

    def _module_status(
        self,
        st: _PatchState,
        m: _ModuleState,
        mc: assembler.ModuleCounters | None,
        now: float,
        dt: float | None,
    ) -> DiagStatus:
        readings = mc.readings if mc is not None else 0
        if dt is not None:
            m.rate_hz = (readings - m.readings_at_report) / dt if dt > 0 else 0.0
            m.readings_at_report = readings
        rate = m.rate_hz
        age = now - m.last_seen
        silent = m.silent
        # A period lost to a half-received pair is both a gap between readings (missed) and
        # an incomplete pair or an orphan B: counted once. The gaps count every lost period
        # where the stamps are the frames' own; the pairs where they are not (an interface
        # that does not stamp: no gap is ever seen).
        halves = (mc.incomplete + mc.orphan_b) if mc is not None else 0
        drops = max(m.missed_periods, halves)
        values: dict[str, object] = {
            "rate_hz": float(rate),
            "readings": readings,
            "drops": drops,
            "missed_periods": m.missed_periods,
            "incomplete_periods": mc.incomplete if mc is not None else 0,
            "orphan_b": mc.orphan_b if mc is not None else 0,
            "duplicates": mc.duplicates if mc is not None else 0,
            "error_readings": mc.error_readings if mc is not None else 0,
            "last_error_flags": mc.last_error_flags if mc is not None else 0,
            "stale": silent,
            "seconds_since_last_reading": float(age) if math.isfinite(age) else -1.0,
            "returns_after_silence": m.returns,
            "rebaselining": m.rebaselining,
        }
        if silent:
            level, msg = 2, "silent" if readings else "never heard"
        elif m.rebaselining:
            level, msg = 0, f"{rate:.1f} Hz, back after a silence: re-baselining"
        elif mc is not None and mc.last_error_flags:
            level, msg = 1, f"module error flags 0x{mc.last_error_flags:X}"
        else:
            level, msg = 0, f"{rate:.1f} Hz"
        name = f"patch {st.layout.name} module board {m.board} triangle {m.triangle}"
        return DiagStatus(name, level, msg, values, f"board {m.board} triangle {m.triangle}")
