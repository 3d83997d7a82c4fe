"""Regularisers L for min ‖Ax − d‖² + λ²‖Lx‖²: smoothness and compact-support priors.

Pass the result as ``regulariser=`` to :class:`~tactile_contact.inverse.solvers.SvdInverse` or
:class:`~tactile_contact.inverse.solvers.NnlsSolver`. Both are dimensionless (λ carries the units).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

BOUNDARIES = ("dirichlet", "neumann")


def grid_laplacian(
    shape: tuple[int, int], mask: ArrayLike | None = None, boundary: str = "dirichlet"
) -> NDArray[np.float64]:
    """(N, N) five-point Laplacian over the cells of a (rows, cols) grid where ``mask`` is True.

    Cells are numbered row-major over the mask (the Grid convention). ``dirichlet`` treats
    every missing neighbour (off the grid or masked out) as a zero-pressure cell: L is then
    nonsingular and also pulls pressure to zero at the edge of the skin, a compact-support
    prior. ``neumann`` ignores missing neighbours (graph Laplacian): constants are in its null
    space, which at ν = 0.5 (A almost blind to a uniform load) leaves the mean pressure
    unregularised.
    """
    rows, cols = (int(v) for v in shape)
    if rows < 1 or cols < 1 or (rows, cols) != tuple(shape):
        raise ValueError(f"shape must be two positive integers, got {shape!r}")
    if boundary not in BOUNDARIES:
        raise ValueError(f"boundary must be one of {BOUNDARIES}, got {boundary!r}")
    m = np.ones((rows, cols), dtype=bool) if mask is None else np.asarray(mask)
    if m.shape != (rows, cols) or m.dtype != bool:
        raise ValueError(f"mask must be a bool array of shape {(rows, cols)}, got {m.shape}")
    idx = -np.ones((rows, cols), dtype=int)
    idx[m] = np.arange(int(m.sum()))
    n = int(m.sum())
    lap = np.zeros((n, n))
    if boundary == "dirichlet":
        lap[np.diag_indices(n)] = 4.0
    for di, dj in ((0, 1), (1, 0)):
        a, b = idx[: rows - di, : cols - dj], idx[di:, dj:]
        ok = (a >= 0) & (b >= 0)
        i, j = a[ok], b[ok]
        lap[i, j] = lap[j, i] = -1.0
        if boundary == "neumann":
            np.add.at(lap, (i, i), 1.0)
            np.add.at(lap, (j, j), 1.0)
    return lap


def support_weights(
    centers: ArrayLike, support: ArrayLike, radius: float, power: float = 2.0
) -> NDArray[np.float64]:
    """(N, N) diagonal L with w_i = 1 + (dist_i / radius)^power, dist_i the distance [m] of
    cell centre i to the nearest point of ``support`` (e.g. taxel centres or a first estimate
    of the contact): pressure far from the support costs more, a compact-support prior.

    A diagonal L keeps :class:`NnlsSolver` on its fast measurement-space route.
    """
    c = np.asarray(centers, dtype=np.float64)
    s = np.asarray(support, dtype=np.float64)
    for name, v in (("centers", c), ("support", s)):
        if v.ndim != 2 or v.shape[1] != 2 or len(v) == 0 or not np.all(np.isfinite(v)):
            raise ValueError(f"{name} must be a finite (n, 2) array [m], got shape {v.shape}")
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be finite and > 0 m, got {radius!r}")
    if not (np.isfinite(power) and power > 0):
        raise ValueError(f"power must be finite and > 0, got {power!r}")
    dist = np.sqrt(((c[:, None, :] - s[None, :, :]) ** 2).sum(-1)).min(1)
    return np.diag(1.0 + (dist / radius) ** power)
