"""Numerical stability report (``make bench``): writes ``stability.json`` and ``stability.md``.

    python bench/stability.py --out docs/bench [--quick]

1. condition number of square problems (pressures and measurements on one grid) against
   pitch d / thickness h and side L / h, Love and Boussinesq–Cerruti (Ψ exact, Ψ = 0.25), next
   to the estimate κ ≈ max(0.94·h/d, 0.19·L/h) (DESIGN.md §2);
2. the B-C problem near the zero of the fitted Muscari Ψ (cells of ≈ 1.94·h);
3. very small and very large grids (down to d = 0.01·h, up to 128² cells through the FFT
   operator, whose product is checked against dense rows);
4. the B-C coefficients near the point-force singularity against the Love cell integral, and
   Love values at cell edges and corners (finite, continuous);
5. unit neutrality: E and every length rescaled (C scales exactly; κ does not change);
6. noise amplification: ‖C⁺‖₂ and Monte-Carlo spread of force and CoP per solver;
7. float32 against float64 online products, alone and through the whole reconstruction;
8. perturbation of E, h, ν in the model (truth fixed);
9. the loss of net force in the under-determined problem (72 taxels, 698 cells) against the
   contact size, per solver, and how the default (two-pass NNLS + Tikhonov) counters it.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse.linalg import eigsh
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import ROOT, kappa_estimate, square_grid
from stability_report import render
from tradeoff import Config, Pipeline

from tactile_contact.inverse.solvers import SvdInverse
from tactile_contact.model.elastic import (
    boussinesq_effective,
    boussinesq_matrix,
    love_effective,
    love_matrix,
    love_uz,
    muscari_psi,
    muscari_self,
    regular_grid_operator,
)
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere

H, E, NU = 2e-3, 2.1e5, 0.5
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
        top = eigsh(lin, k=1, which="LA", tol=1e-8, return_eigenvectors=False)[0]
        low = eigsh(lin, k=1, which="SA", tol=1e-8, return_eigenvectors=False)[0]
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


def singularity() -> dict[str, Any]:
    d = 2e-3
    a = d / 2
    rows = []
    for r in (0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0):
        love = float(love_effective(r * d, 0.0, a, a, H, E, NU)[()]) / (d * d)  # per newton
        exact = float(boussinesq_effective(r * d, 0.0, H, E, NU)[()]) if r else np.inf
        row = {"r_over_d": r, "love_per_N": love, "exact_per_N": exact}
        for name, psi in (("exact", "exact"), ("0.25", 0.25)):
            used = boussinesq_matrix(
                np.array([[r * d, 0.0]]), np.zeros((1, 2)), d * d, H, E, NU, psi
            )[0, 0]
            row[f"bc_{name}_per_N"] = float(used)
        rows.append(row)
    self_terms = {str(p): float(muscari_self(d * d, H, E, p)[()]) for p in ("exact", 0.25)}
    # Love at cell edges and corners: values on the boundary and ε inside/outside.
    edge = []
    for label, (x0, y0), (dx, dy) in (
        ("edge midpoint", (a, 0.0), (1.0, 0.0)),
        ("corner", (a, a), (1.0, 1.0)),
    ):
        for z in (0.0, H):
            on = float(love_uz(x0, y0, z, a, a, E, NU)[()])
            jumps = []
            for eps in (1e-6, 1e-9, 1e-12):
                v = love_uz(
                    np.array([x0 - eps * a * dx, x0 + eps * a * dx]),
                    np.array([y0 - eps * a * dy, y0 + eps * a * dy]),
                    z,
                    a,
                    a,
                    E,
                    NU,
                )
                jumps.append(float(abs(v[1] - v[0]) / abs(on)))
            edge.append(
                {
                    "where": label,
                    "z": z,
                    "value": on,
                    "finite": bool(np.isfinite(on)),
                    "jump_1e-6": jumps[0],
                    "jump_1e-9": jumps[1],
                    "jump_1e-12": jumps[2],
                }
            )
    return {"cell_mm": d * 1e3, "rows": rows, "self_terms": self_terms, "love_edges": edge}


def units() -> dict[str, Any]:
    pts, half = square_grid(10, 1e-3)
    taxels = pts[::7] + 3e-4
    base = love_matrix(taxels, pts, half, H, E, NU)
    bc = boussinesq_matrix(taxels, pts, 1e-6, H, E, NU)
    out: dict[str, Any] = {}
    for k in (1e-6, 1e3, 7.3e8):  # E in MPa-like, kPa-like and odd scales
        out[f"young_x{k:g}"] = float(
            np.abs(love_matrix(taxels, pts, half, H, k * E, NU) * k - base).max()
            / np.abs(base).max()
        )
    for s in (1e3, 1e-3, 37.0):  # mm, km-ish, an odd factor: u = p·L/E·f(shape) scales with L
        love_s = love_matrix(s * taxels, s * pts, s * half, s * H, E, NU)
        bc_s = boussinesq_matrix(s * taxels, s * pts, s * s * 1e-6, s * H, E, NU)
        out[f"length_x{s:g}_love"] = float(np.abs(love_s / s - base).max() / np.abs(base).max())
        out[f"length_x{s:g}_bc"] = float(np.abs(bc_s * s - bc).max() / np.abs(bc).max())
    sq = love_matrix(pts, pts, half, H, E, NU)
    k_mm = np.linalg.cond(love_matrix(1e3 * pts, 1e3 * pts, 1e3 * half, 1e3 * H, E * 1e-6, NU))
    out["kappa_si"], out["kappa_mm_mpa"] = float(np.linalg.cond(sq)), float(k_mm)
    return out


LINEAR = {"refine": "none"}


def pipelines(tmp: Path) -> dict[str, Pipeline]:
    cfgs = {
        # The linear operators alone (the default would add the round fit to them).
        "pinv": Config("pinv", "pinv", "solver", {"solver": {"method": "pinv", **LINEAR}}),
        "tikhonov": Config(
            "tikhonov", "Tikhonov", "solver", {"solver": {"method": "tikhonov", **LINEAR}}
        ),
        "nnls (1 pass)": Config("nnls", "NNLS", "solver", {"solver": {"tikhonov": 0.0}}, passes=1),
        "nnls+tikhonov (1 pass)": Config("nnls+tikh", "NNLS+Tikhonov", "solver", passes=1),
        "default (2-pass)": Config("default", "default", "default"),
        "default, float64": Config("f64", "default f64", "dtype", dtype="float64"),
        "pinv, float64": Config(
            "pinv f64",
            "pinv f64",
            "dtype",
            {"solver": {"method": "pinv", **LINEAR}},
            dtype="float64",
        ),
    }
    return {k: Pipeline(c, tmp / k.replace(" ", "_")) for k, c in cfgs.items()}


def solve(pipe: Pipeline, delta: np.ndarray) -> Any:
    """Reconstruct from compressions δ [m] through the pipeline's online path."""
    r = pipe.recon
    if pipe.nnls is None:
        return r.solve_deflection(delta)
    # _one_pass takes ΔC: invert the sensor model exactly (compression is monotonic).
    from tactile_contact.model.sensor import compression_to_delta_c

    p = r.params
    return pipe.frame(compression_to_delta_c(delta, p["thickness"], p["epsilon_r"], p["area"]))


