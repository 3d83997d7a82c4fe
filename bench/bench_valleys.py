"""No wrong valleys (issue 26): noise-free random presses through a bundle whose response matches
the truth, and how many come back off by more than 5 % of their force or 0.5 mm.

Truth (``--truth``): ``continuum`` (default), the Love layer's compression under the round load
without cells (tactile_contact.model.elastic.axisymmetric: checked against the half-space closed
forms, and the limit the cell model converges to), or ``cells``, the fine forward model
(tactile_contact.model.forward.ForwardModel, exact cell-averaged Hertz and flat-punch pressure
on ``--cell`` cells, 0.25 mm by default, Love kernel: near a punch's edge 0.25 mm cells read
up to 8 % of the peak off the continuum, 0.05 mm cells 5 %), read as point values at the taxel
centres; the bundle: the default patch with ``footprint_radius: 0`` (the response
calibration finds for that truth), as test/test_valleys.py. Presses: a random indenter of the
paper's four (spheres 12 and 6 mm, cylinders 12 and 3 mm), 1–3 N, uniformly anywhere at least
1.5 mm inside the hull of the taxel centres (the skin's edge lies 1.5–2 mm beyond the outer
taxels: ≥ 3 mm from it), through ``solve_deflection`` with no noise level, as a new user would.
Each seed draws its own presses; the worst press of each seed is named.

    .venv/bin/python bench/bench_valleys.py [--seeds 7,2026,11] [--presses 200]
        [--truth continuum|cells] [--cell 2.5e-4] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
import yaml
from benchkit import LAYOUT, ROOT

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.elastic.axisymmetric import round_response
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import save_bundle

INDENTERS = {
    "sphere 12 mm": HertzSphere(6e-3),
    "sphere 6 mm": HertzSphere(3e-3),
    "cylinder 12 mm": FlatPunch(6e-3),
    "cylinder 3 mm": FlatPunch(1.5e-3),
}
#: A press is off when its force is off by more than this share or its CoP by more [m].
FORCE_TOL, COP_TOL = 0.05, 0.5e-3
#: Presses lie at least this far [m] inside the hull of the taxel centres.
MARGIN = 1.5e-3
#: Places by the distance to the nearest taxel [mm] (the taxels are 5.5 mm apart: ≈ 3.2 mm is
#: the middle of three).
PLACES = (
    ("over a taxel (< 1 mm)", 0.0, 1.0),
    ("1-2.5 mm off a taxel", 1.0, 2.5),
    ("between (>= 2.5 mm)", 2.5, np.inf),
)


def matched(folder: Path) -> Reconstructor:
    """The default patch built with point taxels (footprint 0) under ``folder``."""
    doc = copy.deepcopy(yaml.safe_load(LAYOUT.read_text()))
    doc["patches"][0]["model"]["footprint_radius"] = 0.0
    m, a = build_patch(parse_layout(doc).patches[0])
    return Reconstructor.from_bundle(save_bundle(folder / "point", m, a))


class Continuum:
    """The Love layer's compression under a round load without cells (the limit the cell
    model converges to; test/test_elastic_axisymmetric.py), read at the taxel centres."""

    name = "continuum"

    def __init__(self, taxel_xy: np.ndarray, thickness: float, young: float, poisson: float):
        self.xy, self.h, self.young, self.poisson = taxel_xy, thickness, young, poisson

    def compression(self, indenter, force: float, center: np.ndarray) -> np.ndarray:
        profile = "punch" if isinstance(indenter, FlatPunch) else "hertz"
        a = indenter.contact_radius(force, self.young, self.poisson)
        r = np.hypot(*(self.xy - center).T)
        return force * round_response(profile, a, r, self.h, self.young, self.poisson)


def make_truth(recon: Reconstructor, kind: str, cell: float):
    """The truth ``kind`` ("continuum" or "cells" of edge ``cell`` [m]) on ``recon``'s taxels."""
    p = recon.params
    if kind == "continuum":
        return Continuum(recon.taxel_xy, p["thickness"], p["young"], p["poisson"])
    truth = ForwardModel(recon.taxel_xy, p["thickness"], p["young"], p["poisson"], fine_cell=cell)
    truth.name = f"cells of {cell * 1e3:g} mm"
    return truth


def inside(xy: np.ndarray, point: np.ndarray, margin: float) -> bool:
    """Whether ``point`` lies at least ``margin`` [m] inside the convex hull of ``xy``."""
    from scipy.spatial import ConvexHull

    eq = ConvexHull(xy).equations
    return bool((eq[:, :2] @ point + eq[:, 2]).max() <= -margin)


