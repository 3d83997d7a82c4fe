"""Rectangular cell grids over a patch, masks to the skin area, resampling and taxel discs.

Convention (used by bundles, the reconstruction and the ROS images): a grid has ``origin``
(x0, y0) [m] = the *lower-left corner* of cell (0, 0), square cells of edge ``cell_size`` = s
[m] and ``shape`` = (rows, cols) = (ny, nx). Row i, column j is the cell whose centre is
(x0 + (j + ½)·s, y0 + (i + ½)·s): **rows run along +y, columns along +x**, row 0 at the
smallest y. A 2-D field array ``f`` on the grid is indexed ``f[i, j]``. ``mask`` (ny, nx) marks
the cells that are skin; flat vectors of unknowns list the masked cells in row-major order.
(An image viewer shows row 0 at the top, i.e. the patch mirrored in y; the ROS node states it.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import ConvexHull


def _points(points: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0 or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be a finite non-empty (K, 2) array [m], got shape {p.shape}")
    return p


@dataclass(frozen=True, eq=False)
class Grid:
    """A rectangular grid of square cells with a skin mask (see module docstring)."""

    origin: tuple[float, float]
    cell_size: float
    shape: tuple[int, int]
    mask: NDArray[np.bool_]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cell_size) and self.cell_size > 0):
            raise ValueError(f"cell must be finite and > 0 m, got {self.cell_size!r}")
        if len(self.shape) != 2 or min(self.shape) < 1:
            raise ValueError(f"shape must be (rows, cols) >= 1, got {self.shape!r}")
        if not all(math.isfinite(v) for v in self.origin):
            raise ValueError(f"origin must be finite, got {self.origin!r}")
        if self.mask.shape != tuple(self.shape) or self.mask.dtype != bool:
            raise ValueError(
                f"mask must be a bool array of shape {self.shape}, got "
                f"{self.mask.dtype} {self.mask.shape}"
            )

    @classmethod
    def covering(cls, points: ArrayLike, cell: float, margin: float) -> Grid:
        """Smallest grid of ``cell`` [m] cells covering ``points`` plus ``margin`` [m], centred on
        their bounding box; every cell unmasked (skin)."""
        p = _points(points, "points")
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be finite and >= 0 m, got {margin!r}")
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"cell must be finite and > 0 m, got {cell!r}")
        lo, hi = p.min(0) - margin, p.max(0) + margin
        n = np.maximum(np.ceil((hi - lo) / cell - 1e-9).astype(int), 1)
        origin = 0.5 * (lo + hi) - 0.5 * n * cell
        shape = (int(n[1]), int(n[0]))
        return cls((float(origin[0]), float(origin[1])), float(cell), shape, np.ones(shape, bool))

    def with_mask(self, mask: ArrayLike) -> Grid:
        return Grid(self.origin, self.cell_size, self.shape, np.asarray(mask, dtype=bool))

    @property
    def cell(self) -> tuple[float, float]:
        """Cell size (dx, dy) [m] (square cells: both equal ``cell_size``)."""
        return (self.cell_size, self.cell_size)

    @property
    def n_cells(self) -> int:
        """Number of masked (active) cells."""
        return int(self.mask.sum())

    @property
    def cell_area(self) -> float:
        """Area of one cell [m²]."""
        return self.cell_size * self.cell_size

    def all_centers(self) -> NDArray[np.float64]:
        """(ny, nx, 2) centres [m] of every cell."""
        ny, nx = self.shape
        x = self.origin[0] + (np.arange(nx) + 0.5) * self.cell_size
        y = self.origin[1] + (np.arange(ny) + 0.5) * self.cell_size
        xx, yy = np.meshgrid(x, y)
        return np.stack((xx, yy), axis=-1)

    def centers(self) -> NDArray[np.float64]:
        """(N, 2) centres [m] of the masked cells, row-major."""
        return self.all_centers()[self.mask]

    def half_sizes(self) -> NDArray[np.float64]:
        """(N, 2) cell half-widths [m] of the masked cells."""
        return np.full((self.n_cells, 2), 0.5 * self.cell_size)

    def to_image(self, values: ArrayLike, fill: float = 0.0) -> NDArray[np.float64]:
        """Scatter a (N,) vector over masked cells into a (ny, nx) array; ``fill`` elsewhere."""
        v = np.asarray(values)
        if v.shape != (self.n_cells,):
            raise ValueError(f"values must have shape ({self.n_cells},), got {v.shape}")
        img = np.full(self.shape, fill, dtype=np.result_type(v.dtype, np.float32))
        img[self.mask] = v
        return img

    def to_vector(self, image: ArrayLike) -> NDArray[np.float64]:
        """Inverse of :meth:`to_image`: the masked cells of a (ny, nx) array."""
        img = np.asarray(image)
        if img.shape != tuple(self.shape):
            raise ValueError(f"image must have shape {self.shape}, got {img.shape}")
        return img[self.mask]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready geometry (the mask is stored separately as an array)."""
        return {"origin": list(self.origin), "cell": self.cell_size, "shape": list(self.shape)}