def noise_and_precision(pipes: dict[str, Pipeline], fm: ForwardModel) -> dict[str, Any]:
    r = pipes["default (2-pass)"].recon
    inv = SvdInverse(r.forward)
    lam = float(r.params["tikhonov"])
    out: dict[str, Any] = {
        "kappa_taxels_to_cells": float(inv.condition_number),
        "null_space_dim": int(r.forward.shape[1] - r.forward.shape[0]),
        "shape": [int(k) for k in r.forward.shape],
        "pinv_Pa_per_um": float(np.linalg.norm(inv.pinv_operator(1e-3), 2) * 1e-6),
        "tikhonov_Pa_per_um": float(np.linalg.norm(inv.tikhonov_operator(lam), 2) * 1e-6),
    }
    clean = fm.compression(HertzSphere(6e-3), 1.0, r.taxel_xy[40])
    rng = np.random.default_rng(11)
    mc = []
    for sigma in (1e-6, 3e-6, 1e-5):
        noise = rng.normal(0.0, sigma, (40, len(clean)))
        for name in ("pinv", "tikhonov", "nnls+tikhonov (1 pass)", "default (2-pass)"):
            res = [solve(pipes[name], clean + n) for n in noise]
            f = np.array([x.total_force for x in res])
            cop = np.array([x.cop for x in res])
            mc.append(
                {
                    "sigma_um": sigma * 1e6,
                    "solver": name,
                    "force_mean": float(f.mean()),
                    "force_std": float(f.std()),
                    "cop_std_mm": float(np.sqrt(cop.var(axis=0).sum()) * 1e3),
                }
            )
    out["monte_carlo"] = mc
    op = inv.tikhonov_operator(lam)
    q64 = op @ clean
    q32 = (op.astype(np.float32) @ clean.astype(np.float32)).astype(np.float64)
    out["float32_product_rel"] = float(np.abs(q32 - q64).max() / np.abs(q64).max())
    for name in ("default", "pinv"):
        worst_f = worst_c = 0.0
        paths = set()
        for ind in (HertzSphere(6e-3), HertzSphere(3e-3), FlatPunch(1.5e-3)):
            for k in (3, 40, 50):
                for force in (0.5, 2.0):
                    d = fm.compression(ind, force, r.taxel_xy[k] + 1e-3)
                    a = solve(pipes["default (2-pass)" if name == "default" else name], d)
                    b = solve(pipes[f"{name}, float64"], d)
                    paths.add(a.solver)
                    if a.in_contact:
                        worst_f = max(worst_f, abs(a.total_force / b.total_force - 1))
                        worst_c = max(worst_c, float(np.hypot(*np.subtract(a.cop, b.cop))))
        out[f"float32_{name}"] = {"force_rel": worst_f, "cop_m": worst_c, "paths": sorted(paths)}
    return out


