"""Boussinesq–Cerruti point-force kernels of an elastic half-space, and the Muscari self term.

Conventions (DESIGN.md §2): SI units; z ≥ 0 is the depth into the elastomer; a normal force
F > 0 pushes into the skin and u_z > 0 is displacement into the skin. Offsets (x, y) are
*field point minus force point* [m]. Every kernel is a displacement per unit force [m/N].

Point kernels (Johnson, *Contact Mechanics*, §3.2 and §3.8), C = (1+ν)/(2πE), ρ = √(r²+z²):

    G_xz = C·[x·z/ρ³ − (1−2ν)·x/(ρ(ρ+z))]                       (u_x from F_z)
    G_zz = C·[2(1−ν)/ρ + z²/ρ³]                                 (u_z from F_z)
    G_xx = C·[1/ρ + x²/ρ³ + (1−2ν)·(1/(ρ+z) − x²/(ρ(ρ+z)²))]    (u_x from F_x)
    G_yx = C·[x·y/ρ³ − (1−2ν)·x·y/(ρ(ρ+z)²)]                    (u_y from F_x)
    G_zx = C·[x·z/ρ³ + (1−2ν)·x/(ρ(ρ+z))]                       (u_z from F_x)

No Lamé parameter appears, so ν = 0.5 is an ordinary value. The *effective* kernels
u(0) − u(h) are written without subtracting two large numbers (1/r − 1/ρ = h²/(rρ(r+ρ)) and
similar identities), so they keep full relative accuracy far from the force, where they decay
like 1/r³ (normal) or 1/r² (tangential couplings).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Fitted Muscari shape function Ψ(x) = (a·x − b)/x, x = h/z0 (Muscari et al. 2013).
MUSCARI_PSI_A = 0.2431
MUSCARI_PSI_B = 0.1814


def finite_array(name: str, value: ArrayLike) -> Array:
    """`value` as a float64 array; ValueError naming `name` if any entry is NaN or inf."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be numeric, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return arr


def positive_array(name: str, value: ArrayLike) -> Array:
    """`value` as a finite float64 array whose entries are all > 0."""
    arr = finite_array(name, value)
    if np.any(arr <= 0.0):
        raise ValueError(f"{name} must be > 0, got {value!r}")
    return arr


def depth_array(name: str, value: ArrayLike) -> Array:
    """`value` as a finite float64 array whose entries are all ≥ 0 (a depth [m])."""
    arr = finite_array(name, value)
    if np.any(arr < 0.0):
        raise ValueError(f"{name} (depth) must be >= 0, got {value!r}")
    return arr


def material(young: Any, poisson: Any) -> tuple[float, float]:
    """Validated (E [Pa], ν): E finite > 0, −1 < ν ≤ 0.5 (0.5 = incompressible, allowed)."""
    e = float(finite_array("young", young))
    nu = float(finite_array("poisson", poisson))
    if e <= 0.0:
        raise ValueError(f"young must be > 0 Pa, got {e!r}")
    if not -1.0 < nu <= 0.5:
        raise ValueError(f"poisson must be in (-1, 0.5], got {nu!r}")
    return e, nu


def _no_singularity(name: str, out: Array) -> Array:
    if not np.all(np.isfinite(out)):
        raise ValueError(
            f"{name} is singular at the point of application (r = 0 at the depth used); "
            "use muscari_self or a Love cell for coincident points"
        )
    return out


def boussinesq_uz(x: ArrayLike, y: ArrayLike, z: ArrayLike, young: float, poisson: float) -> Array:
    """Vertical displacement per unit normal force [m/N] at offset (x, y) [m], depth z ≥ 0 [m].

    Broadcasts over x, y, z. Raises ValueError at the singular point x = y = z = 0.
    """
    e, nu = material(young, poisson)
    x, y, z = finite_array("x", x), finite_array("y", y), depth_array("z", z)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rho = np.hypot(np.hypot(x, y), z)
        out = (1.0 + nu) / (2.0 * np.pi * e) * (2.0 * (1.0 - nu) / rho + (z / rho) ** 2 / rho)
    return _no_singularity("boussinesq_uz", np.asarray(out, dtype=np.float64))


