"""Helpers for tests that run real rclpy nodes."""

from __future__ import annotations

import os
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from rclpy.executors import Executor

ROOT = Path(__file__).resolve().parents[1]


def reconstruction_workers(context: object, count: int, **params: object) -> list:
    """``count`` contact_reconstruction nodes in this process, worker 0 … count−1 of
    ``count``, each with ``params`` as parameter overrides."""
    from rclpy.parameter import Parameter

    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    return [
        ContactReconstructionNode(
            context=context,
            parameter_overrides=[
                *(Parameter(k, value=v) for k, v in params.items()),
                Parameter("worker_index", value=index),
                Parameter("worker_count", value=count),
            ],
        )
        for index in range(count)
    ]


def batch_probe(context: object, name: str) -> tuple:
    """A node ``name`` that publishes TaxelBatch bytes on ``taxel_batches`` and collects the
    (patch, stamp [ns]) rows of every ContactArray on ``contacts``: (node, publisher, rows)."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from tactile_contact.msg import ContactArray, TaxelBatch
    from tactile_contact.ros import contact_batches
    from tactile_contact.ros.cdr import read_contact_array
    from tactile_contact.ros.common import SENSOR_QOS

    node = Node(name, context=context)
    pub = node.create_publisher(TaxelBatch, contact_batches.BATCHES_TOPIC, SENSOR_QOS)
    rows: list[tuple[str, int]] = []

    def summarised(data: bytes) -> None:
        got = read_contact_array(data)[1]
        rows.extend(zip(got.patches, got.stamps_ns, strict=True))

    node.create_subscription(
        ContactArray,
        contact_batches.CONTACTS_TOPIC,
        summarised,
        QoSProfile(depth=64, reliability=ReliabilityPolicy.BEST_EFFORT),  # (none lost here)
        raw=True,
    )
    return node, pub, rows


def spin_until(executor: Executor, done: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Spin ``executor`` until ``done()`` is true or ``timeout_s`` passes; return ``done()``."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return done()


class NodeProcess:
    """A node run as its own process (``argv``, from the checkout, unbuffered), its output
    (stdout and stderr) read line by line as it comes; a context manager that kills it if it
    is still there at the end."""

    def __init__(self, argv: Sequence[str]) -> None:
        self.proc = subprocess.Popen(
            list(argv),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        self.lines: list[str] = []
        self._new = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._new:
                self.lines.append(line)
                self._new.notify_all()

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def wait_for_line(self, text: str = "", timeout_s: float = 60.0) -> bool:
        """Wait until a line containing ``text`` (any line: "") was printed; whether it was."""
        with self._new:
            return self._new.wait_for(
                lambda: any(text in line for line in self.lines), timeout=timeout_s
            )

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=5.0)
