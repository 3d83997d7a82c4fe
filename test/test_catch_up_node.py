"""contact_reconstruction over real DDS: the fusion's deferred re-solves are run by the node
after each frame's summary is published (ContactBatches.catch_up, issue 25's tail)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from test.test_reconstruction_node import Rig, _delta_c, bundles  # noqa: F401  (fixture)

pytestmark = pytest.mark.ros


def test_a_held_press_is_re_solved_after_its_frames_are_published(
    ros_context: object,
    bundles: Path,  # noqa: F811
) -> None:
    """A 1.5 N press held 30 frames (0.5-count noise): the windows of DEFER_FROM frames and
    more are re-solved by the node after the frame that made them due was published (none
    left waiting), the shorter ones in their frame, and /diagnostics counts and times the
    deferred ones."""
    rig = Rig(ros_context, bundles)
    pipe = rig.node.pipelines["hexagon"]
    fusion = pipe.recon.fusion
    assert fusion is not None and fusion.defer
    dc = _delta_c(1.5, (0.0, 0.0))
    rng = np.random.default_rng(1)
    lsb = pipe.recon.readings.lsb
    for k in range(30):
        noisy = dc + np.rint(rng.normal(0.0, 0.5, len(dc))) * lsb
        rig.send(noisy, sec=10 + k)
        assert not fusion.pending  # (run after this frame's summary went out)
    last = rig.contacts[-1]
    assert last.in_contact and abs(last.total_force / 1.5 - 1) < 0.3
    # (the node's noise tracker learns the first frames' noise: a few read as changes)
    assert fusion.counts.deferred >= 1 and fusion.counts.fused > fusion.counts.deferred
    values = {kv.key: kv.value for kv in pipe.diagnostics().values}
    assert int(values["resolves_deferred"]) == fusion.counts.deferred
    assert float(values["catch_up_median_ms"]) > 0.0
    rig.close()
