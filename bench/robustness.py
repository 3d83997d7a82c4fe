"""Accuracy on skins whose taxel response is not the one the bundle assumes, before and after
calibration, beside the Cramér–Rao bound (issue 16).

Truth: tactile_contact.forward.ForwardModel (exact cell-averaged Hertz / flat-punch pressure on
0.25 mm cells, Love kernel) with a taxel response of its own: point values, 2 or 3 mm
electrode means, a gain of 0.85 or 1.15, a layer 10 % thinner or thicker. Protocol (the
paper's): 12 and 6 mm spheres, 12 and 3 mm flat punches × 0.2, 0.5, 1, 1.8, 2.5, 3 N × over a
taxel / between two / between three on two modules (144 presses per truth).

Tiers: ``float`` (Gaussian noise, σ = 1 % of the press's largest reading, solve_deflection
with no noise level) and ``8-bit`` (ΔC in counts with 0.15-count noise, rounded; solve).
Rows: the default bundle (uncalibrated), and a bundle calibrated by tactile-contact-calibrate
on 48 presses at other places (random, ≥ 2 mm from every test place, random indenter,
0.5–3 N) of the same truth and tier. Columns: median |force error| per force band, over
≥ 1 N, overall, p90; median CoP error; misses (no contact reported: counted as 100 %).
Last: per force band the median error beside the median Cramér–Rao bound σ_F/F of the
point-taxel truth (x, y, F and the indenter's size unknown; Jacobian by central differences)
and their ratio.

    .venv/bin/python bench/robustness.py [--quick] [--out docs/bench]

Forward simulations are cached under out/bench-cache (the electrode truths cost ≈ 1.7 s a
press on this machine).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from threadpoolctl import threadpool_limits  # noqa: E402

from tactile_contact.build import build_layout  # noqa: E402
from tactile_contact.calibrate import INDENTERS  # noqa: E402
from tactile_contact.calibrate import main as calibrate_main  # noqa: E402
from tactile_contact.forward import ForwardModel  # noqa: E402
from tactile_contact.indenters import FlatPunch, HertzSphere  # noqa: E402
from tactile_contact.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.sensor import compression_to_delta_c, value_count_farad  # noqa: E402

LAYOUT = ROOT / "config" / "hexagon_patch.yaml"
FORCES = (0.2, 0.5, 1.0, 1.8, 2.5, 3.0)
BANDS = (("0.2 N", (0.2,)), ("0.5 N", (0.5,)), (">=1 N", (1.0, 1.8, 2.5, 3.0)))
#: name → (taxel footprint radius [m], layer thickness scale, gain)
TRUTHS = {
    "point": (0.0, 1.0, 1.0),
    "2 mm electrode": (2e-3, 1.0, 1.0),
    "3 mm electrode": (3e-3, 1.0, 1.0),
    "gain 0.85": (2e-3, 1.0, 0.85),
    "gain 1.15": (2e-3, 1.0, 1.15),
    "layer 0.9": (2e-3, 0.9, 1.0),
    "layer 1.1": (2e-3, 1.1, 1.0),
}
QUICK = ("point", "2 mm electrode", "gain 1.15")
CACHE = ROOT / "out" / "bench-cache"


def positions(xy: np.ndarray, modules=(4, 2)) -> list[np.ndarray]:
    """Over taxel 3, between taxels 7 and 11, at the centroid of 3, 7, 11 of each module."""
    out = []
    for k in modules:
        m = xy[12 * k : 12 * k + 12]
        out += [m[3], (m[7] + m[11]) / 2, (m[3] + m[7] + m[11]) / 3]
    return out


def _model(xy, foot, scale, young=2.1e5, nu=0.5):
    return ForwardModel(xy, 2e-3 * scale, young, nu, fine_cell=2.5e-4, taxel_radius=foot)


def test_presses(name: str, xy: np.ndarray) -> dict[str, np.ndarray]:
    """The protocol's 144 presses of truth ``name`` (cached): deflection [m] before noise."""
    foot, scale, gain = TRUTHS[name]
    key = CACHE / f"test_{foot * 1e3:g}_{scale:g}.npz"
    if not key.exists():
        fm = _model(xy, foot, scale)
        rows = [
            (fm.compression(ind, f, c), f, c, n)
            for (n, ind), c, f in itertools.product(INDENTERS.items(), positions(xy), FORCES)
        ]
        CACHE.mkdir(parents=True, exist_ok=True)
        np.savez(
            key,
            d=np.array([r[0] for r in rows]),
            f=np.array([r[1] for r in rows]),
            c=np.array([r[2] for r in rows]),
            n=np.array([r[3] for r in rows]),
        )
    z = np.load(key)
    return {"d": gain * z["d"], "f": z["f"], "c": z["c"], "n": z["n"]}


