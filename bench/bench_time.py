"""A press held still is measured better the longer it is held (issue 26 "Time"): single frames
and fused frames beside the Cramér–Rao bound for N frames, and a sliding press's lag.

Readings: 8-bit whole counts of a truth's compressions through the layout's sensor model, with
Gaussian converter noise of 0.5 count before rounding (issue 26's tier), drawn anew every
frame; each taxel's noise passed in as the node's tracker learns it (one count·√(0.5² + 1/12)
of compression). Truths (benchkit.truths, the fine forward model on 0.25 mm cells): a taxel
response other than the default bundle's 2 mm electrode mean (``point`` taxels; ``3 mm
electrode``, ...).

Held presses: the robust bench's protocol (4 indenters × 6 forces 0.2–3 N × 6 places), each
after IDLE frames without contact and then held HOLD frames; the result after N = 1, 2, 5, 10,
20, 50 frames of the press:

    single   Reconstructor(follow=True): every frame solved on its own (the node before fusion)
    fused    Reconstructor(follow=True, fuse=True) (inverse/temporal.py)

Bundles: ``default`` (config/hexagon_patch.yaml) and ``calibrated`` on 48 single-frame presses
of the same truth at the same noise (``python -m tactile_contact.offline.calibrate``, named
indenters). Columns: median |force error| [%] at 0.2 N and 0.5 N (misses of the 24 at 0.5 N),
over ≥ 1 N (median, p90, the worst with its press), CoP median [mm] over ≥ 1 N, the median
Cramér–Rao bound σ_F/F at ≥ 1 N for N frames (one frame's, from the truth's Jacobian in x, y,
F, indenter size with the family known, over √N) and the median error over it (an efficient
estimator: 0.67). A missed press counts 100 %.

Sliding presses: a 12 mm sphere at 1.5 N and a 6 mm sphere at 1 N slide 45 mm across the patch
(taxel 23 → taxel 55) at 0.05–1 mm a frame (2.5–50 mm/s at 50 Hz), point-taxel truth, the
calibrated bundle; lag = how far the reported CoP trails the truth along the path, in frames
(median; single frames for comparison), with the force and CoP errors and the solves a frame.

    .venv/bin/python bench/bench_time.py [--quick] [--truths point,...] [--out docs/bench]

``--quick``: module 4's places and 4 forces, 20 held frames, the two slowest slides.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit import LAYOUT, ROOT
from benchkit.calibration import calibrated_bundle
from benchkit.protocol import Patch
from benchkit.readings import seed
from benchkit.stats import crb
from benchkit.tables import Report, md_table
from benchkit.truths import SHORT, TRUTHS, calibration_presses, test_presses, truth
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.offline.build import build_layout

COUNT_NOISE = 0.5  # converter noise [counts RMS], issue 26's tier
IDLE, HOLD, HOLD_QUICK = 10, 50, 20
AT = (1, 2, 5, 10, 20, 50)
N_CAL = 48
SLIDE_CACHE = ROOT / "out" / "bench-time-cache"
SLIDES = {"sphere 12 mm": (HertzSphere(6e-3), 1.5), "sphere 6 mm": (HertzSphere(3e-3), 1.0)}
SLIDE_STEP = 5e-5  # path sampled every 0.05 mm
SPEEDS = (1, 2, 4, 10, 20)  # path samples a frame: 0.05 … 1 mm a frame
#: Issue 26's targets after 10 frames: ≥ 1 N median [%], 0.5 N median [%] (and detected).
TARGET_HIGH, TARGET_HALF = 8.0, 25.0


def frame_noise(lay: Patch) -> float:
    """One frame's compression noise [m] at small readings: the converter's and the rounding."""
    return float(lay.to_deflection(np.array([lay.lsb]))[0]) * math.hypot(COUNT_NOISE, 12**-0.5)


def frames(lay: Patch, d: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n frames of ΔC [F] of compressions d (K,) [m]: whole counts, noise before rounding."""
    counts = lay.to_delta_c(d) / lay.lsb
    return np.rint(counts + rng.normal(0.0, COUNT_NOISE, (n, len(d)))) * lay.lsb


