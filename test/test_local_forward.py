"""The real-time forward model of large patches (tactile_contact.sim.local_forward) against the
dense fixed-grid model and the contact-centred reference, and the simulator on an iCub patch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_contact.model.forward import ForwardModel, PatchForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import load_layout
from tactile_contact.sim.local_forward import LocalForwardModel
from tactile_contact.sim.simulator import Indentation, simulator_for_patch

ROOT = Path(__file__).resolve().parents[1]
H, E, NU = 2.0e-3, 2.1e5, 0.5
#: One 8-bit count is about 10 µm of compression (DESIGN.md §2).
COUNT = 1.0e-5


def test_cut_kernel_matches_the_dense_one_on_the_hexagon():
    xy = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0].channel_xy()
    dense = PatchForwardModel(xy, H, E, NU, fine_cell=1.0e-3, taxel_radius=2e-3)
    local = LocalForwardModel(xy, H, E, NU, fine_cell=1.0e-3, taxel_radius=2e-3)
    rng = np.random.default_rng(1)
    worst = 0.0
    for k in range(16):
        c = xy[rng.integers(len(xy))] + rng.normal(0.0, 3e-3, 2)
        ind = HertzSphere(6e-3) if k % 2 else FlatPunch(2e-3)
        a = dense.compression(ind, 3.0, c)
        b = local.compression(ind, 3.0, c)
        worst = max(worst, float(np.abs(a - b).max()))
    # Cutting each taxel's kernel at 20 mm loses loads farther away: under 0.1 count at 3 N.
    assert worst < 0.1 * COUNT
    assert local.kernel.nnz < dense.kernel.size


def test_cut_kernel_against_the_reference_model_on_the_forearm():
    patch = load_layout(ROOT / "config" / "icub" / "left_forearm_V2.yaml").patches[0]
    xy = patch.taxel_xy()
    local = LocalForwardModel(xy, H, E, NU, fine_cell=5.0e-4, taxel_radius=2e-3)
    ref = ForwardModel(xy, H, E, NU, fine_cell=2.0e-4, taxel_radius=2e-3)
    ind = HertzSphere(6e-3)
    for k in (17, 100, 201):  # on three modules of both boards
        a = ref.compression(ind, 2.0, xy[k])
        b = local.compression(ind, 2.0, xy[k])
        # The fixed 0.5 mm grid against the contact-centred 0.2 mm one (PatchForwardModel's
        # stated accuracy is about 3 %).
        assert np.abs(a - b).max() < 0.04 * np.abs(a).max()
    assert np.all(local.compression(ind, 0.0, xy[0]) == 0)
    with pytest.raises(ValueError, match="force must be finite"):
        local.compression(ind, -1.0, xy[0])


def test_simulator_runs_an_imported_forearm():
    patch = load_layout(ROOT / "config" / "icub" / "left_forearm_V2.yaml").patches[0]
    sim = simulator_for_patch(patch, fine_cell=5.0e-4, realtime=True, noise_cdc=0.0, seed=0)
    assert isinstance(sim.model, LocalForwardModel)
    centre = patch.taxel_xy()[120]
    press = Indentation.press(HertzSphere(5e-3), 2.0, centre, start_s=0.0, ramp_s=0.1, hold_s=0.5)
    period = sim.period(press, 0.3)
    assert len(period.messages) == 2 * len(patch.modules)  # frames A and B of 24 triangles
    assert period.truth.force == pytest.approx(2.0)
    ids = {m.arbitration_id for m in period.messages}
    assert 0x400 | 13 << 4 | 0 in ids and 0x400 | 12 << 4 | 13 in ids
