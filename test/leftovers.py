"""Processes a test leaves running: found, ended and named (conftest's ``no_leftover_process``).

Why: in stop 37's CI run a contact_reconstruction that a test had sent SIGINT lost it and
served on the test domain after the test gave up on it; seven later ROS tests failed beside
that stray node instead of the one that left it. Each test's new descendants still alive at
its end (after GRACE_S) are killed here and the test that left them fails, naming them.

Read from /proc (Linux): a process's parent and state from ``/proc/PID/stat``, its command line
from ``/proc/PID/cmdline``. A process whose parent ended is re-parented away from the test
run and is not seen: this finds what a test started and did not end, not daemons.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

#: Long-lived helpers of the test process itself, started on first use and kept (a
#: multiprocessing forkserver and its resource tracker): not a test's leftovers.
KEPT = ("multiprocessing.forkserver", "multiprocessing.resource_tracker")
#: How long a test's new processes may take to end after it [s] (a node told to stop in a
#: fixture's teardown exits within the stuck watcher's 4–5 s).
GRACE_S = 6.0


def _parents() -> dict[int, int]:
    """Live (not zombie) processes: pid → parent pid."""
    out = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue  # (ended meanwhile)
        # the name in parentheses may hold spaces and parentheses: fields after the last ')'
        state, ppid = stat[stat.rindex(")") + 2 :].split()[:2]
        if state != "Z":
            out[int(entry)] = int(ppid)
    return out


def command(pid: int) -> str:
    """``pid``'s command line ('' once it ended)."""
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return ""
    return raw.replace(b"\0", b" ").decode(errors="replace").strip()


def descendants(root: int | None = None) -> set[int]:
    """Live descendants of ``root`` (default: this process), KEPT helpers and theirs left out."""
    root = os.getpid() if root is None else root
    children: dict[int, list[int]] = {}
    for pid, ppid in _parents().items():
        children.setdefault(ppid, []).append(pid)
    out: set[int] = set()
    todo = list(children.get(root, []))
    while todo:
        pid = todo.pop()
        if any(k in command(pid) for k in KEPT):
            continue
        out.add(pid)
        todo += children.get(pid, [])
    return out


def end_leftovers(before: set[int], grace_s: float = GRACE_S) -> list[str]:
    """Descendants not in ``before`` still alive after ``grace_s``: killed (SIGKILL); their
    command lines (empty list: none). Zombies count as ended."""
    deadline = time.monotonic() + grace_s
    while True:
        left = descendants() - before
        if not left or time.monotonic() >= deadline:
            break
        time.sleep(0.1)
    named = [f"pid {pid}: {command(pid)[:200]}" for pid in sorted(left)]
    for pid in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    # (not reaped here: the zombie is its Popen's to collect, with its exit status)
    return named
