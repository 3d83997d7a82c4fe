"""contact_reconstruction over real DDS: outputs, skips, bad input, refused bundles."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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


def _delta_c(force: float, center: tuple[float, float]) -> np.ndarray:
    """ΔC [F] per taxel of a 12 mm sphere, from the independent fine forward model."""
    from tactile_contact.model.forward import ForwardModel
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.layout import load_layout

    patch = load_layout(LAYOUT).patches[0]
    e, s = patch.elastomer, patch.sensor
    model = ForwardModel(
        patch.taxel_xy(), e.thickness, e.young, e.poisson, taxel_radius=s.taxel_radius
    )
    delta = model.compression(HertzSphere(radius=6e-3), force, center)
    from tactile_contact.model.sensor import compression_to_delta_c

    return compression_to_delta_c(delta, e.thickness, s.epsilon_r, s.area)


class Rig:
    """The node under test plus a probe node that publishes taxels and listens to outputs."""

    def __init__(self, context: object, bundles_dir: Path, **params: object) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from tactile_contact.model.layout import load_layout
        from tactile_contact.msg import ContactState, TaxelArray
        from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

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

    from tactile_contact.ros.common import DIAGNOSTICS_QOS

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


def test_diagnostics_go_out_once_a_period_whatever_loads_later(
    ros_context: object, bundles: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The steps of a diagnostics period are counted from the patches given, not those
    loaded at start: a bundle refused at start that loads later is taken within the same
    number of steps (the array still once a period, both patches in it), and a period
    with no patch to report publishes once, not at every step."""
    import tactile_contact.ros.contact_reconstruction as cr

    monkeypatch.setattr(cr, "DIAG_PATCHES_PER_STEP", 1)
    shutil.copytree(bundles / "hexagon", tmp_path / "hexagon")
    _second_patch(bundles, tmp_path)
    manifest = tmp_path / "forearm" / "manifest.json"
    good = manifest.read_text()
    manifest.write_text(good.replace('"schema_version": ', '"schema_version": 99, "was": '))
    rig = Rig(ros_context, tmp_path, diagnostics_period=0.1)
    node = rig.node
    assert set(node.pipelines) == {"hexagon"} and "forearm" in node.load_errors
    published: list[list[str]] = []
    monkeypatch.setattr(
        node, "_publish_diagnostics", lambda st: published.append(sorted(s.name for s in st))
    )
    node._diag_tick = 0  # (a period's start; the rig's spinning may have stepped it)
    for _ in range(3 * 2):  # 2 patches given: steps of 1, 3 a period
        node.diagnostics_step()
    assert len(published) == 2, published
    manifest.write_text(good)  # the bundle mended: loaded on a thread, taken by a step
    deadline = time.monotonic() + 30.0
    while "forearm" not in node.pipelines and time.monotonic() < deadline:
        node.diagnostics_step()
        time.sleep(0.01)
    assert set(node.pipelines) == {"hexagon", "forearm"}
    while node._diag_tick:  # (to the next period's start)
        node.diagnostics_step()
    del published[:]
    for _ in range(3 * 2):
        node.diagnostics_step()
    assert len(published) == 2, published
    assert published[-1] == [
        "contact_reconstruction: forearm",
        "contact_reconstruction: hexagon",
    ]
    node.pipelines.clear()  # nothing to report: still one array a period
    for _ in range(3 * 3):
        node.diagnostics_step()
    assert len(published) == 5, published
    rig.close()


def test_a_worker_names_a_patch_the_layout_does_not_have(
    ros_context: object, bundles: Path
) -> None:
    """Workers split the patches of the layout; a name in ``patches`` that the layout does
    not have (a typo) is in no worker's share: worker 0 reports it, the others serve on."""
    from test.rosutil import reconstruction_workers

    given = {"bundles_dir": str(bundles), "layout": str(LAYOUT), "patches": ["hexagon", "hexagn"]}
    nodes = reconstruction_workers(ros_context, 2, **given)
    assert "not in the layout" in nodes[0].load_errors["hexagn"]
    assert "hexagn" not in nodes[1].load_errors
    assert {n for node in nodes for n in node.pipelines} == {"hexagon"}
    assert any(line.startswith("hexagn: not served") for line in nodes[0].summary())
    for node in nodes:
        node.destroy_node()


