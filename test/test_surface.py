"""The patch surface on the robot (tactile_contact.model.surface) and its layout key."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tactile_contact.model.layout import LayoutError, load_layout, parse_layout
from tactile_contact.model.surface import Surface, matrix_quaternion, quaternion_matrix

unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_quaternions_agree_with_scipy(q):
    q = np.asarray(q) / np.linalg.norm(q)
    m = quaternion_matrix(q)
    np.testing.assert_allclose(m, Rotation.from_quat(q).as_matrix(), atol=1e-12)
    back = matrix_quaternion(m)
    # q and −q are the same rotation; matrix_quaternion returns the one with w ≥ 0.
    assert back[3] >= 0
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


def _cylinder(radius=0.036) -> Surface:
    q = Rotation.from_euler("xyz", [0.3, -0.7, 1.1]).as_quat()
    return Surface("l_forearm", "cylinder", (0.01, -0.02, 0.03), tuple(q), radius)


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-0.08, 0.08), st.floats(-0.08, 0.08), st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)
)
def test_cylinder_keeps_arc_lengths_and_axial_distances(u1, u2, v1, v2):
    s = _cylinder()
    r = s.radius
    p = s.to_link([[u1, v1], [u2, v1], [u1, v2]])
    # Around the axis: the chord of the arc |Δu| on a circle of radius R.
    assert np.linalg.norm(p[0] - p[1]) == pytest.approx(
        2 * r * abs(math.sin((u1 - u2) / (2 * r))), abs=1e-12
    )
    # Along the axis: the same distance as in the plane.
    assert np.linalg.norm(p[0] - p[2]) == pytest.approx(abs(v1 - v2), abs=1e-12)


def test_cylinder_geometry_and_frames():
    s = _cylinder()
    uv = np.array([[0.0, 0.0], [0.02, 0.01], [-0.05, 0.03], [0.1, -0.02]])
    np.testing.assert_allclose(s.to_link(uv[:1])[0], s.origin, atol=1e-15)
    rot = s.rotation
    axis, centre = rot[:, 1], np.asarray(s.origin) - s.radius * rot[:, 2]
    p = s.to_link(uv)
    n = s.normals(uv)
    # Every point is R from the axis, and its normal points away from the axis.
    d = p - centre
    radial = d - np.outer(d @ axis, axis)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), s.radius, rtol=1e-12)
    np.testing.assert_allclose(n, radial / s.radius, atol=1e-12)
    # A point 2 mm outward is 2 mm further along the normal.
    np.testing.assert_allclose(s.to_link(uv, 0.002) - p, 0.002 * n, atol=1e-12)
    f = s.frames(uv)
    for k in range(len(uv)):
        np.testing.assert_allclose(f[k].T @ f[k], np.eye(3), atol=1e-12)
        assert np.linalg.det(f[k]) == pytest.approx(1.0)
        np.testing.assert_allclose(f[k][:, 2], n[k], atol=1e-12)
        # x̂ is the direction in which the point moves when u grows (finite difference).
        du = (s.to_link(uv[k] + [1e-7, 0]) - s.to_link(uv[k] - [1e-7, 0]))[0] / 2e-7
        np.testing.assert_allclose(f[k][:, 0], du, atol=1e-6)


def test_plane_is_a_rigid_motion():
    q = Rotation.from_euler("zyx", [10, 20, 30], degrees=True).as_quat()
    s = Surface("l_hand", "plane", (0.1, 0.2, 0.3), tuple(q))
    uv = np.random.default_rng(0).uniform(-0.05, 0.05, (20, 2))
    p = s.to_link(uv)
    d2 = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    d3 = np.linalg.norm(p[:, None] - p[None], axis=2)
    np.testing.assert_allclose(d3, d2, atol=1e-12)
    np.testing.assert_allclose(s.normals(uv), np.tile(s.rotation[:, 2], (20, 1)), atol=1e-12)


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"shape": "cone"}, "unknown surface shape"),
        ({"radius": None}, "a cylinder needs a radius"),
        ({"radius": -0.01}, "radius must be a positive length"),
        ({"orientation": (0.0, 0.0, 0.0, 2.0)}, "unit quaternion"),
    ],
)
def test_surface_refuses_bad_values(kw, message):
    args = {
        "frame_id": "l_forearm",
        "shape": "cylinder",
        "origin": (0.0, 0.0, 0.0),
        "orientation": (0.0, 0.0, 0.0, 1.0),
        "radius": 0.03,
    } | kw
    with pytest.raises(ValueError, match=message):
        Surface(**args)


HEX = "config/hexagon_patch.yaml"


def _doc():
    return yaml.safe_load(open(HEX, encoding="utf-8"))


def test_layout_reads_a_surface_and_hashes_it_only_when_present():
    plain = parse_layout(_doc()).patches[0]
    assert plain.surface is None
    assert "surface" not in plain.to_dict() and "cdc_offset" not in plain.to_dict()["sensor"]
    doc = _doc()
    doc["patches"][0]["surface"] = {
        "frame_id": "l_forearm",
        "shape": "cylinder",
        "radius": 0.036,
        "origin": [0.0, 0.01, 0.02],
        "orientation": [0.0, 0.0, 0.0, 1.0],
    }
    doc["patches"][0]["sensor"]["cdc_offset"] = 0x2200
    placed = parse_layout(doc).patches[0]
    assert placed.surface == Surface(
        "l_forearm", "cylinder", (0.0, 0.01, 0.02), (0, 0, 0, 1), 0.036
    )
    assert placed.sensor.cdc_offset == 0x2200
    assert placed.to_dict()["surface"]["radius"] == 0.036
    # The bundle carries the surface: moving the patch on the robot makes its bundle stale,
    # but the matrices' geometry (layout hash) stays.
    assert placed.parameter_hash() != plain.parameter_hash()
    assert placed.layout_hash() == plain.layout_hash()


@pytest.mark.parametrize(
    ("surface", "message"),
    [
        ({"shape": "plane", "origin": [0, 0, 0], "orientation": [0, 0, 0, 1]}, "frame_id"),
        ({"frame_id": "x", "origin": [0, 0, 0], "orientation": [0, 0, 0, 1]}, "shape: missing"),
        (
            {"frame_id": "x", "shape": "plane", "origin": [0, 0], "orientation": [0, 0, 0, 1]},
            "surface.origin: expected [x, y, z]",
        ),
        (
            {"frame_id": "x", "shape": "plane", "origin": [0, 0, 0], "orientation": [0, 0, 1, 1]},
            "surface.orientation: not a unit quaternion",
        ),
        (
            {
                "frame_id": "x",
                "shape": "cylinder",
                "origin": [0, 0, 0],
                "orientation": [0, 0, 0, 1],
            },
            "surface.radius: missing required key",
        ),
        (
            {
                "frame_id": "x",
                "shape": "plane",
                "radius": 0.03,
                "origin": [0, 0, 0],
                "orientation": [0, 0, 0, 1],
            },
            "surface.radius: only a cylinder has a radius",
        ),
        ({"frame_id": "x", "shape": "plane", "pose": 1}, "surface.pose: unknown key"),
    ],
)
def test_layout_surface_errors_name_the_key(tmp_path, surface, message):
    doc = _doc()
    doc["patches"][0]["surface"] = surface
    f = tmp_path / "x.yaml"
    f.write_text(yaml.safe_dump(doc))
    with pytest.raises(LayoutError) as exc:
        load_layout(f)
    assert str(exc.value).startswith(f"{f}: patches[0].surface")
    assert message in str(exc.value)
