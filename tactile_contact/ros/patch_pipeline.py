"""One patch of ``contact_reconstruction``: its publishers, its Reconstructor, its frames.

:class:`PatchPipeline` maps a frame's taxels to the bundle's order, solves what is wanted and
publishes the per-patch outputs (``<patch>/contact``, images, markers, cloud: each computed
only while something subscribes, ``<patch>/contact`` on every frame when the patch's frames
come per patch); it counts and reports every fault of its patch (:meth:`diagnostics`). The
node (tactile_contact.ros.contact_reconstruction) holds one per patch it serves and feeds it
frames from ``<patch>/taxels`` or from batches (tactile_contact.ros.contact_batches).
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header
from threadpoolctl import threadpool_limits
from visualization_msgs.msg import MarkerArray

from tactile_contact.inverse.detection import NoiseTracker
from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.surface import Surface
from tactile_contact.msg import ContactState, GridGeometry, TaxelArray
from tactile_contact.ros import convert
from tactile_contact.ros.cdr import ContactRows
from tactile_contact.ros.common import (
    ERROR,
    OK,
    STATIC_QOS,
    WARN,
    diagnostic_status,
)
from tactile_contact.ros.contact_batches import add_row

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

#: A frame's latency [s] (this node's clock minus the frame's stamp) outside this range is
#: no age but a clock's problem, and is kept out of the latency figures: a stamp ahead of
#: this node's clock (two machines' clocks apart, a bogus stamp: warned) or a minute and
#: more behind it (a bag replayed without use_sim_time: counted, logged once). Why: one
#: frame stamped in 1969 made latency_p99_ms 1.8e12 on /diagnostics.
LATENCY_RANGE_S = (-1.0, 60.0)
#: A patch that had frames and then none for this long [s] is warned about, or for
#: FRAMES_STOPPED_GAPS times the longest recent gap between its frames if longer: the driver
#: sends an untouched patch every idle_every periods only (up to 1000 × 255 ms). The
#: longest gap forgets by GAP_MEMORY a frame (a gap of 5 s weighs 0.07 s 300 frames later).
FRAMES_STOPPED_S = 3.0
FRAMES_STOPPED_GAPS = 3.0
GAP_MEMORY = 0.99
OUTPUT_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
QUIET_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)

# A taxel with any of these flags is left out of the solve.
_UNUSABLE = (
    TaxelArray.STATUS_DISABLED
    | TaxelArray.STATUS_STUCK
    | TaxelArray.STATUS_DEAD
    | TaxelArray.STATUS_SATURATED
)


#: PatchPipeline._quiet_frame's answer when the frame needs the full path.
_FULL_PATH = object()
#: ΔC arrays the quiet path takes (a message's float32; float64 from a caller's own arrays).
_QUIET_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))


class Window:
    """The last ``size`` values of a series (seconds), kept in a ring, and their percentiles.

    Why not a deque: its percentiles went through ``np.fromiter`` and ``np.percentile``,
    ≈ 95 µs a series (four a patch, once a /diagnostics period: ≈ 0.4 ms a patch)."""

    def __init__(self, size: int = 1000) -> None:
        self._values = np.empty(size)
        self._size = size
        self._count = 0

    def append(self, x: float) -> None:
        self._values[self._count % self._size] = x
        self._count += 1

    def __len__(self) -> int:
        return min(self._count, len(self._values))

    def percentiles(self, q: tuple[float, ...]) -> list[float]:
        """The ``q`` percentiles [0–100] of the values kept (numpy's linear method: the
        same numbers as ``np.percentile``), from one partial sort."""
        a = self._values[: len(self)].copy()
        at = [p / 100.0 * (len(a) - 1) for p in q]
        ks = sorted({k for x in at for k in (math.floor(x), math.ceil(x))})
        a.partition(ks)
        return [
            float(a[math.floor(x)] + (a[math.ceil(x)] - a[math.floor(x)]) * (x % 1.0)) for x in at
        ]


@dataclass
class PatchStats:
    """Counters and timings of one patch since start (timings keep the last 1000 frames)."""

    frames: int = 0
    quiet: int = 0  # frames taken by the quiet path (PatchPipeline._quiet_frame)
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
    stamps_ahead: int = 0  # frames stamped ahead of this node's clock (LATENCY_RANGE_S)
    stamps_old: int = 0  # frames stamped a minute and more before it
    contacts: int = 0  # contacts started (a press, from its first frame to CONTACT_END_S after)
    contact_frames: int = 0
    peak_force: float = 0.0  # largest total force [N] of any frame
    last_error: str = ""
    latency_s: Window = field(default_factory=Window)
    stage_s: dict = field(default_factory=dict)

    def time(self, stage: str, seconds: float) -> None:
        series = self.stage_s.get(stage)
        if series is None:
            series = self.stage_s[stage] = Window()
        series.append(seconds)

    def time_frame(self, map_s: float, solve_s: float, publish_s: float) -> None:
        """:meth:`time` of a frame's three stages, map, solve and publish [s], at once (a
        batch's held frame: three calls were ≈ 1.5 µs of its ≈ 60)."""
        s = self.stage_s
        m, v, p = s.get("map"), s.get("solve"), s.get("publish")
        if m is None or v is None or p is None:
            self.time("map", map_s)
            self.time("solve", solve_s)
            self.time("publish", publish_s)
            return
        m.append(map_s)
        v.append(solve_s)
        p.append(publish_s)


