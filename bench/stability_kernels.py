"""Kernel values near the B-C point-force singularity and on Love cell edges and corners,
against the Love cell integral (finite, continuous).

Effective deflection per newton at distance r from a load on 2 mm cells: the Love cell (the
load spread uniformly over the cell, the reference), the exact point-force kernel (∞ at r = 0)
and what the B-C matrix uses (the smaller magnitude of the exact value and the Muscari self
term, Ψ exact and Ψ = 0.25); then Love u_z on a cell's edge midpoint and corner, at the surface
and at depth h, with the relative jump between points ε·a inside and outside.

    python bench/stability_kernels.py --out docs/bench   (part of make bench)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from benchkit.layer import NU, E, H
from benchkit.tables import json_report, md_table

from tactile_contact.model.elastic import (
    boussinesq_effective,
    boussinesq_matrix,
    love_effective,
    love_uz,
    muscari_self,
)


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


def compute(args: Any) -> dict[str, Any]:
    return {"singularity": singularity()}


def render(rep: dict[str, Any]) -> list[str]:
    sg = rep["singularity"]
    out = [
        f"## Near the B-C singularity ({sg['cell_mm']:g} mm cells)",
        "",
        "Effective deflection per newton at distance r from a load: the Love cell (the load "
        "spread uniformly over the cell, the reference), the exact point-force kernel (∞ at "
        "r = 0), and what the B-C matrix uses (the smaller magnitude of the exact value and "
        f"the Muscari self term: {sg['self_terms']['exact']:.3e} m/N with Ψ exact, "
        f"{sg['self_terms']['0.25']:.3e} m/N with Ψ 0.25).",
        "",
    ]
    out += md_table(
        [
            "r/d",
            "Love cell [m/N]",
            "exact point [m/N]",
            "B-C Ψ exact",
            "B-C Ψ 0.25",
            "B-C Ψ exact / Love",
        ],
        [
            [
                f"{r['r_over_d']:g}",
                f"{r['love_per_N']:.3e}",
                f"{r['exact_per_N']:.3e}",
                f"{r['bc_exact_per_N']:.3e}",
                f"{r['bc_0.25_per_N']:.3e}",
                f"{r['bc_exact_per_N'] / r['love_per_N']:.2f}",
            ]
            for r in sg["rows"]
        ],
    )
    out += [
        "",
        "## Love cell edges and corners",
        "",
        "Love u_z on a cell's boundary (value there, and relative jump between points "
        "ε·a inside and outside):",
        "",
    ]
    out += md_table(
        ["where", "z [m]", "u_z [m/Pa]", "finite", "jump ε=1e-6", "ε=1e-9", "ε=1e-12"],
        [
            [
                r["where"],
                f"{r['z']:g}",
                f"{r['value']:.4e}",
                str(r["finite"]),
                f"{r['jump_1e-6']:.1e}",
                f"{r['jump_1e-9']:.1e}",
                f"{r['jump_1e-12']:.1e}",
            ]
            for r in sg["love_edges"]
        ],
    )
    return out


if __name__ == "__main__":
    json_report(__doc__, "stability_kernels", compute, render)
