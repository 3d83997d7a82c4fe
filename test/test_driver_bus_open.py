"""``skin_driver`` when its bus cannot be opened at start (issue 27): it runs, retries with
exponential backoff, says why in /diagnostics (ERROR) and in the log once per change of reason,
and opens the bus when it comes (a USB adapter plugged in late). A bus that can never open (an
unknown python-can interface) still fails the configure transition (test_driver_node.py).

Real driver over DDS, python-can's socketcan (this kernel: no such address family; elsewhere:
no such device) and slcan over a pseudo-terminal (test_driver_faults.SerialAdapter).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from test.test_driver_faults import SerialAdapter
from test.test_driver_node import PERIOD_S, Harness, simulator

pytestmark = pytest.mark.ros


def test_a_bus_that_cannot_be_opened_is_retried_and_reported(
    ros_context: Any, capfd: pytest.CaptureFixture[str]
) -> None:
    h = Harness(
        ros_context,
        "tcnone0",
        interface="socketcan",
        reconnect_interval_s=0.1,
        reconnect_max_interval_s=0.4,
    )
    try:
        assert h.driver._state_machine.current_state[1] == "active"
        assert h.spin_until(lambda: bool(h.diags), 5.0), "no /diagnostics"
        t0 = time.monotonic()
        time.sleep(1.5)
        bus = h.diag()["CAN bus"]
        attempts = int(bus["reconnect_attempts"])
        elapsed = time.monotonic() - t0 + 0.1
        assert bus["_level"] == "2", bus
        assert "cannot open CAN bus socketcan:tcnone0" in bus["_message"], bus
        assert bus["bus_ever_open"] == "False" and bus["bus_problem"], bus
        # backoff 0.1, 0.2, 0.4, 0.4 … s: 4–6 attempts in ≈ 1.6 s, not hundreds
        assert 3 <= attempts <= 2 + elapsed / 0.4 + 1, (attempts, elapsed)
        err = capfd.readouterr().err
        assert err.count("cannot open CAN bus") == 1, err  # once per reason, not per attempt
        assert h.driver.summary()[0].startswith("bus socketcan:tcnone0: 0 CAN frames")
        assert "never opened" in h.driver.summary()[0]
    finally:
        h.close()


def test_an_adapter_plugged_in_after_start_is_opened(
    ros_context: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: Any
) -> None:
    pytest.importorskip("serial", reason="pyserial (python-can's slcan interface) not installed")
    monkeypatch.setenv("CAN_CONFIG", '{"sleep_after_open": 0}')  # python-can's own config
    path = tmp_path / "ttyCAN0"
    h = Harness(
        ros_context,
        str(path),
        interface="slcan",
        reconnect_interval_s=0.1,
        reconnect_max_interval_s=0.3,
    )
    adapter = None
    try:
        assert h.spin_until(lambda: bool(h.diags) and h.diag()["CAN bus"]["_level"] == "2", 5.0)
        adapter = SerialAdapter(path)  # plugged in
        sim, k = simulator(seed=11), 0
        end = time.monotonic() + 10.0
        while len(h.taxels) < 10 and time.monotonic() < end:
            adapter.send(sim.period(None, k * PERIOD_S).messages)
            k += 1
            time.sleep(PERIOD_S)
        assert len(h.taxels) >= 10, "no data after the adapter was plugged in"
        h.driver._publish_diagnostics()
        assert h.spin_until(lambda: h.diag()["CAN bus"]["_level"] in ("0", "1"), 2.0)
        assert h.diag()["CAN bus"]["bus_ever_open"] == "True"
        err = capfd.readouterr().err
        assert err.count("cannot open CAN bus") == 1 and "opened CAN bus slcan:" in err, err
    finally:
        h.close()
        if adapter is not None:
            adapter.unplug()
