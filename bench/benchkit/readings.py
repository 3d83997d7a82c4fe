"""Readings of a truth's compressions and the noise tiers they carry; seeds.

Tiers of the issue-16 benches: ``float``: δ + Gaussian noise of σ = 1 % of the press's largest
|δ| per taxel, through ``solve_deflection(δ)``; ``8-bit``: δ → ΔC with the layout's sensor
model, + 0.15-count Gaussian noise, rounded to counts of ``value_count_farad(farad_per_count,
shift)``, through ``solve(ΔC)``. The first wave's benches (tradeoff, accuracy) add the noise to
ΔC before rounding (:func:`quantised`). Idle skins (:class:`IdleSkin`) rest at a fraction of a
count with the driver's tracked baseline.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import scipy.signal
from numpy.typing import NDArray

from benchkit.protocol import Patch
from tactile_contact.inverse.reconstruction import Reconstructor

TIERS = ("float", "8-bit")
NOISE_REL = 0.01  # float tier: σ over the press's largest |δ| (or over each |δ|: FLOAT_NOISES)
#: How the float tier's "1 % noise" scales (issue 26 names no more): ``peak`` — 1 % of the
#: press's largest compression on every taxel (additive; the harder reading, the benches'
#: default); ``reading`` — 1 % of each taxel's own compression (a gain error per reading), with
#: a floor of PEAK_FLOOR of the first so untouched taxels keep a finite σ.
FLOAT_NOISES = ("peak", "reading")
PEAK_FLOOR = 1e-3
float_noise = "peak"  # set_float_noise (the benches' --float-noise)
COUNT_NOISE = 0.15  # 8-bit tier: converter noise [counts RMS]
CLEAR = 10.0  # a press clearly above noise: a known-shape matched filter reads ‖δ/σ‖ ≥ this


def seed(*parts: str) -> int:
    """A seed named by its parts (the same draws whatever else a bench runs)."""
    return zlib.crc32("/".join(parts).encode())


def set_float_noise(mode: str) -> None:
    """Choose how the float tier's noise scales (one of FLOAT_NOISES) for this process."""
    global float_noise
    if mode not in FLOAT_NOISES:
        raise ValueError(f"float noise {mode!r}: one of {', '.join(FLOAT_NOISES)}")
    float_noise = mode


def float_sigma(d: NDArray) -> NDArray:
    """σ [m] of the float tier's noise on compressions d (..., K) [m], by ``float_noise``:
    (..., 1) for ``peak``, (..., K) for ``reading``."""
    peak = NOISE_REL * np.abs(d).max(axis=-1, keepdims=True)
    if float_noise == "peak":
        return peak
    if float_noise == "reading":
        return np.maximum(NOISE_REL * np.abs(d), PEAK_FLOOR * peak)
    raise ValueError(f"float_noise {float_noise!r}: one of {', '.join(FLOAT_NOISES)}")


def readings(lay: Patch, d: NDArray, tier: str, rng: np.random.Generator) -> NDArray:
    """The tier's readings of compressions d (N, K): deflections [m] (float) or ΔC [F]."""
    if tier == "float":
        return d + rng.normal(size=d.shape) * float_sigma(d)
    counts = np.rint(lay.to_delta_c(d) / lay.lsb + rng.normal(0.0, COUNT_NOISE, d.shape))
    return counts * lay.lsb


def noise_of(lay: Patch, d: NDArray, tier: str) -> NDArray | float:
    """Compression noise [m] of the tier: float (N, 1) per press (``peak``) or (N, K) per
    reading (``reading``: float_sigma); 8-bit a scalar (converter noise and rounding at small
    readings)."""
    if tier == "float":
        return float_sigma(d)
    return float(lay.to_deflection(np.array([lay.lsb]))[0]) * math.hypot(COUNT_NOISE, 12**-0.5)


