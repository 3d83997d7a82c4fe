"""Sensor model of one capacitive taxel: module counts ↔ ΔC [F] ↔ compression δ [m].

Two stages (DESIGN.md §2 and §6):

1. **Module counts → capacitance change.** The AD7147 converter reports a 16-bit CDC value; the
   module firmware sends ``value = noLoad − ((rawCDC − offset − drift) >> shift)`` clipped to
   0..255, so *lower means more capacitance* (more pressure). Relative to a baseline value b
   (the unloaded reading) the capacitance change is

       ΔC = (b − value) · 2**shift · farad_per_count     [F]

   with ``farad_per_count`` the gain of one CDC count (≈ 0.24–0.32 fF). One 8-bit count is
   therefore 2**shift CDC counts (≈ 1.28 fF with the defaults).

2. **Capacitance change → compression.** A taxel is a parallel-plate capacitor of area A with
   a dielectric of nominal thickness h and relative permittivity εr:

       δ  = ΔC·h² / (ε0·εr·A + ΔC·h)            (delta_c_to_compression)
       ΔC = ε0·εr·A·δ / (h·(h − δ))              (compression_to_delta_c)

   δ > 0 is compression. δ ≥ h (the plates touch or cross) and ΔC ≤ −ε0·εr·A/h (capacitance
   at or below zero) are physically impossible and raise ``ValueError``; the ``*_in_range``
   functions give the same test as a mask for real-time callers that prefer flags.

Negative ΔC is signal (the layer bulges beside a small contact, DESIGN.md §2): nothing here
clips it. The only clipping is the module's own 8-bit range, which :func:`module_value`
reproduces and flags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

EPSILON_0 = 8.8541878128e-12
"""Vacuum permittivity [F/m] (CODATA 2018)."""

VALUE_MIN = 0
VALUE_MAX = 255
DEFAULT_NO_LOAD = 240
DEFAULT_SHIFT = 2
DEFAULT_FARAD_PER_COUNT = 0.32e-15
"""Default gain of one CDC count [F] (AD7147: ±8 pF over 16 bits ≈ 0.24 fF; 0.32 fF seen)."""

FloatArray = NDArray[np.float64]


def _positive(name: str, value: ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        bad = arr[~(np.isfinite(arr) & (arr > 0.0))].ravel()
        raise ValueError(f"{name} must be finite and > 0, got {bad[0]!r}")
    return arr


def _finite(name: str, value: ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        idx = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} must be finite, got {arr[tuple(idx)]!r} at index {tuple(idx)}")
    return arr


def _shift(shift: ArrayLike) -> NDArray[np.int64]:
    arr = np.asarray(shift)
    if arr.dtype.kind not in "iu" and not np.all(np.asarray(arr, dtype=np.float64) % 1 == 0):
        raise TypeError(f"shift must be an integer number of bits, got {shift!r}")
    arr = arr.astype(np.int64)
    if np.any((arr < 0) | (arr > 15)):
        raise ValueError(f"shift must be within 0..15 bits, got {shift!r}")
    return arr


def rest_capacitance(thickness: ArrayLike, epsilon_r: ArrayLike, area: ArrayLike) -> FloatArray:
    """Unloaded taxel capacitance C0 = ε0·εr·A/h [F] (h [m], A [m²])."""
    h = _positive("thickness", thickness)
    return EPSILON_0 * _positive("epsilon_r", epsilon_r) * _positive("area", area) / h


def value_count_farad(farad_per_count: ArrayLike, shift: ArrayLike = DEFAULT_SHIFT) -> FloatArray:
    """Capacitance [F] of one 8-bit module count: ``farad_per_count · 2**shift``."""
    return _positive("farad_per_count", farad_per_count) * np.exp2(_shift(shift))


def counts_to_delta_c(
    values: ArrayLike,
    baseline: ArrayLike,
    farad_per_count: ArrayLike = DEFAULT_FARAD_PER_COUNT,
    shift: ArrayLike = DEFAULT_SHIFT,
) -> FloatArray:
    """ΔC [F] from module values and their baselines (both in 8-bit counts, may be fractional).

    ΔC = (baseline − values)·2**shift·farad_per_count; positive = compression. Arguments
    broadcast against each other.
    """
    v = _finite("values", values)
    b = _finite("baseline", baseline)
    return (b - v) * value_count_farad(farad_per_count, shift)


def delta_c_to_counts(
    delta_c: ArrayLike,
    baseline: ArrayLike,
    farad_per_count: ArrayLike = DEFAULT_FARAD_PER_COUNT,
    shift: ArrayLike = DEFAULT_SHIFT,
) -> FloatArray:
    """Inverse of :func:`counts_to_delta_c`: unquantised module values [counts] for ΔC [F]."""
    dc = _finite("delta_c", delta_c)
    b = _finite("baseline", baseline)
    return b - dc / value_count_farad(farad_per_count, shift)


def module_value(
    cdc_delta: ArrayLike, no_load: ArrayLike = DEFAULT_NO_LOAD, shift: ArrayLike = DEFAULT_SHIFT
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """What the module firmware sends for a CDC change ``rawCDC − offset − drift`` [CDC counts].

    ``value = noLoad − (cdc_delta >> shift)`` (arithmetic shift: floor division), clipped to
    0..255. Returns ``(values uint8, out_of_range)`` where ``out_of_range`` marks values the
    module had to clip (its out-of-range bit: value < 0 or > 255 before clipping).
    """
    cdc = np.asarray(cdc_delta)
    if cdc.dtype.kind == "f":
        if not np.all(np.isfinite(cdc)):
            raise ValueError("cdc_delta must be finite")
        cdc = np.floor(cdc)
    cdc = cdc.astype(np.int64)
    nl = np.asarray(no_load, dtype=np.int64)
    if np.any((nl < VALUE_MIN) | (nl > VALUE_MAX)):
        raise ValueError(f"no_load must be within 0..255, got {no_load!r}")
    raw = nl - np.right_shift(cdc, _shift(shift))
    oor = (raw < VALUE_MIN) | (raw > VALUE_MAX)
    return np.clip(raw, VALUE_MIN, VALUE_MAX).astype(np.uint8), oor


def quantize_counts(values: ArrayLike) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Round fractional module values to the 8-bit range; flag those at 0 or 255 (saturated)."""
    v = np.rint(_finite("values", values))
    q = np.clip(v, VALUE_MIN, VALUE_MAX).astype(np.uint8)
    return q, (q == VALUE_MIN) | (q == VALUE_MAX)


