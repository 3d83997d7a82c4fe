"""Calibration of a patch's effective taxel response from presses of known force and position.

What a taxel reads is not known until measured: the deflection averaged over some footprint
(a point, the 2 mm electrode, more), times some gain, over a layer a little thicker or thinner
than its datasheet. Each of these biases the force by 5–20 % (docs/reconstruction.md). A lab
presses the skin with an indenter on a force sensor at known places; this module fits

* ``footprint_radius`` [m]: the disc a taxel averages the deflection over,
* ``gain`` [-]: reading per true compression,
* ``layer_scale`` [-]: elastic layer thickness over the nominal one,

by least squares over all presses, and writes bundles built with them
(``tactile-contact-calibrate LAYOUT.yaml PRESSES.npz -o BUNDLE_DIR``). When the presses name
their indenter (``indenter``: "sphere 12 mm", "cylinder 3 mm", … or "hertz:R" / "punch:a" with
R, a in mm) each press is predicted exactly; otherwise each press's contact (profile and a
continuous radius) is fitted too, from up to three starts, each with two tables of radii to
choose the presses' families from (:func:`fit_quality.free_fit`): a press's
contact size trades against the footprint and the layer, so such presses pin the response
less well.

Every fit carries its parameters' 1-σ errors and correlations from its Jacobian
(:mod:`tactile_contact.offline.fit_quality`) and a report in words
(:mod:`tactile_contact.offline.calibration_report`), printed and kept in the bundle manifest's
``calibration``. A fit whose gain is uncertain beyond MAX_FORCE_SIGMA is refused (exit 1, what
the presses cannot pin and what to add) unless ``--accept-uncertain``: never a silently biased
bundle (docs/calibration.md). No ROS import.

The presses file (PRESSES.npz) and the ``tactile-contact-presses`` command that makes it from a
recorded session are in :mod:`tactile_contact.offline.presses`.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from tactile_contact.model.indenters import FlatPunch
from tactile_contact.model.layout import LayoutError, PatchLayout, load_layout
from tactile_contact.offline.calibration_report import report, unidentified_message
from tactile_contact.offline.fit_quality import (
    ambiguous,
    free_fit,
    jacobian,
    press_profiles,
    uncertainty,
)
from tactile_contact.offline.presses import (  # the names marked F401: importable from
    INDENTERS,  # noqa: F401                        here as before they moved to presses.py
    MIN_PRESSES,  # noqa: F401
    CalibrationError,
    Presses,
    indenter_named,
    load_presses,
    main_presses,  # noqa: F401
    presses_from_bag,  # noqa: F401
)

#: Search grids: footprint radius [m] and layer scale [-] (the gain is solved in closed form).
FOOTPRINTS = tuple(np.round(np.arange(0.0, 4.01e-3, 0.25e-3), 6))
LAYER_SCALES = tuple(np.round(np.arange(0.75, 1.251, 0.05), 4))
#: Only taxels within this distance [m] of a press are fitted (farther ones read < 1 % of it).
REACH = 0.015
#: Profiles tried for a press that names no indenter: contact radii [m] per family.
FREE_RADII = tuple(float(a) for a in np.geomspace(0.5e-3, 8e-3, 16))
#: Radii [m] per family over which such a press's family is chosen (fit_quality.both_families):
#: 4.7 % apart. Between FREE_RADII's (20 % apart) a parabola in log a misjudges a press's best
#: residual by more than the two families differ: at the named fit's response of
#: bench_calibration's gain-1.15 truth (1 % per reading) 11 of 48 presses took the wrong family
#: and the fit ended at 1.005 % of the readings where the true families give 0.581 %; with 31,
#: 61 and 121 radii: 8, 5 and 1 wrong, 0.670, 0.584 and 0.579 % (issue 26). Each radius is one
#: table of the fit's (one FFT field), so this costs ≈ 4× FREE_RADII's per choice.
FAMILY_RADII = tuple(float(a) for a in np.geomspace(0.5e-3, 8e-3, 61))
#: Largest 1-σ relative error of the forces' scale [-] a bundle is written with (without
#: --accept-uncertain): the force error the calibration itself adds (fit_quality.uncertainty's
#: force_scale). 48 presses of the paper's protocol pin it to < 1 % (docs/calibration.md).
MAX_FORCE_SIGMA = 0.02


@dataclass(frozen=True)
class Calibration:
    """Fitted response and how well it explains the presses.

    Attributes:
        footprint_radius: [m]; gain: [-]; layer_scale: [-].
        residual: RMS of (predicted − measured) over the fitted readings [m].
        relative_residual: that RMS over the RMS of the readings [-].
        nominal_relative_residual: the same for the layout's nominal response [-].
        presses: presses used; readings: readings fitted.
        grid: footprint × layer-scale cost surface (relative residual), for the record.
    """

    footprint_radius: float
    gain: float
    layer_scale: float
    residual: float
    relative_residual: float
    nominal_relative_residual: float
    presses: int
    readings: int
    seconds: float = 0.0
    grid: dict[str, Any] = field(default_factory=dict)
    named: bool = True
    uncertainty: dict[str, Any] = field(default_factory=dict)
    press_residuals: list[float] = field(default_factory=list)
    #: The layout's per-taxel compression noise [m] (solver.noise): a residual about this
    #: large is the readings' own noise, not a mismatch (the report's advice).
    noise: float = 0.0

    def metadata(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("grid")
        return d

    def identified(self) -> bool:
        """Whether the presses pin the forces' scale to MAX_FORCE_SIGMA (1 σ), and, when they
        name no indenter, the gain too: the force scale assumes each press's contact as
        fitted, and a reconstruction fits the contact again with the bundle's own footprint
        and layer, so the gain–layer compensation need not carry over (bench_calibration:
        unnamed fits with σ_gain ≤ 2 % came within 1.05× of the named error, one at 2.1 %
        at 2×)."""
        s = self.uncertainty.get("sigma", {})
        ok = s.get("force_scale", math.inf) <= MAX_FORCE_SIGMA
        return bool(ok and (self.named or s.get("gain", math.inf) <= MAX_FORCE_SIGMA))


def _profiles(presses: Presses, young: float, poisson: float) -> tuple[list, NDArray[np.int64]]:
    """Unique (family, contact radius) of the named presses and each press's index."""
    uniq: dict[tuple[int, float], int] = {}
    index = []
    for name, f in zip(presses.indenter or (), presses.force, strict=False):
        ind = indenter_named(name)
        fam = 0 if isinstance(ind, FlatPunch) else 1
        key = (fam, round(float(ind.contact_radius(float(f), young, poisson)), 9))
        index.append(uniq.setdefault(key, len(uniq)))
    return list(uniq), np.asarray(index, dtype=np.int64)


