"""How often the protocol's 0.2 N presses are detected, per truth and noise setting, beside the
presses a known-shape matched filter would see clearly (issue 16 "Noise-aware detection").

The 0.2 N presses of the paper's protocol (4 indenters × 6 places) on the point-taxel and 2 mm
electrode truths (:mod:`benchkit.truths`), ``--draws`` noise draws each, through the default
bundle in the noise settings of bench/bench_false_alarm.py: the float tier (1 % noise, none
passed), Gaussian at the noise the reconstructor assumes (passed in), the 8-bit tier. Printed:
P(detect) over all presses, per indenter and per place, and of the presses whose ideal
matched-filter statistic ‖δ/σ‖ is ≥ 10 how many there are and P(detect) among them.

    .venv/bin/python bench/bench_detection.py [--quick] [--draws 25] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit.protocol import INDENTERS, PLACES, Patch, default_reconstructor
from benchkit.readings import CLEAR, assumed_noise, clear_of, readings, seed
from benchkit.tables import Report
from benchkit.timing import takes
from benchkit.truths import test_presses
from threadpoolctl import threadpool_limits

SHORT = ("sph12", "sph6", "cyl12", "cyl3", "over", "betw2", "betw3")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="module 4's places, 5 draws")
    ap.add_argument("--draws", type=int, default=25, help="noise draws per 0.2 N press")
    ap.add_argument("--out", type=Path, help="write detection.md here")
    args = ap.parse_args()
    if args.quick:
        args.draws = 5
    threadpool_limits(1)
    r = default_reconstructor(Path(tempfile.mkdtemp(prefix="bench_detect_")))
    lay = Patch()
    sigma0 = assumed_noise(r)
    say = Report()
    say(f"detection of the protocol's 0.2 N presses ({args.draws} noise draws each):")
    say(
        f"{'truth':16s} {'readings':34s} {'all':>6s}"
        + "".join(f"{n:>7s}" for n in SHORT)
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
        if takes(r.solve_deflection, "noise"):
            settings.insert(
                1,
                (
                    "float, assumed noise, passed in",
                    "assumed",
                    lambda x: r.solve_deflection(x, noise=sigma0),
                ),
            )
        for label, tier, solve in settings:
            rng = np.random.default_rng(seed("detect", truth, tier))
            hit = np.zeros((len(d), args.draws), bool)
            for j in range(args.draws):
                if tier == "assumed":
                    x = d + rng.normal(size=d.shape) * sigma0
                else:
                    x = readings(lay, d, tier, rng)
                hit[:, j] = [bool(solve(xi).in_contact) for xi in x]
            per = [hit[ind == n].mean() if np.any(ind == n) else np.nan for n in INDENTERS]
            per += [hit[place == n].mean() if np.any(place == n) else np.nan for n in PLACES]
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
        say.write(
            args.out,
            "detection.md",
            "Detection of light presses (bench/bench_detection.py)",
            f".venv/bin/python bench/bench_detection.py --draws {args.draws} --out {args.out}",
        )


if __name__ == "__main__":
    main()
