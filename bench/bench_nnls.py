"""Warm-started NNLS against scipy.optimize.nnls on a moving indenter (issue 7 target: ≥ 5×).

The default hexagon patch (72 taxels) with a 2 mm traction grid (≈ 570 cells), a 12 mm sphere
pressing 1 N and sliding across the patch in 20 frames; compressions from the independent fine
forward model. Every solver minimises ‖A·x − d‖² + λ²‖x‖², x ≥ 0 with the same λ; scipy's
Lawson–Hanson runs cold on the stacked system [A; λI] (it has no warm start), ours warm-start
from the previous frame. Also times the float32 and float64 online products of a dense
linear inverse operator.

    python bench/bench_nnls.py [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import scipy.optimize

from tactile_contact.build import grids_for, taxel_matrix
from tactile_contact.forward import ForwardModel
from tactile_contact.indenters import HertzSphere
from tactile_contact.layout import load_layout
from tactile_contact.solvers import NnlsSolver, SvdInverse

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"


def frames(patch: object, count: int) -> list[np.ndarray]:
    e = patch.elastomer  # type: ignore[attr-defined]
    xy = patch.taxel_xy()  # type: ignore[attr-defined]
    model = ForwardModel(xy, e.thickness, e.young, e.poisson)
    lo, hi = xy.min(0) + 4e-3, xy.max(0) - 4e-3
    path = np.linspace(lo, hi, count)
    return [model.compression(HertzSphere(radius=6e-3), 1.0, c) for c in path]


def timed(fn: object, runs: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    times, xs = [], []
    for d in runs:
        t0 = time.perf_counter()
        xs.append(fn(d))  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return np.asarray(times), xs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--cell", type=float, default=2e-3, help="traction cell [m]")
    args = ap.parse_args()
    patch = load_layout(LAYOUT).patches[0]
    patch = dataclasses.replace(
        patch, grid=dataclasses.replace(patch.grid, traction_cell=args.cell)
    )
    grid, _ = grids_for(patch)
    a = taxel_matrix(patch, grid)
    lam = 0.1 * np.linalg.norm(a, 2)
    data = frames(patch, 20)
    reps = 1 if args.quick else 3
    print(
        f"hexagon patch: K = {a.shape[0]} taxels, N = {a.shape[1]} cells, λ = 0.1·‖A‖₂, 20 frames"
    )

    stacked = np.vstack([a, lam * np.eye(a.shape[1])])
    zeros = np.zeros(a.shape[1])

    def scipy_cold(d: np.ndarray) -> np.ndarray:
        return scipy.optimize.nnls(stacked, np.concatenate([d, zeros]), maxiter=50 * a.shape[1])[0]

    solvers = {
        "scipy.optimize.nnls (cold)": scipy_cold,
    }
    for method in ("bpp", "fista"):
        warm = NnlsSolver(a, tikhonov=lam, method=method)
        cold = NnlsSolver(a, tikhonov=lam, method=method)
        solvers[f"{method} warm"] = lambda d, s=warm: s.solve(d, warm_start=True).x
        solvers[f"{method} cold"] = lambda d, s=cold: s.solve(d, warm_start=False).x

    results = {}
    for name, fn in solvers.items():
        best = None
        for _ in range(reps):
            t, xs = timed(fn, data)
            best = t if best is None or np.median(t) < np.median(best) else best
        results[name] = (best, xs)
    base_t, base_x = results["scipy.optimize.nnls (cold)"]
    print(
        f"\n{'solver':28s} {'median ms':>10s} {'p99 ms':>8s} {'speed-up':>9s} {'max rel Δx':>11s}"
    )
    for name, (t, xs) in results.items():
        diff = max(
            np.abs(x - b).max() / max(np.abs(b).max(), 1e-300)
            for x, b in zip(xs, base_x, strict=True)
        )
        print(
            f"{name:28s} {np.median(t) * 1e3:10.3f} {np.percentile(t, 99) * 1e3:8.3f} "
            f"{np.median(base_t) / np.median(t):9.1f} {diff:11.2e}"
        )

    op = SvdInverse(a).tikhonov_operator(lam)
    op32 = op.astype(np.float32)
    d = data[10]
    n = 2000 if args.quick else 20000
    for label, mat, vec in (("float64", op, d), ("float32", op32, d.astype(np.float32))):
        t0 = time.perf_counter()
        for _ in range(n):
            mat @ vec
        dt = (time.perf_counter() - t0) / n
        print(f"dense Tikhonov product {label}: {dt * 1e6:7.2f} µs")
    rel = np.abs(op32 @ d.astype(np.float32) - op @ d).max() / np.abs(op @ d).max()
    print(f"float32 product relative error: {rel:.1e}")


if __name__ == "__main__":
    main()