def calibrate(lay: Patch, name: str, folder: Path) -> tuple[Path | None, str]:
    """A bundle calibrated on N_CAL single-frame presses of the truth at this noise."""
    cal = calibration_presses(lay, name, N_CAL)
    rng = np.random.default_rng(seed("time-calibration", name))
    dc = np.array([frames(lay, d, 1, rng)[0] for d in cal["d"]])
    return calibrated_bundle(lay, cal, dc, folder, SHORT[name])


def held(recon: Reconstructor, lay: Patch, p: dict, hold: int, name: str) -> dict:
    """Per press: the result after each N in AT (signed force error [%], NaN: missed; CoP
    error [mm]), of one reconstructor fed IDLE idle frames then the press, press after press.
    The fusion (if any) and the followed contact start afresh for each press."""
    sigma = np.full(recon.n_taxels, frame_noise(lay))
    at = [n for n in AT if n <= hold]
    err = np.full((len(p["f"]), len(at)), np.nan)
    cop = np.full_like(err, np.nan)
    solves = 0
    for i, (d, f, c) in enumerate(zip(p["d"], p["f"], p["c"], strict=True)):
        rng = np.random.default_rng(seed("time", name, str(i)))
        if recon.fusion is not None:
            recon.fusion.reset()
        recon.followed = None
        for dc in frames(lay, np.zeros_like(d), IDLE, rng):
            recon.solve(dc, noise=sigma, want_traction=False, want_deflection=False)
        for k, dc in enumerate(frames(lay, d, hold, rng), 1):
            res = recon.solve(dc, noise=sigma, want_traction=False, want_deflection=False)
            solves += recon.fusion is None or recon.fusion.last != "held"
            if k in at and res.in_contact:
                j = at.index(k)
                err[i, j] = (res.total_force / f - 1.0) * 100.0
                cop[i, j] = float(np.hypot(*(np.asarray(res.cop) - c))) * 1e3
    return {"err": err, "cop": cop, "at": at, "solves": solves / (len(p["f"]) * (hold + IDLE))}


def one_frame_bound(lay: Patch, p: dict) -> np.ndarray:
    """Per press: Cramér–Rao σ_F/F [%] of one frame at this noise (readings in ΔC)."""
    out = []
    sigma = np.full(len(lay.xy), lay.lsb * math.hypot(COUNT_NOISE, 12**-0.5))
    for d, jac, f in zip(p["d"], p["J"], p["f"], strict=True):
        eps = 1e-9
        slope = (lay.to_delta_c(d + eps) - lay.to_delta_c(d - eps)) / (2 * eps)
        out.append(crb(slope[:, None] * jac, sigma, float(f))[0])
    return np.array(out)


def information(recon: Reconstructor, lay: Patch, p: dict, i: int) -> str:
    """What press ``i`` gives a detector, noise-free: its largest reading [counts] and the
    matched-filter statistic z₁ [σ] of one frame (the bank's best filter on its noiseless
    readings at this noise); a mean of n frames reaches z₁·√n, so the frames it needs before
    z clears the detection threshold (the information limit, whatever the fusion does)."""
    det = copy.deepcopy(recon.detector)  # the caller's keeps its noise
    det.set_noise(np.full(recon.n_taxels, frame_noise(lay)))
    z1 = det.statistic(p["d"][i])[0]
    top = float(np.abs(lay.to_delta_c(p["d"][i])).max() / lay.lsb)
    need = math.ceil((det.threshold / z1) ** 2) if z1 > 0 else math.inf
    return (
        f"{p['ind'][i]}, {p['place'][i]}, {p['f'][i]:g} N: largest reading {top:.2f} counts, "
        f"z of one noiseless frame {z1:.2f} σ → {need} frames to reach the threshold "
        f"{det.threshold:.2f}"
    )


def rows(r: dict, p: dict, bound: np.ndarray) -> list[list[str]]:
    """Table rows, one per N."""
    f = p["f"]
    hi, half, low = f >= 1.0, np.isclose(f, 0.5), np.isclose(f, 0.2)
    out = []
    for j, n in enumerate(r["at"]):
        e = r["err"][:, j]
        a = np.where(np.isnan(e), 100.0, np.abs(e))
        worst = int(np.argmax(np.where(hi, a, -1.0)))
        who = f"{p['ind'][worst]}, {p['place'][worst]}, {f[worst]:g} N"
        b = float(np.median(bound[hi])) / math.sqrt(n)
        med = float(np.median(a[hi]))
        out.append(
            [
                str(n),
                f"{np.median(a[low]):.1f}" if low.any() else "-",
                f"{np.median(a[half]):.1f} ({int(np.isnan(e[half]).sum())}/{half.sum()})"
                if half.any()
                else "-",
                f"{med:.1f}",
                f"{np.percentile(a[hi], 90):.1f}",
                f"{a[worst]:.0f} ({who})",
                f"{np.nanmedian(r['cop'][hi, j]):.2f}",
                f"{b:.1f}",
                f"{med / b:.1f}",
            ]
        )
    return out


