"""Helpers for tests that run real rclpy nodes."""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.executors import Executor


def spin_until(executor: Executor, done: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Spin ``executor`` until ``done()`` is true or ``timeout_s`` passes; return ``done()``."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return done()
