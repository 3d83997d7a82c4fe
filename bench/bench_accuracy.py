"""Accuracy of the reconstruction variants on synthetic indentations (docs/reconstruction.md).

Ground truth: tactile_contact.model.forward (exact cell-averaged Hertz / flat-punch pressure on
0.25 mm
cells, Love kernel, mean over each 2 mm electrode, exact capacitance of the deformed plate), then
Gaussian noise of ``--noise`` 8-bit counts and 8-bit quantisation. Indenters: the paper's 12 mm
and 6 mm half-spheres, 12 mm and 3 mm flat cylinders; positions over a taxel, between two,
between three (two modules each); forces 0.2, 0.5, 1, 2, 3 N. Each variant is one bundle built
from config/hexagon_patch.yaml with a few keys changed. Prints median / p90 of the force error
[%], CoP error [mm] and contact-area IoU per variant and per indenter, position and force.

    .venv/bin/python bench/bench_accuracy.py [--noise 0.15] [--quick]
"""

from __future__ import annotations

import argparse
import copy
import itertools
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile_contact.inverse.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.model.forward import ForwardModel  # noqa: E402
from tactile_contact.model.indenters import FlatPunch, HertzSphere  # noqa: E402
from tactile_contact.model.sensor import value_count_farad  # noqa: E402
from tactile_contact.offline.build import build_layout  # noqa: E402

INDENTERS = {
    "sphere 12 mm": HertzSphere(6e-3),
    "sphere 6 mm": HertzSphere(3e-3),
    "cylinder 12 mm": FlatPunch(6e-3),
    "cylinder 3 mm": FlatPunch(1.5e-3),
}
FORCES = (0.2, 0.5, 1.0, 2.0, 3.0)


def positions(xy: np.ndarray, modules=(4, 2)) -> list[tuple[str, np.ndarray]]:
    """Over taxel 3, between taxels 7 and 11, at the centroid of 3, 7, 11 of each module."""
    out = []
    for k in modules:
        m = xy[12 * k : 12 * k + 12]
        out += [
            ("over a taxel", m[3]),
            ("between two", (m[7] + m[11]) / 2),
            ("between three", (m[3] + m[7] + m[11]) / 3),
        ]
    return out


def iou(res, grid, center, radius) -> float:
    """IoU of the reconstructed contact cells and the true contact disc on a 0.1 mm raster."""
    if res.traction is None or not res.in_contact:
        return 0.0
    peak = res.peak_pressure
    on = res.traction > max(0.1 * peak, 100.0)
    ext = radius + 4e-3
    ax = np.arange(-ext, ext, 1e-4)
    xx, yy = np.meshgrid(ax + center[0], ax + center[1])
    true = np.hypot(xx - center[0], yy - center[1]) < radius
    j = np.floor((xx - grid.origin[0]) / grid.cell_size).astype(int)
    i = np.floor((yy - grid.origin[1]) / grid.cell_size).astype(int)
    ok = (i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])
    rec = np.zeros_like(true)
    rec[ok] = on[i[ok], j[ok]]
    union = (true | rec).sum()
    return float((true & rec).sum() / union) if union else 0.0


def make_cases(recon: Reconstructor, noise: float, seed: int, forces=FORCES, cutoff=None):
    p = recon.params
    fm = ForwardModel(
        recon.taxel_xy,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=2.5e-4,
        taxel_radius=p["taxel_radius"],
    )
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    rng = np.random.default_rng(seed)
    cases = []
    for (iname, ind), (pname, c), f in itertools.product(
        INDENTERS.items(), positions(recon.taxel_xy), forces
    ):
        dc = fm.delta_c(ind, f, c, p["epsilon_r"])
        dcq = np.rint((dc + rng.normal(0.0, noise * lsb, dc.shape)) / lsb) * lsb
        a = ind.contact_radius(f, p["young"], p["poisson"])
        cases.append((iname, pname, f, c, a, dcq))
    return cases


def evaluate(recon: Reconstructor, cases) -> list[tuple]:
    rows = []
    for iname, pname, f, c, a, dcq in cases:
        res = recon.solve(dcq)
        ferr = abs(res.total_force / f - 1.0) * 100.0
        cerr = float(np.hypot(*(np.asarray(res.cop) - c)) * 1e3) if res.in_contact else np.inf
        rows.append(
            (iname, pname, f, ferr, cerr, iou(res, recon.traction_grid, c, a), res.solve_time)
        )
    return rows


