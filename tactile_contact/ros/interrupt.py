"""Ctrl-C for the node executables: one KeyboardInterrupt, then a bounded way out.

Standard library only, so that an executable installs it (:func:`catch_interrupts`) before
its heavy imports (numpy, scipy, numba, rclpy: several seconds on a busy machine). Why: until
then Python's default handler raises a KeyboardInterrupt wherever the import is, and where that
is a ctypes callback or a finaliser, Python prints it and carries on ("Exception ignored …"):
the node started anyway and ran on, unasked, serving its patches beside the next test's
(CI: a contact_reconstruction sent SIGINT 0.4 s after its start was still up 20 s later, and
the eight ROS tests after it failed). With this handler, the first SIGINT also arms
:func:`exit_if_stuck`, and :func:`interrupted` tells ``run_node`` not to start the node.
"""

from __future__ import annotations

import contextlib
import faulthandler
import importlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Iterator
from typing import Any

#: A node still running this long after its shutdown began (Ctrl-C, or its spin ended) is stuck
#: in a library's cleanup: it says where and exits. Why: CI saw worker_monitor hang after
#: Ctrl-C (once in ≈ 10 runs of the suite's ≈ 20 launches; ros2 launch escalated to SIGTERM, which
#: rclpy's handler turns into a context shutdown only, then SIGKILL 15 s later). Below the 5 s
#: after which ros2 launch escalates. [s]
STUCK_AFTER_S = 4.0
_cleaned_up = threading.Event()  # run_node's cleanup returned: the Python watcher ends
_interrupted = threading.Event()  # a SIGINT came (whether or not its KeyboardInterrupt landed)
_deferred = threading.Event()  # while set, a SIGINT is noted, not raised (see deferred())
_node_name = ["node"]  # the name run_node runs, for the stuck message
_starting = threading.Event()  # run_node is building the node (the stuck message says so)
_spinning = threading.Event()  # run_node spins the node: a callback may still be running
_watcher: list[threading.Thread] = []


def exit_if_stuck(code: int = 0, after_s: float = STUCK_AFTER_S) -> None:
    """From now on, if this process is still here ``after_s`` s later, print where its main
    thread is and exit with ``code`` (the code the shutdown was going to end with). Armed once;
    later calls do nothing.

    Two watchers: a Python thread, which runs while the main thread waits with the GIL released
    (a lock, a join, an rcl call that releases it) and exits with ``code``; and, one second
    later, faulthandler's C thread, which needs no GIL (a deadlock inside a C call that holds
    it) and dumps every thread's stack, then exits with 1. The first ends when run_node's
    cleanup returns; the second stays armed for the interpreter's own exit (where no Python
    thread runs any more).
    """
    if _watcher:
        return
    main = threading.main_thread().ident

    def watch() -> None:
        if _cleaned_up.wait(after_s):
            return
        name = _node_name[0]  # (armed by a SIGINT in the imports, before run_node named it)
        frame = sys._current_frames().get(main) if main is not None else None
        where = "".join(traceback.format_stack(frame)) if frame is not None else "(not found)\n"
        if _starting.is_set():  # (a Ctrl-C while the node was built: it is not stuck)
            what = (
                f"still starting {after_s:.0f} s after the Ctrl-C (building the node: its "
                "model takes long on a busy machine)"
            )
        elif _spinning.is_set():  # (the Ctrl-C waits for the callback running to return)
            what = (
                f"still in a callback {after_s:.0f} s after the Ctrl-C (its work unfinished, "
                "the node's cleanup skipped)"
            )
        else:
            what = (
                f"still shutting down {after_s:.0f} s after it began (stuck in a library's cleanup)"
            )
        sys.stderr.write(f"WARNING: {name}: {what}; exiting now. Its main thread was in:\n{where}")
        sys.stderr.flush()
        os._exit(code)

    _watcher.append(threading.Thread(target=watch, name="exit_if_stuck", daemon=True))
    _watcher[0].start()
    faulthandler.dump_traceback_later(after_s + 1.0, exit=True)


