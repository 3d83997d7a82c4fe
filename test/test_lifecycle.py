"""Clean start and stop of every node (issue 17): no traceback, no "cannot use Destroyable",
no leaked CAN bus or thread.

- Each node is started and stopped 20 times in this process, stopped the way Ctrl-C stops it
  (the context shut down while the executor spins and the node's threads publish), with
  frames flowing; threads and python-can virtual buses are counted before and after.
- The driver goes through configure / activate / deactivate / cleanup 20 times over its
  lifecycle services, as ``ros2 lifecycle set`` drives it.
- Each node executable gets a real SIGINT, during start-up and while running; the two ways a
  SIGINT can meet a node still being built (its context shut down under an rcl call, or a
  KeyboardInterrupt after the node's thread started) are also reproduced on purpose.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from can.interfaces import virtual

from tactile_contact.sim.simulator import simulator_for_patch

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"
BAD_OUTPUT = ("Traceback", "cannot use Destroyable", "Exception in thread", "InvalidHandle")
CYCLES = 20


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(LAYOUT, out)
    return out


@pytest.fixture
def thread_errors() -> Iterator[list[str]]:
    """Exceptions that escaped any thread (threading.excepthook), as text."""
    caught: list[str] = []
    old = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        where = "".join(traceback.format_tb(args.exc_traceback)[-3:])
        caught.append(f"{args.thread.name if args.thread else '?'}: {args.exc_value!r}\n{where}")

    threading.excepthook = hook
    try:
        yield caught
    finally:
        threading.excepthook = old


class Feeder:
    """Simulated skin frames on a virtual channel, from a thread, until stopped."""

    def __init__(self, channel: str) -> None:
        from tactile_contact.model.layout import load_layout

        self.sim = simulator_for_patch(load_layout(LAYOUT).patches[0], period_s=0.02)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="feeder", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        k = 0
        while not self.stop.wait(0.02):
            for m in self.sim.period(None, 0.02 * k).messages:
                self.bus.send(m)
            k += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.bus.shutdown()


def _make(name: str, context: Any, channel: str, bundles: Path) -> Any:
    from rclpy.parameter import Parameter

    if name == "skin_driver":
        from tactile_contact.ros.skin_driver import SkinDriver

        params = {"interface": "virtual", "channel": channel, "layout": str(LAYOUT)}
        params |= {"diagnostics_period_s": 0.1, "period_ms": 20, "calibration_samples": 2}
        cls: Any = SkinDriver
    elif name == "skin_simulator":
        from tactile_contact.ros.skin_simulator import SkinSimulatorNode

        params = {"interface": "virtual", "channel": channel, "layout": str(LAYOUT)}
        params |= {"period_ms": 20}
        cls = SkinSimulatorNode
    else:
        from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

        params = {"bundles_dir": str(bundles), "diagnostics_period": 0.1}
        cls = ContactReconstructionNode
    return cls(
        context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
    )


def _taxel_source(context: Any) -> tuple[Any, Any]:
    """A node publishing zero taxel frames of the hexagon patch (for the reconstruction)."""
    import numpy as np
    from rclpy.node import Node

    from tactile_contact.model.layout import load_layout
    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.common import publish_while_up

    node = Node("taxel_source", context=context)
    pub = node.create_publisher(TaxelArray, "hexagon/taxels", 5)
    ids = load_layout(LAYOUT).patches[0].taxel_ids().tolist()
    rng = np.random.default_rng(0)

    def tick() -> None:
        msg = TaxelArray(patch="hexagon", taxel_ids=ids, raw=[240] * len(ids))
        msg.delta_c = (rng.normal(0.0, 1e-16, len(ids))).astype(np.float32).tolist()
        msg.status = [0] * len(ids)
        msg.header.stamp = node.get_clock().now().to_msg()
        publish_while_up(node, pub, msg)  # (as the nodes' timers do: see the test below)

    node.create_timer(0.02, tick)
    return node, pub


@pytest.mark.parametrize("name", ["skin_driver", "skin_simulator", "contact_reconstruction"])
def test_node_starts_and_stops_20_times_cleanly(
    name: str, bundles: Path, capfd: pytest.CaptureFixture[str], thread_errors: list[str]
) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor

    from tactile_contact.ros.common import spin_until_shutdown

    channel = f"lifecycle-{name}"
    feeder = Feeder(channel) if name == "skin_driver" else None
    baseline = {t.ident for t in threading.enumerate()}
    buses_before = len(virtual.channels.get(channel, []))
    try:
        for cycle in range(CYCLES):
            context = Context()
            rclpy.init(context=context)
            node = _make(name, context, channel, bundles)
            extra = _taxel_source(context)[0] if name == "contact_reconstruction" else None
            # the executor run_node gives each node
            executor = (
                EventsExecutor(context=context)
                if name == "contact_reconstruction"
                else SingleThreadedExecutor(context=context)
            )
            executor.add_node(node)
            if extra is not None:
                executor.add_node(extra)

            def spin(ex: Any = executor, ctx: Context = context) -> None:
                with contextlib.suppress(ExternalShutdownException):
                    spin_until_shutdown(ex, ctx)  # as run_node spins

            spinner = threading.Thread(target=spin, name="spin")
            spinner.start()
            time.sleep(0.05 + 0.1 * (cycle % 3))  # vary the moment of the "Ctrl-C"
            # What rclpy's SIGINT handler does: shut the context down under the running
            # executor and the node's own threads; then the node is destroyed (run_node).
            context.try_shutdown()
            spinner.join(5.0)
            assert not spinner.is_alive(), "the executor did not stop"
            executor.shutdown(timeout_sec=1.0)
            if extra is not None:
                extra.destroy_node()
            node.destroy_node()
    finally:
        if feeder is not None:
            feeder.close()
    leftover = [t.name for t in threading.enumerate() if t.ident not in baseline and t.is_alive()]
    assert not leftover, f"threads left after {CYCLES} start/stop cycles: {leftover}"
    assert len(virtual.channels.get(channel, [])) <= max(buses_before - 1, 0), "a bus leaked"
    out, err = capfd.readouterr()
    for text in BAD_OUTPUT:
        assert text not in out + err, f"{text!r} printed:\n{(out + err)[-3000:]}"
    assert not thread_errors, thread_errors


def test_driver_lifecycle_transitions_20_times_over_its_services(
    ros_context: Any, capfd: pytest.CaptureFixture[str], thread_errors: list[str]
) -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    channel = "lifecycle-transitions"
    feeder = Feeder(channel)
    node = _make("skin_driver", ros_context, channel, Path())
    # autostart: configured and active at once; ros2 lifecycle then drives it by services.
    manager = Node("lifecycle_manager", context=ros_context)
    change = manager.create_client(ChangeState, "/skin_driver/change_state")
    get = manager.create_client(GetState, "/skin_driver/get_state")
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(manager)
    stop = threading.Event()
    spinner = threading.Thread(
        target=lambda: [executor.spin_once(timeout_sec=0.01) for _ in iter(stop.is_set, True)]
    )
    spinner.start()

    def call(client: Any, request: Any) -> Any:
        assert client.wait_for_service(timeout_sec=5.0)
        future = client.call_async(request)
        deadline = time.monotonic() + 5.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.005)
        assert future.done(), "no answer"
        return future.result()

    def transition(tid: int) -> None:
        result = call(change, ChangeState.Request(transition=Transition(id=tid)))
        assert result.success, tid

    def state() -> str:
        return call(get, GetState.Request()).current_state.label

    try:
        assert state() == "active"
        threads_active = {t.ident for t in threading.enumerate()}
        for _ in range(CYCLES):
            transition(Transition.TRANSITION_DEACTIVATE)
            assert state() == "inactive"
            transition(Transition.TRANSITION_CLEANUP)
            assert state() == "unconfigured" and all(link.bus is None for link in node._links)
            assert not any(t.name == "skin_rx" for t in threading.enumerate())
            transition(Transition.TRANSITION_CONFIGURE)
            transition(Transition.TRANSITION_ACTIVATE)
            assert state() == "active"
            time.sleep(0.05)  # frames flow, the receive thread publishes
        assert {t.ident for t in threading.enumerate() if t.is_alive()} - threads_active <= {
            node._links[0].thread.ident
        }
        transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert state() == "finalized" and all(link.bus is None for link in node._links)
    finally:
        stop.set()
        spinner.join(5.0)
        executor.shutdown()
        node.destroy_node()
        manager.destroy_node()
        feeder.close()
    assert not [t for t in threading.enumerate() if t.name == "skin_rx"], "receive thread leaked"
    assert len(virtual.channels.get(channel, [])) == 0, "a bus leaked"
    out, err = capfd.readouterr()
    for text in BAD_OUTPUT:
        assert text not in out + err, f"{text!r} printed:\n{(out + err)[-3000:]}"
    assert not thread_errors, thread_errors


@pytest.mark.parametrize("name", ["skin_driver", "skin_simulator", "contact_reconstruction"])
def test_sigint_during_start_up_and_while_running_is_clean(name: str, bundles: Path) -> None:
    """The installed executable (scripts/) under a real SIGINT, early and late."""
    args = {
        "skin_driver": ["-p", "interface:=virtual"],
        "skin_simulator": ["-p", "interface:=virtual"],
        "contact_reconstruction": ["-p", f"bundles_dir:={bundles}"],
    }[name]
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    for delay in (0.4, None):  # during the imports; after the node says it is up
        proc = subprocess.Popen(
            [sys.executable, str(ROOT / "scripts" / name), "--ros-args", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=env,
            text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        lines: list[str] = []
        reader = threading.Thread(
            target=lambda p=proc, out=lines: out.extend(p.stdout), daemon=True
        )
        reader.start()
        if delay is not None:
            time.sleep(delay)
        else:
            ready = ("active: publishing", "simulating patch", "traction grid")
            deadline = time.monotonic() + 30.0
            while not any(r in line for line in list(lines) for r in ready):
                assert time.monotonic() < deadline, "".join(lines)[-2000:]
                time.sleep(0.05)
            time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=20.0)
        except subprocess.TimeoutExpired:
            # Not left running: a node serving the hexagon beside the next tests failed eight
            # of them. SIGABRT first, for faulthandler's stacks of every thread.
            proc.send_signal(signal.SIGABRT)
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            reader.join(5.0)
            pytest.fail(
                f"{name} still running 20 s after SIGINT ({delay=}):\n" + "".join(lines)[-6000:]
            )
        reader.join(5.0)
        # −SIGINT (a shell shows 130): the process ended by the signal's default action,
        # quietly, as any program under Ctrl-C. Two ways, neither ours to change: the ROS
        # wheels' bootstrapper (a .pth) re-executes the interpreter at start, which runs
        # without Python's handler for its first ≈ 0.1 s; and CPython 3.11 marks a
        # KeyboardInterrupt raised inside exec() of a string (scipy's array_api_compat loads
        # numpy that way, during the simulator's start-up) as unhandled even though run_node
        # catches it, and at exit re-raises SIGINT on itself.
        assert code in (0, 130, -signal.SIGINT), f"exit {code}: " + "".join(lines)[-2000:]
        text = "".join(lines)
        for bad in BAD_OUTPUT:
            assert bad not in text, f"{name}, SIGINT after {delay} s: {bad!r}\n{text[-3000:]}"


# A SIGINT while the node is being built, at the two moments a timed signal only hits by chance
# (on a busy machine): run_node builds the node through ``factory``.
_INTERRUPTED_START = """
import sys, threading
import rclpy
from tactile_contact.ros import common
from tactile_contact.ros.skin_driver import SkinDriver
from tactile_contact.ros.skin_simulator import SkinSimulatorNode

