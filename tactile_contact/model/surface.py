"""Where a flat patch lies on the robot: its surface in a link frame.

A patch is reconstructed in a flat frame (x, y on the skin, z outward). On a robot that frame
is the *unrolled* skin of a curved body part. A :class:`Surface` maps it back: the robot link
whose frame the 3-D positions are in (e.g. ``l_forearm``), the shape (``plane`` or
``cylinder``), and the pose of the patch frame's origin on that surface.

The map from the patch frame (u, v) [m] and a height w [m] above the taxel layer to the link
frame, in the tangent frame at the patch origin::

    plane:    local = (u, v, w)
    cylinder: local = ((R + w)·sin(u/R), v, (R + w)·cos(u/R) − R)      axis along local ŷ,
                                                                        R the taxel-layer radius
    link      = rotation · local + origin

so u runs around the cylinder (arc length at the taxel layer, where the unrolling is exact),
v along its axis, and the outward normal is (sin(u/R), 0, cos(u/R)) in local coordinates.
``orientation`` is the quaternion (x, y, z, w) of ``rotation``, as in geometry_msgs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

SHAPES = ("plane", "cylinder")


def quaternion_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """(3, 3) rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in np.asarray(q, dtype=np.float64))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_quaternion(m: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (x, y, z, w), w ≥ 0, of a (3, 3) rotation matrix (Shepperd's method:
    divides by the largest of the four candidates, so it stays accurate at every angle)."""
    r = np.asarray(m, dtype=np.float64)
    tr = np.trace(r)
    cands = [tr, r[0, 0], r[1, 1], r[2, 2]]
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    else:
        i = k - 1
        j, n = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[n, n], 0.0))
        q = [0.0, 0.0, 0.0, (r[n, j] - r[j, n]) / s]
        q[i] = s / 4
        q[j] = (r[j, i] + r[i, j]) / s
        q[n] = (r[n, i] + r[i, n]) / s
    out = np.asarray(q, dtype=np.float64)
    out /= np.linalg.norm(out)
    return out if out[3] >= 0 else -out


@dataclass(frozen=True)
class Surface:
    """A patch's skin surface on the robot (see the module docstring for the map).

    Attributes:
        frame_id: the robot link frame the 3-D positions are in (e.g. ``l_forearm``).
        shape: ``plane`` or ``cylinder``.
        origin: (x, y, z) [m] of the patch frame's origin, in the link frame.
        orientation: quaternion (x, y, z, w) of the patch frame's axes at its origin.
        radius: cylinder radius [m] at the taxel layer (None for a plane).
    """

    frame_id: str
    shape: str
    origin: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    radius: float | None = None

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"unknown surface shape {self.shape!r} (known: {', '.join(SHAPES)})")
        if (self.shape == "cylinder") != (self.radius is not None):
            raise ValueError("a cylinder needs a radius and a plane has none")
        if self.radius is not None and not (self.radius > 0 and math.isfinite(self.radius)):
            raise ValueError(f"radius must be a positive length, got {self.radius!r}")
        n = math.sqrt(sum(v * v for v in self.orientation))
        if not abs(n - 1.0) < 1e-3:
            raise ValueError(f"orientation must be a unit quaternion (x, y, z, w), norm {n:.6g}")

    @property
    def rotation(self) -> NDArray[np.float64]:
        """(3, 3) rotation from the tangent frame at the patch origin to the link frame."""
        q = np.asarray(self.orientation, dtype=np.float64)
        return quaternion_matrix(q / np.linalg.norm(q))

    def _local(self, uv: ArrayLike, height: float) -> tuple[NDArray, NDArray]:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        u, v = uv[:, 0], uv[:, 1]
        if self.shape == "plane":
            pts = np.column_stack([u, v, np.full_like(u, height)])
            nrm = np.tile([0.0, 0.0, 1.0], (len(u), 1))
            return pts, nrm
        r = float(self.radius)  # type: ignore[arg-type]
        a = u / r
        nrm = np.column_stack([np.sin(a), np.zeros_like(a), np.cos(a)])
        pts = np.column_stack([(r + height) * np.sin(a), v, (r + height) * np.cos(a) - r])
        return pts, nrm

    def to_link(self, uv: ArrayLike, height: float = 0.0) -> NDArray[np.float64]:
        """(N, 3) link-frame points [m] of patch-frame points ``uv`` (N, 2) [m], ``height``
        [m] outward of the taxel layer."""
        pts, _ = self._local(uv, height)
        return pts @ self.rotation.T + np.asarray(self.origin, dtype=np.float64)

    def normals(self, uv: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) outward unit normals, link frame, at patch-frame points ``uv``."""
        _, nrm = self._local(uv, 0.0)
        return nrm @ self.rotation.T

    def frames(self, uv: ArrayLike) -> NDArray[np.float64]:
        """(N, 3, 3) rotations of the surface's local frames at ``uv`` (columns: x̂ along u,
        ŷ along v, ẑ outward), link frame: the orientation of a marker lying on the skin."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        n = len(uv)
        local = np.tile(np.eye(3), (n, 1, 1))
        if self.shape == "cylinder":
            a = uv[:, 0] / float(self.radius)  # type: ignore[arg-type]
            c, s = np.cos(a), np.sin(a)
            local[:, 0, 0], local[:, 2, 0] = c, -s  # x̂: d(point)/du
            local[:, 0, 2], local[:, 2, 2] = s, c  # ẑ: the normal
        return np.einsum("ij,njk->nik", self.rotation, local)

    @classmethod
    def from_dict(cls, d: dict | None) -> Surface | None:
        """The surface of :meth:`to_dict`'s plain data (as stored in a bundle manifest's
        layout); None for None. Raises ValueError on bad values."""
        if d is None:
            return None
        return cls(
            str(d["frame_id"]),
            str(d["shape"]),
            tuple(float(v) for v in d["origin"]),  # type: ignore[arg-type]
            tuple(float(v) for v in d["orientation"]),  # type: ignore[arg-type]
            float(d["radius"]) if d.get("radius") is not None else None,
        )

    def to_dict(self) -> dict:
        """Plain data as written in a layout file."""
        d: dict = {
            "frame_id": self.frame_id,
            "shape": self.shape,
            "origin": [float(v) for v in self.origin],
            "orientation": [float(v) for v in self.orientation],
        }
        if self.radius is not None:
            d["radius"] = float(self.radius)
        return d
