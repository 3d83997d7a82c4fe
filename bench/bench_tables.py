"""Cost of the round-contact response tables (round_contact.radial_responses) against the
whole-grid product they replaced, on the calls the calibration and the bundle build make.

Each profile's reading at distance r is a disc average of the deflection field of its cell
pressures. The baseline pushes those pressures through the regular-grid operator over the
whole square grid (a (2n)² FFT per profile, n ≈ 2·(reach + footprint)/cell: what
radial_responses did before); radial_responses convolves the contact's block of cells with the
kernel only over the strip of cells its samples read, and caches each contact's cell pressures
(a polish trial's contacts are new: "cold"; the Jacobian's layer step asks for the same
contacts at another thickness: "warm"). Both are run alternately (the same background load)
and must agree to 1e-12 of the largest reading before anything is timed.

    .venv/bin/python bench/bench_tables.py [--out docs/bench]     # about a minute
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import scipy.ndimage
from benchkit.tables import Report, md_table
from benchkit.timing import paired_best

from tactile_contact.inverse import round_contact as rc
from tactile_contact.model.elastic import regular_grid_operator
from tactile_contact.model.grids import disc_quadrature
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import load_layout
from tactile_contact.model.layout_spec import Elastomer
from tactile_contact.offline.calibrate import REACH

ROOT = Path(__file__).resolve().parents[1]


def whole_grid(
    h: float,
    young: float,
    nu: float,
    feet: list[float],
    profiles: list[tuple[int, float]],
    reach: float,
    step: float,
    cell: float = 1e-4,
) -> np.ndarray:
    """The baseline: every profile's field on the whole (n × n) grid by the operator's FFT
    product, then the same 8 × 24-point disc average (bilinear) as radial_responses."""
    dist = np.arange(round(reach / step) + 1) * step
    n = 2 * math.ceil((reach + max(feet) + 2 * cell) / cell) + 1
    op = regular_grid_operator(n, n, cell, cell, h, young, nu)
    coords = (np.arange(n) - n // 2) * cell
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    centers = np.column_stack((gx.ravel(), gy.ravel()))
    box = np.abs(centers).max(axis=1)
    out = np.empty((len(profiles), len(feet), len(dist)))
    for k, (fi, a) in enumerate(profiles):
        shape = (
            FlatPunch(a)
            if rc.FAMILIES[fi] == "punch"
            else HertzSphere.with_contact_radius(a, 1.0, young, nu)
        )
        near = box <= a + cell
        p = np.zeros(len(centers))
        p[near] = shape.pressure_on_cells(
            centers[near], np.full(2, cell / 2), 1.0, (0, 0), young, nu
        )
        field = op.matvec(p).reshape(n, n)
        for m, r in enumerate(feet):
            q, w = disc_quadrature(float(r), 8, 24)
            px = (dist[:, None] + q[None, :, 0]) / cell + n // 2
            py = np.broadcast_to(q[None, :, 1] / cell + n // 2, px.shape)
            vals = scipy.ndimage.map_coordinates(field, [px.ravel(), py.ravel()], order=1)
            out[k, m] = vals.reshape(px.shape) @ w
    return out


def row(
    label: str,
    e: Elastomer,
    profiles: list[tuple[int, float]],
    feet: list[float],
    reach: float,
    step: float,
) -> list[str]:
    """One case's table row: per-profile times [ms] of the baseline and ours (cold, warm)."""

    def ours() -> np.ndarray:
        return rc.radial_responses(
            e.thickness, e.young, e.poisson, feet, profiles, reach=reach, step=step
        )

    def cold() -> np.ndarray:
        rc._cell_pressures.cache_clear()
        return ours()

    def base() -> np.ndarray:
        return whole_grid(e.thickness, e.young, e.poisson, feet, profiles, reach, step)

    ref, got = base(), cold()
    err = float(np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
    assert err < 1e-12, (label, err)
    t_base, t_cold = paired_best(base, cold, budget=2.0)
    ours()  # (the cache filled)
    _, t_warm = paired_best(base, ours, budget=0.0)
    per = 1e3 / len(profiles)
    return [
        label,
        f"{t_base * per:.2f}",
        f"{t_cold * per:.2f}",
        f"{t_warm * per:.2f}",
        f"{t_base / t_cold:.1f}x",
        f"{t_base / t_warm:.1f}x",
        f"{err:.1e}",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, help="write tables.md into this folder")
    args = ap.parse_args()
    patch = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0]
    e, foot = patch.elastomer, patch.footprint
    rng = np.random.default_rng(5)
    presses = [
        (int(f), float(a))
        for f, a in zip(rng.integers(0, 2, 48), rng.uniform(1e-3, 4e-3, 48), strict=True)
    ]
    cases = [
        (
            "calibration: 48 presses' contacts, 2 footprints",
            presses,
            [foot, math.hypot(foot, 3.2e-4)],
            REACH + 2e-4,
            1e-4,
        ),
        (
            "bundle build: 128 profiles 0.4-9.6 mm, footprint",
            [(f, a) for f in (0, 1) for a in rc.DEFAULT_RADII],
            [foot],
            0.02,
            rc.TABLE_STEP,
        ),
    ]
    rep = Report()
    rep(
        f"hexagon patch: layer {e.thickness * 1e3:.2f} mm, E {e.young:.3g} Pa, nu {e.poisson}, "
        f"footprint {foot * 1e3:.2f} mm; times are the best of alternate runs"
    )
    rows = [row(label, e, *case) for label, *case in cases]
    head = [
        "call",
        "whole grid ms/profile",
        "ours cold",
        "ours warm",
        "speed-up cold",
        "warm",
        "max diff / max",
    ]
    for line in md_table(head, rows):
        rep(line)
    if args.out:
        rep.write(
            args.out,
            "tables.md",
            "Round-contact response tables: cost against the whole-grid product",
            "python bench/bench_tables.py --out docs/bench",
        )


if __name__ == "__main__":
    main()