def stats(rows) -> str:
    a = np.array([r[3:6] for r in rows], dtype=float)
    cop = np.where(np.isfinite(a[:, 1]), a[:, 1], 99.0)
    return (
        f"{np.median(a[:, 0]):6.1f} {np.percentile(a[:, 0], 90):6.1f} | "
        f"{np.median(cop):5.2f} {np.percentile(cop, 90):5.2f} | {np.median(a[:, 2]):4.2f}"
    )


NO = {"refine": "none"}
VARIANTS = {
    "default: round-contact posterior (refine: round)": {},
    "2-pass NNLS λ 0.1, no refinement": {"solver": NO},
    "2-pass NNLS λ 0.01, no refinement": {"solver": {"tikhonov": 0.01, **NO}},
    "2-pass NNLS λ 0.001, no refinement": {"solver": {"tikhonov": 0.001, **NO}},
    "1-pass NNLS λ 0.1 (no support restriction)": {
        "solver": {"seed_fraction": 0.0, "support_radius": 0.1, **NO}
    },
    "2-pass NNLS, Laplacian λ 0.1, no refinement": {"solver": {"regulariser": "laplacian", **NO}},
    "2-pass NNLS, point taxels, no refinement": {
        "model": {"taxel_average": False},
        "solver": NO,
    },
    "2-pass NNLS, 3 mm cells, no refinement": {"grid": {"traction_cell": 0.003}, "solver": NO},
    "2-pass NNLS, 4 mm cells, no refinement": {"grid": {"traction_cell": 0.004}, "solver": NO},
    "2-pass NNLS, ν 0.49 model, no refinement": {"elastomer": {"poisson": 0.49}, "solver": NO},
    "Tikhonov λ 0.1, free only": {"solver": {"method": "tikhonov", **NO}},
    "paper: pseudo-inverse rcond 1e-3": {"solver": {"method": "pinv", **NO}},
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--noise", type=float, default=0.15, help="noise RMS [8-bit counts]")
    ap.add_argument("--quick", action="store_true", help="default, no refinement and pinv")
    ap.add_argument("--detail", action="store_true", help="per indenter/position/force table")
    args = ap.parse_args()
    base = yaml.safe_load((ROOT / "config/hexagon_patch.yaml").read_text())
    tmp = Path(tempfile.mkdtemp(prefix="bench_acc_"))
    quick = list(VARIANTS)[:1] + list(VARIANTS)[2:3] + list(VARIANTS)[-1:]
    names = quick if args.quick else list(VARIANTS)
    cases = None
    print(
        f"noise {args.noise} counts RMS + 8-bit quantisation; 4 indenters × 6 positions × "
        f"{len(FORCES)} forces"
    )
    print(f"{'variant':58s} force err % med p90 | CoP mm med p90 | IoU med | solve ms med")
    for i, name in enumerate(names):
        doc = copy.deepcopy(base)
        for sec, kv in VARIANTS[name].items():
            doc["patches"][0].setdefault(sec, {}).update(kv)
        lay = tmp / f"v{i}.yaml"
        lay.write_text(yaml.safe_dump(doc))
        build_layout(lay, tmp / f"b{i}", jobs=1)
        recon = Reconstructor.from_bundle(tmp / f"b{i}" / "hexagon")
        if cases is None:
            t = time.perf_counter()
            cases = make_cases(recon, args.noise, seed=1)
            print(f"(forward simulation of {len(cases)} cases: {time.perf_counter() - t:.0f} s)")
        rows = evaluate(recon, cases)
        ms = np.median([r[6] for r in rows]) * 1e3
        print(f"{name:58s} {stats(rows)} | {ms:.2f}", flush=True)
        if i == 0 and args.detail:
            for key, label in ((0, "indenter"), (1, "position"), (2, "force N")):
                groups = defaultdict(list)
                for r in rows:
                    groups[r[key]].append(r)
                for k, v in groups.items():
                    print(f"    {label:9s} {k!s:16s} {stats(v)}")


if __name__ == "__main__":
    main()