def calibration_presses(name: str, xy: np.ndarray, n: int = 48) -> dict[str, np.ndarray]:
    """``n`` presses at random places ≥ 2 mm from every test place (cached, seeded)."""
    foot, scale, gain = TRUTHS[name]
    key = CACHE / f"cal_{foot * 1e3:g}_{scale:g}_{n}.npz"
    if not key.exists():
        fm = _model(xy, foot, scale)
        rng = np.random.default_rng(11)
        tests = np.array(positions(xy))
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        names = list(INDENTERS)
        d, f, c, nm = [], [], [], []
        while len(f) < n:
            p = rng.uniform(lo, hi)
            if np.min(np.hypot(*(xy - p).T)) > 4e-3 or np.min(np.hypot(*(tests - p).T)) < 2e-3:
                continue
            k = names[rng.integers(len(names))]
            force = float(rng.uniform(0.5, 3.0))
            d.append(fm.compression(INDENTERS[k], force, p))
            f.append(force)
            c.append(p)
            nm.append(k)
        CACHE.mkdir(parents=True, exist_ok=True)
        np.savez(key, d=np.array(d), f=np.array(f), c=np.array(c), n=np.array(nm))
    z = np.load(key)
    return {"d": gain * z["d"], "f": z["f"], "c": z["c"], "n": z["n"]}


def noisy(d: np.ndarray, tier: str, recon: Reconstructor, rng) -> np.ndarray:
    """The tier's reading of compressions d (N, K): deflections [m] or ΔC [F]."""
    if tier == "float":
        return d + rng.normal(size=d.shape) * 0.01 * np.abs(d).max(axis=1, keepdims=True)
    p = recon.params
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    dc = compression_to_delta_c(d, p["thickness"], p["epsilon_r"], p["area"])
    return np.rint(dc / lsb + rng.normal(0.0, 0.15, dc.shape)) * lsb


def evaluate(recon: Reconstructor, tier: str, readings, presses) -> dict[str, float]:
    errs, cops, misses = [], [], 0
    for x, f, c in zip(readings, presses["f"], presses["c"], strict=True):
        res = recon.solve_deflection(x) if tier == "float" else recon.solve(x)
        if not res.in_contact:
            misses += 1
            errs.append(100.0)
            cops.append(np.inf)
            continue
        errs.append(abs(res.total_force / f - 1) * 100)
        cops.append(float(np.hypot(*(np.asarray(res.cop) - c))) * 1e3)
    e, cop, fs = np.array(errs), np.array(cops), presses["f"]
    out = {b: float(np.median(e[np.isin(fs, v)])) for b, v in BANDS}
    out |= {
        "overall": float(np.median(e)),
        "p90": float(np.percentile(e, 90)),
        "cop": float(np.median(np.where(np.isfinite(cop), cop, 99.0))),
        "misses": misses,
    }
    return out


def calibrated_bundle(name: str, tier: str, recon, xy, tmp: Path) -> Path:
    cal = calibration_presses(name, xy)
    rng = np.random.default_rng(5)
    x = noisy(cal["d"], tier, recon, rng)
    arrays = {"force": cal["f"], "position": cal["c"], "indenter": cal["n"]}
    if tier == "float":
        arrays["deflection"] = x
    else:
        p = recon.params
        arrays["delta_c"] = x / value_count_farad(p["farad_per_count"], p["shift"])
    path = tmp / f"cal_{abs(hash((name, tier)))}.npz"
    np.savez(path, **arrays)
    out = tmp / f"b_{abs(hash((name, tier)))}"
    if calibrate_main([str(LAYOUT), str(path), "-o", str(out), "--json"]) != 0:
        raise RuntimeError(f"calibration failed for {name} / {tier}")
    return out / "hexagon"