def distance_to_points(query: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """(M,) distance [m] from each query point to the nearest of ``points``."""
    from scipy.spatial import cKDTree

    q = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    p = _points(points, "points")
    # (a k-d tree: the all-pairs distances of a robot patch's bounding-box grid against its
    # taxels took M × P × 8 bytes)
    return np.asarray(cKDTree(p).query(q)[0], dtype=np.float64)


def distance_to_hull(query: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """(M,) distance [m] from each query point to the convex hull of ``points`` (0 inside)."""
    q = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    p = _points(points, "points")
    hull = p[ConvexHull(p).vertices]  # counter-clockwise
    a, b = hull, np.roll(hull, -1, axis=0)
    e = b - a
    rel = q[:, None, :] - a[None, :, :]
    inside = np.all(e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0] >= 0, axis=1)
    t = np.clip((rel * e[None]).sum(-1) / (e * e).sum(-1)[None], 0.0, 1.0)
    d = np.linalg.norm(rel - t[..., None] * e[None], axis=-1).min(axis=1)
    return np.where(inside, 0.0, d)


def skin_grid(
    taxel_xy: ArrayLike,
    cell: float,
    margin: float,
    mask: str = "taxels",
    mask_distance: float = 3.5e-3,
    module_channels: list[NDArray[np.float64]] | None = None,
) -> Grid:
    """Grid over a patch with its skin mask.

    ``mask``: ``taxels`` keeps cells whose centre lies within ``mask_distance`` [m] of a taxel,
    ``modules`` cells within ``mask_distance`` of a module's channel hull (pass
    ``module_channels``, one (12, 2) array per module), ``none`` keeps every cell.
    """
    grid = Grid.covering(taxel_xy, cell, margin)
    c = grid.all_centers().reshape(-1, 2)
    if mask == "none":
        return grid
    if mask == "taxels":
        keep = distance_to_points(c, taxel_xy) <= mask_distance
    elif mask == "modules":
        if not module_channels:
            raise ValueError("mask 'modules' needs module_channels")
        dist = np.min([distance_to_hull(c, m) for m in module_channels], axis=0)
        keep = dist <= mask_distance
    else:
        raise ValueError(f"unknown mask {mask!r} (known: taxels, modules, none)")
    return grid.with_mask(keep.reshape(grid.shape))


def resample(field: ArrayLike, src: Grid, dst: Grid, fill: float = 0.0) -> NDArray[np.float64]:
    """Bilinear resampling of a (ny, nx) field on ``src`` onto the cell centres of ``dst``.

    Values between the outermost source centres and the source edge are extrapolated from the
    nearest cells (constant); points outside the source grid and cells masked out on ``dst``
    get ``fill``. Returns a (ny', nx') array.
    """
    f = np.asarray(field, dtype=np.float64)
    if f.shape != tuple(src.shape):
        raise ValueError(f"field must have shape {src.shape}, got {f.shape}")
    ny, nx = src.shape
    x = src.origin[0] + (np.arange(nx) + 0.5) * src.cell_size
    y = src.origin[1] + (np.arange(ny) + 0.5) * src.cell_size
    pts = dst.all_centers()
    px = np.clip(pts[..., 0], x[0], x[-1])
    py = np.clip(pts[..., 1], y[0], y[-1])
    if nx == 1 or ny == 1:  # degenerate axis: interpolate along the other one only
        out = np.interp(px if ny == 1 else py, x if ny == 1 else y, f.ravel())
    else:
        out = RegularGridInterpolator((y, x), f)(np.stack((py, px), axis=-1))
    inside = (
        (pts[..., 0] >= src.origin[0])
        & (pts[..., 0] <= src.origin[0] + nx * src.cell_size)
        & (pts[..., 1] >= src.origin[1])
        & (pts[..., 1] <= src.origin[1] + ny * src.cell_size)
    )
    return np.where(inside & dst.mask, out, fill)


def disc_quadrature(radius: float, n_r: int = 3, n_theta: int = 8) -> tuple[NDArray, NDArray]:
    """Points (M, 2) [m] and weights (M,) summing to 1 for the mean over a disc of ``radius``.

    Gauss–Legendre in r² (area-uniform) times the trapezoid rule in θ: exact for polynomials in
    x, y up to degree ``2·n_r − 1`` in r² and ``n_theta − 1`` in angle. ``radius`` 0 gives the
    centre with weight 1.
    """
    if not (math.isfinite(radius) and radius >= 0):
        raise ValueError(f"radius must be finite and >= 0 m, got {radius!r}")
    if radius == 0:
        return np.zeros((1, 2)), np.ones(1)
    t, w = np.polynomial.legendre.leggauss(n_r)
    t, w = 0.5 * (t + 1), 0.5 * w  # on [0, 1] in s = (r/R)²
    r = radius * np.sqrt(t)
    th = 2 * math.pi * (np.arange(n_theta) + 0.5) / n_theta
    rr, tt = np.meshgrid(r, th, indexing="ij")
    pts = np.stack((rr * np.cos(tt), rr * np.sin(tt)), axis=-1).reshape(-1, 2)
    wt = np.repeat(w / n_theta, n_theta)
    return pts, wt
