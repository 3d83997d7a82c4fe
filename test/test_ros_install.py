"""The ROS 2 integration as a robot user meets it (issue 18): ``colcon build`` in a workspace,
``source install/setup.bash``, ``ros2 pkg prefix``, ``ros2 run`` and ``ros2 launch`` — the real
commands, in real processes, over real DDS.

colcon comes from PyPI (requirements/python.txt); ros2cli, launch and launch_ros from
``make ros-launch`` (../shared/ros-launch). Where either is missing the tests skip with the
reason, except under TACTILE_REQUIRE_ROS=1 (``make test``, CI), where they fail.

``ros2 launch … use_simulator:=true`` runs the simulator and the driver as separate processes,
so they share the bus through python-can's ``udp_multicast`` interface on loopback (this
kernel has no vcan); each test run takes a multicast group of its own.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
EXECUTABLES = ("skin_driver", "skin_simulator", "contact_reconstruction", "tactile_contact_bringup")
BAD_OUTPUT = ("Traceback", "cannot use Destroyable")


def _require(tool: str) -> None:
    if (VENV_BIN / tool).exists():
        return
    reason = f"{tool} not in {VENV_BIN} (make ros-launch / pip install colcon-core)"
    if os.environ.get("TACTILE_REQUIRE_ROS") == "1":
        pytest.fail(f"TACTILE_REQUIRE_ROS=1 but {reason}")
    pytest.skip(reason)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    prefix = str(VENV_BIN.parent)
    env["AMENT_PREFIX_PATH"] = prefix
    env["CMAKE_PREFIX_PATH"] = prefix
    env.pop("PYTHONPATH", None)
    return env


class Shell:
    """A command run in a shell that sourced the workspace's install/setup.bash, in its own
    process group with SIGINT at its default action (a child of a background job inherits it
    ignored), its output collected line by line."""

    def __init__(self, ws: Path, command: str) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            ["bash", "-c", f"source {ws}/install/setup.bash && exec {command}"],
            cwd=ws,
            env=_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, text: str, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if text in self.output:
                return True
            if self.proc.poll() is not None:
                return False
            time.sleep(0.1)
        return False

    def interrupt(self, timeout_s: float = 30.0) -> int:
        """Ctrl-C to the whole group, as a terminal sends it; the exit code."""
        os.killpg(self.proc.pid, signal.SIGINT)
        try:
            return self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            raise AssertionError(f"no exit {timeout_s} s after SIGINT:\n{self.output}") from None
        finally:
            self._reader.join(timeout=5.0)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``colcon build --packages-select tactile_contact`` in a fresh workspace whose src/ links
    to this checkout, with the ROS 2 wheels of the venv as the underlay."""
    _require("colcon")
    ws = tmp_path_factory.mktemp("ws")
    (ws / "src").mkdir()
    (ws / "src" / "tactile_contact").symlink_to(ROOT, target_is_directory=True)
    done = subprocess.run(
        [
            str(VENV_BIN / "colcon"),
            "build",
            "--packages-select",
            "tactile_contact",
            "--cmake-args",
            f"-DPython3_EXECUTABLE={sys.executable}",
            "-DBUILD_TESTING=OFF",
        ],
        cwd=ws,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, f"colcon build failed:\n{done.stdout}\n{done.stderr}"
    return ws


def test_colcon_installs_an_ament_package(workspace: Path) -> None:
    prefix = workspace / "install" / "tactile_contact"
    for exe in EXECUTABLES:
        path = prefix / "lib" / "tactile_contact" / exe
        assert path.is_file() and os.access(path, os.X_OK), path
    share = prefix / "share" / "tactile_contact"
    assert (share / "package.xml").is_file()
    assert (share / "launch" / "skin.launch.py").is_file()
    for name in ("skin_driver", "skin_simulator", "contact_reconstruction", "hexagon_patch"):
        assert (share / "config" / f"{name}.yaml").is_file(), name
    assert any((share / "rviz").glob("*.rviz"))
    index = prefix / "share" / "ament_index" / "resource_index" / "packages" / "tactile_contact"
    assert index.is_file()
    # The messages and the library import from the install, not from this checkout.
    probe = Shell(
        workspace,
        "python -c 'import tactile_contact, tactile_contact.msg as m; "
        "print(tactile_contact.__file__); print(m.ContactState.__module__)'",
    )
    assert probe.proc.wait(timeout=60) == 0, probe.output
    probe._reader.join(timeout=5)
    assert str(prefix) in probe.lines[0], probe.output
    where = Shell(workspace, "ros2 pkg prefix tactile_contact")
    assert where.proc.wait(timeout=60) == 0, where.output
    where._reader.join(timeout=5)
    assert where.lines[-1].strip() == str(prefix)


def test_ros2_run_starts_the_driver_and_ctrl_c_stops_it(workspace: Path) -> None:
    _require("ros2")
    run = Shell(
        workspace,
        "ros2 run tactile_contact skin_driver --ros-args -p interface:=virtual "
        f"-p channel:=ros2run{os.getpid()}",
    )
    assert run.wait_for("active", timeout_s=60), run.output
    code = run.interrupt()
    assert code == 0, run.output
    for bad in BAD_OUTPUT:
        assert bad not in run.output, run.output


def test_ros2_launch_with_the_simulator(workspace: Path, ros_context: object) -> None:
    """The README's launch line: contacts with a force arrive, /diagnostics says OK, Ctrl-C
    ends every process cleanly."""
    _require("ros2")
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from tactile_contact.build import build_layout
    from tactile_contact.msg import ContactState

    bundles = workspace / "bundles"
    build_layout(ROOT / "config" / "hexagon_patch.yaml", bundles, jobs=1)
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    launch = Shell(
        workspace,
        "ros2 launch tactile_contact skin.launch.py use_simulator:=true scenario:=press "
        f"interface:=udp_multicast channel:={group} bundles:={bundles}",
    )
    node = Node("launch_probe", context=ros_context)
    forces: list[float] = []
    levels: dict[str, int] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            levels[s.name] = (
                int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level)
            )

    # The contact stream is sensor data (best effort); a reliable reader would get nothing.
    node.create_subscription(
        ContactState,
        "/hexagon/contact",
        lambda m: forces.append(m.total_force),
        qos_profile_sensor_data,
    )
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)

    def healthy() -> bool:
        driver = [lv for name, lv in levels.items() if name.startswith("skin_driver")]
        recon = [lv for name, lv in levels.items() if name.startswith("contact_reconstruction")]
        return bool(driver and recon and max(driver) == 0 and max(recon) == 0)

    try:
        end = time.monotonic() + 90.0
        while time.monotonic() < end and not (any(f > 0 for f in forces) and healthy()):
            executor.spin_once(timeout_sec=0.1)
            if launch.proc.poll() is not None:
                break
        assert any(f > 0 for f in forces), f"no contact with a force:\n{launch.output}"
        assert healthy(), (levels, launch.output)
    finally:
        executor.shutdown()
        node.destroy_node()
        code = launch.interrupt()
    assert code == 0, launch.output
    for bad in BAD_OUTPUT:
        assert bad not in launch.output, launch.output
    assert launch.output.count("process has finished cleanly") == 3, launch.output
