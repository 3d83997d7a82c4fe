"""Run time against error over model, grid, measurement mode, solver, dtype and noise.

    python bench/tradeoff.py --out docs/bench [--quick] [--replot]      (make bench / bench-quick)

The paper's protocol in simulation: 12 mm and 6 mm half-spheres, 12 mm and 3 mm flat cylinders
× over a taxel / between two / between three (two modules) × 0.2, 0.5, 1, 1.8, 2.5, 3 N. The
truth is the independent fine forward model (:class:`tactile_contact.model.forward.ForwardModel`:
0.25 mm cells, electrode average, exact capacitance); then noise, 8-bit quantisation, and for
the ``+offsets`` levels a fixed per-taxel baseline offset of up to ±½ count, as a real driver's
baseline (a mean of quantised samples) leaves. Noisy levels are repeated with 3 noise seeds.

Design: one factor at a time around the default (config/hexagon_patch.yaml: Love, 2 mm cells,
taxel measurements, two-pass NNLS + Tikhonov, float32 online products) plus the paper's methods
and a few interesting pairs (CONFIGS). Per configuration: offline build time and peak traced
memory, online time per patch frame (ΔC in → traction, deflection and summary out; median and
p99, warm, one BLAS thread as in the node), and errors against the truth: total force
(relative), CoP [mm], contact-area IoU, relative L2 of the traction (vs the exact cell averages
of the true pressure) and of the deflection (both through the bundle's deflection operator).
Undetected contacts count as 100 % force error, 99 mm CoP error, IoU 0, L2 1.

Writes ``results.json``, ``tradeoff.png`` (online time against force and CoP error, Pareto
front per noise level marked) and ``tradeoff.md``; ``--replot`` redraws the last two from the
JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from benchkit import ROOT
from benchkit.configs import Config, Pipeline
from benchkit.protocol import FORCES, INDENTERS, PLACES, positions
from benchkit.readings import quantised
from benchkit.stats import iou
from benchkit.truths import fine_model
from threadpoolctl import threadpool_limits
from tradeoff_report import render

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.sensor import value_count_farad

PINV = {"solver": {"method": "pinv", "refine": "none"}}
TIKH = {"solver": {"method": "tikhonov", "refine": "none"}}
NONE = {"solver": {"refine": "none"}}
BC025 = {"model": {"kind": "boussinesq", "psi": 0.25}}
CONFIGS = [
    Config(
        "default", "default: Love, 2 mm, taxels, 2-pass NNLS+Tikhonov, round fit, f32", "default"
    ),
    Config("BC exact", "B-C, Ψ exact", "model", {"model": {"kind": "boussinesq"}}),
    Config("BC 0.25", "B-C, Ψ = 0.25", "model", BC025),
    Config("1 mm", "1 mm cells", "cell", {"grid": {"traction_cell": 0.001}}),
    Config("3 mm", "3 mm cells", "cell", {"grid": {"traction_cell": 0.003}}),
    Config("4 mm", "4 mm cells", "cell", {"grid": {"traction_cell": 0.004}}),
    Config("grid", "interpolated grid, default solver", "measurement", mode="grid"),
    Config("pinv", "pinv (rcond 1e-3)", "solver", PINV),
    Config("tikhonov", "Tikhonov λ 0.1·s₁ (free)", "solver", TIKH),
    Config(
        "tsvd",
        "TSVD rank 20",
        "solver",
        {"solver": {"method": "tsvd", "tsvd_rank": 20, "refine": "none"}},
    ),
    Config(
        "nnls", "NNLS, 1 pass", "solver", {"solver": {"tikhonov": 0.0, "refine": "none"}}, passes=1
    ),
    Config("nnls+tikh", "NNLS+Tikhonov λ 0.1, 1 pass", "solver", NONE, passes=1),
    Config("grid only", "2-pass NNLS+Tikhonov, no round fit (former default)", "solver", NONE),
    Config("f64", "default, float64 products", "dtype", dtype="float64"),
    Config("pinv f64", "pinv, float64 products", "dtype", PINV, dtype="float64"),
    Config("grid+pinv", "paper: Love, interpolated grid, pinv", "pair", PINV, mode="grid"),
    Config(
        "grid+BC+pinv",
        "paper: B-C Ψ 0.25, interpolated grid, pinv",
        "pair",
        {**BC025, **PINV},
        mode="grid",
    ),
    Config("grid+tikh", "interpolated grid, Tikhonov", "pair", TIKH, mode="grid"),
    Config("4 mm+tikh", "4 mm cells, Tikhonov", "pair", {"grid": {"traction_cell": 0.004}, **TIKH}),
    Config(
        "BC exact 4 mm",
        "B-C Ψ exact, 4 mm cells (Ψ ≈ 0)",
        "pair",
        {"model": {"kind": "boussinesq"}, "grid": {"traction_cell": 0.004}},
    ),
    Config(
        "BC 0.25 3 mm",
        "B-C Ψ 0.25, 3 mm cells",
        "pair",
        {**BC025, "grid": {"traction_cell": 0.003}},
    ),
]
QUICK = ("default", "grid only", "BC 0.25", "grid+pinv", "pinv", "f64")
#: name → (noise RMS [counts], baseline offsets ±½ count?)
NOISE = {
    "none": (0.0, False),
    "0.15 count": (0.15, False),
    "0.15 count +offsets": (0.15, True),
    "0.3 count +offsets": (0.3, True),
}
QUICK_NOISE = ("0.15 count +offsets",)
REPEATS = 3


def truth(recon: Reconstructor, forces: tuple[float, ...], modules: tuple[int, ...]) -> list:
    """(indenter, position name, force [N], centre [m], contact radius [m], exact ΔC [F])."""
    p = recon.params
    fm = fine_model(recon)
    return [
        (
            ind,
            pname,
            f,
            c,
            ind.contact_radius(f, p["young"], p["poisson"]),
            fm.delta_c(ind, f, c, p["epsilon_r"]),
        )
        for ind in INDENTERS.values()
        for pname, c in positions(recon.taxel_xy, modules)
        for f in forces
    ]


def noisy(cases: list, lsb: float, rms: float, offsets: bool, seed: int) -> list:
    """Cases with Gaussian noise of ``rms`` counts, 8-bit quantisation (``lsb`` [F] per count)
    and, if ``offsets``, a fixed per-taxel baseline offset uniform in ±½ count."""
    rng = np.random.default_rng(seed)
    out = []
    offset = rng.uniform(-0.5, 0.5, cases[0][5].shape) * lsb if offsets else 0.0
    for ind, pname, f, c, a, dc in cases:
        out.append((ind, pname, f, c, a, quantised(dc, lsb, rms, rng) + offset))
    return out


def evaluate(pipe: Pipeline, cases: list, taxel_recon: Reconstructor) -> dict[str, float]:
    """Online time and error statistics of one configuration over ``cases``.

    The frames run back to back first and only they are timed (warm caches, as a node working
    through a stream); the errors are computed afterwards."""
    recon = pipe.recon
    pipe.frame(cases[-1][5])  # warm: first-frame caches
    m: dict[str, list[float]] = {k: [] for k in ("t", "solve", "f", "cop", "iou", "l2t", "l2d")}
    results = []
    for case in cases:
        t0 = time.perf_counter()
        res = pipe.frame(case[5])
        m["t"].append(time.perf_counter() - t0)
        results.append(res)
    grid = recon.traction_grid
    centres, halves = grid.centers(), grid.half_sizes()
    g_out = np.asarray(recon.bundle["deflection_operator"], dtype=np.float64)
    p = taxel_recon.params
    seen = []
    for (ind, _, f, c, a, _), res in zip(cases, results, strict=True):
        m["solve"].append(res.solve_time)
        true_q = ind.pressure_on_cells(centres, halves, f, c, p["young"], p["poisson"])
        est_q = res.traction[grid.mask] if res.in_contact else np.zeros_like(true_q)
        m["l2t"].append(np.linalg.norm(est_q - true_q) / np.linalg.norm(true_q))
        true_d = g_out @ true_q
        m["l2d"].append(np.linalg.norm(g_out @ est_q - true_d) / np.linalg.norm(true_d))
        m["f"].append(abs(res.total_force / f - 1.0) * 100.0 if res.in_contact else 100.0)
        m["cop"].append(
            float(np.hypot(*(np.asarray(res.cop) - c))) * 1e3 if res.in_contact else 99.0
        )
        m["iou"].append(iou(res, grid, c, a))
        seen.append(res.in_contact)
    t, solve = np.asarray(m["t"]) * 1e3, np.asarray(m["solve"]) * 1e3

    def med(k: str) -> float:
        return float(np.median(m[k]))

    def p90(k: str) -> float:
        return float(np.percentile(m[k], 90))

    return {
        "frames": len(cases),
        "online_ms_median": float(np.median(t)),
        "online_ms_p99": float(np.percentile(t, 99)),
        "solve_ms_median": float(np.median(solve)),
        "force_err_pct_median": med("f"),
        "force_err_pct_p90": p90("f"),
        "cop_mm_median": med("cop"),
        "cop_mm_p90": p90("cop"),
        "iou_median": med("iou"),
        "l2_traction_median": med("l2t"),
        "l2_deflection_median": med("l2d"),
        "detected": float(np.mean(seen)),
    }


def describe(cfg: Config, recon: Reconstructor) -> dict[str, Any]:
    p = recon.params
    model = "Love" if p["model"] == "love" else f"B-C Ψ {p['psi']}"
    solver = {
        "nnls_tikhonov": "2-pass NNLS+Tikhonov",
        "pinv": "pinv",
        "tikhonov": "Tikhonov",
        "tsvd": "TSVD",
    }[p["method"]]
    if cfg.passes == 1:
        solver = "NNLS" if p["tikhonov"] == 0 else "NNLS+Tikhonov"
    if p.get("refine") == "round":
        solver += " + round fit"
    return {
        "key": cfg.key,
        "config": cfg.name,
        "factor": cfg.factor,
        "model": model,
        "cell_mm": p["traction_cell"] * 1e3,
        "measurement": cfg.mode,
        "solver": solver,
        "dtype": cfg.dtype,
        "cells": int(recon.traction_grid.n_cells),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench")
    ap.add_argument("--quick", action="store_true", help="6 configurations, 1 noise, 36 cases")
    ap.add_argument("--replot", action="store_true", help="redraw from OUT/results.json")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        render(json.loads((args.out / "results.json").read_text()), args.out)
        return
    configs = [c for c in CONFIGS if not args.quick or c.key in QUICK]
    noises = QUICK_NOISE if args.quick else tuple(NOISE)
    forces = (0.5, 1.0, 3.0) if args.quick else FORCES
    modules = (4,) if args.quick else (4, 2)
    repeats = 1 if args.quick else REPEATS
    tmp = Path(tempfile.mkdtemp(prefix="tradeoff_"))
    t_start = time.perf_counter()
    rows: list[dict[str, Any]] = []
    exact: list = []
    taxel_recon: Reconstructor | None = None
    # One BLAS thread, as the reconstruction node runs (threads spin between small products).
    with threadpool_limits(1):
        for i, cfg in enumerate(configs):
            pipe = Pipeline(cfg, tmp / f"c{i}")
            if taxel_recon is None:
                taxel_recon = pipe.recon  # the default's taxel order and parameters
                t0 = time.perf_counter()
                exact = truth(taxel_recon, forces, modules)
                print(f"truth: {len(exact)} cases in {time.perf_counter() - t0:.0f} s")
            lsb = value_count_farad(
                taxel_recon.params["farad_per_count"], taxel_recon.params["shift"]
            )
            for noise in noises:
                rms, offsets = NOISE[noise]
                reps = 1 if rms == 0 and not offsets else repeats
                cases = [c for s in range(reps) for c in noisy(exact, lsb, rms, offsets, 7 + s)]
                r = evaluate(pipe, cases, taxel_recon)
                rows.append(
                    {
                        **describe(cfg, pipe.recon),
                        "noise": noise,
                        "build_s": pipe.build_s,
                        "build_mb": pipe.build_mb,
                        **r,
                    }
                )
                print(
                    f"{cfg.key:14s} {noise:20s} build {pipe.build_s:5.2f} s "
                    f"{pipe.build_mb:5.0f} MB | {r['online_ms_median']:6.2f} ms | force "
                    f"{r['force_err_pct_median']:5.1f} % | CoP {r['cop_mm_median']:5.2f} mm | "
                    f"IoU {r['iou_median']:.2f}",
                    flush=True,
                )
    results = {
        "protocol": {
            "indenters": list(INDENTERS),
            "forces_N": list(forces),
            "positions": list(PLACES),
            "modules": list(modules),
            "repeats_noisy": repeats,
            "cases": len(exact),
        },
        "machine": f"{platform.machine()}, {platform.python_version()}, one BLAS thread",
        "quick": args.quick,
        "seconds": time.perf_counter() - t_start,
        "rows": rows,
    }
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    render(results, args.out)
    print(f"wrote {args.out}/results.json, tradeoff.png, tradeoff.md in {results['seconds']:.0f} s")


if __name__ == "__main__":
    main()
