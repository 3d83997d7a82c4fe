"""contact_reconstruction's batched input and output: one message in, one out, many patches.

The middleware costs per message, not per patch (docs/bench/load.md: taking a message,
turning it into Python objects, publishing one). So a worker takes a whole bus's new
readings in one ``TaxelBatch`` (``taxel_batches``, raw bytes read by
:mod:`tactile_contact.ros.cdr`), solves the patches of it that it serves, and publishes their
summaries in one ``ContactArray`` (``contacts``, written as bytes). Per-patch
``<patch>/contact`` and the images, markers and clouds go out only while something subscribes
to them (PatchPipeline).

Batches come on one topic for every bus; a worker that knows its buses (from the layout)
subscribes with a content filter on the batch's ``bus`` so that only theirs reach it
(workers.bus_filter), and one that falls behind keeps the newest :data:`BATCH_DEPTH` batches
(a patch's older frame in the queue is skipped once a newer one of it was solved).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription_content_filter_options import ContentFilterOptions

from tactile_contact.msg import ContactArray, TaxelBatch
from tactile_contact.ros.cdr import CdrError, ContactRows, read_taxel_batch, write_contact_array
from tactile_contact.ros.common import publish_while_up

BATCHES_TOPIC = "taxel_batches"
CONTACTS_TOPIC = "contacts"
#: Batches kept while a solve runs: every bus's newest few (one topic carries all buses).
BATCH_DEPTH = 16
#: After a message's summaries are published, the re-solves the fusion deferred (a held
#: window's, an idle patch's look into its window means: 1–12 ms each on the robot's
#: patches) run until the callback has taken this long [s] (at least one a message; the
#: rest wait for the next message, oldest first). Why: run inside the frame, one patch's
#: re-solve held every patch of its bus and every message queued behind it (docs/bench/
#: tail.md).
CATCH_UP_BUDGET_S = 2.0e-3
#: While a callback has run less than this [s], a batch already waiting in the queue is
#: taken in the same callback and its rows join the same ContactArray (at most
#: COALESCE_MAX batches). Why: a worker behind its input paid the publish (≈ 100–200 µs of
#: CPU on this machine: the CDR bytes, DDS's write and its shared-memory wake-up) and the
#: executor's dispatch once per batch (docs/bench/tail.md, "Where the worker's CPU goes");
#: a worker that keeps up finds nothing waiting and publishes each batch as before.
COALESCE_BUDGET_S = 2.0e-3
COALESCE_MAX = 8
#: A patch's frame stamped no later than the newest one solved is skipped (an older frame
#: out of a queue) when within this much of it [ns]; further back, its clock stepped (an NTP
#: step, a replay or driver restarted, a bogus stamp before): it is taken and the order
#: starts again from it. Why: one frame stamped in 2038 stopped its patch until then, and a
#: clock stepped back by X s dropped X s of frames, with no word either time.
CLOCK_STEP_NS = 1_000_000_000
#: ... and more than this many frames of a patch in a row older than its newest are a step
#: too (a frozen clock stamping 0, a bag shorter than a second played in a loop: every frame
#: after the first pass was skipped), not frames out of a queue.
STALE_RUN = 8


def add_row(rows: ContactRows, pipe: Any, stamp_ns: int, result: Any) -> None:
    """Append one patch's summary (``result`` None: the frame failed; see /diagnostics)."""
    rows.patches.append(pipe.name)
    rows.frame_ids.append(pipe.frame_id)
    rows.stamps_ns.append(stamp_ns)
    if result is None:
        rows.states.append(ContactArray.FAILED)
        rows.total_force.append(0.0)
        rows.cop_x.append(0.0)
        rows.cop_y.append(0.0)
        return
    if not result.in_contact:
        rows.states.append(ContactArray.IDLE)
        rows.total_force.append(0.0)
        rows.cop_x.append(0.0)
        rows.cop_y.append(0.0)
        return
    # HELD: the fusion (fuse_frames) found the readings unchanged and republished its result
    fusion = getattr(pipe.recon, "fusion", None)
    held = fusion is not None and fusion.last == "held"
    rows.states.append(ContactArray.HELD if held else ContactArray.CONTACT)
    rows.total_force.append(float(result.total_force))
    rows.cop_x.append(float(result.cop[0]))
    rows.cop_y.append(float(result.cop[1]))
    k = len(rows.patches) - 1
    for c in result.contacts:
        rows.force.append(float(c.force))
        rows.center.append((float(c.center[0]), float(c.center[1]), 0.0))
        rows.radius.append(float(c.radius))
        rows.profile.append(str(c.profile))
        rows.contact_patch.append(k)


def full_frame(pipe: Any, stamp_ns: int, view: Any, a: int, b: int) -> Any:
    """``pipe``'s frame of a batch (``view``'s rows ``a`` to ``b``) by PatchPipeline.frame;
    None (a FAILED row) if it raised: counted and said as PatchPipeline.internal_error
    does, and the batch's other patches go on (re-raised once the context is shut down)."""
    try:
        return pipe.frame(
            stamp_ns, view.taxel_ids[a:b], view.delta_c[a:b], view.status[a:b], contact=False
        )
    except Exception as exc:
        if not pipe.node.context.ok():
            raise
        pipe.internal_error(exc)
        return None


