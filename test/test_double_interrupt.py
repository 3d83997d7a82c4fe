"""Ctrl-C in a terminal reaches every process of the group, and ros2 launch forwards its own:
a node gets two SIGINTs, often milliseconds apart. Each must end it quietly (exit 0, no
traceback): a second one raised while the first was being handled escaped run_node and killed
the process by the signal (ros2 launch: "process has died … exit code -2", seen in CI)."""

from __future__ import annotations

import os
import signal
import sys
import time

import pytest

from test.rosutil import NodeProcess

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("gap_s", [0.0, 0.001, 0.02])
def test_two_interrupts_end_a_node_quietly(gap_s: float) -> None:
    with NodeProcess([sys.executable, "-m", "tactile_contact.ros.contact_reconstruction"]) as node:
        # Its first log line comes from the node being built, so its modules are imported and
        # run_node's handling is in place (a Ctrl-C during `import` is Python's, before any
        # code of ours: on a saturated machine the imports took over 3 s, the fixed wait here).
        assert node.wait_for_line(timeout_s=60.0), "the node printed nothing in 60 s"
        time.sleep(1.0)
        proc = node.proc
        assert proc.poll() is None, node.output
        os.kill(proc.pid, signal.SIGINT)
        if gap_s:
            time.sleep(gap_s)
        os.kill(proc.pid, signal.SIGINT)
        proc.wait(timeout=30.0)
    out = node.output
    assert proc.returncode == 0, out
    assert "Traceback" not in out, out
