"""Model perturbation: the force and CoP a bundle built with E, h or ν off by a few per cent
reconstructs, against the unperturbed bundle's, the truth fixed.

Loads (fine forward model, clean compressions): 2 N 12 mm sphere over a taxel; 1 N 6 mm sphere
between two; 1 N 3 mm punch over a taxel. Bundles: the default with E × 0.9 / 1.1, h × 0.9 /
1.1, ν × 0.98 / 0.9.

    python bench/stability_perturbation.py --out docs/bench   (part of make bench)
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from benchkit.configs import Config, Pipeline
from benchkit.layer import NU, E, H
from benchkit.tables import json_report, md_table
from benchkit.truths import fine_model

from tactile_contact.model.indenters import FlatPunch, HertzSphere


def compute(args: Any) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="stability_perturbation_"))
    base = Pipeline(Config("d", "d", "default"), tmp / "base", measure=False).recon
    fm, xy = fine_model(base), base.taxel_xy
    loads = [
        (HertzSphere(6e-3), 2.0, xy[40]),
        (HertzSphere(3e-3), 1.0, (xy[19] + xy[23]) / 2),
        (FlatPunch(1.5e-3), 1.0, xy[51]),
    ]
    deltas = [fm.compression(*ld) for ld in loads]
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
        r = Pipeline(cfg, tmp / f"{key}{factor}", measure=False).recon
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
    return {"perturbation": out}


def render(rep: dict[str, Any]) -> list[str]:
    out = [
        "Change against the unperturbed model. Loads: 2 N 12 mm sphere over a taxel; 1 N 6 mm "
        "sphere between two; 1 N 3 mm punch over a taxel.",
        "",
    ]
    out += md_table(
        ["model parameter", "force change", "CoP shift [mm]"],
        [
            [
                f"{r['parameter']} × {r['factor']:g}",
                " / ".join(f"{v * 100:+.1f} %" for v in r["force_change"]),
                " / ".join(f"{v:.3f}" for v in r["cop_shift_mm"]),
            ]
            for r in rep["perturbation"]
        ],
    )
    return out


if __name__ == "__main__":
    json_report(__doc__, "stability_perturbation", compute, render)
