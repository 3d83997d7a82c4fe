"""Noise amplification per solver: ‖C⁺‖₂ of pinv and Tikhonov, and the Monte-Carlo spread of
force and CoP of pinv, Tikhonov, one-pass NNLS+Tikhonov and the default.

Default patch (72 taxels → 698 cells of 2 mm): κ of the taxel matrix over its singular values
and the dimension of its null space; the operator norms of pinv (rcond 1e-3) and Tikhonov
(λ = params["tikhonov"]) in Pa per µm of taxel noise; then a 1 N 12 mm sphere over a taxel
(fine forward model, clean compressions) with 40 draws of Gaussian taxel noise at 1, 3 and
10 µm (no quantisation) through each solver.

    python bench/stability_noise.py --out docs/bench   (part of make bench)
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from benchkit.configs import pipelines
from benchkit.tables import json_report, md_table
from benchkit.truths import fine_model

from tactile_contact.inverse.solvers import SvdInverse
from tactile_contact.model.indenters import HertzSphere

SOLVERS = ["pinv", "tikhonov", "nnls+tikhonov (1 pass)", "default (2-pass)"]


def compute(args: Any) -> dict[str, Any]:
    pipes = pipelines(SOLVERS, Path(tempfile.mkdtemp(prefix="stability_noise_")))
    r = pipes["default (2-pass)"].recon
    fm = fine_model(r)
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
        for name in SOLVERS:
            res = [pipes[name].deflection(clean + n) for n in noise]
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
    return {"noise": out}


def render(rep: dict[str, Any]) -> list[str]:
    n = rep["noise"]
    k, cells = n["shape"]
    out = [
        f"Default patch: {k} taxels → {cells} cells of 2 mm.",
        "",
        f"- κ of the {k} × {cells} taxel matrix over its {k} singular values: "
        f"{n['kappa_taxels_to_cells']:.3g}; its null space has {n['null_space_dim']} "
        "dimensions (loads no inverse can see).",
        f"- ‖C⁺‖₂: pinv (rcond 1e-3) {n['pinv_Pa_per_um']:.0f} Pa per µm, Tikhonov "
        f"λ = 0.1·s₁ {n['tikhonov_Pa_per_um']:.0f} Pa per µm of taxel noise.",
        "- Monte Carlo, 1 N 12 mm sphere over a taxel, 40 draws of Gaussian taxel noise "
        "(1 count ≈ 10 µm; no quantisation):",
        "",
    ]
    out += md_table(
        ["σ [µm]", "solver", "mean force [N]", "force std [N]", "CoP std [mm]"],
        [
            [
                f"{r['sigma_um']:g}",
                r["solver"],
                f"{r['force_mean']:.3f}",
                f"{r['force_std']:.3f}",
                f"{r['cop_std_mm']:.3f}",
            ]
            for r in n["monte_carlo"]
        ],
    )
    return out


if __name__ == "__main__":
    json_report(__doc__, "stability_noise", compute, render)