def saturated(values: ArrayLike) -> NDArray[np.bool_]:
    """True where an 8-bit module value sits at a clipping limit (0 or 255)."""
    v = np.asarray(values)
    return (v <= VALUE_MIN) | (v >= VALUE_MAX)


def delta_c_in_range(
    delta_c: ArrayLike, thickness: ArrayLike, epsilon_r: ArrayLike, area: ArrayLike
) -> NDArray[np.bool_]:
    """True where ΔC [F] maps to a finite compression (ΔC > −C0)."""
    c0 = rest_capacitance(thickness, epsilon_r, area)
    return np.asarray(delta_c, dtype=np.float64) > -c0


def compression_in_range(delta: ArrayLike, thickness: ArrayLike) -> NDArray[np.bool_]:
    """True where a compression δ [m] is physically possible (δ < h)."""
    return np.asarray(delta, dtype=np.float64) < _positive("thickness", thickness)


def delta_c_to_compression(
    delta_c: ArrayLike, thickness: ArrayLike, epsilon_r: ArrayLike, area: ArrayLike
) -> FloatArray:
    """Compression δ [m] of the dielectric from the capacitance change ΔC [F].

    δ = ΔC·h²/(ε0·εr·A + ΔC·h); thickness h [m], area A [m²]; arguments broadcast.
    Raises ValueError where ΔC ≤ −ε0·εr·A/h (a capacitance ≤ 0: no finite gap gives it).
    """
    dc = _finite("delta_c", delta_c)
    h = _positive("thickness", thickness)
    k = EPSILON_0 * _positive("epsilon_r", epsilon_r) * _positive("area", area)
    den = k + dc * h
    if np.any(den <= 0.0):
        bad = float(np.broadcast_to(dc, den.shape)[den <= 0.0].ravel()[0])
        limit = float(np.max(np.broadcast_to(-k / h, den.shape)[den <= 0.0]))
        raise ValueError(
            f"delta_c {bad!r} F is at or below -C0 = {limit!r} F: the capacitance would be <= 0"
        )
    return dc * h * h / den


