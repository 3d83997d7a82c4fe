"""launch/skin.launch.py: what it names exists and matches the nodes' declared parameters.

``launch`` and ``launch_ros`` are not on PyPI (``make ros-launch`` installs them); where they
import, the launch description is also loaded for real, and test_ros_install.py runs it.
Everywhere, the file is read as Python source (ast) and every executable, parameter file and
parameter name it uses is checked against the package.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "skin.launch.py"
# Parameters every rclpy node declares by itself.
RCLPY_BUILTIN = {"use_sim_time", "start_type_description_service"}
NODE_CLASSES = {
    "skin_driver": ("tactile_contact.ros.skin_driver", "SkinDriver"),
    "contact_reconstruction": (
        "tactile_contact.ros.contact_reconstruction",
        "ContactReconstructionNode",
    ),
    "skin_simulator": ("tactile_contact.ros.skin_simulator", "SkinSimulatorNode"),
    "worker_monitor": ("tactile_contact.ros.worker_monitor", "WorkerMonitor"),
}


def _node_calls() -> list[dict[str, ast.expr]]:
    tree = ast.parse(LAUNCH.read_text())
    calls = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Node":
            calls.append({k.arg: k.value for k in n.keywords if k.arg})
    return calls


def _const(expr: ast.expr) -> object:
    return expr.value if isinstance(expr, ast.Constant) else None


def _own_nodes() -> dict[str, dict[str, ast.expr]]:
    return {
        str(_const(c["executable"])): c
        for c in _node_calls()
        if _const(c["package"]) == "tactile_contact"
    }


def test_every_executable_is_installed() -> None:
    cmake = (ROOT / "CMakeLists.txt").read_text()
    setup = (ROOT / "setup.py").read_text()
    for exe in _own_nodes():
        assert (ROOT / "scripts" / exe).is_file(), f"scripts/{exe} missing"
        assert f"scripts/{exe}" in cmake, f"CMakeLists.txt does not install scripts/{exe}"
        assert exe in NODE_CLASSES, exe
    assert "tactile-contact" in setup


def test_every_file_the_launch_file_names_exists() -> None:
    text = LAUNCH.read_text()
    named = re.findall(r'shared\("(\w+)", "([\w.]+)"\)', text)
    # the nodes' parameter files, read by defaults(<node>): config/<node>.yaml
    named += [("config", f"{n}.yaml") for n in re.findall(r'defaults\("(\w+)"\)', text)]
    assert len(named) >= 6, named  # four parameter files, the layout, the rviz configuration
    for folder, name in named:
        assert (ROOT / folder / name).is_file(), f"{folder}/{name} named by the launch file"
        assert folder in ("config", "rviz", "launch")
    assert re.search(
        r"install\(DIRECTORY launch config rviz", (ROOT / "CMakeLists.txt").read_text()
    )


def _declared(context: object, exe: str) -> set[str]:
    from rclpy.parameter import Parameter

    module, cls = NODE_CLASSES[exe]
    node_cls = getattr(importlib.import_module(module), cls)
    overrides = [Parameter("autostart", value=False)] if exe == "skin_driver" else []
    node = node_cls(context=context, parameter_overrides=overrides)
    try:
        return set(node._parameters) - RCLPY_BUILTIN
    finally:
        node.destroy_node()


@pytest.mark.ros
def test_parameter_files_and_launch_arguments_match_declared_parameters(
    ros_context: object,
) -> None:
    for exe, call in _own_nodes().items():
        declared = _declared(ros_context, exe)
        config = yaml.safe_load((ROOT / "config" / f"{exe}.yaml").read_text())
        from_yaml = set(config[exe]["ros__parameters"])
        assert from_yaml <= declared, f"{exe}: YAML keys not declared: {from_yaml - declared}"
        # String arrays default to empty, which a parameter YAML cannot type: documented in
        # comments instead.
        missing = declared - from_yaml - {"patches", "buses", "channels"}
        assert not missing, f"{exe}: parameters missing from config/{exe}.yaml: {missing}"
        inline = set()
        for item in call["parameters"].elts:  # type: ignore[attr-defined]
            if isinstance(item, ast.Dict):
                inline |= {str(_const(k)) for k in item.keys if k is not None}
        inline.discard("use_sim_time")
        assert inline <= declared, f"{exe}: launch sets undeclared {inline - declared}"


def test_launch_description_loads() -> None:
    """Loaded by launch itself (``make ros-launch``; on a robot, ROS 2 has it). Skips where
    launch_ros is missing, fails there under TACTILE_REQUIRE_LAUNCH=1 (make test, CI)."""
    if importlib.util.find_spec("launch_ros") is None:
        reason = "launch_ros is not installed (not on PyPI): make ros-launch"
        if os.environ.get("TACTILE_REQUIRE_LAUNCH") == "1":
            pytest.fail(f"TACTILE_REQUIRE_LAUNCH=1 but {reason}")
        pytest.skip(reason)
    from launch.actions import DeclareLaunchArgument
    from launch.launch_description_sources import PythonLaunchDescriptionSource

    description = PythonLaunchDescriptionSource(
        str(LAUNCH)
    ).try_get_launch_description_without_context()
    names = {e.name for e in description.entities if isinstance(e, DeclareLaunchArgument)}
    assert {"layout", "bundles", "interface", "channel", "use_simulator", "use_rviz"} <= names


def test_every_launch_argument_is_documented() -> None:
    """The README's launch-argument table lists exactly the file's arguments and defaults."""
    tree = ast.parse(LAUNCH.read_text())
    (arguments,) = [
        ast.literal_eval(n.value)
        for n in tree.body
        if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", None) == "ARGUMENTS"
    ]
    rows = {}
    for line in (ROOT / "README.md").read_text().splitlines():
        m = re.match(r'\| `(\w+)` \| "([^"]*)" \| (.+) \|$', line)
        if m:
            rows[m.group(1)] = (m.group(2), m.group(3))
    assert rows == {name: (default, text) for name, default, text in arguments}


def test_every_test_that_runs_ros2_checks_for_it_first() -> None:
    """``ros2`` comes from ``make ros-launch`` (or a full ROS install): a test that runs it must
    skip, with the reason, where it is missing (a clone with nothing beside it), so each test
    of test_ros_install.py that names a ``ros2`` command calls ``_require_ros2()`` first."""
    tree = ast.parse((ROOT / "test" / "test_ros_install.py").read_text())
    helpers = {
        f.name: f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name.startswith("_")
    }

    def runs_ros2(f: ast.FunctionDef, seen: frozenset[str] = frozenset()) -> bool:
        for n in ast.walk(f):
            text = n.value if isinstance(n, ast.Constant) else None
            if isinstance(text, str) and re.search(r"(^|&& |exec )ros2 ", text):
                return True
            if isinstance(n, ast.Call) and getattr(n.func, "id", None) in helpers:
                name = n.func.id  # type: ignore[attr-defined]
                if name not in seen and runs_ros2(helpers[name], seen | {f.name}):
                    return True
        return False

    tests = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name.startswith("test")]
    unchecked = []
    for f in tests:
        first = next(
            (i for i, st in enumerate(f.body) if "_require_ros2()" in ast.unparse(st)), None
        )
        if runs_ros2(f) and (first is None or first > 1):
            unchecked.append(f.name)
    assert not unchecked, f"run ros2 without _require_ros2() first: {unchecked}"


def test_a_multicast_channel_names_its_port() -> None:
    """The launch file's simulation channel (GROUP:PORT) as the driver and simulator open it:
    python-can binds a udp_multicast bus to its port, so the port keeps simulations apart."""
    from tactile_contact.canbus.stream import bus_kwargs

    assert bus_kwargs("udp_multicast", "239.74.163.2:43156") == {
        "interface": "udp_multicast",
        "channel": "239.74.163.2",
        "port": 43156,
    }
    assert bus_kwargs("udp_multicast", "239.74.163.2")["channel"] == "239.74.163.2"
    assert bus_kwargs("socketcan", "can0", 500_000) == {
        "interface": "socketcan",
        "channel": "can0",
        "bitrate": 500_000,
    }
    with pytest.raises(ValueError, match="port 70000"):
        bus_kwargs("udp_multicast", "239.1.2.3:70000")
