"""The whole skin graph in one process on one executor, with plain rclpy.

For machines without ``launch`` (``ros2 launch`` needs launch_ros): the same nodes and
parameters as ``launch/skin.launch.py``. In one process, python-can's ``virtual`` interface
connects the simulator to the driver, so the full pipeline runs with no hardware.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode
from tactile_contact.ros.skin_driver import SkinDriver, default_layout_path


@dataclass
class GraphConfig:
    """What to start. Parameter dicts override the nodes' defaults (config/*.yaml)."""

    layout: str = ""
    bundles_dir: str = "bundles"
    simulate: bool = True
    interface: str = "virtual"
    channel: str = "tactile_contact"
    scenario: str = "sweep"
    namespace: str = ""
    driver: dict[str, Any] = field(default_factory=dict)
    reconstruction: dict[str, Any] = field(default_factory=dict)
    simulator: dict[str, Any] = field(default_factory=dict)

    @property
    def layout_path(self) -> str:
        return self.layout or str(default_layout_path())


def _overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


def make_nodes(config: GraphConfig, context: Context) -> list[Node]:
    """Simulator (optional), driver and reconstruction nodes, in data-flow order.

    Created the other way round, readers first: the reconstruction loads and warms up its
    bundles (seconds while numba's cache is cold), and a simulator already sending would play
    its scenario to nobody meanwhile.
    """
    common = {"context": context, "namespace": config.namespace}
    bus = {"interface": config.interface, "channel": config.channel}
    # The layout tells the reconstruction which patches need a bundle: one without is an
    # error it reports (and the summary below), not an empty contact topic.
    recon = {"bundles_dir": str(Path(config.bundles_dir)), "layout": config.layout_path}
    nodes: list[Node] = [
        ContactReconstructionNode(
            parameter_overrides=_overrides({**recon, **config.reconstruction}), **common
        ),
        SkinDriver(
            parameter_overrides=_overrides({"layout": config.layout_path, **bus, **config.driver}),
            **common,
        ),
    ]
    if config.simulate:
        from tactile_contact.ros.skin_simulator import SkinSimulatorNode

        sim_params = {"layout": config.layout_path, "scenario": config.scenario, **bus}
        nodes.append(
            SkinSimulatorNode(
                parameter_overrides=_overrides({**sim_params, **config.simulator}), **common
            )
        )
    return nodes[::-1]


@contextmanager
def running_graph(
    config: GraphConfig, context: Context, extra_nodes: tuple[Node, ...] = ()
) -> Iterator[SingleThreadedExecutor]:
    """Create the graph, yield its executor (spin it yourself), destroy everything after.

    One executor thread: the driver and the simulator receive and send in threads of their
    own, and a multi-threaded executor driven by ``spin_once`` re-polls entities whose callback
    is still queued (measured: a busy core for nothing).
    """
    nodes = make_nodes(config, context)
    executor = SingleThreadedExecutor(context=context)
    for node in (*nodes, *extra_nodes):
        executor.add_node(node)
    try:
        yield executor
    finally:
        executor.shutdown(timeout_sec=2.0)
        for node in reversed(nodes):
            node.destroy_node()


def summarise(nodes: Iterable[Node]) -> tuple[list[str], list[str]]:
    """What the graph's nodes did, as lines for the end of a run (frames, contacts, forces,
    anything dropped), and what kept it from its job (no bus, a patch without a bundle, a
    driver not running): an empty second list means nothing did."""
    lines: list[str] = []
    problems: list[str] = []
    published: dict[str, int] = {}
    for node in nodes:
        if isinstance(node, SkinDriver):
            lines += [f"skin_driver: {line}" for line in node.summary()]
            published.update(node.published())
            state = node.state_label()
            if state != "active":
                problems.append(f"skin_driver is {state}, not active (its log says why)")
            elif not node.bus_opened:
                problems.append(f"the CAN bus never opened: {node.bus_problem()}")
    for node in nodes:
        if isinstance(node, ContactReconstructionNode):
            lines += [f"contact_reconstruction: {line}" for line in node.summary()]
            for name, pipe in node.pipelines.items():
                skipped = published.get(name, 0) - pipe.stats.frames
                if skipped > 0:
                    lines.append(
                        f"contact_reconstruction: {name}: {skipped} of {published[name]} "
                        "frames not taken (it keeps the newest when busy)"
                    )
            problems += [f"patch {name}: {error}" for name, error in node.load_errors.items()]
    return lines, problems