def calibrate(
    patch: PatchLayout, presses: Presses, *, progress: bool = False, jobs: int | None = None
) -> Calibration:
    """Fit footprint radius, gain and layer scale to ``presses`` (see module docstring).

    A grid over footprint radius × layer scale (FOOTPRINTS × LAYER_SCALES) with the gain in
    closed form at each point; a parabola through the best point and its neighbours along
    each axis refines both; the refined point is evaluated exactly for the reported gain and
    residual. Presses without indenter names are then refined with continuous contact radii
    (up to three starts × two family tables: fit_quality.free_fit; the best kept), those
    ends in up to ``jobs`` processes (default 1: in this one; the same result either way;
    the command's default is 2). More than one starts processes (forkserver) that import
    the caller's main script: a script that calls this at its top level needs
    ``if __name__ == "__main__":`` (else the pool breaks: BrokenProcessPool). The
    uncertainties come from the Jacobian at the result.
    """
    t0 = time.perf_counter()
    model = _PressModel(patch, presses)
    scales = np.asarray(LAYER_SCALES)
    feet = np.asarray(FOOTPRINTS)
    it = scales
    if progress:
        from tqdm import tqdm

        it = tqdm(scales, desc="calibrating", unit="layer scale", file=sys.stderr)
    cost = np.empty((len(feet), len(scales)))
    gains = np.empty_like(cost)
    for si, s in enumerate(it):
        cost[:, si], gains[:, si] = model.cost(float(s), feet)
    fi, si = np.unravel_index(int(np.argmin(cost)), cost.shape)
    foot = _parabola(feet, cost[:, si], fi, lo=0.0)
    scale = _parabola(scales, cost[fi, :], si)
    c1, g1 = model.cost(scale, np.array([foot]))
    if c1[0] > cost[fi, si]:  # the parabola overshot: keep the grid point
        foot, scale, c1, g1 = (
            float(feet[fi]),
            float(scales[si]),
            cost[fi, si : si + 1],
            gains[fi, si : si + 1],
        )
    nominal, _ = model.cost(patch.model.layer_scale, np.array([patch.footprint]), gain=1.0)
    norm2, n_read = model.norm2, model.readings
    free = model.index is None
    gain = float(g1[0])
    starts: list[dict[str, float]] = []
    if free:  # each press's contact radius made continuous, then everything refined together
        s_nom, f_nom = float(patch.model.layer_scale), float(patch.footprint)
        g_nom = float(model.cost(s_nom, np.array([f_nom]))[1][0])
        scale, foot, gain, fam, rad, jac, res, starts = free_fit(
            model,
            cost,
            gains,
            feet,
            scales,
            (scale, foot, gain),
            (s_nom, f_nom, g_nom),
            jobs=jobs,
        )
        c1 = np.array([float(res @ res)])
    else:
        fam, rad = press_profiles(model, scale, foot, gain)
        jac, res = jacobian(model, scale, foot, gain, fam, rad, False)
    rows = np.nonzero(model.use)[0]  # press of each fitted reading
    unc = uncertainty(jac, res, foot, len(fam) if free else 0, rows, gain).as_dict()
    if starts:
        unc["starts"] = starts
        # two fits as good and far apart: the presses cannot tell them apart
        other = ambiguous(starts, unc["dof"], MAX_FORCE_SIGMA)
        if other is not None:
            gap = abs(starts[0]["gain"] - other["gain"])
            unc["sigma"]["force_scale"] = max(unc["sigma"]["force_scale"], gap)
            unc["ambiguous"] = {
                "gains": [starts[0]["gain"], other["gain"]],
                "relative_residuals": [
                    starts[0]["relative_residual"],
                    other["relative_residual"],
                ],
            }
    r2 = np.bincount(rows, res * res, minlength=len(fam))
    read = presses.deflection[model.use]
    d2 = np.bincount(rows, read**2, minlength=len(fam))
    p2 = np.bincount(rows, (read + res) ** 2, minlength=len(fam))  # (res = predicted − read)
    # Over the larger of what the press read and what the fit predicts for it: a press that
    # reads nothing where the fit expects a contact is 100 % off (over its own readings it was
    # 10^150 %), and one that reads a contact the fit does not predict likewise.
    per_press = np.sqrt(r2 / np.maximum(np.maximum(d2, p2), 1e-300))
    return Calibration(
        footprint_radius=float(foot),
        gain=gain,
        layer_scale=float(scale),
        residual=math.sqrt(float(c1[0]) / max(n_read, 1)),
        relative_residual=math.sqrt(float(c1[0]) / norm2),
        nominal_relative_residual=math.sqrt(float(nominal[0]) / norm2),
        presses=len(presses.force),
        readings=n_read,
        seconds=round(time.perf_counter() - t0, 2),
        grid={
            "footprints": feet.tolist(),
            "layer_scales": scales.tolist(),
            "relative_residual": np.sqrt(cost / norm2).tolist(),
        },
        named=not free,
        uncertainty=unc,
        press_residuals=[round(float(v), 4) for v in per_press],
        noise=float(patch.solver.noise),
    )


