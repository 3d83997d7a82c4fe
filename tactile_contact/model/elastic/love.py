"""Love's solution: uniform normal pressure on a 2a × 2b rectangle of an elastic half-space.

Conventions as in :mod:`tactile_contact.model.elastic.boussinesq`: SI units, depth z ≥ 0 into the
skin, compressive pressure p > 0, u_z > 0 into the skin. (x, y) [m] is the offset of the field
point from the cell centre. Every function returns a displacement per unit pressure [m/Pa].

Near the cell the point kernels are integrated in closed form as a corner sum
Σ s_X·s_Y·F(X, Y) over X ∈ {a−x (+), −a−x (−)}, Y ∈ {b−y (+), −b−y (−)} with asinh / atan2
antiderivatives (DESIGN.md §2; derivations in docs/elastic.md). A corner sum of four terms
of size ~d·log d whose result is ~ab/d loses about d²/(ab) in relative accuracy at distance d,
so far away the smooth point kernel is integrated by tensor Gauss–Legendre quadrature instead,
which converges like (2d/s)^(−2n), s = max(a, b): for u_z, u_x, u_y from d ≥ FAR_RATIO·s; for
the effective u_z(0) − u_z(h), whose corner terms are put in a decaying (canonical) form first,
by the budget rule of :func:`effective_far_plan`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
from numpy.typing import ArrayLike

from tactile_contact.model.elastic.boussinesq import (
    Array,
    depth_array,
    finite_array,
    material,
    positive_array,
)

#: Distance / half-size ratio from which u_z, u_x, u_y use Gauss quadrature (corner sums lose
#: ≲ 1e-12 relative below it; 5-point Gauss errs ≲ (2·30)^(−10) above it).
FAR_RATIO = 30.0
FAR_ORDER = 5
#: The effective u_z(0) − u_z(h) corner sum loses ~ε·R²·M relative (R² = r²/ab, M = how much
#: smaller the result is than its terms: 1 at ν = 0.5, up to r²/h² as ν → 0, where the 1/r³
#: parts cancel). Gauss quadrature takes over where R²·M exceeds this budget (≈ 2e-11 error).
EFFECTIVE_BUDGET = 4.0e4
#: No quadrature closer than this many half-sizes (the corner sum is exact there anyway).
EFFECTIVE_MIN_RATIO = 2.5

_CORNERS = ((1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0))


@cache
def _gauss(n: int) -> tuple[Array, Array]:
    return np.polynomial.legendre.leggauss(n)


_HUGE = 1e300


def _ratio(num: Array, den: Array) -> Array:
    """num/den for den ≥ 0, 0 where den = 0, clamped to ±1e300 (subnormal den overflows)."""
    return np.clip(num / np.where(den > 0.0, den, 1.0), -_HUGE, _HUGE) * (den > 0.0)


def _xasinh(x: Array, y: Array, q: Array) -> Array:
    """x·asinh(y/q) with the limit 0 where q = 0 (then x = 0 too); |x| ≤ q keeps it finite."""
    return x * np.arcsinh(_ratio(y, q))


def _corner_uz(xc: Array, yc: Array, z: Array, nu: float) -> Array:
    """πE·u_z corner antiderivative (DESIGN.md §2)."""
    qx, qy = np.hypot(xc, z), np.hypot(yc, z)
    r = np.hypot(qx, yc)
    return (1.0 - nu * nu) * (_xasinh(xc, yc, qx) + _xasinh(yc, xc, qy)) - 0.5 * (1.0 + nu) * (
        1.0 - 2.0 * nu
    ) * z * np.arctan2(xc * yc, z * r)


def _corner_ux(xc: Array, yc: Array, z: Array, nu: float) -> Array:
    """2πE/(1+ν)·u_x corner antiderivative of ∫∫[−X·z/R³ + (1−2ν)·X/(R(R+z))] dX dY."""
    qx = np.hypot(xc, z)
    r = np.hypot(qx, yc)
    rz = r + z
    log_term = np.where(rz > 0.0, yc * np.log(np.where(rz > 0.0, rz, 1.0)), 0.0)
    # X·[atan(Y/X) − atan(zY/(XR))] merged into one atan2 (no 1/X, no cancellation).
    ang = xc * np.arctan2(xc * yc * (xc * xc + yc * yc), rz * (xc * xc * r + z * yc * yc))
    return 2.0 * (1.0 - nu) * z * np.arcsinh(_ratio(yc, qx)) + (1.0 - 2.0 * nu) * (log_term + ang)


def _corner_uz_effective(xc: Array, yc: Array, h: float, nu: float) -> Array:
    """2πE/(1+ν)·[u_z(0) − u_z(h)] corner antiderivative in canonical (decaying) form.

    The plain antiderivative 2(1−ν)(P_X + P_Y) + (1−2ν)·h·atan(XY/(hR)) tends to the edge
    asymptotes sgn(X)·G(Y) + sgn(Y)·G(X) − sgn(X)sgn(Y)·G(∞) far from a corner; those are
    subtracted here, in closed cancellation-free forms, so that every corner term is ~h²/d at
    distance d and the corner sum loses only ~(d/s)² (not (d/s)³). The subtracted pieces are
    added back exactly by :func:`_edge_correction`.
    """
    ax, ay = np.abs(xc), np.abs(yc)
    r0 = xc * xc
    r0 += yc * yc
    r = r0 + h * h
    np.sqrt(r0, out=r0)
    np.sqrt(r, out=r)
    s = r0 + r
    np.divide(h * h, s, out=s)
    # P_Y − sgn(X)·G(Y) = sgn(X)·Y·ln((|X|+R0)/(|X|+R)) = sgn(X)·Y·log1p(−s/(|X|+R)). The
    # factor 1 + 4ε on R keeps the ratio below 1 where X = Y = 0 (so 0·log stays finite) and
    # changes it by one rounding at most elsewhere. Written in place: this is the hot loop.
    rt = r * (1.0 + 4.0 * np.finfo(float).eps)

    def tail(along: Array, other: Array, a_other: Array) -> Array:
        t = a_other + rt
        np.divide(s, t, out=t)
        np.negative(t, out=t)
        np.log1p(t, out=t)
        t *= along
        t *= np.sign(other)
        return t

    p = tail(yc, xc, ax)
    p += tail(xc, yc, ay)
    if nu == 0.5:
        return p
    # V = atan(XY/(hR)) − sgnX·atan(Y/h) − sgnY·atan(X/h) + sgnX·sgnY·π/2 (for X, Y > 0) equals
    # atan(h/M) − atan(h·m·(m²+h²)/((M+R)(M·m² + h²R))), M = max(|X|,|Y|), m = min; merged
    # into one atan2 whose two arguments are sums of positive terms (hD ≥ 2·M·N).
    big, small = np.maximum(ax, ay), np.minimum(ax, ay)
    num = h * small * (small * small + h * h)
    den = (big + r) * (big * small * small + h * h * r)
    v = np.arctan2(h * den - big * num, big * den + h * num)
    return 2.0 * (1.0 - nu) * p + (1.0 - 2.0 * nu) * h * np.sign(xc) * np.sign(yc) * v


def edge_g(t: Array, h: float) -> Array:
    """t·asinh(h²/(2|t|q_t)) = ½·t·log1p(h²/t²), q_t = √(t²+h²); 0 at t = 0 (clamped)."""
    with np.errstate(divide="ignore", over="ignore"):
        return 0.5 * t * np.log1p(np.minimum(h * h / (t * t), _HUGE))


def edge_atan(t1: Array, t2: Array, h: float) -> Array:
    """atan(t1/h) − atan(t2/h) without cancellation when t1 ≈ t2 ≫ h."""
    return np.arctan2(h * (t1 - t2), h * h + t1 * t2)


def _edge_correction(xp: Array, xm: Array, yp: Array, ym: Array, h: float, nu: float) -> Array:
    """What the canonical corner sum leaves out; non-zero only when the field point lies in the
    cell's x-range or y-range (xp = a − x, xm = −a − x, yp, ym likewise):
    c_x·[G(Y+) − G(Y−)] + c_y·[G(X+) − G(X−)] − c_x·c_y·G(∞), c_x = sgn(X+) − sgn(X−),
    G(t) = 2(1−ν)·edge_g(t) + (1−2ν)·h·atan(t/h), G(∞) = (1−2ν)·h·π/2."""
    cx = np.sign(xp) - np.sign(xm)
    cy = np.sign(yp) - np.sign(ym)
    out = (
        2.0
        * (1.0 - nu)
        * (cx * (edge_g(yp, h) - edge_g(ym, h)) + cy * (edge_g(xp, h) - edge_g(xm, h)))
    )
    if nu != 0.5:
        k = (1.0 - 2.0 * nu) * h
        out += k * (cx * edge_atan(yp, ym, h) + cy * edge_atan(xp, xm, h) - cx * cy * 0.5 * np.pi)
    return out


def corner_sum_effective(x: Array, y: Array, a: Array, b: Array, h: float, nu: float) -> Array:
    """2πE/(1+ν)·[u_z(0) − u_z(h)] of a 2a × 2b cell by the closed form (any distance)."""
    xp, xm, yp, ym = a - x, -a - x, b - y, -b - y
    total = (
        _corner_uz_effective(xp, yp, h, nu)
        - _corner_uz_effective(xm, yp, h, nu)
        - _corner_uz_effective(xp, ym, h, nu)
        + _corner_uz_effective(xm, ym, h, nu)
    )
    return total + _edge_correction(xp, xm, yp, ym, h, nu)


def effective_point_kernel(dx: Array, dy: Array, h: float, nu: float) -> Array:
    """2πE/(1+ν)·[u_z(0) − u_z(h)] of a unit point force, cancellation-free [1/m]."""
    r = np.hypot(dx, dy)
    rho = np.sqrt(r * r + h * h)
    base = h * h / (r * rho * (r + rho))  # the form of boussinesq._effective_zz
    return base * (h * h * (2.0 * rho + r) / (rho * rho * (r + rho)) - 2.0 * nu)


def _corner_sum(corner: Callable[[Array, Array], Array], x: Array, y: Array, a: Array, b: Array):
    total = np.zeros(np.broadcast_shapes(x.shape, y.shape, a.shape, b.shape))
    for sx, sy in _CORNERS:
        total += sx * sy * corner(sx * a - x, sy * b - y)
    return total


def _gauss_cell(kernel: Callable[[Array, Array], Array], x, y, a, b, n: int = FAR_ORDER):
    """∫∫ kernel(x − ξ, y − η) dξ dη over [−a, a] × [−b, b] by n × n Gauss–Legendre."""
    t, w = _gauss(n)
    total = np.zeros(np.broadcast_shapes(x.shape, y.shape, a.shape, b.shape))
    for ti, wi in zip(t, w, strict=True):
        for tj, wj in zip(t, w, strict=True):
            total += wi * wj * kernel(x - a * ti, y - b * tj)
    return total * a * b


def effective_far_plan(r: Array, a: Array, b: Array, h: float, nu: float) -> tuple[Array, Array]:
    """Where the effective-u_z integral over a 2a × 2b cell should use Gauss quadrature (the
    corner sum loses ~ε·(r²/ab)·M there, see EFFECTIVE_BUDGET), and how many points per axis:
    enough for (2R)^(−2n) < 1e-14 with R = r/max(a, b)."""
    with np.errstate(all="ignore"):  # overflow to inf is the right limit in each step here
        ratio = r / np.maximum(a, b)
        magnify = 1.0 / np.maximum(1.5 * (h / np.maximum(r, 1e-300)) ** 2, 2.0 * nu)
        loss = (r / a) * (r / b) * np.minimum(magnify, 1e300)
        far = (ratio >= EFFECTIVE_MIN_RATIO) & (loss > EFFECTIVE_BUDGET)
        order = np.ceil(7.0 / np.log10(2.0 * np.maximum(ratio, EFFECTIVE_MIN_RATIO)))
    return far, np.clip(order, 3, 18).astype(int)


def effective_far_radius(a: Array, b: Array, h: float, nu: float) -> Array:
    """The distance [m] from which :func:`effective_far_plan` chooses quadrature for a cell of
    half-sizes a, b [m]: the smallest r with r ≥ 2.5·max(a, b) and (r²/ab)·M > EFFECTIVE_BUDGET."""
    ab = np.asarray(a, dtype=float) * np.asarray(b, dtype=float)
    r = (1.5 * EFFECTIVE_BUDGET * ab * h * h) ** 0.25  # M = r²/(1.5h²) branch
    if nu > 0.0:
        r_flat = np.sqrt(2.0 * nu * EFFECTIVE_BUDGET * ab)  # M = 1/(2ν) branch
        r = np.where(r_flat * r_flat >= 0.75 * h * h / nu, r_flat, r)
    return np.maximum(r, EFFECTIVE_MIN_RATIO * np.maximum(a, b)) * (1.0 + 1e-12)


def gauss_effective(x: Array, y: Array, a: Array, b: Array, h: float, nu: float, order: Array):
    """2πE/(1+ν)·[u_z(0) − u_z(h)] of cells by Gauss quadrature, `order` points per axis."""
    out = np.empty(np.broadcast_shapes(x.shape, order.shape))
    for n in np.unique(order):
        m = order == n
        out[m] = _gauss_cell(
            lambda dx, dy: effective_point_kernel(dx, dy, h, nu), x[m], y[m], a[m], b[m], int(n)
        )
    return out


def _split(shape, x, y, a, b, dist, near_fn, far_fn, ratio: float = FAR_RATIO) -> Array:
    """Evaluate near_fn where dist < ratio·max(a, b), far_fn elsewhere (on subsets only)."""
    x, y, a, b, dist = np.broadcast_arrays(x, y, a, b, dist)
    far = dist >= ratio * np.maximum(a, b)
    out = np.empty(shape)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for mask, fn in ((~far, near_fn), (far, far_fn)):
            if np.any(mask):
                out[mask] = fn(x[mask], y[mask], a[mask], b[mask], mask)
    return out


def _inputs(x, y, a, b):
    return (
        finite_array("x", x),
        finite_array("y", y),
        positive_array("a (half-size)", a),
        positive_array("b (half-size)", b),
    )


def love_uz(
    x: ArrayLike, y: ArrayLike, z: ArrayLike, a: ArrayLike, b: ArrayLike, young, poisson
) -> Array:
    """Vertical displacement per unit pressure [m/Pa] at offset (x, y) [m], depth z ≥ 0 [m].

    The cell is 2a × 2b [m] centred at the origin; broadcasts over all array arguments.
    Positive = into the skin under compressive pressure.
    """
    e, nu = material(young, poisson)
    x, y, a, b = _inputs(x, y, a, b)
    z = depth_array("z", z)
    x, y, z, a, b = np.broadcast_arrays(x, y, z, a, b)

    def near(xs, ys, as_, bs, m):
        zz = z[m]
        return _corner_sum(lambda xc, yc: _corner_uz(xc, yc, zz, nu), xs, ys, as_, bs) / (np.pi * e)

    def far(xs, ys, as_, bs, m):
        zz = z[m]
        c = (1.0 + nu) / (2.0 * np.pi * e)

        def kern(dx, dy):
            rho = np.sqrt(dx * dx + dy * dy + zz * zz)
            return c * (2.0 * (1.0 - nu) / rho + zz * zz / rho**3)

        return _gauss_cell(kern, xs, ys, as_, bs)

    return _split(x.shape, x, y, a, b, np.sqrt(x * x + y * y + z * z), near, far)


def _love_lateral(x, y, z, a, b, young, poisson, swap: bool) -> Array:
    e, nu = material(young, poisson)
    x, y, a, b = _inputs(x, y, a, b)
    z = depth_array("z", z)
    if swap:  # u_y is u_x with the axes exchanged
        x, y, a, b = y, x, b, a
    x, y, z, a, b = np.broadcast_arrays(x, y, z, a, b)
    # Odd in x, even in y: evaluated at |x|, |y| and given the sign of x, so mirror images
    # agree exactly (near x = 0 the terms nearly cancel, and sums taken in mirrored order
    # differ by their rounding: 2.5e-12 relative at x = 0.13 mm, y = 12 mm).
    sign = np.sign(x)
    x, y = np.abs(x), np.abs(y)
    c = (1.0 + nu) / (2.0 * np.pi * e)

    def near(xs, ys, as_, bs, m):
        zz = z[m]
        return c * _corner_sum(lambda xc, yc: _corner_ux(xc, yc, zz, nu), xs, ys, as_, bs)

    def far(xs, ys, as_, bs, m):
        zz = z[m]

        def kern(dx, dy):
            rho = np.sqrt(dx * dx + dy * dy + zz * zz)
            return c * dx * (zz / rho**3 - (1.0 - 2.0 * nu) / (rho * (rho + zz)))

        return _gauss_cell(kern, xs, ys, as_, bs)

    return sign * _split(x.shape, x, y, a, b, np.sqrt(x * x + y * y + z * z), near, far)


def love_ux(
    x: ArrayLike, y: ArrayLike, z: ArrayLike, a: ArrayLike, b: ArrayLike, young, poisson
) -> Array:
    """Horizontal displacement along x per unit normal pressure [m/Pa]; arguments as love_uz.

    Negative for x > 0 at the surface when ν < 0.5 (material moves towards the load).
    """
    return _love_lateral(x, y, z, a, b, young, poisson, swap=False)


def love_uy(
    x: ArrayLike, y: ArrayLike, z: ArrayLike, a: ArrayLike, b: ArrayLike, young, poisson
) -> Array:
    """Horizontal displacement along y per unit normal pressure [m/Pa]; arguments as love_uz."""
    return _love_lateral(x, y, z, a, b, young, poisson, swap=True)


def love_effective(
    x: ArrayLike,
    y: ArrayLike,
    a: ArrayLike,
    b: ArrayLike,
    thickness: float,
    young: float,
    poisson: float,
    component: str = "z",
) -> Array:
    """Effective displacement u(0) − u(h) per unit pressure [m/Pa] of a 2a × 2b cell.

    (x, y) [m] offset from the cell centre, thickness h [m]; component "z" (compression a taxel
    measures), "x" or "y". Broadcasts over x, y, a, b.
    """
    e, nu = material(young, poisson)
    h = float(positive_array("thickness", thickness))
    x, y, a, b = _inputs(x, y, a, b)
    if component not in ("x", "y", "z"):
        raise ValueError(f"component must be 'x', 'y' or 'z', got {component!r}")
    if component == "y":
        x, y, a, b = y, x, b, a
    x, y, a, b = np.broadcast_arrays(x, y, a, b)
    # Even in y, and in x for "z", odd in x otherwise: evaluated at |x|, |y| (the sign put
    # back), so mirror images agree exactly and not only to the rounding of mirrored sums.
    sign = np.sign(x)
    x, y = np.abs(x), np.abs(y)
    c = (1.0 + nu) / (2.0 * np.pi * e)
    k = 1.0 - 2.0 * nu

    if component == "z":
        out = np.empty(x.shape)
        far, order = effective_far_plan(np.hypot(x, y), a, b, h, nu)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            near = ~far
            out[near] = corner_sum_effective(x[near], y[near], a[near], b[near], h, nu)
            out[far] = gauss_effective(x[far], y[far], a[far], b[far], h, nu, order[far])
        return c * out

    zero, depth = np.zeros(1), np.full(1, h)

    def corner(xc, yc):
        return _corner_ux(xc, yc, zero, nu) - _corner_ux(xc, yc, depth, nu)

    def kern(dx, dy):
        r2 = dx * dx + dy * dy
        rho = np.sqrt(r2 + h * h)
        return -dx * h * (k / (r2 * rho) + 1.0 / rho**3)

    def near(xs, ys, as_, bs, m):
        return c * _corner_sum(corner, xs, ys, as_, bs)

    def far(xs, ys, as_, bs, m):
        return c * _gauss_cell(kern, xs, ys, as_, bs)

    return sign * _split(x.shape, x, y, a, b, np.hypot(x, y), near, far)


def love_uz_effective(x, y, a, b, thickness, young, poisson) -> Array:
    """u_z(0) − u_z(h) per unit pressure [m/Pa]; shorthand for love_effective(..., "z")."""
    return love_effective(x, y, a, b, thickness, young, poisson, "z")
