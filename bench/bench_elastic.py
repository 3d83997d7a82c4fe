"""Cost of the elastic operator: dense Love assembly against dense Boussinesq–Cerruti and the
regular-grid fast path (Toeplitz + FFT), build and product.

For square grids of n × n cells (pitch 1 mm, h = 2 mm, E = 2.1e5 Pa) measured at the cell
centres, prints coefficients per second of the dense Love and B-C builds, their ratio, the
time to build the Toeplitz fast operator (distinct kernel values + FFT spectrum) and its
speed-up over the dense Love build, and one product C·q dense vs FFT. Correctness is checked
before anything is timed. Times are minima over repeats (Love and B-C run alternately, so
both see the same background load on a shared machine; two runs each for the largest grid).

    .venv/bin/python bench/bench_elastic.py            # 10×10 … 100×100 (about a minute)
    .venv/bin/python bench/bench_elastic.py --quick    # 10×10 … 40×40
"""

from __future__ import annotations

import argparse

import numpy as np
from benchkit.layer import E, H
from benchkit.timing import best_time, paired_best

from tactile_contact.model.elastic import boussinesq_matrix, love_matrix, regular_grid_operator

PITCH = 1e-3


def centres(n: int) -> np.ndarray:
    g = np.arange(n) * PITCH
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def check(nu: float) -> None:
    """The fast path and the dense builds agree before anything is timed."""
    c = centres(12)
    op = regular_grid_operator(12, 12, PITCH, PITCH, H, E, nu)
    dense = love_matrix(c, c, [PITCH / 2, PITCH / 2], H, E, nu)
    assert np.allclose(op.dense(), dense, rtol=1e-10, atol=1e-12 * np.abs(dense).max())
    q = np.random.default_rng(0).normal(size=144)
    assert np.allclose(op.matvec(q), dense @ q, rtol=0, atol=1e-12 * np.abs(dense @ q).max())
    opb = regular_grid_operator(12, 12, PITCH, PITCH, H, E, nu, model="boussinesq")
    assert np.allclose(opb.dense(), boussinesq_matrix(c, c, PITCH**2, H, E, nu), rtol=1e-12)


def row(n: int, nu: float) -> dict[str, float]:
    c = centres(n)
    coeffs = float(c.shape[0]) ** 2
    t_love, t_bc = paired_best(
        lambda: love_matrix(c, c, [PITCH / 2, PITCH / 2], H, E, nu),
        lambda: boussinesq_matrix(c, c, PITCH**2, H, E, nu),
    )
    dense = love_matrix(c, c, [PITCH / 2, PITCH / 2], H, E, nu)
    t_fast, op = best_time(lambda: regular_grid_operator(n, n, PITCH, PITCH, H, E, nu))
    q = np.random.default_rng(1).normal(size=n * n)
    t_mv_dense, ref = best_time(lambda: dense @ q)
    t_mv_fft, got = best_time(lambda: op.matvec(q))
    err = float(np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
    return {
        "n": n,
        "coeffs": coeffs,
        "love_rate": coeffs / t_love,
        "bc_rate": coeffs / t_bc,
        "love_over_bc": t_love / t_bc,
        "t_love": t_love,
        "t_fast": t_fast,
        "fast_speedup": t_love / t_fast,
        "mv_speedup": t_mv_dense / t_mv_fft,
        "mv_err": err,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="grids up to 40×40 only")
    parser.add_argument("--poisson", type=float, default=0.5, help="Poisson ratio (default 0.5)")
    args = parser.parse_args()
    sizes = [10, 20, 40] if args.quick else [10, 20, 40, 70, 100]
    check(args.poisson)
    print(f"pitch {PITCH * 1e3:g} mm, h {H * 1e3:g} mm, E {E:g} Pa, ν {args.poisson:g}")
    head = (
        f"{'grid':>8} {'coeffs':>9} {'Love Mcoef/s':>13} {'B-C Mcoef/s':>12} {'Love/B-C':>9}"
        f" {'dense Love s':>13} {'fast s':>9} {'fast ×':>9} {'C·q FFT ×':>10} {'FFT err':>8}"
    )
    print(head)
    print("-" * len(head))
    for n in sizes:
        r = row(n, args.poisson)
        print(
            f"{n:>3}×{n:<4} {r['coeffs']:>9.2e} {r['love_rate'] / 1e6:>13.1f}"
            f" {r['bc_rate'] / 1e6:>12.1f} {r['love_over_bc']:>9.2f} {r['t_love']:>13.3f}"
            f" {r['t_fast']:>9.4f} {r['fast_speedup']:>9.0f} {r['mv_speedup']:>10.1f}"
            f" {r['mv_err']:>8.0e}",
            flush=True,
        )
    print(
        "Love/B-C: dense Love build time over dense B-C build time (target ≤ 3);"
        " fast ×: dense Love build over fast-path build (target ≥ 20 at 100×100);"
        " C·q FFT ×: dense product over FFT product; FFT err: max error / max |C·q|."
    )


if __name__ == "__main__":
    main()
