"""Per-taxel baseline: calibration, drift tracking frozen in contact, tare, bad-taxel detection.

The module value of an unloaded taxel (its *baseline*, in 8-bit counts) is learnt from the
first ``calibration_samples`` readings, then follows slow drift (temperature, humidity) with an
exponential filter of time constant ``drift_time_constant_s`` — but only where nothing touches
the skin. Contact is detected per taxel on the *magnitude* of the deviation from the baseline
(beside a small contact the layer bulges and taxels read negative, DESIGN.md §2), with
hysteresis in level (``contact_on_counts`` / ``contact_off_counts``) and time (``release_s``);
tracking is frozen on the taxels in contact, on every taxel within ``freeze_radius_m`` of one,
and, with ``module_freeze``, on the whole module. A held contact therefore keeps its ΔC
for ``max_freeze_s`` (5 min by default), while drift without contact is followed. Drift that
accumulated unseen under a long contact is absorbed after the contact ends: a taxel is released
when its deviation stays below ``release_fraction`` of its contact peak (or below
``contact_off_counts``) for ``release_s``, and only contacts with a fast onset freeze anything,
so the residual is then tracked away with the drift time constant.

Output is ΔC [F] (positive = compression) through :mod:`tactile_contact.model.sensor`, and per-taxel
status flags whose values match ``tactile_contact/msg/TaxelArray`` (plus STATUS_UNCALIBRATED).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.model.sensor import DEFAULT_FARAD_PER_COUNT, DEFAULT_SHIFT, value_count_farad

if TYPE_CHECKING:
    from tactile_contact.model.layout import PatchLayout

STATUS_OK = 0
STATUS_DISABLED = 1
STATUS_STUCK = 2
STATUS_DEAD = 4
STATUS_SATURATED = 8
STATUS_OUT_OF_RANGE = 16
STATUS_STALE = 32
STATUS_CONTACT = 64
STATUS_UNCALIBRATED = 128
"""Not in TaxelArray.msg yet: the channel has not collected its calibration samples."""

STATUS_NAMES = {
    STATUS_DISABLED: "disabled",
    STATUS_STUCK: "stuck",
    STATUS_DEAD: "dead",
    STATUS_SATURATED: "saturated",
    STATUS_OUT_OF_RANGE: "out_of_range",
    STATUS_STALE: "stale",
    STATUS_CONTACT: "contact",
    STATUS_UNCALIBRATED: "uncalibrated",
}
BAD_STATUS = STATUS_DISABLED | STATUS_STUCK | STATUS_DEAD | STATUS_SATURATED | STATUS_OUT_OF_RANGE
_MAX_DT_S = 1.0  # a long silence must not let one sample pull the baseline all the way
#: A timestamp this much [s] before the latest is a clock that stepped back (reordered
#: frames are milliseconds apart): the tracker's held times move with it.
CLOCK_STEP_S = 1.0


def status_names(status: int) -> list[str]:
    """Names of the flags set in one status byte."""
    return [name for bit, name in STATUS_NAMES.items() if status & bit]


@dataclass(frozen=True)
class BaselineConfig:
    """Baseline tracking parameters (recommended driver defaults).

    Attributes:
        calibration_samples: unloaded readings averaged at start (and on recalibrate) [-].
        drift_time_constant_s: time constant of the drift filter [s]; the gain per reading is
            1 − exp(−dt/τ). Drift of r counts/s is followed with a lag of r·τ counts.
        contact_on_counts: |baseline − value| at or above which a taxel is in contact [counts].
        contact_off_counts: |deviation| below which a taxel may leave contact [counts].
        release_s: time the deviation must stay below the release level to release [s].
        release_fraction: a taxel also counts as released when |deviation| stays below this
            fraction of its peak during the contact (0 disables). This lets drift that built
            up under a long contact be tracked again once the object is lifted, instead of
            holding the contact forever.
        onset_time_constant_s: time constant of the onset filter [s]. Only a contact whose
            value stepped by ``contact_on_counts`` against this filter (a press faster than
            about contact_on_counts / onset_time_constant_s counts/s) freezes baselines; slower
            deviations (drift, very slow light presses) are flagged as contact but tracked.
        freeze_radius_m: taxels within this distance of a contact are frozen too [m] (needs
            positions; 0 freezes only the taxels in contact).
        module_freeze: freeze the whole module when one of its taxels is in contact.
        max_freeze_s: resume tracking after this long frozen [s] (None: never). The escape
            from the cases no rule can tell from a held object (a light load absorbed by
            tracking and then lifted reads as a lasting negative contact); a longer hold then
            fades with the drift time constant.
        stuck_timeout_s: a valid taxel whose value has not changed for this long is stuck [s]
            (None: never).
        dead_timeout_s: a taxel reading 0 for this long is dead [s].
        tare_window: readings averaged by :meth:`BaselineTracker.tare` [-].
    """

    calibration_samples: int = 20
    drift_time_constant_s: float = 20.0
    contact_on_counts: float = 3.0
    contact_off_counts: float = 2.0
    release_s: float = 1.0
    release_fraction: float = 0.25
    onset_time_constant_s: float = 2.0
    freeze_radius_m: float = 0.012
    module_freeze: bool = True
    max_freeze_s: float | None = 300.0
    stuck_timeout_s: float | None = 60.0
    dead_timeout_s: float = 5.0
    tare_window: int = 10

    def __post_init__(self) -> None:
        if not (isinstance(self.calibration_samples, int) and self.calibration_samples >= 1):
            raise ValueError(
                f"calibration_samples must be an int >= 1, got {self.calibration_samples!r}"
            )
        if not (isinstance(self.tare_window, int) and self.tare_window >= 1):
            raise ValueError(f"tare_window must be an int >= 1, got {self.tare_window!r}")
        for name in (
            "drift_time_constant_s",
            "onset_time_constant_s",
            "contact_on_counts",
            "dead_timeout_s",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if not 0.0 <= self.release_fraction < 1.0:
            raise ValueError(
                f"release_fraction must be within [0, 1), got {self.release_fraction!r}"
            )
        for name in ("release_s", "freeze_radius_m", "contact_off_counts"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        if self.contact_off_counts > self.contact_on_counts:
            raise ValueError(
                f"contact_off_counts {self.contact_off_counts} exceeds contact_on_counts "
                f"{self.contact_on_counts}"
            )
        for name in ("max_freeze_s", "stuck_timeout_s"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be None or finite and > 0, got {v!r}")


@dataclass(frozen=True)
class BaselineResult:
    """Output of one :meth:`BaselineTracker.update`.

    Attributes:
        delta_c: (N,) capacitance change [F], positive = compression (0 where disabled or
            uncalibrated). Never clipped.
        deviation: (N,) baseline − value [8-bit counts].
        status: (N,) uint8 STATUS_* flags.
        contact: (N,) taxels in contact (hysteresis state).
        frozen: (N,) taxels whose baseline is frozen this reading (near a fast-onset contact).
        calibrated: every valid taxel has its calibration.
    """

    delta_c: NDArray[np.float64]
    deviation: NDArray[np.float64]
    status: NDArray[np.uint8]
    contact: NDArray[np.bool_]
    frozen: NDArray[np.bool_]
    calibrated: bool


class BaselineTracker:
    """Baselines of the N channels of one patch (thermal pads and disabled channels included).

    Args:
        n_channels: N.
        valid: (N,) True for real, enabled taxels (layout ``valid_mask``); default all.
        module_index: (N,) module number of each channel (for ``module_freeze``); default
            consecutive groups of 12.
        positions: (N, 2) channel centres [m] (for ``freeze_radius_m``); None: no radius.
        farad_per_count: gain of one CDC count [F] (scalar or (N,)).
        shift: firmware shift [bits] (scalar or (N,)).
        config: :class:`BaselineConfig`.
    """

    def __init__(
        self,
        n_channels: int,
        *,
        valid: ArrayLike | None = None,
        module_index: ArrayLike | None = None,
        positions: ArrayLike | None = None,
        farad_per_count: ArrayLike = DEFAULT_FARAD_PER_COUNT,
        shift: ArrayLike = DEFAULT_SHIFT,
        config: BaselineConfig | None = None,
    ) -> None:
        if not (isinstance(n_channels, int) and n_channels >= 1):
            raise ValueError(f"n_channels must be an int >= 1, got {n_channels!r}")
        n = n_channels
        self.n = n
        self.config = cfg = config or BaselineConfig()
        self.valid = self._mask("valid", valid, True)
        mi = np.arange(n) // 12 if module_index is None else np.asarray(module_index)
        if mi.shape != (n,):
            raise ValueError(f"module_index must have shape ({n},), got {mi.shape}")
        self._gain = np.broadcast_to(value_count_farad(farad_per_count, shift), (n,)).copy()
        # Freeze neighbourhood as a 0/1 matrix: frozen = (nbr @ contact) > 0.
        nbr = np.eye(n, dtype=bool)
        if positions is not None:
            p = np.asarray(positions, dtype=np.float64)
            if p.shape != (n, 2) or not np.all(np.isfinite(p)):
                raise ValueError(f"positions must be a finite ({n}, 2) array [m], got {p.shape}")
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
            nbr |= d <= cfg.freeze_radius_m
        if cfg.module_freeze:
            nbr |= mi[:, None] == mi[None, :]
        self._nbr = nbr.astype(np.float64)
        self._nbr_cols = np.ascontiguousarray(self._nbr.T)  # column j as a contiguous row
        # The last tare_window readings, each with the channels it carries (fresh, no module
        # error): a tare averages each channel over its own.
        self._recent: deque[tuple[NDArray[np.float64], NDArray[np.bool_]]] = deque(
            maxlen=cfg.tare_window
        )
        # Per-call constants: update() runs at 50 Hz per patch on a driver serving dozens of
        # patches, where a numpy call on 72 elements costs about as much as its arithmetic.
        self._all = np.ones(n, dtype=bool)
        self._none = np.zeros(n, dtype=bool)
        self._all.flags.writeable = self._none.flags.writeable = False
        self._all_valid = bool(self.valid.all())
        self._disabled = np.where(self.valid, 0, STATUS_DISABLED).astype(np.uint8)
        self._disabled_contact = self._disabled | np.uint8(STATUS_CONTACT)
        self._exp_arg = np.empty(2)
        self._t_max = -math.inf  # latest timestamp so far [s]
        self.recalibrate()

    @classmethod
    def from_patch(
        cls, patch: PatchLayout, config: BaselineConfig | None = None
    ) -> BaselineTracker:
        """A tracker of every channel of a layout patch (layout order, pads and disabled
        channels included and flagged), with its positions, modules and sensor gain."""
        xy = patch.channel_xy()
        return cls(
            len(xy),
            valid=patch.valid_mask(),
            module_index=np.repeat(np.arange(len(patch.modules)), 12),
            positions=xy,
            farad_per_count=patch.sensor.farad_per_count,
            shift=patch.sensor.shift,
            config=config,
        )

    def _mask(self, name: str, m: ArrayLike | None, default: bool) -> NDArray[np.bool_]:
        if m is None:
            return np.full(self.n, default)
        a = np.asarray(m, dtype=bool)
        if a.shape != (self.n,):
            raise ValueError(f"{name} must have shape ({self.n},), got {a.shape}")
        return a

    # -- state control --------------------------------------------------------------------
    def recalibrate(self, channels: ArrayLike | None = None) -> None:
        """Forget the baselines and learn them again from the next readings (send unloaded).

        ``channels``: (N,) bool mask of the channels to recalibrate (e.g. one module that came
        back after a silence, possibly rebooted with another offset); default all.
        """
        n = self.n
        # Shortcut flags of update(), each only ever True when what it claims holds:
        # _all_cal every channel calibrated; _last_t_all the value of every _last_t (NaN
        # included) or None; _ref_nan _onset_ref may hold NaN; _blank_end >= every _blank_until;
        # _zero_any / _cal_zero_any _zero_s / _cal_zero may be non-zero.
        self._all_cal = False
        self._ref_nan = True
        if channels is None:
            self._last_t_all: float | None = math.nan
            self._zero_any = self._cal_zero_any = False
            self.baseline = np.zeros(n)
            self._cal_sum = np.zeros(n)
            self._cal_count = np.zeros(n, dtype=np.int64)
            self._cal_zero = np.zeros(n, dtype=bool)
            self._clear_dynamics()
            self._last_value = np.full(n, -1, dtype=np.int64)
            self._unchanged_s = np.zeros(n)
            self._zero_s = np.zeros(n)
            self._last_t = np.full(n, np.nan)
            self._onset_ref = np.full(n, np.nan)
            self._recent.clear()
            return
        m = self._mask("channels", channels, False)
        # (their readings so far are of the state they are recalibrated from: no tare's)
        self._recent = deque(((v, f & ~m) for v, f in self._recent), maxlen=self._recent.maxlen)
        self._last_t_all = None
        self.baseline[m] = 0.0
        self._cal_sum[m] = 0.0
        self._cal_count[m] = 0
        self._cal_zero[m] = False
        self._clear_dynamics(m)
        self._last_value[m] = -1
        self._unchanged_s[m] = 0.0
        self._zero_s[m] = 0.0
        self._last_t[m] = np.nan
        self._onset_ref[m] = np.nan

    def _clear_dynamics(self, m: NDArray[np.bool_] | None = None) -> None:
        # _hard_key: hard.tobytes() of the cached _frozen; _fs_ok: _frozen_since and _fs_min
        # are up to date for that _frozen.
        self._hard_key = b""
        self._fs_ok = False
        if m is None:
            n = self.n
            self._blank_end = -math.inf
            self.contact = np.zeros(n, dtype=bool)
            self.hard = np.zeros(n, dtype=bool)
            self._blank_until = np.full(n, -np.inf)
            self._blank_level = np.zeros(n)
            self._peak = np.zeros(n)
            self._quiet_since = np.full(n, np.inf)
            self._frozen_since = np.full(n, np.inf)
            return
        self.contact[m] = False
        self.hard[m] = False
        self._blank_until[m] = -np.inf
        self._blank_level[m] = 0.0
        self._peak[m] = 0.0
        self._quiet_since[m] = np.inf
        self._frozen_since[m] = np.inf

    def _clock_stepped(self, shift: float) -> None:
        """The timestamps jumped back by −``shift`` [s] (an adapter's clock restarted at a
        reconnect, a wall clock set): the times held move with them, so that a contact is
        released and a freeze ends after the durations they were due, not after the step."""
        for a in (self._quiet_since, self._frozen_since, self._blank_until, self._last_t):
            np.add(a, shift, out=a, where=np.isfinite(a))
        if math.isfinite(self._blank_end):
            self._blank_end += shift
        if self._last_t_all is not None and math.isfinite(self._last_t_all):
            self._last_t_all += shift
        self._t_max += shift
        self._fs_ok = False

    def tare(self) -> bool:
        """Make the current readings the baselines: each channel's mean over the last
        ``tare_window`` readings that carried it (fresh, no module error, since its last
        recalibration). A channel none of them carried (a module not heard yet, or silent
        and being calibrated again) keeps its state: no reading of it, no baseline.

        Clears the contact states. Returns whether every valid channel was tared (False,
        and nothing done, before any reading).
        """
        if not self._recent:
            return False
        values = np.stack([v for v, _ in self._recent])
        carried = np.stack([f for _, f in self._recent])
        count = carried.sum(axis=0)
        tared = count > 0
        mean = (values * carried).sum(axis=0) / np.maximum(count, 1)
        self.baseline = np.where(tared, mean, self.baseline)
        self._onset_ref = np.where(tared, mean, self._onset_ref)
        self._ref_nan = True
        done = tared & (self._cal_count < self.config.calibration_samples)
        self._cal_count[done] = self.config.calibration_samples
        self._all_cal = bool(np.all(self.calibrated_mask))
        self._clear_dynamics()
        return bool(np.all(tared[self.valid]))

    @property
    def calibrated_mask(self) -> NDArray[np.bool_]:
        """(N,) channels that have their calibration."""
        return self._cal_count >= self.config.calibration_samples

    @property
    def calibrated(self) -> bool:
        """All valid channels have their calibration."""
        return bool(np.all(self.calibrated_mask[self.valid]))

    # -- the update -----------------------------------------------------------------------
    def update(
        self,
        raw: ArrayLike,
        timestamp: float,
        *,
        fresh: ArrayLike | None = None,
        out_of_range: ArrayLike | None = None,
        module_error: ArrayLike | None = None,
    ) -> BaselineResult:
        """Process one reading of all N channels.

        Args:
            raw: (N,) module values [8-bit counts, 0..255].
            timestamp: receive time [s] (monotonic within a tracker).
            fresh: (N,) channels updated since the previous call (others are stale: their
                baselines and timers are left alone); default all.
            out_of_range: (N,) the module's out-of-range bits.
            module_error: (N,) the module reported an I²C / connection error.
        """
        n = self.n
        r = np.asarray(raw)
        if r.shape != (n,):
            raise ValueError(f"raw must have shape ({n},), got {r.shape}")
        v = r.astype(np.float64)
        # uint8 (what the codec delivers) cannot be out of range: skip the check.
        if r.dtype != np.uint8 and (not np.all(np.isfinite(v)) or np.any((v < 0) | (v > 255))):
            raise ValueError(f"raw values must be within 0..255, got range {v.min()}..{v.max()}")
        if not (math.isfinite(timestamp) if type(timestamp) is float else np.isfinite(timestamp)):
            raise ValueError(f"timestamp must be finite, got {timestamp!r}")
        cfg = self.config
        t = float(timestamp)
        if t < self._t_max - CLOCK_STEP_S:
            self._clock_stepped(t - self._t_max)
        # Masks that are all True or all False are common (every module fresh, no module
        # error, nothing out of range); the flags below skip the operations they make no-ops.
        if fresh is None:
            fr, all_fresh = self._all, True
        else:
            fr = self._mask("fresh", fresh, True)
            all_fresh = np.count_nonzero(fr) == n
        if out_of_range is None:
            oor, any_oor = self._none, False
        else:
            oor = self._mask("out_of_range", out_of_range, False)
            any_oor = np.count_nonzero(oor) > 0
        if module_error is None:
            err, any_err = self._none, False
        else:
            err = self._mask("module_error", module_error, False)
            any_err = np.count_nonzero(err) > 0
        all_valid = self._all_valid

        # dt [s] per channel, or one scalar when every channel shares it (the usual case).
        dt: float | NDArray[np.float64]
        lt = self._last_t_all
        if all_fresh and lt is not None:
            dt = 0.0 if math.isnan(lt) else min(max(t - lt, 0.0), _MAX_DT_S)
            # The same numpy expm1 as per channel, on the shared value: identical gains.
            x = self._exp_arg
            x[0] = -dt / cfg.onset_time_constant_s
            x[1] = -dt / cfg.drift_time_constant_s
            e_on, e_drift = np.expm1(x)
            a_on, alpha = -e_on, -e_drift
        else:
            dt = np.fmin(np.fmax(t - self._last_t, 0.0), _MAX_DT_S)  # fmax: NaN (never) → 0
            if not all_fresh:
                dt[~fr] = 0.0
            a_on = -np.expm1(-dt / cfg.onset_time_constant_s)
            alpha = -np.expm1(-dt / cfg.drift_time_constant_s)
        if all_fresh:
            self._last_t.fill(t)
            self._last_t_all = t
        else:
            self._last_t[fr] = t
            self._last_t_all = None
        # (v and the masks are never written to)
        self._recent.append((v, fr & ~err if any_err else fr))

        if r.dtype == np.uint8:  # a byte search costs far less than two comparisons and an or
            rb = r.tobytes()
            any_sat = b"\x00" in rb or b"\xff" in rb
        else:
            any_sat = True
        if any_sat:
            zero = v == 0
            sat = (v <= 0) | (v >= 255)
            any_sat = np.count_nonzero(sat) > 0
        else:
            zero = sat = self._none

        # Calibration: plain mean of the first samples of every channel.
        if self._all_cal:
            cal, just = self._all, None
            dev = self.baseline - v
        else:
            cal_before = self.calibrated_mask
            learn = fr & ~cal_before & ~err
            self._cal_sum[learn] += v[learn]
            self._cal_count[learn] += 1
            self._cal_zero[learn] |= v[learn] == 0
            self._cal_zero_any = np.count_nonzero(self._cal_zero) > 0
            just = learn & self.calibrated_mask
            self.baseline[just] = self._cal_sum[just] / self._cal_count[just]
            cal = self.calibrated_mask
            self._all_cal = bool(np.count_nonzero(cal) == n)
            dev = np.where(cal, self.baseline - v, 0.0)
        mag = np.abs(dev)
        every_active = self._all_cal and all_fresh and all_valid
        active = None if every_active else cal & self.valid & fr
        # Level hysteresis with a release delay.
        on = mag >= cfg.contact_on_counts
        if active is not None:
            on &= active
        contact = self.contact
        had_contact = np.count_nonzero(contact) > 0
        co = contact | on if had_contact else on
        if np.count_nonzero(co):
            peak = np.maximum(self._peak, mag)
            peak *= co  # peak >= 0 is finite: the same as np.where(co, peak, 0.0)
            quiet = mag < np.maximum(cfg.contact_off_counts, cfg.release_fraction * peak)
        else:
            peak = np.zeros(n)
            quiet = mag < max(cfg.contact_off_counts, 0.0)
        if active is not None:
            quiet &= active
        # The "since" times hold past timestamps or inf: while time runs forward, "t where inf"
        # is a minimum.
        monotonic = t >= self._t_max
        self._t_max = max(self._t_max, t)
        if monotonic and active is None:
            self._quiet_since = qs = np.where(quiet, np.minimum(self._quiet_since, t), np.inf)
        else:
            qs = self._quiet_since
            qs[quiet & np.isinf(qs)] = t
            qs[~quiet if active is None else active & ~quiet] = np.inf
        if had_contact:
            # With every channel active, qs is inf where not quiet: t - inf never releases.
            released = contact & (t - qs >= cfg.release_s)
            if active is not None:
                released &= quiet
            if np.count_nonzero(released):
                co &= ~released
                peak[released] = 0.0
        if not all_valid:
            co &= self.valid
        self.contact = contact = co
        self._peak = peak
        # Only a contact that appeared quickly (a step of contact_on_counts against the onset
        # filter) freezes baselines: drift that built up unseen on a frozen taxel also crosses
        # the level threshold, and must not keep the region frozen for ever.
        if self._ref_nan:
            ref = np.where(np.isnan(self._onset_ref), v, self._onset_ref)
        else:
            ref = self._onset_ref
        d = v - ref
        if np.count_nonzero(contact):
            # Around a fast contact that is being lifted, the layer relaxing (and drift that
            # built up during the hold) steps the neighbours too. Until the onset filter has
            # settled, a step there must reach half the lifted contact's peak to count (a
            # sliding contact moving on does; a relaxing bulge does not).
            hq = self.hard & quiet
            if np.count_nonzero(hq):
                # max_j nbr[i, j]·peak_rel[j] over the few j of nonzero peak (the rest are 0).
                lifted = np.flatnonzero(peak * hq)
                if len(lifted):
                    p = peak[lifted]
                    lvl = (self._nbr_cols[lifted] * p[:, None]).max(axis=0) * 0.5
                    renew = lvl > 0
                    bl, bu = self._blank_level, self._blank_until
                    np.copyto(bl, np.maximum(np.where(t < bu, bl, 0.0), lvl), where=renew)
                    until = t + 2.0 * cfg.onset_time_constant_s
                    np.copyto(bu, until, where=renew)
                    self._blank_end = max(self._blank_end, until)
            # The step must move away from the baseline (ref − v and the deviation of one
            # sign): lifting an object is a fast step too. A blanked step must also reach
            # the blanking level.
            on_c = cfg.contact_on_counts
            if t < self._blank_end:  # else nothing is blanked
                on_c = np.where(t < self._blank_until, np.maximum(self._blank_level, on_c), on_c)
            step = (np.abs(d) >= on_c) & (d * dev < 0)
            if active is not None:
                step &= active
            self.hard = hard = contact & (self.hard | step)
        else:
            # A lifted contact had released every hard taxel (hard is within contact), so
            # their peaks are 0 and no neighbour blanking is renewed either.
            self.hard = hard = np.zeros(n, dtype=bool)
        upd_all = all_fresh and not any_err
        if upd_all:
            self._onset_ref = ref + a_on * d
            self._ref_nan = False
        else:
            upd = fr & ~err
            self._onset_ref[upd] = (ref + a_on * d)[upd]

        # frozen depends on hard alone, which changes a few times per contact.
        key = hard.tobytes()
        if key != self._hard_key:
            self._hard_key = key
            self._frozen = (self._nbr @ hard.astype(np.float64)) > 0.0
            self._any_frozen = np.count_nonzero(self._frozen) > 0
            self._fs_ok = False
        frozen = self._frozen
        if not (self._fs_ok and monotonic):  # else every frozen_since stays as it is
            fs = self._frozen_since
            fs[frozen & np.isinf(fs)] = t
            fs[~frozen] = np.inf
            self._fs_min = fs.min()
            self._fs_ok = True
        hold = None
        if self._any_frozen:
            hold = frozen
            # The oldest freeze within max_freeze_s: all are (rounding of t − x is monotonic).
            mf = cfg.max_freeze_s
            if mf is not None and not t - self._fs_min <= mf:
                hold = frozen & (t - self._frozen_since <= mf)
        b = self.baseline
        track = None  # all
        if not (upd_all and all_valid and not any_sat and not any_oor and just is None):
            track = fr & self.valid & ~sat & ~oor & ~err & cal
            if just is not None:
                track &= ~just
        if hold is not None:
            track = ~hold if track is None else track & ~hold
        if track is None:
            b += alpha * (v - b)
        else:
            np.add(b, alpha * (v - b), out=b, where=track)

        # Fault timers count time of fresh readings only, so a silent module is stale, not stuck.
        same = v == self._last_value
        if all_fresh:
            self._unchanged_s = (self._unchanged_s + dt) * same  # >= 0: where(same, ..., 0)
            self._last_value = v.astype(np.int64)
        else:
            same &= fr
            self._unchanged_s[same] += dt[same]
            self._unchanged_s[fr & ~same] = 0.0
            self._last_value[fr] = v[fr].astype(np.int64)
        if self._zero_any or np.count_nonzero(zero):
            zero = fr & zero
            self._zero_s[zero] += dt[zero] if isinstance(dt, np.ndarray) else dt
            self._zero_s[fr & ~zero] = 0.0
            self._zero_any = np.count_nonzero(self._zero_s) > 0
            dead = err | (self._zero_s > cfg.dead_timeout_s)
        else:
            dead = err

        # Flags other than disabled and contact are rare: set only those present.
        status = np.where(contact, self._disabled_contact, self._disabled)
        if cfg.stuck_timeout_s is not None:
            stuck = self._unchanged_s > cfg.stuck_timeout_s
            if np.count_nonzero(stuck):
                status[stuck & self.valid] |= STATUS_STUCK
        if self._cal_zero_any:
            dead = dead | (cal & self._cal_zero)
        if dead is not err or any_err:
            status[dead] |= STATUS_DEAD
        if any_sat:
            status[sat] |= STATUS_SATURATED
        if any_oor:
            status[oor] |= STATUS_OUT_OF_RANGE
        if not all_fresh:
            status[~fr] |= STATUS_STALE
        if not self._all_cal:
            status[~cal] |= STATUS_UNCALIBRATED

        delta_c = dev * self._gain
        if not (self._all_cal and all_valid):
            delta_c = np.where(cal & self.valid, delta_c, 0.0)
        self._last_status = status
        return BaselineResult(
            delta_c=delta_c,
            deviation=dev,
            status=status,
            contact=contact.copy(),
            frozen=frozen.copy(),
            calibrated=self._all_cal or bool(np.all(cal[self.valid])),
        )

    # -- diagnostics ----------------------------------------------------------------------
    def bad_taxels(self) -> dict[int, list[str]]:
        """Channel index → reasons, for every valid channel flagged bad in the last update."""
        st = getattr(self, "_last_status", None)
        if st is None:
            return {}
        out: dict[int, list[str]] = {}
        for i in np.flatnonzero(self.valid & (st & BAD_STATUS != 0)):
            reasons = []
            s = int(st[i])
            if s & STATUS_DEAD:
                why = "reads 0 at rest" if self._cal_zero[i] else "module error or reads 0"
                reasons.append(f"dead ({why})")
            if s & STATUS_STUCK:
                reasons.append(f"stuck (unchanged for {self._unchanged_s[i]:.0f} s)")
            if s & STATUS_SATURATED:
                reasons.append(f"saturated (value {self._last_value[i]})")
            if s & STATUS_OUT_OF_RANGE:
                reasons.append("out of range (module flag)")
            out[int(i)] = reasons
        return out
