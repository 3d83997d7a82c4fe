"""Where a reconstruction worker's CPU goes over DDS: scene (b) of the whole robot, one worker,
each stage timed with the thread's CPU clock (issue 25; docs/bench/tail.md).

Why not py-spy: on a loaded machine it counts a thread that is runnable but preempted as
running, and the ContactArray's publish wakes the listener, which then takes the core: 24 % of
py-spy's samples sat in that publish (Fast DDS's shared-memory ``sem_post``) for ≈ 5 % of the
worker's CPU.

bench_workers' robot phase (b) runs with one real ``contact_reconstruction`` worker whose
PYTHONPATH holds, before the package, a ``sitecustomize`` that wraps the worker's stages
(the batch callback, the patch-frame and its quiet path, the fusion's steps, solves and idle
looks, the noise tracker, the ContactArray's write and publish, the TaxelBatch read, the takes,
/diagnostics, the heartbeat) with ``time.thread_time``; the package itself is unchanged. After
``--skip`` batches the sums are reset; every 500 batches after that they are written (JSON)
with the process's CPU time over the same span. Printed: each stage's share of the worker's
CPU and of a core, calls and CPU per call. (The wrappers add a few µs a call.)

    python bench/load_stages.py [--seconds 8] [--warmup 6] [--tree DIR] [--out FILE.json]

``--tree``: the package found in DIR (e.g. a ``git worktree`` of the baseline) instead of this
tree's.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from benchkit import ROOT

#: The worker's stage clocks (written as the worker's sitecustomize.py).
SITECUSTOMIZE = r"""
import collections, functools, json, os, time

def _install(path, skip):
    import tactile_contact.ros.contact_batches as cb
    import tactile_contact.ros.contact_reconstruction as cr
    import tactile_contact.ros.patch_pipeline as pp
    import tactile_contact.ros.worker_link as wl
    from tactile_contact.inverse import detection as dt
    from tactile_contact.inverse import temporal as tp

    acc, cnt = collections.Counter(), collections.Counter()
    clock = time.thread_time
    state = {"batches": 0, "p0": 0.0, "w0": 0.0}

    def add(key, t):
        acc[key] += clock() - t
        cnt[key] += 1

    def wrap(owner, name, key=None):
        f = getattr(owner, name, None)
        if f is None:
            return
        key = key or name

        @functools.wraps(f)  # (rclpy inspects a timer callback's signature)
        def timed(*a, **k):
            t = clock()
            try:
                return f(*a, **k)
            finally:
                add(key, t)

        setattr(owner, name, timed)

    for n in ("read_taxel_batch", "write_contact_array", "publish_while_up", "add_row"):
        wrap(cb, n)
    wrap(cb.ContactBatches, "publish", "ContactBatches.publish")
    wrap(cb.ContactBatches, "_rows_of", "ContactBatches._rows_of")
    wrap(pp.PatchPipeline, "frame", "PatchPipeline.frame")
    wrap(pp.PatchPipeline, "_quiet_frame", "PatchPipeline._quiet_frame")
    wrap(pp.PatchPipeline, "_finish", "PatchPipeline._finish")
    wrap(pp.PatchPipeline, "_recount", "PatchPipeline._recount")
    wrap(pp.PatchPipeline, "_publish", "PatchPipeline._publish")
    wrap(pp.PatchPipeline, "catch_up", "PatchPipeline.catch_up")
    wrap(cr.ContactReconstructionNode, "diagnostics_step", "diagnostics_step")
    wrap(cr.ContactReconstructionNode, "_publish_worker_status", "worker status")
    wrap(wl.WorkerLink, "_beat", "heartbeat")
    wrap(dt.NoiseTracker, "update", "NoiseTracker.update")
    for n in ("_fresh", "_resolve", "_idle_pick"):
        wrap(tp.FrameFusion, n, "FrameFusion." + n)

    idle_solve = tp.FrameFusion._idle_solve

    def timed_idle_solve(self, w, on_clock, sigma):
        t = clock()
        found = idle_solve(self, w, on_clock, sigma)
        how = "on the clock" if on_clock else "picked by the scan"
        add(f"idle look {how}, found {found is not None}", t)
        return found

    tp.FrameFusion._idle_solve = timed_idle_solve
    step_message = tp.FrameFusion.step_message

    def timed_step_message(self, *a, **k):
        t = clock()
        out = step_message(self, *a, **k)
        contact = self.result is not None and self.result.in_contact
        add(f"FrameFusion.step_message {self.last}, {'contact' if contact else 'idle'}", t)
        return out

    tp.FrameFusion.step_message = timed_step_message
    take = getattr(cb.ContactBatches, "_take", None)
    if take is not None:

        def timed_take(self):
            t = clock()
            got = take(self)
            add("ContactBatches._take " + ("(a batch)" if got is not None else "(none)"), t)
            return got

        cb.ContactBatches._take = timed_take
    on_batch = cb.ContactBatches._on_batch

    def timed_on_batch(self, data):
        t = clock()
        try:
            return on_batch(self, data)
        finally:
            add("ContactBatches._on_batch", t)
            state["batches"] += 1
            n = state["batches"]
            if n == skip:
                acc.clear()
                cnt.clear()
                state["p0"], state["w0"] = time.process_time(), time.monotonic()
            elif n > skip and n % 500 == 0:
                out = {
                    "process_s": time.process_time() - state["p0"],
                    "wall_s": time.monotonic() - state["w0"],
                    "cpu_s": dict(acc),
                    "calls": dict(cnt),
                }
                with open(path, "w") as f:
                    json.dump(out, f)

    cb.ContactBatches._on_batch = timed_on_batch