def crb(xy: np.ndarray, presses, tier: str, lsb_m: float) -> np.ndarray:
    """σ_F/F of each press from the point-taxel truth's Jacobian in (x, y, F, size)."""
    fm = _model(xy, 0.0, 1.0)
    out = []
    for _d0, f, c, n in zip(presses["d"], presses["f"], presses["c"], presses["n"], strict=True):
        ind = INDENTERS[str(n)]
        size = ind.radius
        make = HertzSphere if isinstance(ind, HertzSphere) else FlatPunch

        def g(v, make=make):
            return fm.compression(make(v[3]), v[2], v[:2])

        v0 = np.array([c[0], c[1], f, size])
        steps = np.array([1e-5, 1e-5, 1e-3 * f, 1e-3 * size])
        jac = np.column_stack(
            [
                (g(v0 + s * e) - g(v0 - s * e)) / (2 * s)
                for s, e in zip(steps, np.eye(4), strict=True)
            ]
        )
        base = g(v0)
        sigma = 0.01 * np.abs(base).max() if tier == "float" else lsb_m / np.sqrt(12.0)
        fisher = jac.T @ jac / sigma**2
        try:
            cov = np.linalg.inv(fisher)
            out.append(np.sqrt(max(cov[2, 2], 0.0)) / f * 100)
        except np.linalg.LinAlgError:
            out.append(np.inf)
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help=f"truths {', '.join(QUICK)} only")
    ap.add_argument("--out", type=Path, help="write robustness.md here")
    args = ap.parse_args()
    threadpool_limits(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench_robust_"))
    build_layout(LAYOUT, tmp / "default", jobs=1)
    recon = Reconstructor.from_bundle(tmp / "default" / "hexagon")
    xy = recon.taxel_xy
    names = QUICK if args.quick else tuple(TRUTHS)
    lines = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    head = f"{'truth':16s} {'tier':6s} {'bundle':10s} | " + " ".join(f"{b:>6s}" for b, _ in BANDS)
    say(head + " |  all   p90 | CoP mm | misses")
    worst: dict[tuple[str, str], dict[str, float]] = {}
    t0 = time.perf_counter()
    for name in names:
        presses = test_presses(name, xy)
        for tier in ("float", "8-bit"):
            rng = np.random.default_rng(1)
            readings = noisy(presses["d"], tier, recon, rng)
            rows = {"default": evaluate(recon, tier, readings, presses)}
            cal = Reconstructor.from_bundle(calibrated_bundle(name, tier, recon, xy, tmp))
            rows["calibrated"] = evaluate(cal, tier, readings, presses)
            for kind, r in rows.items():
                say(
                    f"{name:16s} {tier:6s} {kind:10s} | "
                    + " ".join(f"{r[b]:6.1f}" for b, _ in BANDS)
                    + f" | {r['overall']:4.1f} {r['p90']:5.1f} | {r['cop']:6.2f} | {r['misses']}"
                )
                w = worst.setdefault((tier, kind), {})
                for k, v in r.items():
                    w[k] = max(w.get(k, 0.0), v)
    say()
    say("worst case over the truths:")
    for (tier, kind), r in worst.items():
        say(
            f"{'WORST':16s} {tier:6s} {kind:10s} | "
            + " ".join(f"{r[b]:6.1f}" for b, _ in BANDS)
            + f" | {r['overall']:4.1f} {r['p90']:5.1f} | {r['cop']:6.2f} | {int(r['misses'])}"
        )
    # Cramér–Rao bound (point-taxel truth) against the calibrated bundle's errors on it.
    say()
    presses = test_presses("point", xy)
    p = recon.params
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    lsb_m = float(recon.compression(np.array([lsb]))[0])
    for tier in ("float", "8-bit"):
        bound = crb(xy, presses, tier, lsb_m)
        rng = np.random.default_rng(1)
        readings = noisy(presses["d"], tier, recon, rng)
        cal = Reconstructor.from_bundle(calibrated_bundle("point", tier, recon, xy, tmp))
        errs = []
        for x, f in zip(readings, presses["f"], strict=True):
            res = cal.solve_deflection(x) if tier == "float" else cal.solve(x)
            errs.append(abs(res.total_force / f - 1) * 100 if res.in_contact else 100.0)
        errs = np.array(errs)
        say(f"Cramér–Rao bound, point-taxel truth, {tier}, calibrated bundle:")
        say(f"  {'force':>6s} | median error % | median CRB % | ratio")
        for f in FORCES:
            m = presses["f"] == f
            e, b = float(np.median(errs[m])), float(np.median(bound[m]))
            say(f"  {f:6.1f} | {e:14.2f} | {b:12.2f} | {e / b:5.1f}")
    say(f"\n({time.perf_counter() - t0:.0f} s)")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        text = "# Robustness to the taxel response (bench/robustness.py)\n\n```\n"
        (args.out / "robustness.md").write_text(text + "\n".join(lines) + "\n```\n")


if __name__ == "__main__":
    main()
