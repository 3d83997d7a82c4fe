"""A reconstruction worker's link to the others: its heartbeat, and which patches it serves.

Every ``contact_reconstruction`` process announces itself on ``reconstruction_workers``
(tactile_contact/ReconstructionWorker, every :data:`workers.HEARTBEAT_PERIOD_S`): its name
(host/pid), its index and the number of workers, when it started, the patches it serves and
those it leaves to an older claim. It reads the others' heartbeats into a
:class:`workers.Roster` and serves a patch only while no live worker that started before it
serves the same one, so that a patch is never served twice: a worker started as a second
server of a patch (two machines given overlapping lists, a launch started twice) leaves it to
the first, reports that on /diagnostics, and takes it over if the first goes silent.

Started as a worker (``worker_count`` > 0) it first listens for :data:`workers.SILENT_AFTER_S`
before serving anything: a worker that starts while another serves its patches hears it
before its first frame. ``worker_monitor`` (tactile_contact.ros.worker_monitor) reads the same
heartbeats to report a worker that died.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from tactile_contact.msg import ReconstructionWorker
from tactile_contact.ros.common import publish_while_up
from tactile_contact.ros.workers import HEARTBEAT_PERIOD_S, SILENT_AFTER_S, Roster, WorkerInfo

TOPIC = "reconstruction_workers"
#: Heartbeats: reliable (a lost one looks like a death), the last few kept.
HEARTBEAT_QOS = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)


def worker_name() -> str:
    """This process's name among the workers: host/pid."""
    return f"{socket.gethostname()}/{os.getpid()}"


def info_from_message(msg: Any) -> WorkerInfo:
    """The :class:`WorkerInfo` a ReconstructionWorker message carries."""
    return WorkerInfo(
        msg.worker, msg.index, msg.count, tuple(msg.patches), msg.started, frames=msg.frames
    )


class WorkerLink:
    """The heartbeat and the claims of one reconstruction node (see the module docstring).

    Args:
        node: the node (its clock, publishers, timers).
        patches: the patches it was given (by the split, by name, or all of its bundles).
        index, count: its place among the workers (-1 and 0: not started as a worker: it
            serves at once and never yields, as a lone node always did).
        frames: returns the frames taken so far (for the heartbeat).
    """

    def __init__(
        self, node: Node, patches: list[str], index: int, count: int, frames: Any = None
    ) -> None:
        self.node = node
        self.given = tuple(sorted(patches))
        self.me = WorkerInfo(worker_name(), index, count, self.given, time.time())
        self.worker_mode = count > 0
        self.roster = Roster()
        self.yielded: dict[str, WorkerInfo] = {}  # patch → the older worker serving it
        self.serving: frozenset[str] = frozenset() if self.worker_mode else frozenset(self.given)
        self._frames = frames or (lambda: 0)
        self._listening_since: float | None = None
        self._pub = node.create_publisher(ReconstructionWorker, TOPIC, HEARTBEAT_QOS)
        node.create_subscription(ReconstructionWorker, TOPIC, self._heard, HEARTBEAT_QOS)
        node.create_timer(HEARTBEAT_PERIOD_S, self._beat)

    def _heard(self, msg: Any) -> None:
        if msg.worker != self.me.worker:
            self.roster.heard(info_from_message(msg), time.monotonic())

    def _beat(self) -> None:
        """Decide what to serve, then announce it (timer; never raises into the executor)."""
        try:
            self._decide(time.monotonic())
            self._announce()
        except Exception as exc:
            if self.node.context.ok():
                self.node.get_logger().error(
                    f"worker heartbeat: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0
                )

    def _decide(self, now: float) -> None:
        if not self.worker_mode:
            return
        if self._listening_since is None:
            self._listening_since = now
        if now - self._listening_since < SILENT_AFTER_S:
            return  # still listening for workers that already serve these patches
        self.roster.forget(60.0, now)
        taken = self.roster.taken(self.given, self.me, now)
        log = self.node.get_logger()
        for p, w in taken.items():
            if p not in self.yielded:
                log.error(
                    f"patch {p} is already served by worker {w.worker} (index {w.index} of "
                    f"{w.count}), started before this one: left to it (a patch is served once)"
                )
        for p in set(self.yielded) - set(taken):
            log.warning(f"patch {p}: worker {self.yielded[p].worker} is gone; serving it")
        self.yielded = taken
        self.serving = frozenset(p for p in self.given if p not in taken)
        self.me.patches = tuple(sorted(self.serving))

    def _announce(self) -> None:
        msg = ReconstructionWorker(
            worker=self.me.worker,
            index=self.me.index,
            count=self.me.count,
            started=self.me.started,
            patches=sorted(self.serving),
            yielded=sorted(self.yielded),
            frames=int(self._frames()),
            cpu_time=time.process_time(),
        )
        msg.header.stamp = self.node.get_clock().now().to_msg()
        publish_while_up(self.node, self._pub, msg)

    def status(self) -> tuple[bool, str]:
        """(problem?, what to say) about the claims, for /diagnostics."""
        if self.worker_mode and self._listening_since is None:
            return False, "starting: listening for other workers"
        if self.yielded:
            text = ", ".join(f"{p} (served by {w.worker})" for p, w in sorted(self.yielded.items()))
            return True, f"left to older workers: {text}"
        return False, ""
