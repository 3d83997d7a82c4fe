"""Warm-started NNLS (block principal pivoting, FISTA; warm and cold) against
scipy.optimize.nnls on a moving indenter (issue 7 target: ≥ 5×).

Two problems on a 24 × 25 grid of 2.5 mm Love cells (N = 600) covering the default hexagonal
patch (six roboskin12 modules, h = 2 mm, E = 2.1e5 Pa, ν = 0.5; :mod:`benchkit.layer`):

- ``taxels``: K = 72 taxel centres (under-determined, the real case);
- ``square``: K = N = 600 measurement points at the cell centres.

A 12 mm sphere pressing 1 N slides along the patch diagonal in 20 frames; compressions come
from the independent fine forward model (tactile_contact.model.forward) plus 1 µm Gaussian noise
(seeded). Every solver minimises ‖A·x − d‖² + λ²‖L·x‖², x ≥ 0 with the same λ = 0.1·‖A‖₂ and
L = I (and, for the taxel problem, also L = Dirichlet grid Laplacian). scipy's Lawson–Hanson
runs cold on the stacked system [A; λL] (it has no warm start); ours run warm (from the
previous frame) and cold. Times are per frame, best of ``reps`` passes over the stream. The
dense online products: bench/bench_products.py.

    python bench/bench_nnls.py [--quick]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import scipy.optimize
from benchkit.layer import NU, PITCH, SHAPE, E, H, cell_grid, hexagon_taxels, sliding_sphere

from tactile_contact.inverse.solvers import NnlsSolver, grid_laplacian
from tactile_contact.model.elastic import love_matrix


def run(fn: Callable[[np.ndarray], tuple[np.ndarray, int]], data: list[np.ndarray], reps: int):
    """Per-frame times of the best pass, the solutions and the iterations of the last pass."""
    best = None
    for _ in range(reps):
        times, xs, its = [], [], []
        for d in data:
            t0 = time.perf_counter()
            x, it = fn(d)
            times.append(time.perf_counter() - t0)
            xs.append(x)
            its.append(it)
        t = np.asarray(times)
        if best is None or np.median(t) < np.median(best[0]):
            best = (t, xs, its)
    return best


def compare(label: str, a: np.ndarray, ell: np.ndarray | None, data: list, reps: int) -> dict:
    n = a.shape[1]
    lam = 0.1 * np.linalg.norm(a, 2)
    stacked = np.vstack([a, lam * (np.eye(n) if ell is None else ell)])
    pad = np.zeros(stacked.shape[0] - a.shape[0])

    def scipy_cold(d: np.ndarray) -> tuple[np.ndarray, int]:
        return scipy.optimize.nnls(stacked, np.concatenate([d, pad]), maxiter=50 * n)[0], 0

    rows = {"scipy.optimize.nnls (cold)": run(scipy_cold, data, max(1, reps // 2))}
    for method in ("bpp", "fista"):
        for warm in (True, False):
            s = NnlsSolver(a, tikhonov=lam, regulariser=ell, method=method).prepare()

            def solve(d: np.ndarray, s: NnlsSolver = s, w: bool = warm) -> tuple[np.ndarray, int]:
                r = s.solve(d, warm_start=w)
                if not r.success:
                    raise RuntimeError(f"{s.method} failed: {r.message}")
                return r.x, r.iterations

            rows[f"{method} {'warm' if warm else 'cold'}"] = run(solve, data, reps)
    base_t, base_x, _ = rows["scipy.optimize.nnls (cold)"]
    print(f"\n{label}: K = {a.shape[0]}, N = {n}, λ = 0.1·‖A‖₂, {len(data)} frames")
    print(
        f"{'solver':28s} {'median ms':>10s} {'p99 ms':>8s} {'speed-up':>9s} "
        f"{'p99 ratio':>9s} {'iter':>6s} {'max rel Δx':>11s}"
    )
    out = {}
    for name, (t, xs, its) in rows.items():
        diff = max(
            np.abs(x - b).max() / max(np.abs(b).max(), 1e-300)
            for x, b in zip(xs, base_x, strict=True)
        )
        speed = np.median(base_t) / np.median(t)
        p99 = np.percentile(base_t, 99) / np.percentile(t, 99)
        print(
            f"{name:28s} {np.median(t) * 1e3:10.3f} {np.percentile(t, 99) * 1e3:8.3f} "
            f"{speed:9.1f} {p99:9.1f} {np.mean(its):6.1f} {diff:11.2e}"
        )
        out[name] = speed
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one pass over the stream")
    args = ap.parse_args()
    reps = 1 if args.quick else 3
    taxels = hexagon_taxels()
    centers = cell_grid(taxels)
    half = np.full(2, PITCH / 2)
    a_tax = love_matrix(taxels, centers, half, H, E, NU)
    a_sq = love_matrix(centers, centers, half, H, E, NU)
    data_tax, data_sq = sliding_sphere(taxels, taxels, 1), sliding_sphere(centers, taxels, 2)
    lap = grid_laplacian(SHAPE)
    speed = compare("taxels, L = I", a_tax, None, data_tax, reps)
    compare("taxels, L = Dirichlet Laplacian", a_tax, lap, data_tax, reps)
    compare("square (K = N), L = I", a_sq, None, data_sq, reps)
    target = speed["bpp warm"]
    print(f"\nwarm-started bpp vs scipy.optimize.nnls (taxels, L = I): {target:.1f}× (target ≥ 5×)")


if __name__ == "__main__":
    main()
