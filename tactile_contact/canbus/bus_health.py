"""Health of the CAN bus itself: receive errors, reconnect backoff, controller error state.

ROS-free, like :mod:`tactile_contact.canbus.stream`; the driver node reports these in
``/diagnostics``.

- :class:`BusErrorPolicy` counts receive errors and asks for a reconnect after a run of them.
- :class:`Backoff` spaces reconnect attempts: the first after ``initial_s``, each failed one
  doubling the wait up to ``max_s``.
- :class:`ControllerState` follows the controller's error state from the error frames that
  SocketCAN delivers (error class in the id, details in the data; ``linux/can/error.h``):
  error-active, warning, error-passive, bus-off. A restart notice or any data frame after a
  bus-off means the controller is back.
"""

from __future__ import annotations

import errno
import math
from dataclasses import dataclass, field

import can

# Error classes (the id of an error frame) and controller details (data[1]), linux/can/error.h.
ERR_TX_TIMEOUT = 0x001
ERR_LOSTARB = 0x002
ERR_CRTL = 0x004
ERR_PROT = 0x008
ERR_TRX = 0x010
ERR_ACK = 0x020
ERR_BUSOFF = 0x040
ERR_BUSERROR = 0x080
ERR_RESTARTED = 0x100
CRTL_RX_OVERFLOW = 0x01
CRTL_TX_OVERFLOW = 0x02
CRTL_RX_WARNING = 0x04
CRTL_TX_WARNING = 0x08
CRTL_RX_PASSIVE = 0x10
CRTL_TX_PASSIVE = 0x20
CRTL_ACTIVE = 0x40

ERROR_ACTIVE = "error-active"
WARNING = "warning"
ERROR_PASSIVE = "error-passive"
BUS_OFF = "bus-off"


@dataclass
class BusErrorPolicy:
    """Counts bus errors; asks for a reconnect after ``reconnect_after`` consecutive ones."""

    reconnect_after: int
    errors: int = 0
    consecutive: int = 0
    reconnects: int = 0
    reconnect_attempts: int = 0
    internal_errors: int = 0
    last_error: str = ""
    _errors_at_last_report: int = 0

    def error(self, exc: BaseException) -> bool:
        """Record one error; True when the bus should be closed and reopened."""
        self.errors += 1
        self.consecutive += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if self.consecutive >= self.reconnect_after:
            self.consecutive = 0
            return True
        return False

    def ok(self) -> None:
        self.consecutive = 0

    def values(self, window: bool = True) -> dict[str, object]:
        """Diagnostic key/values; ``bus_errors_in_window`` counts errors since the last call
        with ``window`` True (an extra report does not shorten the periodic window)."""
        in_window = self.errors - self._errors_at_last_report
        if window:
            self._errors_at_last_report = self.errors
        return {
            "bus_errors": self.errors,
            "bus_errors_in_window": in_window,
            "reconnects": self.reconnects,
            "reconnect_attempts": self.reconnect_attempts,
            "internal_errors": self.internal_errors,
            "last_bus_error": self.last_error,
        }


@dataclass
class Backoff:
    """Waits between reconnect attempts [s]: ``initial_s``, doubled after each failure, at
    most ``max_s``; :meth:`reset` after a success."""

    initial_s: float
    max_s: float
    failures: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.initial_s) and self.initial_s > 0):
            raise ValueError(f"initial_s must be finite and > 0, got {self.initial_s!r}")
        self.max_s = max(self.max_s, self.initial_s)

    @property
    def wait_s(self) -> float:
        """The wait before the next attempt [s]."""
        return min(self.initial_s * 2.0 ** min(self.failures, 60), self.max_s)

    def failed(self) -> None:
        self.failures += 1

    def reset(self) -> None:
        self.failures = 0


@dataclass
class ControllerState:
    """The CAN controller's error state, from error frames (see the module docstring).

    Attributes:
        state: ``error-active``, ``warning``, ``error-passive`` or ``bus-off``.
        error_frames: error frames seen; ``by_class``: per error class name.
        bus_off_count: times the controller went bus-off; ``bus_off_since``: the monotonic
            time [s] of the current bus-off (None when not bus-off).
    """

    state: str = ERROR_ACTIVE
    error_frames: int = 0
    bus_off_count: int = 0
    bus_off_since: float | None = None
    restarts: int = 0
    by_class: dict[str, int] = field(default_factory=dict)

    _NAMES = (
        (ERR_TX_TIMEOUT, "tx_timeout"),
        (ERR_LOSTARB, "lost_arbitration"),
        (ERR_CRTL, "controller"),
        (ERR_PROT, "protocol"),
        (ERR_TRX, "transceiver"),
        (ERR_ACK, "no_ack"),
        (ERR_BUSOFF, "bus_off"),
        (ERR_BUSERROR, "bus_error"),
        (ERR_RESTARTED, "restarted"),
    )

    def error_frame(self, msg: can.Message, now: float) -> str | None:
        """Take one error frame; the new state if it changed, else None."""
        self.error_frames += 1
        cls = msg.arbitration_id
        for bit, name in self._NAMES:
            if cls & bit:
                self.by_class[name] = self.by_class.get(name, 0) + 1
        before = self.state
        if cls & ERR_BUSOFF:
            if self.state != BUS_OFF:
                self.bus_off_count += 1
                self.bus_off_since = now
            self.state = BUS_OFF
        elif cls & ERR_RESTARTED:
            self.restarts += 1
            self._back(now)
        elif cls & ERR_CRTL and len(msg.data) > 1 and self.state != BUS_OFF:
            d = msg.data[1]
            if d & (CRTL_RX_PASSIVE | CRTL_TX_PASSIVE):
                self.state = ERROR_PASSIVE
            elif d & (CRTL_RX_WARNING | CRTL_TX_WARNING):
                self.state = WARNING
            elif d & CRTL_ACTIVE:
                self.state = ERROR_ACTIVE
        return self.state if self.state != before else None

    def data_frame(self, now: float) -> str | None:
        """A data frame arrived: a bus-off controller is evidently back. New state or None."""
        if self.state == BUS_OFF:
            self._back(now)
            return self.state
        return None

    def _back(self, now: float) -> None:
        self.state = ERROR_ACTIVE
        self.bus_off_since = None

    def values(self) -> dict[str, object]:
        out: dict[str, object] = {
            "controller_state": self.state,
            "error_frames": self.error_frames,
            "bus_off_count": self.bus_off_count,
            "controller_restarts": self.restarts,
        }
        out.update({f"error_frames_{k}": v for k, v in sorted(self.by_class.items())})
        return out


def interface_gone(exc: BaseException) -> str:
    """ "down" / "removed" when a receive error says the network interface is, else ""."""
    # python-can's socketcan raises CanOperationError(..., error_code=errno) from the OSError
    errno_ = (
        getattr(exc, "errno", None)
        or getattr(exc, "error_code", None)
        or getattr(exc.__cause__, "errno", None)
    )
    if errno_ == errno.ENETDOWN:
        return "down"
    if errno_ in (errno.ENODEV, errno.ENXIO):
        return "removed"
    return ""


def may_come_up(exc: BaseException, replay_file: str) -> bool:
    """Whether a bus that failed to open with ``exc`` is worth retrying: a live interface that
    is not there yet (no such device, address family, adapter unplugged); not an unknown
    python-can interface, a backend that cannot import, a bad channel or a replay file."""
    if replay_file:
        return False
    return not isinstance(exc, (can.CanInterfaceNotImplementedError, ImportError, ValueError))
