"""``skin_driver``: ROBOSKIN module frames from a CAN bus → per-patch taxel ΔC messages.

A thin lifecycle adapter over the core library (docs/driver.md has the full description):

- configure: load the patch layout, build the period assembler and per-patch baselines, open
  the bus (python-can from parameters, or a candump log replayed at recorded pace). A bus that
  cannot be opened now (no such interface yet, an adapter not plugged in) is retried with
  exponential backoff from the receive thread and reported in /diagnostics (ERROR, with the
  reason) and in the log once per change of reason; one that can never open (an unknown
  python-can interface, its backend missing, a replay file that cannot be read) is logged and
  reported as FAILURE.
- activate: optionally send the board configuration, start the receive thread; publish
  ``<patch>/taxels`` (TaxelArray, sensor-data QoS) whenever every live module of a patch has
  a new reading or ``max_wait_ms`` has passed (modules without a new reading flagged STALE).
- while configured: ``~/tare`` (std_srvs/Trigger) and ``/diagnostics`` every
  ``diagnostics_period_s``.

With ``autostart`` (default) the node configures and activates itself, so it runs without a
lifecycle manager. The receive thread never raises: bus errors are counted, warned about at
most every few seconds, and ``reconnect_after_errors`` consecutive errors (or one that says
the interface is down or gone) close the bus and reopen it with exponential backoff;
error frames drive the controller state (bus-off is reported, and reopened after the backoff
if no data follows); modules silent past the timeout are reported at once and their taxels
flagged invalid; bad frames are counted per kind by the assembler.

The ROS-free part (bus opening, log replay, gathering module readings into patch messages)
lives in :mod:`tactile_contact.canbus.stream`.
"""

from __future__ import annotations

import array
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.publisher import Publisher
from rclpy.timer import Timer
from std_srvs.srv import Trigger

from tactile_contact.canbus import codec
from tactile_contact.canbus.baseline import BaselineConfig
from tactile_contact.canbus.batcher import Batcher
from tactile_contact.canbus.bus_health import (
    BUS_OFF,
    ERROR_PASSIVE,
    WARNING,
    Backoff,
    interface_gone,
    may_come_up,
)
from tactile_contact.canbus.idle_gate import IdleGate
from tactile_contact.canbus.stream import (
    BusErrorPolicy,
    PatchFrame,
    ReplayBus,
    SkinStream,
    close_bus,
    open_bus,
)
from tactile_contact.model.layout import load_layout
from tactile_contact.msg import TaxelArray, TaxelBatch
from tactile_contact.ros import common as cm
from tactile_contact.ros.cdr import write_taxel_batch
from tactile_contact.ros.driver_parameters import PARAMETERS

WARN_THROTTLE_S = 5.0
#: Subscribers of the per-patch <patch>/taxels are counted this often [s].
SUBSCRIBERS_RECOUNT_S = 0.2
BATCHES_TOPIC = "taxel_batches"
#: State changes are published on /diagnostics at once, but at most this often [s].
EVENT_DIAG_MIN_S = 0.1
SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE


