"""Where a worker's tail comes from: scene (b) of the whole robot through one
``contact_reconstruction`` node in this process, timed frame by frame (issue 25).

No DDS and no executor: a real ContactReconstructionNode (``input: batches``, every patch of
config/icub_robot.yaml, bundles in out/robot/bundles) is handed bench_workers' readings of scene
(b) (out/bench_workers/readings_icub_robot_typical_*.pkl: run bench_workers' robot phase once
to make them), one TaxelBatch a bus, seven a period, back to back; its diagnostics steps run
at their timer's rate (one per period × patches + 1 per second). Timed, after ``--skip``
periods: each patch-frame (``PatchPipeline.frame``) by patch and by what the fusion did with
it (solved on its own, fused, held: an idle patch's or a held press's; wall time and the
thread's CPU time, which a loaded machine's preemption does not add to), each row's time from
its batch's start until its ContactArray is published, each batch's whole callback (with the
re-solves the fusion deferred until after the publish), each diagnostics step, the garbage
collector's pauses (the node's objects frozen after start-up, as run_node does), and the idle
patches' looks into their window means (``FrameFusion._idle_solve``: on the clock and
screened, or picked by the scan).

    python bench/load_tail.py [--periods 600] [--skip 150] [--tree DIR]

``--tree``: the package found in DIR (e.g. ``git archive <commit> tactile_contact | tar -x -C
DIR``) instead of this tree's, for a before/after pair in alternation.
"""

from __future__ import annotations

import argparse
import collections
import gc
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "icub_robot.yaml"
BUNDLES = ROOT / "out" / "robot" / "bundles"
READINGS = ROOT / "out" / "bench_workers"