def boussinesq_block(
    x: ArrayLike, y: ArrayLike, z: ArrayLike, young: float, poisson: float
) -> Array:
    """Full Boussinesq–Cerruti 3×3 block G [m/N] at offset (x, y) [m] and depth z ≥ 0 [m].

    Returns shape (..., 3, 3) with G[..., i, j] = displacement along axis i (x, y, z) per unit
    surface force along axis j. Raises ValueError at x = y = z = 0.
    """
    e, nu = material(young, poisson)
    x, y, z = finite_array("x", x), finite_array("y", y), depth_array("z", z)
    x, y, z = np.broadcast_arrays(x, y, z)
    c = (1.0 + nu) / (2.0 * np.pi * e)
    k = 1.0 - 2.0 * nu
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rho = np.hypot(np.hypot(x, y), z)
        r3 = rho**3
        rz = rho + z
        g = np.empty((*x.shape, 3, 3))
        g[..., 0, 0] = c * (1 / rho + x * x / r3 + k * (1 / rz - x * x / (rho * rz * rz)))
        g[..., 1, 1] = c * (1 / rho + y * y / r3 + k * (1 / rz - y * y / (rho * rz * rz)))
        g[..., 0, 1] = g[..., 1, 0] = c * x * y * (1 / r3 - k / (rho * rz * rz))
        g[..., 0, 2] = c * x * (z / r3 - k / (rho * rz))
        g[..., 1, 2] = c * y * (z / r3 - k / (rho * rz))
        g[..., 2, 0] = c * x * (z / r3 + k / (rho * rz))
        g[..., 2, 1] = c * y * (z / r3 + k / (rho * rz))
        g[..., 2, 2] = c * (2.0 * (1.0 - nu) / rho + z * z / r3)
    return _no_singularity("boussinesq_block", g)