def perturbation(tmp: Path, fm: ForwardModel, xy: np.ndarray) -> list[dict[str, Any]]:
    loads = [
        (HertzSphere(6e-3), 2.0, xy[40]),
        (HertzSphere(3e-3), 1.0, (xy[19] + xy[23]) / 2),
        (FlatPunch(1.5e-3), 1.0, xy[51]),
    ]
    deltas = [fm.compression(*ld) for ld in loads]
    base = Pipeline(Config("d", "d", "default"), tmp / "base").recon
    ref = [base.solve_deflection(d) for d in deltas]
    out = []
    for key, factor in (
        ("young", 0.9),
        ("young", 1.1),
        ("thickness", 0.9),
        ("thickness", 1.1),
        ("poisson", 0.98),
        ("poisson", 0.9),
    ):
        cfg = Config(
            key,
            key,
            "elastomer",
            {"elastomer": {key: {"young": E, "thickness": H, "poisson": NU}[key] * factor}},
        )
        r = Pipeline(cfg, tmp / f"{key}{factor}").recon
        res = [r.solve_deflection(d) for d in deltas]
        out.append(
            {
                "parameter": key,
                "factor": factor,
                "force_change": [
                    a.total_force / b.total_force - 1 for a, b in zip(res, ref, strict=True)
                ],
                "cop_shift_mm": [
                    float(np.hypot(*np.subtract(a.cop, b.cop)) * 1e3)
                    for a, b in zip(res, ref, strict=True)
                ],
            }
        )
    return out


def net_force(pipes: dict[str, Pipeline], fm: ForwardModel) -> dict[str, Any]:
    r = pipes["default (2-pass)"].recon
    c = r.forward
    # A uniform pressure over the whole grid: what the taxels see, against one cell's load of
    # the same total force placed under the central taxel.
    uniform = c @ np.ones(c.shape[1])
    k = int(np.argmin(np.hypot(*(r.taxel_xy - r.taxel_xy.mean(0)).T)))
    cell = int(np.argmin(np.hypot(*(r.traction_grid.centers() - r.taxel_xy[k]).T)))
    point = c[:, cell] * c.shape[1]
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    ones = np.ones(c.shape[1]) / np.sqrt(c.shape[1])
    out: dict[str, Any] = {
        "uniform_over_point_at_centre_taxel": float(uniform[k] / point[k]),
        "uniform_in_row_space": float(np.linalg.norm(vt @ ones)),
        "rows": [],
    }
    centre = r.taxel_xy[k]
    for radius in (1.5e-3, 3e-3, 6e-3, 9e-3, 12e-3):
        d = fm.compression(FlatPunch(radius), 2.0, centre)
        row: dict[str, Any] = {
            "punch_radius_mm": radius * 1e3,
            "max_taxel_um": float(np.abs(d).max() * 1e6),
        }
        for name in (
            "pinv",
            "tikhonov",
            "nnls (1 pass)",
            "nnls+tikhonov (1 pass)",
            "default (2-pass)",
        ):
            res = solve(pipes[name], d)
            row[name] = res.total_force
        row["default_path"] = res.solver  # "free" when the free solution looked non-negative
        out["rows"].append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench")
    ap.add_argument("--quick", action="store_true", help="skip the largest grids")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="stability_"))
    t0 = time.perf_counter()
    with threadpool_limits(1):
        report: dict[str, Any] = {
            "conditioning": conditioning(args.quick),
            "psi_zero": {"d_over_h": PSI_ZERO_D_OVER_H, "rows": psi_zero()},
            "extremes": extremes(args.quick),
            "singularity": singularity(),
            "units": units(),
        }
        pipes = pipelines(tmp)
        r = pipes["default (2-pass)"].recon
        p = r.params
        fm = ForwardModel(
            r.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, p["taxel_radius"]
        )
        report["noise_precision"] = noise_and_precision(pipes, fm)
        report["perturbation"] = perturbation(tmp, fm, r.taxel_xy)
        report["net_force"] = net_force(pipes, fm)
    report["seconds"] = time.perf_counter() - t0
    (args.out / "stability.json").write_text(json.dumps(report, indent=1))
    text = render(report)
    (args.out / "stability.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
