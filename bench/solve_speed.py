"""Run time of one frame through Reconstructor, beside scipy.optimize.nnls on the same problem
(issue 16's speed targets: contact frame ≤ 1 ms p50 and ≤ 3 ms p99, frame without contact
≤ 50 µs). One core: BLAS pinned to one thread; the compiled fit (numba) is single-threaded.

Contact frames: the paper's protocol (bench/robustness.py: 144 presses, 4 indenters × 6 forces
× 6 places) on the point-taxel truth, float readings with 1 % noise (solve_deflection) and
8-bit counts (solve), every output wanted (traction and deflection grids). Frames without
contact: noise only. Baseline, same frames: scipy.optimize.nnls on [C; λI] q = [δ; 0] with the
bundle's forward matrix C (72 × 698) and its λ — the constrained solve the grid path would run.

    .venv/bin/python bench/solve_speed.py [--repeat 5] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.optimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from robustness import noisy, test_presses  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from tactile_contact.build import build_layout  # noqa: E402
from tactile_contact.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.sensor import value_count_farad  # noqa: E402


def timed(fn, frames, repeat: int) -> np.ndarray:
    out = []
    for _ in range(repeat):
        for x in frames:
            t = time.perf_counter()
            fn(x)
            out.append(time.perf_counter() - t)
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    threadpool_limits(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench_speed_"))
    build_layout(ROOT / "config" / "hexagon_patch.yaml", tmp, jobs=1)
    recon = Reconstructor.from_bundle(tmp / "hexagon")
    presses = test_presses("point", recon.taxel_xy)
    rng = np.random.default_rng(1)
    flt = noisy(presses["d"], "float", recon, rng)
    q8 = noisy(presses["d"], "8-bit", recon, rng)
    p = recon.params
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    idle_f = rng.normal(0.0, 1.0, (2000, recon.n_taxels)) * recon.default_noise
    idle_q = np.rint(rng.normal(0.0, 0.15, (2000, recon.n_taxels))) * lsb
    for x in flt[:3]:  # compile and warm up
        recon.solve_deflection(x)
    c = recon.forward
    lam = float(p["tikhonov"])
    a = np.vstack([c, lam * np.eye(c.shape[1])])
    rows: list[tuple[str, np.ndarray]] = [
        ("contact, float (solve_deflection)", timed(recon.solve_deflection, flt, args.repeat)),
        ("contact, 8-bit (solve)", timed(recon.solve, q8, args.repeat)),
        (
            "no contact, float, noise given",
            timed(lambda x: recon.solve_deflection(x, noise=recon.default_noise), idle_f, 1),
        ),
        ("no contact, 8-bit (solve)", timed(recon.solve, idle_q, 1)),
    ]
    zeros = np.zeros(c.shape[1])
    rows.append(
        (
            "scipy.optimize.nnls [C; λI] (baseline)",
            timed(lambda d: scipy.optimize.nnls(a, np.concatenate([d, zeros])), flt[::4], 1),
        )
    )
    lines = [f"{'frame':42s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s}"]
    for name, t in rows:
        lines.append(
            f"{name:42s} {np.median(t) * 1e6:9.0f} {np.percentile(t, 99) * 1e6:9.0f} "
            f"{t.max() * 1e6:9.0f}"
        )
    base = np.median(rows[-1][1])
    lines.append("")
    lines.append(
        f"contact frame p50 vs scipy nnls p50: {np.median(rows[0][1]) / base:.3f} (float), "
        f"{np.median(rows[1][1]) / base:.3f} (8-bit); targets: contact ≤ 1000 µs p50, "
        "≤ 3000 µs p99; no contact ≤ 50 µs"
    )
    print("\n".join(lines))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        text = "# One frame's run time (bench/solve_speed.py)\n\n```\n"
        (args.out / "solve_speed.md").write_text(text + "\n".join(lines) + "\n```\n")


if __name__ == "__main__":
    main()
