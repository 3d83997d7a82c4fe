"""Noise-aware contact detection: a bank of matched filters with a stated false-alarm rate.

A contact anywhere on the patch makes the readings δ [m] follow F·r_c, where r_c (K,) is the
response of a contact of some profile at some place c. Against per-taxel Gaussian noise σ_i
the best test for "a contact at c" is the matched filter z_c = Σ r_ci δ_i/σ_i² /
√(Σ r_ci²/σ_i²), which is N(0, 1) on noise alone and grows with the force. The detector takes
the largest z_c over a bank of places and profiles and reports contact above a threshold set
by the Bonferroni bound: P(false contact per frame) ≤ M·Q(threshold) for M filters, so the
stated rate is an upper bound (correlated filters make the true rate lower; the bench measures
it). A light touch between taxels, which reads a few negative µm at three taxels and nothing
above any per-taxel threshold, still sums to a large z.

Readings whose noise is not known (unquantised deflections handed to the library with no
noise level) get a second, scale-free test as well: the share of the frame's energy that the
best filter explains, ρ = z_c²/‖δ/σ‖². On white noise of *any* level each filter's share is
Beta(½, (K−1)/2)-distributed, so the same Bonferroni bound states its false-alarm rate; a
contact read with little noise explains most of the energy whatever its size. Each test gets
half the stated rate.

Readings whose noise the caller did not pass may be noisier than the sensor model says (a skin
with 1 count of converter noise, against the ≈ 0.4 count the model assumes, read as a false
contact in most frames). Their own noise is then estimated from the energy the best filter
leaves (:meth:`ContactDetector.frame_noise`: K − 1 degrees of freedom), and when it exceeds the
assumed level the statistic is divided by it and compared with Student's t quantile of the same
rate instead of the normal one (:class:`FrameNoise`). No ROS import.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtri
from scipy.stats import beta
from scipy.stats import chi2 as chi2_dist
from scipy.stats import t as student_t

from tactile_contact.inverse._temporal_kernels import learn_noise as _learn

#: A bank statistic at these fractions of its thresholds (z, share) or more sends the frame
#: to the refined test (ContactDetector.near_miss): each about 2-5 % of white-noise frames.
NEAR_Z, NEAR_SHARE = 0.6, 0.5

#: A frame's estimated noise (:meth:`ContactDetector.frame_noise`) keeps the normal thresholds
#: only when its upper confidence bound (this tail of its χ²) is at most the assumed level;
#: otherwise the t test runs on the estimate, and at least the assumed level. Why: gated on the
#: estimate itself (above 0.95 of the assumed level), 0.5-count noise (1.4× the assumed) whose
#: far taxels happened to read low took the normal thresholds: 5 false contacts in 6·10⁵
#: frames (1.5 per hour), every one there.
NOISE_CONFIDENCE = 1.0e-3

#: Parameters of a fitted round contact (centre, size, force, and its family chosen).
FITTED_PARAMETERS = 5
#: The frame's noise is measured at the taxels where the best contact's response is at most
#: this share of its largest (beyond its bulge ring: ≈ 55 of the default patch's 72 taxels)...
FAR_RESPONSE = 0.01
#: ... when there are at least this many (else from the energy the best filter leaves).
FAR_TAXELS = 12
#: White-noise frames (seeded) on which the far estimate's selection bias is measured, once
#: per noise level: the best filter wins where the noise reads most like a contact, so the
#: taxels it leaves read less than white noise does (10 % less energy on the default patch).
BIAS_DRAWS = 500
#: The far taxels' noise is also read from how many of them read at least this many assumed σ
#: (half a count where σ is one count/√6, the sensor model's: an 8-bit taxel reads 0 unless its
#: noise reached half a count): a count a second contact among them moves only by its own few
#: taxels, where their mean square grows without bound. The mean-square estimate is used up to
#: ROBUST_CAP times the count's (on white noise it exceeds it in ≈ 1 % of frames).
HALF_COUNT = math.sqrt(6.0) / 2.0
ROBUST_CAP = 1.5
#: A bank of at most this many bytes as a dense float32 matrix is kept so as well (see
#: ContactDetector.set_noise).
DENSE_BANK = 1 << 20
#: The bank's coarse copy (ContactDetector.surely_quiet) holds each weight as a whole multiple
#: of its filter's largest over this (int8).
QUANT_LEVELS = 127
#: A noise whose ratios to the one the filters were built for agree within this (relative)
#: is a uniform multiple of it (ContactDetector.set_noise rescales instead of rebuilding).
UNIFORM = 1e-12


def estimated(scale: float, dof: int) -> FrameNoise:
    """The FrameNoise of an estimate ``scale`` (over the assumed level) on ``dof`` degrees of
    freedom: ASSUMED (the normal thresholds) when even its upper bound at NOISE_CONFIDENCE,
    scale·√(dof/χ²_dof(NOISE_CONFIDENCE)), is at most 1; else max(scale, 1) with ``dof`` (the t
    test, never on less noise than assumed)."""
    if scale * math.sqrt(dof / _chi2_low(dof)) <= 1.0:
        return ASSUMED
    return FrameNoise(max(scale, 1.0), dof)


@functools.lru_cache(maxsize=512)
def _chi2_low(dof: int) -> float:
    """χ²_dof's NOISE_CONFIDENCE quantile."""
    return float(chi2_dist.ppf(NOISE_CONFIDENCE, dof))


