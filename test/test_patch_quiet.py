"""PatchPipeline's quiet path: a batch's idle and held patch-frames in one compiled call
(issue 25), frame by frame the same as the full path.

A real ContactReconstructionNode (``input: batches``) serves config/robot_skin.yaml (a
forearm of 72 taxels and a palm of 40 with disabled taxels), its bundles built from the
layout. Beside each of its patches a second PatchPipeline of the same bundle takes every
frame by the full path (``quiet = False``). Both are handed the same TaxelBatch bytes (read
by ros/cdr.py as the node reads them) of the skin simulator's 8-bit readings with converter
noise: idle, a sphere pressed and held, slid, pressed lighter; with a taxel that goes stuck
for a while, a reading beyond full scale and a NaN reading. Every frame: the same
result (state, force, centre of pressure, contacts), the same fusion path, the same noise
learnt (bit for bit), the same counters; and most frames went the quiet way.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = [pytest.mark.ros]

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "robot_skin.yaml"
PERIOD_S = 0.02
PERIODS = 450  # 9 s


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("quiet_bundles")
    build_layout(LAYOUT, out, jobs=2)
    return out


def _batches(periods: int) -> list[bytes]:
    """The TaxelBatch bytes of every period: both patches, the simulator's readings."""
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.layout import load_layout
    from tactile_contact.model.modules import taxel_id
    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.cdr import write_taxel_batch
    from tactile_contact.sim.scenes import scenario_indentation
    from tactile_contact.sim.simulator import simulator_for_patch

    patches = load_layout(LAYOUT).patches
    per_patch = []
    for k, patch in enumerate(patches):
        sim = simulator_for_patch(
            patch, fine_cell=5e-4, realtime=True, period_s=PERIOD_S, noise_cdc=0.6, seed=k
        )
        held = scenario_indentation("press", patch, HertzSphere(6e-3), 1.5, 3.0)
        swept = scenario_indentation("sweep", patch, HertzSphere(6e-3), 2.0, 2.0)
        light = scenario_indentation("press", patch, HertzSphere(3e-3), 0.4, 3.0)
        ids = np.array(
            [taxel_id(m.board, m.triangle, c) for m in patch.modules for c in range(12)], np.uint16
        )
        status = np.where(patch.valid_mask(), 0, TaxelArray.STATUS_DISABLED).astype(np.uint8)
        count_farad = patch.sensor.farad_per_count * 2**patch.sensor.shift
        # the driver's baseline: the mean of unloaded readings (its calibration)
        baseline = np.mean([sim.period(None, -1.0).truth.values for _ in range(100)], axis=0)
        rows = []
        for j in range(periods):
            t = j * PERIOD_S
            # idle 1 s, a 1.5 N press (ramp, held, released) 3 s, a slide 2 s, 0.4 N 3 s
            if t < 1.0:
                scene, at = None, t
            elif t < 4.0:
                scene, at = held, t - 1.0
            elif t < 6.0:
                scene, at = swept, t - 4.0
            else:
                scene, at = light, t - 6.0
            values = sim.period(scene, at).truth.values
            dc = ((baseline - values.astype(np.float64)) * count_farad).astype(np.float32)
            st = status.copy()
            if 30 <= j < 80:
                st[5] |= TaxelArray.STATUS_STUCK  # a taxel stuck a while: the window restarts
            if j == 130:
                dc[7] = np.float32(1e-9)  # beyond any 8-bit reading: out of range, counted
            if j == 140:
                dc[9] = np.float32("nan")  # the full path's fault, said and counted
            rows.append((patch.name, patch.frame_id, ids, dc, st))
        per_patch.append(rows)
    out = []
    for j in range(periods):
        rows = [p[j] for p in per_patch]
        stamp = 1_000_000_000 + j * int(PERIOD_S * 1e9)
        data = write_taxel_batch(
            stamp,
            "",
            [r[0] for r in rows],
            [r[1] for r in rows],
            [stamp] * len(rows),
            [r[2] for r in rows],
            [r[3] for r in rows],
            [np.zeros(len(r[3]), np.uint8) for r in rows],
            [r[4] for r in rows],
        )
        out.append(bytes(data))
    return out


def _same(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is b
    if a.in_contact != b.in_contact or a.taxels_used != b.taxels_used:
        return False
    return (
        a.total_force == b.total_force
        and tuple(a.cop) == tuple(b.cop)
        and [(c.force, tuple(c.center), c.radius, c.profile) for c in a.contacts]
        == [(c.force, tuple(c.center), c.radius, c.profile) for c in b.contacts]
    )


COUNTERS = (
    "frames",
    "solved",
    "constrained",
    "skipped_idle",
    "skipped_deflection",
    "skipped_images",
    "skipped_visualization",
    "bad_frames",
    "nonfinite_frames",
    "nonfinite_readings",
    "out_of_range",
    "unpublishable",
    "contacts",
    "contact_frames",
    "peak_force",
)


def test_the_quiet_path_gives_the_full_paths_results_frame_by_frame(
    ros_context: object, bundles: Path
) -> None:
    from rclpy.parameter import Parameter

    from tactile_contact.ros.cdr import read_taxel_batch
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
        full = {}
        for name, pipe in pipes.items():
            full[name] = PatchPipeline(node, load_reconstructor(pipe.bundle), pipe.bundle)
            full[name].quiet = False
        quiet_frames = 0
        paths: dict[str, int] = {}
        for data in _batches(PERIODS):
            view = read_taxel_batch(data)
            for i, name in enumerate(view.patches):
                a, b = view.offsets[i], view.offsets[i + 1]
                args = (view.taxel_ids[a:b], view.delta_c[a:b], view.status[a:b])
                before = pipes[name].stats.quiet
                got = pipes[name].frame(view.stamps_ns[i], *args, contact=False)
                want = full[name].frame(view.stamps_ns[i], *args, contact=False)
                q, f = pipes[name].recon.fusion, full[name].recon.fusion
                assert _same(got, want), (name, view.stamps_ns[i])
                assert q.last == f.last
                paths[q.last] = paths.get(q.last, 0) + 1
                quiet_frames += pipes[name].stats.quiet - before
                assert np.array_equal(pipes[name].noise.sigma, full[name].noise.sigma)
                assert pipes[name].noise.frames_used == full[name].noise.frames_used
                # the re-solves the fusion deferred, as the node runs them after the publish
                assert q.pending == f.pending
                assert pipes[name].catch_up() is None and full[name].catch_up() is None
                assert _same(q.result, f.result) and q.result_frames == f.result_frames
            node.batches._deferred.clear()  # (run above, pipe by pipe)
        for name in pipes:
            s, t = pipes[name].stats, full[name].stats
            for key in COUNTERS:
                assert getattr(s, key) == getattr(t, key), (name, key)
            cq, cf = pipes[name].recon.fusion.counts, full[name].recon.fusion.counts
            assert cq == cf
            assert s.out_of_range >= 1 and s.nonfinite_frames == 1 and t.quiet == 0
        # most frames took the quiet path; the scene's every kind of frame was seen
        assert quiet_frames > 0.6 * 2 * PERIODS
        assert paths["solved"] > 5 and paths["fused"] > 5
        assert all(math.isfinite(p.stats.peak_force) for p in pipes.values())
        assert max(p.stats.peak_force for p in pipes.values()) > 0.5
    finally:
        node.destroy_node()
