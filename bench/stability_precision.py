"""float32 against float64 online products: the free product alone, and the whole
reconstruction (default and pinv) with the float32 operator against the float64 one.

The free product C⁺·δ (Tikhonov operator of the default patch) of a 1 N 12 mm sphere over a
taxel in float32 against float64 (relative, max-norm); then 18 loads (12 mm and 6 mm spheres,
3 mm punch × 3 places × 0.5 and 2 N, fine forward model) through the default and pinv
configurations with the library's float32 operator and with the float64 one swapped in:
largest force (relative) and CoP difference, and the paths taken.

    python bench/stability_precision.py --out docs/bench   (part of make bench)
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from benchkit.configs import pipelines
from benchkit.tables import json_report
from benchkit.truths import fine_model

from tactile_contact.inverse.solvers import SvdInverse
from tactile_contact.model.indenters import FlatPunch, HertzSphere

SOLVERS = ["default (2-pass)", "default, float64", "pinv", "pinv, float64"]


def compute(args: Any) -> dict[str, Any]:
    pipes = pipelines(SOLVERS, Path(tempfile.mkdtemp(prefix="stability_precision_")))
    r = pipes["default (2-pass)"].recon
    fm = fine_model(r)
    inv = SvdInverse(r.forward)
    lam = float(r.params["tikhonov"])
    clean = fm.compression(HertzSphere(6e-3), 1.0, r.taxel_xy[40])
    out: dict[str, Any] = {}
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
                    a = pipes["default (2-pass)" if name == "default" else name].deflection(d)
                    b = pipes[f"{name}, float64"].deflection(d)
                    paths.add(a.solver)
                    if a.in_contact:
                        worst_f = max(worst_f, abs(a.total_force / b.total_force - 1))
                        worst_c = max(worst_c, float(np.hypot(*np.subtract(a.cop, b.cop))))
        out[f"float32_{name}"] = {"force_rel": worst_f, "cop_m": worst_c, "paths": sorted(paths)}
    return {"precision": out}


def render(rep: dict[str, Any]) -> list[str]:
    n = rep["precision"]
    return [
        f"- Free product C⁺·δ in float32: {n['float32_product_rel']:.1e} relative (max-norm).",
        "- Whole reconstruction, float32 against float64 free operator, 18 loads (largest "
        "difference): "
        + "; ".join(
            f"{k} (paths {', '.join(v['paths'])}): force {v['force_rel']:.1e} relative, CoP "
            f"{v['cop_m']:.1e} m"
            for k, v in (("default", n["float32_default"]), ("pinv", n["float32_pinv"]))
        )
        + ". The NNLS runs in float64 either way (the float32 product only decides whether "
        "it runs); the deflection product is float32 in the library whatever the bench sets.",
    ]


if __name__ == "__main__":
    json_report(__doc__, "stability_precision", compute, render)
