"""The real ``skin_driver`` node on python-can buses fed by the skin simulator.

Each test runs the node in-process (python-can's ``virtual`` bus is in-process only) with a
listener node on one executor, sends simulated module frames from another thread and checks
what comes out on ``hexagon/taxels`` and ``/diagnostics``. The frames come from
:class:`tactile_contact.simulator.SkinSimulator` driven by a smooth analytic bump
(:class:`BumpModel`): the driver is under test here, not the elastic physics, and the bump gives
known ΔC on every taxel without building the fine forward model. Periods are 20 ms.
"""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from tactile_contact.codec import CLASS_SKIN
from tactile_contact.layout import PatchLayout, load_layout
from tactile_contact.sensor import SensorParams, value_count_farad
from tactile_contact.simulator import Indentation, PeriodTruth, SimPeriod, SkinSimulator

pytestmark = pytest.mark.ros

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"
PERIOD_S = 0.02
N_MODULES = 6


class BumpModel:
    """Compression [m] = force · 150 µm/N · exp(−r²/2σ²), σ = 4 mm, r from the centre."""

    def __init__(self, channel_xy: np.ndarray) -> None:
        self.xy = channel_xy

    def compression(self, indenter: Any, force: float, center_xy: Any) -> np.ndarray:
        r2 = np.sum((self.xy - np.asarray(center_xy)) ** 2, axis=1)
        return force * 150e-6 * np.exp(-r2 / (2 * 0.004**2))


def patch() -> PatchLayout:
    return load_layout(LAYOUT).patch("hexagon")


def simulator(noise_cdc: float = 0.0, seed: int = 0) -> SkinSimulator:
    pl = patch()
    el, se = pl.elastomer, pl.sensor
    sensor = SensorParams(
        thickness=el.thickness,
        epsilon_r=se.epsilon_r,
        area=se.area,
        farad_per_count=se.farad_per_count,
        shift=se.shift,
        no_load=se.no_load,
    )
    return SkinSimulator(
        [(m.board, m.triangle) for m in pl.modules],
        BumpModel(pl.channel_xy()),
        sensor=sensor,
        taxel_mask=pl.valid_mask(),
        noise_cdc=noise_cdc,
        period_s=PERIOD_S,
        seed=seed,
    )


def press(force: float = 6.0, start_s: float = 0.3, hold_s: float = 0.6) -> Indentation:
    return Indentation.press(
        None, force, (0.0167, -0.0097), start_s=start_s, ramp_s=0.2, hold_s=hold_s
    )


