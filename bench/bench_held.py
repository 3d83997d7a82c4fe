"""What a held, idle or slowly moving patch costs when the frames of a held scene are fused
(issue 25 "Skip what the scene does not need"), beside solving every frame, in the same run;
and the accuracy on those streams.

Streams of one patch (8-bit whole counts, 0.5-count converter noise before rounding, point-taxel
truth from the fine forward model, the default bundle, noise passed in as the node's tracker
learns it):

    idle         frames without contact
    held         a 12 mm sphere at 1.5 N over a taxel, held still
    held light   a 6 mm sphere at 0.5 N between two taxels, held still
    slow slide   a 12 mm sphere at 1.5 N sliding 0.1 mm a frame (5 mm/s at 50 Hz)
    fast slide   the same, 1 mm a frame (50 mm/s)

through ``Reconstructor(follow=True)`` (every frame solved: the node before fusion) and
``Reconstructor(follow=True, fuse=True)``, in alternating blocks of frames so both see the same
load on this shared machine. Per stream: CPU time a frame [µs] (the thread's: time spent
waiting for the machine's other processes left out; mean: what a core spends; p50; p99), the
ratio fused / every frame, the frames solved (on their own or fused), force and CoP errors
(median over the frames in contact; misses count 100 %). The reading's conversion
(``ReadingModel.from_delta_c``) and the detector's pass alone (what every idle frame cost
before fusion) are timed beside them.

False contacts on noise alone (the fused idle patch solves means of up to 32 frames, credited
with less noise): ``--false-frames`` idle frames of (a) independent 0.5-count noise, (b) the
false-alarm bench's idle skin (benchkit.readings.IdleSkin: taxels resting at fractions of a
count, 0.15-count noise, the driver's tracked baseline; a new skin every 100 000 frames), noise
passed as a tracker learns it (RMS of each skin's first 500 frames, at least the sensor
model's); contacts counted as frames reported in contact after one that was not, per hour at
50 Hz, with the 95 % Poisson upper bound.

    .venv/bin/python bench/bench_held.py [--frames 2000] [--false-frames 200000] [--out docs/bench]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import benchkit.onecore  # noqa: F401  (before numpy)
import numpy as np
from bench_time import SLIDE_STEP, frame_noise, frames, slide_truth
from benchkit import LAYOUT
from benchkit.protocol import Patch
from benchkit.readings import IdleSkin, seed
from benchkit.stats import poisson_upper
from benchkit.tables import Report, md_table
from benchkit.truths import truth
from threadpoolctl import threadpool_limits

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.offline.build import build_layout

BLOCK = 100  # frames per block; the two reconstructors alternate blocks


def streams(lay: Patch, n: int) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """name → (ΔC frames (n, K) [F], true force (n,) [N], true centre (n, 2) [m])."""
    out = {}
    rng = np.random.default_rng(seed("held"))
    zero = np.zeros(len(lay.xy))
    out["idle"] = (frames(lay, zero, n, rng), np.zeros(n), np.zeros((n, 2)))
    made = truth(lay, "point")
    for name, ind, force, where in (
        ("held", HertzSphere(6e-3), 1.5, lay.xy[30]),
        ("held light", HertzSphere(3e-3), 0.5, (lay.xy[31] + lay.xy[35]) / 2),
    ):
        d = made.presses(ind, [force], np.asarray(where), jacobian=False)[0][0]
        out[name] = (frames(lay, d, n, rng), np.full(n, force), np.tile(where, (n, 1)))
    path, d = slide_truth(lay, "sphere 12 mm")
    for name, step in (("slow slide", 2), ("fast slide", 20)):
        idx = (np.arange(n) * step) % len(path)  # back to the start at the end of the path
        dc = np.array([frames(lay, d[j], 1, rng)[0] for j in idx])
        out[name] = (dc, np.full(n, 1.5), path[idx])
    return out


def run(
    recons: dict[str, Reconstructor], dc: np.ndarray, sigma: np.ndarray
) -> dict[str, dict[str, np.ndarray]]:
    """Per reconstructor: wall time [s], result force, CoP, whether it solved, per frame."""
    out = {k: {"t": [], "f": [], "c": [], "solved": []} for k in recons}
    for r in recons.values():
        if r.fusion is not None:
            r.fusion.reset()
        r.followed = None
    for start in range(0, len(dc), BLOCK):
        for name, r in recons.items():
            o = out[name]
            for x in dc[start : start + BLOCK]:
                t0 = time.thread_time()
                res = r.solve(x, noise=sigma, want_traction=False, want_deflection=False)
                o["t"].append(time.thread_time() - t0)
                o["f"].append(res.total_force if res.in_contact else np.nan)
                o["c"].append(res.cop)
                o["solved"].append(r.fusion is None or r.fusion.last != "held")
    return {k: {q: np.asarray(v) for q, v in o.items()} for k, o in out.items()}


def errors(o: dict[str, np.ndarray], force: np.ndarray, centre: np.ndarray) -> tuple[str, str]:
    if not (force > 0).any():
        return f"{np.mean(~np.isnan(o['f'])) * 100:.2f} % false", "-"
    e = np.where(np.isnan(o["f"]), 100.0, np.abs(o["f"] / force - 1.0) * 100.0)
    ok = ~np.isnan(o["f"])
    cop = np.hypot(*(o["c"][ok] - centre[ok]).T) * 1e3
    return f"{np.median(e):.1f}", f"{np.median(cop):.2f}" if ok.any() else "-"


def false_contacts(recons: dict[str, Reconstructor], lay: Patch, n: int) -> list[list[str]]:
    """Rows: per idle kind and reconstructor, contacts started, per hour, its upper bound."""
    rows = []
    k = len(lay.xy)
    floor = frame_noise(lay) / np.hypot(0.5, 12**-0.5) / np.sqrt(6.0)  # one count/√6 [m]
    for kind in ("0.5-count noise", "idle skin (driver baselines)"):
        for name, r in recons.items():
            if r.fusion is not None:
                r.fusion.reset()
            r.followed = None
            rng = np.random.default_rng(seed("false", kind))
            skin = IdleSkin(k, rng, 100_000)
            starts, seen, was, sigma = 0, 0, False, None
            while seen < n:
                if kind.startswith("0.5"):
                    counts = np.rint(rng.normal(0.0, 0.5, (min(5000, n - seen), k)))
                    sigma = np.full(k, frame_noise(lay))
                else:
                    counts, fresh = skin.frames(min(5000, n - seen))
                    if fresh or sigma is None:
                        rms = np.sqrt(np.mean(counts[:500] ** 2, axis=0))
                        sigma = np.maximum(lay.to_deflection(rms * lay.lsb), floor)
                for x in counts * lay.lsb:
                    res = r.solve(x, noise=sigma, want_traction=False, want_deflection=False)
                    starts += res.in_contact and not was
                    was = res.in_contact
                seen += len(counts)
            hour = 3600 * 50
            rows.append(
                [
                    kind,
                    name,
                    str(seen),
                    str(starts),
                    f"{starts / seen * hour:.2f}",
                    f"{poisson_upper(starts, seen) * hour:.2f}",
                ]
            )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2000, help="frames per stream")
    ap.add_argument("--false-frames", type=int, default=200_000, help="idle frames per kind")
    ap.add_argument("--out", type=Path, help="write held.md here")
    args = ap.parse_args()
    threadpool_limits(1)
    say = Report()
    lay = Patch()
    tmp = Path(tempfile.mkdtemp(prefix="bench_held_"))
    build_layout(LAYOUT, tmp, jobs=1)
    bundle = tmp / "hexagon"
    recons = {
        "every frame": Reconstructor.from_bundle(bundle, follow=True),
        "fused": Reconstructor.from_bundle(bundle, follow=True, fuse=True),
    }
    for r in recons.values():
        r.warm_up()
    sigma = np.full(lay.xy.shape[0], frame_noise(lay))
    say(
        f"{args.frames} frames a stream, blocks of {BLOCK} alternating; 8-bit, 0.5-count noise; "
        f"slides {2 * SLIDE_STEP * 1e3:.1f} and {20 * SLIDE_STEP * 1e3:.1f} mm a frame"
    )
    head = ["stream", "mode", "mean µs", "p50 µs", "p99 µs", "fused/every"]
    head += ["solved", "force %", "CoP mm"]
    table = []
    for name, (dc, force, centre) in streams(lay, args.frames).items():
        got = run(recons, dc, sigma)
        base = float(got["every frame"]["t"].mean())
        for mode, o in got.items():
            f, c = errors(o, force, centre)
            t = o["t"] * 1e6
            table.append(
                [
                    name,
                    mode,
                    f"{t.mean():.1f}",
                    f"{np.median(t):.1f}",
                    f"{np.percentile(t, 99):.0f}",
                    f"{o['t'].mean() / base:.3f}",
                    f"{o['solved'].mean() * 100:.1f} %",
                    f,
                    c,
                ]
            )
    for line in md_table(head, table):
        say(line)
    # An idle frame's parts: conversion, and the detector's pass (the former idle cost's core).
    r = recons["fused"]
    idle = streams(lay, 200)["idle"][0]
    n = 2000
    t0 = time.thread_time()
    for i in range(n):
        r.readings.from_delta_c(idle[i % 200], None)
    conv = (time.thread_time() - t0) / n
    d = r.readings.from_delta_c(idle[0], None)[0]
    det = r.detector
    t0 = time.thread_time()
    for _ in range(n):
        det.detect(d, False)
    bank = (time.thread_time() - t0) / n
    say()
    say(
        f"idle frame parts: conversion (from_delta_c) {conv * 1e6:.1f} µs; the detector's pass "
        f"alone {bank * 1e6:.1f} µs (every idle frame ran it before fusion)"
    )
    if args.false_frames:
        say()
        say("false contacts on noise alone (contacts started; per hour at 50 Hz):")
        head = ["idle frames", "mode", "frames", "contacts", "per hour", "95 % upper"]
        for line in md_table(head, false_contacts(recons, lay, args.false_frames)):
            say(line)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        body = "\n".join(say.lines)
        title = "# Held, idle and moving patches: cost with fusion (bench/bench_held.py)"
        cmd = f".venv/bin/python bench/bench_held.py --frames {args.frames}"
        cmd += f" --false-frames {args.false_frames}"
        (args.out / "held.md").write_text(f"{title}\n\n`{cmd}`\n\n{body}\n")


if __name__ == "__main__":
    main()
