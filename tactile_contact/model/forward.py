"""Fine forward simulation of an indentation: the ground truth for tests, simulator and benchmark.

The indenter's exact cell-averaged pressure (:mod:`tactile_contact.model.indenters`) is laid on a
fine
grid (default 0.2 mm cells, at most a/8, over the contact disc only) and pushed through the Love
kernel to the taxels. It shares only the elastic kernel with the reconstruction; its grid, its
cell placement and its taxel model (optionally the mean over the electrode disc, and the exact
nonlinear capacitance of a deformed plate) are independent of any reconstruction grid.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.model.grids import disc_quadrature
from tactile_contact.model.indenters import Indenter

EPSILON_0 = 8.8541878128e-12  # vacuum permittivity [F/m]


def _load_center(force: float, center_xy: ArrayLike) -> NDArray[np.float64]:
    """The indenter axis as a (2,) array, after checking force [N] and centre [m]."""
    c = np.asarray(center_xy, dtype=np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center_xy must be a finite (x, y) pair [m], got {center_xy!r}")
    if not (math.isfinite(force) and force >= 0):
        raise ValueError(f"force must be finite and >= 0 N, got {force!r}")
    return c


@dataclass(frozen=True)
class ForwardFields:
    """One simulated indentation.

    Attributes:
        centers: (M, 2) fine cell centres [m] (cells intersecting the contact disc).
        half_sizes: (M, 2) fine cell half-widths [m].
        pressure: (M,) true cell-averaged pressure [Pa]; Σ pressure·area = force.
        compression: (K,) effective deflection u_z(0) − u_z(h) at the taxels [m] (mean over
            the taxel disc when the model has a taxel radius).
        contact_radius: radius of the contact [m].
        force: applied normal force [N].
        center_xy: indenter axis [m].
    """

    centers: NDArray[np.float64]
    half_sizes: NDArray[np.float64]
    pressure: NDArray[np.float64]
    compression: NDArray[np.float64]
    contact_radius: float
    force: float
    center_xy: tuple[float, float]

    @property
    def contact_area(self) -> float:
        """True contact area π a² [m²]."""
        return math.pi * self.contact_radius**2


class ForwardModel:
    """Finely discretised forward simulation on the Love model.

    Args:
        points_xy: (K, 2) taxel centres [m].
        thickness: layer thickness h [m].
        young: Young's modulus E [Pa].
        poisson: Poisson's ratio ν.
        fine_cell: edge of the fine pressure cells [m] (also capped at a/8 of each contact).
        taxel_radius: electrode radius [m]; > 0 averages the deflection over the disc.
    """

    def __init__(
        self,
        points_xy: ArrayLike,
        thickness: float,
        young: float,
        poisson: float,
        fine_cell: float = 2.0e-4,
        taxel_radius: float = 0.0,
    ) -> None:
        p = np.asarray(points_xy, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0 or not np.all(np.isfinite(p)):
            raise ValueError(f"points_xy must be a finite (K, 2) array [m], got shape {p.shape}")
        for name, v in (("thickness", thickness), ("young", young), ("fine_cell", fine_cell)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if not (-1.0 < poisson <= 0.5):
            raise ValueError(f"poisson must be in (-1, 0.5], got {poisson!r}")
        if not (math.isfinite(taxel_radius) and taxel_radius >= 0):
            raise ValueError(f"taxel_radius must be finite and >= 0 m, got {taxel_radius!r}")
        self.points_xy = p
        self.thickness = float(thickness)
        self.young = float(young)
        self.poisson = float(poisson)
        self.fine_cell = float(fine_cell)
        self.taxel_radius = float(taxel_radius)
        # The bundles' 8 × 24 points (tactile_contact.offline.build.TAXEL_QUADRATURE). Where the 2
        # mm
        # electrode straddles a small contact's edge the integrand has a kink: for a 1.5 mm
        # punch at the taxel, 4 × 12 points were 6 % low (286 µm/N against 304 µm/N with
        # 16 × 48), 8 × 24 are 2 % low; for contacts larger than the electrode all agree to
        # 0.1 %.
        q, self._qw = disc_quadrature(taxel_radius, n_r=8, n_theta=24)
        self._qpts = (p[:, None, :] + q[None, :, :]).reshape(-1, 2)

    def _cells(self, a: float, center: NDArray[np.float64]) -> tuple[NDArray, float]:
        cell = min(self.fine_cell, a / 8.0)
        n = 2 * math.ceil(a / cell)
        c1 = (np.arange(n) - n / 2 + 0.5) * cell
        xx, yy = np.meshgrid(c1, c1)
        # Keep cells that reach into the disc: nearest point of the cell within a.
        dx = np.maximum(np.abs(xx) - cell / 2, 0)
        dy = np.maximum(np.abs(yy) - cell / 2, 0)
        keep = dx**2 + dy**2 < a * a
        return np.stack((xx[keep], yy[keep]), axis=-1) + center, cell

    def _point_compression(self, centers, half_sizes, pressure) -> NDArray[np.float64]:
        from tactile_contact.model.elastic import love_matrix

        out = np.zeros(len(self._qpts))
        # Chunks bound the memory of the (points × cells) kernel block.
        step = max(1, 2_000_000 // max(len(centers), 1))
        for s in range(0, len(self._qpts), step):
            g = love_matrix(
                self._qpts[s : s + step],
                centers,
                half_sizes,
                self.thickness,
                self.young,
                self.poisson,
            )
            out[s : s + step] = g @ pressure
        return out.reshape(len(self.points_xy), -1)

    def fields(self, indenter: Indenter, force: float, center_xy: ArrayLike) -> ForwardFields:
        """Simulate ``indenter`` pressed with ``force`` [N] at ``center_xy`` [m]."""
        c = _load_center(force, center_xy)
        k = len(self.points_xy)
        if force == 0:
            z = np.zeros((0, 2))
            return ForwardFields(z, z, np.zeros(0), np.zeros(k), 0.0, 0.0, (c[0], c[1]))
        a = indenter.contact_radius(force, self.young, self.poisson)
        centers, cell = self._cells(a, c)
        hs = np.full_like(centers, cell / 2)
        p = indenter.pressure_on_cells(centers, hs, force, c, self.young, self.poisson)
        dq = self._point_compression(centers, hs, p)
        self._last_quadrature = dq
        return ForwardFields(centers, hs, p, dq @ self._qw, a, float(force), (c[0], c[1]))

    def compression(
        self, indenter: Indenter, force: float, center_xy: ArrayLike
    ) -> NDArray[np.float64]:
        """(K,) effective deflection u_z(0) − u_z(h) [m] at the taxels."""
        return self.fields(indenter, force, center_xy).compression

    def delta_c(
        self, indenter: Indenter, force: float, center_xy: ArrayLike, epsilon_r: float
    ) -> NDArray[np.float64]:
        """(K,) exact capacitance change [F] of each taxel's deformed parallel plate:
        ΔC = ε0·εr·∫(1/(h − δ) − 1/h) dA over the electrode disc (needs ``taxel_radius`` > 0)."""
        if self.taxel_radius <= 0:
            raise ValueError("delta_c needs a ForwardModel with taxel_radius > 0")
        if not (math.isfinite(epsilon_r) and epsilon_r >= 1):
            raise ValueError(f"epsilon_r must be finite and >= 1, got {epsilon_r!r}")
        self.fields(indenter, force, center_xy)
        dq = self._last_quadrature
        h = self.thickness
        if np.any(dq >= h):
            raise ValueError("compression reaches the layer thickness: force too large")
        area = math.pi * self.taxel_radius**2
        return EPSILON_0 * epsilon_r * area * ((1.0 / (h - dq) - 1.0 / h) @ self._qw)


class PatchForwardModel:
    """A forward model for real-time simulation: one fixed fine grid over the whole patch.

    The Love kernel from every fine cell to every (electrode-averaged) taxel is computed once;
    a frame then costs the indenter's exact cell averages on the cells it touches and one small
    product, instead of a new kernel per contact position (:class:`ForwardModel`, the accuracy
    reference, builds a contact-centred grid each time). Cells do not follow the contact, so
    small contacts are resolved by ``fine_cell`` only; the total force is still exact.

    Args:
        points_xy: (K, 2) taxel centres [m].
        thickness, young, poisson: layer h [m], E [Pa], ν.
        fine_cell: edge of the fixed pressure cells [m].
        taxel_radius: electrode radius [m]; > 0 averages over the disc (as the bundles do).
        margin: how far the grid extends beyond the taxels [m].
    """

    def __init__(
        self,
        points_xy: ArrayLike,
        thickness: float,
        young: float,
        poisson: float,
        fine_cell: float = 5.0e-4,
        taxel_radius: float = 0.0,
        margin: float = 6.0e-3,
    ) -> None:
        from tactile_contact.model.grids import Grid

        self._ref = ForwardModel(points_xy, thickness, young, poisson, fine_cell, taxel_radius)
        p = self._ref.points_xy
        self.grid = Grid.covering(p, fine_cell, margin)
        self._centers = self.grid.centers()
        self._half = np.full(2, 0.5 * self.grid.cell_size)
        self.kernel = _patch_kernel(
            p.tobytes(),
            len(p),
            thickness,
            young,
            poisson,
            self.grid.cell_size,
            margin,
            taxel_radius,
        )
        self.young, self.poisson = float(young), float(poisson)

    def compression(
        self, indenter: Indenter, force: float, center_xy: ArrayLike
    ) -> NDArray[np.float64]:
        """(K,) effective deflection u_z(0) − u_z(h) [m] at the taxels."""
        c = _load_center(force, center_xy)
        if force == 0:
            return np.zeros(self.kernel.shape[0])
        a = indenter.contact_radius(force, self.young, self.poisson)
        near = np.abs(self._centers - c).max(axis=1) <= a + self.grid.cell_size
        p = indenter.pressure_on_cells(
            self._centers[near], self._half, force, c, self.young, self.poisson
        )
        return self.kernel[:, near] @ p


@functools.lru_cache(maxsize=4)
def _patch_kernel(
    points: bytes,
    count: int,
    thickness: float,
    young: float,
    poisson: float,
    cell: float,
    margin: float,
    taxel_radius: float,
) -> NDArray[np.float64]:
    """(K, M) kernel of :class:`PatchForwardModel`, cached: simulators of one patch started in
    one process (tests, bringup) share it instead of recomputing seconds of Love kernels."""
    from tactile_contact.model.elastic import love_matrix
    from tactile_contact.model.grids import Grid

    p = np.frombuffer(points, dtype=np.float64).reshape(count, 2)
    centers = Grid.covering(p, cell, margin).centers()
    half = np.full(2, 0.5 * cell)
    q, w = disc_quadrature(taxel_radius, n_r=3, n_theta=8)
    kernel = np.empty((count, len(centers)))
    for i in range(count):  # one taxel at a time bounds the memory
        rows = p[i] + q
        kernel[i] = w @ love_matrix(rows, centers, half, thickness, young, poisson)
    kernel.setflags(write=False)
    return kernel