def _parabola(x: NDArray, y: NDArray, i: int, lo: float | None = None) -> float:
    """Vertex of the parabola through (x, y) at i − 1, i, i + 1 (x[i] at an end)."""
    if i == 0 or i == len(x) - 1:
        return float(x[i])
    x0, x1, x2 = x[i - 1 : i + 2]
    y0, y1, y2 = y[i - 1 : i + 2]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    b = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
    if not a > 0:
        return float(x1)
    v = float(np.clip(-b / (2 * a), x0, x2))
    return max(v, lo) if lo is not None else v


class _PressModel:
    """Predicted readings of the presses for a layer scale and footprint radii."""

    def __init__(self, patch: PatchLayout, presses: Presses) -> None:
        e = patch.elastomer
        self.patch, self.presses = patch, presses
        xy = patch.taxel_xy()
        pos = presses.position
        dist = np.hypot(xy[None, :, 0] - pos[:, None, 0], xy[None, :, 1] - pos[:, None, 1])
        self.use = presses.valid & (dist <= REACH)
        if presses.indenter is not None:
            self.profiles, self.index = _profiles(presses, e.young, e.poisson)
        else:
            self.profiles, self.index = [(f, a) for f in (0, 1) for a in FREE_RADII], None
        #: profiles among which an unnamed press's family is chosen (FAMILY_RADII)
        self.family_profiles = (
            self.profiles
            if self.index is not None
            else [(f, a) for f in (0, 1) for a in FAMILY_RADII]
        )
        self.step, self.reach = 1e-4, REACH
        j = np.minimum(dist, REACH) / self.step
        self.jl = np.floor(j).astype(np.int64)
        self.w = j - self.jl
        d = presses.deflection
        self.norm2 = float(np.sum(np.where(self.use, d * d, 0.0)))
        self.readings = int(self.use.sum())
        if not self.norm2 > 0:
            raise CalibrationError("the presses read nothing within reach of their positions")

    def cost(
        self, scale: float, footprints: NDArray, gain: float | None = None
    ) -> tuple[NDArray, NDArray]:
        """(squared residual [m²], gain) per footprint at this layer scale; the gain is
        fitted unless given."""
        from tactile_contact.inverse.round_contact import radial_responses

        e, p = self.patch.elastomer, self.presses
        tab = radial_responses(
            e.thickness * scale,
            e.young,
            e.poisson,
            footprints,
            self.profiles,
            reach=REACH + 2 * self.step,
            step=self.step,
            model=self.patch.model.kind,
            psi=self.patch.model.psi,
        )  # (P, F, J)
        d, use = p.deflection, self.use
        costs, gains = np.empty(len(footprints)), np.empty(len(footprints))
        for fi in range(len(footprints)):
            t = tab[:, fi]
            resp = t[:, self.jl] * (1 - self.w) + t[:, self.jl + 1] * self.w  # (P, N, K)
            pred = resp * p.force[None, :, None]
            if self.index is not None:
                pr = pred[self.index, np.arange(len(self.index))]
                g = gain
                if g is None:
                    den = float(np.sum(np.where(use, pr * pr, 0.0)))
                    g = float(np.sum(np.where(use, pr * d, 0.0))) / den if den > 0 else 0.0
                costs[fi] = float(np.sum(np.where(use, (g * pr - d) ** 2, 0.0)))
                gains[fi] = g
            else:
                gains[fi], costs[fi] = _free_gain(pred, d, use, gain)
        return costs, gains