class ContactBatches:
    """The ``contacts`` publisher and, with ``input: batches``, the ``taxel_batches`` input.

    Args:
        node: the ContactReconstructionNode (its ``pipelines``, ``link``, ``now_ns``).
        batches: subscribe to ``taxel_batches`` (else frames come per patch, PatchPipeline).
    """

    def __init__(self, node: Node, batches: bool, only: str | None = None) -> None:
        from tactile_contact.ros.patch_pipeline import _UNUSABLE, OUTPUT_QOS, QUIET_EVENTS
        from tactile_contact.ros.quiet_batch import QuietBatch

        self.node = node
        self.pub = node.create_publisher(
            ContactArray, CONTACTS_TOPIC, OUTPUT_QOS, event_callbacks=QUIET_EVENTS
        )
        self.batches = 0
        self.bad_batches = 0
        self.last_error = ""
        self._newest: dict[str, int] = {}  # patch → stamp [ns] of its newest frame solved
        #: Frames skipped as older than one of their patch already solved (CLOCK_STEP_NS),
        #: and frames taken although stamped more than that before it (a clock step).
        self.stale_frames = 0
        self.clock_steps = 0
        self.last_clock_step = ""
        self._stale_run: dict[str, int] = {}  # patch → frames skipped as stale in a row
        # Patches whose fusion deferred a re-solve, oldest first (PatchPipeline.frame).
        self._deferred: dict[str, Any] = {}
        #: Batches taken inside another's callback (their rows in its ContactArray).
        self.coalesced = 0
        #: A batch's idle and held patch-frames go through one compiled call (None: each by
        #: PatchPipeline.frame; the same results, test/test_quiet_batch.py).
        self.quiet: QuietBatch | None = QuietBatch(
            int(_UNUSABLE),
            lambda text: node.get_logger().error(text, throttle_duration_sec=5.0),
        )
        self.sub: Any = None
        if batches:
            qos = QoSProfile(depth=BATCH_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.sub = self._subscribe(qos, only)

    def _subscribe(self, qos: QoSProfile, only: str | None) -> Any:
        """The ``taxel_batches`` subscription, with the content filter ``only`` if given
        (workers.bus_filter): the middleware then drops other buses' batches before they
        reach this process. A middleware that cannot filter (or refuses the expression)
        gets the subscription without it: every batch, its patches picked here as always."""
        node = self.node
        if only is not None:
            try:
                sub = node.create_subscription(
                    TaxelBatch,
                    BATCHES_TOPIC,
                    self.on_batch,
                    qos,
                    raw=True,
                    content_filter_options=ContentFilterOptions(only, []),
                )
                if sub.is_cft_enabled:
                    node.get_logger().info(f"taxel_batches filtered: {only}")
                return sub
            except Exception as exc:  # (rclpy raises RCLError, or TypeError on an older one)
                node.get_logger().warning(
                    f"taxel_batches: no content filter ({type(exc).__name__}: {exc}); "
                    "taking every bus's batches"
                )
        return node.create_subscription(TaxelBatch, BATCHES_TOPIC, self.on_batch, qos, raw=True)

    def on_batch(self, data: bytes) -> None:
        """One batch: each patch of it this worker serves, solved; one ContactArray out.
        Never raises into the executor."""
        try:
            self._on_batch(data)
        except Exception as exc:
            if not self.node.context.ok():
                return  # (a Ctrl-C shut the context down under this batch)
            self.bad_batches += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            self.node.get_logger().error(
                f"taxel batch: {self.last_error}; batch dropped", throttle_duration_sec=5.0
            )

    def defer(self, pipe: Any) -> None:
        """``pipe``'s fusion has a re-solve waiting: run it by :meth:`catch_up`."""
        self._deferred.setdefault(pipe.name, pipe)

    def catch_up(self, started: float, least: int = 1) -> None:
        """Run deferred re-solves, oldest first, until the callback that began at
        ``started`` (time.perf_counter) has spent CATCH_UP_BUDGET_S (at least ``least``:
        one a batch the callback took)."""
        pipelines = self.node.pipelines
        ran = 0
        while self._deferred:
            name = next(iter(self._deferred))
            pipe = self._deferred.pop(name)
            if pipelines.get(name) is pipe:
                pipe.catch_up()
            ran += 1
            if ran >= least and time.perf_counter() - started >= CATCH_UP_BUDGET_S:
                return

    def _on_batch(self, data: bytes) -> None:
        started = time.perf_counter()
        rows = self._rows_of(data, ContactRows())
        # Batches already waiting join this one's ContactArray (COALESCE_BUDGET_S).
        taken = 1
        while taken < COALESCE_MAX and time.perf_counter() - started < COALESCE_BUDGET_S:
            more = self._take()
            if more is None:
                break
            taken += 1
            self.coalesced += 1
            rows = self._rows_of(more, rows)
        if rows.patches:
            self.publish(rows)
        self.catch_up(started, taken)

    def _take(self) -> bytes | None:
        """The next batch waiting in the subscription's queue (raw bytes), or None."""
        if self.sub is None:
            return None
        with self.sub.handle:  # (as rclpy's executors take: the handle kept alive meanwhile)
            got = self.sub.handle.take_message(self.sub.msg_type, True)
        return None if got is None else got[0]

    def _rows_of(self, data: bytes, rows: ContactRows) -> ContactRows:
        """One batch's patches this worker serves, solved, their rows appended to ``rows``;
        the rows to go on with (``rows`` published first and new ones begun when the batch
        has a patch ``rows`` holds already: a ContactArray has a patch once). A batch that
        cannot be read: counted, logged, nothing appended."""
        try:
            view = read_taxel_batch(data)
        except CdrError as exc:
            self.bad_batches += 1
            self.last_error = str(exc)
            self.node.get_logger().error(
                f"taxel batch: {exc}; batch dropped", throttle_duration_sec=5.0
            )
            return rows
        self.batches += 1
        if rows.patches and not set(rows.patches).isdisjoint(view.patches):
            self.publish(rows)
            rows = ContactRows()
        node = self.node
        pipelines, serving, newest = node.pipelines, node.link.serving, self._newest
        off = view.offsets
        quiet = self.quiet
        if quiet is not None and not (
            view.delta_c.dtype == np.float32
            and view.status.dtype == np.uint8
            and view.taxel_ids.dtype == np.uint16
        ):
            quiet = None
        items = []
        taken: set[str] = set()  # (the patches in items)
        for i, name in enumerate(view.patches):
            pipe = pipelines.get(name)
            if pipe is None or name not in serving:
                continue  # another worker's patch
            stamp = view.stamps_ns[i]
            last = newest.get(name)
            if last is not None and stamp <= last:
                run = self._stale_run.get(name, 0) + 1
                if last - stamp <= CLOCK_STEP_NS and run <= STALE_RUN:
                    self._stale_run[name] = run
                    self.stale_frames += 1  # a newer frame of it was solved already
                    continue
                self.clock_steps += 1
                pipe.end_contact()  # (its stamps went back: the contact followed ends)
                self.last_clock_step = (
                    f"patch {name}: a frame stamped {(last - stamp) * 1e-9:.3g} s before the "
                    "newest one solved (a clock step, a restarted replay or a bogus stamp): "
                    "taken, the order starts again from it"
                )
                node.get_logger().warning(self.last_clock_step, throttle_duration_sec=5.0)
            newest[name] = stamp
            self._stale_run[name] = 0
            a, b = off[i], off[i + 1]
            if quiet is None:
                add_row(rows, pipe, stamp, full_frame(pipe, stamp, view, a, b))
            else:
                # A patch twice in one batch (never from the driver): its second frame must
                # see the state the first leaves, so it takes the full path after it.
                ready = -1
                if name not in taken:
                    taken.add(name)
                    try:
                        ready = pipe.batch_ready(view.taxel_ids[a:b])
                    except Exception as exc:  # (its full path says what is wrong, or fails)
                        quiet.fault(f"patch {name}'s check", exc)
                items.append((pipe, stamp, a, b, ready))
        if items:
            quiet.run(view, items, rows, add_row)  # type: ignore[union-attr]
        return rows

    def publish(self, rows: ContactRows) -> None:
        """Publish ``rows`` as one ContactArray, each patch's latency measured now."""
        now = self.node.now_ns()
        rows.latency = [(now - s) * 1e-9 for s in rows.stamps_ns]
        for name, lat in zip(rows.patches, rows.latency, strict=True):
            pipe = self.node.pipelines.get(name)
            if pipe is not None and pipe.latency_ok(lat):
                pipe.stats.latency_s.append(lat)
        try:
            data = write_contact_array(max(rows.stamps_ns), self.node.link.me.worker, rows)
        except ValueError as exc:  # (non-finite: each result was checked; never expected)
            self.bad_batches += 1
            self.last_error = str(exc)
            return
        publish_while_up(self.node, self.pub, data)

    def values(self) -> dict[str, object]:
        """Counters for /diagnostics."""
        return {
            "batches": self.batches,
            "bad_batches": self.bad_batches,
            "batches_coalesced": self.coalesced,
            "stale_frames": self.stale_frames,
            "clock_steps": self.clock_steps,
            # frames a batch's compiled call took with nothing more, and with Python after
            "frames_batch_held": self.quiet.held if self.quiet is not None else 0,
            "frames_batch_rest": self.quiet.rest if self.quiet is not None else 0,
            # the compiled call's faults (its frames taken by the full path, nothing lost)
            "quiet_batch_errors": self.quiet.errors if self.quiet is not None else 0,
        }
