"""Reconstruction workers: which process serves which patch, and who is alive (no ROS here).

A skin too large for one core is served by N ``contact_reconstruction`` processes, the
*workers*, on one machine or several in one ROS domain. Each owns a disjoint set of patches:

- :func:`assign_patches` deals the patches to N workers, balanced by taxel count (the solve's
  cost grows with a patch's taxels), each CAN bus whole where that costs little balance (a
  bus's batches are then read by one worker), and *stable*: the result depends only on the
  patch names, their taxel counts, their buses and N — not on the order they are listed in,
  the machine or the time —
  so every worker computes the same split on its own, and a restarted worker takes back the
  patches it had, with nothing to agree on over the network.
- :class:`Roster` keeps the workers' heartbeats (each worker announces its patches a few times
  a second): who has been silent too long (its patches are *stale*), and which patch more than
  one live worker claims (a patch served twice: the older claim keeps it).
"""

from __future__ import annotations

import heapq
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

#: Workers announce themselves this often [s].
HEARTBEAT_PERIOD_S = 0.2
#: A worker not heard for this long is reported dead and its patches stale [s]: 2.5 heartbeat
#: periods, so one late heartbeat on a busy machine is not a death, and a real one is on
#: /diagnostics well within a second.
SILENT_AFTER_S = 0.5
#: How much busier than the patch-by-patch split a worker may be made to keep a bus whole
#: (:func:`assign_patches`): the robot's 7 buses dealt whole to 2 workers leave the busier 8 %
#: above. What a whole bus saves is the traffic to a worker (on another machine: the robot's
#: batches are ≈ 1.6 MB/s) and the batches it takes; on one machine at 50 Hz the workers' CPU
#: measured the same either way (docs/bench/load.md), so the slack stays small.
BUS_SLACK = 0.1
#: A worker of a split (index i of N) not heard this long after another of the same split
#: [s] is reported missing: one that fails before its first heartbeat (and again at every
#: respawn) would otherwise leave its patches unserved without a word. Long enough for the
#: slowest start (a worker loads and warms up its bundles first: seconds on a loaded machine).
MISSING_AFTER_S = 20.0


def default_workers(patches: int | None = None) -> int:
    """Workers to start on this machine: one per core this process may run on, at most one
    per patch (a worker without a patch would only idle)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not Linux)
        cores = os.cpu_count() or 1
    return max(1, min(cores, patches if patches else cores))


def _deal(
    items: Iterable[tuple[tuple[str, ...], int]],
    load: list[tuple[int, int]],
    owned: list[list[str]],
) -> None:
    """Each item (patches, their taxels), in the order given, to the least-loaded worker
    (``load``: a min-heap of (taxels so far, worker index), changed in place; ``owned``: per
    worker, its patches)."""
    for patches, n in items:
        total, k = heapq.heappop(load)
        owned[k].extend(patches)
        heapq.heappush(load, (total + n, k))


def _largest_first(taxels: Mapping[str, int]) -> list[tuple[tuple[str, ...], int]]:
    """Each patch alone, largest first, equal sizes in name order."""
    return [((p,), taxels[p]) for p in sorted(taxels, key=lambda p: (-taxels[p], p))]


def assign_patches(
    taxels: Mapping[str, int], workers: int, buses: Mapping[str, str] | None = None
) -> list[tuple[str, ...]]:
    """Deal the patches to ``workers`` workers, balanced by taxel count, each bus's patches
    kept with one worker where that costs little balance.

    Largest patch first, each to the least-loaded worker (ties: the lower worker index);
    patches of equal size in name order. This greedy rule (longest processing time first)
    leaves the busiest worker at most 4/3 of the best possible split's busiest, and within one
    patch's taxels of the mean.

    With ``buses`` (patch → its CAN bus) the buses are dealt whole the same way, largest
    first, as long as the least-loaded worker stays within BUS_SLACK of that patch-by-patch
    split's busiest; a bigger bus is cut: that worker takes what of it fits (largest patches
    first, at least one) and the rest is dealt again as a smaller bus. Why: a bus's batches
    reach every worker serving one of its patches (a worker subscribes to its own buses'
    batches only), so a bus kept whole is taken and read by one process. If the busiest
    worker still ends more than BUS_SLACK above the patch-by-patch split's, that split is
    returned; so it is with one bus.

    Args:
        taxels: patch name → its taxel count (> 0).
        workers: number of workers (≥ 1).
        buses: patch name → its bus name (a patch it does not name is a bus of its own).

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
    owned: list[list[str]] = [[] for _ in range(workers)]
    load = [(0, k) for k in range(workers)]
    _deal(_largest_first(taxels), load, owned)
    split = [tuple(sorted(names)) for names in owned]
    if buses is None or workers == 1:
        return split
    on_bus: dict[tuple[bool, str], dict[str, int]] = {}
    for name, n in taxels.items():
        key = (True, buses[name]) if name in buses else (False, name)
        on_bus.setdefault(key, {})[name] = n
    if len(on_bus) < 2:
        return split
    limit = (1.0 + BUS_SLACK) * max(total for total, _ in load)
    owned = [[] for _ in range(workers)]
    load = [(0, k) for k in range(workers)]
    # Largest bus first, whole to the least-loaded worker if it fits under the limit; else
    # that worker takes what of it fits (largest patches first, at least one) and the rest
    # goes back as a smaller bus: a bus too big for one worker is cut in as few parts as the
    # greedy rule finds, not spread over every worker.
    todo = [  # (−taxels, bus, its patches largest first): a min-heap, the largest bus first
        (-sum(m.values()), key, tuple(sorted(m, key=lambda p: (-m[p], p))))
        for key, m in on_bus.items()
    ]
    heapq.heapify(todo)
    while todo:
        minus_size, key, patches = heapq.heappop(todo)
        total, k = heapq.heappop(load)
        if total - minus_size <= limit:
            took = list(patches)
        else:
            room, took = limit - total, []
            for p in patches:
                if taxels[p] <= room or not took:
                    took.append(p)
                    room -= taxels[p]
        owned[k].extend(took)
        heapq.heappush(load, (total + sum(taxels[p] for p in took), k))
        rest = tuple(p for p in patches if p not in took)
        if rest:
            heapq.heappush(todo, (-sum(taxels[p] for p in rest), key, rest))
    if max(total for total, _ in load) > limit:
        return split
    return [tuple(sorted(names)) for names in owned]