def _free_gain(pred: NDArray, d: NDArray, use: NDArray, gain: float | None) -> tuple[float, float]:
    """(gain, squared residual) when each press's profile is free: for each gain on a fine
    grid (or the given one), every press takes its best profile; the least total wins."""
    best = (1.0, math.inf)
    m = use[None]
    pp = np.sum(np.where(m, pred * pred, 0.0), axis=2)  # (P, N)
    pd = np.sum(np.where(m, pred * d[None], 0.0), axis=2)
    dd = np.sum(np.where(use, d * d, 0.0), axis=1)  # (N,)
    for g in np.arange(0.5, 2.0001, 0.005) if gain is None else [gain]:
        r2 = dd[None] - 2 * g * pd + g * g * pp  # (P, N)
        total = float(np.sum(r2.min(axis=0)))
        if total < best[1]:
            best = (float(g), total)
    return best


def calibrated_layout(layout_doc: dict[str, Any], patch: str, cal: Calibration) -> dict[str, Any]:
    """A copy of the layout document with ``patch``'s model set to the fitted response."""
    doc = copy.deepcopy(layout_doc)
    for p in doc.get("patches", []):
        if p.get("name") == patch:
            m = p.setdefault("model", {}) or {}
            m.update(
                footprint_radius=round(cal.footprint_radius, 7),
                gain=round(cal.gain, 5),
                layer_scale=round(cal.layer_scale, 5),
            )
            p["model"] = m
            return doc
    raise CalibrationError(f"patch {patch!r} not in the layout")