def robust_scale(x: NDArray[np.float64], half: float = HALF_COUNT) -> float:
    """The σ of zero-mean Gaussian ``x`` (rounded to whole multiples of 2·``half`` or not) from
    the share p of |x| ≥ ``half``: half / Φ⁻¹(1 − p/2), p kept within half a reading of 0 and
    of 1 (a few readings far off, e.g. a contact's, move it by their share only)."""
    n = len(x)
    if n == 0:
        return 0.0
    p = float(np.count_nonzero(np.abs(x) >= half)) / n
    p = min(max(p, 0.5 / n), 1.0 - 0.5 / n)
    return float(half / ndtri(1.0 - p / 2.0))


#: Default stated false-contact rate [per hour] and the frame rate it is stated at [Hz].
FALSE_ALARMS_PER_HOUR = 0.1
FRAME_RATE = 50.0


def threshold_for(n_filters: int, per_hour: float, frame_rate: float) -> float:
    """Matched-filter threshold [σ] giving at most ``per_hour`` false contacts per hour at
    ``frame_rate`` [Hz] over ``n_filters`` filters (Bonferroni; one-sided: F > 0)."""
    if not (n_filters >= 1 and per_hour > 0 and frame_rate > 0):
        raise ValueError("need n_filters >= 1, per_hour > 0 and frame_rate > 0")
    p_frame = per_hour / (3600.0 * frame_rate)
    return float(-ndtri(p_frame / n_filters))


class FrameNoise(NamedTuple):
    """A frame's own noise level, estimated when the caller passed none.

    Attributes:
        scale: the frame's noise over the level the filters assume (1.0: as assumed, or not
            estimated).
        dof: degrees of freedom of the estimate (0: not estimated; the normal thresholds).
    """

    scale: float = 1.0
    dof: int = 0


#: The frame's noise as assumed (nothing estimated).
ASSUMED = FrameNoise()