def _effective_zz(r: Array, h: float, e: float, nu: float) -> Array:
    """Stable C·[2(1−ν)(1/r − 1/ρ) − h²/ρ³] [m/N]; +inf at r = 0 (no exception)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rho = np.sqrt(r * r + h * h)
        h2 = h * h
        # 2(1−ν)/(rρ(r+ρ)) − 1/ρ³ = [h²(2ρ+r)/(ρ²(r+ρ)) − 2ν]/(rρ(r+ρ)): the 1/r³ parts
        # cancel analytically, so small ν keeps its relative accuracy far away too.
        base = h2 / (r * rho * (r + rho))
        out = (
            (1.0 + nu)
            / (2.0 * np.pi * e)
            * base
            * (h2 * (2.0 * rho + r) / (rho * rho * (r + rho)) - 2.0 * nu)
        )
    return np.where(r == 0.0, np.inf, out)


def boussinesq_effective(
    x: ArrayLike, y: ArrayLike, thickness: float, young: float, poisson: float
) -> Array:
    """Effective normal displacement u_z(0) − u_z(h) per unit normal force [m/N].

    (x, y) [m] is the horizontal offset from the force, thickness h [m] the layer thickness.
    Negative beyond r ≈ 0.79·h at ν = 0.5 (the layer bulges). Raises ValueError at r = 0.
    """
    e, nu = material(young, poisson)
    h = float(positive_array("thickness", thickness))
    r = np.hypot(finite_array("x", x), finite_array("y", y))
    return _no_singularity("boussinesq_effective", _effective_zz(r, h, e, nu))


def boussinesq_block_effective(
    x: ArrayLike, y: ArrayLike, thickness: float, young: float, poisson: float
) -> Array:
    """Effective 3×3 block G(z=0) − G(z=h) [m/N], shape (..., 3, 3), same axes as boussinesq_block.

    Written with cancellation-free differences; raises ValueError at r = 0.
    """
    e, nu = material(young, poisson)
    h = float(positive_array("thickness", thickness))
    x, y = np.broadcast_arrays(finite_array("x", x), finite_array("y", y))
    g = _block_effective(x, y, h, e, nu)
    return _no_singularity("boussinesq_block_effective", g)


def _block_effective(x: Array, y: Array, h: float, e: float, nu: float) -> Array:
    """Cancellation-free G(0) − G(h) (see module docstring); inf/NaN where r = 0."""
    c = (1.0 + nu) / (2.0 * np.pi * e)
    k = 1.0 - 2.0 * nu
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = np.hypot(x, y)
        rho = np.sqrt(r * r + h * h)
        dr = h * h / (rho + r)  # ρ − r
        d1 = dr / (r * rho)  # 1/r − 1/ρ
        d3 = dr * (rho * rho + rho * r + r * r) / (r**3 * rho**3)  # 1/r³ − 1/ρ³
        rh = rho + h
        e3 = (dr * (rho * rho + rho * r + r * r) + 2 * rho * rho * h + rho * h * h) / (
            r**3 * rho * rh * rh
        )  # 1/r³ − 1/(ρ(ρ+h)²)
        f1 = (dr + h) / (r * rh)  # 1/r − 1/(ρ+h)
        g = np.empty((*x.shape, 3, 3))
        g[..., 0, 0] = c * (d1 + x * x * d3 + k * (f1 - x * x * e3))
        g[..., 1, 1] = c * (d1 + y * y * d3 + k * (f1 - y * y * e3))
        g[..., 0, 1] = g[..., 1, 0] = c * x * y * (d3 - k * e3)
        lateral_from_normal = -c * h * (k / (r * r * rho) + 1.0 / rho**3)
        normal_from_lateral = c * h * (k / (r * r * rho) - 1.0 / rho**3)
        g[..., 0, 2] = x * lateral_from_normal
        g[..., 1, 2] = y * lateral_from_normal
        g[..., 2, 0] = x * normal_from_lateral
        g[..., 2, 1] = y * normal_from_lateral
        g[..., 2, 2] = (
            c
            * (h * h / (r * rho * (r + rho)))
            * (h * h * (2.0 * rho + r) / (rho * rho * (r + rho)) - 2.0 * nu)
        )
    return g


def muscari_psi(x: ArrayLike, psi: str | float = "exact") -> Array:
    """Muscari shape function Ψ(x), x = h/z0 > 0: "exact" → (0.2431x − 0.1814)/x, or a constant."""
    x = positive_array("h/z0", x)
    if isinstance(psi, str):
        if psi != "exact":
            raise ValueError(f"psi must be 'exact' or a number, got {psi!r}")
        return (MUSCARI_PSI_A * x - MUSCARI_PSI_B) / x
    value = float(finite_array("psi", psi))
    return np.full_like(x, value)


def muscari_self(
    area: ArrayLike, thickness: float, young: float, psi: str | float = "exact"
) -> Array:
    """Muscari self term δ/F = 9/(2πE)·Ψ(h/z0)/z0 [m/N], z0 = √(3A/(2π)), for cell area A [m²].

    Replaces the singular r = 0 coefficient of the effective kernel (derived for ν = 0.5).
    psi: "exact" for the fitted Ψ(x) = (0.2431x − 0.1814)/x, or a number (e.g. 0.25).
    """
    a = positive_array("area", area)
    h = float(positive_array("thickness", thickness))
    e = float(positive_array("young", young))
    z0 = np.sqrt(3.0 * a / (2.0 * np.pi))
    return 9.0 / (2.0 * np.pi * e) * muscari_psi(h / z0, psi) / z0


def min_magnitude(exact: ArrayLike, approx: ArrayLike) -> Array:
    """The paper's rule for arbitrary grids: per entry, the coefficient of smaller magnitude.

    Non-finite `exact` entries (the r = 0 singularity) always give way to `approx`.
    """
    ex, ap = np.broadcast_arrays(np.asarray(exact, float), np.asarray(approx, float))
    keep = np.isfinite(ex) & (np.abs(ex) <= np.abs(ap))
    return np.where(keep, ex, ap)
