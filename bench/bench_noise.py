"""Noise it did not expect: 8-bit readings noisier than the sensor model assumes, solved with
the layout's default noise model (issue 26 "Noise it did not expect").

Readings: whole counts of the ideal capacitor of a truth's compressions (the layout's sensor
model), with Gaussian converter noise of σ counts added before rounding
(:func:`benchkit.readings.quantised`), through ``Reconstructor.solve(ΔC)`` with no ``noise=``:
the reconstructor assumes its layout's default (≈ 0.4 count of compression), and must find
out itself when the readings are noisier. Truths (:mod:`benchkit.truths`, the fine forward
model on 0.25 mm cells): ``point`` taxels (another response than the default bundle's 2 mm
electrode mean) and the ``2 mm electrode`` the bundle models. Presses: the robust bench's
protocol (4 indenters × 6 forces 0.2–3 N × 6 places; 144 a truth).

Bundles: ``default`` (as built from config/hexagon_patch.yaml: a 2 mm electrode response, so on
``point`` taxels it also carries a model error: its noise-free float rows in robust.md) and
``calibrated`` (``python -m tactile_contact.offline.calibrate``, named indenters, on 48 presses
of the same truth at the same noise, elsewhere on the skin: the issue's first row).

Columns (force errors in %, a miss counts 100 %): median |error| at 0.2 N, 0.5 N, ≥ 1 N; the
median and p90 over all presses; the worst press as reported/true force (the largest ratio,
named below) and the smallest; p90 over the presses reported ("p90 seen": misses left out; at
0.2 and 0.5 N most presses are below the noise even at 0.15 count, robust.md); median CoP
error over ≥ 1 N [mm]; misses (in_contact False). Targets at σ = 1 count: p90 ≤ 50 %, no press
above 2× its force.

    .venv/bin/python bench/bench_noise.py [--quick] [--sigmas 0.5,1] [--out docs/bench]

``--quick``: module 4's places and forces 0.2, 0.5, 1, 3 N (48 presses a truth).
``--draws D``: also read every press D times more (noise drawn anew) and print, per force band,
the presses reported, the median reported/true force, the p90 |error| of those reported, the
share above 2× and the largest with its press: one draw a press names a worst case that the
next seed moves (a ≈ 5 % event is in the row or not).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit.calibration import calibrated_bundle
from benchkit.protocol import Patch, default_reconstructor
from benchkit.readings import quantised, seed
from benchkit.stats import crb, errors
from benchkit.tables import Report
from benchkit.truths import N_CAL, SHORT, TRUTHS, calibration_presses, test_presses
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor

#: Converter noise [counts RMS] of the rows; issue 26's targets hold at 1 count.
SIGMAS = (0.5, 1.0)
NAMES = ("point", "2 mm electrode")
#: Issue 26's targets at σ = 1 count: p90 [%], largest reported/true force.
TARGET_P90, TARGET_RATIO = 50.0, 2.0
#: A press's force is "determined" when its Cramér–Rao bound σ_F/F is at most this [%]: a
#: 2× error is then a 4σ event for an efficient estimator.
DETERMINED = 25.0


def force_bound(lay: Patch, p: dict, sigma: float) -> np.ndarray:
    """Per press: the Cramér–Rao bound σ_F/F [%] of one frame of 8-bit readings with ``sigma``
    counts of converter noise and the rounding (the truth's Jacobian in x, y, F, size;
    benchkit.stats.crb)."""
    noise = np.full(len(lay.xy), lay.lsb * math.hypot(sigma, 12**-0.5))
    out = []
    for d, jac, f in zip(p["d"], p["J"], p["f"], strict=True):
        eps = 1e-9
        slope = (lay.to_delta_c(d + eps) - lay.to_delta_c(d - eps)) / (2 * eps)
        out.append(crb(slope[:, None] * jac, noise, float(f))[0])
    return np.array(out)


def calibrated(lay: Patch, name: str, sigma: float, folder: Path) -> tuple[Path | None, str]:
    """A bundle calibrated (named indenters) on N_CAL presses of the truth read at ``sigma``
    counts; (its path or None, the command's summary line or error)."""
    cal = calibration_presses(lay, name, N_CAL)
    rng = np.random.default_rng(seed("noise-calibration", name, f"{sigma:g}"))
    dc = quantised(lay.to_delta_c(cal["d"]), lay.lsb, sigma, rng)
    tag = f"{SHORT[name]}_{sigma:g}".replace(".", "")
    # Refused as uncertain (its message is kept in the notes): the bundle it would write.
    return calibrated_bundle(lay, cal, dc, folder, tag, retry_uncertain=True)


def draws(
    recon: Reconstructor, p: dict, dc: np.ndarray, lsb: float, sigma: float, n: int, tag: str
) -> list[str]:
    """Lines of the ``--draws`` table: every press read ``n`` times at ``sigma`` counts
    (seeds of their own), ratios reported/true force pooled per force band."""
    f = p["f"]
    ratio = np.full((n, len(f)), np.nan)
    for k in range(n):
        rng = np.random.default_rng(seed("noise-draws", tag, str(k)))
        x = quantised(dc, lsb, sigma, rng)
        r = errors(recon, "8-bit", x, p)
        ratio[k] = 1.0 + r["err"] / 100.0
    out = []
    for band, sel in (
        ("0.2 N", np.isclose(f, 0.2)),
        ("0.5 N", np.isclose(f, 0.5)),
        (">=1 N", f >= 1.0),
        ("all", np.ones(len(f), dtype=bool)),
    ):
        got = ratio[:, sel]
        seen = got[~np.isnan(got)]
        if not sel.any() or seen.size == 0:
            out.append(f"    {band:6s} reported 0 of {got.size}")
            continue
        k, j = np.unravel_index(int(np.nanargmax(got)), got.shape)
        i = int(np.flatnonzero(sel)[j])
        out.append(
            f"    {band:6s} reported {seen.size:5d} of {got.size:5d} | ratio median "
            f"{np.median(seen):5.2f}, p90 |error| {np.percentile(np.abs(seen - 1) * 100, 90):6.1f} "
            f"%, above 2× {np.mean(seen > 2.0) * 100:5.1f} %, largest {seen.max():5.2f}× "
            f"({p['ind'][i]}, {f[i]:g} N, {p['place'][i]}, draw {k})"
        )
    return out


def stats(r: dict[str, np.ndarray], p: dict[str, np.ndarray], bound: np.ndarray) -> dict:
    """One row: medians per band, median and p90 overall [%], the extreme ratios with their
    presses (over all, and over the presses whose force is determined: ``bound`` (N,) σ_F/F
    [%] ≤ DETERMINED), CoP over ≥ 1 N [mm], misses."""
    f, err = p["f"], r["err"]
    miss = np.isnan(err)
    a = np.where(miss, 100.0, np.abs(err))
    ratio = np.where(miss, 0.0, 1.0 + err / 100.0)
    hi = f >= 1.0
    top, low = int(np.argmax(ratio)), int(np.argmin(ratio))
    known = bound <= DETERMINED
    top_known = int(np.flatnonzero(known)[np.argmax(ratio[known])]) if known.any() else top

    def press(i: int) -> str:
        return f"{p['ind'][i]}, {f[i]:g} N, {p['place'][i]}"

    return {
        "0.2 N": float(np.median(a[np.isclose(f, 0.2)])),
        "0.5 N": float(np.median(a[np.isclose(f, 0.5)])),
        ">=1 N": float(np.median(a[hi])),
        "all": float(np.median(a)),
        "p90": float(np.percentile(a, 90)),
        "p90 seen": float(np.percentile(a[~miss], 90)) if (~miss).any() else float("nan"),
        "max ratio": float(ratio[top]),
        "max press": press(top),
        "max ratio determined": float(ratio[top_known]) if known.any() else float("nan"),
        "max press determined": press(top_known) if known.any() else "-",
        "determined": int(known.sum()),
        "max ratio >=1 N": float(ratio[hi].max()),
        "min ratio": float(ratio[low]),
        "min press": press(low),
        "cop>=1": float(np.nanmedian(np.where(miss, np.inf, r["cop"])[hi])),
        "misses": int(miss.sum()),
        "presses": len(f),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="module 4's places, 4 forces")
    ap.add_argument("--sigmas", help="comma-separated converter noise [counts RMS]")
    ap.add_argument("--truths", help="comma-separated truth names (default: point, 2 mm)")
    ap.add_argument("--no-calibrate", action="store_true", help="the default bundle only")
    ap.add_argument("--out", type=Path, help="write noise.md and noise.json here")
    ap.add_argument(
        "--draws", type=int, default=0, help="read every press this many times more (worst case)"
    )
    args = ap.parse_args()
    threadpool_limits(1)
    t0 = time.perf_counter()
    sigmas = tuple(float(s) for s in args.sigmas.split(",")) if args.sigmas else SIGMAS
    names = tuple(s.strip() for s in args.truths.split(",")) if args.truths else NAMES
    for n in names:
        if n not in TRUTHS:
            raise SystemExit(f"unknown truth {n!r}; known: {', '.join(TRUTHS)}")
    lay = Patch()
    tmp = Path(tempfile.mkdtemp(prefix="bench_noise_"))
    default = default_reconstructor(tmp / "default")
    say = Report()
    say(
        "8-bit: whole counts of the ideal capacitor, σ counts of Gaussian noise before rounding; "
        "solve(ΔC) with no noise= (the layout's default model)"
    )
    say(
        f"{'truth':15s} {'σ cnt':>5s} {'bundle':10s} | {'0.2 N':>6s} {'0.5 N':>6s} {'>=1 N':>6s} "
        f"{'all':>6s} {'p90':>6s} {'p90 seen':>8s} | {'max ×F':>6s} {'min ×F':>6s} | "
        f"{'CoP mm':>6s} {'miss':>4s}"
    )
    rows, notes = [], []
    for name in names:
        p = test_presses(lay, name, args.quick)
        dc = lay.to_delta_c(p["d"])
        for s in sigmas:
            bundles = {"default": default}
            if not args.no_calibrate:
                path, note = calibrated(lay, name, s, tmp)
                notes.append(f"calibrated {name} at {s:g} count: {note}")
                if path is not None:
                    bundles["calibrated"] = Reconstructor.from_bundle(path)
            rng = np.random.default_rng(seed("noise", name, f"{s:g}"))
            x = quantised(dc, lay.lsb, s, rng)
            bound = force_bound(lay, p, s)
            for kind, recon in bundles.items():
                t = time.perf_counter()
                r = errors(recon, "8-bit", x, p)
                row = {"truth": name, "sigma": s, "bundle": kind, **stats(r, p, bound)}
                row["seconds"] = time.perf_counter() - t
                rows.append(row)
                say(
                    f"{name:15s} {s:5.2f} {kind:10s} | {row['0.2 N']:6.1f} {row['0.5 N']:6.1f} "
                    f"{row['>=1 N']:6.1f} {row['all']:6.1f} {row['p90']:6.1f} "
                    f"{row['p90 seen']:8.1f} | {row['max ratio']:6.2f} {row['min ratio']:6.2f} | "
                    f"{row['cop>=1']:6.2f} {row['misses']:4d}"
                )
                say(
                    f"{'':34s}max: {row['max press']}; min: {row['min press']}; ≥ 1 N: max "
                    f"{row['max ratio >=1 N']:.2f}×; {row['determined']} presses of σ_F/F ≤ "
                    f"{DETERMINED:g} % (Cramér–Rao): max {row['max ratio determined']:.2f}× "
                    f"({row['max press determined']})"
                )
                if args.draws > 0:
                    say(f"{'':34s}{args.draws} draws more of every press:")
                    tag = f"{name} {s:g} {kind}"
                    for line in draws(recon, p, dc, lay.lsb, s, args.draws, tag):
                        say(f"{'':30s}{line}")
    say()
    say(f"issue 26 targets at σ = 1 count: p90 ≤ {TARGET_P90:g} %, max ×F ≤ {TARGET_RATIO:g}")
    for row in rows:
        if row["sigma"] != 1.0:
            continue
        ok = row["p90 seen"] <= TARGET_P90 and row["max ratio"] <= TARGET_RATIO
        say(
            f"  {'ok  ' if ok else 'MISS'} {SHORT[row['truth']]:5s} {row['bundle']:10s} p90 "
            f"{row['p90']:.1f} % (reported presses: {row['p90 seen']:.1f} %), max "
            f"{row['max ratio']:.2f}× its force (force determined, σ_F/F ≤ {DETERMINED:g} %: "
            f"{row['max ratio determined']:.2f}×; ≥ 1 N: {row['max ratio >=1 N']:.2f}×)"
        )
    for note in notes:
        say(note)
    say(f"({time.perf_counter() - t0:.0f} s in all; ×F: reported/true force, a miss 0)")
    if args.out:
        q = "".join(
            f" {flag} {value}".rstrip()
            for flag, value in (
                ("--quick", "" if args.quick else None),
                ("--sigmas", args.sigmas),
                ("--truths", args.truths),
                ("--draws", args.draws or None),
            )
            if value is not None
        )
        say.write(
            args.out,
            "noise.md",
            "Noise it did not expect (bench/bench_noise.py)",
            f".venv/bin/python bench/bench_noise.py{q} --out {args.out}",
        )
        (args.out / "noise.json").write_text(json.dumps({"rows": rows}, indent=1))


if __name__ == "__main__":
    main()
