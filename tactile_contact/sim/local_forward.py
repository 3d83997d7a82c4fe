"""A real-time forward model for large patches: the fixed fine grid, each taxel's kernel cut
at a reach.

:class:`tactile_contact.model.forward.PatchForwardModel` precomputes the Love kernel from every
fine cell of the patch to every taxel: on a 24-module forearm (288 channels, a 0.5 mm grid of
≈ 95 000 cells) that is 27 million entries, about 220 MB and minutes of kernel evaluations
before the first frame. A taxel does not feel a load far away: the effective point-load kernel
u(0) − u(h) falls as ν·h²/r³, so beyond ``reach`` (default 20 mm = 10 h) a 1 N contact moves a
taxel by less than 0.3 µm, 0.03 of one 8-bit count. :class:`LocalForwardModel` keeps, per
taxel, the cells within ``reach`` only (a sparse kernel, ≈ 5 000 cells a taxel), and is
otherwise the same model: electrode-averaged Love kernel on a fixed grid, the indenter's exact
cell averages on the cells it touches. Contacts farther than ``reach`` from a taxel read 0
there, which is the one approximation (measured against the dense model in the tests).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.spatial import cKDTree

from tactile_contact.model.grids import Grid, disc_quadrature
from tactile_contact.model.indenters import Indenter

#: Distance [m] beyond which a cell's load is not felt by a taxel (about 10 layer thicknesses).
DEFAULT_REACH = 20.0e-3


class LocalForwardModel:
    """Fixed-grid forward model with each taxel's kernel limited to ``reach`` (see above).

    Args:
        points_xy: (K, 2) taxel centres [m].
        thickness, young, poisson: layer h [m], E [Pa], ν.
        fine_cell: edge of the fixed pressure cells [m].
        taxel_radius: electrode radius [m]; > 0 averages over the disc (3 × 8 points).
        margin: how far the grid extends beyond the taxels [m].
        reach: kernel cut-off distance [m] from each taxel centre.
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
        reach: float = DEFAULT_REACH,
    ) -> None:
        from tactile_contact.model.elastic import love_matrix

        p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        if not (math.isfinite(reach) and reach > 0):
            raise ValueError(f"reach must be a positive length [m], got {reach!r}")
        self.points_xy = p
        self.grid = Grid.covering(p, fine_cell, margin)
        self.young, self.poisson = float(young), float(poisson)
        centres = self.grid.all_centers().reshape(-1, 2)
        tree = cKDTree(centres)
        near = tree.query_ball_point(p, reach + fine_cell)
        # The columns: every cell within reach of some taxel (the rest is never loaded).
        used = np.unique(np.concatenate([np.asarray(n, dtype=np.int64) for n in near]))
        self._column = np.full(len(centres), -1, dtype=np.int64)
        self._column[used] = np.arange(len(used))
        self._centres = centres[used]
        half = np.full(2, 0.5 * fine_cell)
        q, w = disc_quadrature(taxel_radius, n_r=3, n_theta=8)
        rows, cols, vals = [], [], []
        for i, cells in enumerate(near):
            cells = np.asarray(cells, dtype=np.int64)
            k = w @ love_matrix(p[i] + q, centres[cells], half, thickness, young, poisson)
            rows.append(np.full(len(cells), i))
            cols.append(self._column[cells])
            vals.append(k)
        self.kernel = sparse.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(len(p), len(used)),
        )

    def compression(
        self, indenter: Indenter, force: float, center_xy: ArrayLike
    ) -> NDArray[np.float64]:
        """(K,) effective deflection u_z(0) − u_z(h) [m] at the taxels."""
        c = np.asarray(center_xy, dtype=np.float64)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"center_xy must be a finite (x, y) pair [m], got {center_xy!r}")
        if not (math.isfinite(force) and force >= 0):
            raise ValueError(f"force must be finite and >= 0 N, got {force!r}")
        if force == 0:
            return np.zeros(self.kernel.shape[0])
        g = self.grid
        a = indenter.contact_radius(force, self.young, self.poisson) + g.cell_size
        # The grid cells of the square around the contact, by index (no search over the grid).
        lo = np.floor((c - a - np.asarray(g.origin)) / g.cell_size).astype(int)
        hi = np.ceil((c + a - np.asarray(g.origin)) / g.cell_size).astype(int)
        ny, nx = g.shape
        ix = np.arange(max(lo[0], 0), min(hi[0], nx))
        iy = np.arange(max(lo[1], 0), min(hi[1], ny))
        flat = (iy[:, None] * nx + ix[None, :]).ravel()
        cols = self._column[flat]
        cols = cols[cols >= 0]
        if len(cols) == 0:
            return np.zeros(self.kernel.shape[0])
        p = indenter.pressure_on_cells(
            self._centres[cols],
            np.full(2, 0.5 * g.cell_size),
            force,
            c,
            self.young,
            self.poisson,
        )
        return np.asarray(self.kernel[:, cols] @ p).ravel()