def compression_to_delta_c(
    delta: ArrayLike, thickness: ArrayLike, epsilon_r: ArrayLike, area: ArrayLike
) -> FloatArray:
    """Capacitance change ΔC [F] for a compression δ [m] (inverse of delta_c_to_compression).

    ΔC = ε0·εr·A·δ/(h·(h − δ)); negative δ (the layer thickens) gives negative ΔC. Raises
    ValueError where δ ≥ h (the electrodes would touch).
    """
    d = _finite("delta", delta)
    h = _positive("thickness", thickness)
    k = EPSILON_0 * _positive("epsilon_r", epsilon_r) * _positive("area", area)
    gap = h - d
    if np.any(gap <= 0.0):
        bad = float(np.broadcast_to(d, gap.shape)[gap <= 0.0].ravel()[0])
        raise ValueError(f"compression {bad!r} m is not below the thickness {float(np.max(h))!r} m")
    return k * d / (h * gap)


@dataclass(frozen=True)
class SensorParams:
    """Sensor parameters of a patch (scalars; DESIGN.md §6 defaults).

    Attributes:
        thickness: dielectric (elastomer) thickness h [m].
        epsilon_r: relative permittivity of the dielectric [-].
        area: taxel electrode area A [m²].
        farad_per_count: capacitance of one CDC count [F].
        shift: firmware right shift from CDC counts to 8-bit counts [bits].
        no_load: firmware no-load value [8-bit counts].
    """

    thickness: float = 2e-3
    epsilon_r: float = 4.37
    area: float = float(np.pi * 2e-3**2)
    farad_per_count: float = DEFAULT_FARAD_PER_COUNT
    shift: int = DEFAULT_SHIFT
    no_load: int = DEFAULT_NO_LOAD

    def __post_init__(self) -> None:
        for name in ("thickness", "epsilon_r", "area", "farad_per_count"):
            _positive(name, getattr(self, name))
        _shift(self.shift)
        if not 0 <= int(self.no_load) <= VALUE_MAX:
            raise ValueError(f"no_load must be within 0..255, got {self.no_load!r}")

    @property
    def rest_capacitance(self) -> float:
        """C0 [F]."""
        return float(rest_capacitance(self.thickness, self.epsilon_r, self.area))

    @property
    def value_count_farad(self) -> float:
        """ΔC [F] of one 8-bit count."""
        return float(value_count_farad(self.farad_per_count, self.shift))

    def counts_to_delta_c(self, values: ArrayLike, baseline: ArrayLike) -> FloatArray:
        """ΔC [F] from module values and baselines [counts]."""
        return counts_to_delta_c(values, baseline, self.farad_per_count, self.shift)

    def delta_c_to_compression(self, delta_c: ArrayLike) -> FloatArray:
        """δ [m] from ΔC [F]."""
        return delta_c_to_compression(delta_c, self.thickness, self.epsilon_r, self.area)

    def compression_to_delta_c(self, delta: ArrayLike) -> FloatArray:
        """ΔC [F] from δ [m]."""
        return compression_to_delta_c(delta, self.thickness, self.epsilon_r, self.area)
