"""The boards' shift: range against resolution, with the saturation it brings (issue 26
"Shift"). Which shift to configure for which forces.

The firmware sends ``value = noLoad − (cdc >> shift)`` clipped to 0..255 (docs/can_protocol.md;
:func:`tactile_contact.model.sensor.module_value`, as the simulator): one count is
``farad_per_count·2**shift`` (0.32 fF at shift 0, 2.56 fF at 3), a compression clips at noLoad
counts (value 0) and a bulge beside a small contact at 255 − noLoad counts (value 255; 15 with
the default noLoad 240). The converter's noise is in CDC counts, so the same 2 CDC counts RMS
(0.5 count at the default shift 2: issue 26's tier) is 2 counts at shift 0 and 0.25 at 3.

Per variant (shift 0–3 at noLoad 240; shifts 0 and 1 with a lower noLoad): the point-taxel
truth's presses of the robust bench's protocol (4 indenters × 6 forces 0.2–3 N × 6 places),
CDC counts of ΔC with 2 counts of Gaussian noise, rounded, shifted and clipped as the firmware
does; ΔC = (baseline − value)·count with the baseline the mean value of idle frames (a
driver's); clipped channels (value 0 or 255) left out, as the driver flags them saturated; each
taxel's noise passed in as a tracker learns it from idle frames. Bundles: the layout calibrated
on the truth (48 presses at shift 2, bench_time's calibration), built at the variant's shift
and noLoad. Columns: one count in fF and in µm of compression at rest, the noise in counts,
the compression and bulge where the value clips, the presses with a clipped taxel, and the
median |force error| [%] at 0.2 N, 0.5 N (misses), over ≥ 1 N, at 3 N, the p90 over ≥ 1 N,
for one frame and for 10 frames fused (``Reconstructor(fuse=True)``).

    .venv/bin/python bench/bench_shift.py [--out docs/bench]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
import yaml
from bench_time import calibrate
from benchkit.protocol import Patch
from benchkit.readings import seed
from benchkit.tables import Report, md_table
from benchkit.truths import test_presses
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.sensor import module_value
from tactile_contact.offline.build import build_layout

NOISE_CDC = 2.0  # converter noise [CDC counts RMS]: 0.5 count at shift 2
FRAMES = 10
IDLE_SAMPLES = 20000
#: (shift, noLoad) variants.
VARIANTS = ((0, 240), (1, 240), (2, 240), (3, 240), (0, 200), (1, 220))


class Firmware:
    """One variant's readings: ΔC [F] as a driver gets them, the valid (unclipped) taxels."""

    def __init__(self, lay: Patch, shift: int, no_load: int, farad_per_count: float) -> None:
        self.lay, self.shift, self.no_load, self.fpc = lay, shift, no_load, farad_per_count
        self.count = farad_per_count * 2**shift
        rng = np.random.default_rng(seed("shift-idle", str(shift), str(no_load)))
        idle = self.values(np.zeros(IDLE_SAMPLES), rng)[0].astype(float)
        self.baseline = float(idle.mean())  # the driver's: the mean of idle values
        #: the noise a tracker learns: RMS of idle ΔC, as compression [m]
        rms = math.sqrt(float(np.mean((self.baseline - idle) ** 2)))
        self.noise_counts = rms
        self.sigma = float(lay.to_deflection(np.array([rms * self.count]))[0])

    def values(self, dc: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(8-bit values, clipped) of ΔC [F] (any shape) with the converter's noise."""
        cdc = np.rint(dc / self.fpc + rng.normal(0.0, NOISE_CDC, dc.shape))
        return module_value(cdc, self.no_load, self.shift)

    def frames(self, d: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
        """n frames of (ΔC [F], valid) of compressions d (K,) [m]."""
        dc = np.broadcast_to(self.lay.to_delta_c(d), (n, len(d)))
        v, _ = self.values(dc, rng)
        valid = (v > 0) & (v < 255)
        return (self.baseline - v.astype(float)) * self.count, valid

    def limits(self) -> tuple[float, float]:
        """(compression, bulge) [m] where the value clips (the baseline at its mean)."""
        hi = self.lay.to_deflection(np.array([(self.baseline - 0.5) * self.count]))[0]
        lo = self.lay.to_deflection(np.array([(self.baseline - 254.5) * self.count]))[0]
        return float(hi), float(lo)


def variant_bundle(layout: Path, shift: int, no_load: int, folder: Path) -> Path:
    """The calibrated layout at this shift and noLoad, built."""
    doc = yaml.safe_load(layout.read_text())
    for patch in doc["patches"]:
        patch["sensor"]["shift"] = shift
        patch["sensor"]["no_load"] = no_load
    path = folder / f"shift{shift}_{no_load}.yaml"
    path.write_text(yaml.safe_dump(doc))
    out = folder / f"shift{shift}_{no_load}"
    build_layout(path, out, jobs=1)
    return out / doc["patches"][0]["name"]


def run(fw: Firmware, bundle: Path, p: dict, fuse: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per press: signed force error [%] after FRAMES frames (NaN: missed), clipped taxels."""
    recon = Reconstructor.from_bundle(bundle, follow=True, fuse=fuse)
    sigma = np.full(recon.n_taxels, fw.sigma)
    err = np.full(len(p["f"]), np.nan)
    clipped = np.zeros(len(p["f"]), bool)
    for i, (d, f) in enumerate(zip(p["d"], p["f"], strict=True)):
        rng = np.random.default_rng(seed("shift", str(fw.shift), str(fw.no_load), str(i)))
        if recon.fusion is not None:
            recon.fusion.reset()
        recon.followed = None
        dc, valid = fw.frames(d, FRAMES, rng)
        clipped[i] = not valid.all()
        for k in range(FRAMES):
            res = recon.solve(dc[k], valid[k], noise=sigma, want_traction=False)
        if res.in_contact:
            err[i] = (res.total_force / f - 1.0) * 100.0
    return err, clipped


def cells(err: np.ndarray, f: np.ndarray) -> list[str]:
    a = np.where(np.isnan(err), 100.0, np.abs(err))
    hi, half = f >= 1.0, np.isclose(f, 0.5)
    return [
        f"{np.median(a[np.isclose(f, 0.2)]):.0f}",
        f"{np.median(a[half]):.0f} ({int(np.isnan(err[half]).sum())})",
        f"{np.median(a[hi]):.1f}",
        f"{np.median(a[np.isclose(f, 3.0)]):.1f}",
        f"{np.percentile(a[hi], 90):.0f}",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, help="write shift.md here")
    args = ap.parse_args()
    threadpool_limits(1)
    t_start = time.perf_counter()
    say = Report()
    lay = Patch()
    tmp = Path(tempfile.mkdtemp(prefix="bench_shift_"))
    bundle, note = calibrate(lay, "point", tmp)
    if bundle is None:
        raise SystemExit(f"calibration failed: {note}")
    layout = next(bundle.parent.glob("*.calibrated.yaml"))
    fpc = float(yaml.safe_load(layout.read_text())["patches"][0]["sensor"]["farad_per_count"])
    p = test_presses(lay, "point")
    f = p["f"]
    say(
        f"point-taxel truth, {len(f)} presses, calibrated ({note}); converter noise "
        f"{NOISE_CDC:g} CDC counts; {FRAMES} frames a press"
    )
    head = ["shift", "noLoad", "count fF", "count µm", "noise counts", "clips at mm"]
    head += ["bulge clips µm", "clipped >=1 N", "frames"]
    head += ["0.2 N", "0.5 N (missed)", ">=1 N", "3 N", "p90 >=1 N"]
    table = []
    for shift, no_load in VARIANTS:
        fw = Firmware(lay, shift, no_load, fpc)
        b = variant_bundle(layout, shift, no_load, tmp)
        hi, lo = fw.limits()
        rest = float(lay.to_deflection(np.array([fw.count]))[0])
        for fuse in (False, True):
            err, clipped = run(fw, b, p, fuse)
            table.append(
                [
                    str(shift),
                    str(no_load),
                    f"{fw.count * 1e15:.2f}",
                    f"{rest * 1e6:.1f}",
                    f"{fw.noise_counts:.2f}",
                    f"{hi * 1e3:.2f}",
                    f"{lo * 1e6:.0f}",
                    f"{clipped[f >= 1.0].sum()}/{(f >= 1.0).sum()}",
                    f"{FRAMES} fused" if fuse else "1",
                    *cells(err, f),
                ]
            )
            say(" | ".join(table[-1]))
    say()
    for line in md_table(head, table):
        say(line)
    say()
    say(f"({time.perf_counter() - t_start:.0f} s in all)")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        body = "\n".join(say.lines)
        title = "# The boards' shift: range, resolution, saturation (bench/bench_shift.py)"
        cmd = ".venv/bin/python bench/bench_shift.py"
        (args.out / "shift.md").write_text(f"{title}\n\n`{cmd}`\n\n{body}\n")


if __name__ == "__main__":
    main()
