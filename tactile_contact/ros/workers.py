"""Reconstruction workers: which process serves which patch, and who is alive (no ROS here).

A skin too large for one core is served by N ``contact_reconstruction`` processes, the
*workers*, on one machine or several in one ROS domain. Each owns a disjoint set of patches:

- :func:`assign_patches` deals the patches to N workers, balanced by taxel count (the solve's
  cost grows with a patch's taxels), and *stable*: the result depends only on the patch names,
  their taxel counts and N — not on the order they are listed in, the machine or the time —
  so every worker computes the same split on its own, and a restarted worker takes back the
  patches it had, with nothing to agree on over the network.
- :class:`Roster` keeps the workers' heartbeats (each worker announces its patches a few times
  a second): who has been silent too long (its patches are *stale*), and which patch more than
  one live worker claims (a patch served twice: the older claim keeps it).
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

#: Workers announce themselves this often [s].
HEARTBEAT_PERIOD_S = 0.2
#: A worker not heard for this long is reported dead and its patches stale [s]: 2.5 heartbeat
#: periods, so one late heartbeat on a busy machine is not a death, and a real one is on
#: /diagnostics well within a second.
SILENT_AFTER_S = 0.5


def default_workers(patches: int | None = None) -> int:
    """Workers to start on this machine: one per core this process may run on, at most one
    per patch (a worker without a patch would only idle)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not Linux)
        cores = os.cpu_count() or 1
    return max(1, min(cores, patches if patches else cores))


def assign_patches(taxels: Mapping[str, int], workers: int) -> list[tuple[str, ...]]:
    """Deal the patches to ``workers`` workers, balanced by taxel count.

    Largest patch first, each to the least-loaded worker (ties: the lower worker index);
    patches of equal size in name order. This greedy rule (longest processing time first)
    leaves the busiest worker at most 4/3 of the best possible split's busiest, and within one
    patch's taxels of the mean.

    Args:
        taxels: patch name → its taxel count (> 0).
        workers: number of workers (≥ 1).

    Returns:
        Per worker, its patches in name order (a worker may get none when there are more
        workers than patches).

    Raises:
        ValueError: ``workers`` < 1, or a taxel count that is not a positive integer.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    for name, n in taxels.items():
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"patch {name!r}: taxel count must be an integer >= 1, got {n!r}")
    load = [(0, k) for k in range(workers)]  # (taxels so far, worker index): a min-heap
    owned: list[list[str]] = [[] for _ in range(workers)]
    for name in sorted(taxels, key=lambda p: (-taxels[p], p)):
        total, k = heapq.heappop(load)
        owned[k].append(name)
        heapq.heappush(load, (total + taxels[name], k))
    return [tuple(sorted(names)) for names in owned]


def worker_patches(taxels: Mapping[str, int], index: int, count: int) -> tuple[str, ...]:
    """The patches of worker ``index`` of ``count`` (:func:`assign_patches`)."""
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
        raise ValueError(f"worker index must be within 0..{count - 1}, got {index!r}")
    return assign_patches(taxels, count)[index]


@dataclass
class WorkerInfo:
    """What a worker's heartbeat says, and when it was last heard [s, the roster's clock]."""

    worker: str  # unique name: host/pid (what a restarted worker changes)
    index: int  # its index among the workers (-1: patches named by hand)
    count: int  # the number of workers it was started with (0: patches named by hand)
    patches: tuple[str, ...]
    started: float  # when it started serving [s since the epoch]: the older claim wins
    heard: float = 0.0
    frames: int = 0


@dataclass
class Roster:
    """The workers heard from, by name (see the module docstring)."""

    silent_after_s: float = SILENT_AFTER_S
    workers: dict[str, WorkerInfo] = field(default_factory=dict)

    def heard(self, info: WorkerInfo, now: float) -> None:
        """Record a heartbeat received at ``now``."""
        info.heard = now
        self.workers[info.worker] = info

    def forget(self, older_than_s: float, now: float) -> list[WorkerInfo]:
        """Drop and return the workers silent for longer than ``older_than_s``."""
        gone = [w for w in self.workers.values() if now - w.heard > older_than_s]
        for w in gone:
            del self.workers[w.worker]
        return gone

    def alive(self, now: float) -> list[WorkerInfo]:
        return [w for w in self.workers.values() if now - w.heard <= self.silent_after_s]

    def silent(self, now: float) -> list[WorkerInfo]:
        """Workers heard once, but not within ``silent_after_s`` (dead or cut off)."""
        return [w for w in self.workers.values() if now - w.heard > self.silent_after_s]

    def claims(self, now: float) -> dict[str, list[WorkerInfo]]:
        """Patch → the live workers that claim it, the oldest claim first."""
        out: dict[str, list[WorkerInfo]] = {}
        for w in sorted(self.alive(now), key=lambda w: (w.started, w.worker)):
            for p in w.patches:
                out.setdefault(p, []).append(w)
        return out

    def served_twice(self, now: float) -> dict[str, list[WorkerInfo]]:
        """Patches more than one live worker claims (oldest claim first)."""
        return {p: ws for p, ws in self.claims(now).items() if len(ws) > 1}

    def taken(self, patches: Iterable[str], me: WorkerInfo, now: float) -> dict[str, WorkerInfo]:
        """Of ``patches``, those a live worker older than ``me`` serves: patch → that worker.
        ``me`` serves the rest (a patch is served by its oldest live claimant)."""
        wanted = set(patches)
        out: dict[str, WorkerInfo] = {}
        for w in sorted(self.alive(now), key=lambda w: (w.started, w.worker)):
            if (w.started, w.worker) >= (me.started, me.worker):
                break
            for p in w.patches:
                if p in wanted and p not in out:
                    out[p] = w
        return out
