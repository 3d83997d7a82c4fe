"""A batch's quiet patch-frames in one compiled call (tactile_contact.ros.quiet_batch, issue
25): frame by frame the same as each patch's own full path.

A real ContactReconstructionNode (``input: batches``) serves config/robot_skin.yaml (a
forearm of 72 taxels and a palm of 40 with disabled taxels) and takes each TaxelBatch as it
takes one from DDS (ContactBatches._rows_of: the bytes read by ros/cdr.py, the rows of its
ContactArray); beside each of its patches a second PatchPipeline of the same bundle takes
every frame by the full path (``quiet = False``). The readings are test_patch_quiet's: the
skin simulator's 8-bit readings with converter noise, idle, a sphere pressed and held, slid,
pressed lighter, with a taxel stuck a while, a reading beyond full scale and a NaN. Every
frame: the same row (state, force, centre of pressure), the same fusion path and result, the
same noise learnt (bit for bit), the same deferred re-solves; at the end the same counters;
and most frames went by the compiled call with nothing more to do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from test.test_patch_quiet import COUNTERS, LAYOUT, PERIODS, _batches, _same

pytestmark = [pytest.mark.ros]


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("quiet_batch_bundles")
    build_layout(LAYOUT, out, jobs=2)
    return out


def test_a_batchs_quiet_frames_in_one_call_give_each_full_paths_results(
    ros_context: object, bundles: Path
) -> None:
    from rclpy.parameter import Parameter

    from tactile_contact.msg import ContactArray
    from tactile_contact.ros.cdr import ContactRows, read_taxel_batch
    from tactile_contact.ros.contact_reconstruction import (
        ContactReconstructionNode,
        load_reconstructor,
    )
    from tactile_contact.ros.patch_pipeline import PatchPipeline

    node = ContactReconstructionNode(
        context=ros_context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(bundles)),
            Parameter("layout", value=str(LAYOUT)),
            Parameter("input", value="batches"),
        ],
    )
    try:
        pipes = dict(node.pipelines)
        assert len(pipes) == 2
        assert set(pipes) <= node.link.serving
        full = {}
        for name, pipe in pipes.items():
            full[name] = PatchPipeline(node, load_reconstructor(pipe.bundle), pipe.bundle)
            full[name].quiet = False
        paths: dict[str, int] = {}
        quiet = node.batches.quiet
        assert quiet is not None
        for data in _batches(PERIODS):
            rows = node.batches._rows_of(data, ContactRows())
            view = read_taxel_batch(data)
            assert rows.patches == list(view.patches)
            for i, name in enumerate(view.patches):
                a, b = view.offsets[i], view.offsets[i + 1]
                args = (view.taxel_ids[a:b], view.delta_c[a:b], view.status[a:b])
                want = full[name].frame(view.stamps_ns[i], *args, contact=False)
                q, f = pipes[name].recon.fusion, full[name].recon.fusion
                assert _same(q.result, want), (name, view.stamps_ns[i])
                assert q.last == f.last
                paths[q.last] = paths.get(q.last, 0) + 1
                state = (
                    ContactArray.IDLE
                    if not want.in_contact
                    else ContactArray.HELD
                    if f.last == "held"
                    else ContactArray.CONTACT
                )
                assert rows.states[i] == state
                assert rows.total_force[i] == (want.total_force if want.in_contact else 0.0)
                assert np.array_equal(pipes[name].noise.sigma, full[name].noise.sigma)
                assert pipes[name].noise.frames_used == full[name].noise.frames_used
                assert q.pending == f.pending
                pipes[name].catch_up()
                full[name].catch_up()
                assert _same(q.result, f.result) and q.result_frames == f.result_frames
            node.batches._deferred.clear()  # (run above, pipe by pipe)
        for name in pipes:
            s, t = pipes[name].stats, full[name].stats
            for key in COUNTERS:
                assert getattr(s, key) == getattr(t, key), (name, key)
            assert pipes[name].recon.fusion.counts == full[name].recon.fusion.counts
            assert s.out_of_range >= 1 and s.nonfinite_frames == 1
        # most held frames went by the one call with nothing more; some needed Python after it
        print(f"frames by the call {quiet.held}, with Python after {quiet.rest}; paths {paths}")
        assert quiet.held > 0.7 * paths["held"] and quiet.rest > 5
        assert paths["solved"] > 5 and paths["fused"] > 5
    finally:
        node.destroy_node()


def _node(context: object, bundles: Path) -> Any:
    from rclpy.parameter import Parameter

    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    return ContactReconstructionNode(
        context=context,
        parameter_overrides=[
            Parameter("bundles_dir", value=str(bundles)),
            Parameter("layout", value=str(LAYOUT)),
            Parameter("input", value="batches"),
        ],
    )


def _rows(node: Any, batches: list[bytes], before: Any = None) -> list[Any]:
    """Each batch's rows as the node makes them (ContactBatches._rows_of), every deferred
    re-solve run after it (all of them: catch_up's time budget would make two runs differ);
    ``before(j)`` called ahead of batch j."""
    from tactile_contact.ros.cdr import ContactRows

    out = []
    for j, data in enumerate(batches):
        if before is not None:
            before(j)
        out.append(node.batches._rows_of(data, ContactRows()))
        deferred = node.batches._deferred
        while deferred:
            deferred.pop(next(iter(deferred))).catch_up()
    return out


def _row(rows: Any, name: str) -> tuple:
    """Patch ``name``'s row in ``rows``, its contacts with it: every value, to compare bit
    for bit."""
    k = rows.patches.index(name)
    contacts = [
        (rows.force[c], rows.center[c], rows.radius[c], rows.profile[c])
        for c in range(len(rows.force))
        if rows.contact_patch[c] == k
    ]
    return (
        rows.stamps_ns[k],
        rows.states[k],
        rows.total_force[k],
        rows.cop_x[k],
        rows.cop_y[k],
        contacts,
    )


def _faulty(pipe: Any, fail_at: dict[str, set[int]]) -> list[tuple[str, int]]:
    """Fault injection only: ``pipe`` (a real PatchPipeline serving in the node) made one
    whose n-th call of ``frame``, ``batch_held`` or ``batch_rest`` (n in ``fail_at[name]``)
    raises RuntimeError before doing anything. No real reading makes a pipeline raise:
    arrays of the wrong length, unknown taxels, NaN and readings out of range are each
    refused or left out and counted (test_patch_quiet); this stands for a bug. Returns the
    list the faults are noted in: (method, stamp [ns])."""
    from tactile_contact.ros.patch_pipeline import PatchPipeline

    raised: list[tuple[str, int]] = []
    calls: dict[str, int] = {}

    def fault(what: str, stamp_ns: int) -> None:
        calls[what] = calls.get(what, 0) + 1
        if calls[what] in fail_at.get(what, ()):
            raised.append((what, stamp_ns))
            raise RuntimeError(f"injected fault in {what}")

    class Faulty(PatchPipeline):
        def frame(self, stamp_ns: int, *args: Any, **kwargs: Any) -> Any:
            fault("frame", stamp_ns)
            return super().frame(stamp_ns, *args, **kwargs)

        def batch_held(self, stamp_ns: int, *args: Any) -> Any:
            fault("batch_held", stamp_ns)
            return super().batch_held(stamp_ns, *args)

        def batch_rest(self, stamp_ns: int, *args: Any) -> Any:
            fault("batch_rest", stamp_ns)
            return super().batch_rest(stamp_ns, *args)

    pipe.__class__ = Faulty
    return raised


def test_a_patch_that_raises_costs_its_own_row_only_with_or_without_the_compiled_call(
    ros_context: object, bundles: Path
) -> None:
    """One patch's frame raising (in PatchPipeline.frame, batch_held or batch_rest) gives
    that frame a FAILED row and the patch's ``internal_errors`` and ``last_error``, as a
    TaxelArray's frame does (PatchPipeline.on_taxels); the batch is not dropped and the other
    patch's rows are, bit for bit, those of a node without the fault. The same with the
    batch's loop without the compiled call (``quiet`` None)."""
    from tactile_contact.msg import ContactArray

    batches = _batches(PERIODS)
    nodes = [_node(ros_context, bundles) for _ in range(3)]
    try:
        ref, quiet, loop = nodes
        first, other = list(ref.pipelines)  # (the faulty patch comes first in each batch)
        loop.batches.quiet = None
        faults = {
            "quiet": _faulty(
                quiet.pipelines[first],
                {"frame": {5, 60}, "batch_held": {10, 100}, "batch_rest": {3}},
            ),
            "loop": _faulty(loop.pipelines[first], {"frame": {5, 60, 200, 300}}),
        }
        want = _rows(ref, batches)
        for key, node in (("quiet", quiet), ("loop", loop)):
            got = _rows(node, batches)
            raised = faults[key]
            print(key, raised)
            assert len(raised) == (5 if key == "quiet" else 4)
            assert {what for what, _ in raised} == (
                {"frame", "batch_held", "batch_rest"} if key == "quiet" else {"frame"}
            )
            failed = {stamp for _, stamp in raised}
            for j, (g, w) in enumerate(zip(got, want, strict=True)):
                assert g.patches == w.patches == [first, other], j
                assert _row(g, other) == _row(w, other), (key, j)
                k = g.patches.index(first)
                if g.stamps_ns[k] in failed:
                    assert g.states[k] == ContactArray.FAILED, (key, j)
                else:
                    assert g.states[k] != ContactArray.FAILED, (key, j)
                if g.stamps_ns[k] < min(failed):  # (until its first fault: unchanged too)
                    assert _row(g, first) == _row(w, first), (key, j)
            stats = node.pipelines[first].stats
            assert stats.internal_errors == len(raised)
            assert stats.last_error.startswith("internal error: RuntimeError: injected fault")
            assert node.pipelines[other].stats.internal_errors == 0
            assert node.batches.bad_batches == 0
        assert quiet.batches.quiet is not None and quiet.batches.quiet.errors == 0
        assert quiet.batches.quiet.held > 100
    finally:
        for node in nodes:
            node.destroy_node()


def test_a_compiled_call_that_raises_takes_its_batch_by_the_full_path(
    ros_context: object, bundles: Path
) -> None:
    """The batch's compiled call refusing its arguments (fault injection only: one of its
    typed lists replaced by one of arrays of the wrong shape, numba's TypingError) costs
    nothing but time: that batch's frames take the full path, the error is said once and
    counted (/diagnostics ``quiet_batch_errors``), the typed lists are made again and the
    next batches go by the call again; every row, of both patches, bit for bit a faultless
    node's."""
    from tactile_contact.inverse import _temporal_kernels as kern

    batches = _batches(PERIODS)
    nodes = [_node(ros_context, bundles) for _ in range(2)]
    try:
        ref, node = nodes
        quiet = node.batches.quiet
        assert quiet is not None
        seen: dict[str, int] = {}

        def corrupt(j: int) -> None:
            if j == 20:  # (idle: both patches' frames go by the call)
                assert quiet.lists["i2"] is not None and quiet.held > 0
                quiet.lists["i2"] = kern.list_of(np.zeros(3, np.int64))
                seen["held"] = quiet.held
            if j == 21:
                assert quiet.errors == 1 and quiet.held == seen["held"]

        want = _rows(ref, batches)
        got = _rows(node, batches, corrupt)
        print(quiet.last_error)
        for j, (g, w) in enumerate(zip(got, want, strict=True)):
            assert g.patches == w.patches
            for name in g.patches:
                assert _row(g, name) == _row(w, name), (name, j)
        assert quiet.errors == 1
        assert "TypingError" in quiet.last_error and "full path" in quiet.last_error
        assert node.batches.values()["quiet_batch_errors"] == 1
        assert node.batches.bad_batches == 0
        assert quiet.held > seen["held"] + 100  # (the call serves again)
        assert quiet.held == ref.batches.quiet.held - 2  # (only batch 20's two frames)
        for name, pipe in node.pipelines.items():
            assert pipe.stats.internal_errors == 0
            for key in COUNTERS:
                assert getattr(pipe.stats, key) == getattr(ref.pipelines[name].stats, key)
    finally:
        for node in nodes:
            node.destroy_node()