def write_bundle(
    layout_path: Path,
    patch_name: str,
    cal: Calibration,
    out_dir: Path,
    *,
    accept_uncertain: bool = False,
) -> Path:
    """Write the calibrated layout YAML and the patch's bundle under ``out_dir``.

    Raises CalibrationError (what the presses cannot pin, what to add) when the fit's gain is
    uncertain beyond MAX_FORCE_SIGMA, unless ``accept_uncertain``: never a silently biased
    bundle. The manifest's ``calibration`` keeps the fit, its uncertainties and the report.
    """
    from tactile_contact.offline.build import build_patch
    from tactile_contact.offline.bundle import save_bundle

    if not cal.identified() and not accept_uncertain:
        raise CalibrationError(unidentified_message(cal, MAX_FORCE_SIGMA))
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = yaml.safe_load(layout_path.read_text())
    new = calibrated_layout(doc, patch_name, cal)
    lay_out = out_dir / f"{layout_path.stem}.calibrated.yaml"
    header = (
        f"# {layout_path.name} with the taxel response fitted by tactile-contact-calibrate\n"
        f"# ({cal.presses} presses, relative residual {cal.relative_residual:.4f}).\n"
    )
    # Checked as a layout before it takes its name: a fit that no layout allows (a gain of 0
    # from readings in the wrong unit) is refused, not left on disk.
    staged = lay_out.with_name(lay_out.name + ".tmp")
    staged.write_text(header + yaml.safe_dump(new, sort_keys=False))
    try:
        load_layout(staged)
    except Exception as exc:
        staged.unlink()
        raise CalibrationError(
            f"the fitted response makes no valid layout ({exc}); nothing written — check the "
            "presses' units and indenters"
        ) from exc
    staged.replace(lay_out)
    patch = load_layout(lay_out).patch(patch_name)
    manifest, arrays = build_patch(patch)
    manifest["layout_source"] = str(lay_out.resolve())
    manifest["calibration"] = cal.metadata() | {
        "identified": cal.identified(),
        "report": report(cal, MAX_FORCE_SIGMA),
    }
    return save_bundle(out_dir / patch_name, manifest, arrays)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="tactile-contact-calibrate",
        description="Fit a patch's taxel response (footprint radius, gain, layer scale) to "
        "presses of known force and position, and write calibrated bundles.",
    )
    ap.add_argument("layout", type=Path, help="patch layout YAML")
    ap.add_argument("presses", type=Path, help="PRESSES.npz (see the module docstring)")
    ap.add_argument("-o", "--out", type=Path, required=True, help="bundle directory to write")
    ap.add_argument("--patch", help="patch the presses belong to (default: the only one)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="parallel processes for presses that name no indenter (default 2)",
    )
    ap.add_argument(
        "--accept-uncertain",
        action="store_true",
        help=f"write the bundle even when the presses pin the gain to worse than "
        f"±{MAX_FORCE_SIGMA:.0%}% (1 σ); the manifest keeps the uncertainties",
    )
    args = ap.parse_args(argv)
    if args.jobs is not None and args.jobs < 1:
        print(f"ERROR: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    cal = None
    try:
        lay = load_layout(args.layout)
        if args.patch is None and len(lay.patches) != 1:
            names = ", ".join(p.name for p in lay.patches)
            raise CalibrationError(f"{args.layout}: several patches ({names}): pass --patch")
        patch = lay.patch(args.patch) if args.patch else lay.patches[0]
        presses = load_presses(args.presses, patch)
        cal = calibrate(patch, presses, progress=not args.json, jobs=args.jobs or 2)
        if not args.json:
            _print_fit(patch.name, cal)
        path = write_bundle(
            args.layout, patch.name, cal, args.out, accept_uncertain=args.accept_uncertain
        )
    except (CalibrationError, LayoutError, KeyError, OSError) as e:
        if cal is not None and args.json:
            print(json.dumps(_json(cal, None), indent=2))
        print(f"ERROR: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(_json(cal, path), indent=2))
    else:
        if not cal.identified():
            print(f"WARNING: {unidentified_message(cal, MAX_FORCE_SIGMA)}", file=sys.stderr)
        print(f"bundle: {path}")
    return 0


def _print_fit(name: str, cal: Calibration) -> None:
    """The fitted parameters, then the report in words."""
    print(
        f"{name}: footprint radius {cal.footprint_radius * 1e3:.2f} mm, "
        f"gain {cal.gain:.4f}, layer scale {cal.layer_scale:.3f}; "
        f"residual {cal.residual * 1e6:.3f} µm RMS = {cal.relative_residual:.2%} of the "
        f"readings (nominal response: {cal.nominal_relative_residual:.2%}); "
        f"{cal.presses} presses, {cal.readings} readings, {cal.seconds:.0f} s"
    )
    for line in report(cal, MAX_FORCE_SIGMA):
        print(f"  {line}")


def _json(cal: Calibration, path: Path | None) -> dict[str, Any]:
    return cal.metadata() | {
        "identified": cal.identified(),
        "report": report(cal, MAX_FORCE_SIGMA),
        "bundle": str(path) if path else None,
    }


if __name__ == "__main__":
    sys.exit(main())
