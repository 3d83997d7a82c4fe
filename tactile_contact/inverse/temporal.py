"""Frames of a held scene fused over time (issues 25 and 26).

A press lasts many frames, and one 8-bit frame is near its information limit (one count is
≈ 10 µm of compression; a 1 N press's force information sits in a ring of readings of a count
or two). While the scene does not change, the mean of its frames carries the same contact with
less noise. :class:`FrameFusion` keeps that mean for one patch and solves it now and then; every
other frame republishes the last result without solving, so a held grasp or an idle patch
costs one compiled pass over the readings (:func:`tactile_contact.inverse._temporal_kernels.
held_step`).

Noise. σ_i, passed in, is one frame's error (what the node's tracker learns from frames without
contact). Only the part of it that changes from frame to frame averages out: the converter's
noise, and with it the rounding when that noise dithers it (≳ 0.3 count); a baseline's offset
or the rounding of a still reading without noise stays. The frames' scatter about their mean
measures that part, s·σ_i (s learnt robustly, a trimmed mean of every frame's squared
residuals, over SCALE_MEMORY frames); the mean of n frames then errs by
σ_i·√(max(1 − s², 0) + s²/n), and the reconstructor solves it as that noise (``Frame.frames``,
the effective number of frames).

Per frame, against the mean of the window (the frames since the scene last changed, at most
``window``), with residuals u_i = (δ_i − mean_i)/(s·σ_i·√(1 + 1/n)) (s at least a rounding's
worth, one count/√12, for 8-bit readings):

- the whole frame: Σ u_i² (u_i = (δ_i − mean_i)/(σ_i·√(1 + 1/n))) against its χ² limit;
- each taxel's neighbourhood (taxels within ``reach``): a small contact that appears, moves or
  leaves changes a few taxels, which the whole frame's 72 degrees of freedom would dilute;
- the directions in which the last result's contacts would change (force, centre, size of
  each round contact: its whitened Jacobian): a slow slide or a force that creeps.

Each at a false-change rate ``alpha`` per frame. A change ends the window: the frame is solved
on its own (what the reconstructor alone gives) and a new window starts from it. Otherwise the
frame joins the window, and the window is solved again when its length reaches 2, 3, 4, 6, 8,
… 50 frames and then every ``resolve_every`` frames; each such solve looks back over the
window's frames for a step along the new result's directions (a change too small for one frame,
say a light press that began while the patch read nothing) and drops the frames before it. An
idle patch (the last result has no contact) looks, every frame, at the means of its last 4, 6,
8, 10, 12, 16 and 32 frames, and solves the one whose energy in some neighbourhood stands out
(a χ² level noise alone reaches in ≈ 1 % of frames; :func:`tactile_contact.inverse.
_temporal_kernels.idle_scan`), and the last 32 every ``idle_every`` frames whatever: a touch
too light for one frame is found with up to √32 of its single-frame statistic, at the
reconstructor's stated false-contact rate per solve, without a detector pass a frame.

Costs and limits, measured in bench/bench_time.py and bench/bench_held.py (docs/bench/time.md):
a moving contact is averaged over the frames its motion stays within noise, so the fused
estimate trails it (lag in frames printed there); a change smaller than the noise of the
window is averaged in, not noticed.

All readings are compressions δ [m] of the bundle's taxels; no ROS import.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from tactile_contact.inverse import _temporal_kernels as kern
from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.round_contact import FAMILIES, RoundTables

if TYPE_CHECKING:
    from tactile_contact.inverse.reconstruction import Reconstructor

#: Frames in the window at most (1 s at 50 Hz): the mean's noise is a frame's over √50.
WINDOW = 50
#: The window is solved again when it reaches these lengths, then every RESOLVE_EVERY frames.
RESOLVE_AT = frozenset((2, 3, 4, 6, 8, 10, 12, 16, 20, 25, 32, 40, 50))
RESOLVE_EVERY = 25
#: An idle patch scans the means of its last IDLE_WINDOWS frames every frame, and solves one
#: when its neighbourhood energy passes the level noise alone reaches in IDLE_TRIGGER of the
#: frames (a detector pass, ≈ 20–35 µs; then none for IDLE_BACKOFF's frames), and the last
#: 32 every IDLE_EVERY frames whatever. (A window of 8 alone never finds a press whose frames
#: reach a third of the detection threshold; 32 alone dilutes a press that began within it;
#: cycling 8, 16, 32 every 4 frames missed 7 of 12 presses of 0.5 N after 10 frames. Windows
#: of 4, 8, 16, 32 looked at most every third frame: a press whose mean clears the threshold
#: from its 8th frame waited for a window of 8 or 16 and the look's turn — bench_time's held
#: presses ≤ 1 N, five draws each, calibrated, 0.5 N missed after 10 frames: point truth 13 →
#: 10 of 120, 3 mm electrodes 21 → 11; after 5 frames 46 → 23 and 33 → 28; idle frames
#: ≈ 1.5 µs dearer.)
IDLE_WINDOWS = (4, 6, 8, 10, 12, 16, 32)
IDLE_TRIGGER = 1e-2
#: After a look the scan picked, at a window of w frames, none for w // IDLE_BACKOFF frames:
#: a look that found nothing is worth repeating once the window holds new frames. A
#: light object resting on a patch near the threshold reads as a window that stands out
#: frame after frame: a 0.18 N sphere held between two taxels, 2900 frames, cost 1176 solves
#: and 276 µs a frame looked at every frame, 527 and 114 µs every third frame (the old rule),
#: 376 and 81 µs with this back-off; held presses found after 5 and 10 frames as often as
#: looked at every frame (bench_time's five draws: 0.5 N missed after 10 frames 10 and 11 of
#: 120, against 9 and 11; a back-off of w // 4: 11 and 16).
IDLE_BACKOFF = 8
IDLE_EVERY = 16
#: With ``defer``, a window's re-solve is left to catch_up only from this many frames on:
#: a shorter window follows a change (a contact that moves or settles), whose re-solve is
#: wanted in its own frame; the long windows of a held press are the dear ones (5–12 ms at
#: 20–50 frames on the robot's patches, docs/bench/tail.md) and gain least from one frame.
DEFER_FROM = 8
#: False-change rate of each test per frame (a false change costs one solve and restarts the
#: window).
ALPHA = 1e-3
#: Taxels within this distance [m] of a taxel form its neighbourhood (itself and the ring of
#: nearest taxels at the 5.5 mm pitch).
REACH = 6.5e-3
#: Frames the scale of the frame-to-frame scatter remembers, and the frames its starting
#: value (1: the noise passed in changes from frame to frame) counts for: one frame's 72
#: squared residuals give it to ±20 %, and a scale learnt from the first two frames alone
#: made the change tests too tight. Readings of unknown noise start from the first.
SCALE_MEMORY = 50.0
SCALE_PRIOR = 10.0
#: Steps of the round contacts' derivatives: centre [m] (within one 0.1 mm table step, where
#: the tables are linear), radius (relative).
STEP_XY = 1.0e-5
STEP_RADIUS = 0.02


#: solve(δ (K,) [m], valid (K,), σ (K,) [m] as passed to :meth:`FrameFusion.step`, frames
#: averaged n, effective frames (the mean's noise is σ/√effective), want traction, want
#: deflection, context) → the reconstructor's result for the mean of n frames (n = 1: the
#: frame alone, as the reconstructor solves it; ``context``: what the caller passed to
#: :meth:`FrameFusion.step`).
Solve = Callable[[NDArray, NDArray, NDArray, int, float, bool, bool, object], object]
#: jacobian(result, valid) → (K, m) derivatives [m per unit] of the result's predicted
#: readings in its parameters, or None (no contact, or no parametric contact).
Jacobian = Callable[[object, NDArray], NDArray | None]
#: screen(mean δ (K,) [m], valid (K,), σ (K,) [m], effective frames, context) → whether the
#: mean of an idle window deserves a solve at all (the detector's bank test alone).
Screen = Callable[[NDArray, NDArray, NDArray, float, object], bool]


@dataclass
class FusionCounts:
    """What the frames cost: ``solved`` on their own (a change), ``fused`` (the window solved),
    ``held`` (the last result republished), and the changes by test."""

    solved: int = 0
    fused: int = 0
    held: int = 0
    screened: int = 0  # idle windows on the clock the bank test found nothing in (no solve)
    deferred: int = 0  # re-solves (window or idle look) run by catch_up, after the frame
    changes: dict[str, int] = field(default_factory=dict)


class FrameFusion:
    """Fuses one patch's frames while its scene holds (see the module docstring).

    Args:
        taxel_xy: (K, 2) taxel centres [m].
        solve: the reconstructor's solve of a mean of frames (:data:`Solve`).
        jacobian: the result's parameter directions (:data:`Jacobian`).
        screen: for the idle windows solved on the clock (every ``idle_every`` frames, not
            picked by the scan), whether to solve at all (:data:`Screen`); None: solve.
        defer: a re-solve that no change asks for (the window's on its schedule, from
            DEFER_FROM frames, and an idle patch's look into its window means) is not run
            inside :meth:`step`, which republishes the last result, but by the next
            :meth:`catch_up`: a caller serving
            many patches publishes every patch's frame first and spends the time after
            (contact_reconstruction). The fusion's state after catch_up is what step would
            have left; its result reaches the next frame. False (the default): run at once.
        rounding: the rounding error of one 8-bit reading [m] (one count/√12): the least
            frame-to-frame scatter the change tests assume for quantised readings.
        window, resolve_every, idle_every, idle_windows, alpha, reach: as the module
            constants (IDLE_WINDOWS).
    """

    def __init__(
        self,
        taxel_xy: NDArray,
        solve: Solve,
        jacobian: Jacobian,
        rounding: float = 0.0,
        screen: Screen | None = None,
        *,
        window: int = WINDOW,
        resolve_every: int = RESOLVE_EVERY,
        idle_every: int = IDLE_EVERY,
        idle_windows: tuple[int, ...] = IDLE_WINDOWS,
        alpha: float = ALPHA,
        reach: float = REACH,
        defer: bool = False,
    ) -> None:
        xy = np.asarray(taxel_xy, dtype=np.float64)
        k = len(xy)
        if window < 2 or resolve_every < 1 or idle_every < 1 or not idle_windows:
            raise ValueError("window must be >= 2, the cadences >= 1 frame, idle windows given")
        if min(idle_windows) < 1:
            raise ValueError(f"idle windows must be >= 1 frame, got {idle_windows}")
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"alpha must be within (0, 1), got {alpha!r}")
        self._solve, self._jacobian, self._screen = solve, jacobian, screen
        self._rounding = float(rounding)
        self._quantised = True
        self._sigma_seen: tuple[object, bool] = (None, False)
        self.window, self.resolve_every = int(window), int(resolve_every)
        self.idle_every, self.alpha = int(idle_every), alpha
        self._idle_windows = np.array(sorted({min(int(w), self.window) for w in idle_windows}))
        self._since_check = 0
        self._holdoff = 0  # frames without a look after the last (IDLE_BACKOFF)
        dist = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
        groups = [np.flatnonzero(row <= reach) for row in dist]
        width = max(len(g) for g in groups)
        self._nbr = np.array([np.pad(g, (0, width - len(g)), constant_values=k) for g in groups])
        # Bonferroni over the K neighbourhoods: the local tests together keep the rate alpha.
        self._local_limit = np.array([chi2.isf(alpha / k, len(g)) for g in groups])
        trigger = IDLE_TRIGGER / (k * len(idle_windows))
        self._trigger_limit = np.array([chi2.isf(trigger, len(g)) for g in groups])
        self._buf = np.zeros((self.window, k))
        self._total = np.zeros(k)
        # The idle windows' sums of their newest frames, kept as frames join (held_step_sums)
        # and made again from the ring whenever the window is rebuilt or a look is taken.
        self._wsum = np.zeros((len(self._idle_windows), k))
        self._spare = np.zeros(k)
        self._state = np.zeros(kern.STATE_SIZE)
        self._state[kern.SCALE2] = 1.0
        self._state[kern.SCALE_MEMORY] = SCALE_MEMORY
        self._ok: NDArray[np.bool_] | None = None
        self._limits = np.zeros(2)
        self._q = np.zeros((k, 0))
        self._since = 0
        self._context: object = None
        self.defer = defer
        # The re-solve step() left to catch_up (defer): ("resolve" or "idle", idle window,
        # its clock flag, σ, want traction, want deflection), or None.
        self._pending: tuple | None = None
        self.result: object = None
        #: Frames averaged into ``result`` (1: solved on its own).
        self.result_frames = 0
        #: What the last frame did: "solved", "fused" or "held".
        self.last = ""
        self.counts = FusionCounts()

    @property
    def frames(self) -> int:
        """Frames in the window now."""
        return int(self._state[kern.N])

    @property
    def scatter(self) -> float:
        """s: the frames' scatter about their mean over the noise passed in (robust estimate;
        < 1 where part of that noise stays from frame to frame)."""
        return math.sqrt(max(self._state[kern.SCALE2], 0.0))

    def effective_frames(self, n: int) -> float:
        """The mean of n frames errs as one frame's noise over √(this) (module docstring).
        Readings of unknown noise (not quantised, none passed): all the noise there is to
        know is the scatter, and it averages out (σ·s/√n)."""
        if n <= 1:
            return 1.0
        s2 = max(self._state[kern.SCALE2], 1e-12)
        if not self._quantised:
            return n / s2
        return 1.0 / (max(1.0 - s2, 0.0) + s2 / n)

    def reset(self) -> None:
        """Forget the window and the result (the next frame is solved on its own)."""
        self._state[kern.N] = 0.0
        self._sums()
        self._ok = None
        self.result = None
        self._pending = None

    def step(
        self,
        delta: NDArray,
        ok: NDArray,
        sigma: NDArray,
        *,
        quantised: bool,
        want_traction: bool = True,
        want_deflection: bool = True,
        context: object = None,
    ) -> object:
        """The result for this frame: readings ``delta`` (K,) [m] (0 where not ``ok``), valid
        taxels ``ok`` (K,), each taxel's noise of one frame ``sigma`` (K,) [m] (the same
        array from frame to frame, unless it changed). ``quantised``: 8-bit readings (the
        change tests assume at least a rounding's scatter). ``context`` goes to the solve
        callback."""
        self._context = context
        sigma = self.see_noise(sigma, quantised)
        if self._ok is None or self.result is None:
            return self._fresh(delta, ok, sigma, want_traction, want_deflection, "start")
        changed = kern.held_step_sums(
            delta,
            ok,
            self._ok,
            sigma,
            self._buf,
            self._total,
            self._state,
            self._nbr,
            self._local_limit,
            self._q,
            self._limits,
            self._wsum,
            self._idle_windows,
            self._spare,
        )
        return self.after_held_step(
            changed, delta, ok, sigma, want_traction, want_deflection, context, -1
        )

    def see_noise(self, sigma: NDArray, quantised: bool) -> NDArray:
        """Take this frame's ``sigma`` (K,) [m] and ``quantised`` (:meth:`step`'s first part):
        the tests' floor follows a new noise array. Returns the sigma to pass on."""
        self._quantised = quantised
        if sigma is not self._sigma_seen[0] or quantised != self._sigma_seen[1]:
            sigma = np.ascontiguousarray(sigma, dtype=np.float64)
            floor = self._rounding / float(np.median(sigma)) if quantised else 1e-6
            self._state[kern.SCALE_FLOOR] = floor * floor
            self._state[kern.SCALE_PRIOR] = SCALE_PRIOR if quantised else 0.0
            self._sigma_seen = (sigma, quantised)
        return sigma

    @property
    def holding(self) -> bool:
        """Whether the next frame is tested against a window (not solved on its own at once)."""
        return self._ok is not None and self.result is not None

    @property
    def scan_due(self) -> bool:
        """Whether the next held frame of an idle result runs the idle scan (the holdoff is
        over): a caller that ran :func:`~tactile_contact.inverse._temporal_kernels.quiet_frame`
        passes its scan's answer to :meth:`after_held_step`."""
        return self._since_check + 1 > self._holdoff

    def after_held_step(
        self,
        changed: int,
        delta: NDArray,
        ok: NDArray,
        sigma: NDArray,
        want_traction: bool,
        want_deflection: bool,
        context: object,
        scanned: int,
    ) -> object:
        """:meth:`step` after its compiled held step returned ``changed`` (for a caller that
        ran that step itself, with the frame's conversion: quiet_frame). ``scanned``: the
        idle scan's window if the caller ran it too (``scan_due``), else -1; ``sigma`` as
        :meth:`see_noise` returned it."""
        self._context = context
        if changed:
            kind = ("frame", "neighbourhood", "parameters", "valid")[changed - 1]
            return self._fresh(delta, ok, sigma, want_traction, want_deflection, kind)
        self._since += 1
        res = self.result
        n = self.frames
        missing = (want_traction and res.traction is None) or (  # type: ignore[attr-defined]
            want_deflection and res.deflection is None  # type: ignore[attr-defined]
        )
        if res.in_contact or missing:  # type: ignore[attr-defined]
            due = n in RESOLVE_AT if n < self.window else self._since >= self.resolve_every
            if missing or (due and (not self.defer or n < DEFER_FROM)):
                return self._resolve(sigma, want_traction, want_deflection)
            if due:
                self._pending = ("resolve", 0, False, sigma, want_traction, want_deflection)
        else:
            pick = self._idle_pick(sigma, scanned)
            if pick is not None and self.defer:
                self._pending = ("idle", *pick, sigma, want_traction, want_deflection)
            elif pick is not None:
                found = self._idle_solve(*pick, sigma)
                if found is not None:
                    self._adopt(found, sigma, pick[0])
                    return self._resolve(sigma, want_traction, want_deflection)
        self.counts.held += 1
        self.last = "held"
        return res

    def step_message(
        self,
        delta_c: NDArray,
        status: NDArray,
        perm: NDArray,
        unusable: int,
        convert: NDArray,
        sigma: NDArray,
        want_traction: bool = False,
        want_deflection: bool = False,
    ) -> tuple[object, Frame, int] | None:
        """:meth:`step` of a message's raw readings, converted and tested in one compiled
        call (:func:`~tactile_contact.inverse._temporal_kernels.quiet_frame`): what an idle
        or held patch-frame costs a node. Only while :attr:`holding`; ``delta_c`` (K,) ΔC [F]
        and ``status`` (K,) in the message's order, ``perm`` its index of each taxel,
        ``unusable`` the status flags left out, ``convert`` the sensor model's constants
        (quiet_frame), ``sigma`` (K,) [m] one frame's noise (quantised readings).

        Returns (result, the frame as Reconstructor.solve makes it (its context), taxels
        the status allows), the same as Reconstructor.solve on the readings mapped and masked
        would give; None for a reading that is not finite (nothing done: the caller's full
        path reports it)."""
        sigma = self.see_noise(sigma, True)
        k = len(self._total)
        delta = np.empty(k)
        ok = np.empty(k, dtype=bool)
        scan = not self.result.in_contact and self.scan_due  # type: ignore[attr-defined]
        code, w, valid = kern.quiet_frame(
            delta_c,
            status,
            perm,
            unusable,
            convert,
            delta,
            ok,
            self._ok,
            sigma,
            self._buf,
            self._total,
            self._state,
            self._nbr,
            self._local_limit,
            self._q,
            self._limits,
            scan,
            self._trigger_limit,
            self._idle_windows,
            self._wsum,
            self._spare,
        )
        if code < 0:
            return None
        frame = Frame(delta, ok, sigma)
        result = self.after_held_step(
            code, delta, ok, sigma, want_traction, want_deflection, frame, w
        )
        return result, frame, valid

    def batch_ready(self, sigma: NDArray) -> int:
        """Whether the next frame may go by a batch's compiled call (kern.quiet_batch) with
        ``sigma`` (as :meth:`step_message` would take it): -1 if not (no window held, a
        re-solve waiting, a new noise array, or this frame's held step would be followed by
        a re-solve or a look on the clock: the caller's own path then), else whether the
        idle scan runs (:attr:`scan_due` of an idle result: 1) or not (0)."""
        res = self.result
        seen = self._sigma_seen
        if (
            res is None
            or self._ok is None
            or self._pending is not None
            or not self._quantised
            or seen[0] is not sigma
            or not seen[1]
        ):
            return -1
        if res.in_contact:  # type: ignore[attr-defined]
            n = min(self.frames + 1, self.window)  # (the window after this frame joins it)
            due = n in RESOLVE_AT if n < self.window else self._since + 1 >= self.resolve_every
            return -1 if due else 0
        if self._since_check + 1 > self._holdoff:
            return -1 if self._since_check + 1 >= self.idle_every else 1
        return 0

    def batch_held(self, idle: bool) -> None:
        """The bookkeeping of :meth:`after_held_step` for a frame kern.quiet_batch found
        unchanged and that nothing follows (no re-solve due, the scan picked nothing):
        the last result republished. (``context`` stays the last frame's that set it: only
        a solve reads it, and every frame that solves or defers one sets it.)"""
        self._since += 1
        if idle:
            self._since_check += 1
        self.counts.held += 1
        self.last = "held"

    def after_batch(
        self, code: int, scanned: int, delta: NDArray, ok: NDArray, sigma: NDArray
    ) -> tuple[object, Frame]:
        """:meth:`step_message`'s rest for a frame kern.quiet_batch tested (``code``,
        ``scanned``: its held step's and idle scan's answers; ``delta``, ``ok``: the frame
        it converted, copied here: the call's scratch arrays are reused)."""
        frame = Frame(delta.copy(), ok.copy(), sigma)
        result = self.after_held_step(
            code, frame.delta, frame.ok, sigma, False, False, frame, scanned
        )
        return result, frame

    def batch_replaced(self) -> tuple[NDArray, NDArray]:
        """(window_ok, q): the two of :meth:`batch_arrays` a change or a re-solve replaces."""
        return self._ok, self._q  # type: ignore[return-value]

    def batch_arrays(self) -> dict[str, NDArray]:
        """The arrays kern.quiet_batch reads and changes in place (its F1_*, I1_*, F2_*, B1_*
        slots; ``window_ok`` and ``q`` are replaced by a change or a re-solve)."""
        return {
            "window_ok": self._ok,  # type: ignore[dict-item]
            "total": self._total,
            "state": self._state,
            "local": self._local_limit,
            "limits": self._limits,
            "trigger": self._trigger_limit,
            "spare": self._spare,
            "windows": self._idle_windows,
            "buf": self._buf,
            "q": self._q,
            "wsum": self._wsum,
            "nbr": self._nbr,
        }

    @property
    def context(self) -> object:
        """What the last :meth:`step` was given as ``context`` (from a Reconstructor: the
        frame's :class:`~tactile_contact.inverse.readings.Frame`, the δ it converted)."""
        return self._context

    @property
    def pending(self) -> bool:
        """Whether a re-solve waits for :meth:`catch_up` (``defer``)."""
        return self._pending is not None

    def catch_up(self) -> bool:
        """Run the re-solve the last :meth:`step` deferred (``defer``), as step would have
        run it; True if there was one. A change since (a frame solved on its own) drops
        it. The result is the next frame's (``self.result``); ``last`` stays the frame's."""
        p, self._pending = self._pending, None
        if p is None or self.result is None:
            return False
        kind, w, clock, sigma, want_t, want_d = p
        last = self.last
        if kind == "idle":
            found = self._idle_solve(w, clock, sigma)
            if found is not None:
                self._adopt(found, sigma, w)
                self._resolve(sigma, want_t, want_d)
        else:
            self._resolve(sigma, want_t, want_d)
        self.counts.deferred += 1
        self.last = last
        return True

    def compile(self) -> None:
        """Build (or load from numba's disk cache) the compiled steps now, on this patch's
        shapes, not in the first frames of a stream (seconds on a cold cache). No state of
        the fusion changes."""
        k = len(self._total)
        d, ok, sigma = np.zeros(k), np.ones(k, dtype=bool), np.ones(k)
        buf, total, state = self._buf.copy(), np.zeros(k), self._state.copy()
        state[kern.N], state[kern.HEAD] = 1.0, 1.0
        q = np.zeros((k, 1))
        q[0, 0] = 1.0
        limits = np.full(2, np.inf)
        kern.held_step(d, ok, ok, sigma, buf, total, state, self._nbr, self._local_limit, q, limits)
        kern.held_step(
            d, ok, ok, sigma, buf, total, state, self._nbr, self._local_limit, q[:, :0], limits
        )
        kern.idle_scan(
            buf, state, ok, sigma, self._nbr, self._trigger_limit, self._idle_windows, True
        )
        wsum, spare = self._wsum.copy(), np.zeros(k)
        kern.window_sums(buf, state, self._idle_windows, wsum)
        for m in (1, 0):
            kern.held_step_sums(
                d,
                ok,
                ok,
                sigma,
                buf,
                total,
                state,
                self._nbr,
                self._local_limit,
                q[:, :m],
                limits,
                wsum,
                self._idle_windows,
                spare,
            )
        kern.idle_scan_sums(
            wsum, state, ok, sigma, self._nbr, self._trigger_limit, self._idle_windows, True
        )
        kern.best_split(buf, state, total, sigma, q)
        # A node's message readings (quiet_frame): read-only float32 ΔC and uint8 status, as
        # np.frombuffer gives them (inverse.readings' constants; any positive values do).
        dc = np.frombuffer(bytes(4 * k), dtype=np.float32)
        status = np.frombuffer(bytes(k), dtype=np.uint8)
        perm, convert = np.arange(k), np.array([1e-3, 1e-15, 1e-12, 1e-12])
        kern.quiet_frame(
            dc,
            status,
            perm,
            0,
            convert,
            d.copy(),
            ok.copy(),
            ok,
            sigma,
            buf,
            total,
            state,
            self._nbr,
            self._local_limit,
            q,
            limits,
            True,
            self._trigger_limit,
            self._idle_windows,
            wsum,
            spare,
        )
        kern.orthonormal(q, ok, sigma, np.zeros((k, 1)))

    def step_frame(self, frame: Frame, want_traction: bool, want_deflection: bool) -> Any:
        """:meth:`step` of a reconstructor's :class:`~tactile_contact.inverse.readings.Frame`
        (the context its solve gets back)."""
        return self.step(
            frame.delta,
            frame.ok,
            frame.sigma,
            quantised=frame.quantised,
            want_traction=want_traction,
            want_deflection=want_deflection,
            context=frame,
        )

    # ------------------------------------------------------------------------------------

    def _idle_check(self, sigma: NDArray) -> object | None:
        """An idle patch's look for a press too light for one frame (IDLE_WINDOWS): the
        contact the detector finds on the mean the scan picks, or None."""
        pick = self._idle_pick(sigma)
        return None if pick is None else self._idle_solve(*pick, sigma)

    def _idle_pick(self, sigma: NDArray, scanned: int = -1) -> tuple[int, bool] | None:
        """The idle look's cheap part: the window whose mean deserves a look (its length,
        and whether the clock picked it rather than the scan), or None. ``scanned``: the
        scan's answer if the caller ran it (``scan_due``), else -1."""
        self._since_check += 1
        if self._since_check <= self._holdoff:
            return None
        w = scanned
        if w < 0:
            w = kern.idle_scan_sums(
                self._wsum,
                self._state,
                self._ok,
                sigma,
                self._nbr,
                self._trigger_limit,
                self._idle_windows,
                self._quantised,
            )
        clock = w == 0
        if clock and self._since_check >= self.idle_every:
            w = min(self.frames, int(self._idle_windows[-1]))
        if w < 2:
            return None
        self._since_check = 0
        # (after a look on the clock none: a press that begins just after must not wait)
        self._holdoff = 0 if clock else int(w) // IDLE_BACKOFF
        self._sums()  # (a look taken: the kept sums made again, no drift from adding)
        return int(w), bool(clock)

    def _idle_solve(self, w: int, clock: bool, sigma: NDArray) -> object | None:
        """The idle look's solve of the mean of the last ``w`` frames: the contact found, or
        None (on the clock, first screened by the bank test alone)."""
        mean = self._mean(int(w))
        if clock and self._screen is not None:
            # On the clock, nothing in the window stood out locally: only a contact the bank
            # itself finds on the mean is worth a solve. (A near miss there, a small contact
            # between the bank's places, reads locally: the scan's to pick. Each such fit
            # cost 1–5 ms on noise alone, a third of the clock's solves on the robot's
            # patches.)
            eff = self.effective_frames(int(w))
            if not self._screen(mean, self._ok, sigma, eff, self._context):
                self.counts.screened += 1
                return None
        found = self._call(mean, sigma, int(w), False, False)
        return found if found.in_contact else None  # type: ignore[attr-defined]

    def _call(self, d: NDArray, sigma: NDArray, n: int, want_t: bool, want_d: bool) -> object:
        eff = self.effective_frames(n)
        return self._solve(d, self._ok, sigma, n, eff, want_t, want_d, self._context)

    def _scaled(self, sigma: NDArray) -> NDArray[np.float64]:
        """The frame-to-frame scatter [m] (at least the tests' floor)."""
        return sigma * math.sqrt(max(self._state[kern.SCALE2], self._state[kern.SCALE_FLOOR]))

    def _sums(self) -> None:
        """The idle windows' kept sums made from the ring (after it was rebuilt)."""
        kern.window_sums(self._buf, self._state, self._idle_windows, self._wsum)

    def _rows(self, n: int) -> NDArray[np.intp]:
        """Ring rows of the newest n frames, oldest first."""
        head = int(self._state[kern.HEAD])
        return (head - n + np.arange(n)) % self.window

    def _mean(self, n: int | None = None) -> NDArray[np.float64]:
        if n is None:
            return self._total / self.frames
        return self._buf[self._rows(n)].mean(axis=0)

    def _fresh(
        self, delta: NDArray, ok: NDArray, sigma: NDArray, want_t: bool, want_d: bool, why: str
    ) -> object:
        """A change: the frame alone, solved as the reconstructor solves it; a new window."""
        self._pending = None  # (a change: the deferred re-solve of the old window is moot)
        self._ok = np.array(ok, dtype=bool)
        k = int(self._ok.sum())
        self._limits[0] = _limit(self.alpha, k)
        x = np.where(self._ok, delta, 0.0)
        self._buf[0] = x
        self._total[:] = x
        self._state[kern.N], self._state[kern.HEAD] = 1.0, 1.0 % self.window
        self._sums()
        self.result = self._call(x, sigma, 1, want_t, want_d)
        self.result_frames = 1
        self._since = 0
        self._directions(sigma)
        self.counts.solved += 1
        self.counts.changes[why] = self.counts.changes.get(why, 0) + 1
        self.last = "solved"
        return self.result

    def _adopt(self, result: object, sigma: NDArray, w: int) -> None:
        """A contact found in the mean of the window's last ``w`` frames: its directions, then
        the frames before its start (a step along them) dropped, or, where the window shows
        no such step, the frames before those ``w``."""
        self.result = result
        self._directions(sigma)
        if not self._trim_before_change(sigma) and self.frames > w:
            # The look found it in those w frames: a mean over more would dilute it with the
            # idle frames before (the step test needs more evidence than the look had; a
            # light press found in the last 10 frames of 25 was solved again over all 25 and
            # lost).
            self._state[kern.N] = float(w)
            self._total[:] = self._buf[self._rows(w)].sum(axis=0)
            self._sums()

    def _resolve(self, sigma: NDArray, want_t: bool, want_d: bool) -> object:
        """The window's mean solved; if the window holds a step along the new result's
        directions, the frames before it are dropped and the rest solved."""
        rows = self._rows(self.frames)
        self._total[:] = self._buf[rows].sum(axis=0)  # (no drift from adding and removing)
        self._sums()
        self.result = self._call(self._mean(), sigma, self.frames, want_t, want_d)
        self._directions(sigma)
        if self._trim_before_change(sigma):
            self.result = self._call(self._mean(), sigma, self.frames, want_t, want_d)
            self._directions(sigma)
        self.result_frames = self.frames
        self._since = 0
        self.counts.fused += 1
        self.last = "fused"
        return self.result

    def _directions(self, sigma: NDArray) -> None:
        """The whitened, orthonormal directions of the result's parameters (self._q)."""
        k = len(self._total)
        jac = self._jacobian(self.result, self._ok)
        if jac is None or jac.shape[1] == 0:
            self._q = np.zeros((k, 0))
            return
        q = np.zeros(jac.shape)
        kept = kern.orthonormal(np.ascontiguousarray(jac), self._ok, self._scaled(sigma), q)
        self._q = np.ascontiguousarray(q[:, :kept])
        self._limits[1] = _limit(self.alpha, kept)

    def _trim_before_change(self, sigma: NDArray) -> bool:
        """Drop the frames before the most likely step of the window along self._q, if the
        step is significant (two-segment χ² over every split, Bonferroni over the splits)."""
        n, m = self.frames, self._q.shape[1]
        if m == 0 or n < 3:
            return False
        old, stat = kern.best_split(
            self._buf, self._state, self._total, self._scaled(sigma), self._q
        )
        if stat <= _limit(self.alpha / (n - 1), m):
            return False
        keep = n - old
        self._state[kern.N] = float(keep)
        self._total[:] = self._buf[self._rows(keep)].sum(axis=0)
        self._sums()
        self.counts.changes["step"] = self.counts.changes.get("step", 0) + 1
        return True