def worker_patches(
    taxels: Mapping[str, int],
    index: int,
    count: int,
    buses: Mapping[str, str] | None = None,
) -> tuple[str, ...]:
    """The patches of worker ``index`` of ``count`` (:func:`assign_patches`)."""
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
        raise ValueError(f"worker index must be within 0..{count - 1}, got {index!r}")
    return assign_patches(taxels, count, buses)[index]


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
    #: Per split (worker count N): when a worker of it was heard with none of it in the roster
    #: (the split started, or started again after all of it was forgotten).
    splits: dict[int, float] = field(default_factory=dict)

    def heard(self, info: WorkerInfo, now: float) -> None:
        """Record a heartbeat received at ``now``."""
        info.heard = now
        if info.count > 0 and not any(w.count == info.count for w in self.workers.values()):
            self.splits[info.count] = now
        self.workers[info.worker] = info

    def missing(self, now: float, after_s: float = MISSING_AFTER_S) -> list[tuple[int, int]]:
        """(index, count) of the workers of a split never heard, ``after_s`` [s] or more after
        the first of that split was (a split none of whose workers is in the roster any more,
        one relaunched with another count, is not looked at)."""
        seen: dict[int, set[int]] = {}
        for w in self.workers.values():  # (the roster's: a relaunch's old ones forgotten)
            seen.setdefault(w.count, set()).add(w.index)
        return [
            (i, n)
            for n, first in sorted(self.splits.items())
            if n in seen and now - first >= after_s
            for i in range(n)
            if i not in seen[n]
        ]

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


#: Bus names bus_filter writes into an expression (LIKE's own wildcard _ and the regular
#: expression's . only let more through).
_PLAIN = re.compile(r"[A-Za-z0-9_./:-]*")


def bus_filter(served: Iterable[str], known: Iterable[str]) -> str | None:
    """A DDS content filter (DDS-SQL, as rclpy's ContentFilterOptions takes it) that passes
    the TaxelBatches a worker serving the buses ``served`` needs: those whose ``bus`` names
    one of them, alone or in a comma-separated list (a driver of several buses), and those
    naming no bus. The middleware drops the others before they reach the process: a batch
    no patch of which is this worker's costs it nothing (each was taken and read before).

    Returns:
        The expression, or None (take every batch) when ``served`` covers every bus in
        ``known``, or a bus name holds anything but letters, digits and ``_ - . / :`` (Fast
        DDS turns LIKE into a regular expression: a ``+`` or ``(`` in a name would let its own
        batches miss, or the expression be refused).
    """
    mine, every = set(served), set(known)
    if not mine or every <= mine or not all(_PLAIN.fullmatch(b) for b in mine):
        return None
    terms = ["bus = ''"]
    for b in sorted(mine - {""}):
        terms += [f"bus = '{b}'", f"bus LIKE '{b},%'", f"bus LIKE '%,{b}'", f"bus LIKE '%,{b},%'"]
    return " OR ".join(terms)
