"""Skin pipeline on a robot: skin_driver → contact_reconstruction (+ simulator, + rviz2).

    ros2 launch tactile_contact skin.launch.py layout:=/path/layout.yaml bundles:=/path/bundles
    ros2 launch tactile_contact skin.launch.py use_simulator:=true channel:=vcan0 use_rviz:=true
    ros2 launch tactile_contact skin.launch.py use_simulator:=true \
        interface:=udp_multicast channel:=239.74.163.2

Every node parameter that matters at bringup is a launch argument; the rest come from the
YAML files in config/ (copy and edit them, or override with ros2 param). With
use_simulator the simulator writes module frames to the same CAN bus the driver reads, and
they are separate processes, so the bus must be one processes can share: a SocketCAN vcan
(interface socketcan, channel vcan0) or, where there is no vcan, python-can's udp_multicast
interface (channel = an IPv4 multicast group; loopback works). python-can's `virtual`
interface is shared within one process only: use `tactile-contact bringup --simulate` or
`ros2 run tactile_contact tactile_contact_bringup --simulate` for that.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

ARGUMENTS = [
    ("namespace", "", "namespace of all nodes and topics"),
    ("layout", "", "patch layout YAML (empty: the package's config/hexagon_patch.yaml)"),
    ("bundles", "bundles", "folder of matrix bundles built by tactile-contact-build"),
    ("interface", "socketcan", "python-can interface of the skin bus (socketcan, udp_multicast)"),
    ("channel", "can0", "CAN channel of the skin bus"),
    ("use_simulator", "false", "start skin_simulator writing frames to the same channel"),
    ("scenario", "sweep", "simulator scenario: sweep, press or idle"),
    ("use_rviz", "false", "start rviz2 with the package's configuration"),
    ("use_sim_time", "false", "use /clock (e.g. when replaying a bag)"),
]


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("tactile_contact")
    arg = LaunchConfiguration
    common = {"use_sim_time": arg("use_sim_time")}
    driver = Node(
        package="tactile_contact",
        executable="skin_driver",
        name="skin_driver",
        namespace=arg("namespace"),
        output="screen",
        parameters=[
            PathJoinSubstitution([share, "config", "skin_driver.yaml"]),
            {"layout": arg("layout"), "interface": arg("interface"), "channel": arg("channel")},
            common,
        ],
    )
    reconstruction = Node(
        package="tactile_contact",
        executable="contact_reconstruction",
        name="contact_reconstruction",
        namespace=arg("namespace"),
        output="screen",
        parameters=[
            PathJoinSubstitution([share, "config", "contact_reconstruction.yaml"]),
            {"bundles_dir": arg("bundles")},
            common,
        ],
    )
    simulator = Node(
        package="tactile_contact",
        executable="skin_simulator",
        name="skin_simulator",
        namespace=arg("namespace"),
        output="screen",
        condition=IfCondition(arg("use_simulator")),
        parameters=[
            PathJoinSubstitution([share, "config", "skin_simulator.yaml"]),
            {
                "layout": arg("layout"),
                "interface": arg("interface"),
                "channel": arg("channel"),
                "scenario": arg("scenario"),
            },
            common,
        ],
    )
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        arguments=["-d", PathJoinSubstitution([share, "rviz", "tactile_contact.rviz"])],
        condition=IfCondition(arg("use_rviz")),
        parameters=[common],
    )
    return LaunchDescription(
        [DeclareLaunchArgument(n, default_value=d, description=t) for n, d, t in ARGUMENTS]
        + [driver, reconstruction, simulator, rviz]
    )
