"""Arrays → standard ROS messages for rviz2, rqt and Foxglove (no plugin needed).

Grids go out as ``sensor_msgs/Image`` 32FC1, one pixel per cell: column c grows along +x,
row r along +y, pixel (0, 0) is the cell at the grid origin (minimum x, minimum y). Cells
outside the skin are 0. The same geometry is published as ``tactile_contact/GridGeometry``.

The rviz2 outputs (taxel markers, pressure cloud, contact markers) of a patch whose layout
has a ``surface`` (an imported robot skin, docs/icub.md) are drawn on the robot: in the
surface's link frame, at the 3-D points the surface maps the flat patch frame to, discs
oriented along its normals. Without one they lie flat in the patch frame (z = 0).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from geometry_msgs.msg import Point
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from tactile_contact.model.surface import Surface, matrix_quaternion
from tactile_contact.msg import Contact, ContactState, GridGeometry


class NonFiniteError(ValueError):
    """An array meant for a message holds NaN or inf (never published)."""


class GridLike(Protocol):
    """What the converters need of a cell grid (see :mod:`tactile_contact.model.grids`)."""

    @property
    def origin(self) -> tuple[float, float]: ...  # lower-left corner of cell (0, 0) [m]

    @property
    def cell(self) -> tuple[float, float]: ...  # cell size (dx, dy) [m]

    @property
    def shape(self) -> tuple[int, int]: ...  # (rows along y, columns along x)

    @property
    def mask(self) -> np.ndarray: ...  # (rows, cols) bool, True on the skin


def _finite(name: str, array: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(array)):
        bad = int(np.count_nonzero(~np.isfinite(array)))
        raise NonFiniteError(f"{name}: {bad} non-finite value(s); not published")
    return array


def grid_image(name: str, field: np.ndarray, header: Header) -> Image:
    """A (rows, cols) field as a 32FC1 image (row 0 = minimum y)."""
    data = np.ascontiguousarray(_finite(name, np.asarray(field)), dtype="<f4")
    rows, cols = data.shape
    return Image(
        header=header,
        height=rows,
        width=cols,
        encoding="32FC1",
        is_bigendian=0,
        step=cols * 4,
        data=data.tobytes(),
    )


def grid_geometry(grid: GridLike, which: str, patch: str, header: Header) -> GridGeometry:
    """The geometry message for one grid ("traction" or "deflection")."""
    rows, cols = grid.shape
    return GridGeometry(
        header=header,
        patch=patch,
        grid=which,
        origin_x=float(grid.origin[0]),
        origin_y=float(grid.origin[1]),
        cell_size_x=float(grid.cell[0]),
        cell_size_y=float(grid.cell[1]),
        width=cols,
        height=rows,
        mask=np.asarray(grid.mask, dtype=np.uint8).ravel().tolist(),
    )


_CLOUD_FIELDS = [
    PointField(name="x", offset=0, datatype=PointField.FLOAT32, count=1),
    PointField(name="y", offset=4, datatype=PointField.FLOAT32, count=1),
    PointField(name="z", offset=8, datatype=PointField.FLOAT32, count=1),
    PointField(name="pressure", offset=12, datatype=PointField.FLOAT32, count=1),
]


def _on_surface(header: Header, surface: Surface | None) -> Header:
    """The header of an output drawn on the robot: the surface's link frame, same stamp."""
    if surface is None:
        return header
    return Header(stamp=header.stamp, frame_id=surface.frame_id)


def _pose(marker: Marker, xyz: np.ndarray, rotation: np.ndarray | None = None) -> None:
    marker.pose.position = Point(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
    if rotation is None:
        marker.pose.orientation.w = 1.0
        return
    q = matrix_quaternion(rotation)
    o = marker.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q)


def pressure_cloud(
    grid: GridLike,
    traction: np.ndarray,
    header: Header,
    deflection_scale: float = 0.0,
    surface: Surface | None = None,
) -> PointCloud2:
    """Cells on the skin as points (x, y, z, pressure [Pa]): in the patch frame with z = 0,
    or, given the patch's ``surface``, at their places on the robot in its link frame. rviz2
    colours the points by the ``pressure`` channel.
    """
    _finite("traction", traction)
    rows, cols = grid.shape
    x = grid.origin[0] + (np.arange(cols) + 0.5) * grid.cell[0]
    y = grid.origin[1] + (np.arange(rows) + 0.5) * grid.cell[1]
    xx, yy = np.meshgrid(x, y)
    on = np.asarray(grid.mask, dtype=bool)
    pts = np.zeros((int(on.sum()), 4), dtype="<f4")
    if surface is None:
        pts[:, 0] = xx[on]
        pts[:, 1] = yy[on]
    else:
        pts[:, :3] = surface.to_link(np.column_stack([xx[on], yy[on]]))
        header = _on_surface(header, surface)
    pts[:, 3] = traction[on]
    return PointCloud2(
        header=header,
        height=1,
        width=pts.shape[0],
        fields=_CLOUD_FIELDS,
        is_bigendian=False,
        point_step=16,
        row_step=16 * pts.shape[0],
        data=pts.tobytes(),
        is_dense=True,
    )