class Harness:
    """A SkinDriver plus a listener on one executor; frames are sent from a thread."""

    def __init__(self, ctx: Any, channel: str, **params: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from tactile_contact.msg import TaxelArray
        from tactile_contact.nodes.skin_driver import SkinDriver

        values = {
            "interface": "virtual",
            "channel": channel,
            "layout": str(LAYOUT),
            "period_ms": 20,
            "max_wait_ms": 20.0,
            "calibration_samples": 5,
            "diagnostics_period_s": 0.2,
            **params,
        }
        self.channel = channel
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.driver = SkinDriver(context=ctx, parameter_overrides=overrides)
        self.listener = Node("listener", context=ctx)
        self.taxels: list[Any] = []
        self.diags: list[Any] = []
        deep = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.listener.create_subscription(TaxelArray, "hexagon/taxels", self.taxels.append, deep)
        self.listener.create_subscription(DiagnosticArray, "/diagnostics", self.diags.append, 50)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.driver)
        self.executor.add_node(self.listener)
        self._threads: list[threading.Thread] = []

    def wait_matched(self) -> None:
        pub = self.driver._pubs["hexagon"]
        assert self.spin_until(lambda: pub.get_subscription_count() > 0, 10.0), "no match"

    def spin_until(self, done: Any, timeout_s: float) -> bool:
        from test.rosutil import spin_until

        return spin_until(self.executor, done, timeout_s)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)

    def send(self, batches: Iterable[list[can.Message]], bus: can.BusABC | None = None) -> None:
        """Send each batch then wait one period (real time), in a thread."""
        tx = bus or can.Bus(interface="virtual", channel=self.channel, preserve_timestamps=True)

        def run() -> None:
            t0 = time.monotonic()
            for k, batch in enumerate(batches):
                for m in batch:
                    tx.send(m)
                time.sleep(max(0.0, t0 + (k + 1) * PERIOD_S - time.monotonic()))
            tx.shutdown()

        th = threading.Thread(target=run, daemon=True)
        th.start()
        self._threads.append(th)

    def sending(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def diag(self) -> dict[str, dict[str, str]]:
        """Latest /diagnostics as name → key → value (name without the node prefix)."""
        assert self.diags, "no diagnostics received"
        return {
            s.name.split(": ", 1)[1]: {kv.key: kv.value for kv in s.values}
            | {"_level": str(s.level[0]), "_message": s.message}
            for s in self.diags[-1].status
        }

    def close(self) -> None:
        for t in self._threads:
            t.join(timeout=10.0)
        self.executor.shutdown()
        self.driver.destroy_node()
        self.listener.destroy_node()


@pytest.fixture
def harness_factory(ros_context: Any, request: pytest.FixtureRequest) -> Any:
    made: list[Harness] = []

    def make(**params: Any) -> Harness:
        channel = f"{request.node.name}-{len(made)}"
        h = Harness(ros_context, channel, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def truth_by_stamp(periods: list[SimPeriod]) -> dict[int, PeriodTruth]:
    """Period index (round(t / period)) → truth."""
    return {round(p.t / PERIOD_S): p.truth for p in periods}


def stamp_index(msg: Any) -> int:
    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    return math.floor(t / PERIOD_S + 1e-6)


def quantum() -> float:
    se = patch().sensor
    return float(value_count_farad(se.farad_per_count, se.shift))


# -- (1) live virtual bus: ΔC against the simulated truth -------------------------------------
def test_delta_c_matches_simulated_truth(harness_factory: Any) -> None:
    from tactile_contact.msg import TaxelArray

    h = harness_factory()
    h.wait_matched()
    periods = list(simulator().periods(press(), 1.4))
    h.send(p.messages for p in periods)
    assert h.spin_until(lambda: not h.sending() and len(h.taxels) >= len(periods), 10.0)
    truths = truth_by_stamp(periods)
    valid = patch().valid_mask()
    q = quantum()
    loaded = 0
    assert len(h.taxels) == len(periods)
    for msg in h.taxels:
        assert msg.header.frame_id == "skin_hexagon" and msg.patch == "hexagon"
        truth = truths[stamp_index(msg)]
        assert bytes(msg.raw) == truth.values.tobytes()
        status = np.frombuffer(bytes(msg.status), np.uint8)
        assert not np.any(status & TaxelArray.STATUS_STALE)
        if np.any(status & 128):  # still calibrating: first calibration_samples periods
            continue
        dc = np.asarray(msg.delta_c, dtype=np.float64)
        # The module floors CDC counts to 8-bit values: one value count is the quantum.
        err = np.abs(dc - truth.delta_c)[valid]
        assert err.max() <= q * 1.001 + 1e-20, f"ΔC off by {err.max() / q:.2f} quanta"
        loaded += bool(truth.delta_c.max() > 5 * q)
    assert loaded >= 20, "the press must be visible in many messages"
    # the taxel ids are the layout's, in module then channel order
    ids = list(h.taxels[0].taxel_ids)
    assert ids[:13] == [*range(12), 0x010]


# -- (2) candump log replayed at recorded pace ------------------------------------------------
def test_replays_candump_log(harness_factory: Any, tmp_path: Path) -> None:
    from tactile_contact.simulator import write_log

    periods = list(simulator(noise_cdc=1.0, seed=3).periods(press(start_s=0.2, hold_s=0.2), 0.8))
    log = tmp_path / "skin.log"
    truths = write_log(log, periods)
    t0 = time.monotonic()
    h = harness_factory(replay_file=str(log), autostart=False)
    from rclpy.lifecycle import TransitionCallbackReturn

    assert h.driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
    h.wait_matched()
    assert h.driver.trigger_activate() == TransitionCallbackReturn.SUCCESS
    assert h.spin_until(lambda: len(h.taxels) >= len(truths), 10.0)
    elapsed = time.monotonic() - t0
    assert elapsed >= 0.7 * len(truths) * PERIOD_S, "replay is paced by the log's timestamps"
    got = {stamp_index(m): bytes(m.raw) for m in h.taxels}
    assert got == {round(t.t / PERIOD_S): t.values.tobytes() for t in truths}
    h.spin_until(lambda: any("replay finished" in s.message for s in h.diags[-1].status), 3.0)
    assert h.diag()["CAN bus"]["_message"] == "replay finished"
