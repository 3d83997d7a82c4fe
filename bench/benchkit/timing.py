"""Wall and CPU time of calls and processes, for the side-by-side timings of the benches.

On a shared machine the minimum over repeats filters out other processes (best-of), paired
timings run two candidates alternately so that both see the same background load, and the
per-frame timings of a stream are kept whole for their median and p99.
"""

from __future__ import annotations

import collections
import gc
import inspect
import shutil
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray


def best_of(fn: Callable[[], object], repeats: int) -> float:
    """Best wall time [s] of ``repeats`` calls of fn."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def best_time(fn: Callable[[], object], budget: float = 0.5) -> tuple[float, object]:
    """Best wall time [s] of fn over repeats filling about `budget` seconds (at least 1, at
    most 50 runs), and its last result."""
    best, out, spent, runs = np.inf, None, 0.0, 0
    while runs < 50 and (runs == 0 or spent + best <= budget):
        out = None
        gc.collect()
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best, spent, runs = min(best, dt), spent + dt, runs + 1
    return best, out


def paired_best(
    fa: Callable[[], object], fb: Callable[[], object], budget: float = 1.0
) -> tuple[float, float]:
    """Best times [s] of fa and fb run alternately (same background load for both), repeating
    until about `budget` seconds are spent (at least twice each, at most 200 pairs)."""
    ta = tb = np.inf
    spent, runs = 0.0, 0
    while runs < 200 and (runs < 2 or spent + ta + tb <= budget):
        for fn, which in ((fa, 0), (fb, 1)):
            gc.collect()
            t0 = time.perf_counter()
            fn()
            dt = time.perf_counter() - t0
            spent += dt
            if which == 0:
                ta = min(ta, dt)
            else:
                tb = min(tb, dt)
        runs += 1
    return ta, tb


def per_frame(
    fn: Callable[[Any], Any], frames: Sequence[Any], repeat: int, rng: np.random.Generator
) -> tuple[NDArray[np.float64], int]:
    """Wall time [s] of fn(x) for every frame, ``repeat`` shuffled passes; frames in contact."""
    out, hits = [], 0
    for _ in range(repeat):
        for i in rng.permutation(len(frames)):
            t = time.perf_counter()
            res = fn(frames[i])
            out.append(time.perf_counter() - t)
            hits += bool(getattr(res, "in_contact", False))
    return np.array(out), hits


def timed_build(build: Callable[..., Any], *args: Any) -> tuple[Any, float, float]:
    """(result, wall time [s], peak traced memory [MB]) of ``build(*args)``.

    Timed once untraced (tracemalloc slows allocation-heavy code), then run again under
    tracemalloc for the peak of Python and NumPy allocations."""
    t0 = time.perf_counter()
    out = build(*args)
    seconds = time.perf_counter() - t0
    tracemalloc.start()
    try:
        build(*args)
        peak = tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
    return out, seconds, peak


def cpu_share(run: Callable[[float], object], seconds: float) -> float:
    """Process CPU time / wall time while ``run(seconds)`` executes (1.0 = one core)."""
    c0, w0 = time.process_time(), time.monotonic()
    run(seconds)
    return (time.process_time() - c0) / (time.monotonic() - w0)


def takes(fn: Callable[..., Any], name: str) -> bool:
    """Whether ``fn`` has a parameter ``name`` (a bench runs on older library versions too)."""
    return name in inspect.signature(fn).parameters


def cpu_seconds(pid: int, exclude_tid: int | None = None) -> float:
    """CPU time [s] (user + system) of process ``pid`` so far, without thread ``exclude_tid``."""
    import psutil

    proc = psutil.Process(pid)
    if exclude_tid is None:
        t = proc.cpu_times()
        return t.user + t.system
    return sum(t.user_time + t.system_time for t in proc.threads() if t.id != exclude_tid)


def profile(pid: int, seconds: float, out: Path, skip: str = "") -> str:
    """py-spy samples of ``pid`` for ``seconds`` (raw stacks written to ``out``) → the hottest
    functions (self and inclusive share); stacks through a function named ``skip`` (a load
    generator sharing the process) are left out."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        return "py-spy not installed (pip install py-spy): no profile"
    subprocess.run(
        [
            spy,
            "record",
            "-p",
            str(pid),
            "-d",
            str(int(seconds)),
            "-r",
            "200",
            "-f",
            "raw",
            "-o",
            str(out),
            "--nonblocking",
        ],
        check=True,
        capture_output=True,
    )
    own: collections.Counter[str] = collections.Counter()
    incl: collections.Counter[str] = collections.Counter()
    total = 0
    for line in out.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        n = int(count)
        frames = [
            f.split(" (")[0] + " (" + f.split(" (")[1].split(":")[0] + ")" if " (" in f else f
            for f in stack.split(";")
        ]
        if skip and any(f.split(" (")[0] == skip for f in frames):
            continue
        total += n
        own[frames[-1]] += n
        for f in set(frames):
            incl[f] += n
    idle = sum(n for f, n in own.items() if "wait" in f or "select" in f or "spin_once" in f)
    lines = [f"{total} samples over {seconds:.0f} s ({idle / max(total, 1):.0%} waiting)"]
    lines.append("self time:")
    lines += [f"  {n / max(total, 1):6.1%}  {f}" for f, n in own.most_common(15)]
    lines.append("inclusive time:")
    lines += [f"  {n / max(total, 1):6.1%}  {f}" for f, n in incl.most_common(25)]
    return "\n".join(lines)