def _colour(value: float, full_scale: float) -> ColorRGBA:
    # Diverging map: compression red, bulge (negative) blue, no change grey.
    s = float(np.clip(value / full_scale, -1.0, 1.0)) if full_scale > 0 else 0.0
    if s >= 0:
        return ColorRGBA(r=0.6 + 0.4 * s, g=0.6 * (1 - s), b=0.6 * (1 - s), a=1.0)
    return ColorRGBA(r=0.6 * (1 + s), g=0.6 * (1 + s), b=0.6 - 0.4 * s, a=1.0)


#: Height [m] of a contact's disc per newton of its force.
CONTACT_HEIGHT_PER_NEWTON = 2.0e-3


def contact_markers(
    contacts: Any, header: Header, patch: str, surface: Surface | None = None
) -> MarkerArray:
    """Each contact (:class:`tactile_contact.inverse.summary.Contact`) as a translucent disc of its
    radius at its centre, CONTACT_HEIGHT_PER_NEWTON tall per newton, with its force as text.
    A DELETEALL first clears the discs of the previous frame (there may be fewer contacts).
    Given the patch's ``surface``: on the robot, in its link frame, the disc standing on the
    skin along the normal at the contact's centre."""
    _finite("contacts", np.array([[c.force, c.radius, *c.center] for c in contacts], float))
    ns = f"{patch}/contacts"
    header = _on_surface(header, surface)
    markers = [Marker(header=header, ns=ns, action=Marker.DELETEALL)]
    for i, c in enumerate(contacts):
        height = max(CONTACT_HEIGHT_PER_NEWTON * float(c.force), 1e-4)
        uv = np.array([[float(c.center[0]), float(c.center[1])]])
        disc = Marker(header=header, ns=ns, id=2 * i, type=Marker.CYLINDER, action=Marker.ADD)
        if surface is None:
            _pose(disc, np.array([uv[0, 0], uv[0, 1], 0.5 * height]))
            top = np.array([uv[0, 0], uv[0, 1], height])
        else:
            _pose(disc, surface.to_link(uv, 0.5 * height)[0], surface.frames(uv)[0])
            top = surface.to_link(uv, height)[0]
        disc.scale.x = disc.scale.y = 2.0 * float(c.radius)
        disc.scale.z = height
        disc.color = ColorRGBA(r=1.0, g=0.55, b=0.0, a=0.6)
        label = Marker(
            header=header, ns=ns, id=2 * i + 1, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD
        )
        _pose(label, top)
        label.scale.z = 3e-3
        label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        label.text = f"{float(c.force):.2f} N ({c.profile})"
        markers += [disc, label]
    return MarkerArray(markers=markers)


def taxel_markers(
    taxel_xy: np.ndarray,
    delta_c: np.ndarray,
    valid: np.ndarray,
    header: Header,
    patch: str,
    radius: float,
    full_scale: float,
    surface: Surface | None = None,
) -> MarkerArray:
    """Taxels as discs coloured by ΔC (red compression, blue bulge, black invalid); given the
    patch's ``surface``, as spheres at their places on the robot, in its link frame (a sphere
    list has one orientation for all, which a curved skin does not)."""
    header = _on_surface(header, surface)
    marker = Marker(header=header, ns=f"{patch}/taxels", id=0, type=Marker.SPHERE_LIST)
    marker.action = Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = 2.0 * radius
    marker.scale.z = 0.2 * radius if surface is None else 2.0 * radius
    xyz = (
        np.column_stack([taxel_xy, np.zeros(len(taxel_xy))])
        if surface is None
        else surface.to_link(taxel_xy)
    )
    marker.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in xyz]
    marker.colors = [
        _colour(float(v), full_scale) if ok else ColorRGBA(a=1.0)
        for v, ok in zip(np.nan_to_num(delta_c), valid, strict=True)
    ]
    return MarkerArray(markers=[marker])


def contact(c: Any) -> Contact:
    """A Contact message from a :class:`tactile_contact.inverse.summary.Contact`."""
    return Contact(
        force=float(c.force),
        center=Point(x=float(c.center[0]), y=float(c.center[1]), z=0.0),
        radius=float(c.radius),
        profile=str(c.profile),
    )


def contact_state(result: Any, patch: str, header: Header, **extra: Any) -> ContactState:
    """A ContactState from a reconstruction result; non-finite numbers are refused."""
    values = [result.total_force, result.contact_area, result.peak_pressure, *result.cop]
    _finite("contact summary", np.asarray(values, dtype=float))
    contacts = getattr(result, "contacts", ())
    _finite("contacts", np.array([[c.force, c.radius, *c.center] for c in contacts], float))
    msg = ContactState(
        header=header,
        patch=patch,
        in_contact=bool(result.in_contact),
        total_force=float(result.total_force),
        center_of_pressure=Point(x=float(result.cop[0]), y=float(result.cop[1]), z=0.0),
        contact_area=float(result.contact_area),
        peak_pressure=float(result.peak_pressure),
        contacts=[contact(c) for c in contacts],
    )
    for key, value in extra.items():
        setattr(msg, key, value)
    return msg
