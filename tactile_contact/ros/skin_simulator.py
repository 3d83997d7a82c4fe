"""``skin_simulator``: a scripted indentation played as ROBOSKIN module frames on a CAN bus.

For demos and tests without hardware. Every ``period_ms`` the simulator library
(:func:`tactile_contact.sim.simulator.simulator_for_patch`: forward elastic model → sensor model →
8-bit module values with noise → frames A and B) produces one period of every module of the
patch; a sender thread writes the frames to a python-can bus (``interface``/``channel``;
``virtual`` for in-process use, a SocketCAN ``vcan`` to share with other processes). The ground
truth goes out as ``<patch>/contact_truth`` (tactile_contact/ContactState, sensor-data QoS):
total force [N], centre of pressure [m] in the patch frame, contact area [m²] and peak
pressure [Pa] of the indenter, stamped with the time of the period's last frame.

Scenarios (``scenario``), after ``start_delay_s`` without contact (so that a driver learns its
baselines unloaded), repeated every ``cycle_s`` when ``loop``:

- ``press``: ramp to ``force_n`` on the taxel nearest the patch centre, hold, release;
- ``sweep``: ramp at one side of the patch, slide along x across it (through that taxel)
  while holding, release;
- ``idle``: no contact (noise and drift only).

Like the boards, the simulated modules take the host's SET_TRIANG_CFG and SET_BRD_CFG commands
from the bus (a driver's configuration: shift, enable, noLoad;
:meth:`tactile_contact.sim.simulator.SkinSimulator.apply_command`) before each period; the
8-bit values clip at 0 and 255 with their out-of-range bits (docs/layout.md, "Which shift").
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
from rclpy.node import Node

from tactile_contact.canbus.codec import CLASS_ANALOG_SENSOR, CLASS_SKIN
from tactile_contact.canbus.stream import bus_kwargs
from tactile_contact.inverse.summary import Contact
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import PatchLayout, load_layout
from tactile_contact.msg import ContactState
from tactile_contact.ros import common as cm
from tactile_contact.ros import convert
from tactile_contact.ros.skin_driver import default_layout_path
from tactile_contact.sim.scenes import scenario_indentation
from tactile_contact.sim.simulator import Indentation, SimPeriod, simulator_for_patch

WARN_THROTTLE_S = 5.0

# fmt: off
PARAMETERS: tuple[tuple[str, Any, str, dict[str, Any]], ...] = (
    ("layout", "", "patch layout YAML; empty = the package's config/hexagon_patch.yaml", {}),
    ("patch", "", "patch to simulate; empty = the layout's first patch", {}),
    ("patches", cm.STRING_ARRAY_EMPTY, "patches to simulate on this bus, each with the scenario "
     "(the first is `patch`'s role); empty = `patch` alone", {}),
    ("interface", "virtual", "python-can interface the frames are written to", {}),
    ("channel", "skin", "python-can channel", {}),
    ("bitrate", 0, "bit rate for interfaces that set it; 0 = leave as is",
     {"unit": "bit/s", "int_range": (0, 1_000_000)}),
    ("scenario", "sweep", "what the indenter does", {"choices": ("sweep", "press", "idle")}),
    ("indenter", "sphere", "indenter shape", {"choices": ("sphere", "flat")}),
    ("indenter_radius_m", 0.005, "sphere radius or flat punch radius",
     {"unit": "m", "float_range": (0.0005, 0.1)}),
    ("force_n", 2.0, "peak normal force", {"unit": "N", "float_range": (0.0, 100.0)}),
    ("cycle_s", 4.0, "scenario length (ramp 0.5 s, hold, release 0.5 s, rest 0.5 s)",
     {"unit": "s", "float_range": (2.0, 3600.0)}),
    ("loop", True, "repeat the scenario every cycle_s", {}),
    ("start_delay_s", 2.0, "no contact before the first cycle (lets a driver calibrate)",
     {"unit": "s", "float_range": (0.0, 3600.0)}),
    ("period_ms", 50, "module reading period", {"unit": "ms", "int_range": (1, 255)}),
    ("seed", 0, "random seed (noise, rest offsets)", {"int_range": (0, 2**31 - 1)}),
    ("noise_cdc", 2.0, "converter noise (standard deviation)",
     {"unit": "CDC counts", "float_range": (0.0, 1000.0)}),
    ("rest_spread_cdc", 0.0, "rest offsets drawn uniformly in +-this",
     {"unit": "CDC counts", "float_range": (0.0, 10_000.0)}),
    ("drift_cdc_per_s", 0.0, "baseline drift of every channel",
     {"unit": "CDC counts/s", "float_range": (-1000.0, 1000.0)}),
    ("class3_ids", False, "send class 3 ids (0x3xx, older firmware) instead of class 4", {}),
    ("fine_cell_m", 5.0e-4, "pressure cell of the forward simulation (finer: slower, exacter)",
     {"unit": "m", "float_range": (5.0e-5, 2.0e-3)}),
)
# fmt: on


class _Looped:
    """An indentation after ``delay_s``, repeated every ``cycle_s`` (duck-types Indentation)."""

    def __init__(self, indentation: Indentation, cycle_s: float, loop: bool, delay_s: float):
        self.indenter = indentation.indenter
        self._ind, self._cycle, self._loop, self._delay = indentation, cycle_s, loop, delay_s

    def at(self, t: float) -> tuple[float, np.ndarray]:
        if t < self._delay:
            return 0.0, self._ind.at(0.0)[1]
        t -= self._delay
        return self._ind.at(math.fmod(t, self._cycle) if self._loop else t)


class SkinSimulatorNode(Node):
    """The ``skin_simulator`` node (see the module docstring).

    Args:
        node_name: ROS node name.
        **kwargs: passed to ``rclpy.node.Node`` (``context``, ``parameter_overrides``...).

    Raises:
        rclpy.exceptions.InvalidParameterValueException: a parameter is out of range.
        tactile_contact.model.layout.LayoutError, KeyError: bad layout file or patch name.
        can.CanError, OSError, ...: the bus cannot be opened.
    """

    def __init__(self, node_name: str = "skin_simulator", **kwargs: Any) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bus: can.BusABC | None = None
        super().__init__(node_name, **kwargs)
        for name, default, text, options in PARAMETERS:
            cm.declare_parameter(self, name, default, text, **options)
        names = [spec[0] for spec in PARAMETERS]
        cm.log_parameters(self, names)
        p = {n: self.get_parameter(n).value for n in names}
        layout = load_layout(Path(p["layout"]) if p["layout"] else default_layout_path())
        if p["patches"]:
            patches = [layout.patch(name) for name in p["patches"]]
        else:
            patches = [layout.patch(p["patch"]) if p["patch"] else layout.patches[0]]
        self.period_s = p["period_ms"] * 1e-3
        shape = HertzSphere if p["indenter"] == "sphere" else FlatPunch
        self.indenter = shape(p["indenter_radius_m"])
        # Per patch: (layout, simulator, looped indentation); the first also as self.patch,
        # self.sim, self.indentation (one patch, as before).
        self.simulated: list[tuple[PatchLayout, Any, Any]] = []
        for k, pl in enumerate(patches):
            sim = simulator_for_patch(
                pl,
                noise_cdc=p["noise_cdc"],
                rest_spread_cdc=p["rest_spread_cdc"],
                drift_cdc_per_s=p["drift_cdc_per_s"],
                period_s=self.period_s,
                id_class=CLASS_ANALOG_SENSOR if p["class3_ids"] else CLASS_SKIN,
                seed=p["seed"] + k,
                fine_cell=p["fine_cell_m"],
                realtime=True,
            )
            ind = scenario_indentation(p["scenario"], pl, self.indenter, p["force_n"], p["cycle_s"])
            looped = (
                None if ind is None else _Looped(ind, p["cycle_s"], p["loop"], p["start_delay_s"])
            )
            self.simulated.append((pl, sim, looped))
        self.patch, self.sim, self.indentation = self.simulated[0]
        kwargs_bus = bus_kwargs(p["interface"], p["channel"], p["bitrate"])  # (GROUP:PORT too)
        if p["interface"] == "virtual":
            kwargs_bus["preserve_timestamps"] = True  # receivers see the stamps of the truth
        self._bus = can.Bus(**kwargs_bus)
        try:
            self.truth_pubs = {
                pl.name: self.create_publisher(
                    ContactState, f"{pl.name}/contact_truth", cm.SENSOR_QOS
                )
                for pl, _, _ in self.simulated
            }
            self.truth_pub = self.truth_pubs[self.patch.name]
            self.periods_sent = 0
            self.send_errors = 0
            self.commands_applied = 0
            self._thread = threading.Thread(target=self._run, name="skin_sim", daemon=True)
            self._thread.start()
            names = ", ".join(
                f"{pl.name} ({len(pl.modules)} modules)" for pl, _, _ in self.simulated
            )
            self.get_logger().info(
                f"simulating patch {names}, scenario {p['scenario']}, "
                f"on {p['interface']}:{p['channel']}"
            )
        except BaseException:
            # A Ctrl-C here leaves no node for run_node to destroy, and rclpy's SIGINT handler
            # shuts the context down without destroying the nodes it tracks: the sending thread
            # would run on and the bus stay open.
            self._stop_and_close()
            raise

    def _run(self) -> None:
        """Send one period every ``period_s`` of wall time until stopped; never raises."""
        assert self._bus is not None
        mono0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            t = k * self.period_s
            try:
                self._apply_commands()
                for pl, sim, indentation in self.simulated:
                    period = sim.period(indentation, t)
                    # Stamped when sent, as a bus would: if the simulation falls behind its
                    # schedule, latency downstream is still measured from the frames' real
                    # arrival.
                    sent = time.time()
                    for msg in period.messages:
                        msg.timestamp = sent
                        self._bus.send(msg, timeout=0.01)
                    self._publish_truth(period, pl)
                self.periods_sent += 1
            except Exception as exc:  # a full queue or a bus error must not stop the demo
                self.send_errors += 1
                self.get_logger().warning(
                    f"period {k} not sent: {type(exc).__name__}: {exc}",
                    throttle_duration_sec=WARN_THROTTLE_S,
                )
            k += 1
            self._stop.wait(max(0.0, mono0 + k * self.period_s - time.monotonic()))

    def _apply_commands(self) -> None:
        """The host commands received since the last period, applied as the addressed boards
        would (shift, enable, noLoad); other frames are ignored. Never waits."""
        assert self._bus is not None
        while (msg := self._bus.recv(timeout=0.0)) is not None:
            for _, sim, _ in self.simulated:
                if sim.apply_command(msg):
                    self.commands_applied += 1

    def _publish_truth(self, period: SimPeriod, patch: PatchLayout | None = None) -> None:
        patch = patch or self.patch
        tr = period.truth
        el = patch.elastomer
        msg = ContactState(patch=patch.name, solver="truth", solver_success=True)
        msg.header.frame_id = patch.frame_id
        msg.header.stamp = cm.stamp_from_seconds(period.messages[-1].timestamp)
        msg.in_contact = tr.force > 0.0
        msg.total_force = float(tr.force)
        if tr.force > 0.0:
            a = self.indenter.contact_radius(tr.force, el.young, el.poisson)
            msg.center_of_pressure.x = float(tr.center[0])
            msg.center_of_pressure.y = float(tr.center[1])
            msg.contact_area = math.pi * a * a
            profile = "punch" if isinstance(self.indenter, FlatPunch) else "hertz"
            msg.contacts = [convert.contact(Contact(tr.force, tr.center, a, profile))]
            peak = self.indenter.pressure_at_radius(np.array([0.0]), tr.force, el.young, el.poisson)
            msg.peak_pressure = float(np.max(peak)) if np.all(np.isfinite(peak)) else 0.0
        msg.taxels_used = int(patch.valid_mask().sum())
        cm.publish_while_up(self, self.truth_pubs[patch.name], msg)

    def _stop_and_close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def destroy_node(self) -> None:
        self._stop_and_close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run ``skin_simulator`` until Ctrl-C; exit 1 with a message if it cannot start."""
    cm.run_node("skin_simulator", SkinSimulatorNode, args)


if __name__ == "__main__":
    main()
