"""``contact_reconstruction`` node: taxel ΔC in, traction/deflection grids and contact summary out.

A thin adapter over :class:`tactile_contact.inverse.reconstruction.Reconstructor`: one bundle per
patch, loaded at start (a stale or broken bundle is refused with one log line and the other
patches go on). With ``layout`` set, every patch of that layout must have a bundle: one that has
none, or none usable, is an ERROR in /diagnostics and a warning at start naming the
``tactile-contact-build`` command that makes it. Each contact is logged when it starts (its
force and place) and when it ends (its peak force and duration). Per patch it subscribes to
``<patch>/taxels`` and publishes

- ``<patch>/contact`` (tactile_contact/ContactState), every frame;
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

import math
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header
from threadpoolctl import threadpool_limits
from visualization_msgs.msg import MarkerArray

from tactile_contact.inverse.detection import NoiseTracker
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.layout import load_layout
from tactile_contact.msg import ContactState, GridGeometry, TaxelArray
from tactile_contact.offline.bundle import load_bundle
from tactile_contact.ros import convert
from tactile_contact.ros.common import (
    DIAGNOSTICS_QOS,
    ERROR,
    OK,
    STATIC_QOS,
    STRING_ARRAY_EMPTY,
    WARN,
    declare_parameter,
    diagnostic_status,
    log_parameters,
    run_node,
    seconds_from_stamp,
)

# The online products are small (taxels × cells, a few hundred kB): extra BLAS threads only
# spin-wait between frames (measured: 1.25 instead of 0.48 cores for one patch at 50 Hz).
threadpool_limits(limits=1, user_api="blas")

#: A fault of one kind on one patch is logged at most once per this many seconds.
LOG_THROTTLE_S = 5.0
#: Subscribers to the optional outputs (images, markers, cloud) are counted this often [s].
SUBSCRIBERS_RECOUNT_S = 0.2
#: A contact has ended (and is logged so) after frames without contact for this long [s] of
#: their stamps: a frame or two lost near the detection threshold does not split a press.
CONTACT_END_S = 0.25

OUTPUT_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
QUIET_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)

# A taxel with any of these flags is left out of the solve.
_UNUSABLE = (
    TaxelArray.STATUS_DISABLED
    | TaxelArray.STATUS_STUCK
    | TaxelArray.STATUS_DEAD
    | TaxelArray.STATUS_SATURATED
)

PARAMETERS = (
    "bundles_dir",
    "layout",
    "patches",
    "queue_depth",
    "visualization_every",
    "taxel_full_scale",
    "diagnostics_period",
    "follow_contacts",
)


@dataclass
class PatchStats:
    """Counters and timings of one patch since start (timings keep the last 1000 frames)."""

    frames: int = 0
    solved: int = 0
    constrained: int = 0
    skipped_idle: int = 0
    skipped_deflection: int = 0
    skipped_images: int = 0
    skipped_visualization: int = 0
    bad_frames: int = 0
    foreign_frames: int = 0
    nonfinite_frames: int = 0
    nonfinite_readings: int = 0
    out_of_range: int = 0
    unpublishable: int = 0
    internal_errors: int = 0
    contacts: int = 0  # contacts started (a press, from its first frame to CONTACT_END_S after)
    contact_frames: int = 0
    peak_force: float = 0.0  # largest total force [N] of any frame
    last_error: str = ""
    latency_s: deque = field(default_factory=lambda: deque(maxlen=1000))
    stage_s: dict = field(default_factory=dict)

    def time(self, stage: str, seconds: float) -> None:
        self.stage_s.setdefault(stage, deque(maxlen=1000)).append(seconds)


def _finite(x: float) -> float:
    """x, NaN → 0 and ±inf → ±the largest float (np.nan_to_num of a scalar, 20× faster)."""
    if math.isfinite(x):
        return x
    return 0.0 if math.isnan(x) else math.copysign(sys.float_info.max, x)


def check_result(result: Any) -> None:
    """Refuse a result that no message may carry: anything non-finite, a negative force, area
    or peak pressure (raises :class:`convert.NonFiniteError`, so nothing of the frame goes out).
    """
    values = [result.total_force, result.contact_area, result.peak_pressure, *result.cop]
    values += [x for c in result.contacts for x in (c.force, c.radius, *c.center)]
    if not all(map(math.isfinite, values)):  # (a dozen scalars: numpy's call costs more)
        raise convert.NonFiniteError("contact summary: non-finite value(s); not published")
    forces = [result.total_force, result.contact_area, result.peak_pressure]
    forces += [x for c in result.contacts for x in (c.force, c.radius)]
    if min(forces) < 0.0:
        raise convert.NonFiniteError(
            f"contact summary: negative force, area, pressure or radius ({min(forces):.3g}); "
            "not published"
        )
    for name in ("traction", "deflection"):
        field_ = getattr(result, name)
        if field_ is not None and not np.all(np.isfinite(field_)):
            raise convert.NonFiniteError(f"{name}: non-finite value(s); not published")


class PatchPipeline:
    """Publishers, the reconstructor and the taxel mapping of one patch."""

    def __init__(
        self, node: Node, recon: Reconstructor, bundle: Path, signature: tuple = ()
    ) -> None:
        self.node = node
        self.bundle = bundle
        self.name: str = recon.patch
        self.frame_id: str = recon.frame_id
        self.stats = PatchStats()
        self.signature = signature  # of the bundle folder when loaded (bundle_signature)
        self.bundle_problem = ""  # why the bundle on disk is not the one in use ("" if it is)
        self.reloads = 0
        self._logged: dict[str, float] = {}  # fault kind → monotonic time last logged
        # The contact being followed in the log: (stamp of its first frame, of its last, its
        # peak force [N]); None between contacts.
        self._contact: tuple[float, float, float] | None = None
        self._last_frame = -math.inf  # monotonic time of the last frame taken [s]
        p = self.name

        def publisher(msg_type: Any, topic: str, qos: QoSProfile) -> Any:
            # Without rclpy's default QoS-event handlers: two per publisher, each one more
            # entity in every wait of the executor (24 patches × 8 outputs made the executor
            # a fifth of the node's time). A subscriber whose QoS does not match still warns,
            # on its side (ros2 topic echo, rviz2).
            return node.create_publisher(msg_type, topic, qos, event_callbacks=QUIET_EVENTS)

        self.pub_contact = publisher(ContactState, f"{p}/contact", OUTPUT_QOS)
        self.pub_traction = publisher(Image, f"{p}/traction", OUTPUT_QOS)
        self.pub_deflection = publisher(Image, f"{p}/deflection", OUTPUT_QOS)
        self.pub_geometry = {
            g: publisher(GridGeometry, f"{p}/{g}_geometry", STATIC_QOS)
            for g in ("traction", "deflection")
        }
        self.pub_markers = publisher(MarkerArray, f"{p}/taxel_markers", OUTPUT_QOS)
        self.pub_cloud = publisher(PointCloud2, f"{p}/pressure_cloud", OUTPUT_QOS)
        self.pub_contact_markers = publisher(MarkerArray, f"{p}/contact_markers", OUTPUT_QOS)
        # Depth 1 by default: a reconstruction that falls behind drops old frames instead of
        # queueing them, so what it publishes is always the newest reading.
        input_qos = QoSProfile(depth=node.queue_depth, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.sub = node.create_subscription(TaxelArray, f"{p}/taxels", self.on_taxels, input_qos)
        self._subscribed: dict[Any, int] = {}
        self._subscribed_at = -math.inf
        self.use(recon)

    def subscribed(self, pub: Any) -> bool:
        """Whether ``pub`` has a subscriber, counted at most every SUBSCRIBERS_RECOUNT_S. Why:
        each count is an rmw query (7 a frame cost 2 % of the node's time at 24 patches); a
        new subscriber gets its first message that much later."""
        now = time.monotonic()
        if now - self._subscribed_at > SUBSCRIBERS_RECOUNT_S:
            self._subscribed_at = now
            self._subscribed = {
                o: o.get_subscription_count()
                for o in (
                    self.pub_traction,
                    self.pub_deflection,
                    self.pub_markers,
                    self.pub_cloud,
                    self.pub_contact_markers,
                )
            }
        return self._subscribed[pub] > 0

    def use(self, recon: Reconstructor) -> None:
        """Serve with ``recon`` from now on (at start, and when the bundle was replaced)."""
        self.recon = recon
        # Each taxel's noise, learnt from frames without contact; it sets the detection
        # threshold (tactile_contact.inverse.detection). Floor: the bare rounding of one count.
        self.noise = NoiseTracker(recon.default_noise / np.sqrt(2.0), start=recon.default_noise)
        self._ids = np.asarray(recon.taxel_ids, dtype=np.int64)
        self._perm_key: tuple[int, ...] | None = None
        self._perm: np.ndarray | None = None
        header = Header(frame_id=self.frame_id)
        header.stamp = self.node.get_clock().now().to_msg()
        for kind, grid in (
            ("traction", recon.traction_grid),
            ("deflection", recon.deflection_grid),
        ):
            self.pub_geometry[kind].publish(convert.grid_geometry(grid, kind, self.name, header))

    def _permutation(self, ids: np.ndarray) -> np.ndarray:
        """Index into the message arrays for each bundle taxel (cached per id order)."""
        key = tuple(ids.tolist())
        if key != self._perm_key:
            where = {int(t): i for i, t in enumerate(ids)}
            missing = [int(t) for t in self._ids if int(t) not in where]
            if missing:
                raise ValueError(
                    f"taxel ids {[hex(t) for t in missing[:5]]} of bundle {self.bundle} "
                    f"missing from the message ({len(missing)} in all)"
                )
            self._perm = np.array([where[int(t)] for t in self._ids], dtype=np.intp)
            self._perm_key = key
        assert self._perm is not None
        return self._perm

    def on_taxels(self, msg: TaxelArray) -> None:
        """One frame: map, solve what is wanted, publish. Never raises into the executor:
        an exception would end the executor's spin and with it every other patch."""
        try:
            self._on_taxels(msg)
        except Exception as exc:
            self.stats.internal_errors += 1
            self._fault("internal error", f"{type(exc).__name__}: {exc}; frame dropped")

    def _fault(self, kind: str, text: str, warn: bool = False) -> None:
        """Record a fault for /diagnostics and log it (once per 5 s per patch and kind)."""
        self.stats.last_error = f"{kind}: {text}"
        now = time.monotonic()
        if now - self._logged.get(kind, -math.inf) < LOG_THROTTLE_S:
            return
        self._logged[kind] = now
        # (rclpy keys its loggers by call site, each with one severity: two call sites)
        if warn:
            self.node.get_logger().warning(f"patch {self.name}: {kind}: {text}")
        else:
            self.node.get_logger().error(f"patch {self.name}: {kind}: {text}")

    def _on_taxels(self, msg: TaxelArray) -> None:
        stats = self.stats
        stats.frames += 1
        self._last_frame = time.monotonic()
        t0 = time.perf_counter()
        if msg.patch and msg.patch != self.name:
            stats.foreign_frames += 1
            self._fault(
                "frame of another patch",
                f"TaxelArray of patch {msg.patch!r} on {self.sub.topic_name}; ignored",
            )
            return
        try:
            n = len(msg.taxel_ids)
            if not (len(msg.delta_c) == len(msg.status) == n):
                raise ValueError(
                    f"array lengths differ: taxel_ids {n}, delta_c {len(msg.delta_c)}, "
                    f"status {len(msg.status)}"
                )
            perm = self._permutation(np.asarray(msg.taxel_ids, dtype=np.int64))
            delta_c = np.asarray(msg.delta_c, dtype=np.float64)[perm]
            status = np.asarray(msg.status, dtype=np.uint8)[perm]
        except ValueError as exc:
            stats.bad_frames += 1
            self._fault("bad TaxelArray", str(exc))
            return
        finite = np.isfinite(delta_c)
        if not finite.all():
            # NaN or inf cannot come from the driver: left out of the solve, said, counted.
            bad = int(np.count_nonzero(~finite))
            stats.nonfinite_frames += 1
            stats.nonfinite_readings += bad
            self._fault("non-finite ΔC", f"{bad} taxel(s) NaN or inf; left out", warn=True)
        valid = ((status & _UNUSABLE) == 0) & finite
        want_deflection = self.subscribed(self.pub_deflection)
        want_traction = self.subscribed(self.pub_traction) or self.subscribed(self.pub_cloud)
        t1 = time.perf_counter()
        result = self.recon.solve(
            np.where(valid, delta_c, 0.0),
            valid=valid,
            want_traction=want_traction,
            want_deflection=want_deflection,
            noise=self.noise.sigma,
        )
        if not result.in_contact:
            self.noise.update(
                self.recon.compression(np.where(valid, delta_c, 0.0)), valid, result.in_contact
            )
        t2 = time.perf_counter()
        out_of_range = int(valid.sum()) - result.taxels_used
        if out_of_range:
            # Readings no 8-bit value gives: the driver and the bundle disagree on the
            # count→farad gain or shift. Said, counted, and the other taxels still solved.
            stats.out_of_range += out_of_range
            self._fault(
                "out of range",
                f"{out_of_range} taxel(s) read beyond the converter's full scale "
                f"(|ΔC| > {self.recon.full_scale:.3g} F) or below −C0; left out",
                warn=True,
            )
        stats.time("map", t1 - t0)
        stats.time("solve", t2 - t1)
        if not result.in_contact:
            stats.skipped_idle += 1
        else:
            stats.solved += 1
            stats.constrained += int(result.solver == "nnls")
        self._follow_contact(seconds_from_stamp(msg.header.stamp), result)
        if not want_deflection:
            stats.skipped_deflection += 1
        self._publish(msg, result, delta_c, valid, t0)
        stats.time("publish", time.perf_counter() - t2)

    def _follow_contact(self, stamp: float, result: Any) -> None:
        """Count contacts and log one line when each starts and one when it ends."""
        force = float(result.total_force) if result.in_contact else 0.0
        if not math.isfinite(force):
            return  # (refused by check_result, said there)
        c = self._contact
        if result.in_contact:
            self.stats.contact_frames += 1
            self.stats.peak_force = max(self.stats.peak_force, force)
            if c is None:
                self.stats.contacts += 1
                x, y = (float(v) * 1e3 for v in result.cop)
                self.node.get_logger().info(
                    f"patch {self.name}: contact: {force:.2f} N at ({x:.1f}, {y:.1f}) mm"
                )
                self._contact = (stamp, stamp, force)
            else:
                self._contact = (c[0], stamp, max(c[2], force))
        elif c is not None and stamp - c[1] >= CONTACT_END_S:
            self.end_contact()

    def end_contact(self) -> None:
        """Log the end of the contact being followed (if any)."""
        c, self._contact = self._contact, None
        if c is not None:
            self.node.get_logger().info(
                f"patch {self.name}: contact ended: peak {c[2]:.2f} N, {c[1] - c[0]:.2f} s"
            )

    def summary(self) -> str:
        """One line: what this patch took, found and dropped since start."""
        s = self.stats
        dropped = s.bad_frames + s.foreign_frames + s.unpublishable + s.internal_errors
        text = (
            f"{self.name}: {s.frames} frames, {s.contacts} contact(s) in {s.contact_frames} "
            f"frames, peak force {s.peak_force:.2f} N"
        )
        return text + (f", {dropped} frame(s) dropped ({s.last_error})" if dropped else "")

    def _publish(
        self, msg: TaxelArray, result: Any, delta_c: np.ndarray, valid: np.ndarray, t0: float
    ) -> None:
        stats = self.stats
        header = Header(stamp=msg.header.stamp, frame_id=self.frame_id)
        try:
            check_result(result)
            if result.traction is not None and self.subscribed(self.pub_traction):
                self.pub_traction.publish(convert.grid_image("traction", result.traction, header))
            else:
                stats.skipped_images += 1
            if result.deflection is not None:
                self.pub_deflection.publish(
                    convert.grid_image("deflection", result.deflection, header)
                )
            self._publish_visualization(header, result, delta_c, valid)
            now = self.node.get_clock().now()
            latency = now.nanoseconds * 1e-9 - seconds_from_stamp(msg.header.stamp)
            stats.latency_s.append(latency)
            self.pub_contact.publish(
                convert.contact_state(
                    result,
                    self.name,
                    header,
                    solver=str(result.solver),
                    solver_success=bool(result.success),
                    solver_iterations=int(result.iterations),
                    residual_norm=_finite(float(result.residual_norm)),
                    solve_time=float(result.solve_time),
                    latency=float(latency),
                    taxels_used=int(result.taxels_used),
                    taxels_active=int(result.taxels_active),
                )
            )
        except convert.NonFiniteError as exc:
            stats.unpublishable += 1
            self._fault("not published", str(exc))

    def _publish_visualization(
        self, header: Header, result: Any, delta_c: np.ndarray, valid: np.ndarray
    ) -> None:
        every = self.node.visualization_every
        outputs = (self.pub_markers, self.pub_cloud, self.pub_contact_markers)
        if not any(self.subscribed(o) for o in outputs) or self.stats.frames % every:
            self.stats.skipped_visualization += 1
            return
        if self.subscribed(self.pub_markers):
            self.pub_markers.publish(
                convert.taxel_markers(
                    self.recon.taxel_xy,
                    delta_c,
                    valid,
                    header,
                    self.name,
                    radius=float(self.recon.params.get("taxel_radius", 2e-3)),
                    full_scale=self.node.taxel_full_scale,
                )
            )
        if result.traction is not None and self.subscribed(self.pub_cloud):
            self.pub_cloud.publish(
                convert.pressure_cloud(self.recon.traction_grid, result.traction, header)
            )
        if self.subscribed(self.pub_contact_markers):
            self.pub_contact_markers.publish(
                convert.contact_markers(result.contacts, header, self.name)
            )

    def diagnostics(self) -> Any:
        s = self.stats
        if self._contact is not None and time.monotonic() - self._last_frame > 1.0:
            self.end_contact()  # frames stopped during a contact (a replay, a driver stopped)
        values: dict[str, object] = {
            "bundle": str(self.bundle),
            "frames": s.frames,
            "solved": s.solved,
            "constrained_solves": s.constrained,
            "skipped_idle": s.skipped_idle,
            "skipped_deflection": s.skipped_deflection,
            "skipped_images": s.skipped_images,
            "skipped_visualization": s.skipped_visualization,
            "bad_frames": s.bad_frames,
            "foreign_frames": s.foreign_frames,
            "nonfinite_frames": s.nonfinite_frames,
            "nonfinite_readings": s.nonfinite_readings,
            "out_of_range_readings": s.out_of_range,
            "unpublishable": s.unpublishable,
            "internal_errors": s.internal_errors,
            "contacts": s.contacts,
            "contact_frames": s.contact_frames,
            "peak_force_n": s.peak_force,
            "bundle_reloads": self.reloads,
            "bundle_problem": self.bundle_problem,
            "noise_median_um": float(np.median(self.noise.sigma) * 1e6),
            "noise_max_um": float(np.max(self.noise.sigma) * 1e6),
            "noise_frames": self.noise.frames_used,
            "false_alarm_bound_per_hour": self.recon.detector.per_hour
            if self.recon.detector is not None
            else 0.0,
        }
        # One percentile call per series (median and p99 together): at 24 patches the
        # separate np.median/np.percentile calls cost 3 % of the node's time.
        series = dict(s.stage_s)
        if s.latency_s:
            series["latency"] = s.latency_s
        for stage, times in series.items():
            if times:
                median, p99 = np.percentile(np.fromiter(times, float, len(times)), (50, 99))
                values[f"{stage}_median_ms"] = float(median * 1e3)
                values[f"{stage}_p99_ms"] = float(p99 * 1e3)
        level, message = OK, "ok"
        faults = (
            s.bad_frames,
            s.foreign_frames,
            s.nonfinite_frames,
            s.unpublishable,
            s.out_of_range,
            s.internal_errors,
        )
        if any(faults):
            level, message = WARN, s.last_error
        if s.frames == 0:
            level, message = WARN, "no taxel frames received yet"
        if self.bundle_problem:
            level = ERROR if "refused" in self.bundle_problem else max(level, WARN)
            message = f"{self.bundle_problem}; {message}"
        return diagnostic_status(
            f"contact_reconstruction: {self.name}", level, message, values, self.name
        )


def load_reconstructor(path: Path, follow: bool = True) -> Reconstructor:
    """A Reconstructor of the bundle at ``path``, its arrays read into memory, warmed up;
    following contacts from frame to frame unless ``follow`` is False.

    Not memory-mapped: a bundle file overwritten in place while mapped would crash the process
    (SIGBUS) at the next frame; read, the node keeps what it checked and loaded. Warmed up
    (:meth:`Reconstructor.warm_up`): the first contact must not wait for kernels to compile,
    and a bundle that cannot solve is refused here, before it serves.
    """
    recon = Reconstructor(load_bundle(path, mmap=False), follow=follow)
    recon.warm_up()
    return recon


def bundle_signature(path: Path) -> tuple:
    """What changes when a bundle folder is deleted, replaced or rewritten (() if missing)."""
    try:
        folder = path.stat()
        files = sorted(path.iterdir())
        return (folder.st_ino, *((f.name, *_stat(f)) for f in files))
    except OSError:
        return ()


def _stat(f: Path) -> tuple[int, int, int]:
    st = f.stat()
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
            "patches to serve (empty: every bundle in bundles_dir); lets processes share a skin",
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
        period = declare_parameter(
            self,
            "diagnostics_period",
            1.0,
            "period of /diagnostics",
            unit="s",
            float_range=(0.05, 60.0),
        )
        log_parameters(self, PARAMETERS)
        self.load_errors: dict[str, str] = {}
        self.pipelines: dict[str, PatchPipeline] = {}
        self._refused: dict[Path, tuple] = {}  # bundle → signature of the refused version
        self._paths = self._bundle_paths(requested)
        for name, path in self._paths.items():
            sig = bundle_signature(path)
            try:
                recon = load_reconstructor(path, self.follow_contacts)
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
        # One period's diagnostics work in steps, one patch a step: done at once for 24
        # patches it took ≈ 10 ms, which every frame arriving meanwhile waited for (its p99
        # latency). The array still goes out once a period, with every patch.
        self._diag_todo: list[str] = []
        self._diag_done: dict[str, Any] = {}
        self.create_timer(period / (len(self.pipelines) + 1), self.diagnostics_step)

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
        log = self.get_logger()
        for pipe in list(self.pipelines.values()):
            sig = bundle_signature(pipe.bundle)
            if sig == pipe.signature or sig == self._refused.get(pipe.bundle):
                continue
            if not sig:
                if not pipe.bundle_problem.startswith("bundle deleted"):
                    pipe.bundle_problem = (
                        f"bundle deleted on disk ({pipe.bundle}); serving the copy loaded before"
                    )
                    log.warning(f"patch {pipe.name}: {pipe.bundle_problem}")
                continue
            try:
                recon = load_reconstructor(pipe.bundle, self.follow_contacts)
                if recon.patch != pipe.name:
                    raise ValueError(f"it is now a bundle of patch {recon.patch!r}")
            except Exception as exc:
                self._refused[pipe.bundle] = sig
                pipe.bundle_problem = (
                    f"bundle replaced on disk by one refused ({exc}); serving the copy loaded "
                    "before"
                )
                log.error(f"patch {pipe.name}: {pipe.bundle_problem}")
                continue
            pipe.use(recon)
            pipe.signature, pipe.bundle_problem = sig, ""
            pipe.reloads += 1
            self._refused.pop(pipe.bundle, None)
            log.info(f"patch {pipe.name}: bundle {pipe.bundle} replaced on disk; reloaded")
        for name, path in self._paths.items():
            if name not in self.load_errors:
                continue
            sig = bundle_signature(path)
            if not sig or sig == self._refused.get(path):
                continue
            try:
                recon = load_reconstructor(path, self.follow_contacts)
            except Exception as exc:
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
        """One step of the diagnostics period: first the bundles watched, then one patch's
        status taken per step; after the last, the array published."""
        if not self._diag_todo:
            try:
                self.watch_bundles()
            except Exception as exc:  # never into the executor
                self.get_logger().error(
                    f"watching bundles: {type(exc).__name__}: {exc}", throttle_duration_sec=5.0
                )
            self._diag_todo = list(reversed(self.pipelines))
            if self._diag_todo:
                return
        else:
            name = self._diag_todo.pop()
            if name in self.pipelines:
                self._diag_done[name] = self.pipelines[name].diagnostics()
            if self._diag_todo:
                return
        self._publish_diagnostics(
            [self._diag_done[n] for n in self.pipelines if n in self._diag_done]
        )

    def _publish_diagnostics(self, statuses: list[Any]) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = statuses
        for name, error in self.load_errors.items():
            msg.status.append(
                diagnostic_status(f"contact_reconstruction: {name}", ERROR, error, {}, name)
            )
        self.pub_diag.publish(msg)


def main(args: list[str] | None = None) -> None:
    """Run ``contact_reconstruction`` until Ctrl-C; exit 1 with a message if it cannot start."""
    run_node("contact_reconstruction", ContactReconstructionNode, args, events=True)


if __name__ == "__main__":
    main()