cls = {"skin_driver": SkinDriver, "skin_simulator": SkinSimulatorNode}[sys.argv[1]]

def context_shut_down_under_the_constructor():
    # What rclpy's signal thread does while this thread is still in an rcl call: the
    # KeyboardInterrupt would come later, the RCLError of the call first.
    rclpy.get_default_context().handle.shutdown()
    return cls()

class InterruptedOnceStarted(cls):
    interrupted = False

    def get_logger(self):
        # the first log line of this thread after the node's own thread started
        started = any(t.name in ("skin_rx", "skin_sim") for t in threading.enumerate())
        main = threading.current_thread() is threading.main_thread()
        if started and main and not self.interrupted:
            InterruptedOnceStarted.interrupted = True
            # a real SIGINT: the context shut down (not through rclpy.shutdown, so it destroys
            # no node), then the KeyboardInterrupt
            rclpy.get_default_context().handle.shutdown()
            raise KeyboardInterrupt
        return super().get_logger()

factory = {"shutdown": context_shut_down_under_the_constructor, "interrupt": InterruptedOnceStarted}
common.run_node(sys.argv[1], factory[sys.argv[2]], ["--ros-args", "-p", "interface:=virtual"])
print("threads left:", sorted(t.name for t in threading.enumerate() if t.name != "MainThread"))
"""


@pytest.mark.parametrize("how", ["shutdown", "interrupt"])
@pytest.mark.parametrize("name", ["skin_driver", "skin_simulator"])
def test_sigint_while_the_node_is_built_is_clean(name: str, how: str) -> None:
    done = subprocess.run(
        [sys.executable, "-c", _INTERRUPTED_START, name, how],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    text = done.stdout + done.stderr
    assert done.returncode == 0, text[-3000:]
    for bad in (*BAD_OUTPUT, "ERROR"):
        assert bad not in text, f"{name}, {how}: {bad!r}\n{text[-3000:]}"
    left = [line for line in done.stdout.splitlines() if line.startswith("threads left:")]
    assert left == ["threads left: []"], text[-3000:]


# An executable's start (scripts/): the handler first, then the imports, in one of which a
# library swallows the KeyboardInterrupt of a real SIGINT (as a ctypes callback or a finaliser
# does: Python prints "Exception ignored …" and goes on).
_SWALLOWED_IN_IMPORTS = """
import os, signal, sys, time
from tactile_contact.ros.interrupt import catch_interrupts
import tactile_contact.ros.contact_reconstruction as m  # (first: its time is not the test's)