def starting() -> contextlib.AbstractContextManager[None]:
    """run_node builds the node in this block (the stuck message says it is still starting)."""
    return _holding(_starting)


def spinning() -> contextlib.AbstractContextManager[None]:
    """run_node spins the node in this block (the stuck message says a callback runs)."""
    return _holding(_spinning)


@contextlib.contextmanager
def _holding(flag: threading.Event) -> Iterator[None]:
    """``flag`` set for the block (cleared however it ends)."""
    flag.set()
    try:
        yield
    finally:
        flag.clear()


def name_the_node(name: str) -> None:
    """The name the stuck message gives (run_node's node)."""
    _node_name[0] = name


def shutdown_finished() -> None:
    """run_node's cleanup returned: the Python watcher ends (joined: nothing of run_node's
    outlives it); faulthandler's stays armed for the interpreter's exit."""
    _cleaned_up.set()
    for watcher in _watcher:
        watcher.join(timeout=1.0)


def interrupt_once(signum: int, frame: Any) -> None:
    """SIGINT: a KeyboardInterrupt the first time, ignored from then on. Why: a Ctrl-C in a
    terminal reaches every process of the group and ros2 launch forwards its own, so a node
    gets two, often milliseconds apart; the second, raised while the first was being handled
    (before the cleanup could ignore it), escaped run_node and killed the process by SIGINT
    (ros2 launch: "process has died … exit code -2", seen in CI). The first also arms
    :func:`exit_if_stuck`: if its KeyboardInterrupt is swallowed where it lands, the process
    still ends. Inside :func:`deferred` it is only noted."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if not _interrupted.is_set():
        _interrupted.set()
        exit_if_stuck()
        if not _deferred.is_set():
            raise KeyboardInterrupt


def deferred() -> contextlib.AbstractContextManager[None]:
    """A SIGINT in this block raises no KeyboardInterrupt (:func:`interrupted` says it came;
    rclpy's own handler still shuts the context down). Why: run_node builds the node in one,
    because a KeyboardInterrupt raised inside numba while it loaded a cached kernel crashed
    the process (SIGSEGV in numba's codegen.set_env, 0.07 s after the SIGINT; a double free at
    exit another time): about once in 40–80 SIGINTs timed to land in the build; and spins it
    in one (raised inside a busy callback, the executor logged it as FATAL)."""
    return _holding(_deferred)


def catch_interrupts() -> None:
    """Install :func:`interrupt_once` for SIGINT (unless a SIGINT already came: then it stays
    ignored)."""
    if not _interrupted.is_set():
        signal.signal(signal.SIGINT, interrupt_once)


def interrupted() -> bool:
    """Whether a SIGINT has come since :func:`catch_interrupts` (its KeyboardInterrupt may have
    been lost in a library that swallowed it)."""
    return _interrupted.is_set()


def leave_if_interrupted() -> None:
    """After a Ctrl-C, end the process now, without the interpreter's finalisation (its own
    cleanup has run: run_node's). Why: a SIGINT while the node was being built once left a
    half-made native object to the final garbage collection, which crashed ("free(): double
    free detected", SIGABRT, in a loop of timed SIGINTs); whatever an interrupt leaves half
    done is not worth finalising."""
    if _interrupted.is_set():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


def run_executable(module: str) -> None:
    """A node executable (scripts/): the handler first, then ``module``'s imports (a Ctrl-C
    there leaves with 130, as after start), its ``main()``, then :func:`leave_if_interrupted`."""
    catch_interrupts()
    try:
        main = importlib.import_module(module).main
    except KeyboardInterrupt:  # Ctrl-C while the modules load: leave quietly, as after start
        raise SystemExit(130) from None
    main()
    leave_if_interrupted()
