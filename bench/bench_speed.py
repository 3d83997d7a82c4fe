"""Run time of one frame through Reconstructor, beside scipy.optimize.nnls on the same problem
(issue 16 "Speed": contact frame ≤ 1 ms p50 and ≤ 3 ms p99, frame without contact ≤ 50 µs).

One core: BLAS, OpenMP and numba pinned to one thread (threadpoolctl and the *_NUM_THREADS
variables, set before numpy loads). Wall time of each call, as a node pays it.

* contact frames: the paper's protocol (benchkit.protocol: 4 indenters × 6 forces × 6
  places) on a truth other than the default's (``--truth``, default: point taxels), float
  readings with 1 % noise through ``solve_deflection(δ)`` (every output, and the summary only
  when the call takes ``want_traction``/``want_deflection``), and 8-bit ΔC through ``solve``;
  ``--repeat`` passes over the presses in a shuffled order;
* frames without contact: noise only: Gaussian at the noise the reconstructor assumes
  (``default_noise``/``noise``, passed in when the call takes ``noise``) and an idle 8-bit
  skin (0.15-count converter noise, rounded);
* baseline, same float frames: scipy.optimize.nnls on [C; λI]·q = [δ; 0] with the bundle's
  forward matrix C (``recon.forward``, K × N) and λ = params["tikhonov"] (absolute; else 0.1·‖C‖₂):
  the non-negative Tikhonov problem the library's grid path solves.

    .venv/bin/python bench/bench_speed.py [--quick] [--repeat 5] [--out docs/bench]

Timings on a shared machine: the load average at the start is printed; p99 suffers first.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
import scipy.optimize
from benchkit.protocol import Patch, default_reconstructor
from benchkit.readings import COUNT_NOISE, assumed_noise, readings, seed
from benchkit.tables import write_block
from benchkit.timing import per_frame, takes
from benchkit.truths import TRUTHS, test_presses
from threadpoolctl import threadpool_info, threadpool_limits

TARGETS = {"contact p50": 1000.0, "contact p99": 3000.0, "idle p50": 50.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="quick protocol, 1 pass, 2000 idle")
    ap.add_argument("--repeat", type=int, default=5, help="passes over the contact frames")
    ap.add_argument("--idle", type=int, default=20_000, help="frames without contact")
    ap.add_argument("--truth", default="point", choices=list(TRUTHS))
    ap.add_argument("--out", type=Path, help="write speed.md here")
    args = ap.parse_args()
    if args.quick:
        args.repeat, args.idle = 1, 2000
    threadpool_limits(1)
    load = os.getloadavg()[0]
    recon = default_reconstructor(Path(tempfile.mkdtemp(prefix="bench_speed_")))
    lay = Patch()
    p = test_presses(lay, args.truth, args.quick)
    flt = readings(lay, p["d"], "float", np.random.default_rng(seed("speed", "float")))
    q8 = readings(lay, p["d"], "8-bit", np.random.default_rng(seed("speed", "8-bit")))
    rng = np.random.default_rng(7)
    sigma = assumed_noise(recon)
    idle_f = rng.normal(size=(args.idle, recon.n_taxels)) * sigma
    idle_q = np.rint(rng.normal(0.0, COUNT_NOISE, (args.idle, recon.n_taxels))) * lay.lsb
    for x in flt[:5]:  # compile (numba) and warm caches
        recon.solve_deflection(x)
        recon.solve(q8[0])
    sd = recon.solve_deflection
    rows: list[tuple[str, np.ndarray, int]] = []
    t, h = per_frame(sd, flt, args.repeat, rng)
    rows.append(("contact, float, solve_deflection(δ)", t, h))
    if takes(sd, "want_traction") and takes(sd, "want_deflection"):
        t, h = per_frame(
            lambda x: sd(x, want_traction=False, want_deflection=False), flt, args.repeat, rng
        )
        rows.append(("contact, float, summary only", t, h))
    t, h = per_frame(recon.solve, q8, args.repeat, rng)
    rows.append(("contact, 8-bit, solve(ΔC)", t, h))
    if takes(sd, "noise"):
        t, h = per_frame(lambda x: sd(x, noise=sigma), idle_f, 1, rng)
        rows.append(("no contact, float, noise passed", t, h))
    t, h = per_frame(sd, idle_f, 1, rng)
    rows.append(("no contact, float, no noise passed", t, h))
    t, h = per_frame(recon.solve, idle_q, 1, rng)
    rows.append(("no contact, 8-bit, solve(ΔC)", t, h))
    c = np.asarray(recon.forward, dtype=np.float64)
    lam = recon.params.get("tikhonov")
    lam = float(lam) if lam is not None else 0.1 * float(np.linalg.norm(c, 2))
    a = np.vstack([c, lam * np.eye(c.shape[1])])
    zeros = np.zeros(c.shape[1])
    base_frames = flt if not args.quick else flt[::2]

    def baseline(d: np.ndarray) -> tuple:
        return scipy.optimize.nnls(a, np.concatenate([d, zeros]))

    t, h = per_frame(baseline, base_frames, 1, rng)
    rows.append((f"scipy.optimize.nnls [C; λI] ({c.shape[0]}×{c.shape[1]})", t, h))

    blas = sorted({f"{i['internal_api']}:{i['num_threads']}" for i in threadpool_info()})
    lines = [
        f"{len(flt)} contact frames ({args.truth} truth) × {args.repeat} passes; "
        f"{args.idle} idle frames; load average at start {load:.2f}; threads {', '.join(blas)}",
        f"{'frame':44s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s} {'in contact':>11s}",
    ]
    for i, (name, t, h) in enumerate(rows):
        seen = f"{h:6d}/{len(t):<6d}" if i < len(rows) - 1 else f"{'-':>6s}"
        lines.append(
            f"{name:44s} {np.median(t) * 1e6:9.0f} {np.percentile(t, 99) * 1e6:9.0f} "
            f"{t.max() * 1e6:9.0f} {seen}"
        )
    base = rows[-1][1]
    lines.append("")
    for name, t, _ in rows[:-1]:
        if name.startswith("contact"):
            lines.append(
                f"scipy nnls / {name}: {np.median(base) / np.median(t):6.1f}× at p50, "
                f"{np.percentile(base, 99) / np.percentile(t, 99):6.1f}× at p99"
            )
    lines.append("")
    first = rows[0][1] * 1e6
    idle = [t for name, t, _ in rows if name.startswith("no contact")]
    checks = [
        ("contact frame p50 ≤ 1000 µs", np.median(first), TARGETS["contact p50"]),
        ("contact frame p99 ≤ 3000 µs", np.percentile(first, 99), TARGETS["contact p99"]),
        ("no-contact frame p50 ≤ 50 µs (worst row)", max(np.median(t) for t in idle) * 1e6, 50.0),
    ]
    for label, v, lim in checks:
        lines.append(f"  {'ok  ' if v <= lim else 'MISS'} {label}: {v:.0f} µs")
    print("\n".join(lines))
    if args.out:
        write_block(
            args.out / "speed.md",
            "One frame's run time (bench/bench_speed.py)",
            f".venv/bin/python bench/bench_speed.py --out {args.out}",
            lines,
        )


if __name__ == "__main__":
    main()