_path = os.environ.get("TACTILE_STAGE_CLOCKS")
with open("/proc/self/cmdline", "rb") as _f:
    _worker = b"contact_reconstruction" in _f.read()
if _path and _worker:
    _install(_path, int(os.environ.get("TACTILE_STAGE_SKIP", "1500")))
"""


def report(data: dict) -> list[str]:
    """The stages, largest first: share of the worker's CPU and of a core, calls, µs a call."""
    total, wall = data["process_s"], data["wall_s"]
    lines = [
        f"worker process: {total:.2f} s CPU over {wall:.2f} s = {total / wall:.1%} of a core",
        "| stage | share of the worker | of a core | calls | µs a call |",
        "|---|---|---|---|---|",
    ]
    for key, cpu in sorted(data["cpu_s"].items(), key=lambda kv: -kv[1]):
        n = data["calls"][key]
        lines.append(
            f"| {key} | {cpu / total:.1%} | {cpu / wall:.1%} | {n} | {cpu / n * 1e6:.1f} |"
        )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="measured time of the phase")
    ap.add_argument("--warmup", type=float, default=6.0, help="before the measured window")
    ap.add_argument("--skip", type=int, default=1500, help="batches before the clocks count")
    ap.add_argument("--tree", type=Path, help="run the worker on the package in this folder")
    ap.add_argument("--out", type=Path, help="also write the sums here (JSON)")
    args = ap.parse_args()
    import rclpy
    from bench_workers import ROBOT, ROBOT_BUNDLES, run_phase

    from tactile_contact.offline.build import build_layout

    package = (args.tree or ROOT) / "tactile_contact"
    if not (package / "__init__.py").exists():
        print(f"ERROR: no package tactile_contact in {package.parent}")
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "tactile_contact").symlink_to(package.resolve())
        (work / "sitecustomize.py").write_text(SITECUSTOMIZE)
        sums = work / "stages.json"
        os.environ["TACTILE_STAGE_CLOCKS"] = str(sums)
        os.environ["TACTILE_STAGE_SKIP"] = str(args.skip)
        rclpy.init()
        build_layout(ROBOT, ROBOT_BUNDLES, jobs=2)
        print(f"package {package}; load average {os.getloadavg()[0]:.2f}")
        r = run_phase(
            ROBOT,
            ROBOT_BUNDLES,
            "typical",
            "workers",
            1,
            50.0,
            0,
            args.seconds,
            args.warmup,
            tree=work,
        )
        rclpy.try_shutdown()
        print(
            f"(b) 1 worker: CPU {r['cpu'][0]:.0%} of a core, {r['cpu_per_frame_us']:.0f} µs a "
            f"patch-frame, skipped {r['skipped_share']:.1%}, latency p50 / p99 "
            f"{r['lat_p50']:.2f} / {r['lat_p99']:.2f} ms; load average {os.getloadavg()[0]:.2f}"
        )
        if not sums.exists():
            print(f"ERROR: the worker wrote no stage sums (fewer than {args.skip + 500} batches?)")
            return 1
        data = json.loads(sums.read_text())
    for line in report(data):
        print(line)
    if args.out:
        args.out.write_text(json.dumps(data, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
