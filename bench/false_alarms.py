"""False contacts on noise alone (issue 16: under one per hour per patch at 50 Hz).

Frames of an idle skin through Reconstructor, counted when reported in contact:

* ``8-bit``: counts rounded from 0.15-count Gaussian converter noise, through ``solve`` with
  the layout's noise level (the z test of tactile_contact.detection);
* ``float, noise given``: Gaussian readings at the noise level passed in (the z test);
* ``float, no noise level``: Gaussian readings of an unknown level (1 µm) through
  ``solve_deflection`` with none passed (the z test at the layout's level and the scale-free
  energy-share test).

With k false contacts in n frames the rate is k/n per frame and its one-sided 95 % upper bound
χ²(0.95; 2k + 2)/(2n) (Poisson; 3.0/n for k = 0); × 180 000 frames per hour at 50 Hz.

    .venv/bin/python bench/false_alarms.py [--frames 1000000] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from threadpoolctl import threadpool_limits  # noqa: E402

from tactile_contact.build import build_layout  # noqa: E402
from tactile_contact.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.sensor import value_count_farad  # noqa: E402

PER_HOUR = 3600 * 50


def count(fn, make, frames: int, chunk: int = 20_000) -> tuple[int, float]:
    hits, t0 = 0, time.perf_counter()
    rng = np.random.default_rng(0)
    done = 0
    while done < frames:
        block = make(rng, min(chunk, frames - done))
        hits += sum(fn(x).in_contact for x in block)
        done += len(block)
    return hits, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    threadpool_limits(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench_fa_"))
    build_layout(ROOT / "config" / "hexagon_patch.yaml", tmp, jobs=1)
    r = Reconstructor.from_bundle(tmp / "hexagon")
    k = r.n_taxels
    lsb = float(value_count_farad(r.params["farad_per_count"], r.params["shift"]))
    sigma = r.default_noise
    cases = {
        "8-bit (solve, layout noise)": (
            r.solve,
            lambda g, n: np.rint(g.normal(0.0, 0.15, (n, k))) * lsb,
        ),
        "float, noise given": (
            lambda x: r.solve_deflection(x, noise=sigma),
            lambda g, n: g.normal(size=(n, k)) * sigma,
        ),
        "float, no noise level (1 µm)": (
            r.solve_deflection,
            lambda g, n: g.normal(0.0, 1e-6, (n, k)),
        ),
    }
    lines = [
        f"stated bound: {r.detector.per_hour:g} per hour at {r.detector.frame_rate:g} Hz "
        f"(z ≥ {r.detector.threshold:.2f}, energy share ≥ {r.detector.share_threshold:.3f}, "
        f"{len(r.detector.centres)} filters)",
        f"{'noise':32s} {'frames':>9s} {'false':>6s} {'per hour':>10s} {'95 % bound/h':>13s}"
        f" {'µs/frame':>9s}",
    ]
    for name, (fn, make) in cases.items():
        hits, secs = count(fn, make, args.frames)
        rate = hits / args.frames * PER_HOUR
        bound = chi2.ppf(0.95, 2 * (hits + 1)) / 2 / args.frames * PER_HOUR
        lines.append(
            f"{name:32s} {args.frames:9d} {hits:6d} {rate:10.3f} {bound:13.3f} "
            f"{secs / args.frames * 1e6:9.1f}"
        )
        print(lines[-1], flush=True)
    print("\n".join(lines[:2]))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        text = "# False contacts on noise alone (bench/false_alarms.py)\n\n```\n"
        (args.out / "false_alarms.md").write_text(text + "\n".join(lines) + "\n```\n")


if __name__ == "__main__":
    main()
