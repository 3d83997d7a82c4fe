"""The dense online product of a linear inverse operator in float32 against float64: time per
product and relative error.

The NNLS benches' problems (bench/bench_nnls.py, :mod:`benchkit.layer`): the default patch's
72 taxels and a square problem of 600 measurement points on the 24 × 25 grid of 2.5 mm Love
cells; operators pinv (rcond 1e-10) and Tikhonov (λ = 0.1·s₁); the vector is frame 10 of the
sliding 12 mm sphere. Time per product: the mean of ``count`` products into a preallocated
output (20 000 for the taxel problem, 2 000 for the square one; ``--quick``: a tenth).

    python bench/bench_products.py [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from benchkit.layer import NU, PITCH, E, H, cell_grid, hexagon_taxels, sliding_sphere

from tactile_contact.inverse.solvers import SvdInverse
from tactile_contact.model.elastic import love_matrix


def products(label: str, a: np.ndarray, d: np.ndarray, count: int) -> None:
    """Print the float64 and float32 times [µs] of pinv and Tikhonov products with ``d``."""
    inv = SvdInverse(a)
    for name, op in (
        ("pinv", inv.pinv_operator(1e-10)),
        ("tikhonov", inv.tikhonov_operator(0.1 * inv.singular_values[0])),
    ):
        op32, d32 = op.astype(np.float32), d.astype(np.float32)
        times = {}
        for dtype, mat, vec in (("float64", op, d), ("float32", op32, d32)):
            out = np.empty(mat.shape[0], dtype=mat.dtype)
            t0 = time.perf_counter()
            for _ in range(count):
                np.matmul(mat, vec, out=out)
            times[dtype] = (time.perf_counter() - t0) / count
        ref = op @ d
        rel = np.abs(op32 @ d32 - ref).max() / np.abs(ref).max()
        print(
            f"{label:8s} {name:9s} {op.shape[0]:4d}×{op.shape[1]:<4d} "
            f"{times['float64'] * 1e6:9.2f} {times['float32'] * 1e6:9.2f} "
            f"{times['float64'] / times['float32']:7.2f} {rel:10.1e}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer product repetitions")
    args = ap.parse_args()
    taxels = hexagon_taxels()
    centers = cell_grid(taxels)
    half = np.full(2, PITCH / 2)
    a_tax = love_matrix(taxels, centers, half, H, E, NU)
    a_sq = love_matrix(centers, centers, half, H, E, NU)
    d_tax = sliding_sphere(taxels, taxels, 1)[10]
    d_sq = sliding_sphere(centers, taxels, 2)[10]
    print(
        f"{'problem':8s} {'operator':9s} {'shape':9s} {'f64 µs':>9s} {'f32 µs':>9s} "
        f"{'ratio':>7s} {'f32 rel err':>10s}"
    )
    count = 2000 if args.quick else 20000
    products("taxels", a_tax, d_tax, count)
    products("square", a_sq, d_sq, count // 10)


if __name__ == "__main__":
    main()
