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