def reconstructor_fusion(recon: Reconstructor) -> FrameFusion:
    """The fusion of a reconstructor's frames (``Reconstructor(fuse=True)``): its solve of
    a mean of n frames is the reconstructor's chain on a frame whose noise is that mean's
    (``Frame.frames``; the result's ``frames`` is n), its directions the round contacts'
    derivatives (none for a grid field)."""

    def solve(delta, ok, sigma, n, eff, want_t, want_d, frame):  # type: ignore[no-untyped-def]
        if n == 1:
            return recon._solve(frame, want_t, want_d)
        mean = dataclasses.replace(frame, delta=delta, ok=ok, sigma=sigma, frames=eff)
        return dataclasses.replace(recon._solve(mean, want_t, want_d), frames=n)

    def directions(result, ok):  # type: ignore[no-untyped-def]
        if recon._round is None or not result.in_contact:
            return None
        return round_jacobian(recon._round, recon.taxel_xy, result.contacts)

    rounding = recon.readings.count_sigma / math.sqrt(2.0)  # one count/√12

    def screen(delta, ok, sigma, eff, frame):  # type: ignore[no-untyped-def]
        det = recon.detector
        if det is None:
            return True
        recon._use_noise(sigma)
        # (as Reconstructor._solve tests a mean of frames: δ·√n with one frame's filters)
        dz = delta * math.sqrt(eff)
        scale_free = getattr(frame, "scale_free", False)
        # An upper bound on the bank's statistics first (one byte an entry): on noise alone
        # it answers no at a third of the exact statistic's cost; the answer is detect's.
        return not det.surely_quiet(dz, scale_free) and det.detect(dz, scale_free)[0]

    fusion = FrameFusion(recon.taxel_xy, solve, directions, rounding, screen)
    fusion.compile()
    if recon.detector is not None:  # (the screen's bound kernel: 0.3 s to compile)
        recon.detector.surely_quiet(np.full(len(recon.taxel_xy), 1e-9), False)
    if recon._round is not None:  # (the Jacobian's kernel, with the bundle's tables)
        from tactile_contact.inverse.summary import Contact

        centre = recon.taxel_xy.mean(axis=0)
        one = Contact(1.0, (float(centre[0]), float(centre[1])), 2e-3, FAMILIES[1])
        round_jacobian(recon._round, recon.taxel_xy, (one,))
    return fusion


