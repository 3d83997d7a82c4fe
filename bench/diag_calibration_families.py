"""Presses without indenter names (issue 26): which family and contact radius each press takes
at the named fit's response, against its indenter's, and where the refinement ends from there.

bench_calibration's calibration presses of one truth (default ``gain 1.15``: 2 mm electrode,
gain 1.15), float tier at 1 % noise per reading (or per peak), the same seeds. The named fit
(calibrate) gives the response (gain, footprint, layer scale); at it:

* each press's family and radius chosen by fit_quality.both_families from tables of 16 (the
  library's FREE_RADII), 31, 61, 121 … radii per family from 0.5 to 8 mm (``--radii``), how
  many presses take the other family than their indenter's, and the relative residual there;
* each press's relative residual with its indenter's profile against the chosen one, for the
  last table of ``--radii`` (``--table``);
* fit_quality.polish from the named point with the true families and Hertz radii, and with the
  chosen families followed by free_fit's rounds of choosing again: where each ends.

A fraction of the unnamed calibration's cost (≈ 1 min per table on a quiet core, against
≈ 10 min for tactile-contact-calibrate on unnamed presses).

    PYTHONPATH=. .venv/bin/python -u bench/diag_calibration_families.py [--truth "gain 1.15"]
        [--float-noise reading] [--radii 16,61] [--table]
"""

from __future__ import annotations

import argparse
import copy
import math
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from benchkit import LAYOUT
from benchkit.protocol import Patch
from benchkit.readings import FLOAT_NOISES, readings, seed, set_float_noise
from benchkit.truths import N_CAL, TRUTHS, calibration_presses
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from tactile_contact.model.layout import load_layout
from tactile_contact.offline import fit_quality as fq
from tactile_contact.offline.calibrate import _PressModel, calibrate
from tactile_contact.offline.presses import load_presses

BOUNDS = ((0.0, 4e-3), (0.75, 1.25))  # calibrate's grid ends: footprint [m], layer scale


def relative(model: _PressModel, res: NDArray) -> float:
    """RMS residual over the RMS of the fitted readings [-]."""
    return math.sqrt(float(res @ res) / model.norm2)


def per_press(model: _PressModel, res: NDArray) -> NDArray:
    """Each press's relative residual [-] (as Calibration.press_residuals)."""
    rows = np.nonzero(model.use)[0]
    n = model.use.shape[0]
    r2 = np.bincount(rows, res * res, minlength=n)
    d2 = np.bincount(rows, model.presses.deflection[model.use] ** 2, minlength=n)
    return np.sqrt(r2 / np.maximum(d2, 1e-300))


