"""contact_reconstruction over real DDS: outputs, skips, bad input, refused bundles."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from test.rosutil import spin_until

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(LAYOUT, out)
    return out


def _delta_c(force: float, center: tuple[float, float]) -> np.ndarray:
    """ΔC [F] per taxel of a 12 mm sphere, from the independent fine forward model."""
    from tactile_contact.forward import ForwardModel
    from tactile_contact.indenters import HertzSphere
    from tactile_contact.layout import load_layout

    patch = load_layout(LAYOUT).patches[0]
    e, s = patch.elastomer, patch.sensor
    model = ForwardModel(
        patch.taxel_xy(), e.thickness, e.young, e.poisson, taxel_radius=s.taxel_radius
    )
    delta = model.compression(HertzSphere(radius=6e-3), force, center)
    from tactile_contact.sensor import compression_to_delta_c

    return compression_to_delta_c(delta, e.thickness, s.epsilon_r, s.area)


class Rig:
    """The node under test plus a probe node that publishes taxels and listens to outputs."""

    def __init__(self, context: object, bundles_dir: Path, **params: object) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from tactile_contact.layout import load_layout
        from tactile_contact.msg import ContactState, TaxelArray
        from tactile_contact.nodes.contact_reconstruction import ContactReconstructionNode

        overrides = [Parameter("bundles_dir", value=str(bundles_dir))]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = ContactReconstructionNode(context=context, parameter_overrides=overrides)
        self.probe = Node("probe", context=context)
        self.qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.pub = self.probe.create_publisher(TaxelArray, "hexagon/taxels", 10)
        self.contacts: list[ContactState] = []
        self.probe.create_subscription(
            ContactState, "hexagon/contact", self.contacts.append, self.qos
        )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.ids = load_layout(LAYOUT).patches[0].taxel_ids()
        assert spin_until(self.executor, lambda: self.pub.get_subscription_count() > 0)
        assert spin_until(
            self.executor,
            lambda: self.node.pipelines["hexagon"].pub_contact.get_subscription_count() > 0,
        )

    def send(self, delta_c: np.ndarray, status: np.ndarray | None = None, sec: int = 1) -> None:
        from tactile_contact.msg import TaxelArray

        msg = TaxelArray(patch="hexagon")
        msg.header.stamp.sec = sec
        msg.header.frame_id = "skin_hexagon"
        msg.taxel_ids = self.ids.tolist()
        msg.delta_c = np.asarray(delta_c, np.float32).tolist()
        msg.raw = [240] * len(self.ids)
        msg.status = (np.zeros(len(self.ids), np.uint8) if status is None else status).tolist()
        n = len(self.contacts)
        self.pub.publish(msg)
        assert spin_until(self.executor, lambda: len(self.contacts) > n), "no ContactState"

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()


def test_contact_summary_matches_the_indenter(ros_context: object, bundles: Path) -> None:
    from sensor_msgs.msg import Image

    rig = Rig(ros_context, bundles)
    images: list[Image] = []
    rig.probe.create_subscription(Image, "hexagon/traction", images.append, rig.qos)
    assert spin_until(
        rig.executor,
        lambda: rig.node.pipelines["hexagon"].pub_traction.get_subscription_count() > 0,
    )
    load_center = rig.node.pipelines["hexagon"].recon.taxel_xy[30]
    rig.send(_delta_c(1.0, tuple(load_center)))
    state = rig.contacts[-1]
    assert state.in_contact and state.header.frame_id == "skin_hexagon"
    assert state.header.stamp.sec == 1
    assert state.total_force == pytest.approx(1.0, rel=0.15)
    cop = np.array([state.center_of_pressure.x, state.center_of_pressure.y])
    assert np.linalg.norm(cop - load_center) < 1e-3
    (contact,) = state.contacts
    assert contact.force == pytest.approx(state.total_force, rel=1e-12)
    assert (contact.center.x, contact.center.y) == pytest.approx(tuple(cop), abs=1e-12)
    assert contact.profile in ("punch", "hertz") and contact.radius > 0
    assert spin_until(rig.executor, lambda: bool(images))
    grid = rig.node.pipelines["hexagon"].recon.traction_grid
    img = images[-1]
    assert (img.height, img.width, img.encoding) == (*grid.shape, "32FC1")
    field = np.frombuffer(bytes(img.data), "<f4").reshape(grid.shape)
    assert np.isfinite(field).all() and field.max() > 0
    cell_area = grid.cell[0] * grid.cell[1]
    assert field.sum() * cell_area == pytest.approx(state.total_force, rel=1e-4)
    rig.close()


def test_rviz_outputs_show_taxels_pressure_and_contacts(ros_context: object, bundles: Path) -> None:
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker, MarkerArray

    rig = Rig(ros_context, bundles)
    got: dict[str, list] = {"taxel_markers": [], "contact_markers": [], "pressure_cloud": []}
    for topic, kind in (
        ("taxel_markers", MarkerArray),
        ("contact_markers", MarkerArray),
        ("pressure_cloud", PointCloud2),
    ):
        rig.probe.create_subscription(kind, f"hexagon/{topic}", got[topic].append, rig.qos)
    pipe = rig.node.pipelines["hexagon"]
    publishers = (pipe.pub_markers, pipe.pub_contact_markers, pipe.pub_cloud)
    assert spin_until(rig.executor, lambda: all(p.get_subscription_count() for p in publishers))
    recon = pipe.recon
    centre = tuple(recon.taxel_xy[30])
    rig.send(_delta_c(1.0, centre))
    assert spin_until(rig.executor, lambda: all(got.values()))
    state = rig.contacts[-1]
    # The contact: a DELETEALL (the previous frame's discs go), then its disc and its label.
    clear, disc, label = got["contact_markers"][-1].markers
    assert clear.action == Marker.DELETEALL
    assert disc.type == Marker.CYLINDER and disc.header.frame_id == "skin_hexagon"
    assert disc.scale.x == pytest.approx(2.0 * state.contacts[0].radius)
    assert (disc.pose.position.x, disc.pose.position.y) == pytest.approx(
        (state.center_of_pressure.x, state.center_of_pressure.y)
    )
    assert label.text.startswith(f"{state.total_force:.2f} N")
    # The taxels: one sphere per taxel, the loaded one the reddest.
    (taxels,) = got["taxel_markers"][-1].markers
    assert len(taxels.points) == len(recon.taxel_xy) == len(taxels.colors)
    red = np.array([c.r - c.b for c in taxels.colors])
    xy = np.array([(p.x, p.y) for p in taxels.points])
    assert np.hypot(*(xy[int(np.argmax(red))] - centre)) < 1e-9
    # The pressure cloud: x, y, pressure per skin cell; its integral is the field's force.
    cloud = got["pressure_cloud"][-1]
    pts = np.frombuffer(bytes(cloud.data), "<f4").reshape(-1, 4)
    grid = recon.traction_grid
    assert len(pts) == int(np.count_nonzero(grid.mask))
    assert np.isfinite(pts).all() and pts[:, 3].min() >= 0
    # No contact: the DELETEALL alone clears the disc.
    rig.send(np.zeros(len(rig.ids)), sec=2)
    assert spin_until(rig.executor, lambda: len(got["contact_markers"][-1].markers) == 1)
    # Every topic the package's rviz2 configuration shows is one this node publishes.
    import yaml

    config = yaml.safe_load((ROOT / "rviz" / "tactile_contact.rviz").read_text())
    shown = {
        d["Topic"]["Value"] for d in config["Visualization Manager"]["Displays"] if "Topic" in d
    }
    published = {
        t for t, _ in rig.node.get_publisher_names_and_types_by_node(rig.node.get_name(), "/")
    }
    assert shown and shown <= published, shown - published
    rig.close()


def test_idle_patch_and_unsubscribed_outputs_are_skipped(
    ros_context: object, bundles: Path
) -> None:
    rig = Rig(ros_context, bundles)
    stats = rig.node.pipelines["hexagon"].stats
    for i in range(5):
        rig.send(np.zeros(len(rig.ids)), sec=i + 1)
    assert stats.frames == 5 and stats.skipped_idle == 5 and stats.solved == 0
    assert all(c.solver == "none" and not c.in_contact and not c.contacts for c in rig.contacts)
    # Nobody subscribes to the deflection or traction images: neither is computed.
    rig.send(_delta_c(1.0, (0.0, 0.0)), sec=10)
    assert stats.solved == 1
    assert stats.skipped_deflection == 6 and stats.skipped_images == 6
    rig.close()


def test_bad_frames_are_counted_and_the_node_keeps_running(
    ros_context: object, bundles: Path
) -> None:
    from tactile_contact.msg import TaxelArray

    rig = Rig(ros_context, bundles)
    pipeline = rig.node.pipelines["hexagon"]
    bad = TaxelArray(patch="hexagon", taxel_ids=[1, 2], delta_c=[0.0], raw=[], status=[0, 0])
    unknown = TaxelArray(
        patch="hexagon", taxel_ids=[0x0F00], delta_c=[1e-15], raw=[240], status=[0]
    )
    # The input keeps only the newest frame: send one at a time.
    for count, msg in enumerate((bad, unknown), start=1):
        rig.pub.publish(msg)
        assert spin_until(rig.executor, lambda c=count: pipeline.stats.bad_frames == c)
    # NaN readings and flagged taxels (all on module 0, away from the load) are left out and
    # never reach a message.
    dc = _delta_c(1.0, tuple(pipeline.recon.taxel_xy[30]))
    dc[:5] = np.nan
    status = np.zeros(len(rig.ids), np.uint8)
    status[5:8] = TaxelArray.STATUS_DEAD
    rig.send(dc, status)
    state = rig.contacts[-1]
    assert np.isfinite([state.total_force, state.contact_area, state.peak_pressure]).all()
    assert state.taxels_used == len(rig.ids) - 8
    assert state.total_force == pytest.approx(1.0, rel=0.15)
    # A reading no 8-bit value gives (a gain mismatch between driver and bundle): left out,
    # counted and said on /diagnostics; the frame is still solved.
    dc[8] = 1e-9
    rig.send(dc, status, sec=2)
    state = rig.contacts[-1]
    assert state.taxels_used == len(rig.ids) - 9
    assert state.total_force == pytest.approx(1.0, rel=0.15)
    assert pipeline.stats.out_of_range == 1
    status_report = pipeline.diagnostics()
    values = {kv.key: kv.value for kv in status_report.values}
    assert values["out_of_range_readings"] == "1" and "full scale" in status_report.message
    rig.close()


def test_a_broken_bundle_is_refused_and_the_others_still_served(
    ros_context: object, bundles: Path, tmp_path: Path
) -> None:
    from diagnostic_msgs.msg import DiagnosticArray

    from tactile_contact.nodes.common import DIAGNOSTICS_QOS

    shutil.copytree(bundles / "hexagon", tmp_path / "hexagon")
    shutil.copytree(bundles / "hexagon", tmp_path / "broken")
    manifest = tmp_path / "broken" / "manifest.json"
    content = json.loads(manifest.read_text())
    content["schema_version"] = 99
    manifest.write_text(json.dumps(content))
    rig = Rig(ros_context, tmp_path, diagnostics_period=0.1)
    assert set(rig.node.pipelines) == {"hexagon"}
    assert "broken" in rig.node.load_errors
    diags: list[DiagnosticArray] = []
    rig.probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, DIAGNOSTICS_QOS)
    assert spin_until(rig.executor, lambda: bool(diags))
    levels = {s.name: s.level for s in diags[-1].status}
    assert levels["contact_reconstruction: broken"] == bytes([2])
    rig.send(np.zeros(len(rig.ids)))
    rig.close()