def round_jacobian(
    tables: RoundTables, taxel_xy: NDArray, contacts: tuple
) -> NDArray[np.float64] | None:
    """(K, 4·C) derivatives [m per unit] of the readings of round ``contacts``
    (:class:`tactile_contact.inverse.summary.Contact`, profile ``punch`` or ``hertz``) in
    each one's log force, centre x, y [m] and log radius; None if one is not a round contact
    (a grid field) or there are none. (Compiled: it runs with every solve of a held scene.)"""
    if not contacts or any(c.profile not in FAMILIES for c in contacts):
        return None
    params = np.array(
        [
            (c.force, c.center[0], c.center[1], math.log(c.radius), FAMILIES.index(c.profile))
            for c in contacts
        ]
    )
    t0, dt = tables.log_grid
    xy = np.ascontiguousarray(taxel_xy, dtype=np.float64)
    return kern.round_jacobian(
        tables.table, t0, dt, tables.step, xy, params, STEP_XY, math.log1p(STEP_RADIUS)
    )


@functools.lru_cache(maxsize=512)
def _limit(alpha: float, dof: int) -> float:
    """χ² value exceeded with probability ``alpha`` at ``dof`` degrees of freedom (≥ 1)."""
    return float(chi2.isf(alpha, max(int(dof), 1)))
