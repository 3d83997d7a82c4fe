"""Skin simulator: a scripted indentation → per-period module frames, with the ground truth.

Chain per period: indentation script (force, centre at time t) → forward model (compression δ
of every channel [m]) → sensor model (ΔC [F], :func:`compression_to_delta_c`) → module firmware
(CDC counts with noise, drift and rest offsets; ``noLoad − (cdc >> shift)`` clipped to 8 bits,
:func:`module_value`) → frames A and B (:mod:`tactile_contact.canbus.codec`).

Shift and saturation, as on the boards: each module's ``shift`` and ``noLoad`` start from the
sensor parameters and follow the host's SET_TRIANG_CFG / SET_BRD_CFG commands
(:meth:`SkinSimulator.apply_command`; the ``skin_simulator`` node applies those it receives). A
larger shift divides the converter's counts (and its noise, in counts) by 2**shift: coarser
counts, more range. The value clips at 0 when a taxel is compressed by more than noLoad counts
and at 255 when it bulges by more than 255 − noLoad counts (15 with the default noLoad 240);
clipped channels carry their out-of-range bit (:func:`saturating_delta_c` gives both limits in
farads).

Frame generation (:meth:`SkinSimulator.periods`, a generator of :class:`SimPeriod`) is separate
from delivery: :func:`send_realtime` paces the frames onto any python-can bus, :func:`write_log`
writes a candump ``.log`` (or any format ``can.Logger`` knows). Both return the truth.
Everything is deterministic for a given seed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import can
import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.canbus.codec import (
    CHANNELS,
    CLASS_POLLING,
    CLASS_SKIN,
    CMD_SET_BRD_CFG,
    CMD_SET_TRIANG_CFG,
    reading_messages,
    skin_id,
)
from tactile_contact.model.sensor import (
    VALUE_MAX,
    VALUE_MIN,
    SensorParams,
    compression_to_delta_c,
    module_value,
    value_count_farad,
)

if TYPE_CHECKING:
    from tactile_contact.model.layout import PatchLayout


class CompressionModel(Protocol):
    """What the simulator needs of a forward model (e.g. forward.ForwardModel)."""

    def compression(self, indenter: Any, force: float, center_xy: ArrayLike) -> NDArray[np.float64]:
        """(K,) compression [m] of every channel for a normal force [N] at centre_xy [m]."""
        ...


@dataclass(frozen=True)
class Indentation:
    """A scripted indentation: force and centre, piecewise linear between knots.

    Attributes:
        indenter: indenter shape (indenters.HertzSphere, FlatPunch, ...).
        times: (T,) knot times [s], increasing.
        forces: (T,) normal force [N] at the knots (≥ 0).
        centers: (T, 2) indenter axis [m] in the patch frame at the knots.
    """

    indenter: Any
    times: tuple[float, ...]
    forces: tuple[float, ...]
    centers: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=np.float64)
        f = np.asarray(self.forces, dtype=np.float64)
        c = np.asarray(self.centers, dtype=np.float64)
        n = len(t)
        if n < 1 or t.shape != (n,) or f.shape != (n,) or c.shape != (n, 2):
            raise ValueError(
                f"times, forces, centers must have shapes (T,), (T,), (T, 2); got "
                f"{t.shape}, {f.shape}, {c.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(f)) and np.all(np.isfinite(c))):
            raise ValueError("times, forces and centers must be finite")
        if np.any(np.diff(t) <= 0):
            raise ValueError(f"times must increase strictly, got {list(t)}")
        if np.any(f < 0):
            raise ValueError(f"forces must be >= 0 N, got min {f.min()!r}")

    @classmethod
    def press(
        cls,
        indenter: Any,
        force: float,
        center: tuple[float, float],
        *,
        start_s: float = 1.0,
        ramp_s: float = 0.5,
        hold_s: float = 2.0,
        end: tuple[float, float] | None = None,
    ) -> Indentation:
        """Ramp to ``force`` [N] at ``center`` [m], hold (sliding to ``end`` if given), release."""
        e = center if end is None else end
        t0, t1, t2 = start_s, start_s + ramp_s, start_s + ramp_s + hold_s
        return cls(
            indenter,
            (0.0, t0, t1, t2, t2 + ramp_s) if t0 > 0 else (t0, t1, t2, t2 + ramp_s),
            (0.0, 0.0, force, force, 0.0) if t0 > 0 else (0.0, force, force, 0.0),
            (center, center, center, e, e) if t0 > 0 else (center, center, e, e),
        )

    def at(self, t: float) -> tuple[float, NDArray[np.float64]]:
        """(force [N], centre [m]) at time t [s] (held constant outside the knots)."""
        tt = np.asarray(self.times)
        f = float(np.interp(t, tt, self.forces))
        c = np.asarray(self.centers, dtype=np.float64)
        return f, np.array([np.interp(t, tt, c[:, 0]), np.interp(t, tt, c[:, 1])])


@dataclass(frozen=True)
class PeriodTruth:
    """Ground truth of one period (channel arrays in the simulator's channel order).

    Attributes:
        t: period start [s]; force [N]; center: (2,) [m].
        compression: (K,) δ [m] (0 on thermal pads); delta_c: (K,) ΔC [F].
        values: (K,) uint8 module values sent; out_of_range: (K,) clipped by the module.
    """

    t: float
    force: float
    center: NDArray[np.float64]
    compression: NDArray[np.float64]
    delta_c: NDArray[np.float64]
    values: NDArray[np.uint8]
    out_of_range: NDArray[np.bool_]


@dataclass(frozen=True)
class SimPeriod:
    """One period: its start time [s], the frames (A then B per module) and the truth."""

    t: float
    messages: list[can.Message]
    truth: PeriodTruth


class SkinSimulator:
    """Frames of a set of modules pressed by a scripted indentation.

    Args:
        modules: (board, triangle) of each module; channels are module by module, 12 each.
        model: forward model whose ``compression`` returns (12·M,) δ [m] at the channels.
        sensor: sensor parameters (h, εr, A, gain, shift, noLoad).
        taxel_mask: (12·M,) False for channels that are not taxels (their ΔC is 0).
        noise_cdc: standard deviation of the converter noise [CDC counts].
        rest_spread_cdc: rest offsets drawn uniformly in ±this [CDC counts] (imperfect
            firmware calibration).
        drift_cdc_per_s: baseline drift [CDC counts/s] (scalar or per channel); positive reads
            as a slow compression.
        period_s: reading period [s] (50 ms board default, 20 ms common).
        id_class: 4 (periodic skin) or 3 (older firmware).
        seed: random seed.
        frame_gap_s: time between consecutive frames in a period [s].
        exact_capacitance: ΔC from the model's own ``delta_c`` (the exact capacitance of the
            deformed plate, forward.ForwardModel with a taxel radius) instead of the sensor
            model applied to the mean δ — then the driver's inversion carries a real model
            error, as on hardware.
    """

    def __init__(
        self,
        modules: Sequence[tuple[int, int]],
        model: CompressionModel,
        *,
        sensor: SensorParams | None = None,
        taxel_mask: ArrayLike | None = None,
        noise_cdc: float = 2.0,
        rest_spread_cdc: float = 0.0,
        drift_cdc_per_s: ArrayLike = 0.0,
        period_s: float = 0.05,
        id_class: int = CLASS_SKIN,
        seed: int = 0,
        frame_gap_s: float = 1.3e-4,
        exact_capacitance: bool = False,
    ) -> None:
        self.modules = [(int(b), int(t)) for b, t in modules]
        if not self.modules:
            raise ValueError("modules must name at least one (board, triangle)")
        for b, t in self.modules:
            skin_id(b, t, id_class)
        if len(set(self.modules)) != len(self.modules):
            raise ValueError(f"modules must be unique, got {self.modules}")
        self.n = CHANNELS * len(self.modules)
        self.model = model
        self.sensor = sensor or SensorParams()
        self.taxel_mask = (
            np.ones(self.n, dtype=bool) if taxel_mask is None else np.asarray(taxel_mask, bool)
        )
        if self.taxel_mask.shape != (self.n,):
            raise ValueError(f"taxel_mask must have shape ({self.n},), got {self.taxel_mask.shape}")
        for name, v in (("noise_cdc", noise_cdc), ("rest_spread_cdc", rest_spread_cdc)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        if not (math.isfinite(period_s) and 0.001 <= period_s <= 0.255):
            raise ValueError(f"period_s must be within 0.001..0.255 s, got {period_s!r}")
        if not (math.isfinite(frame_gap_s) and 0 <= frame_gap_s * 2 * len(self.modules) < period_s):
            raise ValueError(f"frame_gap_s {frame_gap_s!r} does not fit the frames in a period")
        self.drift = np.broadcast_to(np.asarray(drift_cdc_per_s, dtype=np.float64), (self.n,))
        if not np.all(np.isfinite(self.drift)):
            raise ValueError("drift_cdc_per_s must be finite")
        self.noise_cdc = float(noise_cdc)
        self.period_s = float(period_s)
        self.id_class = id_class
        self.frame_gap_s = float(frame_gap_s)
        self._rng = np.random.default_rng(seed)
        self.rest_cdc = self._rng.uniform(-rest_spread_cdc, rest_spread_cdc, self.n)
        self.exact_capacitance = exact_capacitance
        if exact_capacitance and not hasattr(model, "delta_c"):
            raise TypeError("exact_capacitance needs a model with delta_c (forward.ForwardModel)")
        self._cache: tuple[float, tuple[float, float], NDArray, NDArray] | None = None
        #: Per module: firmware shift [bits], noLoad [counts] and whether it transmits (the
        #: host's SET_TRIANG_CFG and SET_BRD_CFG change them: :meth:`apply_command`).
        self.shift = np.full(len(self.modules), int(self.sensor.shift), dtype=np.int64)
        self.no_load = np.full(len(self.modules), int(self.sensor.no_load), dtype=np.int64)
        self.enabled = np.ones(len(self.modules), dtype=bool)

    def apply_command(self, msg: can.Message) -> bool:
        """Apply a host command as the addressed boards would; True if it was one for a
        simulated board (SET_TRIANG_CFG: shift and enable of triangles ``first..last``;
        SET_BRD_CFG: noLoad of every triangle of the board). Other frames, commands to other
        boards and malformed commands are ignored (False), as a board ignores them."""
        data = bytes(msg.data)
        if msg.is_extended_id or msg.arbitration_id >> 4 != CLASS_POLLING << 4 or not data:
            return False
        board = msg.arbitration_id & 0xF
        mine = [i for i, (b, _) in enumerate(self.modules) if b == board]
        if not mine:
            return False
        if data[0] == CMD_SET_TRIANG_CFG and len(data) >= 5 and data[1] <= data[2]:
            first, last, shift, enabled = data[1], data[2], data[3], data[4]
            if shift > 15:
                return False
            for i in mine:
                if first <= self.modules[i][1] <= last:
                    self.shift[i] = shift
                    self.enabled[i] = bool(enabled)
            return True
        if data[0] == CMD_SET_BRD_CFG and len(data) >= 4:
            self.no_load[mine] = data[3]
            return True
        return False

    def _physics(
        self, indentation: Indentation | None, t: float
    ) -> tuple[float, NDArray, NDArray, NDArray]:
        """(force [N], centre [m], δ (K,) [m], ΔC (K,) [F]) at time t [s]."""
        s = self.sensor
        zeros = np.zeros(self.n)
        if indentation is None:
            return 0.0, np.zeros(2), zeros, zeros
        force, center = indentation.at(t)
        key = (float(center[0]), float(center[1]))
        if force <= 0.0:
            return 0.0, center, zeros, zeros
        # A held contact repeats the same state: evaluate the forward model once.
        if self._cache is not None and self._cache[0] == force and self._cache[1] == key:
            return force, center, self._cache[2], self._cache[3]
        d = np.asarray(self.model.compression(indentation.indenter, force, center), np.float64)
        if d.shape != (self.n,):
            raise ValueError(f"model returned shape {d.shape}, expected ({self.n},)")
        d = np.where(self.taxel_mask, d, 0.0)
        if self.exact_capacitance:
            dc = self.model.delta_c(indentation.indenter, force, center, s.epsilon_r)  # type: ignore[attr-defined]
            dc = np.where(self.taxel_mask, np.asarray(dc, np.float64), 0.0)
        else:
            dc = compression_to_delta_c(d, s.thickness, s.epsilon_r, s.area)
        self._cache = (force, key, d, dc)
        return force, center, d, dc

    def period(self, indentation: Indentation | None, t: float) -> SimPeriod:
        """Frames and truth of the period starting at t [s]."""
        s = self.sensor
        force, center, delta, dc = self._physics(indentation, t)
        cdc = dc / s.farad_per_count + self.rest_cdc + self.drift * t
        cdc = cdc + self._rng.normal(0.0, self.noise_cdc, self.n) if self.noise_cdc else cdc
        values, oor = module_value(
            np.rint(cdc), np.repeat(self.no_load, CHANNELS), np.repeat(self.shift, CHANNELS)
        )
        msgs: list[can.Message] = []
        for i, (b, tri) in enumerate(self.modules):
            if not self.enabled[i]:
                continue
            sl = slice(CHANNELS * i, CHANNELS * (i + 1))
            mask = int(np.dot(oor[sl].astype(np.int64), 1 << np.arange(CHANNELS)))
            msgs += reading_messages(
                b,
                tri,
                values[sl].tobytes(),
                oor_mask=mask,
                id_class=self.id_class,
                timestamp=t + 2 * i * self.frame_gap_s,
                gap_s=self.frame_gap_s,
            )
        truth = PeriodTruth(t, force, center, delta, dc, values, oor)
        return SimPeriod(t, msgs, truth)

    def periods(
        self, indentation: Indentation | None, duration_s: float, start_s: float = 0.0
    ) -> Iterator[SimPeriod]:
        """Periods from ``start_s`` for ``duration_s`` [s] (frames stamped with simulated time)."""
        if not (math.isfinite(duration_s) and duration_s >= 0 and math.isfinite(start_s)):
            raise ValueError(f"duration_s must be finite and >= 0, got {duration_s!r}")
        n = math.floor(duration_s / self.period_s + 1e-9)
        for k in range(n):
            yield self.period(indentation, start_s + k * self.period_s)


def saturating_delta_c(sensor: SensorParams, shift: int | None = None) -> tuple[float, float]:
    """(largest, smallest) ΔC [F] a module value carries before it clips at 0 (compression)
    or 255 (bulge): ``noLoad`` and ``255 − noLoad`` 8-bit counts of ``farad_per_count ·
    2**shift`` each (``shift`` default: the sensor's). With the defaults (shift 2, noLoad 240):
    +307 fF and −19 fF, about +1.1 mm and −0.17 mm of compression of the 2 mm layer."""
    bits = sensor.shift if shift is None else shift
    count = float(value_count_farad(sensor.farad_per_count, bits))
    return (sensor.no_load - VALUE_MIN) * count, (sensor.no_load - VALUE_MAX) * count


def send_realtime(
    bus: can.BusABC,
    periods: Iterable[SimPeriod],
    *,
    rate: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> list[PeriodTruth]:
    """Send every period's frames on ``bus`` paced at ``rate`` × simulated time (inf: no pacing).

    Returns the truth of the periods sent. Bus errors (can.CanError) propagate.
    """
    if not (rate > 0):
        raise ValueError(f"rate must be > 0, got {rate!r}")
    truths = []
    t_wall0 = clock()
    t_sim0: float | None = None
    for p in periods:
        if t_sim0 is None:
            t_sim0 = p.t
        if math.isfinite(rate):
            wait = t_wall0 + (p.t - t_sim0) / rate - clock()
            if wait > 0:
                sleep(wait)
        for m in p.messages:
            bus.send(m)
        truths.append(p.truth)
    return truths


def write_log(path: str | Path, periods: Iterable[SimPeriod]) -> list[PeriodTruth]:
    """Write the frames to a log file (format from the suffix: ``.log`` is candump); the truth."""
    truths = []
    with can.Logger(str(path)) as log:
        for p in periods:
            for m in p.messages:
                log.on_message_received(m)
            truths.append(p.truth)
    return truths


#: Kernel entries (channels × fine cells) above which the real-time simulator cuts each
#: taxel's kernel at a reach instead of keeping all of it (about 40 MB of float64).
REALTIME_DENSE_ENTRIES = 5_000_000


def simulator_for_patch(
    patch: PatchLayout,
    *,
    fine_cell: float = 2.0e-4,
    taxel_average: bool = False,
    exact_capacitance: bool = False,
    realtime: bool = False,
    **kwargs: Any,
) -> SkinSimulator:
    """A simulator of every module of a layout patch, through forward.ForwardModel.

    Channel order is the layout's (``patch.channel_xy()``); thermal pads read no load. The
    elastomer and sensor sections of the layout give h, E, ν, εr, electrode area, gain, shift
    and noLoad. ``taxel_average`` averages δ over each electrode disc (≈ 25× slower, more
    exact: about 0.5 s instead of 20 ms per period of a moving contact on the 6-module patch);
    ``exact_capacitance`` (implies ``taxel_average``) takes ΔC from the exact capacitance of the
    deformed plate. ``realtime`` uses :class:`forward.PatchForwardModel` instead: electrode
    averaged, kernel precomputed once over a fixed grid (seconds at start, then about 2 ms per
    period; within about 3 % of the reference model), for simulators that must keep pace with
    the bus; on a patch whose fixed-grid kernel would exceed REALTIME_DENSE_ENTRIES (an iCub
    forearm: 288 channels × 95 000 cells) each taxel's kernel is cut at 20 mm instead
    (:class:`tactile_contact.sim.local_forward.LocalForwardModel`, within 0.03 count of the
    dense one). Other keyword arguments go to :class:`SkinSimulator`.
    """
    from tactile_contact.model.forward import ForwardModel, PatchForwardModel
    from tactile_contact.model.grids import Grid

    el, se = patch.elastomer, patch.sensor
    model: CompressionModel
    covering = Grid.covering(patch.channel_xy(), fine_cell, 6.0e-3)
    entries = len(patch.channel_xy()) * covering.shape[0] * covering.shape[1]
    if realtime and entries > REALTIME_DENSE_ENTRIES:
        from tactile_contact.sim.local_forward import LocalForwardModel

        model = LocalForwardModel(
            patch.channel_xy(),
            el.thickness,
            el.young,
            el.poisson,
            fine_cell=fine_cell,
            taxel_radius=se.taxel_radius,
        )
    elif realtime:
        model = PatchForwardModel(
            patch.channel_xy(),
            el.thickness,
            el.young,
            el.poisson,
            fine_cell=fine_cell,
            taxel_radius=se.taxel_radius,
        )
    else:
        model = ForwardModel(
            patch.channel_xy(),
            el.thickness,
            el.young,
            el.poisson,
            fine_cell=fine_cell,
            taxel_radius=se.taxel_radius if (taxel_average or exact_capacitance) else 0.0,
        )
    sensor = SensorParams(
        thickness=el.thickness,
        epsilon_r=se.epsilon_r,
        area=se.area,
        farad_per_count=se.farad_per_count,
        shift=se.shift,
        no_load=se.no_load,
    )
    pads = np.concatenate([np.asarray(m.module_type.taxel, dtype=bool) for m in patch.modules])
    return SkinSimulator(
        [(m.board, m.triangle) for m in patch.modules],
        model,
        sensor=sensor,
        taxel_mask=pads,
        exact_capacitance=exact_capacitance,
        **kwargs,
    )
