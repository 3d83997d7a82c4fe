"""Unit neutrality: the rescaled Love and B-C matrices against their exact scaling.

E rescaled by 1e-6, 1e3 and 7.3e8 (C ∝ 1/E) and every length by 1e3, 1e-3 and 37 (C_Love ∝ L,
B-C per force ∝ 1/L) on a 10² grid of 1 mm cells read at every seventh cell; the largest
relative deviation from the exact scaling, and κ of a square 10² Love problem in SI and in mm
and MPa.

    python bench/stability_units.py --out docs/bench   (part of make bench)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from benchkit.layer import NU, E, H, square_grid
from benchkit.tables import json_report, md_table

from tactile_contact.model.elastic import boussinesq_matrix, love_matrix


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


def compute(args: Any) -> dict[str, Any]:
    return {"units": units()}


def render(rep: dict[str, Any]) -> list[str]:
    u = rep["units"]
    out = [
        "Largest relative deviation of the rescaled matrix from the exact scaling (C ∝ 1/E, "
        "C_Love ∝ L, B-C per force ∝ 1/L):",
        "",
    ]
    out += md_table(
        ["rescaling", "deviation"],
        [[k, f"{v:.1e}"] for k, v in u.items() if not k.startswith("kappa")],
    )
    out += [
        "",
        f"κ of a 10² Love problem in SI: {u['kappa_si']:.6f}; in mm and MPa: "
        f"{u['kappa_mm_mpa']:.6f}.",
    ]
    return out


if __name__ == "__main__":
    json_report(__doc__, "stability_units", compute, render)