def ms(v: list[float]) -> str:
    a = np.asarray(v) * 1e3
    if not a.size:
        return "-"
    return (
        f"n {a.size}, mean {a.mean():.3f}, p50 {np.median(a):.3f}, p90 "
        f"{np.percentile(a, 90):.3f}, p99 {np.percentile(a, 99):.3f}, max {a.max():.2f} ms"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--periods", type=int, default=600, help="20 ms periods fed")
    ap.add_argument("--skip", type=int, default=150, help="periods left out of the figures")
    ap.add_argument("--tree", type=Path, help="run the package found in this folder")
    args = ap.parse_args()
    sys.path.insert(0, str(args.tree or ROOT))
    import rclpy
    from rclpy.parameter import Parameter

    import tactile_contact
    from tactile_contact.model.layout import load_layout
    from tactile_contact.ros.cdr import write_taxel_batch
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    found = sorted(READINGS.glob("readings_icub_robot_typical_*.pkl"))
    if not found:
        print(f"no readings in {READINGS}: run bench/bench_workers.py --phases robot once")
        return 1
    fixed, per_period = pickle.loads(found[-1].read_bytes())
    print(f"package {Path(tactile_contact.__file__).parent}; readings {found[-1].name}")
    rclpy.init()
    node = ContactReconstructionNode(
        parameter_overrides=[
            Parameter("bundles_dir", value=str(BUNDLES)),
            Parameter("layout", value=str(LAYOUT)),
            Parameter("input", value="batches"),
            Parameter("worker_index", value=0),
            Parameter("worker_count", value=1),
        ]
    )
    deadline = time.monotonic() + 30.0
    while not node.link.serving and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    buses: dict[str, list[int]] = {}
    for k, p in enumerate(load_layout(LAYOUT).patches):
        buses.setdefault(p.bus, []).append(k)
    period = [0]
    frames: list[tuple[int, str, str, float]] = []  # (period, patch, fusion's path, s)
    looks: list[tuple[bool, bool, float]] = []  # (clock, screened out, s)
    kinds: dict[str, list[float]] = collections.defaultdict(list)  # what the frame was → s
    kinds_cpu: dict[str, list[float]] = collections.defaultdict(list)  # → the thread's CPU s
    for pipe in node.pipelines.values():
        frame = pipe.frame

        def timed(*a, _frame=frame, _pipe=pipe, **kw):  # type: ignore[no-untyped-def]
            c, t = time.thread_time(), time.perf_counter()
            out = _frame(*a, **kw)
            dt, cpu = time.perf_counter() - t, time.thread_time() - c
            fusion = _pipe.recon.fusion
            last = fusion.last if fusion is not None else ""
            frames.append((period[0], _pipe.name, last, dt))
            if last == "held" and out is not None:  # (republished: idle, or a press held)
                last = "held, in contact" if out.in_contact else "held, idle"
            if period[0] >= args.skip:
                kinds[last].append(dt)
                kinds_cpu[last].append(cpu)
            return out

        pipe.frame = timed
        fusion = pipe.recon.fusion
        if fusion is not None and hasattr(fusion, "_idle_solve"):
            solve = fusion._idle_solve

            def look(w, clock, sigma, _solve=solve, _fusion=fusion):  # type: ignore[no-untyped-def]
                screened = _fusion.counts.screened
                t = time.perf_counter()
                out = _solve(w, clock, sigma)
                looks.append((clock, _fusion.counts.screened > screened, time.perf_counter() - t))
                return out

            fusion._idle_solve = look
    started = [0.0]
    published: list[tuple[int, float, int]] = []  # (period, s after the batch began, rows)
    publish = node.batches.publish

    def timed_publish(rows, _publish=publish):  # type: ignore[no-untyped-def]
        _publish(rows)
        published.append((period[0], time.perf_counter() - started[0], len(rows.patches)))

    node.batches.publish = timed_publish
    # A batch's rows stage all-in (reading the bytes, every patch-frame of it, its rows),
    # thread CPU per patch-frame, for the batches whose every patch-frame was quiet: held
    # idle ("idle") or held idle or in contact ("quiet"), no re-solve left deferred. Why:
    # a batch's quiet frames may go through one compiled call (ros/quiet_batch.py), which
    # PatchPipeline.frame's timing above does not see.
    rows_of = node.batches._rows_of
    from tactile_contact.ros.cdr import read_taxel_batch

    batch_cpu: dict[str, list[float]] = collections.defaultdict(list)

    def timed_rows(data, rows, _rows_of=rows_of):  # type: ignore[no-untyped-def]
        c = time.thread_time()
        out = _rows_of(data, rows)
        cpu = time.thread_time() - c
        if period[0] >= args.skip:
            fusions = [node.pipelines[p].recon.fusion for p in read_taxel_batch(data).patches]
            quiet = all(f.last == "held" and not f.pending for f in fusions)
            if quiet:
                each = cpu / len(fusions)
                batch_cpu["quiet"].append(each)
                if not any(f.result.in_contact for f in fusions):
                    batch_cpu["idle"].append(each)
        return out

    node.batches._rows_of = timed_rows
    kernel_cpu = [0.0, 0]  # the batch's compiled call (ros/quiet_batch.py), thread CPU, frames
    try:
        from tactile_contact.inverse import _temporal_kernels as kern

        quiet_batch = kern.quiet_batch

        def timed_kernel(*a, _call=quiet_batch):  # type: ignore[no-untyped-def]
            c = time.thread_time()
            out = _call(*a)
            if period[0] >= args.skip:
                kernel_cpu[0] += time.thread_time() - c
                kernel_cpu[1] += len(a[3])
            return out

        kern.quiet_batch = timed_kernel
    except (ImportError, AttributeError):
        pass  # (a tree without it)
    pauses: list[float] = []
    gc_start = [0.0]

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            gc_start[0] = time.perf_counter()
        else:
            pauses.append(time.perf_counter() - gc_start[0])

    gc.collect()
    gc.freeze()  # (as run_node does after start-up)
    gc.callbacks.append(on_gc)
    batches: list[tuple[int, float]] = []
    diagnostics: list[float] = []
    steps_per_period = 0.02 * (len(node.pipelines) + 1)
    due = 0.0
    for j in range(args.periods):
        period[0] = j
        rows = per_period[j % len(per_period)]
        for members in buses.values():
            now = time.time_ns()
            data = write_taxel_batch(
                now,
                "",
                [fixed[k][0] for k in members],
                [fixed[k][1] for k in members],
                [now] * len(members),
                [fixed[k][2] for k in members],
                [rows[k][0] for k in members],
                [rows[k][1] for k in members],
                [fixed[k][3] for k in members],
            )
            started[0] = time.perf_counter()
            node.batches.on_batch(bytes(data))
            batches.append((j, time.perf_counter() - started[0]))
        due += steps_per_period
        while due >= 1.0:
            due -= 1.0
            t = time.perf_counter()
            node.diagnostics_step()
            diagnostics.append(time.perf_counter() - t)
    gc.callbacks.remove(on_gc)
    skip = args.skip
    kept = [f for f in frames if f[0] >= skip]
    work = collections.defaultdict(float)
    by = collections.defaultdict(list)
    for j, name, last, dt in kept:
        work[j] += dt
        by[(name, last)].append(dt)
    print(f"{args.periods - skip} periods measured, {len(kept)} patch-frames")
    print(f"patch-frame (PatchPipeline.frame): {ms([f[3] for f in kept])}")
    print(f"a period's patch-frames together: {ms(list(work.values()))}")
    for kind in sorted(kinds):
        v, c = np.asarray(kinds[kind]) * 1e6, np.asarray(kinds_cpu[kind]) * 1e6
        print(
            f"  a patch-frame {kind}: n {v.size}, p50 {np.median(v):.1f}, p90 "
            f"{np.percentile(v, 90):.1f}, p99 {np.percentile(v, 99):.1f}, max {v.max():.0f} µs;"
            f" its CPU time mean {c.mean():.1f}, p50 {np.median(c):.1f}, p99 "
            f"{np.percentile(c, 99):.1f} µs"
        )
    for kind in ("idle", "quiet"):
        c = np.asarray(batch_cpu[kind]) * 1e6
        if c.size:
            print(
                f"  a batch of {kind} patch-frames only, its rows stage all-in, thread CPU a "
                f"patch-frame: batches {c.size}, mean {c.mean():.1f}, p50 {np.median(c):.1f}, "
                f"p90 {np.percentile(c, 90):.1f}, p99 {np.percentile(c, 99):.1f} µs"
            )
    if kernel_cpu[1]:
        print(
            f"  the batches' compiled call (quiet_batch): {kernel_cpu[1]} patch-frames, thread "
            f"CPU {kernel_cpu[0] / kernel_cpu[1] * 1e6:.1f} µs a patch-frame (mean)"
        )
    rows_after = [dt for j, dt, n in published if j >= skip for _ in range(n)]
    print(f"a row, its batch's start → its ContactArray published: {ms(rows_after)}")
    print(
        f"a batch's whole callback (deferred re-solves included): "
        f"{ms([dt for j, dt in batches if j >= skip])}"
    )
    print(f"a diagnostics step: {ms(diagnostics)}")
    print(f"gc pauses: {ms(pauses)}")
    for clock in (True, False):
        for out in (True, False):
            v = [dt for c, s, dt in looks if c == clock and s == out]
            if v:
                what = "on the clock" if clock else "picked by the scan"
                print(
                    f"idle look, {what}, {'screened out' if out else 'solved'}: {ms(v)}, "
                    f"total {sum(v) * 1e3:.0f} ms (all periods)"
                )
    counts: collections.Counter[str] = collections.Counter()
    for pipe in node.pipelines.values():
        if pipe.recon.fusion is not None:
            c = pipe.recon.fusion.counts
            for key in ("solved", "fused", "held", "screened", "deferred"):
                counts[key] += getattr(c, key, 0)
    print(
        "the fusion's counts, every patch, all periods: "
        + ", ".join(f"{k} {v}" for k, v in counts.items())
    )
    print("the patches and paths that cost most (sum over the measured periods):")
    for (name, last), v in sorted(by.items(), key=lambda kv: -sum(kv[1]))[:12]:
        print(f"  {name:22s} {last or '-':7s} {ms(v)}, sum {sum(v) * 1e3:.0f} ms")
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
