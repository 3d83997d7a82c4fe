"""Small helpers shared by the package's nodes: QoS, stamps, parameters, diagnostics.

Everything here is a thin convenience over rclpy; no node logic lives in this module.

- :data:`SENSOR_QOS` for high-rate streams, :data:`STATIC_QOS` for data published once,
  :data:`DIAGNOSTICS_QOS` for ``/diagnostics``.
- :func:`stamp_from_seconds` / :func:`seconds_from_stamp`: python-can float seconds ↔
  ``builtin_interfaces/Time``.
- :func:`declare_parameter`: declare with a descriptor (description, unit, range or choices) and
  return the value; out-of-range or unknown choices are rejected at declaration and on later sets.
- :func:`log_parameters`: one info line at start with the parameters set away from their
  defaults (every value at debug level).
- :func:`diagnostic_status`: a ``DiagnosticStatus`` from a name, level, message and key/values.
- :func:`run_node`: the standard ``main()`` of a node executable.
- :func:`publish_while_up`: publish, unless the context was shut down under the caller (Ctrl-C
  while a callback runs); :func:`spin_until_shutdown` ends quietly on such a failure too.
"""

from __future__ import annotations

import gc
import math
import signal
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy._rclpy_pybind11 import RCLError
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from tactile_contact.ros.interrupt import (
    catch_interrupts,
    deferred,
    exit_if_stuck,
    interrupted,
    name_the_node,
    shutdown_finished,
    spinning,
    starting,
)

#: High-rate streams (taxels, grids): best effort, keep last 5, volatile (the ROS sensor profile).
SENSOR_QOS: QoSProfile = qos_profile_sensor_data

#: Data published once or rarely (geometry, layouts): reliable, transient local, keep last 1, so a
#: late subscriber still receives it.
STATIC_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

#: ``/diagnostics`` as diagnostic_updater publishes it: reliable, volatile, keep last 10.
DIAGNOSTICS_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

#: Diagnostic levels as plain ints (the message stores them as one byte).
OK, WARN, ERROR, STALE = 0, 1, 2, 3


def stamp_from_seconds(seconds: float) -> Time:
    """``builtin_interfaces/Time`` from float seconds (python-can ``Message.timestamp``).

    Rounded to the nearest nanosecond; negative or non-finite input raises ValueError (a stamp
    before the epoch is never a receive time).
    """
    if not math.isfinite(seconds) or seconds < 0.0:
        raise ValueError(f"stamp seconds must be finite and >= 0, got {seconds!r}")
    total_ns = round(seconds * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)


def seconds_from_stamp(stamp: Time) -> float:
    """Float seconds of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


#: Sentinel default for a string-array parameter whose default is empty (rclpy cannot infer the
#: type of ``[]``).
STRING_ARRAY_EMPTY: Any = object()

_CHOICES_ATTR = "_tactile_contact_parameter_choices"
_DEFAULTS_ATTR = "_tactile_contact_parameter_defaults"


def _check_choices(node: Node, params: Sequence[Parameter]) -> SetParametersResult:
    choices: dict[str, tuple[str, ...]] = getattr(node, _CHOICES_ATTR)
    for p in params:
        allowed = choices.get(p.name)
        if allowed is not None and p.value not in allowed:
            return SetParametersResult(
                successful=False,
                reason=f"{p.name}={p.value!r} is not one of {', '.join(allowed)}",
            )
    return SetParametersResult(successful=True)


def read_at_start_only(node: Node) -> None:
    """Refuse every later set of ``node``'s parameters, naming why: a node that reads its
    parameters once at start. Why: ``ros2 param set`` answered "successful" and the parameter
    server then showed a value the running node did not use (bundles_dir, input,
    diagnostics_period, worker_count). Call it after the node's last declaration."""
    name = node.get_name()

    def refuse(params: Sequence[Parameter]) -> SetParametersResult:
        names = ", ".join(p.name for p in params)
        return SetParametersResult(
            successful=False,
            reason=f"{name} reads its parameters at start only: restart it with the new "
            f"value (--ros-args -p NAME:=VALUE) to change {names}",
        )

    node.add_on_set_parameters_callback(refuse)


