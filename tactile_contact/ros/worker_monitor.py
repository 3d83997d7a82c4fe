"""``worker_monitor``: a dead reconstruction worker on /diagnostics within a second.

A worker that dies cannot say so. This node reads the workers' heartbeats
(``reconstruction_workers``, tactile_contact.ros.worker_link; one every 0.2 s from each) and,
ten times a second, reports on ``/diagnostics``:

- ``contact_reconstruction: workers``: OK with the workers heard and their patches; ERROR when
  a worker has been silent for more than :data:`workers.SILENT_AFTER_S` (0.5 s: dead, hung or
  cut off) or a patch is claimed by two live workers;
- for each patch of a silent worker, ``contact_reconstruction: <patch>`` at level STALE
  ("not served: worker host/pid silent for 0.6 s"): the status name its worker reports it
  under, so a monitor shows the patch stale until a worker serves it again (the launch
  respawns a dead worker; its first status replaces this one);
- a patch claimed by two live workers, ERROR under that patch's name;
- a worker of a split (``workers:=N``) never heard :data:`workers.MISSING_AFTER_S` (20 s) after
  another of it: ERROR in ``contact_reconstruction: workers`` ("worker 1 of 2 never heard"),
  `missing` naming them — one that fails before its first heartbeat, at every respawn, would
  otherwise leave its patches unserved with the status OK.

It publishes at once when something changes and every ``diagnostics_period`` otherwise, so
a death is on /diagnostics 0.5–0.6 s after the last heartbeat. A worker replaced by a new one
serving all its patches (a respawn) is forgotten at once; one nobody replaces stays reported.

    ros2 run tactile_contact worker_monitor
"""

from __future__ import annotations

import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from tactile_contact.msg import ReconstructionWorker
from tactile_contact.ros.common import (
    DIAGNOSTICS_QOS,
    ERROR,
    OK,
    STALE,
    declare_parameter,
    diagnostic_status,
    log_parameters,
    publish_while_up,
    run_node,
)
from tactile_contact.ros.worker_link import HEARTBEAT_QOS, TOPIC, info_from_message
from tactile_contact.ros.workers import Roster, WorkerInfo

#: The monitor looks this often [s].
CHECK_PERIOD_S = 0.1


def _who(w: WorkerInfo) -> str:
    place = f"{w.index} of {w.count}" if w.count else "patches by name"
    return f"worker {w.worker} ({place})"


class WorkerMonitor(Node):
    """The ``worker_monitor`` node (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("worker_monitor", **kwargs)
        self.period = declare_parameter(
            self,
            "diagnostics_period",
            1.0,
            "period of /diagnostics when nothing changes",
            unit="s",
            float_range=(0.05, 60.0),
        )
        log_parameters(self, ["diagnostics_period"])
        self.roster = Roster()
        self._said: tuple = ()
        self._last = -1.0
        self.pub = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self.create_subscription(ReconstructionWorker, TOPIC, self._heard, HEARTBEAT_QOS)
        self.create_timer(CHECK_PERIOD_S, self.check)

    def _heard(self, msg: Any) -> None:
        self.roster.heard(info_from_message(msg), time.monotonic())

    def _replaced(self, now: float) -> None:
        """Forget silent workers whose every patch a live worker serves now (a respawn)."""
        served = {p for w in self.roster.alive(now) for p in w.patches}
        for w in self.roster.silent(now):
            if set(w.patches) <= served:
                del self.roster.workers[w.worker]

    def statuses(self, now: float) -> list[Any]:
        """The statuses this monitor publishes now."""
        self._replaced(now)
        alive, silent = self.roster.alive(now), self.roster.silent(now)
        twice = self.roster.served_twice(now)
        out = []
        for w in silent:
            quiet = now - w.heard
            for p in w.patches:
                out.append(
                    diagnostic_status(
                        f"contact_reconstruction: {p}",
                        STALE,
                        f"not served: {_who(w)} silent for {quiet:.1f} s",
                        {"worker": w.worker, "silent_s": quiet},
                        p,
                    )
                )
        for p, ws in twice.items():
            out.append(
                diagnostic_status(
                    f"contact_reconstruction: {p}",
                    ERROR,
                    "served twice: " + " and ".join(_who(w) for w in ws),
                    {"workers": " ".join(w.worker for w in ws)},
                    p,
                )
            )
        patches = sorted({p for w in alive for p in w.patches})
        level, problems = OK, []
        if silent:
            level = ERROR
            problems += [f"{_who(w)} silent for {now - w.heard:.1f} s" for w in silent]
        if twice:
            level = ERROR
            problems += [f"{len(twice)} patch(es) served twice"]
        missing = self.roster.missing(now)
        if missing:
            level = ERROR
            problems += [
                f"worker {i} of {n} never heard (its patches not served)" for i, n in missing
            ]
        message = f"{len(alive)} worker(s) serving {len(patches)} patch(es)"
        values = {
            "alive": " ".join(sorted(w.worker for w in alive)),
            "silent": " ".join(sorted(w.worker for w in silent)),
            "patches": " ".join(patches),
            "served_twice": " ".join(sorted(twice)),
            "missing": " ".join(f"{i}/{n}" for i, n in missing),
        }
        out.append(
            diagnostic_status(
                "contact_reconstruction: workers",
                level,
                "; ".join([message, *problems]),
                values,
                "worker_monitor",
            )
        )
        return out

    def check(self) -> None:
        """Publish when the picture changed (a worker gone, back, a patch twice), and once a
        period anyway."""
        now = time.monotonic()
        statuses = self.statuses(now)
        picture = tuple((s.name, s.level) for s in statuses)
        if picture == self._said and now - self._last < self.period:
            return
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = statuses
        if publish_while_up(self, self.pub, msg):
            self._said, self._last = picture, now


def main(args: list[str] | None = None) -> None:
    """Run ``worker_monitor`` until Ctrl-C."""
    run_node("worker_monitor", WorkerMonitor, args)


if __name__ == "__main__":
    main()
