"""Warm-started NNLS against scipy.optimize.nnls on a moving indenter (issue 7 target: ≥ 5×).

Two problems on a 24 × 25 grid of 2.5 mm Love cells (N = 600) covering the paper's hexagonal
patch (six roboskin12 modules, h = 2 mm, E = 2.1e5 Pa, ν = 0.5):

- ``taxels``: K = 72 taxel centres (under-determined, the real case);
- ``square``: K = N = 600 measurement points at the cell centres.

A 12 mm sphere pressing 1 N slides along the patch diagonal in 20 frames; compressions come
from the independent fine forward model (tactile_contact.model.forward) plus 1 µm Gaussian noise
(seeded). Every solver minimises ‖A·x − d‖² + λ²‖L·x‖², x ≥ 0 with the same λ = 0.1·‖A‖₂ and
L = I (and, for the taxel problem, also L = Dirichlet grid Laplacian). scipy's Lawson–Hanson
runs cold on the stacked system [A; λL] (it has no warm start); ours run warm (from the
previous frame) and cold. Times are per frame, best of ``reps`` passes over the stream.
Also times the dense float32 and float64 online products of the linear inverse operators.

    python bench/bench_nnls.py [--quick]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import scipy.optimize

from tactile_contact.inverse.solvers import NnlsSolver, SvdInverse, grid_laplacian
from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.model.modules import ROBOSKIN12, place_channels

H, E, NU = 2e-3, 2.1e5, 0.5
HEXAGON_MM = (
    ((16.732, 9.660), 60),
    ((33.464, -19.321), 300),
    ((16.732, -28.981), 0),
    ((0.0, -19.321), 60),
    ((0.0, 0.0), 0),
    ((33.464, 0.0), 0),
)
SHAPE, PITCH = (24, 25), 2.5e-3
FRAMES, NOISE = 20, 1e-6


def hexagon_taxels() -> np.ndarray:
    return np.vstack(
        [place_channels(ROBOSKIN12, (x * 1e-3, y * 1e-3), rot) for (x, y), rot in HEXAGON_MM]
    )


def cell_grid(taxels: np.ndarray) -> np.ndarray:
    """(N, 2) cell centres [m], row-major, the grid centred on the taxels' bounding box."""
    mid = 0.5 * (taxels.min(0) + taxels.max(0))
    ys = mid[1] + (np.arange(SHAPE[0]) - (SHAPE[0] - 1) / 2) * PITCH
    xs = mid[0] + (np.arange(SHAPE[1]) - (SHAPE[1] - 1) / 2) * PITCH
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def stream(points: np.ndarray, taxels: np.ndarray, seed: int) -> list[np.ndarray]:
    model = ForwardModel(points, H, E, NU)
    lo, hi = taxels.min(0) + 6e-3, taxels.max(0) - 6e-3
    rng = np.random.default_rng(seed)
    return [
        model.compression(HertzSphere(radius=6e-3), 1.0, c) + NOISE * rng.normal(size=len(points))
        for c in np.linspace(lo, hi, FRAMES)
    ]


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


def products(label: str, a: np.ndarray, d: np.ndarray, count: int) -> None:
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
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one pass, fewer product repetitions")
    args = ap.parse_args()
    reps = 1 if args.quick else 3
    taxels = hexagon_taxels()
    centers = cell_grid(taxels)
    half = np.full(2, PITCH / 2)
    a_tax = love_matrix(taxels, centers, half, H, E, NU)
    a_sq = love_matrix(centers, centers, half, H, E, NU)
    data_tax, data_sq = stream(taxels, taxels, 1), stream(centers, taxels, 2)
    lap = grid_laplacian(SHAPE)
    speed = compare("taxels, L = I", a_tax, None, data_tax, reps)
    compare("taxels, L = Dirichlet Laplacian", a_tax, lap, data_tax, reps)
    compare("square (K = N), L = I", a_sq, None, data_sq, reps)
    print(
        f"\n{'problem':8s} {'operator':9s} {'shape':9s} {'f64 µs':>9s} {'f32 µs':>9s} "
        f"{'ratio':>7s} {'f32 rel err':>10s}"
    )
    count = 2000 if args.quick else 20000
    products("taxels", a_tax, data_tax[10], count)
    products("square", a_sq, data_sq[10], count // 10)
    target = speed["bpp warm"]
    print(f"\nwarm-started bpp vs scipy.optimize.nnls (taxels, L = I): {target:.1f}× (target ≥ 5×)")


if __name__ == "__main__":
    main()