def declare_parameter(
    node: Node,
    name: str,
    default: Any,
    description: str,
    *,
    unit: str = "",
    int_range: tuple[int, int] | None = None,
    float_range: tuple[float, float] | None = None,
    choices: Sequence[str] | None = None,
    read_only: bool = False,
) -> Any:
    """Declare ``name`` with a descriptor and return its value (override or ``default``).

    Args:
        node: the node owning the parameter.
        name: parameter name.
        default: default value; its Python type fixes the parameter type. rclpy cannot infer
            the type of ``[]``: pass :data:`STRING_ARRAY_EMPTY` for an empty string array.
        description: what the parameter does; ``unit`` is appended as ``[unit]``.
        int_range / float_range: inclusive (low, high) bounds enforced by rclpy on declaration and
            on every later set.
        choices: allowed values of a string parameter, enforced the same way.
        read_only: rclpy refuses later sets.

    Raises:
        rclpy.exceptions.InvalidParameterValueException: the override is out of range or not
            one of ``choices``.
    """
    text = f"{description} [{unit}]" if unit else description
    descriptor = ParameterDescriptor(name=name, description=text, read_only=read_only)
    if int_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=1)
        ]
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(
                from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0
            )
        ]
    if choices is not None:
        descriptor.additional_constraints = f"one of: {', '.join(choices)}"
        if not hasattr(node, _CHOICES_ATTR):
            setattr(node, _CHOICES_ATTR, {})
            node.add_on_set_parameters_callback(lambda ps: _check_choices(node, ps))
        getattr(node, _CHOICES_ATTR)[name] = tuple(choices)
    if not hasattr(node, _DEFAULTS_ATTR):
        setattr(node, _DEFAULTS_ATTR, {})
    getattr(node, _DEFAULTS_ATTR)[name] = [] if default is STRING_ARRAY_EMPTY else default
    if default is STRING_ARRAY_EMPTY:
        value = node.declare_parameter(name, Parameter.Type.STRING_ARRAY, descriptor).value
        if value is None:  # no override: give it a typed empty value so get_parameter works
            node.set_parameters([Parameter(name, Parameter.Type.STRING_ARRAY, [])])
            return []
        return list(value)
    value = node.declare_parameter(name, default, descriptor).value
    return list(value) if isinstance(value, (list, tuple)) else value


def log_parameters(node: Node, names: Iterable[str]) -> None:
    """Log the parameters at start, for the record: one info line naming those set away from
    their declared defaults (the rest are the defaults of config/<node>.yaml), and every value
    in one debug line (``--ros-args --log-level <node>:=debug``)."""
    defaults: dict[str, Any] = getattr(node, _DEFAULTS_ATTR, {})
    values = {name: node.get_parameter(name).value for name in names}
    for name, v in values.items():
        if isinstance(v, (tuple, list)) or type(v).__name__ == "array":
            values[name] = list(v)
    changed = [f"{n}={v!r}" for n, v in values.items() if n not in defaults or v != defaults[n]]
    rest = len(values) - len(changed)
    log = node.get_logger()
    if changed:
        log.info(f"parameters: {', '.join(changed)} (the other {rest} at their defaults)")
    else:
        log.info(f"parameters: all {rest} at their defaults")
    log.debug("every parameter: " + ", ".join(f"{n}={v!r}" for n, v in values.items()))


def diagnostic_status(
    name: str,
    level: int,
    message: str,
    values: Mapping[str, object],
    hardware_id: str = "",
) -> DiagnosticStatus:
    """A ``DiagnosticStatus``; ``level`` is one of OK, WARN, ERROR, STALE; values become strings.

    Floats are written with 6 significant digits, everything else with ``str``.
    """
    if level not in (OK, WARN, ERROR, STALE):
        raise ValueError(f"diagnostic level must be 0..3 (OK, WARN, ERROR, STALE), got {level!r}")
    kvs = [
        KeyValue(key=str(k), value=f"{v:.6g}" if isinstance(v, float) else str(v))
        for k, v in values.items()
    ]
    return DiagnosticStatus(
        level=bytes([level]), name=name, message=message, hardware_id=hardware_id, values=kvs
    )


SPIN_STEP_S = 0.1  # a missed wake-up delays the exit by this much, never forever


def spin_until_shutdown(
    executor: Executor,
    context: Context | None = None,
    until: Callable[[], bool] | None = None,
) -> None:
    """Spin ``executor`` until ``context`` (default: rclpy's) is shut down, in bounded steps.

    Why not ``executor.spin()``: the EventsExecutor's ignored Ctrl-C (rclpy 9.1), and the
    SingleThreadedExecutor's, which waits without a timeout, hung once in the lifecycle test
    (60 shutdowns under a spinning executor a run, over many runs; cause not found). A wait
    of at most ``SPIN_STEP_S`` re-checks the context whatever woke it or failed to.

    A callback that fails because the context was shut down while it ran (rclpy's SIGINT
    handler does that from another thread: a publish then raises "publisher's context is
    invalid", or InvalidHandle once the entity is destroyed) ends the spin as the shutdown
    does; any other failure, or one while the context is up, propagates. ``until``: also
    end when it says so (run_node: a Ctrl-C noted while the spin defers it).
    """
    ok = (context or rclpy.get_default_context()).ok
    while ok() and not (until is not None and until()):
        try:
            executor.spin_once(timeout_sec=SPIN_STEP_S)
        except ExternalShutdownException:
            return
        except (RCLError, InvalidHandle):
            if ok():
                raise
            return


