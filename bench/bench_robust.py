"""Force and CoP error on skins with other taxel responses: default bundle against calibrated,
each beside the Cramér–Rao bound (issue 16: "Uncalibrated, robust by default", "Accuracy").

Protocol (the paper's, :mod:`benchkit.protocol`): 4 indenters × forces 0.2, 0.5, 1, 1.8, 2.5,
3 N × over a taxel / between two / between three taxels of modules 4 and 2 (144 presses).
Truths (:mod:`benchkit.truths`): the fine forward model on 0.25 mm cells with a taxel response
of its own: point values, 2 mm and 3 mm electrodes, gain × 0.85 / × 1.15, layer × 0.9 / × 1.1.
Tiers (:mod:`benchkit.readings`): ``float``, δ + 1 % Gaussian noise through
``solve_deflection(δ)``; ``8-bit``, ΔC + 0.15-count noise rounded to counts through
``solve(ΔC)``.

Bundles: ``default``, built from config/hexagon_patch.yaml (``--layout``: another layout's first
patch, e.g. the imported iCub forearm config/icub/left_forearm_V2.yaml: the same places on its
modules 4 and 2, by channel); ``calibrated``, written by
``python -m tactile_contact.offline.calibrate LAYOUT PRESSES.npz -o DIR`` from 48 presses of the
same truth and tier at other places (random, on the skin, ≥ 2 mm from every test place; random
indenter of the four, named in ``indenter``; 0.5–3 N; seeded). Without the calibrate command
the calibrated rows are skipped with a note.

Columns: median |force error| [%] at 0.2 N, at 0.5 N, over ≥ 1 N, and the largest of the
per-force medians at 1, 1.8, 2.5, 3 N ("max>=1"); overall median and p90; bias at ≥ 1 N
(median signed error); median CoP error [mm]; misses (in_contact False: a 100 % force error,
an infinite CoP error). WORST rows take each column's worst truth (named below the row). Then,
per force band, the median |error| beside the median Cramér–Rao bound σ_F/F of the same
presses (truth's Jacobian in x, y, F, indenter size; the tier's noise) and their ratio.

    .venv/bin/python bench/bench_robust.py [--quick] [--truths point,...] [--out docs/bench]

``--quick``: truths point and gain 1.15, forces 0.2, 0.5, 1, 3 N, module 4's places only
(48 presses), 24 calibration presses. Forward simulations are cached under
out/bench-robust-cache (first full run: ≈ 15 min of simulation on one core).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit import LAYOUT, ROOT
from benchkit.protocol import Patch, default_reconstructor
from benchkit.readings import (
    CLEAR,
    COUNT_NOISE,
    FLOAT_NOISES,
    NOISE_REL,
    TIERS,
    clear_of,
    readings,
    seed,
    set_float_noise,
)
from benchkit.stats import BANDS, COLUMNS, bandmask, bounds, errors, row_stats, worst_of
from benchkit.tables import WIDTH, Report, fmt_head, fmt_row
from benchkit.truths import (
    CACHE,
    N_CAL,
    N_CAL_QUICK,
    QUICK_TRUTHS,
    SHORT,
    TRUTHS,
    calibration_presses,
    test_presses,
)
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor

#: Issue 16's accuracy targets (calibrated bundle): (tier, column, limit).
TARGETS = (
    ("float", "max>=1", 5.0),
    ("float", "0.2 N", 15.0),
    ("float", "all", 10.0),
    ("float", "p90", 25.0),
    ("float", "cop", 0.3),
    ("8-bit", "max>=1", 10.0),
    ("8-bit", "cop", 0.8),
)


def calibrated_bundle(
    lay: Patch, name: str, tier: str, n: int, tmp: Path, layout: Path = LAYOUT
) -> tuple[Path | None, str]:
    """Calibrate on ``n`` presses of the truth at the tier's noise with the calibrate command;
    (bundle path or None, its printed summary or error)."""
    cal = calibration_presses(lay, name, n)
    rng = np.random.default_rng(seed("calibration", name, tier))
    x = readings(lay, cal["d"], tier, rng)
    defl = x if tier == "float" else lay.to_deflection(x)
    tag = f"{SHORT[name]}_{tier}".replace("-", "")
    npz = tmp / f"presses_{tag}.npz"
    np.savez(npz, deflection=defl, force=cal["f"], position=cal["c"], indenter=cal["ind"])
    out = tmp / f"calibrated_{tag}"
    cmd = [
        sys.executable,
        "-m",
        "tactile_contact.offline.calibrate",
        str(layout),
        str(npz),
        "-o",
        str(out),
    ]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    secs = time.perf_counter() - t
    (tmp / f"calibrate_{tag}.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return None, f"calibrate failed (exit {proc.returncode}): " + " | ".join(tail)
    bundle = out / lay.name
    if not (bundle / "manifest.json").exists():
        found = sorted(q.parent for q in out.rglob("manifest.json"))
        if not found:
            return None, f"calibrate wrote no bundle under {out}"
        bundle = found[0]
    lines = [s for s in proc.stdout.strip().splitlines() if s.strip()]
    summary = " | ".join(lines[-2:]) if lines else ""
    return bundle, f"({secs:.0f} s) {summary}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 truths, 4 forces, 3 places")
    ap.add_argument("--truths", help="comma-separated truth names (default: all, or quick's)")
    ap.add_argument("--cal-presses", type=int, help="calibration presses (48; quick 24)")
    ap.add_argument("--no-calibrate", action="store_true", help="default bundle only")
    ap.add_argument("--detail", action="store_true", help="per indenter and place, per row")
    ap.add_argument("--out", type=Path, help="write robust.md and robust.json here")
    ap.add_argument(
        "--float-noise",
        choices=FLOAT_NOISES,
        default="peak",
        help="float tier: 1 %% of the press's largest reading on every taxel (peak, default) or "
        "1 %% of each reading (reading; reports go to robust*_reading.md/.json)",
    )
    ap.add_argument(
        "--layout",
        type=Path,
        default=LAYOUT,
        help="layout whose first patch is under test (default: the hexagon; an imported iCub "
        "patch's reports go to robust_<patch>.md/.json)",
    )
    args = ap.parse_args()
    set_float_noise(args.float_noise)
    threadpool_limits(1)
    t_start = time.perf_counter()
    names = (
        tuple(s.strip() for s in args.truths.split(","))
        if args.truths
        else (QUICK_TRUTHS if args.quick else tuple(TRUTHS))
    )
    for n in names:
        if n not in TRUTHS:
            sys.exit(f"unknown truth {n!r}; known: {', '.join(TRUTHS)}")
    n_cal = args.cal_presses or (N_CAL_QUICK if args.quick else N_CAL)
    if n_cal > N_CAL:
        sys.exit(f"--cal-presses at most {N_CAL}")
    say = Report()
    lay = Patch(args.layout)
    tmp = Path(tempfile.mkdtemp(prefix="bench_robust_"))
    default = default_reconstructor(tmp / "default", args.layout)
    if not np.allclose(default.taxel_xy, lay.xy):
        sys.exit("bundle taxel order differs from the layout's taxel_xy()")
    have_cal = not args.no_calibrate and importlib.util.find_spec(
        "tactile_contact.offline.calibrate"
    )
    if not have_cal and not args.no_calibrate:
        say("NOTE: tactile_contact.offline.calibrate not found: calibrated rows skipped")

    t_sim = time.perf_counter()
    presses = {n: test_presses(lay, n, args.quick) for n in names}
    if have_cal:  # simulated (and cached) before the timed part
        for n in names:
            calibration_presses(lay, n, n_cal)
    sim_secs = time.perf_counter() - t_sim
    n_press = len(next(iter(presses.values()))["f"])
    say(
        f"{n_press} presses per truth ({'quick' if args.quick else 'full'} protocol), "
        f"{n_cal} calibration presses; float: {NOISE_REL:.0%} noise ({args.float_noise}); 8-bit: "
        f"{COUNT_NOISE} counts + rounding (1 count = {lay.lsb * 1e15:.2f} fF)"
    )
    say(f"(forward simulations: {sim_secs:.0f} s, cache {CACHE.relative_to(ROOT)})")
    say()
    head = f"{'truth':16s} {'tier':6s} {'bundle':10s}"
    say(fmt_head(head))
    say(
        f"{'':34s}   (force errors in %: median |error|; bias: median signed error; miss!: "
        f"misses of presses clearly above noise, ‖δ/σ‖ ≥ {CLEAR:g})"
    )
    results: dict[tuple[str, str, str], dict] = {}
    per_press: dict[tuple[str, str, str], dict] = {}
    cal_notes: list[str] = []
    for name in names:
        p = presses[name]
        for tier in TIERS:
            x = readings(lay, p["d"], tier, np.random.default_rng(seed("test", name, tier)))
            if tier == "8-bit":
                over = int(np.sum(np.any(np.abs(x / lay.lsb) > 255, axis=1)))
                if over:
                    cal_notes.append(f"{name} 8-bit: {over} presses read beyond ±255 counts")
            bundles = {"default": default}
            if have_cal:
                path, note = calibrated_bundle(lay, name, tier, n_cal, tmp, args.layout)
                cal_notes.append(f"calibrated {name} / {tier}: {note}")
                if path is not None:
                    bundles["calibrated"] = Reconstructor.from_bundle(path)
                else:
                    say(f"NOTE: {name} / {tier}: {note}")
            for kind, recon in bundles.items():
                r = errors(recon, tier, x, p)
                s = row_stats(r, p["f"], clear_of(lay, p["d"], tier))
                results[(name, tier, kind)] = s
                per_press[(name, tier, kind)] = r
                say(fmt_row(f"{name:16s} {tier:6s} {kind:10s}", s))
                if args.detail:
                    detail(say, r, p)
    say()
    say("worst truth per column (bias: largest |bias|):")
    worst: dict[tuple[str, str], dict] = {}
    for tier in TIERS:
        for kind in ("default", "calibrated"):
            keys = [k for k in results if k[1] == tier and k[2] == kind]
            if not keys:
                continue
            w, who = worst_of([(results[k], k[0]) for k in keys])
            worst[(tier, kind)] = {"value": w, "truth": who}
            say(fmt_row(f"{'WORST':16s} {tier:6s} {kind:10s}", w))
            say(
                f"{'':34s} |"
                + "".join(f"{SHORT.get(who[c], '-'):>{WIDTH.get(c, 7)}s}" for c in COLUMNS)
            )
    say("  (" + ", ".join(f"{v} = {k}" for k, v in SHORT.items()) + ")")
    # Cramér–Rao bound beside the errors.
    say()
    say(
        "Cramér–Rao bound: median |force error| / median σ_F/F bound [%] = ratio, per band "
        "(x, y, F, size unknown, family known;"
    )
    say("an efficient estimator gives ≈ 0.67); CoP: median error / median RMS bound [mm]")
    say(f"{head} | {'0.2 N':>18s} | {'0.5 N':>18s} | {'>=1 N':>18s} | {'CoP mm':>13s}")
    crbs: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        p = presses[name]
        for tier in TIERS:
            sf, sc = crbs.setdefault((name, tier), bounds(lay, p, tier))
            for kind in ("default", "calibrated"):
                if (name, tier, kind) not in per_press:
                    continue
                r = per_press[(name, tier, kind)]
                a = np.where(np.isnan(r["err"]), 100.0, np.abs(r["err"]))
                cells = []
                for band in BANDS:
                    m = bandmask(p["f"], band)
                    if not m.any():
                        cells.append(f"{'-':>18s}")
                        continue
                    e, b = float(np.median(a[m])), float(np.median(sf[m]))
                    cells.append(f"{e:5.1f} /{b:5.2f} ={e / b:5.1f}")
                cop = np.where(np.isnan(r["cop"]), np.inf, r["cop"])
                cells.append(f"{np.median(cop):5.2f} /{np.median(sc):5.3f}")
                say(f"{name:16s} {tier:6s} {kind:10s} | " + " | ".join(cells))
    say()
    tails = tail_by_place(say, names, presses, per_press, crbs)
    if have_cal:
        say()
        say("issue 16 targets, calibrated bundle, worst truth:")
        for tier, col, limit in TARGETS:
            if (tier, "calibrated") not in worst:
                continue
            v = worst[(tier, "calibrated")]["value"][col]
            who = worst[(tier, "calibrated")]["truth"][col]
            ok = "ok  " if v <= limit else "MISS"
            say(f"  {ok} {tier:6s} {col:7s} {v:7.2f} (limit {limit:g}; worst: {who})")
    say()
    for note in cal_notes:
        say(note)
    say(f"({time.perf_counter() - t_start:.0f} s in all)")
    if args.out:
        other = args.layout.resolve() != LAYOUT.resolve()
        shown = args.layout.resolve()
        shown = shown.relative_to(ROOT) if shown.is_relative_to(ROOT) else shown
        stem = f"robust_{lay.name}" if other else "robust"
        if args.quick:
            stem += "_quick"
        if args.float_noise != "peak":
            stem += f"_{args.float_noise}"
        say.write(
            args.out,
            f"{stem}.md",
            "Robustness to the taxel response (bench/bench_robust.py)"
            + (f" on {lay.name} ({shown})" if other else ""),
            f".venv/bin/python bench/bench_robust.py{' --quick' if args.quick else ''} "
            + (f"--layout {shown} " if other else "")
            + (f"--float-noise {args.float_noise} " if args.float_noise != "peak" else "")
            + f"--out {args.out}",
        )
        blob = {
            "rows": [
                {"truth": k[0], "tier": k[1], "bundle": k[2], **v} for k, v in results.items()
            ],
            "worst": [{"tier": k[0], "bundle": k[1], **v} for k, v in worst.items()],
            "tail_by_place": tails,
        }
        (args.out / f"{stem}.json").write_text(json.dumps(blob, indent=1, default=float))


def efficient_p90(sf: np.ndarray, draws: int = 2000) -> float:
    """The p90 of |force error| [%] an efficient unbiased estimator reaches on presses whose
    Cramér–Rao bounds σ_F/F are ``sf`` [%]: median over ``draws`` seeded draws of
    |N(0, σ_F/F)| per press (the bound is local: it holds where the valley is one basin)."""
    rng = np.random.default_rng(26)
    sim = np.abs(rng.normal(size=(draws, len(sf)))) * np.asarray(sf)
    return float(np.median(np.percentile(sim, 90, axis=1)))


def tail_by_place(
    say,
    names: tuple[str, ...],
    presses: dict[str, dict],
    per_press: dict[tuple, dict],
    crbs: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]],
) -> list[dict]:
    """The tail beside the median, per kind of place (issue 26): |force error| [%] of the
    presses of 1 N and more (a miss counts 100 %): median, p90, p99, and the worst press named
    (indenter, force, signed error); CoP error [mm] median and worst; beside them the median
    Cramér–Rao bound σ_F/F [%] of those presses (``crbs``: per truth and tier) and the p90 an
    efficient estimator would reach on them (:func:`efficient_p90`). Returns the rows."""
    from benchkit.protocol import PLACES

    say("tail per kind of place, presses >= 1 N: |force error| % median / p90 / p99, worst press;")
    say("CoP mm median / worst (a miss: 100 % and no CoP); CRB: median Cramér–Rao σ_F/F % of")
    say("those presses / the p90 an efficient estimator reaches on them (|N(0, σ_F)| per press)")
    rows = []
    for key, r in per_press.items():
        name, tier, kind = key
        p = presses[name]
        for place in PLACES:
            m = (p["place"] == place) & (p["f"] >= 1.0)
            if not m.any():
                continue
            e = r["err"][m]
            a = np.where(np.isnan(e), 100.0, np.abs(e))
            i = int(np.argmax(a))
            cop = r["cop"][m]
            worst_press = f"{p['ind'][m][i]} {p['f'][m][i]:g} N " + (
                "missed" if np.isnan(e[i]) else f"{e[i]:+.1f} %"
            )
            row = {
                "truth": name,
                "tier": tier,
                "bundle": kind,
                "place": place,
                "median": float(np.median(a)),
                "p90": float(np.percentile(a, 90)),
                "p99": float(np.percentile(a, 99)),
                "worst": float(a[i]),
                "worst_press": worst_press,
                "cop_median": float(np.nanmedian(cop)) if np.isfinite(cop).any() else np.nan,
                "cop_worst": float(np.nanmax(cop)) if np.isfinite(cop).any() else np.nan,
                "crb_median": float(np.median(crbs[(name, tier)][0][m])),
                "efficient_p90": efficient_p90(crbs[(name, tier)][0][m]),
            }
            rows.append(row)
            say(
                f"{name:16s} {tier:6s} {kind:10s} {place:13s} | {row['median']:5.1f} / "
                f"{row['p90']:5.1f} / {row['p99']:5.1f} | worst {row['worst']:5.1f} "
                f"({worst_press}) | CoP {row['cop_median']:4.2f} / {row['cop_worst']:4.2f} | "
                f"CRB {row['crb_median']:4.1f} / {row['efficient_p90']:4.1f}"
            )
    say()
    say("p90 over all presses (the 'p90' column) beside the p90 an efficient estimator reaches:")
    for (name, tier, kind), r in per_press.items():
        a = np.where(np.isnan(r["err"]), 100.0, np.abs(r["err"]))
        eff = efficient_p90(crbs[(name, tier)][0])
        say(
            f"{name:16s} {tier:6s} {kind:10s} | p90 {np.percentile(a, 90):6.1f} | "
            f"efficient {eff:6.1f}"
        )
    return rows


def detail(say, r: dict[str, np.ndarray], p: dict[str, np.ndarray]) -> None:
    """Per indenter and per place: median |error|, median signed error, misses (all forces)."""
    for key in ("ind", "place"):
        for v in dict.fromkeys(p[key]):
            m = p[key] == v
            e = r["err"][m]
            miss = np.isnan(e)
            a = np.where(miss, 100.0, np.abs(e))
            bias = float(np.median(e[~miss])) if (~miss).any() else np.nan
            say(
                f"      {v:16s} |err| {np.median(a):6.1f} %  bias {bias:+6.1f} %  "
                f"CoP {np.nanmedian(r['cop'][m]) if (~miss).any() else np.nan:5.2f} mm  "
                f"misses {int(miss.sum())}"
            )


if __name__ == "__main__":
    main()
