"""Dense influence matrices between arbitrary point sets (measurement points × source cells).

Rows are measurement points (K), columns sources (N). The same matrix serves all four maps of
the paper: it maps forces/pressures to displacements, and its (pseudo-)inverse maps back.
Matrices are float64 and built in row chunks so that temporaries stay near `chunk_elements`.

Love columns share cell corners: on a grid of touching cells each corner belongs to up to four
cells, so the corner antiderivative is evaluated once per (point, distinct corner) and the
matrix is gathered from it; that keeps the Love build close to the cost of Boussinesq–Cerruti.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from tactile_contact.model.elastic.boussinesq import (
    Array,
    _block_effective,
    _effective_zz,
    finite_array,
    material,
    min_magnitude,
    muscari_self,
    positive_array,
)
from tactile_contact.model.elastic.love import (
    _corner_uz_effective,
    edge_atan,
    edge_g,
    effective_far_plan,
    effective_far_radius,
    gauss_effective,
    love_effective,
    love_uz,
)

#: Default bound on the number of matrix entries processed per chunk (memory ~ 10× × 8 bytes).
CHUNK_ELEMENTS = 100_000


def _points(name: str, value: ArrayLike) -> Array:
    arr = finite_array(name, value)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) [m], got shape {arr.shape}")
    return arr


def _per_source(name: str, value: ArrayLike, n: int, width: int | None) -> Array:
    arr = positive_array(name, value)
    shape = (n,) if width is None else (n, width)
    try:
        return np.broadcast_to(arr, shape)
    except ValueError:
        raise ValueError(f"{name} must broadcast to {shape}, got shape {arr.shape}") from None


def _chunks(k: int, width: int, chunk_elements: int):
    step = max(1, int(chunk_elements) // max(width, 1))
    for start in range(0, k, step):
        yield slice(start, min(k, start + step))


def _merge_close(values: Array, limit: float) -> tuple[Array, Array]:
    """Distinct values and inverse indices, merging values within a few ulps (grid corners
    computed as c + a and c' − a differ by rounding only), never by more than `limit` [m]."""
    uniq, inverse = np.unique(values, return_inverse=True)
    if uniq.size > 1:
        tol = min(8.0 * np.finfo(float).eps * np.abs(uniq).max(), limit)
        new_group = np.concatenate(([True], np.diff(uniq) > tol))
        group = np.cumsum(new_group) - 1
        uniq, inverse = uniq[new_group], group[inverse]
    return uniq, inverse.reshape(values.shape)


def love_matrix(
    points: ArrayLike,
    centers: ArrayLike,
    half_sizes: ArrayLike,
    thickness: float,
    young: float,
    poisson: float,
    *,
    component: str = "z",
    chunk_elements: int = CHUNK_ELEMENTS,
) -> Array:
    """K × N effective displacement u(0) − u(h) per unit pressure [m/Pa] (Love cells).

    points (K, 2) [m] measurement points; centers (N, 2) [m] cell centres; half_sizes (N, 2)
    or (2,) [m] half-widths (a, b); thickness h [m]; young E [Pa]; poisson ν ∈ (−1, 0.5].
    component "z" (default: the compression a taxel measures) or "x"/"y" (lateral).
    """
    p, c = _points("points", points), _points("centers", centers)
    n = c.shape[0]
    hs = _per_source("half_sizes", half_sizes, n, 2)
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    if component not in ("x", "y", "z"):
        raise ValueError(f"component must be 'x', 'y' or 'z', got {component!r}")
    out = np.empty((p.shape[0], n))
    if out.size == 0:
        return out
    if component != "z":
        for rows in _chunks(p.shape[0], n, chunk_elements):
            dx = p[rows, 0:1] - c[None, :, 0]
            dy = p[rows, 1:2] - c[None, :, 1]
            out[rows] = love_effective(dx, dy, hs[:, 0], hs[:, 1], h, e, nu, component)
        return out
    a, b = hs[:, 0], hs[:, 1]
    limit = 1e-9 * min(a.min(), b.min())  # merging moves a corner by ≤ 1e-9 of a cell
    ux, ix = _merge_close(np.stack([c[:, 0] + a, c[:, 0] - a]), limit)  # (2, N): +, − corner
    uy, iy = _merge_close(np.stack([c[:, 1] + b, c[:, 1] - b]), limit)
    keys = ix[:, None, :] * uy.size + iy[None, :, :]  # (2, 2, N) corners (sx, sy, cell)
    ukeys, corner = np.unique(keys, return_inverse=True)
    corner = corner.reshape(keys.shape)
    cx, cy = ux[ukeys // uy.size], uy[ukeys % uy.size]
    scale = (1.0 + nu) / (2.0 * np.pi * e)
    # a slightly smaller radius than the plan's, so that rounding never misses a far pair
    far_r2 = (effective_far_radius(a, b, h, nu) * (1.0 - 1e-9)) ** 2
    both = np.concatenate([p, c])
    may_be_far = np.sum(np.ptp(both, axis=0) ** 2) >= far_r2.min()  # else skip the far test
    # In-range tests widened by many roundings of the coordinates: a pair the mask lets through
    # but that lies outside both ranges simply gets a zero correction.
    slack = 64.0 * np.finfo(float).eps * max(np.abs(p).max(), np.abs(c).max(), 1e-300)
    edge_a, edge_b = a * (1.0 + 1e-12) + slack, b * (1.0 + 1e-12) + slack
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for rows in _chunks(p.shape[0], max(n, ukeys.size), chunk_elements):
            px, py = p[rows, 0:1], p[rows, 1:2]
            ec = _corner_uz_effective(cx[None, :] - px, cy[None, :] - py, h, nu)
            blk = np.take(ec, corner[0, 0], axis=1)
            blk -= np.take(ec, corner[1, 0], axis=1)
            blk -= np.take(ec, corner[0, 1], axis=1)
            blk += np.take(ec, corner[1, 1], axis=1)
            dx, dy = px - c[None, :, 0], py - c[None, :, 1]
            # Edge terms exist only where the point lies in a cell's x- or y-range.
            kk, nn = np.nonzero((np.abs(dx) <= edge_a) | (np.abs(dy) <= edge_b))
            if kk.size:
                # the same corner offsets as in ec, so that the signs match bit for bit; the
                # smooth edge function is evaluated once per (point, distinct edge coordinate)
                xk, yk = px[kk, 0], py[kk, 0]
                ixp, ixm, iyp, iym = ix[0, nn], ix[1, nn], iy[0, nn], iy[1, nn]
                xp, xm, yp, ym = ux[ixp] - xk, ux[ixm] - xk, uy[iyp] - yk, uy[iym] - yk
                cxs = np.sign(xp) - np.sign(xm)
                cys = np.sign(yp) - np.sign(ym)
                gx = edge_g(ux[None, :] - px, h)
                gy = edge_g(uy[None, :] - py, h)
                corr = cxs * (gy[kk, iyp] - gy[kk, iym]) + cys * (gx[kk, ixp] - gx[kk, ixm])
                corr *= 2.0 * (1.0 - nu)
                if nu != 0.5:
                    k = (1.0 - 2.0 * nu) * h
                    corr += k * (
                        cxs * edge_atan(yp, ym, h)
                        + cys * edge_atan(xp, xm, h)
                        - cxs * cys * 0.5 * np.pi
                    )
                blk[kk, nn] += corr
            if may_be_far:
                r2 = dx * dx
                r2 += dy * dy
                kk, nn = np.nonzero(r2 >= far_r2)
                if kk.size:
                    r = np.sqrt(r2[kk, nn])
                    far, order = effective_far_plan(r, a[nn], b[nn], h, nu)
                    kk, nn = kk[far], nn[far]
                    blk[kk, nn] = gauss_effective(
                        dx[kk, nn], dy[kk, nn], a[nn], b[nn], h, nu, order[far]
                    )
            out[rows] = scale * blk
    return out


def love_depth_matrix(
    points: ArrayLike, centers: ArrayLike, half_sizes: ArrayLike, depth: float, young, poisson
) -> Array:
    """K × N vertical displacement u_z at one depth z ≥ 0 per unit pressure [m/Pa] (Love)."""
    p, c = _points("points", points), _points("centers", centers)
    hs = _per_source("half_sizes", half_sizes, c.shape[0], 2)
    dx = p[:, 0:1] - c[None, :, 0]
    dy = p[:, 1:2] - c[None, :, 1]
    return love_uz(dx, dy, depth, hs[:, 0], hs[:, 1], young, poisson)


def _self_terms(areas, n, h, e, psi) -> Array:
    return muscari_self(_per_source("areas", areas, n, None), h, e, psi)


def boussinesq_matrix(
    points: ArrayLike,
    sources: ArrayLike,
    areas: ArrayLike,
    thickness: float,
    young: float,
    poisson: float = 0.5,
    psi: str | float = "exact",
    *,
    chunk_elements: int = CHUNK_ELEMENTS,
) -> Array:
    """K × N effective displacement u_z(0) − u_z(h) per unit normal force [m/N] (B-C).

    points (K, 2) [m]; sources (N, 2) [m] force locations; areas (N,) or scalar [m²] of the
    cells the forces stand for (Muscari z0 = √(3A/(2π))); thickness h [m]; young E [Pa].
    Every entry follows the paper's rule: the smaller-magnitude of the exact point-force
    coefficient and the Muscari self term (always the latter at coincident points).
    psi: "exact" (Ψ(x) = (0.2431x − 0.1814)/x) or a constant such as 0.25.
    """
    p, s = _points("points", points), _points("sources", sources)
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    self_term = _self_terms(areas, s.shape[0], h, e, psi)
    out = np.empty((p.shape[0], s.shape[0]))
    for rows in _chunks(p.shape[0], s.shape[0], chunk_elements):
        r = np.hypot(p[rows, 0:1] - s[None, :, 0], p[rows, 1:2] - s[None, :, 1])
        exact = _effective_zz(r, h, e, nu)
        out[rows] = np.where(np.abs(exact) <= np.abs(self_term), exact, self_term)
    return out


def boussinesq_block_matrix(
    points: ArrayLike,
    sources: ArrayLike,
    areas: ArrayLike,
    thickness: float,
    young: float,
    poisson: float = 0.5,
    psi: str | float = "exact",
) -> Array:
    """3K × 3N effective displacements per unit force [m/N] for forces along x, y and z.

    Row 3k+i is the displacement of point k along axis i (x, y, z), column 3n+j the force of
    source n along axis j. The zz entries equal :func:`boussinesq_matrix`. Where the zz entry
    takes the Muscari self term, the pair is treated as coincident: the odd couplings (xy, xz,
    yz, …) vanish and xx, yy take the centre value of a uniform shear traction on the square of
    area A (closed form), or the exact coefficient if that is smaller (the paper's rule).
    """
    p, s = _points("points", points), _points("sources", sources)
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    n = s.shape[0]
    area = _per_source("areas", areas, n, None)
    self_zz = muscari_self(area, h, e, psi)
    self_tt = shear_self(area, h, e, nu)
    dx = p[:, 0:1] - s[None, :, 0]
    dy = p[:, 1:2] - s[None, :, 1]
    g = _block_effective(dx, dy, h, e, nu)  # (K, N, 3, 3), inf/NaN at r = 0
    coincident = ~(np.isfinite(g[..., 2, 2]) & (np.abs(g[..., 2, 2]) <= np.abs(self_zz)))
    g[coincident] = 0.0
    g[..., 2, 2] = np.where(coincident, self_zz, g[..., 2, 2])
    for i in (0, 1):
        g[..., i, i] = np.where(coincident, self_tt, min_magnitude(g[..., i, i], self_tt))
    return g.transpose(0, 2, 1, 3).reshape(3 * p.shape[0], 3 * n)


def shear_self(area: ArrayLike, thickness: float, young: float, poisson: float) -> Array:
    """u_x(0) − u_x(h) [m/N] at the centre of a square of area A [m²] under a uniform shear
    traction of unit total force along x (Cerruti kernel integrated in closed form)."""
    area = positive_array("area", area)
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    c = 0.5 * np.sqrt(area)
    k = 1.0 - 2.0 * nu

    def cell(z: float) -> Array:
        # ∫∫ 1/R + X²/R³ + (1−2ν)(1/(R+z) − X²/(R(R+z)²)) dX dY over the centred square: its
        # four corners contribute alike, X = Y = c.
        q = np.hypot(c, z)
        r = np.hypot(q, c)
        ash = c * np.arcsinh(c / q)
        t = z * np.arctan2(c * c, z * r)
        t2 = z * np.arctan2(2.0 * c**4, (r + z) * (c * c * r + z * c * c))
        return 4.0 * ((2.0 * ash - t) + (ash - t) + k * (ash - t2))

    per_pressure = (1.0 + nu) / (2.0 * np.pi * e) * (cell(0.0) - cell(h))
    return per_pressure / area
