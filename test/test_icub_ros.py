"""An imported iCub patch in ROS: its rviz2 outputs drawn on the robot (in the link frame, at
the surface's 3-D points), from the converters and from a running contact_reconstruction."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_contact.inverse.summary import Contact
from tactile_contact.model.layout import load_layout

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
FOREARM = ROOT / "config" / "icub" / "left_forearm_V2.yaml"


def _axis_distance(surface, points):
    """Distance [m] of link-frame points from the cylinder's axis."""
    rot = surface.rotation
    axis, centre = rot[:, 1], np.asarray(surface.origin) - surface.radius * rot[:, 2]
    d = points - centre
    return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)


def _points(marker):
    return np.array([[p.x, p.y, p.z] for p in marker.points])


def test_converters_draw_a_curved_patch_on_its_link():
    from std_msgs.msg import Header

    from tactile_contact.model.surface import quaternion_matrix
    from tactile_contact.offline.build import grids_for
    from tactile_contact.ros import convert

    patch = load_layout(FOREARM).patches[0]
    s = patch.surface
    header = Header(frame_id=patch.frame_id)
    xy = patch.taxel_xy()
    (m,) = convert.taxel_markers(
        xy, np.zeros(len(xy)), np.ones(len(xy), bool), header, patch.name, 2e-3, 1e-13, s
    ).markers
    assert m.header.frame_id == "l_forearm"
    pts = _points(m)
    np.testing.assert_allclose(pts, s.to_link(xy), atol=1e-12)
    np.testing.assert_allclose(_axis_distance(s, pts), s.radius, rtol=1e-9)

    tg, _ = grids_for(patch)
    cloud = convert.pressure_cloud(tg, np.ones(tg.shape), header, surface=s)
    assert cloud.header.frame_id == "l_forearm" and cloud.width == tg.n_cells
    xyz = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 4)[:, :3]
    np.testing.assert_allclose(_axis_distance(s, xyz.astype(float)), s.radius, atol=1e-5)

    contact = Contact(force=2.0, center=tuple(xy[120]), radius=3e-3, profile="hertz")
    markers = convert.contact_markers([contact], header, patch.name, s).markers
    disc = markers[1]
    assert disc.header.frame_id == "l_forearm"
    o = disc.pose.orientation
    rot = quaternion_matrix([o.x, o.y, o.z, o.w])
    # The disc stands on the skin: its axis is the surface normal at the contact's centre.
    np.testing.assert_allclose(rot[:, 2], s.normals(xy[120:121])[0], atol=1e-9)
    p = disc.pose.position
    np.testing.assert_allclose(
        [p.x, p.y, p.z], s.to_link(xy[120:121], 0.5 * disc.scale.z)[0], atol=1e-12
    )
    # Without a surface nothing changes: flat in the patch frame.
    (flat,) = convert.taxel_markers(
        xy, np.zeros(len(xy)), np.ones(len(xy), bool), header, patch.name, 2e-3, 1e-13
    ).markers
    assert flat.header.frame_id == patch.frame_id and np.all(_points(flat)[:, 2] == 0)


LEG = ROOT / "config" / "icub" / "left_leg_lower.yaml"


