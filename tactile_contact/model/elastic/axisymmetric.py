"""Round loads on the Love layer without cells: the effective compression u_z(0) − u_z(h) a
flat punch or a Hertz pressure of contact radius a causes at distance r, as a 1-D quadrature.

Why: a cell model blurs a punch's edge, where its pressure is singular and a point taxel's
reading changes by 8 % of the peak within 0.05 mm; tables built on 0.1 mm cells read up to
12 % of the peak off there (bench_valleys against a converged truth: 12 mm punches +5 … +10 %).

The point kernel of :func:`tactile_contact.model.elastic.boussinesq.boussinesq_effective` is
split into its surface part A/s, A = (1 − ν²)/(πE), whose ring integral is closed form,
∫₀^2π dθ/s = 4 K(m)/(r + ρ), m = 4rρ/(r + ρ)² (complete elliptic integral of the first kind),
and a part smooth in s² (the depth-h terms), integrated over the ring by the trapezoid rule
(periodic and analytic: geometric convergence). The radial integral over the load runs in
φ (ρ = a sin φ), which removes the punch's 1/√(a² − ρ²); it is split where the ring passes
through the field point (ρ = r, a log singularity of K) and each side's Gauss–Legendre nodes
are clustered at both ends.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import scipy.interpolate
import scipy.special
from numpy.typing import ArrayLike, NDArray

from tactile_contact.model.elastic.boussinesq import material, positive_array

#: Gauss–Legendre nodes per side of the split (≈ 1e-9 relative on the half-space closed forms).
RADIAL_NODES = 64
#: Trapezoid nodes over the ring for the smooth depth part (error ≈ e^(−N·acosh(1 + h²/2rρ))).
RING_NODES = 256
#: The depth part's table step over ρ [m] (a cubic spline between) and its Gauss nodes in φ.
DEPTH_STEP = 2.0e-5
DEPTH_NODES = 48

PROFILES = ("punch", "hertz")


@cache
def _clustered(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nodes u ∈ (0, 1) and weights for ∫₀¹ f du, clustered at both ends (smoothstep map)."""
    x, w = np.polynomial.legendre.leggauss(n)
    t = 0.5 * (x + 1.0)
    g = t**3 * (10.0 - 15.0 * t + 6.0 * t * t)
    dg = 30.0 * t * t * (1.0 - t) ** 2
    return g, 0.5 * w * dg


def _ring_surface(r: NDArray, rho: NDArray) -> NDArray[np.float64]:
    """∫₀^2π dθ/s [1/m], s² = r² + ρ² − 2rρ cos θ, without cancellation near r = ρ."""
    total = np.maximum(r + rho, 1e-300)  # both 0 only on a node of zero weight
    with np.errstate(divide="ignore", invalid="ignore"):
        # 1 − m, kept off 0: a clustered node may round onto the ring itself (weight ≈ 0).
        m1 = np.maximum(np.square((r - rho) / total), 1e-300)
        return 4.0 * scipy.special.ellipkm1(m1) / total


def _ring_depth(r: NDArray, rho: NDArray, h: float, nu: float) -> NDArray[np.float64]:
    """(len(rho), len(r)) ∫₀^2π g(s) dθ of the depth part g(s) = −[2(1−ν)/√(s²+h²) +
    h²/(s²+h²)^1.5] (× C elsewhere), by the trapezoid rule over the half ring (g is even in θ)."""
    theta = np.linspace(0.0, math.pi, RING_NODES // 2 + 1)
    w = np.full(len(theta), math.pi / (RING_NODES // 2))
    w[[0, -1]] *= 0.5
    out = np.empty((len(rho), len(r)))
    for i, p in enumerate(rho):  # rows of (R, θ): bounded memory
        s2 = r[:, None] ** 2 + p * p - 2.0 * r[:, None] * p * np.cos(theta)[None, :]
        q = s2 + h * h
        g = -(2.0 * (1.0 - nu) / np.sqrt(q) + h * h / (q * np.sqrt(q)))
        out[i] = 2.0 * (g @ w)
    return out


def round_responses(
    profiles: list[tuple[str, float]],
    distances: ArrayLike,
    thickness: float,
    young: float,
    poisson: float,
) -> NDArray[np.float64]:
    """(P, R) effective compression u_z(0) − u_z(h) [m/N] of unit-force round loads at the
    ``distances`` [m] from their centres: each of ``profiles`` is ("punch", a) (p ∝
    1/√(a² − ρ²)) or ("hertz", a) (p ∝ √(a² − ρ²)), a the contact radius [m], on a layer of
    ``thickness`` h [m], young E [Pa], poisson ν — the Love model's continuum limit, no cells."""
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    r = np.asarray(distances, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(r) & (r >= 0)):
        raise ValueError("distances must be finite and >= 0 [m]")
    for name, a in profiles:
        if name not in PROFILES:
            raise ValueError(f"profile must be one of {PROFILES}, got {name!r}")
        positive_array("radius", a)
    c_surface = (1.0 - nu * nu) / (math.pi * e)
    c_depth = (1.0 + nu) / (2.0 * math.pi * e)
    u, w = _clustered(RADIAL_NODES)
    # The depth part is smooth in ρ: one table over ρ for every profile, a spline between.
    top = max(a for _, a in profiles)
    grid = np.linspace(0.0, top, max(2, math.ceil(top / DEPTH_STEP)) + 1)
    depth = scipy.interpolate.CubicSpline(grid, _ring_depth(r, grid, h, nu), axis=0)
    xg, wg = np.polynomial.legendre.leggauss(DEPTH_NODES)
    phi_d = 0.25 * math.pi * (xg + 1.0)
    w_d = 0.25 * math.pi * wg
    out = np.empty((len(profiles), len(r)))
    for k, (name, a) in enumerate(profiles):
        # Surface part: φ from 0 to π/2, split at the ring through the field point.
        split = np.arcsin(np.minimum(r / a, 1.0))[:, None]
        phi = np.concatenate((split * u, split + (0.5 * math.pi - split) * u), axis=1)
        wphi = np.concatenate((split * w, (0.5 * math.pi - split) * w), axis=1)
        rho = a * np.sin(phi)
        with np.errstate(invalid="ignore"):
            ring = np.where(wphi > 0.0, wphi * _load(name, phi) * _ring_surface(r[:, None], rho), 0)
        # Depth part: plain Gauss nodes in φ, the same for every distance.
        dep = depth(a * np.sin(phi_d))  # (nodes, R)
        out[k] = c_surface * ring.sum(axis=1) + c_depth * ((w_d * _load(name, phi_d)) @ dep)
    return out


def _load(name: str, phi: NDArray) -> NDArray[np.float64]:
    """Unit-force load p·ρ dρ/dφ at ρ = a sin φ: punch sin φ/(2π), Hertz 3 sin φ cos² φ/(2π)."""
    out = np.sin(phi) / (2.0 * math.pi)
    return 3.0 * out * np.cos(phi) ** 2 if name == "hertz" else out


def round_response(
    profile: str,
    radius: float,
    distances: ArrayLike,
    thickness: float,
    young: float,
    poisson: float,
) -> NDArray[np.float64]:
    """(R,) :func:`round_responses` of one profile ("punch" or "hertz", contact radius [m])."""
    return round_responses([(profile, radius)], distances, thickness, young, poisson)[0]
