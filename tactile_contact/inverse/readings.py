"""Stage 1 of a frame: the taxels' readings → compressions δ [m], the taxels to use, the noise.

A frame arrives as capacitance changes ΔC [F] (the driver's output) or as compressions δ [m]
(a caller with its own conversion). :class:`ReadingModel` holds the bundle's sensor constants
and turns either into a :class:`Frame`: δ per taxel, which taxels the later stages use, each
taxel's noise, and how the readings are to be read (whole 8-bit counts, or precise values of
unknown noise). No ROS import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.model.sensor import EPSILON_0, delta_c_to_compression, value_count_farad

#: Noise levels [m] ``noise=`` may give: a compression noise outside is a unit mistake (a
#: level in counts reads as metres of noise, one in farads as femtometres), not a sensor.
NOISE_RANGE_M = (1e-13, 1e-3)


@dataclass(frozen=True)
class Frame:
    """One frame's readings, as every stage after this one sees them.

    Attributes:
        delta: (K,) compressions [m], bundle taxel order; 0 at the taxels not used.
        ok: (K,) bool, the taxels used (valid, finite, in range).
        sigma: (K,) each taxel's compression noise [m] (detection's and the fit's weights).
        quantised: the readings are whole 8-bit counts: report the posterior over the
            quantisation valley, not the least-squares point.
        scale_free: precise readings of unknown noise: detection adds the scale-free test.
        frames: the readings' noise is sigma/√frames: the mean of that many frames of a held
            scene (:mod:`tactile_contact.inverse.temporal`; fewer, not a whole number, where
            the frames scatter more than sigma says). Detection's statistics and the fit's
            weights are those of the mean; ``sigma`` stays one frame's (the detector's filters
            are built for it).
        estimate: the caller passed no noise level: ``sigma`` is the sensor model's, the least
            noise assumed; detection and the fit estimate the frame's own when it is larger
            (:meth:`tactile_contact.inverse.detection.ContactDetector.detect_estimated`,
            :meth:`tactile_contact.inverse.contacts.ContactFitter.far_noise`).
    """

    delta: NDArray[np.float64]
    ok: NDArray[np.bool_]
    sigma: NDArray[np.float64]
    quantised: bool = True
    scale_free: bool = False
    frames: float = 1.0
    estimate: bool = False

    @property
    def used(self) -> int:
        """Taxels used."""
        return int(np.count_nonzero(self.ok))


class ReadingModel:
    """The bundle's sensor model, applied per frame (see module docstring).

    Attributes:
        n_taxels: K.
        thickness: h [m], the dielectric's nominal thickness.
        lsb: ΔC [F] of one 8-bit count at the layout's shift.
        full_scale: largest |ΔC| [F] an 8-bit reading gives (256 counts); beyond it a taxel
            is excluded.
        count_sigma: one count's compression [m] over √6: the error of a reading minus a
            baseline, each rounded to a count.
        default_noise: (K,) noise [m] used unless a frame passes its own (count_sigma).
    """

    def __init__(self, params: Mapping[str, Any], n_taxels: int) -> None:
        self.n_taxels = n_taxels
        self._params = params
        self.thickness = float(params["thickness"])
        lsb = value_count_farad(float(params["farad_per_count"]), int(params["shift"]))
        self.lsb = float(lsb)
        # ΔC in counts per metre of compression, over h (see on_count_lattice).
        self._counts_per_metre_h = (
            EPSILON_0
            * float(params["epsilon_r"])
            * float(params["area"])
            / (self.thickness * self.lsb)
        )
        # δ = ΔC·h²/(ε0·εr·A + ΔC·h) (sensor.delta_c_to_compression) per frame without its
        # argument checks: the frame's own range mask keeps the denominator positive.
        self._eps_area = EPSILON_0 * float(params["epsilon_r"]) * float(params["area"])
        self._rest_c = self._eps_area / self.thickness
        self.full_scale = 256.0 * self.lsb
        self.count_sigma = float(self.compression(np.array([lsb]))[0]) / math.sqrt(6.0)
        self.default_noise = np.full(n_taxels, self.count_sigma)
        self._noise_cache: tuple[Any, NDArray[np.float64]] | None = None
        # The compiled conversion built (or loaded from numba's cache) now, with the bundle,
        # not in a node's first frame.
        self.from_delta_c(np.zeros(n_taxels), None)

    def compression(self, delta_c: ArrayLike) -> NDArray[np.float64]:
        """ΔC [F] → δ [m] (ValueError, naming it, for a ΔC at or below −C0 or not finite)."""
        dc = np.asarray(delta_c, dtype=np.float64)
        h = self.thickness
        den = self._eps_area + dc * h
        if not np.all(den > 0.0):  # (NaN fails too) the checked conversion says what is wrong
            p = self._params
            return delta_c_to_compression(dc, p["thickness"], p["epsilon_r"], p["area"])
        return dc * (h * h) / den

    def counts(self, delta: NDArray) -> NDArray[np.float64]:
        """The 8-bit counts [-] (not rounded) that compressions ``delta`` [m] read."""
        c, h = self._counts_per_metre_h, self.thickness
        return c * delta / (h - delta)

    def from_counts(self, counts: NDArray) -> NDArray[np.float64]:
        """Compressions [m] that read ``counts`` (the inverse of :meth:`counts`)."""
        c, h = self._counts_per_metre_h, self.thickness
        return counts * h / (c + counts)

    def from_delta_c(
        self, delta_c: ArrayLike, valid: ArrayLike | None
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """(δ [m], taxels used) of capacitance changes ΔC [F] (K,). Excluded: ``valid``
        False, NaN, ΔC at or below −C0 (no compression explains it) and beyond full_scale (no
        8-bit reading gives it: a gain or shift that differs between driver and bundle, or a
        unit mistake). One compiled pass (:func:`_convert`): it is most of what an idle or
        held frame costs once the frames of a held scene are fused (numpy's ten calls took
        ≈ 10 µs of a ≈ 25 µs frame)."""
        dc = np.asarray(delta_c, dtype=np.float64)
        if dc.shape != (self.n_taxels,):
            self._check(dc, "delta_c", valid)  # raises, naming the shape
        mask = None
        if valid is not None:
            mask = np.asarray(valid, dtype=bool)
            if mask.shape != (self.n_taxels,):
                raise ValueError(f"valid must have shape ({self.n_taxels},), got {mask.shape}")
        delta = np.empty(self.n_taxels)
        ok = np.empty(self.n_taxels, dtype=bool)
        _convert(
            dc,
            mask if mask is not None else _ALL_VALID,
            mask is not None,
            self.thickness,
            self._eps_area,
            self._rest_c,
            self.full_scale,
            delta,
            ok,
        )
        return delta, ok

    def from_deflection(
        self, delta: ArrayLike, valid: ArrayLike | None
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """(δ [m], taxels used) of compressions δ [m] (K,). Excluded: ``valid`` False, NaN
        and compressions of the whole layer or more (δ ≥ h)."""
        d, ok = self._check(delta, "delta", valid)
        ok &= d < self.thickness
        if not ok.all():
            d = np.where(ok, d, 0.0)
        return d, ok

    def on_count_lattice(self, delta: NDArray, ok: NDArray) -> bool:
        """True when the compressions [m] are whole 8-bit counts through the sensor model
        (to 1 % of a count) and at least one is not zero."""
        # ΔC = ε0·εr·A·δ / (h·(h − δ)) (sensor.compression_to_delta_c), in counts.
        c, h = self._counts_per_metre_h, self.thickness
        # The largest reading first: off the lattice there (as float readings almost surely
        # are), the whole frame is, without converting every taxel.
        i = int(np.argmax(np.abs(delta)))
        one = c * float(delta[i]) / (h - float(delta[i]))
        if ok[i] and abs(one - round(one)) >= 0.01:
            return False
        d = delta[ok]
        counts = c * d / (h - d)
        # (max over the taxels only: an ``initial`` would take part in it.)
        return bool(np.any(np.abs(counts) > 0.5) and np.abs(counts - np.rint(counts)).max() < 0.01)

    def noise(self, noise: ArrayLike | None) -> NDArray[np.float64]:
        """(K,) noise [m] for this frame: ``noise`` (scalar or (K,)) or the default."""
        if noise is None:
            return self.default_noise
        if isinstance(noise, float) and NOISE_RANGE_M[0] <= noise <= NOISE_RANGE_M[1]:
            # A constant level passed every frame: one array, so the detector keeps its filters.
            # (the cache may hold an array a caller passed before: compare as floats only)
            key = None if self._noise_cache is None else self._noise_cache[0]
            if not (isinstance(key, float) and key == noise):
                self._noise_cache = (noise, np.full(self.n_taxels, noise))
            return self._noise_cache[1]
        # The same array as last frame (a tracker replaces its array when it learns) was
        # checked then; its values are compared, not trusted, in case it was edited since.
        cached = self._noise_cache
        if cached is not None and noise is cached[0] and (noise == cached[1]).all():
            return cached[1]
        s = np.broadcast_to(np.asarray(noise, dtype=np.float64), (self.n_taxels,))
        if not np.all(np.isfinite(s) & (s > 0)):
            raise ValueError(f"noise must be finite and > 0 m, shape () or ({self.n_taxels},)")
        if not (NOISE_RANGE_M[0] <= s.min() and s.max() <= NOISE_RANGE_M[1]):
            raise ValueError(
                f"noise must be each taxel's compression noise in metres (a count of this "
                f"sensor is ≈ {self.count_sigma * math.sqrt(6):.2g} m), within "
                f"{NOISE_RANGE_M[0]:g}..{NOISE_RANGE_M[1]:g} m; got {s.min():.3g}..{s.max():.3g}"
                " (counts or farads?)"
            )
        if isinstance(noise, np.ndarray):
            self._noise_cache = (noise, s.copy())
            return self._noise_cache[1]
        return s

    def _check(
        self, x: ArrayLike, name: str, valid: ArrayLike | None
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        v = np.asarray(x, dtype=np.float64)
        if v.shape != (self.n_taxels,):
            raise ValueError(
                f"{name} must have shape ({self.n_taxels},) in the bundle's taxel "
                f"order, got {v.shape}"
            )
        ok = np.isfinite(v)
        if valid is not None:
            mask = np.asarray(valid, dtype=bool)
            if mask.shape != (self.n_taxels,):
                raise ValueError(f"valid must have shape ({self.n_taxels},), got {mask.shape}")
            ok &= mask
        return (v if ok.all() else np.where(ok, v, 0.0)), ok


_ALL_VALID = np.ones(1, dtype=bool)


@numba.njit(cache=True, nogil=True)
def _convert(dc, valid, masked, h, eps_area, rest_c, full_scale, delta, ok):  # pragma: no cover
    """ReadingModel.from_delta_c in one pass: ok_i = valid, finite, −C0 < ΔC, |ΔC| ≤ full
    scale; δ_i = ΔC·h²/(ε0·εr·A + ΔC·h) there, 0 elsewhere (the same floating-point
    operations, in the same order, as numpy's)."""
    for i in range(dc.shape[0]):
        x = dc[i]
        good = (not masked or valid[i]) and x > -rest_c and abs(x) <= full_scale
        ok[i] = good
        delta[i] = x * (h * h) / (eps_area + x * h) if good else 0.0