def refine(
    model: _PressModel, choose: _PressModel, start: tuple[float, float, float], fam: NDArray
) -> tuple[float, float, float, NDArray, float]:
    """free_fit's refinement of one start with the families ``fam``: polish, then choose the
    families again (over ``choose``'s radii) and polish while that lowers the residual.
    (scale, foot, gain, families, squared residual)."""
    s, f, g = start
    _, rad = fq.both_families(choose, s, f, g, choose.profiles)
    s1, f1, g1, _, _, res = fq.polish(model, s, f, g, fam, rad, bounds=BOUNDS)
    c = float(res @ res)
    for _ in range(fq.REFAMILY_ROUNDS):
        fam2, rad2 = fq.both_families(choose, s1, f1, g1, choose.profiles)
        if np.array_equal(fam2, fam):
            break
        cand = fq.polish(model, s1, f1, g1, fam2, rad2, bounds=BOUNDS)
        c2 = float(cand[5] @ cand[5])
        if not c2 < c:
            break
        s1, f1, g1, fam, c = cand[0], cand[1], cand[2], fam2, c2
    return s1, f1, g1, fam, c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--truth", default="gain 1.15", choices=list(TRUTHS))
    ap.add_argument("--float-noise", default="reading", choices=FLOAT_NOISES)
    ap.add_argument("--radii", default="16,61", help="radii per family, comma-separated")
    ap.add_argument("--table", action="store_true", help="each press, last table of --radii")
    args = ap.parse_args()
    set_float_noise(args.float_noise)
    threadpool_limits(1)
    lay = Patch()
    cal = calibration_presses(lay, args.truth, N_CAL)
    rng = np.random.default_rng(seed("calibration", args.truth, "float"))
    defl = readings(lay, cal["d"], "float", rng)
    tmp = Path(tempfile.mkdtemp(prefix="diag_families_"))
    common = {"deflection": defl, "force": cal["f"], "position": cal["c"]}
    np.savez(tmp / "named.npz", indenter=cal["ind"], **common)
    np.savez(tmp / "unnamed.npz", **common)
    patch = load_layout(LAYOUT).patches[0]
    pn, pu = load_presses(tmp / "named.npz", patch), load_presses(tmp / "unnamed.npz", patch)
    t = time.perf_counter()
    named = calibrate(patch, pn)
    s, f, g = named.layer_scale, named.footprint_radius, named.gain
    print(
        f"{args.truth}, 1 % per {args.float_noise}; named fit ({time.perf_counter() - t:.0f} s): "
        f"gain {g:.4f}, footprint {f * 1e3:.3f} mm, layer {s:.4f}, "
        f"residual {named.relative_residual:.3%}"
    )
    mn, mu = _PressModel(patch, pn), _PressModel(patch, pu)
    fam_t = np.array([mn.profiles[i][0] for i in mn.index])
    rad_t = np.array([mn.profiles[i][1] for i in mn.index])
    _, res_t = fq.jacobian(mn, s, f, g, fam_t, rad_t, False)
    t = time.perf_counter()
    s1, f1, g1, _, _, res = fq.polish(mu, s, f, g, fam_t, rad_t, bounds=BOUNDS)
    print(
        f"polish from the named point, true families and radii ({time.perf_counter() - t:.0f} s):"
        f" gain {g1:.4f}, footprint {f1 * 1e3:.3f} mm, layer {s1:.4f}, "
        f"residual {relative(mu, res):.3%}"
    )
    sizes = [int(v) for v in args.radii.split(",")]
    for n in sizes:
        choose = copy.copy(mu)  # its profiles: the table both_families is given
        choose.profiles = [(k, float(a)) for k in (0, 1) for a in np.geomspace(5e-4, 8e-3, n)]
        t = time.perf_counter()
        fam, rad = fq.both_families(choose, s, f, g, choose.profiles)
        tb = time.perf_counter() - t
        _, res = fq.jacobian(mu, s, f, g, fam, rad, True)
        wrong = np.nonzero(fam != fam_t)[0].tolist()
        print(
            f"{n:3d} radii per family ({tb:.1f} s a choice): at the named point {len(wrong)} "
            f"presses in the other family {wrong}, residual {relative(mu, res):.3%}"
        )
        t = time.perf_counter()
        s1, f1, g1, fam1, c = refine(mu, choose, (s, f, g), fam)
        wrong = np.nonzero(fam1 != fam_t)[0].tolist()
        print(
            f"    refined from there ({time.perf_counter() - t:.0f} s): gain {g1:.4f}, footprint "
            f"{f1 * 1e3:.3f} mm, layer {s1:.4f}, residual {math.sqrt(c / mu.norm2):.3%}; "
            f"{len(wrong)} in the other family"
        )
        if args.table and n == sizes[-1]:
            pr_t, pr_c = per_press(mn, res_t), per_press(mu, res)
            print(
                "  press  indenter        force N | true family, a mm | chosen "
                "| residual true, chosen"
            )
            for i in range(len(fam)):
                mark = " *" if fam[i] != fam_t[i] else ""
                print(
                    f"  {i:5d}  {cal['ind'][i]:14s} {cal['f'][i]:6.2f} | "
                    f"{fam_t[i]} {rad_t[i] * 1e3:5.2f}  | {fam[i]} {rad[i] * 1e3:5.2f} | "
                    f"{pr_t[i]:.4f} {pr_c[i]:.4f}{mark}"
                )


if __name__ == "__main__":
    main()