def publish_while_up(node: Node, publisher: Any, msg: Any) -> bool:
    """Publish ``msg`` unless ``node``'s context is shut down, also when that happens during
    the call (a Ctrl-C while a callback runs: see :func:`spin_until_shutdown`); whether it was
    published. A failure while the context is up propagates."""
    if not node.context.ok():
        return False
    try:
        publisher.publish(msg)
    except (RCLError, InvalidHandle):
        if node.context.ok():
            raise
        return False
    return True


def run_node(
    name: str, factory: Callable[[], Node], args: list[str] | None = None, *, events: bool = False
) -> None:
    """Spin the node ``factory()`` makes until Ctrl-C or shutdown; if it cannot even be
    constructed (e.g. a parameter out of range), print ``ERROR: <name>: …`` and exit 1.

    Ctrl-C at any moment (during start-up too) ends it quietly: the executor is shut down,
    then the node destroyed (its threads joined, its bus closed), then the context.

    ``events``: rclpy's EventsExecutor instead of the SingleThreadedExecutor. Why: the
    latter rebuilds its wait set in Python for every callback, which for a node with 24
    subscriptions costs ≈ 190 µs per message taken, callback run and message published,
    against ≈ 90 µs (measured on this machine, 24 × 50 Hz). Either is spun by
    :func:`spin_until_shutdown`.
    """
    node = None
    executor = None
    initialized = False
    code = 0  # the exit code the shutdown ends with, should it get stuck
    name_the_node(name)
    # Before rclpy.init, so that rclpy's own handler (which shuts the context down) chains to it.
    # (The executables install it before their imports already: see interrupt.py.)
    catch_interrupts()
    try:
        try:
            if interrupted():  # a Ctrl-C during the imports whose KeyboardInterrupt was lost
                return
            rclpy.init(args=args)
            initialized = True
            with deferred(), starting():  # (a KeyboardInterrupt in numba's loading crashed it)
                node = factory()
            if interrupted():  # a Ctrl-C while the node was built
                return
            # What the node holds from now on (bundles, tables, rclpy's objects: ≈ 200 000 at
            # 24 patches) is left out of the cyclic collector's full passes: such a pass
            # stopped the node for ≈ 85 ms, ≈ 3.5 ms after this. (A bundle replaced later is
            # freed by reference counting; only a reference cycle in it would stay.)
            gc.collect()
            gc.freeze()
            if events:
                from rclpy.experimental import EventsExecutor

                executor = EventsExecutor()
            else:
                executor = SingleThreadedExecutor()
            executor.add_node(node)
            # A Ctrl-C while spinning is noted, not raised: raised inside a busy callback (a
            # worker's solve) the executor logged it as a FATAL "Exception in 'subscriptions'
            # callback" with a traceback. rclpy's handler shuts the context down, which ends
            # the spin after the callback; ``interrupted`` ends it if that did not. A callback
            # still running STUCK_AFTER_S later ends the process (exit_if_stuck says so).
            with deferred(), spinning():
                spin_until_shutdown(executor, until=interrupted)
        except ExternalShutdownException:
            pass
        except Exception as exc:
            # rclpy's SIGINT handler shuts the context down from a thread of its own, and the
            # KeyboardInterrupt follows only when this thread runs Python again: a Ctrl-C while
            # the node is being built (a long rcl call on a busy machine) surfaces first as an
            # RCLError "context is not valid" from that call. That is the Ctrl-C, not a node
            # that cannot start.
            if initialized and not rclpy.ok():
                return
            print(f"ERROR: {name}: {type(exc).__name__}: {exc}")  # could not start: say why
            code = 1
            raise SystemExit(1) from None
    except KeyboardInterrupt:  # (also when it comes while the handler above runs)
        pass
    finally:
        # A Ctrl-C in a terminal reaches every process of the group, and ros2 launch forwards
        # its own SIGINT too: a second one during the cleanup must not interrupt it (it left
        # a KeyboardInterrupt traceback from a thread join and a half-closed bus).
        # rclpy's shutdown puts back the handler it found, so ignore again after it: the
        # process is on its way out.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        exit_if_stuck(code)
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        shutdown_finished()