def run_seed(recon: Reconstructor, truth: ForwardModel, seed: int, n: int) -> list[dict]:
    """``n`` random presses of ``seed``: one dict each (indenter, force, centre, errors)."""
    rng = np.random.default_rng(seed)
    xy = recon.taxel_xy
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    names = list(INDENTERS)
    out = []
    while len(out) < n:
        c = rng.uniform(lo, hi)
        if not inside(xy, c, MARGIN):
            continue
        name = names[rng.integers(len(names))]
        force = float(rng.uniform(1.0, 3.0))
        res = recon.solve_deflection(truth.compression(INDENTERS[name], force, c))
        err = res.total_force / force - 1.0 if res.in_contact else -1.0
        off = float(np.hypot(*(np.asarray(res.cop) - c))) if res.in_contact else float("inf")
        near = float(np.hypot(*(xy - c).T).min())
        out.append(
            dict(
                indenter=name,
                force=force,
                x=float(c[0]),
                y=float(c[1]),
                error=err,
                cop=off,
                nearest_taxel=near,
                solver=res.solver,
            )
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="7,2026,11", help="comma-separated seeds")
    ap.add_argument("--presses", type=int, default=200, help="presses per seed")
    ap.add_argument(
        "--truth",
        choices=("continuum", "cells"),
        default="continuum",
        help="continuum: the Love layer without cells (converged limit); cells: ForwardModel",
    )
    ap.add_argument("--cell", type=float, default=2.5e-4, help="--truth cells: cell edge [m]")
    ap.add_argument("--out", type=Path, help="write valleys.md here")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    lines = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    with tempfile.TemporaryDirectory() as tmp:
        recon = matched(Path(tmp))
        truth = make_truth(recon, args.truth, args.cell)
        say(
            f"{args.presses} noise-free presses a seed, 1-3 N, the four indenters, ≥ "
            f"{MARGIN * 1e3:.1f} mm inside the taxel hull; point-taxel truth ({truth.name}), point "
            "bundle; off: "
            f"|force error| > {FORCE_TOL:.0%} or CoP > {COP_TOL * 1e3:.1f} mm"
        )
        say()
        say("seed   presses  off  |err| median  p90   p99    max  | CoP median  p99   max mm | s")
        total_off = total = 0
        offs = []
        every: list[dict] = []
        for s in seeds:
            t0 = time.perf_counter()
            rows = run_seed(recon, truth, s, args.presses)
            dt = time.perf_counter() - t0
            e = np.abs([r["error"] for r in rows]) * 100
            c = np.array([r["cop"] for r in rows]) * 1e3
            bad = [r for r in rows if abs(r["error"]) > FORCE_TOL or r["cop"] > COP_TOL]
            total_off += len(bad)
            total += len(rows)
            offs += [(s, r) for r in bad]
            say(
                f"{s:<6d} {len(rows):7d} {len(bad):4d}  {np.median(e):11.2f} "
                f"{np.percentile(e, 90):5.2f} {np.percentile(e, 99):5.2f} {e.max():6.2f}  | "
                f"{np.median(c):10.3f} {np.percentile(c, 99):5.3f} {c.max():7.3f} | {dt:3.0f}"
            )
            every += rows
        say(f"all    {total:7d} {total_off:4d}")
        say()
        say("per place (distance to the nearest taxel), every seed: |force error| % median / p90 /")
        say("p99 / worst, CoP mm median / worst, presses off")
        near = np.array([r["nearest_taxel"] for r in every]) * 1e3
        for label, lo, hi in PLACES:
            sel = [r for r, n in zip(every, near, strict=True) if lo <= n < hi]
            if not sel:
                continue
            e = np.abs([r["error"] for r in sel]) * 100
            c = np.array([r["cop"] for r in sel]) * 1e3
            n_off = sum(abs(r["error"]) > FORCE_TOL or r["cop"] > COP_TOL for r in sel)
            say(
                f"  {label:<22s} {len(sel):4d} | {np.median(e):5.2f} / {np.percentile(e, 90):5.2f}"
                f" / {np.percentile(e, 99):5.2f} / {e.max():6.2f} | {np.median(c):5.3f} / "
                f"{c.max():5.3f} | off {n_off}"
            )
        say()
        if offs:
            say("presses off (seed: indenter, force, centre mm, nearest taxel mm, error, CoP mm):")
            for s, r in offs:
                say(
                    f"  {s}: {r['indenter']}, {r['force']:.2f} N, ({r['x'] * 1e3:.2f}, "
                    f"{r['y'] * 1e3:.2f}), {r['nearest_taxel'] * 1e3:.2f}, "
                    f"{r['error'] * 100:+.1f} %, {r['cop'] * 1e3:.2f} ({r['solver']})"
                )
        else:
            say("no press off")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        cmd = " ".join(["bench/bench_valleys.py", *sys.argv[1:]])
        title = "# No wrong valleys (bench/bench_valleys.py)"
        body = "\n".join(lines)
        (args.out / "valleys.md").write_text(
            f"{title}\n\n`.venv/bin/python {cmd}` (from {ROOT.name})\n\n```\n{body}\n```\n"
        )


if __name__ == "__main__":
    main()
