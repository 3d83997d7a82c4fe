"""The reference elastic layer (h = 2 mm, E = 2.1e5 Pa, ν = 0.5: the default patch's) and the
problems posed on it without a bundle: square grids of cells, and the NNLS benches' 600-cell
grid under the default patch's taxels with a 12 mm sphere sliding over it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from benchkit.protocol import Patch
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import HertzSphere

#: Layer thickness [m], Young's modulus [Pa], Poisson's ratio.
H, E, NU = 2e-3, 2.1e5, 0.5


def square_grid(n: int, pitch: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centres (n², 2) [m] of an n × n grid of ``pitch`` [m] cells and the cell half sizes."""
    c = (np.arange(n) - (n - 1) / 2) * pitch
    xx, yy = np.meshgrid(c, c)
    return np.column_stack([xx.ravel(), yy.ravel()]), np.full(2, pitch / 2)


def kappa_estimate(h: float, d: float, length: float) -> float:
    """DESIGN.md §2: κ ≈ max(0.94·h/d, 0.19·L/h) of a square problem (pitch d, side L)."""
    return max(0.94 * h / d, 0.19 * length / h)


#: The NNLS benches' grid: 24 × 25 cells of 2.5 mm (N = 600) over the default patch.
SHAPE, PITCH = (24, 25), 2.5e-3
#: Frames of the sliding sphere; Gaussian noise of its compressions [m].
FRAMES, NOISE = 20, 1e-6


def hexagon_taxels() -> NDArray[np.float64]:
    """(72, 2) taxel centres [m] of the default patch (six roboskin12 modules)."""
    return Patch().xy


def cell_grid(taxels: NDArray) -> NDArray[np.float64]:
    """(N, 2) cell centres [m], row-major, the grid centred on the taxels' bounding box."""
    mid = 0.5 * (taxels.min(0) + taxels.max(0))
    ys = mid[1] + (np.arange(SHAPE[0]) - (SHAPE[0] - 1) / 2) * PITCH
    xs = mid[0] + (np.arange(SHAPE[1]) - (SHAPE[1] - 1) / 2) * PITCH
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def sliding_sphere(points: NDArray, taxels: NDArray, seed: int) -> list[NDArray[np.float64]]:
    """Compressions [m] at ``points`` of a 12 mm sphere pressing 1 N, sliding along the
    patch's diagonal in FRAMES frames (fine forward model, point values) + NOISE (seeded)."""
    model = ForwardModel(points, H, E, NU)
    lo, hi = taxels.min(0) + 6e-3, taxels.max(0) - 6e-3
    rng = np.random.default_rng(seed)
    return [
        model.compression(HertzSphere(radius=6e-3), 1.0, c) + NOISE * rng.normal(size=len(points))
        for c in np.linspace(lo, hi, FRAMES)
    ]