def stamp_from_ns(ns: int) -> Time:
    """``builtin_interfaces/Time`` of ``ns`` [ns since the epoch]."""
    sec, nsec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nsec)


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


def file_signature(path: Path | None) -> tuple:
    """(inode, mtime [ns], size) of the file at ``path``, () if there is none."""
    if path is None:
        return ()
    try:
        st = os.stat(path)
    except OSError:
        return ()
    return st.st_ino, st.st_mtime_ns, st.st_size


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
        self._gap = 0.0  # the longest recent gap between frames [s] (GAP_MEMORY)
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
        # queueing them, so what it publishes is always the newest reading. (With batches
        # there is no per-patch subscription: the driver publishes <patch>/taxels only while
        # something subscribes to it.)
        self.sub = None
        if node.input == "patches":
            qos = QoSProfile(depth=node.queue_depth, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.sub = node.create_subscription(TaxelArray, f"{p}/taxels", self.on_taxels, qos)
        self._subscribed: dict[Any, int] = {}
        self._subscribed_at = -math.inf
        #: Take a batch's idle and held frames by the quiet path (_quiet_frame); False: every
        #: frame by the full path (the same results: the tests compare the two).
        self.quiet = True
        self.use(recon)

    def subscribed(self, pub: Any) -> bool:
        """Whether ``pub`` has a subscriber, counted at most every SUBSCRIBERS_RECOUNT_S. Why:
        each count is an rmw query (7 a frame cost 2 % of the node's time at 24 patches); a
        new subscriber gets its first message that much later."""
        self._recount()
        return self._subscribed[pub] > 0

    def _recount(self) -> None:
        """Count the outputs' subscribers again if the last count is SUBSCRIBERS_RECOUNT_S old."""
        now = time.monotonic()
        if now - self._subscribed_at > SUBSCRIBERS_RECOUNT_S:
            self._subscribed_at = now
            self._subscribed = {
                o: o.get_subscription_count()
                for o in (
                    self.pub_contact,
                    self.pub_traction,
                    self.pub_deflection,
                    self.pub_markers,
                    self.pub_cloud,
                    self.pub_contact_markers,
                )
            }

    def use(self, recon: Reconstructor) -> None:
        """Serve with ``recon`` from now on (at start, and when the bundle was replaced)."""
        self.recon = recon
        if recon.fusion is not None:
            # Its scheduled re-solves wait until the frame's summaries are out (catch_up).
            recon.fusion.defer = True
        # Where the patch lies on the robot (an imported skin): its rviz2 outputs go there.
        manifest = getattr(getattr(recon, "bundle", None), "manifest", {})
        self.surface = Surface.from_dict(manifest.get("layout", {}).get("surface"))
        # The layout file the bundle was built from, and its state now: an edit of it that
        # makes the bundle stale is noticed while the node runs (the node's watch_bundle).
        source = manifest.get("layout_source")
        self.source = Path(source) if isinstance(source, str) else None
        self.source_signature = file_signature(self.source)
        # Each taxel's noise, learnt from frames without contact; it sets the detection
        # threshold (tactile_contact.inverse.detection). Floor: the bare rounding of one count.
        self.noise = NoiseTracker(recon.default_noise / np.sqrt(2.0), start=recon.default_noise)
        self._ids = np.asarray(recon.taxel_ids, dtype=np.int64)
        self._perm_key: bytes | None = None
        self._perm: np.ndarray | None = None
        # The quiet path's (frame): the sensor model's constants, as its compiled conversion
        # uses them (ReadingModel.from_delta_c), and the noise array last handed out.
        r = recon.readings
        self._convert = np.array([r.thickness, r._eps_area, r._rest_c, r.full_scale])
        self._noise_seen: tuple[Any, Any] = (None, None)
        self._checked: Any = None  # the result check_result passed last
        header = Header(frame_id=self.frame_id)
        header.stamp = self.node.get_clock().now().to_msg()
        for kind, grid in (
            ("traction", recon.traction_grid),
            ("deflection", recon.deflection_grid),
        ):
            self.pub_geometry[kind].publish(convert.grid_geometry(grid, kind, self.name, header))

    def _permutation(self, ids: np.ndarray) -> np.ndarray:
        """Index into the message arrays for each bundle taxel (cached per id order, keyed by
        the ids' bytes: a tuple of them cost more than the rest of the mapping)."""
        key = ids.tobytes()
        if key != self._perm_key:
            where: dict[int, int] = {}
            twice: list[int] = []
            for i, t in enumerate(ids.tolist()):
                if where.setdefault(t, i) != i:
                    twice.append(t)
            if twice:
                # (which of the two readings is the taxel's cannot be told: the later one
                # silently won, a press read as zeros by its copy was lost)
                raise ValueError(
                    f"taxel ids {[hex(t) for t in twice[:5]]} appear more than once in the "
                    f"message ({len(twice)} in all)"
                )
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
            if not self.node.context.ok():
                return  # (a Ctrl-C shut the context down under this frame)
            self.internal_error(exc)

    def internal_error(self, exc: Exception) -> None:
        """A frame of this patch that raised ``exc`` (a bug, or a reading the code did not
        foresee): counted (``internal_errors`` in /diagnostics), said (once per 5 s) and the
        frame dropped. The same report whichever path took the frame (a TaxelArray, a
        batch's loop or its compiled call); the other patches go on."""
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
        if msg.patch and msg.patch != self.name:
            self.stats.frames += 1
            self.stats.foreign_frames += 1
            self._fault(
                "frame of another patch",
                f"TaxelArray of patch {msg.patch!r} on {self.sub.topic_name}; ignored",
            )
            return
        node = self.node
        if self.name not in node.link.serving:
            return  # left to another worker (or still listening for one)
        started = time.perf_counter()
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        result = self.frame(stamp, msg.taxel_ids, msg.delta_c, msg.status, contact=True)
        rows = ContactRows()
        add_row(rows, self, stamp, result)
        node.batches.publish(rows)
        node.batches.catch_up(started)

    def catch_up(self) -> None:
        """Run the re-solve this patch's fusion deferred (after the frame was published);
        timed as the stage ``catch_up``. Never raises into the executor."""
        fusion = self.recon.fusion
        if fusion is None:
            return
        t = time.perf_counter()
        try:
            ran = fusion.catch_up()
        except Exception as exc:
            if not self.node.context.ok():
                return
            self.stats.internal_errors += 1
            self._fault("internal error", f"{type(exc).__name__}: {exc}; deferred re-solve")
            return
        if ran:
            self.stats.time("catch_up", time.perf_counter() - t)

    def frame(self, stamp_ns: int, ids: Any, delta_c: Any, status: Any, contact: bool) -> Any:
        """One frame of this patch: map, solve what is wanted, publish the per-patch outputs
        (``<patch>/contact`` always with ``contact``, else while subscribed). Returns the
        result, or None for a frame refused (bad arrays) or that could not be published."""
        if (
            not contact
            and self.quiet
            and self.recon.fusion is not None
            and (self.recon.fusion.holding)
        ):
            quiet = self._quiet_frame(stamp_ns, ids, delta_c, status)
            if quiet is not _FULL_PATH:
                return quiet
        stats = self.stats
        stats.frames += 1
        self._took_frame(time.monotonic())
        t0 = time.perf_counter()
        try:
            n = len(ids)
            if not (len(delta_c) == len(status) == n):
                raise ValueError(
                    f"array lengths differ: taxel_ids {n}, delta_c {len(delta_c)}, "
                    f"status {len(status)}"
                )
            perm = self._permutation(np.asarray(ids, dtype=np.uint16))
            delta_c = np.asarray(delta_c, dtype=np.float64)[perm]
            status = np.asarray(status, dtype=np.uint8)[perm]
        except ValueError as exc:
            stats.bad_frames += 1
            self._fault("bad TaxelArray", str(exc))
            return None
        finite = np.isfinite(delta_c)
        if not finite.all():
            # NaN or inf cannot come from the driver: left out of the solve, said, counted.
            bad = int(np.count_nonzero(~finite))
            stats.nonfinite_frames += 1
            stats.nonfinite_readings += bad
            self._fault("non-finite ΔC", f"{bad} taxel(s) NaN or inf; left out", warn=True)
        valid = ((status & _UNUSABLE) == 0) & finite
        self._recount()  # (once a frame: the outputs' subscriber counts, refreshed at 5 Hz)
        sub = self._subscribed
        want_deflection = sub[self.pub_deflection] > 0
        want_traction = sub[self.pub_traction] > 0 or sub[self.pub_cloud] > 0
        t1 = time.perf_counter()
        readings = np.where(valid, delta_c, 0.0)
        if self.recon.detector is not None:
            # The detector keeps its filters while the learnt noise moves within the tracker's
            # own spread of a uniform multiple of theirs (a rebuild: 0.5–28 ms a patch).
            self.recon.detector.tolerance = self.noise.tolerance
        result = self.recon.solve(
            readings,
            valid=valid,
            want_traction=want_traction,
            want_deflection=want_deflection,
            noise=self.noise.sigma,
        )
        fusion = self.recon.fusion
        if not result.in_contact:
            # δ of the taxels used, as the solve converted them (δ as Reconstructor.compression
            # gives it, bit for bit): the frame the fusion was given, else converted again.
            seen = fusion.context if fusion is not None else None
            if isinstance(seen, Frame):
                self.noise.update(seen.delta, seen.ok, False)
            else:
                self.noise.update(*self.recon.readings.from_delta_c(readings, valid), False)
        if fusion is not None and fusion.pending:
            self.node.batches.defer(self)  # (run after the frame's summary is published)
        t2 = time.perf_counter()
        used = int(np.count_nonzero(valid))
        return self._finish(
            stamp_ns, result, used, (t0, t1, t2), delta_c, valid, contact, want_deflection
        )

    def _quiet_frame(self, stamp_ns: int, ids: Any, delta_c: Any, status: Any) -> Any:
        """:meth:`frame` of a batch's patch while its fusion holds a window and nothing per
        patch is subscribed: the mapping, the conversion and the fusion's held step (with
        its idle scan) in one compiled call (FrameFusion.step_message), the rest as the full
        path does it. The same result, counters and noise learnt as the full path (test/
        test_patch_quiet.py); _FULL_PATH where that path is needed (new taxel order, arrays
        not a message's, a non-finite reading, a subscriber)."""
        if not (
            isinstance(ids, np.ndarray)
            and isinstance(delta_c, np.ndarray)
            and isinstance(status, np.ndarray)
            and status.dtype == np.uint8
            and delta_c.dtype in _QUIET_FLOATS
            and len(delta_c) == len(status) == len(ids)
        ):
            return _FULL_PATH
        t0 = time.perf_counter()
        if ids.dtype != np.uint16 or ids.tobytes() != self._perm_key:
            return _FULL_PATH
        self._recount()
        if any(self._subscribed.values()):
            return _FULL_PATH
        noise = self.noise
        seen, sigma = self._noise_seen
        if noise.sigma is not seen:  # (the tracker hands out a new array when it learns)
            sigma = self.recon.readings.noise(noise.sigma)
            self._noise_seen = (noise.sigma, sigma)
        fusion = self.recon.fusion
        detector = self.recon.detector
        if detector is not None:
            detector.tolerance = noise.tolerance  # (as the full path)
        t1 = time.perf_counter()
        out = fusion.step_message(delta_c, status, self._perm, _UNUSABLE, self._convert, sigma)
        if out is None:
            return _FULL_PATH
        return self._quiet_rest(stamp_ns, *out, t0, t1)

    def batch_ready(self, ids: np.ndarray) -> int:
        """Whether this frame of a batch (taxel ids ``ids``, the message's uint16) may go by
        the batch's compiled call (tactile_contact.ros.quiet_batch): -1 if not (it takes
        :meth:`frame`), else FrameFusion.batch_ready's answer (whether the idle scan runs).
        The checks :meth:`_quiet_frame` makes, and those that let the frame skip the rest
        of it (:meth:`batch_held`)."""
        fusion = self.recon.fusion
        if not self.quiet or fusion is None or ids.tobytes() != self._perm_key:
            return -1
        self._recount()
        if any(self._subscribed.values()):
            return -1
        noise = self.noise
        seen, sigma = self._noise_seen
        result = fusion.result
        if noise.sigma is not seen or result is not self._checked or result is None:
            return -1
        if result.deflection is not None:
            return -1
        detector = self.recon.detector
        if detector is not None:
            detector.tolerance = noise.tolerance  # (as the full path)
        return fusion.batch_ready(sigma)

    def batch_held(self, stamp_ns: int, learnt: bool, now: float, times: tuple) -> Any:
        """:meth:`frame`'s bookkeeping for a batch's frame the compiled call found unchanged
        and that nothing follows (FrameFusion.batch_held): the counters, the noise tracker's
        count (``learnt``: its compiled step learnt from the frame), the contact log, the
        held result returned. ``now``: monotonic time; ``times``: this frame's share of the
        batch's map, solve and publish [s]. What :meth:`_quiet_rest` and :meth:`_finish`
        do for such a frame, nothing per patch published (none subscribed)."""
        fusion = self.recon.fusion
        result = fusion.result
        idle = not result.in_contact
        fusion.batch_held(idle)
        stats = self.stats
        stats.frames += 1
        stats.quiet += 1
        self._took_frame(now)
        if learnt:
            self.noise.learnt()
        stats.time_frame(*times)
        if idle:
            stats.skipped_idle += 1
        else:
            stats.solved += 1
            stats.constrained += int(result.solver == "nnls")
        if idle and self._contact is None:
            pass  # (_follow_contact has nothing to do)
        else:
            self._follow_contact(stamp_ns * 1e-9, result)
        stats.skipped_deflection += 1
        stats.skipped_images += 1
        stats.skipped_visualization += 1
        return result

    def batch_rest(
        self, stamp_ns: int, code: int, scanned: int, valid: int, delta: Any, ok: Any, t0: float
    ) -> Any:
        """:meth:`frame`'s rest for a batch's frame the compiled call tested (held step
        ``code``, idle scan ``scanned``, ``valid`` taxels the status allows; ``delta``, ``ok``:
        the frame as converted) where more follows: a change, a look, a count that differs."""
        fusion = self.recon.fusion
        t1 = time.perf_counter()
        result, seen_frame = fusion.after_batch(code, scanned, delta, ok, self._noise_seen[1])
        return self._quiet_rest(stamp_ns, result, seen_frame, valid, t0, t1)

    def _quiet_rest(
        self, stamp_ns: int, result: Any, seen_frame: Any, used: int, t0: float, t1: float
    ) -> Any:
        """The quiet path after the fusion's step: counters, noise learnt, outputs."""
        fusion = self.recon.fusion
        noise = self.noise
        stats = self.stats
        stats.frames += 1
        stats.quiet += 1
        self._took_frame(time.monotonic())
        if not result.in_contact:
            noise.update(seen_frame.delta, seen_frame.ok, False)
        if fusion.pending:
            self.node.batches.defer(self)
        t2 = time.perf_counter()
        return self._finish(stamp_ns, result, used, (t0, t1, t2), None, None, False, False)

    def _finish(
        self,
        stamp_ns: int,
        result: Any,
        used: int,
        times: tuple[float, float, float],
        delta_c: Any,
        valid: Any,
        contact: bool,
        want_deflection: bool,
    ) -> Any:
        """A frame's counters, contact log and per-patch outputs after its solve (``used``:
        the taxels its status and values allowed; ``times``: perf_counter at its start, after
        the mapping, after the solve)."""
        stats = self.stats
        t0, t1, t2 = times
        out_of_range = used - result.taxels_used
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
        self._follow_contact(stamp_ns * 1e-9, result)
        if not want_deflection:
            stats.skipped_deflection += 1
        ok = self._publish(stamp_ns, result, delta_c, valid, contact)
        stats.time("publish", time.perf_counter() - t2)
        return result if ok else None

    def _took_frame(self, now: float) -> None:
        """Note a frame taken at monotonic ``now`` [s] (the gap since the last one)."""
        gap = now - self._last_frame
        self._gap = max(gap, self._gap * GAP_MEMORY) if gap < math.inf else 0.0
        self._last_frame = now

    def latency_ok(self, latency: float) -> bool:
        """Whether a frame's latency [s] is an age (LATENCY_RANGE_S) to count; if not, it is
        counted and said (a stamp ahead: warned; one old: logged once)."""
        low, high = LATENCY_RANGE_S
        if low <= latency <= high:
            return True
        s = self.stats
        node = self.node
        if getattr(node, "_sim_time", False) and node.now_ns() == 0:
            return False  # (sim time before the first /clock: no age to tell)
        if latency < low:
            s.stamps_ahead += 1
            self._fault(
                "stamp ahead",
                f"a frame stamped {-latency:.3g} s ahead of this node's clock: its latency is "
                "not counted (the sender's and this machine's clocks apart? NTP, chrony)",
                warn=True,
            )
        elif math.isfinite(latency):
            s.stamps_old += 1
            if s.stamps_old == 1:
                self.node.get_logger().info(
                    f"patch {self.name}: frames stamped {latency:.3g} s before this node's "
                    "clock (a replay without use_sim_time?): their latency is not counted"
                )
        return False

    def _follow_contact(self, stamp: float, result: Any) -> None:
        """Count contacts and log one line when each starts and one when it ends."""
        force = float(result.total_force) if result.in_contact else 0.0
        if not math.isfinite(force):
            return  # (refused by check_result, said there)
        c = self._contact
        if c is not None and stamp < c[1]:
            # (the stamps went back — a clock step, a replay restarted: that contact ends)
            self.end_contact()
            c = None
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
        self, stamp_ns: int, result: Any, delta_c: np.ndarray, valid: np.ndarray, contact: bool
    ) -> bool:
        """The per-patch outputs (those wanted); False if the result cannot be published."""
        stats = self.stats
        if result is not self._checked:  # (a held result is checked once: results are frozen)
            try:
                check_result(result)
            except convert.NonFiniteError as exc:
                stats.unpublishable += 1
                self._fault("not published", str(exc))
                return False
            self._checked = result
        sub = self._subscribed
        want_images = result.traction is not None and sub[self.pub_traction] > 0
        if not want_images:
            stats.skipped_images += 1
        want_contact = contact or sub[self.pub_contact] > 0
        if not (want_images or want_contact or result.deflection is not None) and (
            self._skip_visualization()
        ):
            stats.skipped_visualization += 1
            return True  # (nothing per patch wanted: not even a Header built)
        header = Header(stamp=stamp_from_ns(stamp_ns), frame_id=self.frame_id)
        try:
            if want_images:
                self.pub_traction.publish(convert.grid_image("traction", result.traction, header))
            if result.deflection is not None:
                self.pub_deflection.publish(
                    convert.grid_image("deflection", result.deflection, header)
                )
            self._publish_visualization(header, result, delta_c, valid)
            if not want_contact:
                return True
            latency = (self.node.now_ns() - stamp_ns) * 1e-9
            if contact and self.latency_ok(latency):
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
            return False
        return True

    def _skip_visualization(self) -> bool:
        """No markers or cloud this frame: nobody subscribes, or not the N-th frame."""
        every = self.node.visualization_every
        outputs = (self.pub_markers, self.pub_cloud, self.pub_contact_markers)
        sub = self._subscribed
        return not any(sub[o] for o in outputs) or bool(self.stats.frames % every)

    def _publish_visualization(
        self, header: Header, result: Any, delta_c: np.ndarray, valid: np.ndarray
    ) -> None:
        if self._skip_visualization():
            self.stats.skipped_visualization += 1
            return
        sub = self._subscribed
        if sub[self.pub_markers]:
            self.pub_markers.publish(
                convert.taxel_markers(
                    self.recon.taxel_xy,
                    delta_c,
                    valid,
                    header,
                    self.name,
                    radius=float(self.recon.params.get("taxel_radius", 2e-3)),
                    full_scale=self.node.taxel_full_scale,
                    surface=self.surface,
                )
            )
        if result.traction is not None and sub[self.pub_cloud]:
            self.pub_cloud.publish(
                convert.pressure_cloud(
                    self.recon.traction_grid, result.traction, header, surface=self.surface
                )
            )
        if sub[self.pub_contact_markers]:
            self.pub_contact_markers.publish(
                convert.contact_markers(result.contacts, header, self.name, self.surface)
            )

    def _fusion_counts(self) -> dict[str, object]:
        """The held scene's frames (fuse_frames): solved on their own (a change), fused (the
        mean of the held frames solved), republished without a solve; and the idle windows
        the clock would have solved that the bank test found nothing in."""
        fusion = self.recon.fusion
        if fusion is None:
            return {}
        c = fusion.counts
        return {
            "frames_solved_alone": c.solved,
            "frames_fused": c.fused,
            "frames_republished": c.held,
            "frames_in_result": fusion.result_frames,
            "idle_windows_screened": c.screened,
            "resolves_deferred": c.deferred,
        }

    def diagnostics(self) -> Any:
        s = self.stats
        if self._contact is not None and time.monotonic() - self._last_frame > 1.0:
            self.end_contact()  # frames stopped during a contact (a replay, a driver stopped)
        values: dict[str, object] = {
            "bundle": str(self.bundle),
            "frames": s.frames,
            "frames_quiet": s.quiet,
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
            "stamps_ahead": s.stamps_ahead,
            "stamps_old": s.stamps_old,
            "contacts": s.contacts,
            "contact_frames": s.contact_frames,
            "peak_force_n": s.peak_force,
            "bundle_reloads": self.reloads,
            "bundle_problem": self.bundle_problem,
            "noise_median_um": float(np.median(self.noise.sigma) * 1e6),
            "noise_max_um": float(np.max(self.noise.sigma) * 1e6),
            "noise_frames": self.noise.frames_used,
            **self._fusion_counts(),
            "false_alarm_bound_per_hour": self.recon.detector.per_hour
            if self.recon.detector is not None
            else 0.0,
        }
        # One partial sort per series (median and p99 together; Window.percentiles).
        series = dict(s.stage_s)
        if len(s.latency_s):
            series["latency"] = s.latency_s
        for stage, times in series.items():
            if len(times):
                median, p99 = times.percentiles((50, 99))
                values[f"{stage}_median_ms"] = median * 1e3
                values[f"{stage}_p99_ms"] = p99 * 1e3
        level, message = OK, "ok"
        faults = (
            s.bad_frames,
            s.foreign_frames,
            s.nonfinite_frames,
            s.unpublishable,
            s.out_of_range,
            s.internal_errors,
            s.stamps_ahead,
        )
        if any(faults):
            level, message = WARN, s.last_error
        if s.frames == 0:
            level, message = WARN, "no taxel frames received yet"
        elif math.isfinite(self._last_frame):  # (frames of another patch only: never taken)
            quiet_for = time.monotonic() - self._last_frame
            if quiet_for > max(FRAMES_STOPPED_S, FRAMES_STOPPED_GAPS * self._gap):
                level = WARN
                message = f"no taxel frame for {quiet_for:.0f} s; {message}"
        if self.bundle_problem:
            level = ERROR if "refused" in self.bundle_problem else max(level, WARN)
            message = f"{self.bundle_problem}; {message}"
        return diagnostic_status(
            f"contact_reconstruction: {self.name}", level, message, values, self.name
        )
