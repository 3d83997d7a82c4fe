"""Skin pipeline on a robot: skin_driver → contact_reconstruction (+ simulator, + rviz2).

    ros2 launch tactile_contact skin.launch.py layout:=/path/layout.yaml bundles:=/path/bundles
    ros2 launch tactile_contact skin.launch.py use_simulator:=true
    ros2 launch tactile_contact skin.launch.py use_simulator:=true channel:=vcan0 use_rviz:=true
    # a second machine in the same ROS domain taking worker 2 of 3 (this one runs 0 and 1):
    ros2 launch tactile_contact skin.launch.py layout:=… bundles:=… workers:=2 worker_count:=3
    ros2 launch tactile_contact skin.launch.py layout:=… bundles:=… use_driver:=false \
        use_monitor:=false workers:=1 worker_count:=3 first_worker:=2

One skin_driver per CAN bus of the layout (its patches' ``bus``; docs/layout.md), publishing
each bus's readings in batches, or with ``drivers:=one`` one skin_driver reading every bus into
one stream of batches; the reconstruction runs as ``workers`` processes (default:
one per core, at most one per patch), each serving its share of the patches (balanced by
taxels, the same split on every machine: tactile_contact.ros.workers), restarted when one dies
(respawn), with ``worker_monitor`` reporting a dead worker's patches stale on /diagnostics.

Every node parameter that matters at bringup is a launch argument; the rest come from the
YAML files in config/ (copy and edit them, or override with ros2 param). With
use_simulator the simulator writes module frames to the same CAN bus the driver reads, and
they are separate processes, so the bus must be one processes can share. Left empty, the bus
is the robot's (socketcan, can0) without the simulator and, with it, python-can's
udp_multicast interface on loopback (no CAN hardware or vcan needed) with a multicast group
and a port of this ROS_DOMAIN_ID (GROUP:PORT, see ``simulation_channel``), so that
simulations in other ROS domains on the same machine do not hear each other. A SocketCAN vcan
works too (interface socketcan, channel vcan0). python-can's `virtual` interface is shared
within one process only: use `tactile-contact bringup --simulate` for that.

rviz2 is optional: when use_rviz is true and rviz2 is not installed, a warning says so and
everything else runs. Any of the package's nodes that exits ends the launch (and with it the
other nodes): a pipeline with a node missing is reported, not left half running.
"""

import os

from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, Shutdown
from launch.logging import get_logger
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = [
    ("namespace", "", "namespace of all nodes and topics"),
    ("layout", "", "patch layout YAML (empty: the package's config/hexagon_patch.yaml)"),
    ("bundles", "bundles", "folder of matrix bundles built by tactile-contact-build"),
    (
        "interface",
        "",
        "python-can interface of the skin bus (empty: socketcan; udp_multicast with use_simulator)",
    ),
    (
        "channel",
        "",
        "CAN channel of the skin bus (empty: can0; with use_simulator a multicast GROUP:PORT "
        "of this ROS_DOMAIN_ID)",
    ),
    ("use_simulator", "false", "start skin_simulator writing frames to the same channel"),
    ("scenario", "sweep", "simulator scenario: sweep, press or idle"),
    ("use_rviz", "false", "start rviz2 with the package's configuration"),
    ("use_sim_time", "false", "use /clock (e.g. when replaying a bag)"),
    (
        "workers",
        "auto",
        "reconstruction workers on this machine (auto: one per core, at most one per patch)",
    ),
    ("worker_count", "", "reconstruction workers over all machines (empty: workers)"),
    ("first_worker", "0", "index of this machine's first worker (another machine runs the others)"),
    ("use_driver", "true", "start skin_driver (false: only reconstruct)"),
    (
        "drivers",
        "per_bus",
        "per_bus: one skin_driver per bus of the layout; one: a single skin_driver reading every "
        "bus (one receive thread each, one taxel_batches stream: fewer messages and processes)",
    ),
    (
        "idle_every",
        "1",
        "skin_driver: an untouched patch's readings go out every this many periods, a touched "
        "one's every period (1: every reading; canbus.idle_gate)",
    ),
    ("use_monitor", "true", "start worker_monitor (one per robot: a dead worker on /diagnostics)"),
]
#: A dead worker is started again after this long [s] (launch respawn).
RESPAWN_DELAY_S = 0.5