HEAD = ["N", "0.2 N", "0.5 N (missed)", ">=1 N", "p90", "worst >=1 N", "CoP mm", "CRB %", "ratio"]


# --- sliding presses ------------------------------------------------------------------------


def slide_truth(lay: Patch, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(path (P, 2) [m], compressions (P, K) [m]) of a point-taxel truth along the path, cached
    (≈ 30–80 s per indenter the first time)."""
    a, b = lay.xy[23], lay.xy[55]
    length = float(np.hypot(*(b - a)))
    s = np.arange(0.0, length + 1e-12, SLIDE_STEP)
    path = a + (b - a) / length * s[:, None]
    SLIDE_CACHE.mkdir(parents=True, exist_ok=True)
    key = SLIDE_CACHE / f"slide_point_{name.replace(' ', '')}_{len(path)}.npz"
    if not key.exists():
        ind, force = SLIDES[name]
        made = truth(lay, "point")
        d = np.array([made.presses(ind, [force], c, jacobian=False)[0][0] for c in path])
        np.savez(key, path=path, d=d)
    z = np.load(key)
    return z["path"], z["d"]


def slide(recon: Reconstructor, lay: Patch, name: str, step: int) -> dict[str, float]:
    """Force [%] and CoP [mm] medians, lag [frames] (median of the along-path CoP offset over
    the distance a frame), misses and solves a frame of a press sliding ``step`` samples a
    frame."""
    path, d = slide_truth(lay, name)
    force = SLIDES[name][1]
    idx = np.arange(0, len(path), step)
    u = (path[-1] - path[0]) / np.hypot(*(path[-1] - path[0]))
    per_frame = step * SLIDE_STEP
    rng = np.random.default_rng(seed("slide", name, str(step)))
    sigma = np.full(recon.n_taxels, frame_noise(lay))
    if recon.fusion is not None:
        recon.fusion.reset()
    recon.followed = None
    fe, ce, lag, solves = [], [], [], 0
    for j in idx:
        dc = frames(lay, d[j], 1, rng)[0]
        res = recon.solve(dc, noise=sigma, want_traction=False, want_deflection=False)
        solves += recon.fusion is None or recon.fusion.last != "held"
        if not res.in_contact:
            fe.append(100.0)
            continue
        fe.append(abs(res.total_force / force - 1.0) * 100.0)
        off = np.asarray(res.cop) - path[j]
        ce.append(float(np.hypot(*off)) * 1e3)
        lag.append(-float(off @ u) / per_frame)
    return {
        "force": float(np.median(fe)),
        "cop": float(np.median(ce)),
        "lag": float(np.median(lag)),
        "lag_mm": float(np.median(lag)) * per_frame * 1e3,
        "miss": len(idx) - len(ce),
        "frames": len(idx),
        "solves": solves / len(idx),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="module 4's places, 4 forces")
    ap.add_argument("--truths", default="point", help="comma-separated truths (benchkit)")
    ap.add_argument("--no-slides", action="store_true", help="held presses only")
    ap.add_argument("--out", type=Path, help="write time.md here")
    args = ap.parse_args()
    threadpool_limits(1)
    t_start = time.perf_counter()
    names = [s.strip() for s in args.truths.split(",")]
    for n in names:
        if n not in TRUTHS or n == "2 mm electrode":
            sys.exit(f"truth {n!r}: one of {', '.join(t for t in TRUTHS if t[0] != '2')}")
    say = Report()
    lay = Patch()
    tmp = Path(tempfile.mkdtemp(prefix="bench_time_"))
    build_layout(LAYOUT, tmp / "default", jobs=1)
    default = tmp / "default" / "hexagon"
    hold = HOLD_QUICK if args.quick else HOLD
    say(
        f"8-bit readings, {COUNT_NOISE} count converter noise before rounding; {IDLE} idle "
        f"frames, then each press held {hold} frames; one frame's noise "
        f"{frame_noise(lay) * 1e6:.2f} µm passed in"
    )
    targets: list[tuple[str, float, int, float, int]] = []
    calibrated: dict[str, Path] = {}
    for name in names:
        p = test_presses(lay, name, args.quick)
        bound = one_frame_bound(lay, p)
        path, note = calibrate(lay, name, tmp)
        say()
        say(f"## truth: {name} ({len(p['f'])} presses)")
        say(f"calibrated: {note}")
        bundles = {"default": default}
        if path is not None:
            bundles["calibrated"] = calibrated[name] = path
        for kind, bundle in bundles.items():
            for mode in ("single", "fused"):
                recon = Reconstructor.from_bundle(bundle, follow=True, fuse=mode == "fused")
                recon.warm_up()
                t0 = time.perf_counter()
                r = held(recon, lay, p, hold, name)
                say()
                say(
                    f"{name} / {kind} / {mode}: {r['solves']:.2f} solves a frame "
                    f"({time.perf_counter() - t0:.0f} s)"
                )
                table = rows(r, p, bound)
                for line in md_table(HEAD, table):
                    say(line)
                if kind == "calibrated" and mode == "fused" and 10 in r["at"]:
                    j = r["at"].index(10)
                    e, f = r["err"][:, j], p["f"]
                    for i in np.flatnonzero(np.isnan(e) & (f >= 0.5)):
                        say(f"  missed after 10 frames: {information(recon, lay, p, int(i))}")
                    a = np.where(np.isnan(e), 100.0, np.abs(e))
                    half = np.isclose(f, 0.5)
                    targets.append(
                        (
                            name,
                            float(np.median(a[f >= 1.0])),
                            int(np.isnan(e[half]).sum()),
                            float(np.median(a[half])),
                            int(half.sum()),
                        )
                    )
    if targets:
        say()
        say("issue 26 targets after 10 frames (calibrated, fused):")
        for name, high, missed, half, n_half in targets:
            ok1 = "ok  " if high <= TARGET_HIGH else "MISS"
            ok2 = "ok  " if half <= TARGET_HALF else "MISS"
            say(f"  {ok1} {name}: >= 1 N median {high:.1f} % (limit {TARGET_HIGH:g})")
            say(
                f"  {ok2} {name}: 0.5 N median {half:.1f} % (limit {TARGET_HALF:g}), "
                f"{missed} of {n_half} missed"
            )
    if not args.no_slides and "point" in calibrated:
        say()
        say("## sliding presses (point-taxel truth, calibrated bundle)")
        head = ["press", "mm/frame", "mode", "force %", "CoP mm", "lag frames", "lag mm"]
        head += ["missed", "solves/frame"]
        table = []
        for name in SLIDES:
            for step in SPEEDS[:2] if args.quick else SPEEDS:
                for mode in ("single", "fused"):
                    recon = Reconstructor.from_bundle(
                        calibrated["point"], follow=True, fuse=mode == "fused"
                    )
                    s = slide(recon, lay, name, step)
                    table.append(
                        [
                            name,
                            f"{step * SLIDE_STEP * 1e3:.2f}",
                            mode,
                            f"{s['force']:.1f}",
                            f"{s['cop']:.2f}",
                            f"{s['lag']:.1f}",
                            f"{s['lag_mm']:.2f}",
                            f"{s['miss']}/{s['frames']}",
                            f"{s['solves']:.2f}",
                        ]
                    )
        for line in md_table(head, table):
            say(line)
    say()
    say(f"({time.perf_counter() - t_start:.0f} s in all)")
    if args.out:
        cmd = "bench/bench_time.py" + (" --quick" if args.quick else "")
        if args.truths != "point":
            cmd += f" --truths '{args.truths}'"
        args.out.mkdir(parents=True, exist_ok=True)
        body = "\n".join(say.lines)
        title = "# Held presses over time (bench/bench_time.py)"
        (args.out / "time.md").write_text(f"{title}\n\n`.venv/bin/python {cmd}`\n\n{body}\n")


if __name__ == "__main__":
    main()
