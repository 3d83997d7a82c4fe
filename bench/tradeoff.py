"""Run time against error over models, grids, solvers and noise (``make bench``).

The paper's protocol in simulation (bench/bench_accuracy.py builds the cases): 12 mm and 6 mm
half-spheres, 12 mm and 3 mm flat cylinders; over a taxel, between two, between three; forces
0.2–3 N; the ground truth from the independent fine forward model (0.25 mm cells, electrode
average, exact capacitance), then noise and 8-bit quantisation. The driver's baseline is a mean
of quantised samples, so the ``+offsets`` noise levels add a fixed offset of up to ±½ count to
every taxel, as a real skin reads.

One factor at a time around the default (config/hexagon_patch.yaml) plus the paper's methods:
model (Love, Boussinesq–Cerruti with Ψ exact and Ψ = 0.25), traction cell (1–4 mm), solver
(pinv, Tikhonov, TSVD, NNLS, NNLS+Tikhonov two-pass = default, + round-contact refinement),
noise. Per configuration: offline build time and peak memory, online time per frame (median,
p99, warm), errors (total force, CoP, contact-area IoU). Writes ``results.json``,
``tradeoff.png`` (online time against force and CoP error, Pareto front marked) and
``tradeoff.md``; ``--replot`` redraws them from the JSON.

    python bench/tradeoff.py --out docs/bench [--quick] [--replot]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_accuracy import INDENTERS, iou, positions  # noqa: E402

from tactile_contact.build import build_patch  # noqa: E402
from tactile_contact.bundle import save_bundle  # noqa: E402
from tactile_contact.forward import ForwardModel  # noqa: E402
from tactile_contact.layout import parse_layout  # noqa: E402
from tactile_contact.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.sensor import value_count_farad  # noqa: E402

# name → layout sections to change; the default first.
CONFIGS: dict[str, dict] = {
    "default (Love, 2 mm, 2-pass NNLS+Tikhonov)": {},
    "+ round-contact refinement": {"solver": {"refine": "axisymmetric"}},
    "B-C, Ψ exact": {"model": {"kind": "boussinesq", "psi": "exact"}},
    "B-C, Ψ = 0.25": {"model": {"kind": "boussinesq", "psi": 0.25}},
    "1 mm cells": {"grid": {"traction_cell": 0.001}},
    "3 mm cells": {"grid": {"traction_cell": 0.003}},
    "4 mm cells": {"grid": {"traction_cell": 0.004}},
    "NNLS (λ 0.001)": {"solver": {"tikhonov": 0.001}},
    "Tikhonov λ 0.1 (free)": {"solver": {"method": "tikhonov"}},
    "TSVD rank 20": {"solver": {"method": "tsvd", "tsvd_rank": 20}},
    "paper: pinv": {"solver": {"method": "pinv"}},
}
QUICK = ("default (Love, 2 mm, 2-pass NNLS+Tikhonov)", "B-C, Ψ = 0.25", "3 mm cells", "paper: pinv")
NOISE = {
    "none": (0.0, False),
    "0.15 count": (0.15, False),
    "0.15 count +offsets": (0.15, True),
    "0.3 count +offsets": (0.3, True),
}
QUICK_NOISE = ("0.15 count +offsets",)


def build(doc: dict, folder: Path) -> tuple[Reconstructor, float, float]:
    """Bundle of one configuration: (reconstructor, build time [s], peak memory [MB])."""
    patch = parse_layout(doc).patches[0]
    tracemalloc.start()
    t0 = time.perf_counter()
    manifest, arrays = build_patch(patch)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return (
        Reconstructor.from_bundle(save_bundle(folder / patch.name, manifest, arrays)),
        seconds,
        peak,
    )


def truth_cases(recon: Reconstructor, forces: tuple[float, ...], modules: tuple[int, ...]) -> list:
    """Exact ΔC [F] of every (indenter, position, force), before noise."""
    p = recon.params
    fm = ForwardModel(
        recon.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, p["taxel_radius"]
    )
    return [
        (ind, pname, f, c, ind.contact_radius(f, p["young"], p["poisson"]),
         fm.delta_c(ind, f, c, p["epsilon_r"]))
        for iname, ind in INDENTERS.items()
        for pname, c in positions(recon.taxel_xy, modules)
        for f in forces
    ]  # fmt: skip


def noisy(cases: list, lsb: float, rms: float, offsets: bool, seed: int) -> list:
    rng = np.random.default_rng(seed)
    out = []
    for ind, pname, f, c, a, dc in cases:
        v = dc + rng.normal(0.0, rms * lsb, dc.shape)
        q = np.rint(v / lsb) * lsb
        if offsets:
            q = q + rng.uniform(-0.5, 0.5, dc.shape) * lsb
        out.append((ind, pname, f, c, a, q))
    return out


def evaluate(recon: Reconstructor, cases: list) -> dict:
    """Errors of one configuration. Relative L2 errors compare with the true pressure averaged
    exactly over each traction cell, and with the deflection that pressure gives through the
    bundle's own deflection operator (so the deflection error is the reconstruction's, not the
    grid's)."""
    recon.solve(cases[0][5])  # warm: first-frame caches
    grid = recon.traction_grid
    centers, halves = grid.centers(), grid.half_sizes()
    g_out = np.asarray(recon.bundle["deflection_operator"], dtype=np.float64)
    p = recon.params
    times, ferr, cop, ious, seen, l2t, l2d = [], [], [], [], [], [], []
    for ind, _, f, c, a, dc in cases:
        t0 = time.perf_counter()
        res = recon.solve(dc)
        times.append(time.perf_counter() - t0)
        true_q = ind.pressure_on_cells(centers, halves, f, c, p["young"], p["poisson"])
        est_q = res.traction[grid.mask] if res.traction is not None else np.zeros_like(true_q)
        l2t.append(np.linalg.norm(est_q - true_q) / np.linalg.norm(true_q))
        true_d, est_d = g_out @ true_q, g_out @ est_q
        l2d.append(np.linalg.norm(est_d - true_d) / np.linalg.norm(true_d))
        ferr.append(abs(res.total_force / f - 1.0) * 100.0)
        seen.append(bool(res.in_contact))
        cop.append(float(np.hypot(*(np.asarray(res.cop) - c))) * 1e3 if res.in_contact else 99.0)
        ious.append(iou(res, recon.traction_grid, c, a))
    t = np.asarray(times) * 1e3
    return {
        "online_ms_median": float(np.median(t)),
        "online_ms_p99": float(np.percentile(t, 99)),
        "force_err_pct_median": float(np.median(ferr)),
        "force_err_pct_p90": float(np.percentile(ferr, 90)),
        "cop_mm_median": float(np.median(cop)),
        "cop_mm_p90": float(np.percentile(cop, 90)),
        "iou_median": float(np.median(ious)),
        "l2_traction_median": float(np.median(l2t)),
        "l2_deflection_median": float(np.median(l2d)),
        "detected": float(np.mean(seen)),
    }


