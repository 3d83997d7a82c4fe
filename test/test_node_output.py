"""What the nodes say in the first hour (issue 27): parameters in one compact line, a line when
a contact starts and when it ends (with its force), and a patch without a usable bundle an
ERROR in /diagnostics plus a warning at start that names the command building it.

Real nodes over real DDS; log lines read from the process's stderr (rclpy's console output).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from test.rosutil import spin_until

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(LAYOUT, out)
    return out


def _two_patch_layout(path: Path) -> Path:
    """The hexagon layout with a second patch, ``forearm``, on other boards."""
    doc = yaml.safe_load(LAYOUT.read_text())
    second = yaml.safe_load(yaml.safe_dump(doc["patches"][0]))
    second["name"], second["frame_id"] = "forearm", "forearm"
    for m in second["modules"]:
        m["board"] = int(m.get("board", 0)) + 1
    doc["patches"].append(second)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _node(context: object, **params: object) -> object:
    from rclpy.parameter import Parameter

    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return ContactReconstructionNode(context=context, parameter_overrides=overrides)


def _statuses(context: object, node: object) -> dict[str, tuple[int, str]]:
    """The node's next /diagnostics: status name → (level, message)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from tactile_contact.ros.common import DIAGNOSTICS_QOS

    got: list[DiagnosticArray] = []
    probe = node.create_subscription(DiagnosticArray, "/diagnostics", got.append, DIAGNOSTICS_QOS)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        assert spin_until(executor, lambda: bool(got), 10.0), "no /diagnostics"
    finally:
        executor.remove_node(node)
        node.destroy_subscription(probe)
    return {s.name: (s.level[0], s.message) for s in got[-1].status}


def test_a_patch_of_the_layout_without_a_bundle_is_an_error_naming_the_build_command(
    ros_context: object, bundles: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    layout = _two_patch_layout(tmp_path / "skin.yaml")
    node = _node(ros_context, bundles_dir=str(bundles), layout=str(layout), diagnostics_period=0.1)
    try:
        command = f"tactile-contact-build {layout} -o {bundles}"
        assert set(node.pipelines) == {"hexagon"}
        err = capfd.readouterr().err
        warned = [line for line in err.splitlines() if "forearm" in line and "WARN" in line]
        assert warned and command in warned[0], err
        level, message = _statuses(ros_context, node)["contact_reconstruction: forearm"]
        assert level == 2 and command in message, message
        assert "hexagon" in node.summary()[0] and "forearm: not served" in node.summary()[1]
    finally:
        node.destroy_node()


def test_a_missing_bundle_folder_is_an_error_naming_the_build_command(
    ros_context: object, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "no_bundles"
    node = _node(ros_context, bundles_dir=str(missing), diagnostics_period=0.1)
    try:
        err = capfd.readouterr().err
        assert f"tactile-contact-build LAYOUT.yaml -o {missing}" in err, err
        statuses = _statuses(ros_context, node)
        assert [v for v in statuses.values() if v[0] == 2 and "tactile-contact-build" in v[1]]
    finally:
        node.destroy_node()


def test_a_refused_bundle_names_its_folder_once(
    ros_context: object, bundles: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A truncated array: the message names the folder once, the array, and the command."""
    import shutil

    shutil.copytree(bundles / "hexagon", tmp_path / "hexagon")
    inverse = tmp_path / "hexagon" / "inverse.npy"
    inverse.write_bytes(inverse.read_bytes()[:5000])
    node = _node(ros_context, bundles_dir=str(tmp_path))
    try:
        error = node.load_errors["hexagon"]
        assert error.count(str(tmp_path / "hexagon")) == 1, error
        assert "'inverse'" in error and "tactile-contact-build" in error, error
        line = next(x for x in capfd.readouterr().err.splitlines() if "inverse" in x)
        assert line.count(str(tmp_path / "hexagon")) == 1, line
    finally:
        node.destroy_node()


def test_parameters_are_one_line(
    ros_context: object, bundles: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from rclpy.parameter import Parameter

    from tactile_contact.ros.skin_driver import SkinDriver

    node = _node(ros_context, bundles_dir=str(bundles), queue_depth=3)
    driver = SkinDriver(
        context=ros_context,
        parameter_overrides=[Parameter("autostart", value=False)],
    )
    try:
        err = capfd.readouterr().err
        lines = [x for x in err.splitlines() if re.search(r"\]: parameters?\b", x)]
        assert len(lines) == 2, err  # one per node
        recon = next(x for x in lines if "[contact_reconstruction]" in x)
        assert f"bundles_dir='{bundles}'" in recon and "queue_depth=3" in recon, recon
        assert "visualization_every" not in recon  # at its default: not repeated
        driver_line = next(x for x in lines if "[skin_driver]" in x)
        assert "autostart=False" in driver_line and len(driver_line) < 300, driver_line
    finally:
        node.destroy_node()
        driver.destroy_node()


def test_a_line_when_a_contact_starts_and_when_it_ends(
    ros_context: object, bundles: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from tactile_contact.model.forward import ForwardModel
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.layout import load_layout
    from tactile_contact.model.sensor import compression_to_delta_c
    from tactile_contact.msg import TaxelArray

    patch = load_layout(LAYOUT).patches[0]
    e, s = patch.elastomer, patch.sensor
    xy = patch.taxel_xy()
    fm = ForwardModel(xy, e.thickness, e.young, e.poisson, taxel_radius=s.taxel_radius)
    press = compression_to_delta_c(
        fm.compression(HertzSphere(6e-3), 2.0, xy[20]), e.thickness, s.epsilon_r, s.area
    )
    node = _node(ros_context, bundles_dir=str(bundles), queue_depth=100)
    probe = Node("probe", context=ros_context)
    pub = probe.create_publisher(TaxelArray, "hexagon/taxels", 100)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    pipe = node.pipelines["hexagon"]
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
        capfd.readouterr()
        # 1 s pressed, one frame without contact inside it (not an end), then 1 s released
        frames = [press] * 20 + [press * 0] + [press] * 20 + [press * 0] * 50
        for k, dc in enumerate(frames):
            msg = TaxelArray(patch="hexagon", taxel_ids=patch.taxel_ids())
            msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 50, (k % 50) * 20_000_000
            msg.delta_c = dc.astype(np.float32).tolist()
            msg.status = [0] * len(dc)
            pub.publish(msg)
            spin_until(executor, lambda k=k: pipe.stats.frames > k, 2.0)
        assert pipe.stats.frames == len(frames)
        err = capfd.readouterr().err
        starts = re.findall(
            r"patch hexagon: contact: ([0-9.]+) N at \(([-0-9.]+), ([-0-9.]+)\) mm", err
        )
        ends = re.findall(r"patch hexagon: contact ended: peak ([0-9.]+) N, ([0-9.]+) s", err)
        assert len(starts) == 1 and len(ends) == 1, err
        assert float(ends[0][0]) == pytest.approx(2.0, rel=0.3)
        assert (
            np.hypot(float(starts[0][1]) - xy[20, 0] * 1e3, float(starts[0][2]) - xy[20, 1] * 1e3)
            < 1.5
        )
        assert float(ends[0][1]) == pytest.approx(0.8, abs=0.05)
        assert pipe.stats.contacts == 1 and pipe.stats.peak_force == pytest.approx(2.0, rel=0.3)
        assert "1 contact(s)" in node.summary()[0]
    finally:
        executor.shutdown()
        probe.destroy_node()
        node.destroy_node()