@pytest.fixture(scope="module")
def leg_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundle of one patch of the shipped lower leg (board 9: 8 modules on a cylinder)."""
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("icub_bundles")
    build_layout(LEG, out, patches=["left_leg_lower_b9"], jobs=1)
    return out


def test_a_running_node_draws_an_imported_patch_on_its_link(ros_context, leg_bundle):
    """contact_reconstruction over real DDS: a press on the leg's patch comes out as markers
    and a cloud in the leg's link frame, on the cylinder, the contact disc along the normal."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    from tactile_contact.model.forward import ForwardModel
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.sensor import compression_to_delta_c
    from tactile_contact.model.surface import quaternion_matrix
    from tactile_contact.msg import ContactState, TaxelArray
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode
    from test.rosutil import spin_until

    name = "left_leg_lower_b9"
    patch = load_layout(LEG).patch(name)
    s = patch.surface
    node = ContactReconstructionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(leg_bundle)),
            Parameter("patches", value=[name]),
        ],
    )
    probe = Node("probe", context=ros_context)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    got: dict[str, list] = {"contact": [], "taxel_markers": [], "contact_markers": [], "cloud": []}
    probe.create_subscription(ContactState, f"{name}/contact", got["contact"].append, qos)
    probe.create_subscription(
        MarkerArray, f"{name}/taxel_markers", got["taxel_markers"].append, qos
    )
    probe.create_subscription(
        MarkerArray, f"{name}/contact_markers", got["contact_markers"].append, qos
    )
    probe.create_subscription(PointCloud2, f"{name}/pressure_cloud", got["cloud"].append, qos)
    pub = probe.create_publisher(TaxelArray, f"{name}/taxels", 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(probe)
    try:
        pipe = node.pipelines[name]
        outs = (pipe.pub_markers, pipe.pub_contact_markers, pipe.pub_cloud, pipe.pub_contact)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0)
        assert spin_until(ex, lambda: all(p.get_subscription_count() for p in outs))
        # A 12 mm sphere at 1.5 N on taxel 40, by the independent fine forward model.
        xy = patch.taxel_xy()
        e, se = patch.elastomer, patch.sensor
        model = ForwardModel(xy, e.thickness, e.young, e.poisson, taxel_radius=se.taxel_radius)
        delta = model.compression(HertzSphere(6e-3), 1.5, xy[40])
        msg = TaxelArray(patch=name)
        msg.header.stamp.sec = 1
        msg.header.frame_id = patch.frame_id
        msg.taxel_ids = patch.taxel_ids().tolist()
        msg.delta_c = compression_to_delta_c(delta, e.thickness, se.epsilon_r, se.area).tolist()
        msg.raw = [240] * len(xy)
        msg.status = [0] * len(xy)
        pub.publish(msg)
        assert spin_until(ex, lambda: all(got.values())), {k: len(v) for k, v in got.items()}
    finally:
        ex.shutdown()
        node.destroy_node()
        probe.destroy_node()
    state = got["contact"][-1]
    assert state.in_contact and state.header.frame_id == patch.frame_id  # the flat frame
    assert state.total_force == pytest.approx(1.5, rel=0.3)
    (taxels,) = got["taxel_markers"][-1].markers
    assert taxels.header.frame_id == "l_lower_leg"
    pts = np.array([[p.x, p.y, p.z] for p in taxels.points])
    np.testing.assert_allclose(pts, s.to_link(xy), atol=1e-9)
    np.testing.assert_allclose(_axis_distance(s, pts), s.radius, rtol=1e-6)
    cloud = got["cloud"][-1]
    assert cloud.header.frame_id == "l_lower_leg"
    cxyz = np.frombuffer(bytes(cloud.data), "<f4").reshape(-1, 4)[:, :3].astype(float)
    np.testing.assert_allclose(_axis_distance(s, cxyz), s.radius, atol=2e-5)
    _, disc, _ = got["contact_markers"][-1].markers
    assert disc.header.frame_id == "l_lower_leg"
    centre = np.array([[state.contacts[0].center.x, state.contacts[0].center.y]])
    o = disc.pose.orientation
    np.testing.assert_allclose(
        quaternion_matrix([o.x, o.y, o.z, o.w])[:, 2], s.normals(centre)[0], atol=1e-6
    )
    # Where the node puts the contact on the robot is within a few mm of the press's 3-D
    # place (the positions file's row of taxel 40, through the importer's flattening).
    press_3d = s.to_link(xy[40:41])[0]
    foot = s.to_link(centre)[0]
    assert np.linalg.norm(foot - press_3d) < 3e-3