#: python-can's default IPv4 group of its udp_multicast interface, and its default port.
MULTICAST_GROUP, MULTICAST_PORT = "239.74.163.2", 43113


def simulation_channel(domain_id: str, bus_index: int = 0) -> str:
    """The udp_multicast channel of a simulation in ROS domain ``domain_id``: python-can binds
    every such bus to its port on all addresses, and Linux then delivers every group joined on
    the machine at that port to it, so the port (43113 + domain id, + 256 per further bus of
    the layout) is what keeps two simulations, and two buses, apart."""
    domain = int(domain_id) if domain_id.strip().isdigit() else 0
    return f"{MULTICAST_GROUP}:{MULTICAST_PORT + domain + 256 * bus_index}"


def _true(context: LaunchContext, name: str) -> bool:
    return LaunchConfiguration(name).perform(context).strip().lower() in ("true", "1", "yes")


def _rviz2_installed() -> bool:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        get_package_prefix("rviz2")
    except PackageNotFoundError:
        return False
    return True


def _nodes(context: LaunchContext) -> list:
    """The nodes, with the bus and the layout resolved (defaults that depend on use_simulator)."""
    from ament_index_python.packages import get_package_share_directory

    share = get_package_share_directory("tactile_contact")

    def shared(folder: str, name: str) -> str:  # (test_launch.py checks that these exist)
        return os.path.join(share, folder, name)

    def defaults(node: str) -> dict:
        """config/<node>.yaml's parameters as a dict. Why not the file: it is keyed by the
        node's name, so a node started under another (skin_driver_can0, skin_simulator_can1,
        contact_reconstruction_1) got none of it and ran on its declared defaults — workers
        read per-patch topics instead of the batches (input: patches)."""
        import yaml

        with open(shared("config", f"{node}.yaml"), encoding="utf-8") as f:
            return dict(yaml.safe_load(f)[node]["ros__parameters"])

    arg = LaunchConfiguration
    simulate = _true(context, "use_simulator")
    interface = arg("interface").perform(context) or ("udp_multicast" if simulate else "socketcan")
    channel = arg("channel").perform(context)
    if not channel:
        channel = (
            simulation_channel(os.environ.get("ROS_DOMAIN_ID", "0"))
            if interface == "udp_multicast"
            else "can0"
        )
    layout = arg("layout").perform(context) or shared("config", "hexagon_patch.yaml")
    log = get_logger("skin.launch")
    log.info(f"skin bus: {interface}:{channel}; layout {layout}")
    common = {"use_sim_time": arg("use_sim_time")}

    def ends_launch(name: str) -> list:
        return [Shutdown(reason=f"{name} exited")]

    from tactile_contact.model.layout import load_layout

    buses = load_layout(layout).buses()
    single = buses == ("",) or len(buses) == 1

    def bus_channel(k: int, bus: str) -> str:
        if single:
            return channel
        if interface == "udp_multicast" and not arg("channel").perform(context):
            return simulation_channel(os.environ.get("ROS_DOMAIN_ID", "0"), k)
        return bus  # socketcan: the bus is named after its interface (can0, can1, ...)

    drivers = arg("drivers").perform(context).strip()
    if drivers not in ("per_bus", "one"):
        raise ValueError(f"drivers:={drivers!r}: per_bus or one")
    idle = arg("idle_every").perform(context).strip()
    if not (idle.isdigit() and 1 <= int(idle) <= 1000):
        raise ValueError(f"idle_every:={idle!r}: a whole number of periods, 1 to 1000")
    driving = {"layout": layout, "interface": interface, "idle_every": int(idle)}
    nodes = []
    if _true(context, "use_driver") and drivers == "one" and not single:
        nodes.append(
            Node(
                package="tactile_contact",
                executable="skin_driver",
                name="skin_driver",
                namespace=arg("namespace"),
                output="screen",
                on_exit=ends_launch("skin_driver"),
                parameters=[
                    defaults("skin_driver"),
                    {
                        **driving,
                        "buses": list(buses),
                        "channels": [bus_channel(k, bus) for k, bus in enumerate(buses)],
                    },
                    common,
                ],
            )
        )
    for k, bus in enumerate(buses):
        suffix = f"_{bus}" if not single else ""
        if _true(context, "use_driver") and (drivers == "per_bus" or single):
            nodes.append(
                Node(
                    package="tactile_contact",
                    executable="skin_driver",
                    name=f"skin_driver{suffix}",
                    namespace=arg("namespace"),
                    output="screen",
                    on_exit=ends_launch(f"skin_driver{suffix}"),
                    parameters=[
                        defaults("skin_driver"),
                        {
                            **driving,
                            "channel": bus_channel(k, bus),
                            "bus": bus,
                        },
                        common,
                    ],
                )
            )
        if simulate:
            on_bus = [p.name for p in load_layout(layout).patches if p.bus == bus]
            nodes.append(
                Node(
                    package="tactile_contact",
                    executable="skin_simulator",
                    name=f"skin_simulator{suffix}",
                    namespace=arg("namespace"),
                    output="screen",
                    on_exit=ends_launch(f"skin_simulator{suffix}"),
                    parameters=[
                        defaults("skin_simulator"),
                        {
                            "layout": layout,
                            "interface": interface,
                            "channel": bus_channel(k, bus),
                            "scenario": arg("scenario"),
                            "patches": on_bus,
                        },
                        common,
                    ],
                )
            )
    nodes += _workers(context, layout, common, defaults("contact_reconstruction"))
    if _true(context, "use_monitor"):
        nodes.append(
            Node(
                package="tactile_contact",
                executable="worker_monitor",
                name="worker_monitor",
                namespace=arg("namespace"),
                output="screen",
                on_exit=ends_launch("worker_monitor"),
                parameters=[defaults("worker_monitor"), common],
            )
        )
    if _true(context, "use_rviz"):
        if _rviz2_installed():
            nodes.append(
                Node(
                    package="rviz2",
                    executable="rviz2",
                    name="rviz2",
                    arguments=["-d", shared("rviz", "tactile_contact.rviz")],
                    parameters=[common],
                )
            )
        else:
            log.warning(
                "use_rviz: rviz2 is not installed, not started (the skin runs without it; "
                "install ros-$ROS_DISTRO-rviz2, or pass use_rviz:=false)"
            )
    return nodes


