"""Closed-form contact pressure distributions of axisymmetric indenters (reference solutions).

Each indenter gives the pressure under it as a function of radius and, for a grid of
rectangular cells, the *exact* cell average of that pressure. Cell integrals are differences of
the cumulative function Φ(x, y) = ∫∫_{x'<x, y'<y} p dA evaluated at the cell corners, so the
integrable edge singularity of the flat punch is handled and the cell forces of any grid that
covers the contact sum to the applied force to rounding error. The inner y-integral is closed
form; the outer x-integral uses Gauss–Legendre quadrature in θ with x = a·sin θ, which removes
the square-root behaviour at x = ±a.

Sources: Johnson, *Contact Mechanics*, §3.8 (flat punch) and §4.2 (Hertz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


def effective_modulus(young: float, poisson: float) -> float:
    """Plane-strain modulus E* = E / (1 − ν²) [Pa] of an elastic half-space on a rigid body."""
    if not (math.isfinite(young) and young > 0):
        raise ValueError(f"young must be finite and > 0 Pa, got {young!r}")
    if not (-1.0 < poisson <= 0.5):
        raise ValueError(f"poisson must be in (-1, 0.5], got {poisson!r}")
    return young / (1.0 - poisson**2)


def _check_common(force: float, center_xy: ArrayLike) -> NDArray[np.float64]:
    if not (math.isfinite(force) and force >= 0):
        raise ValueError(f"force must be finite and >= 0 N, got {force!r}")
    c = np.asarray(center_xy, dtype=np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center_xy must be a finite (x, y) pair [m], got {center_xy!r}")
    return c


class Indenter:
    """Base class: an axisymmetric pressure distribution of contact radius ``a`` [m].

    Subclasses define :meth:`contact_radius`, :meth:`pressure_at_radius` and the closed-form
    inner integral :meth:`_strip` = ∫_{-∞}^{y} p(√(x² + y'²)) dy' / scale at half-chord s.
    """

    name = "indenter"

    def contact_radius(self, force: float, young: float, poisson: float) -> float:
        raise NotImplementedError

    def peak_scale(self, force: float, a: float) -> float:
        raise NotImplementedError

    def pressure_at_radius(
        self, r: ArrayLike, force: float, young: float, poisson: float
    ) -> NDArray[np.float64]:
        raise NotImplementedError

    @staticmethod
    def _strip(y: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
        raise NotImplementedError

    def _cumulative(
        self, xs: NDArray[np.float64], ys: NDArray[np.float64], a: float
    ) -> NDArray[np.float64]:
        """Φ at the corners (len(ys), len(xs)) in units of ``scale``·m² (before scaling)."""
        th = np.arcsin(np.clip(xs / a, -1.0, 1.0))
        lo = np.concatenate(([-math.pi / 2], th[:-1]))
        # Segment j spans θ from the previous corner to this one; cumulative sum gives Φ.
        half = 0.5 * (th - lo)
        t = 0.5 * (th + lo)[:, None] + half[:, None] * _GL_X[None, :]  # (nx, q)
        x = a * np.sin(t)
        s = np.sqrt(np.maximum(a * a - x * x, 0.0))
        w = (half[:, None] * _GL_W[None, :]) * a * np.cos(t)  # dx = a cos θ dθ
        vals = self._strip(ys[:, None, None], s[None, :, :])  # (ny, nx, q)
        seg = np.einsum("ijq,jq->ij", vals, w)
        return np.cumsum(seg, axis=1)

    def pressure_on_cells(
        self,
        centers: ArrayLike,
        half_sizes: ArrayLike,
        force: float,
        center_xy: ArrayLike,
        young: float,
        poisson: float,
    ) -> NDArray[np.float64]:
        """Cell-averaged pressure [Pa] on rectangular cells.

        Args:
            centers: (N, 2) cell centres [m].
            half_sizes: (N, 2) or (2,) cell half-widths (a, b) [m].
            force: total normal force [N] (≥ 0).
            center_xy: indenter axis (x, y) [m].
            young, poisson: elastic constants of the skin [Pa], [-].

        Returns:
            (N,) mean pressure over each cell [Pa]; Σ p·area equals the force when the cells
            tile a region covering the contact.
        """
        c = _check_common(force, center_xy)
        ctr = np.asarray(centers, dtype=np.float64)
        if ctr.ndim != 2 or ctr.shape[1] != 2 or not np.all(np.isfinite(ctr)):
            raise ValueError(f"centers must be a finite (N, 2) array [m], got shape {ctr.shape}")
        hs = np.broadcast_to(np.asarray(half_sizes, dtype=np.float64), ctr.shape)
        if not np.all(hs > 0) or not np.all(np.isfinite(hs)):
            raise ValueError("half_sizes must be finite and > 0 m")
        if force == 0 or len(ctr) == 0:
            return np.zeros(len(ctr))
        a = self.contact_radius(force, young, poisson)
        scale = self.peak_scale(force, a)
        x0 = ctr[:, 0] - c[0]
        y0 = ctr[:, 1] - c[1]
        # Evaluate Φ on the union of all corner coordinates so shared corners agree exactly.
        xs, xi = np.unique(np.concatenate((x0 - hs[:, 0], x0 + hs[:, 0])), return_inverse=True)
        ys, yi = np.unique(np.concatenate((y0 - hs[:, 1], y0 + hs[:, 1])), return_inverse=True)
        phi = self._cumulative(xs, ys, a)
        n = len(ctr)
        x1, x2, y1, y2 = xi[:n], xi[n:], yi[:n], yi[n:]
        cell_force = phi[y2, x2] - phi[y2, x1] - phi[y1, x2] + phi[y1, x1]
        # Cells off the contact come out as ±1e-20-level rounding; pressure is never negative.
        cell_force = np.maximum(cell_force, 0.0)
        return scale * cell_force / (4.0 * hs[:, 0] * hs[:, 1])


@dataclass(frozen=True)
class HertzSphere(Indenter):
    """Rigid sphere of radius ``radius`` [m]: p(r) = p0·√(1 − r²/a²), a = (3FR/(4E*))^(1/3),
    p0 = 3F/(2πa²). The skin is treated as a half-space (the sphere itself rigid)."""

    radius: float
    name = "hertz"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"sphere radius must be finite and > 0 m, got {self.radius!r}")

    @classmethod
    def with_contact_radius(
        cls, a: float, force: float, young: float, poisson: float
    ) -> HertzSphere:
        """The sphere whose Hertz contact radius is ``a`` [m] at ``force`` [N]."""
        return cls(4.0 * effective_modulus(young, poisson) * a**3 / (3.0 * force))

    def contact_radius(self, force: float, young: float, poisson: float) -> float:
        """Hertz contact radius a [m]."""
        return (3.0 * force * self.radius / (4.0 * effective_modulus(young, poisson))) ** (1 / 3)

    def peak_scale(self, force: float, a: float) -> float:
        return 3.0 * force / (2.0 * math.pi * a**3)  # p0 / a

    def pressure_at_radius(
        self, r: ArrayLike, force: float, young: float, poisson: float
    ) -> NDArray[np.float64]:
        """Pressure p(r) [Pa] at distance r [m] from the axis."""
        a = self.contact_radius(force, young, poisson)
        rr = np.asarray(r, dtype=np.float64)
        return 3.0 * force / (2.0 * math.pi * a * a) * np.sqrt(np.clip(1 - (rr / a) ** 2, 0, None))

    def surface_deflection(
        self, r: ArrayLike, force: float, young: float, poisson: float
    ) -> NDArray[np.float64]:
        """Surface displacement u_z(r, z=0) [m] inside the contact: π p0 (2a² − r²)/(4aE*)."""
        a = self.contact_radius(force, young, poisson)
        p0 = 3.0 * force / (2.0 * math.pi * a * a)
        rr = np.asarray(r, dtype=np.float64)
        return math.pi * p0 * (2 * a * a - rr**2) / (4 * a * effective_modulus(young, poisson))

    @staticmethod
    def _strip(y: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
        # ∫_{-s}^{min(y,s)} √(s² − t²) dt = ½[t√(s²−t²) + s² asin(t/s)] from −s.
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(s > 0, np.clip(y / np.where(s > 0, s, 1), -1.0, 1.0), 0.0)
        return 0.5 * s * s * (u * np.sqrt(1 - u * u) + np.arcsin(u) + math.pi / 2)


@dataclass(frozen=True)
class FlatPunch(Indenter):
    """Rigid flat cylinder of radius ``radius`` [m]: p(r) = F / (2πa√(a² − r²)), a = radius."""

    radius: float
    name = "punch"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"punch radius must be finite and > 0 m, got {self.radius!r}")

    def contact_radius(self, force: float, young: float, poisson: float) -> float:
        return self.radius

    def peak_scale(self, force: float, a: float) -> float:
        return force / (2.0 * math.pi * a)

    def pressure_at_radius(
        self, r: ArrayLike, force: float, young: float, poisson: float
    ) -> NDArray[np.float64]:
        """Pressure p(r) [Pa]; infinite at r = a, zero outside."""
        a = self.radius
        rr = np.asarray(r, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            p = force / (2 * math.pi * a * np.sqrt(a * a - rr**2))
        return np.where(rr < a, p, np.where(rr == a, np.inf, 0.0))

    @staticmethod
    def _strip(y: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
        # ∫_{-s}^{min(y,s)} dt / √(s² − t²) = asin(t/s) + π/2.
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(s > 0, np.clip(y / np.where(s > 0, s, 1), -1.0, 1.0), 0.0)
        return np.where(s > 0, np.arcsin(u) + math.pi / 2, 0.0)