def pareto(rows: list[dict], key: str) -> list[bool]:
    """Rows not dominated in (online time, error ``key``)."""
    out = []
    for r in rows:
        out.append(
            not any(
                o["online_ms_median"] <= r["online_ms_median"]
                and o[key] <= r[key]
                and (o["online_ms_median"] < r["online_ms_median"] or o[key] < r[key])
                for o in rows
            )
        )
    return out


def render(results: dict, out: Path) -> None:
    """tradeoff.md and tradeoff.png from the results dictionary."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["rows"]
    lines = [
        f"Cases: {results['cases']} (indenters × positions × forces), hexagon patch, "
        f"{results['machine']}. Errors: median (p90). `+offsets`: every taxel also carries a "
        "fixed baseline offset of up to ±½ count, as a real driver's baseline does.",
        "",
        "| configuration | noise | build s | build MB | online ms med (p99) | force err % | "
        "CoP mm | IoU | L2 traction | L2 deflection | detected |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['config']} | {r['noise']} | {r['build_s']:.2f} | {r['build_mb']:.0f} | "
            f"{r['online_ms_median']:.2f} ({r['online_ms_p99']:.2f}) | "
            f"{r['force_err_pct_median']:.1f} ({r['force_err_pct_p90']:.0f}) | "
            f"{r['cop_mm_median']:.2f} ({r['cop_mm_p90']:.1f}) | {r['iou_median']:.2f} | "
            f"{r['l2_traction_median']:.2f} | {r['l2_deflection_median']:.2f} | "
            f"{r['detected'] * 100:.0f} % |"
        )
    target = [
        r
        for r in rows
        if r["force_err_pct_median"] <= 10
        and r["cop_mm_median"] <= 1
        and r["online_ms_median"] <= 1
    ]
    lines += [
        "",
        "Target (force ≤ 10 %, CoP ≤ 1 mm median, ≤ 1 ms online): "
        + (", ".join(f"{r['config']} ({r['noise']})" for r in target) if target else "not met"),
    ]
    (out / "tradeoff.md").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), layout="constrained")
    for ax, key, label in (
        (axes[0], "force_err_pct_median", "total force error, median [%]"),
        (axes[1], "cop_mm_median", "CoP error, median [mm]"),
    ):
        noises = sorted({r["noise"] for r in rows})
        for k, (noise, marker) in enumerate(zip(noises, "osD^v", strict=False)):
            colour = f"C{k}"
            sub = [r for r in rows if r["noise"] == noise]
            front = pareto(sub, key)
            for r, f in zip(sub, front, strict=True):
                ax.scatter(
                    r["online_ms_median"],
                    r[key],
                    marker=marker,
                    s=60 if f else 25,
                    c=colour if f else "lightgrey",
                    edgecolors="k" if f else "none",
                )
                ax.annotate(
                    r["config"],
                    (r["online_ms_median"], r[key]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
            pts = sorted(
                (r["online_ms_median"], r[key]) for r, f in zip(sub, front, strict=True) if f
            )
            ax.step(
                *zip(*pts, strict=True),
                where="post",
                c=colour,
                lw=1,
                label=f"Pareto front, noise {noise}",
            )
        ax.set_xscale("log")
        ax.set_xlabel("online time per patch frame, median [ms]")
        ax.set_ylabel(label)
        ax.axvline(1.0, c="grey", ls=":", lw=1)
        ax.axhline(10.0 if key.startswith("force") else 1.0, c="grey", ls=":", lw=1)
        ax.legend(fontsize=7)
    fig.suptitle(
        "tactile_contact: online time against error per noise level "
        "(large markers: Pareto front; grey: dominated)"
    )
    fig.savefig(out / "tradeoff.png", dpi=100)
    plt.close(fig)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench")
    ap.add_argument("--quick", action="store_true", help="4 configurations, 1 noise, fewer cases")
    ap.add_argument("--replot", action="store_true", help="redraw from OUT/results.json")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        render(json.loads((args.out / "results.json").read_text()), args.out)
        return
    base = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
    tmp = Path(tempfile.mkdtemp(prefix="tradeoff_"))
    names = QUICK if args.quick else tuple(CONFIGS)
    noises = QUICK_NOISE if args.quick else tuple(NOISE)
    forces = (0.5, 1.0, 3.0) if args.quick else (0.2, 0.5, 1.0, 1.8, 2.5, 3.0)
    modules = (4,) if args.quick else (4, 2)
    t_start = time.perf_counter()
    rows, exact = [], None
    for i, name in enumerate(names):
        doc = copy.deepcopy(base)
        for sec, kv in CONFIGS[name].items():
            doc["patches"][0].setdefault(sec, {}).update(kv)
        recon, build_s, build_mb = build(doc, tmp / f"c{i}")
        if exact is None:
            exact = truth_cases(recon, forces, modules)
        lsb = value_count_farad(recon.params["farad_per_count"], recon.params["shift"])
        for noise in noises:
            rms, offsets = NOISE[noise]
            r = evaluate(recon, noisy(exact, lsb, rms, offsets, seed=7))
            rows.append(
                {"config": name, "noise": noise, "build_s": build_s, "build_mb": build_mb, **r}
            )
            print(
                f"{name:44s} {noise:20s} build {build_s:5.2f} s {build_mb:5.0f} MB | "
                f"{r['online_ms_median']:6.2f} ms | force {r['force_err_pct_median']:5.1f} % | "
                f"CoP {r['cop_mm_median']:5.2f} mm | IoU {r['iou_median']:.2f}",
                flush=True,
            )
    results = {
        "cases": len(exact or []),
        "machine": "2-core machine, one process",
        "seconds": time.perf_counter() - t_start,
        "rows": rows,
    }
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    render(results, args.out)
    print(
        f"wrote {args.out / 'results.json'}, tradeoff.png, tradeoff.md "
        f"in {results['seconds']:.0f} s"
    )


if __name__ == "__main__":
    main()
