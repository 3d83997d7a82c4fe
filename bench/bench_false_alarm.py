"""False contacts on noise alone, and how often a light press is seen (issue 16 "Noise-aware
detection": under one false contact per hour per patch at 50 Hz).

Idle frames of the default patch, counted when ``Reconstructor`` reports ``in_contact``:

* ``8-bit, baseline on a count``: ΔC = rint(0.15-count Gaussian) counts (the robust bench's
  8-bit tier with no press: each taxel's rest level sits exactly on a count);
* ``8-bit, tracked baseline``: each taxel rests at a random fraction u ∈ [0, 1) of a count
  (fixed per simulated skin; a new skin every ``--skin-frames``), the module rounds u + noise,
  and the baseline is what the driver's tracker keeps: the mean of the first 20 readings, then
  an exponential filter with τ = 20 s at 50 Hz (tactile_contact.canbus.baseline defaults), so that
  readings are the module value minus a fractional baseline. A taxel resting near half a count
  flips between two values: up to 0.5 count RMS, more than the one count/√6 the sensor model
  assumes. Through ``solve`` without and with a per-taxel noise level passed in (RMS of the
  first 500 frames of the skin, floored at the assumed level: what the node's noise tracker
  learns);
* ``float``: Gaussian at the noise the reconstructor assumes (``default_noise``; passed in, and
  not), and at 1 µm with none passed (the float protocol's level, unknown to the library).

With k false contacts in n frames: k/n per frame × 180 000 frames per hour at 50 Hz, and the
95 % Poisson upper bound (3.0/n per frame for k = 0). Last, the probability of detecting each
0.2 N press of the protocol (4 indenters × 6 places, ``--draws`` noise draws each) for the
point-taxel and 2 mm electrode truths in the same noise settings.

    .venv/bin/python bench/bench_false_alarm.py [--quick] [--frames 1000000] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import inspect
import os
import sys
import tempfile
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
import scipy.signal  # noqa: E402
import scipy.stats  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_robust import CLEAR, LAYOUT, Layout, _seed, clear_of, readings, test_presses  # noqa: E402
from bench_speed import assumed_noise  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from tactile_contact.inverse.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.offline.build import build_layout  # noqa: E402

PER_HOUR = 3600 * 50
COUNT_NOISE = 0.15
CALIBRATION_SAMPLES = 20  # tactile_contact.canbus.baseline.BaselineConfig defaults
DRIFT_TAU_S = 20.0
NOISE_FRAMES = 500  # frames the noise level is learnt from
CHUNK = 20_000


class IdleSkin:
    """8-bit idle readings [counts] with a tracked fractional baseline (see module doc)."""

    def __init__(self, k: int, rng: np.random.Generator, skin_frames: int) -> None:
        self.k, self.rng, self.skin_frames = k, rng, skin_frames
        self.alpha = 1.0 - np.exp(-1.0 / 50.0 / DRIFT_TAU_S)
        self.left = 0

    def _new_skin(self) -> None:
        self.rest = self.rng.uniform(0.0, 1.0, self.k)
        cal = np.rint(self.rest + self.rng.normal(0.0, COUNT_NOISE, (CALIBRATION_SAMPLES, self.k)))
        self.baseline = cal.mean(axis=0)
        self.left = self.skin_frames
        self.fresh = True

    def frames(self, n: int) -> tuple[np.ndarray, bool]:
        """Up to n frames of Δcounts = baseline − value (one skin), and whether a new skin
        starts with them."""
        if self.left == 0:
            self._new_skin()
        n = min(n, self.left)
        values = np.rint(self.rest + self.rng.normal(0.0, COUNT_NOISE, (n, self.k)))
        a = self.alpha
        zi = (1.0 - a) * self.baseline
        tracked, _ = scipy.signal.lfilter([a], [1.0, -(1.0 - a)], values, axis=0, zi=zi[None, :])
        before = np.vstack([self.baseline[None, :], tracked[:-1]])
        self.baseline = tracked[-1]
        self.left -= n
        fresh, self.fresh = self.fresh, False
        return before - values, fresh


def poisson_upper(k: int, n: int) -> float:
    """95 % upper bound on the per-frame rate after k events in n frames."""
    return float(scipy.stats.chi2.ppf(0.95, 2 * k + 2) / 2.0 / n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="20 000 frames a case, 5 draws")
    ap.add_argument("--frames", type=int, default=1_000_000, help="idle frames per case")
    ap.add_argument("--skin-frames", type=int, default=100_000, help="frames per idle skin")
    ap.add_argument("--draws", type=int, default=25, help="noise draws per 0.2 N press")
    ap.add_argument("--out", type=Path, help="write false_alarm.md here")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.draws = min(args.frames, 20_000), 5
    threadpool_limits(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench_fa_"))
    build_layout(LAYOUT, tmp, jobs=1)
    r = Reconstructor.from_bundle(tmp / "hexagon")
    lay = Layout()
    k = r.n_taxels
    lsb = lay.lsb
    sigma0 = assumed_noise(r)
    takes_noise = "noise" in inspect.signature(r.solve_deflection).parameters
    lines: list[str] = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    det = getattr(r, "detector", None)
    stated = getattr(det, "per_hour", None)
    say(
        f"assumed compression noise {np.median(sigma0) * 1e6:.2f} µm (median over taxels); "
        f"1 count = {lsb * 1e15:.2f} fF ≈ {float(lay.to_deflection(np.array([lsb]))[0]) * 1e6:.1f}"
        f" µm; stated bound: {stated if stated is not None else 'n/a'} per hour"
    )
    say(
        f"{'noise-only frames':44s} {'frames':>8s} {'false':>6s} {'per hour':>9s} "
        f"{'95% bound/h':>11s} {'µs/frame':>9s}"
    )

    def count(name: str, solve, make) -> None:
        rng = np.random.default_rng(_seed("false-alarm", name))
        hits = done = 0
        t0 = time.perf_counter()
        while done < args.frames:
            block = make(rng, min(CHUNK, args.frames - done))
            hits += sum(bool(solve(x).in_contact) for x in block)
            done += len(block)
        secs = time.perf_counter() - t0
        rate = hits / done * PER_HOUR
        bound = poisson_upper(hits, done) * PER_HOUR
        say(f"{name:44s} {done:8d} {hits:6d} {rate:9.3f} {bound:11.3f} {secs / done * 1e6:9.1f}")

    count(
        "8-bit, baseline on a count",
        r.solve,
        lambda g, n: np.rint(g.normal(0.0, COUNT_NOISE, (n, k))) * lsb,
    )
    skins: dict[str, IdleSkin] = {}
    floor: dict[str, np.ndarray] = {}

    def tracked(g, n, key):
        skin = skins.setdefault(key, IdleSkin(k, g, args.skin_frames))
        counts, fresh = skin.frames(n)
        dc = counts * lsb
        if fresh:  # what a noise tracker learns from the skin's first frames
            d = lay.to_deflection(dc[:NOISE_FRAMES])
            floor[key] = np.maximum(np.sqrt(np.mean(d**2, axis=0)), sigma0)
        return dc

    count("8-bit, tracked baseline", r.solve, lambda g, n: tracked(g, n, "a"))
    if "noise" in inspect.signature(r.solve).parameters:
        # The same readings, each skin's learnt level passed with every frame.
        class Passed:
            def __call__(self, x):
                return r.solve(x, noise=floor["b"])

        count("8-bit, tracked baseline, tracked noise", Passed(), lambda g, n: tracked(g, n, "b"))
        say(
            f"  (tracked noise, last skin: median {np.median(floor['b']) * 1e6:.2f} µm, "
            f"max {floor['b'].max() * 1e6:.2f} µm)"
        )
    if takes_noise:
        count(
            "float, assumed noise, passed in",
            lambda x: r.solve_deflection(x, noise=sigma0),
            lambda g, n: g.normal(size=(n, k)) * sigma0,
        )
    count(
        "float, assumed noise, none passed",
        r.solve_deflection,
        lambda g, n: g.normal(size=(n, k)) * sigma0,
    )
    count(
        "float, 1 µm, none passed",
        r.solve_deflection,
        lambda g, n: g.normal(0.0, 1e-6, (n, k)),
    )
    say(f"(per hour: × {PER_HOUR} frames at 50 Hz; bound: 95 % Poisson upper limit)")

    say()
    say(f"detection of the protocol's 0.2 N presses ({args.draws} noise draws each):")
    names = ("sphere 12 mm", "sphere 6 mm", "cylinder 12 mm", "cylinder 3 mm")
    places = ("over a taxel", "between two", "between three")
    short = ("sph12", "sph6", "cyl12", "cyl3", "over", "betw2", "betw3")
    say(
        f"{'truth':16s} {'readings':34s} {'all':>6s}"
        + "".join(f"{n:>7s}" for n in short)
        + f"  {'z≥10':>9s}"
    )
    say(
        f"  (z≥10: of the presses whose known-shape matched filter would read ‖δ/σ‖ ≥ {CLEAR:g}"
        " σ, how many, and P(detect))"
    )
    for truth in ("point", "2 mm electrode"):
        p = test_presses(lay, truth, args.quick)
        m = np.isclose(p["f"], 0.2)
        d, ind, place = p["d"][m], p["ind"][m], p["place"][m]
        settings = [
            ("float 1 %, solve_deflection(δ)", "float", lambda x: r.solve_deflection(x)),
            ("8-bit, solve(ΔC)", "8-bit", r.solve),
        ]
        if takes_noise:
            settings.insert(
                1,
                (
                    "float, assumed noise, passed in",
                    "assumed",
                    lambda x: r.solve_deflection(x, noise=sigma0),
                ),
            )
        for label, tier, solve in settings:
            rng = np.random.default_rng(_seed("detect", truth, tier))
            hit = np.zeros((len(d), args.draws), bool)
            for j in range(args.draws):
                if tier == "assumed":
                    x = d + rng.normal(size=d.shape) * sigma0
                else:
                    x = readings(lay, d, tier, rng)
                hit[:, j] = [bool(solve(xi).in_contact) for xi in x]
            per = [hit[ind == n].mean() if np.any(ind == n) else np.nan for n in names]
            per += [hit[place == n].mean() if np.any(place == n) else np.nan for n in places]
            if tier == "assumed":
                clear = np.linalg.norm(d / sigma0, axis=1) >= CLEAR
            else:
                clear = clear_of(lay, d, tier)
            pc = f"{hit[clear].mean():.3f}" if clear.any() else "-"
            say(
                f"{truth:16s} {label:34s} {hit.mean():6.3f}"
                + "".join(f"{v:7.3f}" for v in per)
                + f"  {int(clear.sum()):3d} {pc:>5s}"
            )
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        text = (
            "# False contacts on noise alone (bench/bench_false_alarm.py)\n\n"
            f"`.venv/bin/python bench/bench_false_alarm.py --frames {args.frames} "
            f"--out {args.out}`\n\n```\n"
        )
        (args.out / "false_alarm.md").write_text(text + "\n".join(lines) + "\n```\n")


if __name__ == "__main__":
    main()
