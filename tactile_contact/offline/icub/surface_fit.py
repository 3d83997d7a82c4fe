"""Fitting a skin part's 3-D taxel positions: plane or cylinder, unrolling, 2-D rigid fits.

All lengths are metres. A curved part is flattened at the taxel layer: a cylinder is fitted
to the positions (least squares on the radial residual), cut along the widest empty angular
gap (the seam) and unrolled, ``u = R·φ`` around the axis and ``v`` along it. That map is an
isometry of the cylinder, so distances measured in the surface are kept exactly; what the
unrolling cannot keep (a section that is not round, the layer's thickness) is measured by
the importer's report, not assumed. The unrolled frame is right-handed seen from outside:
x̂ = φ̂ (around the axis), ŷ = the axis, ẑ = outward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

#: A part is treated as flat when its points lie within this rms distance [m] of a plane.
PLANE_RMS = 0.6e-3
#: ... or when the fitted cylinder is this many times wider than the part (nearly flat).
FLAT_RADIUS_RATIO = 6.0


@dataclass(frozen=True)
class SurfaceFit:
    """A plane or cylinder fitted to 3-D points, with a frame to flatten them in.

    Attributes:
        shape: ``plane`` or ``cylinder``.
        centre: a point [m]: on the axis (cylinder) or the points' centroid (plane).
        axis: unit vector: the cylinder axis, or the plane's in-plane ŷ.
        ref: unit vector ⊥ axis: the direction of the seam's far side (cylinder: φ is measured
            from the radial direction ``ref`` rotated by π, i.e. the seam is at ``-ref``...) —
            see :meth:`flatten`; for a plane, its in-plane x̂.
        normal: unit vector: the plane's outward normal (cylinder: unused, radial outward).
        radius: the cylinder radius [m] (inf for a plane).
        rms: rms distance of the fitted points from the surface [m].
        worst: largest such distance [m].
    """

    shape: str
    centre: NDArray[np.float64]
    axis: NDArray[np.float64]
    ref: NDArray[np.float64]
    normal: NDArray[np.float64]
    radius: float
    rms: float
    worst: float

    def flatten(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) flattened (u, v) [m] of 3-D points: for a cylinder u = R·φ with φ in
        (−π, π] measured from ``ref`` counter-clockwise about the axis, v along the axis;
        for a plane the in-plane coordinates along ``ref`` and ``axis``."""
        d = np.asarray(points, dtype=np.float64) - self.centre
        v = d @ self.axis
        if self.shape == "plane":
            return np.column_stack([d @ self.ref, v])
        side = np.cross(self.axis, self.ref)  # φ = +90°
        phi = np.arctan2(d @ side, d @ self.ref)
        return np.column_stack([self.radius * phi, v])

    def unflatten(self, uv: NDArray[np.float64], height: float = 0.0) -> NDArray[np.float64]:
        """(N, 3) points of the surface (offset ``height`` [m] outward) at flattened ``uv``."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.shape == "plane":
            return self.centre + uv[:, :1] * self.ref + uv[:, 1:] * self.axis + height * self.normal
        phi = uv[:, 0] / self.radius
        side = np.cross(self.axis, self.ref)
        radial = np.cos(phi)[:, None] * self.ref + np.sin(phi)[:, None] * side
        return self.centre + uv[:, 1:] * self.axis + (self.radius + height) * radial

    def normals(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 3) outward unit normals of the surface at (the projections of) ``points``."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.shape == "plane":
            return np.tile(self.normal, (len(p), 1))
        d = p - self.centre
        d = d - np.outer(d @ self.axis, self.axis)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


def _orthonormal(a: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit vectors completing ``a`` to an orthonormal basis."""
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def _canonical(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``v`` with the sign that makes its largest component positive (deterministic axes)."""
    return v if v[int(np.argmax(np.abs(v)))] > 0 else -v


def fit_plane(points: NDArray[np.float64]) -> SurfaceFit:
    """Least-squares plane through ``points`` (N ≥ 3); in-plane axes along the principal
    directions (ŷ the longest), normal completing a right-handed frame."""
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    y = _canonical(vt[0])
    n = _canonical(vt[2])
    x = np.cross(y, n)
    dist = np.abs((p - c) @ n)
    return SurfaceFit(
        "plane", c, y, x, n, math.inf, float(np.sqrt(np.mean(dist**2))), float(dist.max())
    )


def _circle(xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """Algebraic (Kåsa) circle through 2-D points: centre and radius (a starting guess)."""
    a = np.column_stack([2 * xy, np.ones(len(xy))])
    b = (xy**2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:2]
    return centre, float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))


def _axis(x: NDArray, basis: tuple) -> tuple[NDArray, NDArray]:
    """Axis direction and point of the cylinder parameters ``x`` (two tilts of the guessed
    axis a0 towards e1, e2; the point's offset from m in the plane ⊥ the axis)."""
    a0, e1, e2, m = basis
    a = a0 + x[0] * e1 + x[1] * e2
    a = a / np.linalg.norm(a)
    f1, f2 = _orthonormal(a)
    return a, m + x[2] * f1 + x[3] * f2


def _radial_residual(x: NDArray, p: NDArray, basis: tuple) -> NDArray:
    """Distance of each point from the axis minus the radius x[4]."""
    a, c = _axis(x, basis)
    d = p - c
    d = d - np.outer(d @ a, a)
    return np.linalg.norm(d, axis=1) - x[4]


def fit_cylinder(
    points: NDArray[np.float64], axis_guesses: list[NDArray[np.float64]] | None = None
) -> SurfaceFit:
    """Least-squares cylinder through ``points`` (N ≥ 5): minimises the radial residual over
    the axis direction and position and the radius, started from each guessed axis (default:
    the three principal directions of the points) and keeping the best. The reference
    direction (φ = 0) points at the middle of the points' angular extent, so that the seam
    (φ = ±π) falls in the widest empty gap."""
    p = np.asarray(points, dtype=np.float64)
    m = p.mean(axis=0)
    if axis_guesses is None:
        _, _, vt = np.linalg.svd(p - m, full_matrices=False)
        axis_guesses = list(vt)
    best: tuple[float, NDArray, NDArray, float] | None = None
    for a0 in axis_guesses:
        a0 = np.asarray(a0, dtype=np.float64) / np.linalg.norm(a0)
        e1, e2 = _orthonormal(a0)
        q = p - m
        c2, r0 = _circle(np.column_stack([q @ e1, q @ e2]))
        if not np.isfinite(r0) or r0 <= 0:
            continue

        # Start: the axis through the circle centre found in the plane ⊥ a0.
        f1, f2 = _orthonormal(a0)
        c0 = m + c2[0] * e1 + c2[1] * e2
        x0 = np.array([0.0, 0.0, (c0 - m) @ f1, (c0 - m) @ f2, r0])
        basis = (a0, e1, e2, m)
        sol = least_squares(_radial_residual, x0, method="lm", x_scale="jac", args=(p, basis))
        a, c = _axis(sol.x, basis)
        radius = abs(float(sol.x[4]))
        rms = float(np.sqrt(np.mean(sol.fun**2)))
        if best is None or rms < best[0]:
            best = (rms, a, c, radius)
    if best is None:
        raise ValueError("no cylinder fits these points")
    rms, a, c, radius = best
    a = _canonical(a)
    c = c + ((m - c) @ a) * a  # the axis point level with the points' centroid
    d = p - c
    d = d - np.outer(d @ a, a)
    resid = np.abs(np.linalg.norm(d, axis=1) - radius)
    # φ = 0 opposite the seam: the middle of the occupied arc, found from the widest gap.
    e1, e2 = _orthonormal(a)
    phi = np.sort(np.arctan2(d @ e2, d @ e1))
    gaps = np.diff(np.concatenate([phi, [phi[0] + 2 * np.pi]]))
    k = int(np.argmax(gaps))
    seam = phi[k] + gaps[k] / 2
    ref_angle = seam + np.pi
    ref = math.cos(ref_angle) * e1 + math.sin(ref_angle) * e2
    return SurfaceFit(
        "cylinder", c, a, ref, np.zeros(3), radius, float(np.sqrt(np.mean(resid**2))),
        float(resid.max()),
    )  # fmt: skip


def fit_surface(
    points: NDArray[np.float64], normals: NDArray[np.float64] | None = None
) -> SurfaceFit:
    """The plane if the points are flat (rms ≤ PLANE_RMS) or a cylinder does not describe them
    better, else the cylinder. ``normals`` (real ones, not a constant) add an axis guess: the
    direction least represented among them."""
    p = np.asarray(points, dtype=np.float64)
    plane = fit_plane(p)
    if plane.rms <= PLANE_RMS or len(p) < 6:
        return plane
    guesses = None
    if normals is not None and len(normals) >= 3:
        n = np.asarray(normals, dtype=np.float64)
        _, _, vt = np.linalg.svd(n, full_matrices=False)
        _, _, vp = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)
        guesses = [vt[2], *vp]
    try:
        cyl = fit_cylinder(p, guesses)
    except ValueError:
        return plane
    extent = float(np.ptp(p @ plane.ref)) + float(np.ptp(p @ plane.axis))
    if cyl.radius > FLAT_RADIUS_RATIO * extent or cyl.rms >= 0.8 * plane.rms:
        return plane
    return cyl


def flip_plane(fit: SurfaceFit) -> SurfaceFit:
    """The same plane seen from its other side (normal and x̂ reversed)."""
    if fit.shape != "plane":
        raise ValueError("only a plane has two sides to choose from")
    return SurfaceFit(
        "plane", fit.centre, fit.axis, -fit.ref, -fit.normal, fit.radius, fit.rms, fit.worst
    )


@dataclass(frozen=True)
class RigidFit2D:
    """``target ≈ R(angle)·F·source + offset`` with F = diag(−1, 1) if ``mirrored``.

    Attributes:
        angle_deg: counter-clockwise rotation [deg], in [0, 360).
        mirrored: the source was mirrored (x → −x) before rotating.
        offset: (2,) translation [m].
        rms: rms distance of the fitted points [m].
        worst: largest distance [m].
        scale: the best similarity scale (1 for a rigid fit; fitted if asked).
    """

    angle_deg: float
    mirrored: bool
    offset: NDArray[np.float64]
    rms: float
    worst: float
    scale: float = 1.0

    def apply(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2).copy()
        if self.mirrored:
            xy[:, 0] = -xy[:, 0]
        t = math.radians(self.angle_deg)
        rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        return self.scale * xy @ rot.T + self.offset


def rigid_fit_2d(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    mirrored: bool,
    scale: bool = False,
) -> RigidFit2D:
    """Least-squares rotation (+ optional uniform scale) and translation taking ``source``
    (mirrored first if asked) onto ``target`` (Kabsch / Umeyama in 2-D; ≥ 2 points)."""
    s = np.asarray(source, dtype=np.float64).reshape(-1, 2).copy()
    t = np.asarray(target, dtype=np.float64).reshape(-1, 2)
    if mirrored:
        s[:, 0] = -s[:, 0]
    sc, tc = s.mean(axis=0), t.mean(axis=0)
    a, b = s - sc, t - tc
    # The optimal angle maximises Σ b·R a: atan2 of the cross and dot sums.
    angle = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])), float(np.sum(a * b)))
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    k = 1.0
    if scale:
        den = float(np.sum(a * a))
        k = float(np.sum(b * (a @ rot.T))) / den if den > 0 else 1.0
    offset = tc - k * sc @ rot.T
    res = np.linalg.norm(k * s @ rot.T + offset - t, axis=1)
    return RigidFit2D(
        math.degrees(angle) % 360.0, mirrored, offset, float(np.sqrt(np.mean(res**2))),
        float(res.max()), k,
    )  # fmt: skip