catch_interrupts()
try:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5.0)  # (the handler raises here)
except KeyboardInterrupt:
    print("swallowed by a library")
os.kill(os.getpid(), signal.SIGINT)  # a second Ctrl-C: ignored, as before
built = []

class Counted(m.ContactReconstructionNode):
    def __init__(self, **kwargs):
        built.append(1)
        super().__init__(**kwargs)

m.ContactReconstructionNode = Counted
m.main(["--ros-args", "-p", "bundles_dir:=" + sys.argv[1]])
print("node built:", len(built))
"""


def test_a_sigint_lost_in_the_imports_still_ends_the_node(bundles: Path) -> None:
    """The CI failure this guards: a SIGINT during the imports whose KeyboardInterrupt a
    library swallowed; the node then started anyway and served on. Now run_node sees the
    interrupt and builds nothing, and the process ends at once (not by the stuck watcher)."""
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", _SWALLOWED_IN_IMPORTS, str(bundles)],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    took = time.monotonic() - t0
    text = done.stdout + done.stderr
    assert done.returncode == 0, text[-3000:]
    assert "swallowed by a library" in done.stdout, text[-3000:]
    assert "node built: 0" in done.stdout, text[-3000:]
    assert "still shutting down" not in text, text[-3000:]
    assert took < 30.0, (took, text[-3000:])


def _late_publisher(
    node: Any, pub: Any, bare: bool, inside: threading.Event, down: threading.Event, done: list
) -> Any:
    """A timer callback that, the first time, waits until the context is down, then publishes
    (bare: straight; else through publish_while_up, its result in ``done``)."""
    from std_msgs.msg import String

    from tactile_contact.ros.common import publish_while_up

    def callback() -> None:
        if inside.is_set():
            return
        inside.set()
        down.wait(5.0)
        if bare:
            pub.publish(String(data="late"))  # raises: the context is gone
        else:
            done.append(publish_while_up(node, pub, String(data="late")))

    return callback


@pytest.mark.parametrize("executor_kind", ["events", "single"])
def test_a_callback_that_publishes_while_the_context_is_shut_down_ends_the_spin_quietly(
    executor_kind: str, capfd: pytest.CaptureFixture[str], thread_errors: list[str]
) -> None:
    """The race a loaded machine hit in the 20 start/stop cycles above: rclpy's SIGINT handler
    shuts the context down (from another thread) while a callback runs; the callback's
    publish then fails ("publisher's context is invalid", or InvalidHandle once the publisher
    is destroyed). Made to happen every time here: the callback waits until the context is
    down, then publishes, once through publish_while_up (the nodes' way: nothing raised) and
    once bare (spin_until_shutdown: the spin ends as the shutdown does, nothing escapes)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from std_msgs.msg import String

    from tactile_contact.ros.common import spin_until_shutdown

    for bare in (False, True):
        context = Context()
        rclpy.init(context=context)
        node = Node("racer", context=context)
        pub = node.create_publisher(String, "race", 5)
        inside, down, done = threading.Event(), threading.Event(), []

        # (built by a function: rclpy hands a TimerInfo to a callback that takes an argument)
        callback = _late_publisher(node, pub, bare, inside, down, done)
        node.create_timer(0.005, callback)
        cls = EventsExecutor if executor_kind == "events" else SingleThreadedExecutor
        executor = cls(context=context)
        executor.add_node(node)
        spinner = threading.Thread(target=spin_until_shutdown, args=(executor, context))
        spinner.start()
        assert inside.wait(5.0)
        context.try_shutdown()
        down.set()
        spinner.join(5.0)
        assert not spinner.is_alive()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        assert done == ([] if bare else [False])
    assert not thread_errors, thread_errors
