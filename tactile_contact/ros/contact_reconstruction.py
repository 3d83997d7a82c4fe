"""``contact_reconstruction`` node: taxel ΔC in, traction/deflection grids and contact summary out.

A thin adapter over :class:`tactile_contact.inverse.reconstruction.Reconstructor`: one bundle per
patch, loaded at start (a stale or broken bundle is refused with one log line and the other
patches go on). With ``layout`` set, every patch of that layout must have a bundle: one that has
none, or none usable, is an ERROR in /diagnostics and a warning at start naming the
``tactile-contact-build`` command that makes it. Each contact is logged when it starts (its
force and place) and when it ends (its peak force and duration).

Input (``input``): ``patches`` takes each patch's ``<patch>/taxels`` (TaxelArray) as it
always did; ``batches`` takes ``taxel_batches`` (TaxelBatch: a bus's patches in one message,
as skin_driver publishes them; tactile_contact.ros.contact_batches). A skin too large for one
core is split over worker processes (``worker_index`` of ``worker_count``: each serves its
share of the patches, balanced by taxels, tactile_contact.ros.workers), which announce
themselves and never serve a patch twice (tactile_contact.ros.worker_link). It publishes

- ``contacts`` (tactile_contact/ContactArray): the summaries of every patch of an input
  message in one message;
- ``<patch>/contact`` (tactile_contact/ContactState): every frame with ``input: patches``;
  with ``batches`` while something subscribes to it;
- ``<patch>/traction`` (sensor_msgs/Image 32FC1, Pa) and ``<patch>/deflection`` (32FC1, m);
- ``<patch>/traction_geometry``, ``<patch>/deflection_geometry`` (tactile_contact/GridGeometry,
  reliable + transient local, published once);
- ``<patch>/taxel_markers``, ``<patch>/contact_markers`` (MarkerArray) and
  ``<patch>/pressure_cloud`` (PointCloud2) for rviz2;
- ``/diagnostics`` (skips, stage timings, latency, errors).

Work nobody asked for is skipped and counted: an output without subscribers is not computed
(the deflection field is not even resampled), a patch with no contact costs no solve, and the
constrained solve runs only when the free solution needs it (decided inside the Reconstructor).
The subscription keeps only the newest frame, so a slow frame never queues old ones.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.layout import load_layout
from tactile_contact.offline.bundle import load_bundle, read_manifest, source_problem
from tactile_contact.ros.common import (
    DIAGNOSTICS_QOS,
    ERROR,
    OK,
    STRING_ARRAY_EMPTY,
    WARN,
    declare_parameter,
    diagnostic_status,
    log_parameters,
    publish_while_up,
    read_at_start_only,
    run_node,
)
from tactile_contact.ros.contact_batches import ContactBatches
from tactile_contact.ros.patch_pipeline import (  # noqa: F401  (their old home: re-exported)
    CONTACT_END_S,
    OUTPUT_QOS,
    QUIET_EVENTS,
    PatchPipeline,
    PatchStats,
    check_result,
    file_signature,
)
from tactile_contact.ros.worker_link import WorkerLink
from tactile_contact.ros.workers import bus_filter, worker_patches

#: Patches whose statuses one diagnostics step takes (≈ 90 µs each: with all 24 at once the
#: frames arriving meanwhile waited ≈ 10 ms). Several a step, not one: each step is a timer
#: callback, and rclpy's executor costs ≈ 85 µs per callback whatever it does
#: (docs/bench/load.md, "Idle patches sent less often").
DIAG_PATCHES_PER_STEP = 6

PARAMETERS = (
    "bundles_dir",
    "layout",
    "patches",
    "input",
    "worker_index",
    "worker_count",
    "queue_depth",
    "visualization_every",
    "taxel_full_scale",
    "diagnostics_period",
    "follow_contacts",
    "fuse_frames",
)


def load_reconstructor(path: Path, follow: bool = True, fuse: bool = True) -> Reconstructor:
    """A Reconstructor of the bundle at ``path``, its arrays read into memory, warmed up;
    following contacts from frame to frame unless ``follow`` is False, fusing the frames of a
    scene held still (:mod:`tactile_contact.inverse.temporal`) unless ``fuse`` is False.

    Not memory-mapped: a bundle file overwritten in place while mapped would crash the process
    (SIGBUS) at the next frame; read, the node keeps what it checked and loaded. Warmed up
    (:meth:`Reconstructor.warm_up`): the first contact must not wait for kernels to compile,
    and a bundle that cannot solve is refused here, before it serves.
    """
    recon = Reconstructor(load_bundle(path, mmap=False), follow=follow, fuse=fuse)
    recon.warm_up()
    return recon


def _read_layout(path: Path) -> Any:
    """The layout at ``path``, or the exception reading it raised (for a thread's result)."""
    try:
        return load_layout(path)
    except Exception as exc:
        return exc


def bundle_signature(path: Path) -> tuple:
    """What changes when a bundle folder is deleted, replaced or rewritten (() if missing):
    the folder's inode, then each file's name, inode, mtime [ns] and size, by name. (os.scandir
    rather than pathlib: a diagnostics step looks at one bundle, and pathlib's objects
    doubled its 11 stat calls' cost, 130 against 64 µs.)"""
    try:
        folder = os.stat(path)
        with os.scandir(path) as found:
            files = sorted(found, key=lambda f: f.name)
        return (folder.st_ino, *((f.name, *_stat(f.stat())) for f in files))
    except OSError:
        return ()


def _stat(st: os.stat_result) -> tuple[int, int, int]:
    return st.st_ino, st.st_mtime_ns, st.st_size


class ContactReconstructionNode(Node):
    """Loads one bundle per patch and runs a :class:`PatchPipeline` for each."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("contact_reconstruction", **kwargs)
        self.bundles_dir = Path(
            declare_parameter(
                self, "bundles_dir", "bundles", "folder holding one matrix bundle per patch"
            )
        ).expanduser()
        self.layout = declare_parameter(
            self,
            "layout",
            "",
            "patch layout YAML the bundles are built from: each of its patches needs a bundle "
            "(ERROR in /diagnostics without one); empty: serve the bundles in bundles_dir",
        )
        requested = declare_parameter(
            self,
            "patches",
            STRING_ARRAY_EMPTY,
            "patches to serve (empty: every bundle in bundles_dir, or of the layout); lets "
            "processes share a skin (see also worker_index and worker_count)",
        )
        self.input = declare_parameter(
            self,
            "input",
            "patches",
            "patches: each patch's <patch>/taxels (TaxelArray); batches: taxel_batches "
            "(TaxelBatch, a bus's patches in one message: far less ROS work per frame)",
            choices=("patches", "batches"),
        )
        worker_index = declare_parameter(
            self,
            "worker_index",
            -1,
            "this process's index among worker_count workers (-1: not a worker)",
            int_range=(-1, 1023),
        )
        worker_count = declare_parameter(
            self,
            "worker_count",
            0,
            "workers sharing the patches (given by name, or those of the layout or bundles), "
            "each serving its share balanced by taxels; 0: serve them all in this process",
            int_range=(0, 1024),
        )
        if worker_count and not 0 <= worker_index < worker_count:
            raise ValueError(
                f"worker_index {worker_index} is not one of the {worker_count} workers "
                f"(0..{worker_count - 1})"
            )
        self.queue_depth = declare_parameter(
            self,
            "queue_depth",
            1,
            "input frames kept while a solve runs (1: only the newest; more: process every "
            "frame, late, when the machine cannot keep up)",
            int_range=(1, 1000),
        )
        self.visualization_every = declare_parameter(
            self,
            "visualization_every",
            1,
            "publish rviz markers and the pressure cloud every N-th frame",
            int_range=(1, 1000),
        )
        self.taxel_full_scale = declare_parameter(
            self,
            "taxel_full_scale",
            2.0e-13,
            "ΔC shown at full colour in the taxel markers",
            unit="F",
            float_range=(1e-16, 1e-9),
        )
        self.follow_contacts = declare_parameter(
            self,
            "follow_contacts",
            True,
            "start each frame's contact fit from the last frame's contact and search the whole "
            "patch only when it no longer explains the readings (false: every frame on its own)",
        )
        self.fuse_frames = declare_parameter(
            self,
            "fuse_frames",
            True,
            "while a patch's readings hold still, solve the mean of their frames now and then "
            "and republish its result in between: a held press is measured better the longer "
            "it is held and costs almost nothing; a change is solved at once (false: every "
            "frame solved)",
        )
        period = declare_parameter(
            self,
            "diagnostics_period",
            1.0,
            "period of /diagnostics",
            unit="s",
            float_range=(0.05, 60.0),
        )
        log_parameters(self, PARAMETERS)
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        read_at_start_only(self)
        self.load_errors: dict[str, str] = {}
        self.pipelines: dict[str, PatchPipeline] = {}
        self._refused: dict[Path, tuple] = {}  # bundle → signature of the refused version
        self._loader: ThreadPoolExecutor | None = None  # bundles changed on disk, loaded
        self._loads: dict[Path, tuple[tuple, Future]] = {}  # bundle → (signature, its load)
        # A served bundle's layout file → (its signature, its reading on the loader's thread).
        self._source_jobs: dict[Path, tuple[tuple, Future]] = {}
        self._paths = self._bundle_paths(requested)
        counts, buses = self._sizes_and_buses()
        if worker_count:
            # A name the layout does not have is in no worker's share: said (by worker 0),
            # not dropped in silence.
            for name in sorted(set(self._paths) - set(counts)) if worker_index == 0 else ():
                self.load_errors[name] = (
                    f"patch {name!r} (parameter patches) is not in the layout {self.layout}: "
                    "no worker serves it"
                )
                self.get_logger().error(f"patch {name}: {self.load_errors[name]}")
            mine = worker_patches(counts, worker_index, worker_count, buses)
            self._paths = {name: path for name, path in self._paths.items() if name in mine}
            self.get_logger().info(
                f"worker {worker_index} of {worker_count}: patches {sorted(self._paths)}"
            )
        self.link = WorkerLink(
            self,
            list(self._paths),
            worker_index,
            worker_count,
            lambda: sum(p.stats.frames for p in self.pipelines.values()),
        )
        only = None
        if all(name in buses for name in self._paths):
            only = bus_filter({buses[name] for name in self._paths}, buses.values())
        self.batches = ContactBatches(self, self.input == "batches", only)
        for name, path in self._paths.items():
            sig = bundle_signature(path)
            try:
                recon = load_reconstructor(path, self.follow_contacts, self.fuse_frames)
            except Exception as exc:  # every refusal is reported; other patches go on
                self.load_errors[name] = self._unusable(path, exc)
                self._refused[path] = sig
                self.get_logger().warning(f"patch {name}: {self.load_errors[name]}")
                continue
            self.pipelines[recon.patch] = PatchPipeline(self, recon, path, sig)
            self.get_logger().info(
                f"patch {recon.patch}: {len(recon.taxel_ids)} taxels, "
                f"traction grid {recon.traction_grid.shape}, bundle {path}"
            )
        if "*" in self.load_errors:
            self.get_logger().warning(self.load_errors["*"])
        elif not self.pipelines and not self.load_errors:
            self.load_errors["*"] = (
                f"no bundle in {self.bundles_dir}: build them with {self.build_command()}"
            )
            self.get_logger().warning(self.load_errors["*"])
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        # One period's diagnostics work in steps of DIAG_PATCHES_PER_STEP patches: done at
        # once for 24 patches it took ≈ 10 ms, which every frame arriving meanwhile waited
        # for (its p99 latency). The array still goes out once a period, with every patch.
        # The steps are counted from the patches given (bundles refused now may load later).
        self._diag_todo: list[str] = []
        self._diag_done: dict[str, Any] = {}
        self._diag_steps = -(-len(self._paths) // DIAG_PATCHES_PER_STEP) + 1
        self._diag_tick = 0
        self._diag_per_step = DIAG_PATCHES_PER_STEP
        self.create_timer(period / self._diag_steps, self.diagnostics_step)
        if self.link.worker_mode:  # (a lone node's array stays what it always was)
            self.create_timer(period, self._publish_worker_status)

    def now_ns(self) -> int:
        """Now [ns since the epoch]: the system clock read directly (rclpy's Clock.now()
        builds objects: ≈ 20 µs a call here), the ROS clock with use_sim_time."""
        if self._sim_time:
            return self.get_clock().now().nanoseconds
        return time.time_ns()

    def _sizes_and_buses(self) -> tuple[dict[str, int], dict[str, str]]:
        """Patch → taxels, for the split over workers: from the layout if given (the same
        file on every machine), else from each bundle's manifest (1 if unreadable: the
        worker given it reports why); and every patch of the layout → its bus, for the split
        and the batches' filter: from the layout only (a manifest may name an older bus:
        moving a patch to another bus needs no rebuild), so without a layout none."""
        if self.layout:
            layout = load_layout(self.layout)
            counts = {p.name: len(p.taxel_ids()) for p in layout.patches if p.name in self._paths}
            return counts, {p.name: p.bus for p in layout.patches}
        counts, unread = {}, []
        for name, path in self._paths.items():
            try:
                counts[name] = int(read_manifest(path)["arrays"]["taxel_ids"]["shape"][0]) or 1
            except Exception:
                counts[name], unread = 1, [*unread, name]
        if unread and self.get_parameter("worker_count").value:
            self.get_logger().warning(
                f"worker split without a layout, and the manifests of {unread} unreadable "
                "(counted as 1 taxel): a worker that reads them splits differently and a patch "
                "may go unserved; give every worker the same `layout`"
            )
        return counts, {}

    def build_command(self) -> str:
        """The command that builds the bundles this node looks for."""
        return f"tactile-contact-build {self.layout or 'LAYOUT.yaml'} -o {self.bundles_dir}"

    def _unusable(self, path: Path, exc: BaseException) -> str:
        """Why the bundle at ``path`` cannot serve, and the command that builds it."""
        text = str(exc)
        if str(path) not in text:  # (the bundle errors name the folder already)
            text = f"{path}: {text}"
        verb = "no bundle" if not path.exists() else "bundle refused"
        return f"{verb} ({text}); build it with {self.build_command()}"

    def _bundle_paths(self, requested: list[str]) -> dict[str, Path]:
        if self.layout and not requested:
            # LayoutError (file, key and problem) ends the start, as a bad parameter does
            requested = [p.name for p in load_layout(self.layout).patches]
        if requested:
            return {name: self.bundles_dir / name for name in requested}
        if not self.bundles_dir.is_dir():
            self.load_errors["*"] = (
                f"{self.bundles_dir}: no such folder; build the bundles with {self.build_command()}"
            )
            return {}
        return {p.name: p for p in sorted(self.bundles_dir.iterdir()) if p.is_dir()}

    def summary(self) -> list[str]:
        """A line per patch: frames, contacts, peak force, drops; or why it was not served."""
        lines = [p.summary() for p in self.pipelines.values()]
        return lines + [f"{name}: not served: {error}" for name, error in self.load_errors.items()]

    def watch_bundles(self) -> None:
        """Notice bundles deleted or replaced on disk since they were loaded.

        A replaced bundle is loaded and checked first; only a good one replaces the one in
        use (a refused one is reported and the loaded copy goes on serving). A deleted one
        is reported; the copy in memory goes on serving. A bundle refused at start is tried
        again when it changes.
        """
        for pipe in list(self.pipelines.values()):
            self.watch_bundle(pipe)
        self.retry_refused()

    def _load(self, path: Path, sig: tuple, wait: bool) -> Reconstructor | Exception | None:
        """The bundle at ``path`` (of signature ``sig``) loaded: its Reconstructor, or the
        exception that refused it. ``wait`` False: loaded on a thread of its own, None until
        done (a robot's 240-taxel bundle takes 0.7–1 s to load and warm up: on the executor
        it held every frame of the worker, and its heartbeat past the monitor's 0.5 s)."""
        if wait:
            try:
                return load_reconstructor(path, self.follow_contacts, self.fuse_frames)
            except Exception as exc:
                return exc
        pending = self._loads.get(path)
        if pending is None or pending[0] != sig:  # (changed again while loading: anew)
            if self._loader is None:
                self._loader = ThreadPoolExecutor(1, thread_name_prefix="bundle_load")
            job = self._loader.submit(
                load_reconstructor, path, self.follow_contacts, self.fuse_frames
            )
            self._loads[path] = (sig, job)
            return None
        if not pending[1].done():
            return None
        del self._loads[path]
        exc = pending[1].exception()
        return exc if isinstance(exc, Exception) else pending[1].result()

    def watch_bundle(self, pipe: PatchPipeline, wait: bool = True) -> None:
        """:meth:`watch_bundles` for one served patch's bundle (≈ 0.1 ms of stat calls; the
        diagnostics steps take one patch's at a time: all 34 of the robot at once held
        the frames behind them for ≈ 4.5 ms). ``wait`` False: a changed bundle is loaded on
        a thread and taken by a later call (the diagnostics steps')."""
        log = self.get_logger()
        sig = bundle_signature(pipe.bundle)
        if sig == pipe.signature or sig == self._refused.get(pipe.bundle) or not sig:
            self._loads.pop(pipe.bundle, None)  # (a load of a version gone since: unused)
        if sig == pipe.signature:
            self._watch_source(pipe)
            return
        if sig == self._refused.get(pipe.bundle):
            return
        if not sig:
            if not pipe.bundle_problem.startswith("bundle deleted"):
                pipe.bundle_problem = (
                    f"bundle deleted on disk ({pipe.bundle}); serving the copy loaded before"
                )
                log.warning(f"patch {pipe.name}: {pipe.bundle_problem}")
            return
        recon = self._load(pipe.bundle, sig, wait)
        if recon is None:
            return
        try:
            if isinstance(recon, Exception):
                raise recon
            if recon.patch != pipe.name:
                raise ValueError(f"it is now a bundle of patch {recon.patch!r}")
        except Exception as exc:
            self._refused[pipe.bundle] = sig
            pipe.bundle_problem = (
                f"bundle replaced on disk by one refused ({exc}); serving the copy loaded before"
            )
            log.error(f"patch {pipe.name}: {pipe.bundle_problem}")
            return
        pipe.use(recon)
        pipe.signature, pipe.bundle_problem = sig, ""
        pipe.reloads += 1
        self._refused.pop(pipe.bundle, None)
        log.info(f"patch {pipe.name}: bundle {pipe.bundle} replaced on disk; reloaded")

    def _watch_source(self, pipe: PatchPipeline) -> None:
        """Notice an edit of the layout file a served bundle was built from that makes the
        bundle stale (a module moved, a parameter changed): the next start would refuse it,
        and the copy in memory no longer describes the skin. Said (ERROR) at once, the copy
        going on serving; cleared if the file matches again. Why: it stayed OK until a
        respawn took the patch down. The file is read on the loader's thread, once a change
        for every patch built from it (a robot's layout: ≈ 0.2 s to read; on the executor,
        each patch's check held every frame behind it)."""
        source = pipe.source
        sig = file_signature(source)
        if sig == pipe.source_signature:
            return
        log = self.get_logger()
        if not sig:  # (deleted: a start no longer checks the bundle against it either)
            pipe.source_signature = sig
            if pipe.bundle_problem.startswith("its layout file changed"):
                pipe.bundle_problem = ""
            log.warning(f"patch {pipe.name}: its layout file {source} is gone; not checked")
            return
        assert source is not None
        job = self._source_jobs.get(source)
        if job is None or job[0] != sig:
            if self._loader is None:
                self._loader = ThreadPoolExecutor(1, thread_name_prefix="bundle_load")
            self._source_jobs[source] = (sig, self._loader.submit(_read_layout, source))
            return
        if not job[1].done():
            return
        pipe.source_signature = sig
        problem = source_problem(pipe.bundle, job[1].result())
        if problem:
            pipe.bundle_problem = (
                f"its layout file changed since the build, refused at the next start "
                f"({problem}); serving the copy loaded before"
            )
            log.error(f"patch {pipe.name}: {pipe.bundle_problem}")
        elif pipe.bundle_problem.startswith("its layout file changed"):
            pipe.bundle_problem = ""
            log.info(f"patch {pipe.name}: its layout file {source} matches its bundle again")

    def retry_refused(self, wait: bool = True) -> None:
        """The bundles refused at start, tried again when they changed on disk (``wait``
        False: as :meth:`watch_bundle`)."""
        log = self.get_logger()
        for name, path in self._paths.items():
            if name not in self.load_errors:
                continue
            sig = bundle_signature(path)
            if not sig or sig == self._refused.get(path):
                self._loads.pop(path, None)  # (a load of a version gone since: unused)
                continue
            recon = self._load(path, sig, wait)
            if recon is None:
                continue
            if isinstance(recon, Exception):
                exc = recon
                self._refused[path] = sig
                self.load_errors[name] = self._unusable(path, exc)
                log.error(f"patch {name}: {self.load_errors[name]}")
                continue
            if recon.patch in self.pipelines:
                continue
            del self.load_errors[name]
            self._refused.pop(path, None)
            self.pipelines[recon.patch] = PatchPipeline(self, recon, path, sig)
            log.info(f"patch {recon.patch}: bundle {path} now loads; serving it")

    def diagnostics_step(self) -> None:
        """One step of the diagnostics period (a period is a fixed number of steps): the
        first tries the bundles refused again, the others take the patches' statuses
        (DIAG_PATCHES_PER_STEP a step, more when more bundles loaded than the steps were
        counted for), each one's bundle watched; the array goes out once a period, at the
        step that took the last (at the first when there is none)."""
        tick = self._diag_tick
        self._diag_tick = (tick + 1) % self._diag_steps
        if any(job.done() for _, job in self._loads.values()):
            self._watching(self._take_loaded)
        if tick == 0:
            self._watching(lambda: self.retry_refused(wait=False))
            self._diag_todo = [n for n in reversed(self.pipelines) if self._reports(n)]
            spread = max(self._diag_steps - 1, 1)
            self._diag_per_step = max(DIAG_PATCHES_PER_STEP, -(-len(self._diag_todo) // spread))
            if self._diag_todo and self._diag_steps > 1:
                return
        elif not self._diag_todo:
            return  # (this period's array went out)
        for _ in range(min(self._diag_per_step, len(self._diag_todo))):
            name = self._diag_todo.pop()
            pipe = self.pipelines.get(name)
            if pipe is not None:
                self._watching(lambda pipe=pipe: self.watch_bundle(pipe, wait=False))
                self._diag_done[name] = pipe.diagnostics()
        if self._diag_todo:
            return
        self._publish_diagnostics(
            [
                self._diag_done[n]
                for n in self.pipelines
                if n in self._diag_done and self._reports(n)
            ]
        )

    def _take_loaded(self) -> None:
        """The bundles loaded on the loader's thread since the last step, put to use."""
        by_bundle = {pipe.bundle: pipe for pipe in self.pipelines.values()}
        for path, (_, job) in list(self._loads.items()):
            if job.done() and path in by_bundle:
                self.watch_bundle(by_bundle[path], wait=False)
        if any(job.done() for _, job in self._loads.values()):
            self.retry_refused(wait=False)

    def destroy_node(self) -> None:
        """The node's ROS entities, and a bundle load under way left to end on its own."""
        # (getattr: a node whose construction failed, e.g. on a parameter of the wrong type,
        # is destroyed too, by its context's shutdown)
        loader = getattr(self, "_loader", None)
        if loader is not None:
            loader.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()

    def _watching(self, watch: Any) -> None:
        """Run ``watch`` (a look at the bundles on disk); never raises into the executor."""
        try:
            watch()
        except Exception as exc:
            self.get_logger().error(
                f"watching bundles: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0
            )

    def _reports(self, patch: str) -> bool:
        """Whether this process reports the patch on /diagnostics: a worker only those it
        serves (one left to another worker is that one's to report)."""
        return not self.link.worker_mode or patch in self.link.serving

    def _publish_diagnostics(self, statuses: list[Any]) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = statuses
        for name, error in self.load_errors.items():
            msg.status.append(
                diagnostic_status(f"contact_reconstruction: {name}", ERROR, error, {}, name)
            )
        if self.input == "batches" and not self.link.worker_mode:
            # (a worker reports its batches in its own status; a lone node's bad batches and
            # clock steps were in its log only)
            msg.status.append(self._batches_status())
        # (a timer: it may run while a Ctrl-C shuts the context down under it)
        publish_while_up(self, self.pub_diag, msg)

    def _batches_status(self) -> Any:
        """The taxel_batches input's status (a node that is no worker): batches taken, the
        last bad one, the last clock step."""
        b = self.batches
        quiet = b.quiet
        faults = b.bad_batches + (quiet.errors if quiet is not None else 0)
        level = WARN if faults or b.clock_steps else OK
        parts = [f"{b.batches} batches"]
        if b.last_error:
            parts.append(f"last bad batch: {b.last_error}")
        if b.last_clock_step:
            parts.append(f"last clock step: {b.last_clock_step}")
        if quiet is not None and quiet.last_error:
            parts.append(f"last {quiet.last_error}")
        values = {"input": self.input, **b.values(), "cpu_time_s": time.process_time()}
        return diagnostic_status(
            "contact_reconstruction: batches", level, "; ".join(parts), values, "batches"
        )

    def _publish_worker_status(self) -> None:
        """The worker's own status, in an array of its own (timer, once a period)."""
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._worker_status()]
        publish_while_up(self, self.pub_diag, msg)

    def _worker_status(self) -> Any:
        """This process as a worker: what it serves, what it left to others, batches."""
        link = self.link
        problem, text = link.status()
        me = link.me
        values: dict[str, object] = {
            "worker": me.worker,
            "index": me.index,
            "count": me.count,
            "input": self.input,
            "patches": " ".join(sorted(link.serving)),
            "yielded": " ".join(sorted(link.yielded)),
            **self.batches.values(),
            "cpu_time_s": time.process_time(),
        }
        served = f"serving {len(link.serving)} of {len(link.given)} patches"
        quiet = self.batches.quiet
        faults = self.batches.bad_batches + (quiet.errors if quiet is not None else 0)
        level = WARN if problem or faults or self.batches.clock_steps else OK
        message = f"{served}; {text}" if text else served
        if self.batches.last_error:
            message += f"; last bad batch: {self.batches.last_error}"
        if self.batches.last_clock_step:
            message += f"; last clock step: {self.batches.last_clock_step}"
        if quiet is not None and quiet.last_error:
            message += f"; last {quiet.last_error}"
        name = f"contact_reconstruction: worker {me.worker}"
        return diagnostic_status(name, level, message, values, me.worker)


def main(args: list[str] | None = None) -> None:
    """Run ``contact_reconstruction`` until Ctrl-C; exit 1 with a message if it cannot start."""
    run_node("contact_reconstruction", ContactReconstructionNode, args, events=True)


if __name__ == "__main__":
    main()