class ContactDetector:
    """Largest matched-filter statistic over a bank of contact responses.

    Args:
        responses: (M, K) compression [m] per newton of each bank contact at each taxel.
        centres: (M, 2) where each bank contact presses [m] (the start of the fit).
        sigma: (K,) or scalar noise of each taxel's compression [m].
        per_hour, frame_rate: stated false-contact rate [1/h] at this frame rate [Hz].
    """

    def __init__(
        self,
        responses: ArrayLike,
        centres: ArrayLike,
        sigma: ArrayLike,
        *,
        per_hour: float = FALSE_ALARMS_PER_HOUR,
        frame_rate: float = FRAME_RATE,
        refined_filters: int = 0,
    ) -> None:
        r = np.asarray(responses, dtype=np.float64)
        c = np.asarray(centres, dtype=np.float64)
        if r.ndim != 2 or c.shape != (len(r), 2):
            raise ValueError(
                f"responses (M, K) and centres (M, 2) needed, got {r.shape}, {c.shape}"
            )
        keep = np.any(r != 0, axis=1)
        self._responses = r[keep]
        self.centres = c[keep]
        # The bank is sparse: each filter reads only the taxels within its kernel's reach
        # (≤ 37 of 72 on the hexagon, ≤ 35 of 240 on the iCub forearm; exactly 0 beyond), so
        # it is held by its non-zero entries alone, row by row (CSR: one filter's statistic)
        # and taxel by taxel (CSC: the whole bank's, from the taxels that read anything).
        # Why: the dense forearm bank (12 270 × 240 float32, 11.8 MB) was read from memory
        # every frame, 0.4–1.2 ms; an 8-bit frame reads 0 at most taxels.
        rows, cols = np.nonzero(self._responses)
        n_m, n_k = self._responses.shape
        self._nz_rows, self._nz_cols = rows, cols
        self._nz_response = self._responses[rows, cols]
        self._row_ptr = np.concatenate(([0], np.cumsum(np.bincount(rows, minlength=n_m))))
        self._by_taxel = np.argsort(cols, kind="stable")  # CSR order → CSC order
        self._col_rows = rows[self._by_taxel].astype(np.int32)
        self._col_ptr = np.concatenate(([0], np.cumsum(np.bincount(cols, minlength=n_k))))
        self._row_cols = cols.astype(np.int32)
        self._blocks_of(rows, cols)
        # Per bank contact, the taxels it reads nothing at (frame_noise measures the noise there).
        size = np.abs(self._responses)
        self._far = size <= FAR_RESPONSE * size.max(axis=1, keepdims=True)
        self.per_hour, self.frame_rate = float(per_hour), float(frame_rate)
        self.threshold = threshold_for(len(self._responses), per_hour / 2.0, frame_rate)
        # One-sided (F > 0): half of each filter's two-sided share tail.
        p_frame = per_hour / 2.0 / (3600.0 * frame_rate)
        n_k = r.shape[1]
        self.share_threshold = float(
            beta.isf(2.0 * p_frame / len(self._responses), 0.5, (n_k - 1) / 2.0)
        )
        # The refined test (confirm): a contact fitted where the bank came close, its own
        # matched filter. The fit chooses among far more responses than the bank holds, so
        # the bound counts them all (``refined_filters``) and its thresholds are higher.
        self._refined_filters = int(refined_filters)
        n_ref = max(int(refined_filters), len(self._responses))
        self.refined_threshold = threshold_for(n_ref, per_hour / 2.0, frame_rate)
        self.refined_share_threshold = float(beta.isf(2.0 * p_frame / n_ref, 0.5, (n_k - 1) / 2.0))
        self.sigma = np.zeros(r.shape[1])
        self._built: NDArray[np.float64] | None = None  # the noise the filters are for [m]
        #: (K,) or scalar: a noise whose ratios to the one the filters were built for stay
        #: within this share of their median c keeps the filters (statistics × 1/c; e.g. a
        #: NoiseTracker's ``tolerance``, its own estimates' wander). 0: only an exact uniform
        #: multiple (to UNIFORM).
        self.tolerance: ArrayLike = 0.0
        self._z_scale = 1.0  # the statistics' factor for the noise in use (set_noise)
        #: Times the filters were built (set_noise: not for a uniform multiple of the noise).
        self.rebuilds = 0
        self.set_noise(sigma)

    def _blocks_of(self, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> None:
        """The layout of the bank's coarse copy (:meth:`surely_quiet`; its weights filled by
        set_noise): the filters grouped by the taxel each reads most, a group's block its
        (taxels any of them reads × its filters) weights, taxel-major (1.3–1.5× the non-zero
        entries, one byte each): each taxel's reading is added to all its group's filters in
        one contiguous run."""
        n_m, n_k = self._responses.shape
        group = np.argmax(np.abs(self._responses), axis=1)
        order = np.argsort(group, kind="stable")  # block row → bank row
        rank = np.empty(n_m, dtype=np.int64)
        rank[order] = np.arange(n_m)
        kept = np.flatnonzero(np.bincount(group, minlength=n_k))  # groups with filters
        size = np.bincount(group, minlength=n_k)[kept]
        row_ptr = np.concatenate(([0], np.cumsum(size)))
        # The taxels each group reads: its distinct (group, taxel) pairs, in order.
        pairs = group[rows] * n_k + cols
        used = np.unique(pairs)
        taxel_ptr = np.concatenate((np.searchsorted(used, kept * n_k), [len(used)]))
        offsets = np.concatenate(([0], np.cumsum(np.diff(taxel_ptr) * size)))
        # Entry (row, taxel) → its group's offset + the taxel's place in the group's × the
        # group's size + the row's place in the group.
        g = np.searchsorted(kept, group[rows])
        place = np.searchsorted(used, pairs) - taxel_ptr[g]
        self._blk_at = (offsets[g] + place * size[g] + (rank[rows] - row_ptr[g])).astype(np.int32)
        self._blk_order = order.astype(np.int64)  # block row → bank row
        self._upper = np.empty(n_m)  # (scratch: each block row's upper bound)
        self._blk_rows = row_ptr.astype(np.int64)
        self._blk_taxels = (used % n_k).astype(np.int32)
        self._blk_tptr = taxel_ptr.astype(np.int64)
        self._blk_offsets = offsets.astype(np.int64)

    def set_noise(self, sigma: ArrayLike) -> None:
        """Use the per-taxel noise ``sigma`` [m] (scalar or (K,), finite, > 0).

        A ``sigma`` that is a uniform multiple c of the noise σ_b the filters were built for,
        each taxel within ``tolerance`` of it, keeps the filters: the bank's statistics z are
        those of noise c·σ_b, the built filters' times 1/c (the matched filter of c·σ_b is
        σ_b's over c); the energy (share test) and the refined test use ``sigma`` itself. Why:
        the build costs 0.5–28 ms on the robot's banks (1 655–12 270 filters), and the node's
        noise tracker hands a new level every 50 frames, which moves as a whole while each
        taxel's estimate wanders within its spread (:class:`NoiseTracker`). The same ``sigma``
        as built gives the built filters' statistics bit for bit."""
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), self.sigma.shape).copy()
        if not np.all(np.isfinite(s) & (s > 0)):
            raise ValueError("noise sigma must be finite and > 0 m for every taxel")
        self._inv_var = 1.0 / s**2
        self.sigma = s
        built = self._built
        if built is not None:
            ratio = s / built
            c = float(np.median(ratio))
            if np.all(np.abs(ratio - c) <= np.maximum(self.tolerance, UNIFORM) * c):
                # (argmax over the bank, hence far_bias's selection, is the same at any scale)
                self._z_scale = 1.0 if c == 1.0 else 1.0 / c
                return
        # Each filter's non-zero entries r_ck/σ_k² / ‖r_c/σ‖ (the dense bank's, entry by entry).
        w = self._nz_response / (s**2)[self._nz_cols]
        norm = np.sqrt(np.bincount(self._nz_rows, w * self._nz_response, len(self._responses)))
        # float32: the statistic only has to clear a threshold of a few σ.
        self._row_vals = (w / norm[self._nz_rows]).astype(np.float32)
        self._col_vals = self._row_vals[self._by_taxel]
        self._bank = (self._col_ptr, self._col_rows, self._col_vals)
        # The coarse copy (surely_quiet): each filter's weights as whole multiples of its
        # largest/127 (one byte each), in the blocks of _blocks_of.
        coarse = np.zeros(int(self._blk_offsets[-1]), dtype=np.int8)
        step = _quantise(self._row_ptr, self._row_vals, self._blk_at, coarse)
        self._coarse = (
            self._blk_rows,
            self._blk_tptr,
            self._blk_taxels,
            self._blk_offsets,
            coarse,
            step[self._blk_order],
        )
        # A bank small enough to stay in the cache (the hexagon's, 0.9 MB) is also kept dense,
        # for frames most taxels of which read something (float readings): BLAS's dense product
        # then beats the sparse sums (25 against 140 µs on the hexagon; on the forearm's, out
        # of the cache, both ≈ 0.5 ms).
        self._dense: NDArray[np.float32] | None = None
        self._small = self._filters if self._responses.size * 4 <= DENSE_BANK else None
        self._built = s
        self._z_scale = 1.0
        self.rebuilds += 1
        self._far_bias: float | None = None

    def statistic(self, delta: NDArray[np.float64]) -> tuple[float, float, int]:
        """(largest z [σ], its share ρ of the frame's energy, index of its bank contact) for
        readings ``delta`` (K,) [m], with invalid taxels set to 0 (they then count as reading
        nothing, which only lowers z)."""
        best, i = self._best(delta)
        return best, self._share(delta, best), i

    def _best(self, delta: NDArray[np.float64]) -> tuple[float, int]:
        """(largest z [σ] over the bank, its index) for readings ``delta`` (K,) [m]: the first
        largest, as numpy's argmax (all 0 for a frame that reads nothing: index 0)."""
        x = np.asarray(delta, np.float64)
        if 2 * np.count_nonzero(x) > len(x):
            if self._small is not None:
                z = self._small @ x.astype(np.float32)
                i = int(np.argmax(z))
                return float(z[i]) * self._z_scale, i
            # A frame that reads something at most taxels (a mean of frames): the coarse
            # copy's bounds first; only the filters whose upper bound reaches the largest
            # lower bound (the best is among them: a few dozen) summed exactly, as the sparse
            # sums would (the same numbers bit for bit). 2-4× faster on the robot's banks.
            low = _coarse_sums(*self._coarse, x, self._upper)
            best, i = _pruned_best(
                self._upper, low, self._blk_order, self._row_ptr, self._row_cols, self._row_vals, x
            )
            return best * self._z_scale, int(i)
        best, i = _bank_best(*self._bank, x, len(self._responses))
        return best * self._z_scale, int(i)

    def statistics(self, delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """(M,) z [σ] of every bank contact on readings ``delta`` (K,) [m] (the sparse sums)."""
        x = np.asarray(delta, np.float64)
        return _bank_statistics(*self._bank, x, len(self._responses)) * self._z_scale

    def filter_statistic(self, k: int, delta: NDArray[np.float64]) -> float:
        """z [σ] of bank contact ``k`` alone on readings ``delta`` (K,) [m]."""
        a, b = self._row_ptr[k], self._row_ptr[k + 1]
        z = _row_statistic(self._row_cols[a:b], self._row_vals[a:b], np.asarray(delta, np.float64))
        return z * self._z_scale

    @property
    def _filters(self) -> NDArray[np.float32]:
        """(M, K) the bank as a dense float32 matrix (built on demand, for inspection: the
        frames use the sparse one)."""
        if self._dense is None:
            dense = np.zeros(self._responses.shape, dtype=np.float32)
            dense[self._nz_rows, self._nz_cols] = self._row_vals
            self._dense = dense
        return self._dense

    def _share(self, delta: NDArray[np.float64], z: float) -> float:
        """ρ = z²/‖δ/σ‖², the share of the frame's energy a filter reading ``z`` explains (0
        for z ≤ 0 or a frame without energy)."""
        if z <= 0:
            return 0.0
        energy = float(np.dot(delta * delta, self._inv_var))
        return z * z / energy if energy > 0 else 0.0

    def _passes(
        self, delta: NDArray[np.float64], z: float, z_min: float, share_min: float, scale_free: bool
    ) -> bool:
        """z ≥ ``z_min``, or with ``scale_free`` its share ρ ≥ ``share_min`` (the energy sum
        only when the z test fails: a frame without contact pays for little else)."""
        return z >= z_min or (scale_free and self._share(delta, z) >= share_min)

    def frame_noise(self, delta: NDArray[np.float64], k: int, ok: NDArray[np.bool_]) -> FrameNoise:
        """The noise of readings ``delta`` (K,) [m] over the assumed level, measured where the
        best bank contact ``k`` reads nothing: √(mean (δ/σ)²) over the taxels ``ok`` (used)
        whose response to it is at most FAR_RESPONSE of its largest, with as many degrees of
        freedom (χ² on white noise of any level, and independent of the statistic, which
        reads the other taxels: the t test's premise). Fewer than FAR_TAXELS such taxels: the
        energy the best filter leaves, √((‖δ/σ‖² − z²)/(used − 1)). Estimated (dof > 0) only
        when the noise may exceed the assumed level (:func:`estimated`).

        Why not the energy the best filter leaves everywhere: the largest of the bank's
        statistics takes the most noise energy with it (the estimate's variance came out
        12.6 % low on white noise, 2000 frames of the default patch), and a contact the
        bank's few profiles fit poorly leaves energy beside it that reads as noise. A second
        contact far from the first still does (the estimate then errs high: fewer
        detections, not more false ones).
        """
        far = ok & self._far[k]
        n = int(far.sum())
        if n >= FAR_TAXELS:
            x = delta[far] * np.sqrt(self._inv_var[far])
            scale = math.sqrt(float(np.dot(x, x)) / n / self.far_bias())
            scale = min(scale, ROBUST_CAP * robust_scale(x))
            dof = n
        else:
            dof = int(ok.sum()) - 1
            if dof < 2:
                return ASSUMED
            z = self.filter_statistic(k, delta)
            energy = float(np.dot(delta * delta, self._inv_var))
            scale = math.sqrt(max(energy - max(z, 0.0) ** 2, 0.0) / dof)
        return estimated(scale, dof)

    def far_bias(self) -> float:
        """E[Σ_far (δ/σ)²] / E[n_far] of :meth:`frame_noise`'s far taxels on white noise at the
        assumed level (1 without the selection): measured on BIAS_DRAWS seeded frames, once
        per noise level (≈ 0.1 s on the default patch's bank)."""
        if self._far_bias is None:
            noise = np.random.default_rng(0).standard_normal((BIAS_DRAWS, len(self.sigma)))
            delta = noise * self.sigma
            if self._small is not None:
                best = np.argmax(delta.astype(np.float32) @ self._small.T, axis=1)
            else:
                best = _bank_argmax_each(*self._bank, delta, len(self._responses))
            far = self._far[best]
            self._far_bias = float(np.sum(far * noise**2) / max(int(far.sum()), 1))
        return self._far_bias

    def residual_noise(
        self, delta: NDArray[np.float64], predicted: NDArray[np.float64], ok: NDArray[np.bool_]
    ) -> FrameNoise:
        """As :meth:`frame_noise`, for a fitted contact of response ``predicted`` (K,) [m]:
        measured at the taxels ``ok`` where it predicts at most FAR_RESPONSE of its largest
        |prediction|; fewer than FAR_TAXELS of them, from what it leaves everywhere, over
        used − FITTED_PARAMETERS degrees of freedom. Why: the bank's few profiles leave much
        of a strong press's energy, which then reads as noise (with 1 count of noise, a 2 N
        press read by point taxels was taken for noise by the bank alone)."""
        size = np.abs(predicted)
        far = ok & (size <= FAR_RESPONSE * float(size.max()))
        n = int(far.sum())
        if n >= FAR_TAXELS:
            # The fit, started from the bank's best, is placed where the noise reads most like
            # a contact too: the same selection (far_bias).
            x, dof = delta[far] * np.sqrt(self._inv_var[far]), n
            scale = math.sqrt(float(np.dot(x, x)) / dof / self.far_bias())
            scale = min(scale, ROBUST_CAP * robust_scale(x))
        else:
            dof = int(ok.sum()) - FITTED_PARAMETERS
            if dof < 2:
                return ASSUMED
            res = np.where(ok, delta - predicted, 0.0)
            scale = math.sqrt(float(np.dot(res * res, self._inv_var)) / dof)
        return estimated(scale, dof)

    def thresholds(self, noise: FrameNoise) -> tuple[float, float]:
        """(bank threshold, refined threshold) on the statistic divided by ``noise.scale``:
        the normal ones, or Student's t quantiles of the same rate for an estimated level."""
        if noise.dof == 0:
            return self.threshold, self.refined_threshold
        cache = self.__dict__.setdefault("_t_thresholds", {})
        if noise.dof not in cache:
            p_frame = self.per_hour / 2.0 / (3600.0 * self.frame_rate)
            n_ref = max(self._refined_filters, len(self._responses))
            cache[noise.dof] = (
                float(student_t.isf(p_frame / len(self._responses), noise.dof)),
                float(student_t.isf(p_frame / n_ref, noise.dof)),
            )
        return cache[noise.dof]

    def surely_quiet(self, delta: NDArray[np.float64], scale_free: bool) -> bool:
        """True only if :meth:`detect` finds no contact on ``delta`` (K,) [m], known from an
        upper bound on every bank statistic (the coarse copy's sums plus their rounding,
        half a step of each weight times the group's Σ|δ|); False: ask detect. Why: for a
        mean of frames (most taxels read something) the bank's exact statistic visits every
        non-zero entry (0.15–0.6 ms on the robot's banks of 4 000–12 270 filters), and an idle
        patch's look on the clock wants only its answer, which on noise alone is no by a
        margin (the best statistic at 0.43 of the threshold, median; 0.74 at most in 767
        looks of scene (b)): the bound reads one byte an entry, in order."""
        bound = _coarse_bound(*self._coarse, np.asarray(delta, np.float64)) * self._z_scale
        if bound >= self.threshold:
            return False
        if scale_free and bound > 0:
            energy = float(np.dot(delta * delta, self._inv_var))
            return energy > 0 and bound * bound < self.share_threshold * energy
        return True

    def detect(self, delta: NDArray[np.float64], scale_free: bool) -> tuple[bool, int]:
        """(contact?, index of the best bank contact); ``scale_free`` adds the ρ test."""
        best, i = self._best(delta)
        hit = self._passes(delta, best, self.threshold, self.share_threshold, scale_free)
        return hit, i

    def detect_estimated(
        self, delta: NDArray[np.float64], scale_free: bool, ok: NDArray[np.bool_]
    ) -> tuple[bool, int, FrameNoise]:
        """:meth:`detect` for readings whose noise the caller did not pass: (contact?, index of
        the best bank contact, the frame's noise (:meth:`frame_noise`) over the taxels ``ok``
        used), the statistic scaled by that noise against its thresholds (:meth:`thresholds`).
        """
        best, i = self._best(delta)
        noise = self.frame_noise(delta, i, ok)
        limit = self.thresholds(noise)[0]
        hit = self._passes(delta, best / noise.scale, limit, self.share_threshold, scale_free)
        return hit, i, noise

    def near_miss(
        self, delta: NDArray[np.float64], k: int, scale_free: bool, noise: FrameNoise = ASSUMED
    ) -> bool:
        """Whether bank contact ``k`` (the best) came within NEAR_Z or NEAR_SHARE of a
        threshold on readings ``delta`` [m] (of noise ``noise``): a contact between the bank's
        places or sizes (a small one between two taxels reads mostly on the bulge around it)
        then deserves a fit (:meth:`confirms`). On noise alone this is a few % of frames."""
        z = self.filter_statistic(k, delta) / noise.scale
        limit = self.thresholds(noise)[0]
        return self._passes(delta, z, NEAR_Z * limit, NEAR_SHARE * self.share_threshold, scale_free)

    def confirms(
        self,
        delta: NDArray[np.float64],
        predicted: NDArray[np.float64],
        scale_free: bool,
        noise: FrameNoise = ASSUMED,
    ) -> bool:
        """The refined test: the matched filter of a fitted contact's response ``predicted``
        (K,) [m] (0 at invalid taxels) on ``delta`` (K,) [m] (of noise ``noise``) against the
        refined thresholds."""
        w = predicted * self._inv_var
        norm = float(np.dot(w, predicted))
        if norm <= 0:
            return False
        z = float(np.dot(w, delta)) / math.sqrt(norm) / noise.scale
        limit = self.thresholds(noise)[1]
        return self._passes(delta, z, limit, self.refined_share_threshold, scale_free)

    def rate_per_hour(self) -> float:
        """The stated bound on false contacts per hour at ``frame_rate`` (= ``per_hour``)."""
        return (
            len(self._responses)
            * 0.5
            * math.erfc(self.threshold / math.sqrt(2.0))
            * (3600.0 * self.frame_rate)
        )


class NoiseTracker:
    """Each taxel's compression noise [m], tracked online from frames without contact.

    An exponentially weighted mean of δ² over frames the reconstruction found no contact in
    (the same frames the driver's baseline tracker follows), per taxel, never below ``floor``
    (the reading's own rounding). Frames with any reading above SPIKE_SIGMA of the current
    level are skipped as well: a touch too light to be detected must not teach the tracker
    that the skin is noisy. ``sigma`` changes only every ``every`` frames, as one new array, so
    a detector can tell by identity that nothing changed.

    With it, ``tolerance``: how far each taxel's estimate wanders on its own, as a share of
    it: SHAPE_SPREAD standard errors of the difference of two estimates (√2 of one's). One
    estimate's error, of an exponential mean over ``frames`` (α = 1/frames), is
    √(α/(2−α)·Var δ²)/(2σ²) of σ, Var δ² from a mean of δ⁴ tracked alike: 2.2 % at 500
    frames for Gaussian noise, about twice that for 8-bit readings that mostly read 0. A
    detector given it (``ContactDetector.tolerance``) keeps its filters while the noise
    handed out stays within it of a uniform multiple of the noise they were built for
    (measured on 30 000 frames of a 240-taxel patch, 0.6-count noise: at 4 Gaussian errors of
    one estimate a rebuild every ≈ 700 frames, at 5 of its own one every ≈ 2 000, at 5 of
    the difference's none, the settling from the sensor model's level included).

    Args:
        floor: (K,) or scalar lowest noise [m].
        start: (K,) or scalar noise [m] before any frame is seen (default: ``floor``).
        frames: time constant of the mean [frames] (500 = 10 s at 50 Hz).
        every: frames between updates of ``sigma``.
    """

    SPIKE_SIGMA = 6.0
    SHAPE_SPREAD = 5.0

    def __init__(
        self,
        floor: ArrayLike,
        *,
        start: ArrayLike | None = None,
        frames: int = 500,
        every: int = 50,
    ) -> None:
        f = np.asarray(floor, dtype=np.float64)
        s0 = f if start is None else np.broadcast_to(np.asarray(start, np.float64), f.shape)
        if not np.all(np.isfinite(f) & (f > 0) & np.isfinite(s0) & (s0 >= f)):
            raise ValueError("noise floor must be finite and > 0 m, and start >= floor")
        self.floor = f
        self._var = np.square(s0).astype(np.float64)
        self._m4 = 3.0 * np.square(self._var)  # mean of δ⁴ (a Gaussian's to start)
        self._alpha = 1.0 / max(int(frames), 1)
        self._every = max(int(every), 1)
        self._count = 0
        self.frames_used = 0
        self.sigma = np.sqrt(self._var)
        self.tolerance = self._tolerance()
        # The compiled step built (or loaded from numba's cache) now, not in a first frame.
        _learn(
            np.zeros(f.shape),
            np.zeros(f.shape, dtype=bool),
            self.sigma,
            self._var,
            self._m4,
            0.0,
            1.0,
        )

    def _tolerance(self) -> NDArray[np.float64]:
        """(K,) the relative wander of each taxel's σ (class docstring), at least a Gaussian's."""
        a = self._alpha / (2.0 - self._alpha)
        var = np.maximum(self._var, np.square(self.floor))
        spread = np.sqrt(a * np.maximum(self._m4 - np.square(self._var), 2.0 * np.square(var)))
        return self.SHAPE_SPREAD * math.sqrt(2.0) * spread / (2.0 * var)

    def update(self, delta: ArrayLike, valid: ArrayLike, in_contact: bool) -> None:
        """Learn from one frame's compressions ``delta`` [m] (invalid taxels ignored)."""
        if in_contact:
            return
        d = np.asarray(delta, dtype=np.float64)
        ok = np.asarray(valid, dtype=bool)
        if d.shape != self._var.shape or ok.shape != d.shape:
            raise ValueError(
                f"delta and valid must have shape {self._var.shape}, got {d.shape}, {ok.shape}"
            )
        # (one compiled pass: numpy's dozen calls cost ≈ 15–35 µs an idle patch-frame)
        if _learn(d, ok, self.sigma, self._var, self._m4, self._alpha, self.SPIKE_SIGMA):
            self.learnt()

    def step_arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
        """(var, m4, α, spike): what :meth:`update`'s compiled step takes besides the frame and
        ``sigma`` (var and m4 changed in place), for a caller that runs that step itself."""
        return self._var, self._m4, self._alpha, self.SPIKE_SIGMA

    def learnt(self) -> None:
        """Count a frame the compiled step learnt from (:meth:`update`, or a caller that ran
        that step itself: contact_reconstruction's batches); every ``every`` such frames a
        new ``sigma``."""
        self.frames_used += 1
        self._count += 1
        if self._count >= self._every:
            self._count = 0
            self.sigma = np.maximum(np.sqrt(self._var), self.floor)
            self.tolerance = self._tolerance()


@numba.njit(cache=True, nogil=True)
def _bank_statistics(col_ptr, col_rows, col_vals, delta, n_filters):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(n_filters,) statistics of a bank held taxel by taxel (CSC: filter indices ``col_rows``
    and float32 weights ``col_vals`` of taxel k at col_ptr[k]:col_ptr[k+1]) on readings
    ``delta`` (K,) [m]: only the taxels that read something are visited (an 8-bit frame: a
    few), each filter's sum in float64."""
    z = np.zeros(n_filters)
    for k in range(delta.shape[0]):
        x = delta[k]
        if x != 0.0:
            for p in range(col_ptr[k], col_ptr[k + 1]):
                z[col_rows[p]] += col_vals[p] * x
    return z


@numba.njit(cache=True, nogil=True)
def _bank_best(col_ptr, col_rows, col_vals, delta, n_filters):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(largest statistic, its first index) of :func:`_bank_statistics` (numpy's argmax)."""
    z = _bank_statistics(col_ptr, col_rows, col_vals, delta, n_filters)
    best, at = z[0], 0
    for m in range(1, n_filters):
        if z[m] > best:
            best, at = z[m], m
    return best, at


@numba.njit(cache=True, nogil=True)
def _quantise(row_ptr, row_vals, at, coarse):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Each filter's weights (CSR ``row_vals``) as whole multiples of its largest/QUANT_LEVELS,
    into ``coarse`` at the slots ``at``; returns each filter's step. (One pass: numpy's
    reduceat, division, rounding and scatter took 4 ms on a forearm's bank, as long again as
    the rest of a rebuild.)"""
    step = np.empty(row_ptr.shape[0] - 1)
    for m in range(step.shape[0]):
        top = 0.0
        for p in range(row_ptr[m], row_ptr[m + 1]):
            top = max(top, abs(np.float64(row_vals[p])))
        s = (top if top > 0.0 else 1.0) / QUANT_LEVELS
        step[m] = s
        for p in range(row_ptr[m], row_ptr[m + 1]):
            coarse[at[p]] = np.int8(np.rint(np.float64(row_vals[p]) / s))
    return step


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"}, inline="always")
def _group_sums(g, row_ptr, taxel_ptr, taxels, offsets, coarse, delta, z):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Group g's coarse sums Σ q·δ into ``z[:m]`` (m its filters); returns (m, the rounding
    slack (½ + 0.02)·Σ|δ| over the group's taxels): see :func:`_coarse_bound`."""
    m = row_ptr[g + 1] - row_ptr[g]
    z[:m] = 0.0
    a1 = 0.0
    p = offsets[g]
    for t in range(taxel_ptr[g], taxel_ptr[g + 1]):
        x = delta[taxels[t]]
        a1 += abs(x)
        run = coarse[p : p + m]  # (a slice: no index wrap-around checks, so SIMD)
        for r in range(m):
            z[r] += run[r] * x
        p += m
    return m, 0.52 * a1


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _coarse_bound(row_ptr, taxel_ptr, taxels, offsets, coarse, step, delta):  # type: ignore[no-untyped-def]  # pragma: no cover
    """An upper bound on the largest bank statistic on readings ``delta`` (K,) [m], from
    the coarse copy (ContactDetector._blocks_of: group g's filters are block rows
    row_ptr[g]:row_ptr[g+1], the taxels they read taxels[taxel_ptr[g]:taxel_ptr[g+1]], their
    weights w ≈ step·q, q int8 taxel-major at offsets[g]): per filter step·(Σ q·δ + (½ +
    0.02)·Σ|δ| over the group's taxels) ≥ Σ w·δ, as |w − step·q| ≤ step/2 (the 0.02·127
    steps ≥ 2.5 |w|max: float32 rounding of the exact sums, (K + 2)·2⁻²³ Σ|w δ|, with room)."""
    z = np.empty(np.max(np.diff(row_ptr)))
    best = -1e300
    for g in range(row_ptr.shape[0] - 1):
        m, slack = _group_sums(g, row_ptr, taxel_ptr, taxels, offsets, coarse, delta, z)
        for r in range(m):
            b = step[row_ptr[g] + r] * (z[r] + slack)
            if b > best:
                best = b
    return best


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _coarse_sums(row_ptr, taxel_ptr, taxels, offsets, coarse, step, delta, upper):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`_coarse_bound` filter by filter: each block row's upper bound into ``upper``;
    returns the largest lower bound, step·(Σ q·δ − (½ + 0.02)·Σ|δ|) (≤ its statistic)."""
    z = np.empty(np.max(np.diff(row_ptr)))
    low = -1e300
    for g in range(row_ptr.shape[0] - 1):
        m, slack = _group_sums(g, row_ptr, taxel_ptr, taxels, offsets, coarse, delta, z)
        for r in range(m):
            s = step[row_ptr[g] + r]
            upper[row_ptr[g] + r] = s * (z[r] + slack)
            b = s * (z[r] - slack)
            if b > low:
                low = b
    return low


@numba.njit(cache=True, nogil=True)
def _pruned_best(upper, low, order, row_ptr, row_cols, row_vals, delta):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(largest statistic, its first index) of the filters whose upper bound reaches ``low``
    (the largest lower bound: the best is among them), each summed as _bank_statistics does
    (float64, taxels ascending, zero readings skipped): the same numbers bit for bit."""
    best, at = -np.inf, -1
    for j in range(upper.shape[0]):
        if upper[j] >= low:
            i = order[j]
            z = 0.0
            for p in range(row_ptr[i], row_ptr[i + 1]):
                x = delta[row_cols[p]]
                if x != 0.0:
                    z += row_vals[p] * x
            if z > best or (z == best and i < at):
                best, at = z, i
    return best, at


@numba.njit(cache=True, nogil=True)
def _bank_argmax_each(col_ptr, col_rows, col_vals, deltas, n_filters):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`_bank_best`'s index for each row of ``deltas`` (N, K)."""
    out = np.empty(deltas.shape[0], dtype=np.int64)
    for n in range(deltas.shape[0]):
        out[n] = _bank_best(col_ptr, col_rows, col_vals, deltas[n], n_filters)[1]
    return out


@numba.njit(cache=True, nogil=True)
def _row_statistic(cols, vals, delta):  # type: ignore[no-untyped-def]  # pragma: no cover
    """One filter's z: Σ vals·delta[cols] (float64 sum of its float32 weights)."""
    z = 0.0
    for p in range(cols.shape[0]):
        z += vals[p] * delta[cols[p]]
    return z
