"""Calibration with and without indenter names: the fitted response with its 1-σ errors, whether
tactile-contact-calibrate accepts it, and the force and CoP errors of the bundle it writes on
the same independent presses (issue 26, "Calibration without indenter names").

Truths (:mod:`benchkit.truths`, the fine Love model with a taxel response of its own): ``point``
(point-valued taxels, gain 1, layer 1: the issue's case) and ``gain 1.15`` (a 2 mm electrode,
gain 1.15) by default. Calibration: the bench_robust protocol's 48 presses of the truth at other
places (random indenter of the paper's four, 0.5–3 N, seeded), at the tier's noise, written to
PRESSES.npz with the ``indenter`` key (named) or without it (unnamed), through
``python -m tactile_contact.offline.calibrate LAYOUT PRESSES.npz -o DIR --json`` as a user types
it; an unnamed fit that the command refuses is then written with ``--accept-uncertain`` so the
bundle it would have been is measured too. Evaluation: the paper's protocol (4 indenters × 6
forces × 3 places × modules 4 and 2: 144 presses) on the same truth, through
``solve_deflection`` (float tier) or ``solve`` (8-bit), the same draws for every bundle.

Columns: gain, footprint radius [mm], layer scale, each ± its 1-σ error from the fit's Jacobian;
ok: whether the command wrote the bundle without --accept-uncertain; force error [%]: median
|error| over all presses, over ≥ 1 N, p90 and the worst press; CoP error [mm]: median and p90
of the presses found.

    .venv/bin/python bench/bench_calibration.py [--quick] [--truths point,...] [--tiers float]
        [--out docs/bench]

``--quick``: 24 calibration presses, module 4's places and forces 0.2, 0.5, 1, 3 N (48 presses).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit import LAYOUT, ROOT
from benchkit.protocol import Patch
from benchkit.readings import FLOAT_NOISES, TIERS, readings, seed, set_float_noise
from benchkit.stats import errors
from benchkit.tables import Report
from benchkit.truths import N_CAL, N_CAL_QUICK, SHORT, TRUTHS, calibration_presses, test_presses
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor

DEFAULT_TRUTHS = ("point", "gain 1.15")


def calibrate(npz: Path, out: Path, accept: bool) -> tuple[int, dict | None, str]:
    """Run the command; (exit code, its JSON or None, stderr)."""
    cmd = [sys.executable, "-m", "tactile_contact.offline.calibrate", str(LAYOUT), str(npz)]
    cmd += ["-o", str(out), "--json"] + (["--accept-uncertain"] if accept else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    try:
        doc = json.loads(proc.stdout)
    except json.JSONDecodeError:
        doc = None
    return proc.returncode, doc, proc.stderr.strip()


def stats(r: dict[str, np.ndarray], f: np.ndarray) -> dict[str, float]:
    """Median, ≥ 1 N median, p90 and worst |force error| [%] (a miss counts 100 %); median
    and p90 CoP [mm] over the presses found (a miss has no CoP: as infinite, more than 10 %
    of misses, common at 8 bits, made the p90 NaN)."""
    miss = np.isnan(r["err"])
    a = np.where(miss, 100.0, np.abs(r["err"]))
    cop = r["cop"][~miss]
    return {
        "all": float(np.median(a)),
        ">=1 N": float(np.median(a[f >= 1.0])),
        "p90": float(np.percentile(a, 90)),
        "worst": float(a.max()),
        "cop": float(np.median(cop)) if cop.size else math.nan,
        "cop p90": float(np.percentile(cop, 90)) if cop.size else math.nan,
        "misses": int(miss.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="24 calibration presses, 48 test ones")
    ap.add_argument("--truths", help="comma-separated truth names (default: point, gain 1.15)")
    ap.add_argument("--tiers", default="float", help="comma-separated tiers (float, 8-bit)")
    ap.add_argument("--out", type=Path, help="write calibration.md and calibration.json here")
    ap.add_argument(
        "--float-noise",
        choices=FLOAT_NOISES,
        default="peak",
        help="float tier: 1 %% of the press's largest reading on every taxel (peak, default) or "
        "1 %% of each reading (reading; reports go to calibration_reading.md/.json)",
    )
    args = ap.parse_args()
    set_float_noise(args.float_noise)
    threadpool_limits(1)
    t0 = time.perf_counter()
    names = [s.strip() for s in args.truths.split(",")] if args.truths else DEFAULT_TRUTHS
    tiers = [s.strip() for s in args.tiers.split(",")]
    for n in names:
        if n not in TRUTHS:
            sys.exit(f"unknown truth {n!r}; known: {', '.join(TRUTHS)}")
    for t in tiers:
        if t not in TIERS:
            sys.exit(f"unknown tier {t!r}; known: {', '.join(TIERS)}")
    n_cal = N_CAL_QUICK if args.quick else N_CAL
    lay = Patch()
    tmp = Path(tempfile.mkdtemp(prefix="bench_calibration_"))
    say = Report()
    say(
        f"{n_cal} calibration presses; evaluation: the paper's protocol "
        f"({'quick' if args.quick else 'full'}) on the same truth, the same draws per bundle; "
        f"float noise: 1 % ({args.float_noise})"
    )
    say()
    head = (
        f"{'truth':10s} {'tier':6s} {'indenters':9s} | {'gain':>15s} {'footprint mm':>13s} "
        f"{'layer scale':>13s} {'ok':>3s} | {'all':>5s} {'>=1 N':>5s} {'p90':>6s} "
        f"{'worst':>6s} | {'CoP':>5s} {'p90':>5s} | {'s':>4s}"
    )
    say(head)
    say(f"{'':28s}   (± 1 σ from the fit's Jacobian)     | (force error, %)           | (mm)")
    rows = []
    for name in names:
        p = test_presses(lay, name, args.quick)
        cal = calibration_presses(lay, name, n_cal)
        for tier in tiers:
            x_cal = readings(
                lay, cal["d"], tier, np.random.default_rng(seed("calibration", name, tier))
            )
            defl = x_cal if tier == "float" else lay.to_deflection(x_cal)
            x = readings(lay, p["d"], tier, np.random.default_rng(seed("test", name, tier)))
            for named in (True, False):
                tag = f"{SHORT[name]}_{tier}_{'named' if named else 'unnamed'}".replace("-", "")
                npz = tmp / f"presses_{tag}.npz"
                arrays = {"deflection": defl, "force": cal["f"], "position": cal["c"]}
                if named:
                    arrays["indenter"] = cal["ind"]
                np.savez(npz, **arrays)
                t = time.perf_counter()
                rc, doc, err = calibrate(npz, tmp / tag, accept=False)
                secs = time.perf_counter() - t
                ok = rc == 0
                if not ok and doc is not None and not doc.get("identified", True):
                    rc, doc, err = calibrate(npz, tmp / tag, accept=True)
                if rc != 0 or doc is None:
                    say(
                        f"{name:10s} {tier:6s} {'named' if named else 'unnamed':9s} | FAILED: {err}"
                    )
                    continue
                recon = Reconstructor.from_bundle(Path(doc["bundle"]))
                s = stats(errors(recon, tier, x, p), p["f"])
                sig = doc["uncertainty"]["sigma"]
                row = {
                    "truth": name,
                    "tier": tier,
                    "indenters": "named" if named else "unnamed",
                    "accepted": ok,
                    "gain": doc["gain"],
                    "footprint_radius": doc["footprint_radius"],
                    "layer_scale": doc["layer_scale"],
                    "sigma": sig,
                    "relative_residual": doc["relative_residual"],
                    "report": doc["report"],
                    "seconds": secs,
                    **s,
                }
                rows.append(row)
                say(
                    f"{name:10s} {tier:6s} {row['indenters']:9s} | "
                    f"{doc['gain']:6.3f} ± {sig['gain']:6.3f} "
                    f"{doc['footprint_radius'] * 1e3:5.2f} ± {sig['footprint_radius'] * 1e3:4.2f} "
                    f"{doc['layer_scale']:5.3f} ± {sig['layer_scale']:5.3f} "
                    f"{'yes' if ok else 'no':>3s} | {s['all']:5.1f} {s['>=1 N']:5.1f} "
                    f"{s['p90']:6.1f} {s['worst']:6.1f} | {s['cop']:5.2f} {s['cop p90']:5.2f} "
                    f"| {secs:4.0f}"
                )
    say()
    say("ratio unnamed / named (median |force error|, p90; an unnamed fit refused: ok = no):")
    for name in names:
        for tier in tiers:
            pair = {r["indenters"]: r for r in rows if r["truth"] == name and r["tier"] == tier}
            if len(pair) == 2:
                a, b = pair["unnamed"], pair["named"]
                say(
                    f"  {name:10s} {tier:6s} median {a['all'] / b['all']:4.2f}x, "
                    f"p90 {a['p90'] / b['p90']:4.2f}x; unnamed accepted: "
                    f"{'yes' if a['accepted'] else 'no'}"
                )
    say()
    say("the command's report (first truth and tier):")
    for r in rows[:2]:
        say(f"  {r['indenters']}:")
        for line in r["report"]:
            say(f"    {line}")
    say(f"({time.perf_counter() - t0:.0f} s in all; seconds per calibration on a loaded machine)")
    if args.out:
        stem = "calibration" + (f"_{args.float_noise}" if args.float_noise != "peak" else "")
        say.write(
            args.out,
            f"{stem}.md",
            "Calibration with and without indenter names (bench/bench_calibration.py)",
            f".venv/bin/python bench/bench_calibration.py{' --quick' if args.quick else ''} "
            f"--tiers {','.join(tiers)} --float-noise {args.float_noise} --out {args.out}",
        )
        (args.out / f"{stem}.json").write_text(json.dumps({"rows": rows}, indent=1))


if __name__ == "__main__":
    main()
