"""Skin pipeline on a robot: skin_driver → contact_reconstruction (+ simulator, + rviz2).

    ros2 launch tactile_contact skin.launch.py layout:=/path/layout.yaml bundles:=/path/bundles
    ros2 launch tactile_contact skin.launch.py use_simulator:=true
    ros2 launch tactile_contact skin.launch.py use_simulator:=true channel:=vcan0 use_rviz:=true

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
]

#: python-can's default IPv4 group of its udp_multicast interface, and its default port.
MULTICAST_GROUP, MULTICAST_PORT = "239.74.163.2", 43113


def simulation_channel(domain_id: str) -> str:
    """The udp_multicast channel of a simulation in ROS domain ``domain_id``: python-can binds
    every such bus to its port on all addresses, and Linux then delivers every group joined on
    the machine at that port to it, so the port (43113 + domain id) is what keeps two
    simulations apart."""
    domain = int(domain_id) if domain_id.strip().isdigit() else 0
    return f"{MULTICAST_GROUP}:{MULTICAST_PORT + domain}"


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

    nodes = [
        Node(
            package="tactile_contact",
            executable="skin_driver",
            name="skin_driver",
            namespace=arg("namespace"),
            output="screen",
            on_exit=ends_launch("skin_driver"),
            parameters=[
                shared("config", "skin_driver.yaml"),
                {"layout": layout, "interface": interface, "channel": channel},
                common,
            ],
        ),
        Node(
            package="tactile_contact",
            executable="contact_reconstruction",
            name="contact_reconstruction",
            namespace=arg("namespace"),
            output="screen",
            on_exit=ends_launch("contact_reconstruction"),
            parameters=[
                shared("config", "contact_reconstruction.yaml"),
                {"bundles_dir": arg("bundles"), "layout": layout},
                common,
            ],
        ),
    ]
    if simulate:
        nodes.append(
            Node(
                package="tactile_contact",
                executable="skin_simulator",
                name="skin_simulator",
                namespace=arg("namespace"),
                output="screen",
                on_exit=ends_launch("skin_simulator"),
                parameters=[
                    shared("config", "skin_simulator.yaml"),
                    {
                        "layout": layout,
                        "interface": interface,
                        "channel": channel,
                        "scenario": arg("scenario"),
                    },
                    common,
                ],
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


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [DeclareLaunchArgument(n, default_value=d, description=t) for n, d, t in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)]
    )