def _workers(context: LaunchContext, layout: str, common: dict, defaults: dict) -> list:
    """This machine's reconstruction workers: ``workers`` processes, indices ``first_worker``
    on, of ``worker_count``; each restarted RESPAWN_DELAY_S after it dies."""
    from tactile_contact.model.layout import load_layout
    from tactile_contact.ros.workers import default_workers

    arg = LaunchConfiguration
    text = arg("workers").perform(context).strip()
    here = default_workers(len(load_layout(layout).patches)) if text == "auto" else int(text)
    total = int(arg("worker_count").perform(context).strip() or here)
    first = int(arg("first_worker").perform(context).strip() or 0)
    if here < 1 or not 0 <= first <= total - here:
        raise ValueError(
            f"workers {here} from first_worker {first} do not fit in worker_count {total}"
        )
    get_logger("skin.launch").info(
        f"reconstruction: workers {first}..{first + here - 1} of {total} on this machine"
    )
    return [
        Node(
            package="tactile_contact",
            executable="contact_reconstruction",
            name="contact_reconstruction" if total == 1 else f"contact_reconstruction_{i}",
            namespace=arg("namespace"),
            output="screen",
            respawn=True,
            respawn_delay=RESPAWN_DELAY_S,
            parameters=[
                defaults,
                {
                    "bundles_dir": arg("bundles"),
                    "layout": layout,
                    "worker_index": i,
                    "worker_count": total,
                },
                common,
            ],
        )
        for i in range(first, first + here)
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [DeclareLaunchArgument(n, default_value=d, description=t) for n, d, t in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)]
    )
