"""Error statistics, the Cramér–Rao bound and detection rates.

Errors of a press: signed force error [%] and CoP error [mm]; a miss (``in_contact`` False) is
a NaN in both, counted as a 100 % force error and an infinite (or stated) CoP error in the
statistics. The bound: with readings y = g(θ) + noise, independent Gaussian noise σ_k per
taxel, the Fisher information is Jᵀ·diag(σ⁻²)·J and any unbiased estimator of F has
std ≥ √(I⁻¹)_FF. Four unknowns: the centre (x, y), the force and the indenter's size (sphere
radius R or punch radius a); the family (sphere or punch) is taken as known, so a fit that must
also tell the shape can do worse. For an efficient estimator with Gaussian errors the median
|error| is 0.674 × the bound. Quantised readings are treated as Gaussian with the rounding's
variance (1/12 count²) added: an approximation (the rounding of a reading that moves less than
a count is not random).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats
from numpy.typing import NDArray

from benchkit.protocol import Patch
from benchkit.readings import COUNT_NOISE, float_sigma
from tactile_contact.inverse.reconstruction import Reconstructor

#: Force bands of the tables.
BANDS = ("0.2 N", "0.5 N", ">=1 N")
#: Columns of a row of :func:`row_stats`.
COLUMNS = ("0.2 N", "0.5 N", ">=1 N", "max>=1", "all", "p90", "bias>=1", "cop", "misses", "miss!")


def errors(recon: Reconstructor, tier: str, x: NDArray, p: dict) -> dict[str, NDArray]:
    """Per press: signed force error [%] (NaN: missed), CoP error [mm] (NaN: missed), through
    ``solve_deflection`` (float tier) or ``solve`` (8-bit)."""
    err, cop = np.full(len(x), np.nan), np.full(len(x), np.nan)
    for i, (xi, f, c) in enumerate(zip(x, p["f"], p["c"], strict=True)):
        res = recon.solve_deflection(xi) if tier == "float" else recon.solve(xi)
        if res.in_contact:
            err[i] = (res.total_force / f - 1.0) * 100.0
            cop[i] = float(np.hypot(*(np.asarray(res.cop, dtype=float) - c))) * 1e3
    return {"err": err, "cop": cop}


def row_stats(r: dict[str, NDArray], f: NDArray, clear: NDArray) -> dict[str, float]:
    """Columns of one row; ``clear`` (N,) marks presses clearly above noise (ideal z ≥ CLEAR)."""
    miss = np.isnan(r["err"])
    a = np.where(miss, 100.0, np.abs(r["err"]))
    cop = np.where(miss, np.inf, r["cop"])
    hi = f >= 1.0
    return {
        "0.2 N": float(np.median(a[f == 0.2])) if np.any(f == 0.2) else np.nan,
        "0.5 N": float(np.median(a[f == 0.5])) if np.any(f == 0.5) else np.nan,
        ">=1 N": float(np.median(a[hi])),
        "max>=1": max(float(np.median(a[f == v])) for v in np.unique(f[hi])),
        "all": float(np.median(a)),
        "p90": float(np.percentile(a, 90)),
        # Misses hold no sign: the bias is over the detected presses.
        "bias>=1": float(np.median(r["err"][hi & ~miss])) if np.any(hi & ~miss) else np.nan,
        "cop": float(np.median(cop)),
        "misses": int(miss.sum()),
        "miss!": int((miss & clear).sum()),
    }


def worst_of(rows: list[tuple[dict[str, float], str]]) -> tuple[dict, dict]:
    """Each column's worst value over ``rows`` (stats, truth name) and whose it is: the largest
    value, the largest |bias| for the bias; NaNs are left out; the first truth wins a tie, and
    "-" names none when every truth ties at 0."""
    w, who = {}, {}
    for col in COLUMNS:
        vals = [(s[col], name) for s, name in rows]
        vals = [v for v in vals if not (isinstance(v[0], float) and np.isnan(v[0]))]
        if not vals:
            w[col], who[col] = np.nan, "-"
            continue
        pick = max(vals, key=(lambda v: abs(v[0])) if col == "bias>=1" else lambda v: v[0])
        w[col], who[col] = pick
        if pick[0] == 0:  # every truth ties
            who[col] = "-"
    return w, who


def bandmask(f: NDArray, band: str) -> NDArray[np.bool_]:
    """Presses of a force band of BANDS."""
    return f >= 1.0 if band == ">=1 N" else np.isclose(f, float(band.split()[0]))


def fisher_bound(jac: NDArray, sigma: NDArray) -> NDArray[np.float64]:
    """(4, 4) inverse Fisher information (the Cramér–Rao covariance) of (x, y, F, size) for
    Jacobian ``jac`` (K, 4) and per-taxel noise ``sigma`` (K,) in the reading's units.
    Parameters are rescaled before inverting (they span 1e-6 m to newtons)."""
    s = np.maximum(np.abs(jac).max(axis=0), 1e-300)
    a = (jac / s) / np.asarray(sigma, dtype=np.float64)[:, None]
    fisher = a.T @ a
    try:
        cov = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return np.full((4, 4), np.inf)
    return cov / np.outer(s, s)


def crb(jac: NDArray, sigma: NDArray, force: float) -> tuple[float, float]:
    """(σ_F / F [%], RMS centre error [m]) bounds of one press (see :func:`fisher_bound`)."""
    cov = fisher_bound(jac, sigma)
    sf = math.sqrt(max(cov[2, 2], 0.0)) / force * 100.0
    sc = math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0))
    return sf, sc


def bounds(lay: Patch, p: dict[str, NDArray], tier: str) -> tuple[NDArray, NDArray]:
    """Per press: Cramér–Rao σ_F/F [%] and RMS centre bound [mm] for the tier's noise."""
    sf, sc = [], []
    for d, jac, f in zip(p["d"], p["J"], p["f"], strict=True):
        if tier == "float":
            sigma = np.broadcast_to(float_sigma(d), d.shape)
        else:  # in ΔC: the sensor model's slope, the converter noise plus the rounding
            eps = 1e-9
            slope = (lay.to_delta_c(d + eps) - lay.to_delta_c(d - eps)) / (2 * eps)
            jac = slope[:, None] * jac
            sigma = np.full(len(d), lay.lsb * math.sqrt(COUNT_NOISE**2 + 1 / 12))
        a, b = crb(jac, sigma, float(f))
        sf.append(a)
        sc.append(b * 1e3)
    return np.array(sf), np.array(sc)


def poisson_upper(k: int, n: int) -> float:
    """95 % upper bound on the per-frame rate after k events in n frames."""
    return float(scipy.stats.chi2.ppf(0.95, 2 * k + 2) / 2.0 / n)


def iou(res, grid, center, radius) -> float:
    """IoU of the reconstructed contact cells and the true contact disc on a 0.1 mm raster."""
    if res.traction is None or not res.in_contact:
        return 0.0
    peak = res.peak_pressure
    on = res.traction > max(0.1 * peak, 100.0)
    ext = radius + 4e-3
    ax = np.arange(-ext, ext, 1e-4)
    xx, yy = np.meshgrid(ax + center[0], ax + center[1])
    true = np.hypot(xx - center[0], yy - center[1]) < radius
    j = np.floor((xx - grid.origin[0]) / grid.cell_size).astype(int)
    i = np.floor((yy - grid.origin[1]) / grid.cell_size).astype(int)
    ok = (i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])
    rec = np.zeros_like(true)
    rec[ok] = on[i[ok], j[ok]]
    union = (true | rec).sum()
    return float((true & rec).sum() / union) if union else 0.0
