"""Ctrl-C in a terminal reaches every process of the group, and ros2 launch forwards its own:
a node gets two SIGINTs, often milliseconds apart. Each must end it quietly (exit 0, no
traceback): a second one raised while the first was being handled escaped run_node and killed
the process by the signal (ros2 launch: "process has died … exit code -2", seen in CI)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("gap_s", [0.0, 0.001, 0.02])
def test_two_interrupts_end_a_node_quietly(gap_s: float) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tactile_contact.ros.contact_reconstruction"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    lines: list[str] = []
    started = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        # Its first log line comes from the node being built, so its modules are imported and
        # run_node's handling is in place (a Ctrl-C during `import` is Python's, before any
        # code of ours: on a saturated machine the imports took over 3 s, the fixed wait here).
        assert started.wait(60.0), "the node printed nothing in 60 s"
        time.sleep(1.0)
        assert proc.poll() is None, "".join(lines)
        os.kill(proc.pid, signal.SIGINT)
        if gap_s:
            time.sleep(gap_s)
        os.kill(proc.pid, signal.SIGINT)
        proc.wait(timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(timeout=5.0)
    out = "".join(lines)
    assert proc.returncode == 0, out
    assert "Traceback" not in out, out
