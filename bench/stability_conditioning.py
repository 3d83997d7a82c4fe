"""Condition number of square problems against the estimate κ ≈ max(0.94·h/d, 0.19·L/h).

Pressures and measurements on one n × n grid of pitch d (side L = n·d), Love and
Boussinesq–Cerruti (Ψ exact, Ψ = 0.25) next to the estimate of DESIGN.md §2: over pitch and
side, near the zero of the fitted Muscari Ψ (where the B-C diagonal vanishes), and at
very small and very large grids (down to d = 0.01·h; up to 128² cells through the FFT
operator, whose product is checked against dense rows and whose extreme eigenvalues come from
Lanczos).

    python bench/stability_conditioning.py --out docs/bench [--quick]   (part of make bench)
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from benchkit.layer import NU, E, H, kappa_estimate, square_grid
from benchkit.tables import json_report, md_table
from scipy.sparse.linalg import eigsh

from tactile_contact.model.elastic import (
    boussinesq_matrix,
    love_matrix,
    muscari_psi,
    regular_grid_operator,
)

#: Cell side at which the fitted Ψ(h/z0) = (0.2431x − 0.1814)/x vanishes: x = 0.1814/0.2431,
#: z0 = √(3A/(2π)) = 0.691·d for square cells.
PSI_ZERO_D_OVER_H = 1.0 / (0.1814 / 0.2431 * np.sqrt(3.0 / (2.0 * np.pi)))


def kappas(n: int, d: float, h: float = H) -> dict[str, float]:
    pts, half = square_grid(n, d)
    area = np.full(len(pts), d * d)
    out = {"love": float(np.linalg.cond(love_matrix(pts, pts, half, h, E, NU)))}
    for name, psi in (("bc_exact", "exact"), ("bc_025", 0.25)):
        out[name] = float(np.linalg.cond(boussinesq_matrix(pts, pts, area, h, E, NU, psi)))
    return out


def conditioning(quick: bool) -> list[dict[str, Any]]:
    grid = [
        (16, 0.05),
        (16, 0.1),
        (16, 0.25),
        (16, 0.5),
        (16, 1.0),
        (16, 2.0),
        (8, 1.0),
        (24, 1.0),
        (32, 1.0),
    ] + ([] if quick else [(40, 1.0)])
    return [
        {
            "n": n,
            "d_over_h": r,
            "L_over_h": n * r,
            **kappas(n, r * H),
            "estimate": kappa_estimate(H, r * H, n * r * H),
        }
        for n, r in grid
    ]


def psi_zero() -> list[dict[str, Any]]:
    rows = []
    for r in (1.0, 1.5, 1.8, 1.9, round(PSI_ZERO_D_OVER_H, 3), 2.0, 2.2, 2.5, 3.0):
        d = r * H
        x = H / np.sqrt(3 * d * d / (2 * np.pi))
        rows.append(
            {
                "d_over_h": r,
                "psi_exact": float(muscari_psi(x)[()]),
                **kappas(12, d),
                "estimate": kappa_estimate(H, d, 12 * d),
            }
        )
    return rows


def extremes(quick: bool) -> dict[str, Any]:
    small = []
    for n, r in ((16, 0.01), (16, 0.02), (16, 5.0), (16, 10.0), (1, 1.0), (2, 1.0), (3, 1.0)):
        pts, half = square_grid(n, r * H)
        c = love_matrix(pts, pts, half, H, E, NU)
        small.append(
            {
                "n": n,
                "d_over_h": r,
                "finite": bool(np.isfinite(c).all()),
                "kappa_love": float(np.linalg.cond(c)),
                "estimate": kappa_estimate(H, r * H, n * r * H),
            }
        )
    large = []
    rng = np.random.default_rng(3)
    for n in (64,) if quick else (64, 128):
        t0 = time.perf_counter()
        op = regular_grid_operator(n, n, H, H, H, E, NU)
        lin = op.as_linear_operator()
        # A fixed start vector: ARPACK's own random one made the last digits differ from run
        # to run (≈ 1e-9 relative).
        v0 = np.ones(n * n)
        top = eigsh(lin, k=1, which="LA", tol=1e-8, v0=v0, return_eigenvectors=False)[0]
        low = eigsh(lin, k=1, which="SA", tol=1e-8, v0=v0, return_eigenvectors=False)[0]
        q = rng.uniform(0, 1e4, n * n)
        c = (np.arange(n) * H)[:, None]
        pts = np.column_stack([np.repeat(c[:, 0], n), np.tile(c[:, 0], n)])  # C order (i, j)
        rows = rng.choice(n * n, 40, replace=False)
        dense = love_matrix(pts[rows], pts, np.full(2, H / 2), H, E, NU) @ q
        fft = op.matvec(q)[rows]
        large.append(
            {
                "n": n,
                "cells": n * n,
                "lambda_min": float(low),
                "lambda_max": float(top),
                "kappa_love": float(top / low),
                "estimate": kappa_estimate(H, H, n * H),
                "fft_vs_dense": float(np.abs(fft - dense).max() / np.abs(dense).max()),
                "seconds": time.perf_counter() - t0,
            }
        )
    return {"dense": small, "fft": large}


def compute(args: Any) -> dict[str, Any]:
    return {
        "conditioning": conditioning(args.quick),
        "psi_zero": {"d_over_h": PSI_ZERO_D_OVER_H, "rows": psi_zero()},
        "extremes": extremes(args.quick),
    }


def render(rep: dict[str, Any]) -> list[str]:
    out = [
        "## Condition number of square problems",
        "",
        "Pressures and measurements on one n × n grid of pitch d (side L = n·d).",
        "",
    ]
    out += md_table(
        [
            "cells",
            "d/h",
            "L/h",
            "κ Love",
            "κ B-C Ψ exact",
            "κ B-C Ψ 0.25",
            "max(0.94 h/d, 0.19 L/h)",
            "Love / estimate",
        ],
        [
            [
                f"{r['n']}²",
                f"{r['d_over_h']:g}",
                f"{r['L_over_h']:g}",
                f"{r['love']:.1f}",
                f"{r['bc_exact']:.1f}",
                f"{r['bc_025']:.1f}",
                f"{r['estimate']:.1f}",
                f"{r['love'] / r['estimate']:.2f}",
            ]
            for r in rep["conditioning"]
        ],
    )
    pz = rep["psi_zero"]
    out += [
        "",
        f"## B-C near the zero of the fitted Ψ (d ≈ {pz['d_over_h']:.3f}·h)",
        "",
        "The Muscari self term is 9/(2πE)·Ψ(h/z0)/z0 with z0 = √(3A/2π) = 0.691·d; the fitted "
        "Ψ(x) = (0.2431x − 0.1814)/x changes sign at x = 0.746, i.e. at cells of "
        f"{pz['d_over_h']:.3f}·h. There the diagonal of the square B-C problem vanishes and "
        "the min-magnitude rule keeps it: the problem is (nearly) singular. 12² cells:",
        "",
    ]
    out += md_table(
        ["d/h", "Ψ exact", "κ B-C Ψ exact", "κ B-C Ψ 0.25", "κ Love", "estimate"],
        [
            [
                f"{r['d_over_h']:g}",
                f"{r['psi_exact']:+.4f}",
                f"{r['bc_exact']:.3g}",
                f"{r['bc_025']:.1f}",
                f"{r['love']:.1f}",
                f"{r['estimate']:.1f}",
            ]
            for r in pz["rows"]
        ],
    )
    ex = rep["extremes"]
    out += ["", "## Very small and very large grids", "", "Dense Love matrices:", ""]
    out += md_table(
        ["cells", "d/h", "all finite", "κ Love", "estimate"],
        [
            [
                f"{r['n']}²",
                f"{r['d_over_h']:g}",
                str(r["finite"]),
                f"{r['kappa_love']:.2f}",
                f"{r['estimate']:.2f}",
            ]
            for r in ex["dense"]
        ],
    )
    out += [
        "",
        "Regular-grid FFT operator (d = h), extreme eigenvalues by Lanczos (the matrix is "
        "symmetric), product checked against 40 dense rows:",
        "",
    ]
    out += md_table(
        ["cells", "λ_min [m/Pa]", "λ_max [m/Pa]", "κ", "estimate", "FFT vs dense", "time s"],
        [
            [
                f"{r['n']}² = {r['cells']}",
                f"{r['lambda_min']:.3e}",
                f"{r['lambda_max']:.3e}",
                f"{r['kappa_love']:.1f}",
                f"{r['estimate']:.1f}",
                f"{r['fft_vs_dense']:.1e}",
                f"{r['seconds']:.1f}",
            ]
            for r in ex["fft"]
        ],
    )
    return out


if __name__ == "__main__":
    json_report(__doc__, "stability_conditioning", compute, render, quick="skip the largest grids")
