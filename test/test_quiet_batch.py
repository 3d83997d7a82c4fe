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