def clear_of(lay: Patch, d: NDArray, tier: str) -> NDArray[np.bool_]:
    """(N,) presses whose ideal matched-filter statistic ‖δ/σ‖ is at least CLEAR, σ the
    press's peak-scaled noise for the float tier in either mode (per reading, every touched
    taxel reads 100 σ and every press would count as clear)."""
    sigma = NOISE_REL * np.abs(d).max(axis=1, keepdims=True) if tier == "float" else None
    return np.linalg.norm(d / (noise_of(lay, d, tier) if sigma is None else sigma), axis=1) >= CLEAR


def quantised(dc: NDArray, lsb: float, rms: float, rng: np.random.Generator) -> NDArray:
    """ΔC [F] + Gaussian noise of ``rms`` counts, rounded to counts of ``lsb`` [F]."""
    return np.rint((dc + rng.normal(0.0, rms * lsb, dc.shape)) / lsb) * lsb


def assumed_noise(recon: Reconstructor) -> NDArray[np.float64]:
    """(K,) compression noise [m] the reconstructor assumes when none is passed."""
    for attr in ("default_noise", "noise_sigma", "noise"):
        v = getattr(recon, attr, None)
        if v is not None and not callable(v):
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (recon.n_taxels,)).copy()
    return np.full(recon.n_taxels, float(recon.params["noise"]))


#: tactile_contact.canbus.baseline.BaselineConfig defaults: samples of the first baseline,
#: time constant of its drift filter [s]; the skin's frame rate [Hz].
CALIBRATION_SAMPLES = 20
DRIFT_TAU_S = 20.0
RATE_HZ = 50.0


class IdleSkin:
    """8-bit idle readings [counts] with a tracked fractional baseline.

    Each taxel rests at a random fraction u ∈ [0, 1) of a count (fixed per simulated skin; a
    new skin every ``skin_frames``), the module rounds u + 0.15-count noise, and the baseline is
    what the driver's tracker keeps: the mean of the first 20 readings, then an exponential
    filter with τ = 20 s at 50 Hz, so that readings are the module value minus a fractional
    baseline. A taxel resting near half a count flips between two values: up to 0.5 count RMS.
    """

    def __init__(
        self, k: int, rng: np.random.Generator, skin_frames: int, drift_lag: float = 0.0
    ) -> None:
        """``drift_lag``: RMS [counts] over taxels of how far the tracked baseline lags a
        steady drift (each taxel drifts at a rate drawn so that its lag, rate × τ, has this
        RMS); 0: no drift."""
        self.k, self.rng, self.skin_frames = k, rng, skin_frames
        self.alpha = 1.0 - np.exp(-1.0 / RATE_HZ / DRIFT_TAU_S)
        self.drift_lag = drift_lag
        self.left = 0

    def _new_skin(self) -> None:
        self.rest = self.rng.uniform(0.0, 1.0, self.k)
        cal = np.rint(self.rest + self.rng.normal(0.0, COUNT_NOISE, (CALIBRATION_SAMPLES, self.k)))
        self.baseline = cal.mean(axis=0)
        # Per frame [counts]; the rest level moves by it every frame. (No draw without drift:
        # the other benches' idle skins stay the same draws.)
        self.rate = np.zeros(self.k)
        if self.drift_lag:
            self.rate = self.rng.normal(0.0, self.drift_lag / DRIFT_TAU_S / RATE_HZ, self.k)
        self.frame = 0
        self.left = self.skin_frames
        self.fresh = True

    def frames(self, n: int) -> tuple[NDArray[np.float64], bool]:
        """Up to n frames of Δcounts = baseline − value (one skin), and whether a new skin
        starts with them."""
        if self.left == 0:
            self._new_skin()
        n = min(n, self.left)
        t = self.frame + np.arange(n)[:, None]
        self.frame += n
        values = np.rint(self.rest + self.rate * t + self.rng.normal(0.0, COUNT_NOISE, (n, self.k)))
        a = self.alpha
        zi = (1.0 - a) * self.baseline
        tracked, _ = scipy.signal.lfilter([a], [1.0, -(1.0 - a)], values, axis=0, zi=zi[None, :])
        before = np.vstack([self.baseline[None, :], tracked[:-1]])
        self.baseline = tracked[-1]
        self.left -= n
        fresh, self.fresh = self.fresh, False
        return before - values, fresh