def default_layout_path() -> Path:
    """The package's ``config/hexagon_patch.yaml`` (installed share, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory("tactile_contact")) / "config/hexagon_patch.yaml"
        if path.is_file():
            return path
    except Exception:  # not installed through ament: fall back to the source tree
        pass
    return Path(__file__).resolve().parents[2] / "config" / "hexagon_patch.yaml"


def _stamp_s(stamp: float) -> float:
    """A reading's CAN receive time [s] as a message stamp can carry it: 0 for a negative
    one, the host's clock for one not finite or past a builtin_interfaces/Time's int32
    seconds (one such frame made the whole batch unwritable: every patch of it lost)."""
    if 0.0 <= stamp < 2.0**31:
        return stamp
    if stamp < 0.0:
        return 0.0
    return min(time.time(), 2.0**31 - 1.0)


@dataclass
class _Link:
    """One CAN bus the driver serves: its own stream, error policy, backoff and receive thread
    (module ids repeat from bus to bus; a bus that fails leaves the others alone)."""

    name: str  # the layout's bus ("" for a layout's only, unnamed bus)
    channel: str  # its python-can channel
    stream: SkinStream
    policy: BusErrorPolicy
    backoff: Backoff
    bus: Any = None  # the open python-can bus (None while closed)
    next_attempt: float = 0.0  # monotonic time of the next reopen attempt [s]
    problem: str = ""  # why the bus is closed ("" while open)
    opened: bool = False  # the bus was open at least once
    config_sent: bool = False
    last_frame: float = -1.0  # monotonic time of the last frame received (-1: none yet)
    finished_logged: bool = False
    thread: threading.Thread | None = None


class SkinDriver(LifecycleNode):
    """The ``skin_driver`` lifecycle node (see the module docstring).

    Args:
        node_name: ROS node name.
        **kwargs: passed to ``rclpy.lifecycle.LifecycleNode`` (``context``,
            ``parameter_overrides``, ``namespace``...).

    Raises:
        rclpy.exceptions.InvalidParameterValueException: a parameter override is out of range.
    """

    def __init__(self, node_name: str = "skin_driver", **kwargs: Any) -> None:
        # State first: a constructor that fails on a bad parameter still gets destroy_node().
        self._lock = threading.Lock()  # the streams and error policies (any receive thread)
        self._batch_lock = threading.Lock()  # the batcher and the publishers' use of it
        self._diag_lock = threading.Lock()  # the publisher is destroyed under it, used under it
        self._stop = threading.Event()
        self._links: list[_Link] = []  # the buses served, in the order of the bus parameters
        self._batch_bus = ""  # the TaxelBatch's bus field (one bus served)
        self._patch_bus: dict[str, str] = {}  # patch → its bus (several buses served)
        self._pubs: dict[str, Publisher] = {}
        self._batch_pub: Publisher | None = None
        self._batcher: Batcher | None = None
        self._gate: IdleGate | None = None  # which readings the batches carry (idle_every)
        self._subscribed: dict[str, bool] = {}  # patch → <patch>/taxels has a subscriber
        self._ids_u16_cache: dict[str, np.ndarray] = {}
        self._published_patch_messages = 0  # <patch>/taxels sent (only while subscribed)
        self._subscribed_at = -1.0  # monotonic time they were counted
        self._diag_pub: Publisher | None = None
        self._diag_timer: Timer | None = None
        self._tare_srv: Any = None
        self._params: dict[str, Any] = {}
        self._ids_arrays: dict[str, array.array] = {}  # patch → its taxel ids, as sent
        self._event_log: dict[str, tuple[float, int]] = {}  # kind → (last logged, unsaid)
        self._warned: dict[str, float] = {}  # kind → monotonic time last logged
        self._diag_due = False  # a state change awaits its /diagnostics
        self._diag_last = -1.0  # monotonic time of the last /diagnostics
        # While unconfigured after a failed configure: its /diagnostics publisher and timer.
        self._failure: tuple[Publisher, Timer] | None = None
        super().__init__(node_name, **kwargs)
        for name, default, text, options in PARAMETERS:
            cm.declare_parameter(self, name, default, text, **options)
        self._names = [spec[0] for spec in PARAMETERS]
        cm.log_parameters(self, self._names)
        try:
            if self._params_value("autostart") and self.trigger_configure() == SUCCESS:
                self.trigger_activate()
        except BaseException:
            # A Ctrl-C here leaves no node for run_node to destroy, and rclpy's SIGINT handler
            # shuts the context down without destroying the nodes it tracks: the receive thread
            # would run on and the bus stay open.
            self._close()
            raise

    def _params_value(self, name: str) -> Any:
        return self.get_parameter(name).value

    # -- lifecycle ------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        failed_before = self._failure is not None
        self._stop_failure_report()
        try:
            result = self._configure()
            if failed_before and self._diag_pub is not None:
                # (the ERROR said before is answered, not left to go stale in a monitor)
                out = DiagnosticArray()
                out.header.stamp = self.get_clock().now().to_msg()
                out.status = [
                    cm.diagnostic_status(
                        f"{self.get_name()}: configure", cm.OK, "configured", {}, self.get_name()
                    )
                ]
                cm.publish_while_up(self, self._diag_pub, out)
            return result
        except Exception as exc:  # a transition must end in FAILURE with a reason, not ERROR
            text = f"configure failed: {type(exc).__name__}: {exc}"
            self.get_logger().error(text)
            self._close()
            self._report_failure(text)
            return FAILURE

    def _report_failure(self, text: str) -> None:
        """Say on /diagnostics (ERROR, every diagnostics period until the next configure)
        why the driver is unconfigured. Why: configure creates the driver's diagnostics, so a
        driver whose configure failed (a layout path mistyped, contact_off_counts above
        contact_on_counts after a parameter set) vanished from /diagnostics and a monitor saw
        nothing wrong."""
        status = cm.diagnostic_status(
            f"{self.get_name()}: configure",
            cm.ERROR,
            f"{text} (unconfigured: fix the parameter and configure again)",
            {},
            self.get_name(),
        )

        def publish() -> None:
            if self._failure is not None:
                out = DiagnosticArray()
                out.header.stamp = self.get_clock().now().to_msg()
                out.status = [status]
                cm.publish_while_up(self, self._failure[0], out)

        period = self._params_value("diagnostics_period_s")
        pub = self.create_publisher(DiagnosticArray, "/diagnostics", cm.DIAGNOSTICS_QOS)
        timer = self.create_timer(period if period > 0 else 1.0, publish)
        self._failure = (pub, timer)
        publish()

    def _stop_failure_report(self) -> None:
        failure, self._failure = self._failure, None
        if failure is not None:
            self.destroy_timer(failure[1])
            self.destroy_publisher(failure[0])

    def _served(self, layout_path: Path, layout: Any) -> list[tuple[str, str]]:
        """The buses this driver serves and their channels, from ``bus``, ``buses`` and
        ``channels`` (ValueError naming the layout and the parameter otherwise)."""
        p = self._params
        buses = layout.buses()
        if p["bus"] and p["buses"]:
            raise ValueError("set bus (one bus) or buses (several), not both")
        served = list(p["buses"]) or ([p["bus"]] if p["bus"] else [])
        if not served:
            if len(buses) > 1:
                raise ValueError(
                    f"{layout_path}: patches on {len(buses)} buses {list(buses)}: set this "
                    "driver's bus parameter (one bus) or buses (several; the launch file "
                    "starts one driver per bus, or one for all with drivers:=one)"
                )
            served = [buses[0]]
        unknown = [b for b in served if b not in buses]
        if unknown or len(set(served)) < len(served):
            raise ValueError(
                f"{layout_path}: bus(es) {unknown or served} unknown or repeated (buses: {buses})"
            )
        if p["replay_file"] and len(served) > 1:
            raise ValueError("replay_file replays one bus: serve one bus (the bus parameter)")
        channels = list(p["channels"])
        if channels and len(channels) != len(served):
            raise ValueError(f"{len(channels)} channels for {len(served)} buses {served}")
        if not channels:
            # (socketcan names an interface after its bus: can0, can1, ...)
            channels = [p["channel"]] if len(served) == 1 else served
        return list(zip(served, channels, strict=True))

    def _configure(self) -> TransitionCallbackReturn:
        p = {n: self._params_value(n) for n in self._names}
        self._params = p
        layout_path = Path(p["layout"]) if p["layout"] else default_layout_path()
        layout = load_layout(layout_path)  # LayoutError names file, key and problem
        served = self._served(layout_path, layout)
        names = [b for b, _ in served]
        on_bus = [pl.name for pl in layout.patches if pl.bus in names]
        wanted = p["patches"] or on_bus
        patches = [layout.patch(name) for name in wanted]  # KeyError lists the known names
        elsewhere = [pl.name for pl in patches if pl.name not in on_bus]
        if elsewhere:
            raise ValueError(f"{layout_path}: patches {elsewhere} are not on bus(es) {names}")
        config = BaselineConfig(
            calibration_samples=p["calibration_samples"],
            drift_time_constant_s=p["drift_time_constant_s"],
            contact_on_counts=p["contact_on_counts"],
            contact_off_counts=p["contact_off_counts"],
            release_s=p["release_s"],
            release_fraction=p["release_fraction"],
            onset_time_constant_s=p["onset_time_constant_s"],
            freeze_radius_m=p["freeze_radius_m"],
            module_freeze=p["module_freeze"],
            max_freeze_s=p["max_freeze_s"] or None,
            stuck_timeout_s=p["stuck_timeout_s"] or None,
            dead_timeout_s=p["dead_timeout_s"],
            tare_window=p["tare_window"],
        )
        classes = (
            (codec.CLASS_SKIN, codec.CLASS_ANALOG_SENSOR)
            if p["accept_class3"]
            else (codec.CLASS_SKIN,)
        )
        self._links = []
        for name, channel in served:
            mine = [pl for pl in patches if pl.bus == name]
            if not mine:  # (the patches parameter left none of this bus)
                continue
            stream = SkinStream(
                mine,
                id_classes=classes,
                baseline=config,
                farad_per_count=p["farad_per_count"] or None,
                max_wait_s=p["max_wait_ms"] * 1e-3,
                module_timeout_s=p["module_timeout_ms"] * 1e-3,
                period_s=p["period_ms"] * 1e-3,
                pair_window_s=p["pair_window_ms"] * 1e-3,
                duplicate_window_s=p["duplicate_window_ms"] * 1e-3,
                strict_status=p["strict_status"],
            )
            policy = BusErrorPolicy(p["reconnect_after_errors"])
            backoff = Backoff(p["reconnect_interval_s"], p["reconnect_max_interval_s"])
            self._links.append(_Link(name, channel, stream, policy, backoff))
        # (the link's name, not the bus parameter: a driver given buses:=[x] names x too)
        self._batch_bus = self._links[0].name if len(self._links) == 1 else ""
        self._patch_bus = {pl.name: pl.bus for pl in patches} if len(self._links) > 1 else {}
        for link in self._links:
            try:
                link.bus = open_bus(**self._bus_config(link))
                link.opened, link.problem = True, ""
            except Exception as exc:  # python-can raises many types for a bus it cannot open
                text = f"cannot open CAN bus {self._bus_name(link)}: {type(exc).__name__}: {exc}"
                if not may_come_up(exc, p["replay_file"]):
                    self.get_logger().error(text)
                    self._close()
                    return FAILURE
                link.problem = text
                link.next_attempt = time.monotonic() + link.backoff.wait_s
                self.get_logger().error(
                    f"{text}; retrying, first in {link.backoff.wait_s:g} s, then up to every "
                    f"{p['reconnect_max_interval_s']:g} s (state in /diagnostics)"
                )
        for pl in patches:
            self._pubs[pl.name] = self.create_lifecycle_publisher(
                TaxelArray, f"{pl.name}/taxels", cm.SENSOR_QOS
            )
        self._batch_pub = self.create_lifecycle_publisher(TaxelBatch, BATCHES_TOPIC, cm.SENSOR_QOS)
        self._batcher = Batcher(
            [pl.name for pl in patches],
            p["batch_window_ms"] * 1e-3,
            {link.name: [pl.name for pl in patches if pl.bus == link.name] for link in self._links},
        )
        self._gate = IdleGate(
            p["idle_every"],
            p["idle_counts"],
            {
                pl.name: (p["farad_per_count"] or pl.sensor.farad_per_count) * 2.0**pl.sensor.shift
                for pl in patches
            },
        )
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", cm.DIAGNOSTICS_QOS)
        self._diag_timer = self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics)
        self._tare_srv = self.create_service(Trigger, "~/tare", self._on_tare)
        self.get_logger().info(
            f"configured: layout {layout_path}, patches {[pl.name for pl in patches]}, "
            f"{sum(len(pl.modules) for pl in patches)} modules, "
            + ", ".join(f"bus {self._bus_name(link)}" for link in self._links)
        )
        return SUCCESS

    def _bus_name(self, link: _Link) -> str:
        p = self._params
        if p["replay_file"]:
            return f"replay of {p['replay_file']}"
        return f"{p['interface']}:{link.channel}"

    def _bus_config(self, link: _Link) -> dict[str, Any]:
        """Keyword arguments of :func:`open_bus` from the parameters."""
        p = self._params
        return {
            "interface": p["interface"],
            "channel": link.channel,
            "bitrate": p["bitrate"],
            "replay_file": p["replay_file"],
            "replay_max_gap_s": p["replay_max_gap_s"],
            "can_filters": link.stream.can_filters() if p["bus_filter"] else None,
        }

    def _open_bus(self, link: _Link) -> can.BusABC | Any | None:
        """The bus reopened, or None; a new reason for failing is logged (once per reason)."""
        try:
            return open_bus(**self._bus_config(link))
        except Exception as exc:  # python-can raises many types for a bus it cannot open
            text = f"cannot open CAN bus {self._bus_name(link)}: {type(exc).__name__}: {exc}"
            if text != link.problem:
                self.get_logger().error(f"{text}; retrying (state in /diagnostics)")
            link.problem = text
            return None

    @property
    def bus_opened(self) -> bool:
        """Whether every bus served was open at least once since configure."""
        return bool(self._links) and all(link.opened for link in self._links)

    def published(self) -> dict[str, int]:
        """Taxel messages published per patch since configure."""
        with self._lock:
            return {name: n for link in self._links for name, n, _ in link.stream.publications()}

    def bus_problem(self) -> str:
        """Why a bus is closed now ("" while every one is open)."""
        return "; ".join(link.problem for link in self._links if link.bus is None and link.problem)

    def summary(self) -> list[str]:
        """Lines for the end of a run: each bus (frames, rejected) and its patches' messages."""
        if not self._links:
            return [f"bus {self._params.get('channel', '?')}: not configured"]
        lines = []
        for link in self._links:
            with self._lock:
                c = link.stream.assembler.counters
                frames, rejected = c.frames, c.rejected
                states = link.stream.publications()
            head = f"bus {self._bus_name(link)}: {frames} CAN frames, {rejected} rejected"
            if not link.opened:
                head += f"; never opened ({link.problem})"
            elif link.bus is None:
                head += f"; closed now ({link.problem})"
            lines += [head] + [
                f"{name}: {n} taxel messages published"
                + (f" ({stale} with silent or late modules)" if stale else "")
                for name, n, stale in states
            ]
        return lines

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        # Publishers first: the receive thread may publish its first message at once.
        result = super().on_activate(state)
        if result != SUCCESS:
            return result
        try:
            self._stop.clear()
            for link in self._links:  # (every bus drained before any receive thread runs)
                if self._params["send_config"] and link.bus is not None:
                    self._send_config(link)
                self._drain(link)
            replay = any(isinstance(link.bus, ReplayBus) for link in self._links)
            with self._batch_lock:  # a batch begun before the pause: its readings are old
                held = len(self._batcher.take()) if self._batcher and not replay else 0
            if held:
                self.get_logger().info(f"dropped a batch of {held} readings made before the pause")
            for link in self._links:
                link.finished_logged = False
                link.thread = threading.Thread(
                    target=self._receive_loop,
                    args=(link,),
                    name=f"skin_rx_{link.name}" if link.name else "skin_rx",
                    daemon=True,
                )
                link.thread.start()
        except Exception as exc:
            self.get_logger().error(f"activate failed: {type(exc).__name__}: {exc}")
            self._stop_thread()
            super().on_deactivate(state)
            return FAILURE
        self.get_logger().info("active: publishing")
        return SUCCESS

    def _drain(self, link: _Link) -> None:
        """Drop frames queued while inactive (old data must not come out with old stamps)."""
        if isinstance(link.bus, ReplayBus):
            return
        dropped = 0
        while link.bus is not None and dropped < 1_000_000 and link.bus.recv(0.0) is not None:
            dropped += 1  # (a bus down now has nothing queued; its stream's readings are old)
        link.stream.assembler.reset()
        with self._lock:  # readings made before the pause, waiting for their patch's message
            readings = link.stream.drop_pending()
        if dropped or readings:
            self.get_logger().info(
                f"dropped {dropped} frames queued while inactive on {self._bus_name(link)}"
                + (f" and {readings} readings made before it" if readings else "")
            )

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_thread()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        self._stop_failure_report()  # (finalized: "configure again" no longer applies)
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        self._stop_failure_report()
        return SUCCESS

    def _stop_thread(self) -> None:
        self._stop.set()
        for link in self._links:
            if link.thread is not None:
                link.thread.join(timeout=5.0)
                link.thread = None

    def _close(self) -> None:
        """Stop the threads, close the buses, destroy what configure created."""
        self._stop_thread()
        for link in self._links:
            bus, link.bus = link.bus, None
            if bus is not None:
                error = close_bus(bus)
                if error:
                    self.get_logger().warning(f"closing the bus {self._bus_name(link)}: {error}")
        for pub in self._pubs.values():
            self.destroy_lifecycle_publisher(pub)
        self._pubs.clear()
        if self._batch_pub is not None:
            self.destroy_lifecycle_publisher(self._batch_pub)
            self._batch_pub = None
        self._ids_u16_cache.clear()  # (a new configuration may load another layout)
        self._ids_arrays.clear()
        if self._diag_timer is not None:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = None
        with self._diag_lock:
            diag_pub, self._diag_pub = self._diag_pub, None
        if diag_pub is not None:
            self.destroy_publisher(diag_pub)
        if self._tare_srv is not None:
            self.destroy_service(self._tare_srv)
            self._tare_srv = None

    def destroy_node(self) -> None:
        self._close()
        self._stop_failure_report()
        super().destroy_node()

    # -- bus ------------------------------------------------------------------------------
    def _send_config(self, link: _Link, at_reopen: bool = False) -> None:
        """SET_BRD_CFG, SET_TRIANG_CFG (all triangles of each board) then SET_TXMODE start;
        ``config_sent`` once every board's went out. A send that fails raises (activation
        fails, as it always did) or, ``at_reopen``, is logged and tried at the next reopen."""
        p = self._params
        for board, (first, last, shift, no_load) in sorted(link.stream.board_ranges().items()):
            try:
                for cmd in (
                    codec.set_board_config(board, p["skin_type"], p["period_ms"], no_load),
                    codec.set_triangle_config(board, first, last, shift, True, p["cdc_offset"]),
                    codec.set_tx_mode(board, True),
                ):
                    link.bus.send(cmd.to_message(), timeout=0.1)
            except (can.CanError, OSError) as exc:
                if not at_reopen:
                    raise
                # (boards that wait for SET_TXMODE stay silent until it is sent)
                self.get_logger().error(
                    f"CAN bus {self._bus_name(link)}: sending board {board}'s configuration "
                    f"failed ({type(exc).__name__}: {exc}); tried again when the bus reopens"
                )
                return
            self.get_logger().info(
                f"sent configuration to board {board} (triangles {first}..{last})"
                + (f" on bus {link.name}" if len(self._links) > 1 else "")
            )
        link.config_sent = True

    def _receive_loop(self, link: _Link) -> None:
        """Receive, decode and publish until stopped; never raises."""
        log = self.get_logger()
        while not self._stop.is_set():
            try:
                self._receive_step(link)
            except Exception as exc:  # the thread must outlive any bug: count, say, go on
                with self._lock:
                    link.policy.internal_errors += 1
                log.error(
                    f"receive loop: {type(exc).__name__}: {exc}",
                    throttle_duration_sec=WARN_THROTTLE_S,
                )
                self._stop.wait(0.01)

    def _receive_step(self, link: _Link) -> None:
        """One receive on ``link``'s bus (or one reopen attempt) and what it completes."""
        p, stream, policy = self._params, link.stream, link.policy
        log = self.get_logger()
        several = len(self._links) > 1
        bus = link.bus
        if bus is None:
            self._reopen(link)
            if link.bus is None:
                # Readings completed before the bus went down, modules falling silent: out
                # now, not after the reopen (up to the backoff's 10 s, with old stamps).
                with self._lock:
                    out = stream.poll(time.monotonic())
                    events, stream.events = stream.events, []
                self._publish(out)  # (and a batch due)
                self._report_events(link, events, several)
            return
        timeout = p["receive_timeout_s"]
        batcher = self._batcher
        if batcher is not None and batcher.pending:
            timeout = min(timeout, max(0.0, batcher.due - time.monotonic()))
        try:
            msg = bus.recv(timeout)
        except Exception as exc:  # the backend's: python-can's interfaces raise many types
            # OSError: a socketcan interface down (ENETDOWN) or removed (ENODEV); CanError:
            # python-can's own (a closed bus, an adapter unplugged); ValueError: a backend
            # that failed to parse what the adapter sent; others (a vendor library's own
            # errors, a bug in a plugin interface) count toward a reopen the same way, which
            # gives the backend a fresh handle, instead of looping on the same error.
            with self._lock:
                reconnect = policy.error(exc)
            if self._due(f"bus error {link.name}"):
                log.warning(
                    f"CAN bus {self._bus_name(link)} error ({policy.errors} so far): "
                    f"{type(exc).__name__}: {exc}"
                )
            gone = interface_gone(exc)
            if reconnect or gone:
                # A socketcan socket reports ENETDOWN / ENODEV once, then waits quietly: the
                # bus is reopened at once, not after a run of errors that would never come.
                why = (
                    f"interface {gone}"
                    if gone
                    else f"{p['reconnect_after_errors']} consecutive bus errors"
                )
                self._drop_bus(link, why)
            else:
                self._stop.wait(min(p["receive_timeout_s"], 0.01))
            return
        policy.ok()
        if msg is not None:
            link.last_frame = time.monotonic()
            if link.backoff.failures and not msg.is_error_frame:
                link.backoff.reset()  # frames flow: the next failure starts short again
        if msg is None and getattr(bus, "finished", False) and not link.finished_logged:
            log.info(f"replay of {p['replay_file']} finished")
            link.finished_logged = True
        with self._lock:
            now = time.monotonic()
            out = stream.feed(msg, now) if msg is not None else []
            out += stream.poll(now)
            events, stream.events = stream.events, []
            bus_off = stream.controller.bus_off_since
        self._publish(out)
        if stream.last_error is not None:
            # (checked here: rclpy's own throttle inspects the call stack on every call)
            if self._due(f"rejected {link.name}"):
                on = f" on bus {link.name}" if several else ""
                log.warning(f"rejected frame{on}: {stream.last_error} (frames counted by kind)")
            stream.last_error = None
        self._report_events(link, events, several)
        # Bus-off with no data since: reopening re-initialises the controller of most adapters
        # (socketcan needs `ip link set can0 type can restart-ms 100` to restart by itself).
        if bus_off is not None and time.monotonic() - bus_off >= link.backoff.wait_s:
            link.backoff.failed()  # the next reopen for a bus-off waits longer
            self._drop_bus(link, "controller bus-off with no data since")

    def _report_events(self, link: _Link, events: list, several: bool) -> None:
        """Log a stream's events (modules silent, back, …) and publish diagnostics soon."""
        if events:
            if several:
                events = [
                    (lv, f"{link.name} {kind}", f"bus {link.name}: {text}")
                    for lv, kind, text in events
                ]
            self._log_events(events)
            self._diag_due = True
        if self._diag_due and time.monotonic() - self._diag_last >= EVENT_DIAG_MIN_S:
            self._diag_due = False
            self._publish_diagnostics(window=False)

    def _due(self, kind: str) -> bool:
        """True at most once per WARN_THROTTLE_S per kind (for the receive thread's logs)."""
        now = time.monotonic()
        if now - self._warned.get(kind, -WARN_THROTTLE_S) < WARN_THROTTLE_S:
            return False
        self._warned[kind] = now
        return True

    def _log_events(self, events: list[tuple[int, str, str]]) -> None:
        """Log state changes; a kind that repeats (a flood of error frames) at most once per
        WARN_THROTTLE_S, with the number left unsaid."""
        log = self.get_logger()
        now = time.monotonic()
        for level, kind, text in events:
            last, quiet = self._event_log.get(kind, (-WARN_THROTTLE_S, 0))
            if now - last < WARN_THROTTLE_S:
                self._event_log[kind] = (last, quiet + 1)
                continue
            if quiet:
                text += f" ({quiet} more changes of this kind in the last {now - last:.0f} s)"
            self._event_log[kind] = (now, 0)
            if level >= cm.ERROR:  # (one severity per rclpy logging call site)
                log.error(text)
            else:
                log.info(text)

    def _drop_bus(self, link: _Link, why: str) -> None:
        """Close ``link``'s bus and schedule a reopen after the backoff wait."""
        bus, link.bus = link.bus, None
        wait = link.backoff.wait_s
        link.next_attempt = time.monotonic() + wait
        link.problem = why
        self.get_logger().warning(
            f"{why}: closing the bus {self._bus_name(link)}, reopening in {wait:.2f} s"
        )
        if bus is not None:
            error = close_bus(bus)
            if error and self._due(f"close {link.name}"):
                self.get_logger().warning(f"closing the failed bus: {error}")
        self._publish_diagnostics(window=False)

    def _reopen(self, link: _Link) -> None:
        """Wait for the next attempt, then try to reopen the bus (backoff on failure)."""
        delay = link.next_attempt - time.monotonic()
        if delay > 0:
            self._stop.wait(min(delay, 0.1))
            return
        with self._lock:
            link.policy.reconnect_attempts += 1
        bus = self._open_bus(link)
        if bus is None:
            link.backoff.failed()
            link.next_attempt = time.monotonic() + link.backoff.wait_s
            return
        link.bus = bus
        first = not link.opened
        link.opened, link.problem = True, ""
        with self._lock:
            link.policy.reconnects += 1
            link.stream.assembler.reset()  # half periods from before the gap
            controller = link.stream.controller
            if controller.bus_off_since is not None:  # still bus-off: wait from now
                controller.bus_off_since = time.monotonic()
            else:
                link.backoff.reset()
        self.get_logger().info(
            f"{'opened' if first else 'reconnected to'} CAN bus {self._bus_name(link)}"
        )
        if self._params["send_config"] and not link.config_sent:
            self._send_config(link, at_reopen=True)
        self._publish_diagnostics(window=False)

    def _publish(self, frames: list[PatchFrame]) -> None:
        """The readings completed: into the batch (published when due), and each patch's
        TaxelArray while something subscribes to its topic."""
        if not self.context.ok():
            return
        with self._batch_lock:  # (each bus's receive thread publishes)
            self._publish_frames(frames)

    def _publish_frames(self, frames: list[PatchFrame]) -> None:
        now = time.monotonic()
        if now - self._subscribed_at > SUBSCRIBERS_RECOUNT_S:
            # (an rmw query per topic: counted a few times a second, not per frame)
            self._subscribed = {n: p.get_subscription_count() > 0 for n, p in self._pubs.items()}
            self._subscribed_at = now
        for f in frames:
            if self._subscribed.get(f.patch):
                self._publish_patch(f)
                self._published_patch_messages += 1
        batcher = self._batcher
        if batcher is None or self._batch_pub is None:
            return
        for f in frames:
            if f.patch in batcher.names:
                for batch in batcher.add(f, now):
                    self._publish_batch(batch)
        if batcher.pending and now >= batcher.due:
            self._publish_batch(batcher.take())

    def _publish_batch(self, frames: list[PatchFrame]) -> None:
        """One TaxelBatch of ``frames`` (serialized here: rclpy's message objects cost more
        than the rest of the publication, docs/bench/load.md)."""
        pub = self._batch_pub
        if pub is None:
            return
        gate = self._gate
        if gate is not None and gate.every > 1:
            frames = [f for f in frames if gate.passes(f)]
        if not frames:
            return
        if self._params["stamp_source"] == "can":
            stamps = [round(_stamp_s(f.stamp) * 1e9) for f in frames]
        else:
            stamps = [self.get_clock().now().nanoseconds] * len(frames)
        bus = self._batch_bus
        if self._patch_bus:
            # the buses of this batch's patches, as the links are listed: a worker subscribes
            # to the batches of its own buses (a content filter on this field)
            mine = {self._patch_bus.get(f.patch, "") for f in frames}
            bus = ",".join(link.name for link in self._links if link.name in mine)
        data = write_taxel_batch(
            time.time_ns(),
            bus,
            [f.patch for f in frames],
            [f.frame_id for f in frames],
            stamps,
            [self._ids_u16(f) for f in frames],
            [f.delta_c for f in frames],
            [f.raw for f in frames],
            [f.status for f in frames],
        )
        pub.publish(data)

    def _ids_u16(self, f: PatchFrame) -> np.ndarray:
        """The patch's taxel ids as uint16 (made once per patch: a list converted per frame
        cost more than the rest of the batch)."""
        ids = self._ids_u16_cache.get(f.patch)
        if ids is None or len(ids) != len(f.taxel_ids):
            ids = self._ids_u16_cache[f.patch] = np.asarray(f.taxel_ids, dtype=np.uint16)
        return ids

    def _publish_patch(self, f: PatchFrame) -> None:
        pub = self._pubs.get(f.patch)
        if pub is None:
            return
        msg = TaxelArray(patch=f.patch)
        msg.header.frame_id = f.frame_id
        if self._params["stamp_source"] == "can":
            msg.header.stamp = cm.stamp_from_seconds(_stamp_s(f.stamp))
        else:
            msg.header.stamp = self.get_clock().now().to_msg()
        # array.array fields: the message setters check a list or a numpy array element by
        # element in Python (measured: a fifth of the driver's time at 24 patches).
        ids = self._ids_arrays.get(f.patch)
        if ids is None:
            ids = self._ids_arrays[f.patch] = array.array("H", f.taxel_ids)
        msg.taxel_ids = ids
        delta_c = array.array("f")
        delta_c.frombytes(np.ascontiguousarray(f.delta_c, dtype=np.float32).tobytes())
        msg.delta_c = delta_c
        msg.raw = array.array("B", f.raw)
        msg.status = array.array("B", f.status)
        pub.publish(msg)

    # -- services and diagnostics ---------------------------------------------------------
    def _on_tare(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if not self._links:
            response.success, response.message = False, "not configured"
            return response
        done: list[str] = []
        missing: list[str] = []
        with self._lock:
            for link in self._links:
                d, m = link.stream.tare()
                done += d
                missing += m
        # (the idle gate sends each patch's first tared reading: they carry the tare count)
        response.success = not missing
        response.message = f"tared patches {done}" + (
            f"; modules not heard yet (their baselines left as they were) in {missing}"
            if missing
            else ""
        )
        self.get_logger().info(f"tare: {response.message}")
        return response

    def _publish_diagnostics(self, window: bool = True) -> None:
        """Publish /diagnostics (periodically, and at once on a state change with ``window``
        False, which leaves the rate windows alone). Safe from any thread."""
        with self._diag_lock:
            pub = self._diag_pub
            if not self._links or pub is None or not self.context.ok():
                return
            prefix = self.get_name()
            several = len(self._links) > 1
            out = DiagnosticArray()
            out.header.stamp = self.get_clock().now().to_msg()
            for link in self._links:
                status, statuses = self._link_diagnostics(link, window)
                if several:
                    status.name += f" {link.name}"
                out.status.append(status)
                out.status += [
                    cm.diagnostic_status(
                        f"{prefix}: {s.name}"
                        + (f" {link.name}" if several and s.name == "frames" else ""),
                        s.level,
                        s.message,
                        s.values,
                        s.hardware_id,
                    )
                    for s in statuses
                ]
            pub.publish(out)
            self._diag_last = time.monotonic()

    def _link_diagnostics(self, link: _Link, window: bool) -> tuple[Any, list[Any]]:
        """``link``'s bus status and its stream's (frames, patches, modules)."""
        with self._lock:
            statuses = link.stream.diagnostics(time.monotonic(), window=window)
            bus_values = link.policy.values(window=window)
            controller = link.stream.controller.values()
            state = link.stream.controller.state
        name = f"{self.get_name()}: CAN bus"
        bus_open = link.bus is not None
        finished = bus_open and getattr(link.bus, "finished", False)
        level = cm.OK if bus_open else cm.ERROR
        if finished:
            message = "replay finished"
        elif bus_open:
            message = "open"
        else:
            wait = max(0.0, link.next_attempt - time.monotonic())
            tries = bus_values["reconnect_attempts"]
            message = f"closed, reopening in {wait:.1f} s ({tries} attempts so far)"
            if link.problem:
                message += f": {link.problem}"
        quiet = time.monotonic() - link.last_frame if link.last_frame >= 0 else -1.0
        timeout = self._params.get("module_timeout_ms", 500.0) * 1e-3
        if bus_open and not finished and quiet > timeout:
            level, message = max(level, cm.WARN), message + f", no frames for {quiet:.1f} s"
        if state == BUS_OFF:
            level, message = cm.ERROR, message + ", controller bus-off"
        elif state in (ERROR_PASSIVE, WARNING):
            level, message = max(level, cm.WARN), message + f", controller {state}"
        values = {
            "bus": self._bus_name(link),
            "state": self._state_label(),
            **bus_values,
            **controller,
            "next_reconnect_wait_s": link.backoff.wait_s,
            "bus_problem": "" if bus_open else link.problem,
            "bus_ever_open": link.opened,
            "seconds_since_last_frame": quiet,
            # (the driver's, over all its buses) idle readings the batches left out
            "idle_readings_held": self._gate.held if self._gate is not None else 0,
        }
        if bus_values["bus_errors_in_window"]:
            level = max(level, cm.WARN)
            message += f", {bus_values['bus_errors_in_window']} bus errors"
        hardware = self._bus_name(link)
        return cm.diagnostic_status(name, level, message, values, hardware), statuses

    def state_label(self) -> str:
        """The lifecycle state ("unconfigured", "inactive", "active", ...)."""
        return self._state_label()

    def _state_label(self) -> str:
        # rclpy's LifecycleNode offers the state only through its ~/get_state service (a call
        # to itself from a callback would deadlock a single-threaded executor); its state
        # machine is the one truth, so read it rather than mirror every transition's outcome.
        return self._state_machine.current_state[1]


def main(args: list[str] | None = None) -> None:
    """Run ``skin_driver`` until Ctrl-C; exit 1 with a message if it cannot start."""
    cm.run_node("skin_driver", SkinDriver, args)


if __name__ == "__main__":
    main()
