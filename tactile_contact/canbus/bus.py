"""Opening a CAN bus and replaying a candump log as if it were one.

ROS-free: :func:`open_bus` builds a python-can bus from an interface and channel (or a
:class:`ReplayBus` from a log file), :func:`close_bus` shuts one down without raising.
:mod:`tactile_contact.canbus.stream` re-exports these for its older callers.
"""

from __future__ import annotations

import contextlib
import re
import threading
from collections.abc import Iterator, Sequence

import can


class ReplayBus:
    """A candump log read like a bus: :meth:`recv` returns its messages at recorded pace.

    Built on ``can.LogReader`` and ``can.MessageSync``. Gaps longer than ``max_gap_s`` are
    shortened to it. ``can_filters`` are applied as a live bus would (python-can form). After
    the last message :attr:`finished` is True and :meth:`recv` returns None after ``timeout``.
    """

    def __init__(
        self, path: str, max_gap_s: float = 1.0, can_filters: Sequence[dict] | None = None
    ) -> None:
        self._reader = can.LogReader(path)
        self._messages: Iterator[can.Message] = iter(
            can.MessageSync(self._reader, timestamps=True, skip=max_gap_s)
        )
        self._filters = list(can_filters or [])
        self.finished = False
        self._closed = threading.Event()

    def _matches(self, msg: can.Message) -> bool:
        if not self._filters:
            return True
        return any(
            (msg.arbitration_id & f["can_mask"]) == (f["can_id"] & f["can_mask"])
            and msg.is_extended_id == f.get("extended", msg.is_extended_id)
            for f in self._filters
        )

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """Next message of the log that passes the filters (waits for its recorded time)."""
        while not self.finished:
            try:
                msg = next(self._messages)
            except StopIteration:
                self.finished = True
                break
            if self._matches(msg):
                return msg
        self._closed.wait(timeout or 0.0)
        return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """A log cannot be written to: the message is discarded."""

    def shutdown(self) -> None:
        self._closed.set()
        self._reader.stop()


def bus_kwargs(interface: str, channel: str, bitrate: int = 0) -> dict:
    """``can.Bus`` keywords for ``interface`` and ``channel`` (``bitrate`` 0: left out).

    For ``udp_multicast`` the channel may name a port as ``GROUP:PORT`` (IPv4, e.g.
    ``239.74.163.2:43156``). Why: python-can binds every such bus to its port (default 43113)
    on all addresses, and Linux delivers every group joined anywhere on the machine at that port
    to it: two simulations on one machine stay apart only on different ports.
    """
    kwargs: dict = {"interface": interface, "channel": channel}
    m = re.fullmatch(r"(\d{1,3}(?:\.\d{1,3}){3}):(\d+)", channel.strip())
    if interface == "udp_multicast" and m:
        port = int(m.group(2))
        if not 1 <= port <= 65535:
            raise ValueError(f"channel {channel!r}: port {port} is not in 1..65535")
        kwargs.update(channel=m.group(1), port=port)
    if bitrate:
        kwargs["bitrate"] = bitrate
    return kwargs


def open_bus(
    *,
    interface: str,
    channel: str,
    bitrate: int = 0,
    replay_file: str = "",
    replay_max_gap_s: float = 1.0,
    can_filters: Sequence[dict] | None = None,
) -> can.BusABC | ReplayBus:
    """A python-can bus from configuration, or a :class:`ReplayBus` when ``replay_file`` is set.

    ``bitrate`` 0 leaves the interface's own setting; channels as :func:`bus_kwargs` reads
    them. Raises whatever python-can raises for a bus it cannot open (``can.CanError``,
    ``OSError``, ``ImportError``, ``ValueError``...).
    """
    if replay_file:
        return ReplayBus(replay_file, replay_max_gap_s, can_filters)
    kwargs = bus_kwargs(interface, channel, bitrate)
    if can_filters:
        kwargs["can_filters"] = list(can_filters)
    return can.Bus(**kwargs)


def close_bus(bus: can.BusABC | ReplayBus) -> str:
    """Shut ``bus`` down; never raises. Returns the error text ("" when it closed cleanly).

    A backend may give up half-way on a device that is gone: python-can's slcan writes its
    close command to an unplugged port, raises, and never closes the port. Then the handles it
    is known to hold are closed here, so that a driver reconnecting for days leaks no file
    descriptor.
    """
    try:
        bus.shutdown()
        return ""
    except Exception as exc:
        for name in ("serialPortOrig", "ser", "socket", "_socket"):
            handle = getattr(bus, name, None)
            if handle is not None and callable(getattr(handle, "close", None)):
                with contextlib.suppress(Exception):
                    handle.close()
        return f"{type(exc).__name__}: {exc}"