# -- hostile input, a second patch served throughout, bundles changed under the node ---------
def _second_patch(bundles: Path, out: Path, name: str = "forearm") -> None:
    """A copy of the hexagon bundle posing as another patch (its manifest renamed; the layout
    file it came from is forgotten so that the rename is not refused as foreign)."""
    shutil.copytree(bundles / "hexagon", out / name)
    manifest = out / name / "manifest.json"
    content = json.loads(manifest.read_text())
    content.update(patch=name, frame_id=f"skin_{name}", layout_source=None)
    manifest.write_text(json.dumps(content))


class TwoPatchRig:
    """The node serving ``hexagon`` and ``forearm``; a probe publishes and listens to both."""

    def __init__(self, context: object, bundles_dir: Path) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from tactile_contact.model.layout import load_layout
        from tactile_contact.msg import ContactState, TaxelArray
        from tactile_contact.ros.common import DIAGNOSTICS_QOS
        from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

        overrides = [
            Parameter("bundles_dir", value=str(bundles_dir)),
            Parameter("diagnostics_period", value=0.1),
        ]
        self.node = ContactReconstructionNode(context=context, parameter_overrides=overrides)
        self.probe = Node("probe", context=context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.pubs = {
            p: self.probe.create_publisher(TaxelArray, f"{p}/taxels", 10)
            for p in ("hexagon", "forearm")
        }
        self.contacts: dict[str, list] = {"hexagon": [], "forearm": []}
        for p, got in self.contacts.items():
            self.probe.create_subscription(ContactState, f"{p}/contact", got.append, qos)
        self.diags: list = []
        self.probe.create_subscription(
            DiagnosticArray, "/diagnostics", self.diags.append, DIAGNOSTICS_QOS
        )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self.ids = load_layout(LAYOUT).patches[0].taxel_ids().tolist()
        for p, pub in self.pubs.items():
            assert spin_until(self.executor, lambda pub=pub: pub.get_subscription_count() > 0)
            pipe = self.node.pipelines[p]
            assert spin_until(
                self.executor, lambda pipe=pipe: pipe.pub_contact.get_subscription_count() > 0
            )

    def msg(self, patch: str, delta_c: object, ids: list | None = None) -> object:
        from tactile_contact.msg import TaxelArray

        ids = self.ids if ids is None else ids
        m = TaxelArray(patch=patch, taxel_ids=ids, raw=[240] * len(ids), status=[0] * len(ids))
        m.delta_c = np.asarray(delta_c, np.float32).tolist()
        m.header.stamp.sec = 1
        return m

    def publish(self, topic: str, msg: object, expect_output: bool) -> None:
        n = len(self.contacts[topic])
        stats = self.node.pipelines[topic].stats
        frames = stats.frames
        self.pubs[topic].publish(msg)
        assert spin_until(self.executor, lambda: stats.frames > frames), "frame not received"
        if expect_output:
            assert spin_until(self.executor, lambda: len(self.contacts[topic]) > n)

    def status(self, patch: str) -> tuple[int, str, dict[str, str]]:
        n = len(self.diags)
        assert spin_until(self.executor, lambda: len(self.diags) > n + 1)
        for s in self.diags[-1].status:
            if s.name == f"contact_reconstruction: {patch}":
                return s.level[0], s.message, {kv.key: kv.value for kv in s.values}
        raise AssertionError(f"no status for {patch}")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()


def _on_taxel(i: int) -> tuple[float, float]:
    from tactile_contact.model.layout import load_layout

    x, y = load_layout(LAYOUT).patches[0].taxel_xy()[i]
    return float(x), float(y)


def _valid(state: object) -> bool:
    values = [state.total_force, state.contact_area, state.peak_pressure]
    values += [state.center_of_pressure.x, state.center_of_pressure.y]
    values += [x for c in state.contacts for x in (c.force, c.radius, c.center.x, c.center.y)]
    return (
        bool(np.all(np.isfinite(values)))
        and min(state.total_force, state.contact_area, state.peak_pressure) >= 0.0
    )


def test_hostile_frames_publish_nothing_invalid_and_the_other_patch_is_served(
    ros_context: object, bundles: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    shutil.copytree(bundles / "hexagon", tmp_path / "hexagon")
    _second_patch(bundles, tmp_path)
    rig = TwoPatchRig(ros_context, tmp_path)
    good = _delta_c(1.0, _on_taxel(30))
    k = len(rig.ids)
    nan_some = good.copy()
    nan_some[::7] = np.nan
    inf_some = good.copy()
    inf_some[3], inf_some[40] = np.inf, -np.inf
    hostile = [
        ("all NaN", rig.msg("hexagon", np.full(k, np.nan)), True),
        ("some NaN", rig.msg("hexagon", nan_some), True),
        ("inf", rig.msg("hexagon", inf_some), True),
        ("huge", rig.msg("hexagon", np.full(k, 1e30)), True),
        ("all negative", rig.msg("hexagon", -np.abs(good) - 1e-15), True),
        ("wrong length", rig.msg("hexagon", good[:-3], ids=rig.ids), False),
        ("unknown taxels", rig.msg("hexagon", good[:5], ids=[0xF00 + i for i in range(5)]), False),
        ("another patch", rig.msg("elbow", good), False),
    ]
    for _what, msg, solved in hostile:
        rig.publish("hexagon", msg, expect_output=solved)
        rig.publish("forearm", rig.msg("forearm", good), expect_output=True)
    for _ in range(3):  # a repeated fault is logged once (rate-limited), counted every time
        rig.publish("hexagon", rig.msg("hexagon", np.full(k, np.nan)), expect_output=True)
    assert all(_valid(s) for s in rig.contacts["hexagon"]), "an invalid summary was published"
    assert all(_valid(s) for s in rig.contacts["forearm"])
    assert len(rig.contacts["forearm"]) == len(hostile)
    forces = [s.total_force for s in rig.contacts["forearm"]]
    assert forces == pytest.approx([1.0] * len(hostile), rel=0.15), forces
    level, message, values = rig.status("hexagon")
    assert level == 1 and message
    assert values["nonfinite_frames"] == "6" and values["bad_frames"] == "2"
    assert values["foreign_frames"] == "1" and values["internal_errors"] == "0"
    assert rig.status("forearm")[0] == 0
    err = capfd.readouterr().err
    assert err.count("non-finite ΔC") == 1, "logged more than once within 5 s"
    assert "Traceback" not in err
    rig.close()


def test_bundles_deleted_or_replaced_while_running(
    ros_context: object, bundles: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "bundles"
    folder.mkdir()
    shutil.copytree(bundles / "hexagon", folder / "hexagon")
    _second_patch(bundles, folder)
    rig = TwoPatchRig(ros_context, folder)
    good = _delta_c(1.0, _on_taxel(30))
    # 1. forearm's bundle deleted: reported, the loaded copy goes on serving.
    shutil.rmtree(folder / "forearm")
    level, message, _ = rig.status("forearm")
    assert level == 1 and "deleted" in message
    rig.publish("forearm", rig.msg("forearm", good), expect_output=True)
    # 2. hexagon's arrays overwritten in place (a mapped file would crash the process):
    #    the broken version is refused and reported, the loaded one goes on serving.
    inverse = folder / "hexagon" / "inverse.npy"
    with inverse.open("r+b") as f:
        f.truncate(100)
    level, message, values = rig.status("hexagon")
    assert level == 2 and "refused" in message, message
    rig.publish("hexagon", rig.msg("hexagon", good), expect_output=True)
    assert rig.contacts["hexagon"][-1].total_force == pytest.approx(1.0, rel=0.15)
    # 3. a good bundle put in its place (atomically, as tactile-contact-build does): reloaded.
    shutil.copytree(bundles / "hexagon", tmp_path / "new")
    shutil.rmtree(folder / "hexagon")
    (tmp_path / "new").rename(folder / "hexagon")
    assert spin_until(rig.executor, lambda: rig.node.pipelines["hexagon"].reloads == 1)
    level, message, values = rig.status("hexagon")
    assert values["bundle_problem"] == "" and values["bundle_reloads"] == "1"
    rig.publish("hexagon", rig.msg("hexagon", good), expect_output=True)
    assert rig.contacts["hexagon"][-1].total_force == pytest.approx(1.0, rel=0.15)
    rig.close()


def test_a_bundle_replaced_while_running_loads_off_the_executor(
    ros_context: object, bundles: Path, tmp_path: Path
) -> None:
    """The diagnostics steps load a replaced bundle on a thread of their own (a robot's
    takes 0.7–1 s: on the executor it held every frame and the worker's heartbeat past the
    monitor's 0.5 s); the old one serves until a later step swaps the new one in."""
    folder = tmp_path / "bundles"
    folder.mkdir()
    shutil.copytree(bundles / "hexagon", folder / "hexagon")
    rig = Rig(ros_context, folder)
    node, pipe = rig.node, rig.node.pipelines["hexagon"]
    old = pipe.recon
    shutil.copytree(bundles / "hexagon", tmp_path / "new")
    shutil.rmtree(folder / "hexagon")
    (tmp_path / "new").rename(folder / "hexagon")
    node.watch_bundle(pipe, wait=False)
    # (handed to the loader's thread: a job, the old copy still serving)
    assert pipe.bundle in node._loads and pipe.reloads == 0 and pipe.recon is old
    deadline = time.monotonic() + 30.0
    while pipe.reloads == 0 and time.monotonic() < deadline:
        node.diagnostics_step()
        time.sleep(0.01)
    assert pipe.reloads == 1 and pipe.recon is not old and pipe.bundle_problem == ""
    rig.close()


def test_a_bundles_signature_changes_with_each_way_it_is_changed(tmp_path: Path) -> None:
    """bundle_signature alone (the node test above runs it through the node): a file
    rewritten in place, a file replaced, the folder replaced, a file added, the folder
    deleted; the same folder looked at twice reads the same."""
    from tactile_contact.ros.contact_reconstruction import bundle_signature

    folder = tmp_path / "b"
    folder.mkdir()
    for name in ("manifest.json", "forward.npy", "inverse.npy"):
        (folder / name).write_bytes(b"x" * 64)
    seen = [bundle_signature(folder)]
    assert seen[0] == bundle_signature(folder)
    assert [entry[0] for entry in seen[0][1:]] == ["forward.npy", "inverse.npy", "manifest.json"]
    with (folder / "inverse.npy").open("r+b") as f:
        f.truncate(10)
    seen.append(bundle_signature(folder))
    (folder / "new.npy").write_bytes(b"y")
    (folder / "new.npy").replace(folder / "forward.npy")
    seen.append(bundle_signature(folder))
    (folder / "extra.npy").write_bytes(b"z")
    seen.append(bundle_signature(folder))
    shutil.copytree(folder, tmp_path / "c")
    shutil.rmtree(folder)
    (tmp_path / "c").rename(folder)
    seen.append(bundle_signature(folder))
    assert len(set(seen)) == len(seen)
    shutil.rmtree(folder)
    assert bundle_signature(folder) == ()
    assert bundle_signature(tmp_path / "c") == ()


# -- property: whatever the readings, what goes out is finite and never a negative force ------
_RECON: dict[str, object] = {}


def _reconstructor(bundles: Path) -> object:
    from tactile_contact.ros.contact_reconstruction import load_reconstructor

    if "r" not in _RECON:
        _RECON["r"] = load_reconstructor(bundles / "hexagon")
    return _RECON["r"]


@st.composite
def readings(draw: st.DrawFn, k: int = 72) -> np.ndarray:
    """8-bit count deviations of every kind a skin gives (× one count's ΔC in the test)."""
    kind = draw(st.sampled_from(["random", "all_negative", "saturated", "single", "zero", "mixed"]))
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    if kind == "random":
        return rng.integers(-20, 60, k).astype(float)
    if kind == "all_negative":
        return -rng.integers(1, 40, k).astype(float)
    if kind == "saturated":
        c = np.zeros(k)
        c[rng.choice(k, draw(st.integers(1, k)), replace=False)] = 255.0
        return c
    if kind == "single":
        c = np.zeros(k)
        c[draw(st.integers(0, k - 1))] = draw(st.sampled_from([-255.0, -3.0, 1.0, 5.0, 255.0]))
        return c
    if kind == "zero":
        return np.zeros(k)
    c = rng.integers(-255, 256, k).astype(float)
    c[rng.random(k) < 0.2] = np.nan
    return c


@given(counts=readings(), valid_fraction=st.floats(0.0, 1.0))
@settings(max_examples=60, deadline=None)
def test_any_reading_gives_a_finite_nonnegative_published_summary(
    bundles: Path, counts: np.ndarray, valid_fraction: float
) -> None:
    from std_msgs.msg import Header

    from tactile_contact.ros import convert
    from tactile_contact.ros.contact_reconstruction import check_result

    recon = _reconstructor(bundles)
    quantum = recon.full_scale / 256.0
    rng = np.random.default_rng(len(counts))
    valid = rng.random(len(counts)) < valid_fraction
    result = recon.solve(counts * quantum, valid=valid)
    check_result(result)  # raises if anything would be refused
    msg = convert.contact_state(result, "hexagon", Header())
    assert _valid(msg)
    for c in result.contacts:
        assert c.force >= 0.0 and c.radius >= 0.0
    for grid in (result.traction, result.deflection):
        assert grid is None or np.isfinite(grid).all()
    if result.traction is not None:
        assert result.traction.min() >= -1e-9 * max(1.0, np.abs(result.traction).max())


@pytest.mark.parametrize("per_step", [1, 6])
def test_diagnostics_are_taken_a_few_patches_a_step_and_published_whole(
    ros_context: object,
    bundles: Path,
    tmp_path: Path,
    per_step: int,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A period's diagnostics work is spread (it held every frame behind it for ≈ 10 ms at
    24 patches): the bundles are watched in one step, DIAG_PATCHES_PER_STEP patches' statuses
    taken in each of the next, and the array that goes out once a period holds every patch."""
    import tactile_contact.ros.contact_reconstruction as cr

    monkeypatch.setattr(cr, "DIAG_PATCHES_PER_STEP", per_step)
    shutil.copytree(bundles / "hexagon", tmp_path / "hexagon")
    _second_patch(bundles, tmp_path)
    rig = TwoPatchRig(ros_context, tmp_path)
    node = rig.node
    taken: list[str] = []
    for name, pipe in node.pipelines.items():
        original = pipe.diagnostics

        def counted(name: str = name, original: object = original) -> object:
            taken.append(name)
            return original()

        pipe.diagnostics = counted
    n = len(rig.diags)
    patches = len(node.pipelines)
    node._diag_tick = 0  # (a period's start; the rig's spinning may have stepped it)
    steps = -(-patches // per_step) + 1  # (a period's: the bundles, then the patches)
    counts = []
    for _ in range(3 * steps):
        before = len(taken)
        node.diagnostics_step()
        counts.append(len(taken) - before)
    assert counts == [0, *[min(per_step, patches)] * (steps - 1)] * 3, counts
    assert spin_until(rig.executor, lambda: len(rig.diags) >= n + 3)
    for array in rig.diags[n:]:
        names = {s.name for s in array.status}
        assert names == {"contact_reconstruction: hexagon", "contact_reconstruction: forearm"}
    rig.close()


def test_repeated_taxel_ids_stamps_and_parameter_sets(
    ros_context: object, bundles: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame that carries a taxel twice (which copy is the taxel's?) is a bad frame named
    as such, and the next good frame is solved; a frame stamped far ahead of the node's clock
    is solved but kept out of the latency figures and warned about; a patch whose frames stop
    is warned about; a parameter set while running is refused with the reason (the node reads
    them at start)."""
    from rclpy.parameter import Parameter

    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros import patch_pipeline

    rig = Rig(ros_context, bundles)
    pipeline = rig.node.pipelines["hexagon"]
    press = _delta_c(1.0, tuple(pipeline.recon.taxel_xy[30]))
    ids = rig.ids.tolist()
    twice = TaxelArray(patch="hexagon", taxel_ids=ids + ids, raw=[240] * (2 * len(ids)))
    # (the press in the first copy, zeros in the second: the second silently won before)
    twice.delta_c = np.concatenate([press, 0 * press]).astype(np.float32).tolist()
    twice.status = [0] * (2 * len(ids))
    rig.pub.publish(twice)
    assert spin_until(rig.executor, lambda: pipeline.stats.bad_frames == 1)
    assert "more than once" in pipeline.stats.last_error
    rig.send(press, sec=int(time.time()))
    assert rig.contacts[-1].total_force == pytest.approx(1.0, rel=0.15)
    latencies = len(pipeline.stats.latency_s)
    assert latencies >= 1
    rig.send(press, sec=2**31 - 1)  # (2038: a bogus stamp)
    assert rig.contacts[-1].total_force == pytest.approx(1.0, rel=0.15)  # still solved
    assert pipeline.stats.stamps_ahead >= 1 and len(pipeline.stats.latency_s) == latencies
    report = pipeline.diagnostics()
    values = {kv.key: kv.value for kv in report.values}
    assert report.level[0] == 1 and "ahead of this node's clock" in report.message
    assert float(values["latency_p99_ms"]) < 60e3
    monkeypatch.setattr(patch_pipeline, "FRAMES_STOPPED_S", 0.2)
    monkeypatch.setattr(patch_pipeline, "FRAMES_STOPPED_GAPS", 0.0)  # (this test's gaps)
    time.sleep(0.3)
    assert "no taxel frame for" in pipeline.diagnostics().message
    # An untouched patch of a driver with idle_every: a frame every 5 s is no stop, 21 s is.
    monkeypatch.setattr(patch_pipeline, "FRAMES_STOPPED_S", 3.0)
    monkeypatch.setattr(patch_pipeline, "FRAMES_STOPPED_GAPS", 3.0)
    now = time.monotonic()
    for ago in (20.0, 15.0, 10.0, 5.0):
        pipeline._took_frame(now - ago)
    assert "no taxel frame for" not in pipeline.diagnostics().message
    for ago in (36.0, 31.0, 26.0, 21.0):
        pipeline._took_frame(now - ago)
    assert "no taxel frame for 21 s" in pipeline.diagnostics().message
    for name, value in (("diagnostics_period", 10.0), ("bundles_dir", "/nonexistent")):
        (result,) = rig.node.set_parameters([Parameter(name, value=value)])
        assert not result.successful and "at start only" in result.reason
        assert rig.node.get_parameter(name).value != value
    rig.close()


def test_a_layout_edit_that_makes_a_served_bundle_stale_is_said_at_once(
    ros_context: object, bundles: Path, tmp_path: Path
) -> None:
    """A bundle built from a layout file that is then edited (the elastomer's modulus here)
    would be refused at the next start: the running node says so at once (ERROR, the copy in
    memory going on serving), and stops saying it when the file matches again. Before, it
    stayed OK until a respawn took the patch down."""
    from tactile_contact.offline.build import build_layout

    layout = tmp_path / "hexagon.yaml"
    text = LAYOUT.read_text()
    layout.write_text(text)
    build_layout(layout, tmp_path / "bundles")
    _second_patch(bundles, tmp_path / "bundles")
    rig = TwoPatchRig(ros_context, tmp_path / "bundles")
    good = _delta_c(1.0, _on_taxel(30))
    rig.publish("hexagon", rig.msg("hexagon", good), expect_output=True)
    level, message, _ = rig.status("hexagon")
    assert level == 0, message
    assert "young: 2.1e5" in text

    def status_until(done: Callable[[int, str], bool]) -> tuple[int, str, dict[str, str]]:
        """The patch's status once ``done(level, message)`` (the file is read on the loader's
        thread: a diagnostics step or two later), at most 10 s."""
        deadline = time.monotonic() + 10.0
        while True:
            level, message, values = rig.status("hexagon")
            if done(level, message) or time.monotonic() > deadline:
                return level, message, values

    layout.write_text(text.replace("young: 2.1e5", "young: 3.0e5"))
    level, message, values = status_until(lambda lv, m: "layout file changed" in m)
    assert level == 2 and "layout file changed" in message and "parameter" in message, message
    rig.publish("hexagon", rig.msg("hexagon", good), expect_output=True)
    assert rig.contacts["hexagon"][-1].total_force == pytest.approx(1.0, rel=0.15)
    layout.write_text(text)
    level, message, values = status_until(lambda lv, m: "layout file changed" not in m)
    assert level == 0 and values["bundle_problem"] == "", message
    rig.close()


def test_frames_before_the_first_clock_in_sim_time_are_not_said_ahead(
    ros_context: object, bundles: Path
) -> None:
    """With use_sim_time and no /clock yet (a bag played with --clock starting), the node's
    clock reads 0: a frame's latency is no age then, and is neither counted nor warned about
    as stamped ahead (NTP advice for a clock that has not started)."""
    rig = Rig(ros_context, bundles, use_sim_time=True)
    pipeline = rig.node.pipelines["hexagon"]
    assert rig.node.now_ns() == 0
    rig.send(_delta_c(1.0, tuple(pipeline.recon.taxel_xy[30])), sec=int(time.time()))
    assert pipeline.stats.stamps_ahead == 0 and len(pipeline.stats.latency_s) == 0
    assert "ahead" not in pipeline.diagnostics().message
    rig.close()
