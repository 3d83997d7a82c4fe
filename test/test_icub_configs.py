"""The shipped iCub layouts (config/icub) build, load and reconstruct; bringup runs one.

The small ones (hand palm, the lower leg's four board patches) are built here; the forearm
(240 taxels, ≈ 13 s of CPU) once for the module. Truth for the presses: the fine forward
model (0.25 mm cells centred on the contact, exact Hertz pressure, 2 mm electrode means), not
the bundle's own matrices or tables.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.model.layout import PatchLayout, load_layout
from tactile_contact.model.sensor import compression_to_delta_c, value_count_farad
from tactile_contact.offline.build import build_layout
from tactile_contact.offline.bundle import load_bundle

ROOT = Path(__file__).resolve().parents[1]
ICUB = ROOT / "config" / "icub"


@pytest.fixture(scope="module")
def forearm_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("icub_forearm")
    build_layout(ICUB / "left_forearm_V2.yaml", out, jobs=1)
    return out / "left_forearm"


def _readings(patch: PatchLayout, presses: list[tuple[float, int]], seed: int = 0) -> np.ndarray:
    """8-bit ΔC [F] of 12 mm spheres (force [N], on taxel k), summed; fine forward model on
    the taxels within 25 mm of each (farther ones move < 0.05 count)."""
    xy = patch.taxel_xy()
    e, s = patch.elastomer, patch.sensor
    delta = np.zeros(len(xy))
    for force, k in presses:
        near = np.linalg.norm(xy - xy[k], axis=1) <= 25e-3
        fm = ForwardModel(xy[near], e.thickness, e.young, e.poisson, 2.5e-4, s.taxel_radius)
        delta[near] += fm.compression(HertzSphere(6e-3), force, xy[k])
    lsb = float(value_count_farad(s.farad_per_count, s.shift))
    dc = compression_to_delta_c(delta, e.thickness, s.epsilon_r, s.area)
    rng = np.random.default_rng(seed)
    return np.rint(dc / lsb + rng.normal(0.0, 0.15, len(dc))) * lsb


def test_small_shipped_layouts_build_and_load(tmp_path):
    for name in ("left_hand_V2_1", "left_leg_lower"):
        layout = load_layout(ICUB / f"{name}.yaml")
        status = build_layout(ICUB / f"{name}.yaml", tmp_path, jobs=2)
        assert set(status.values()) == {"built"}
        for patch in layout.patches:
            bundle = load_bundle(tmp_path / patch.name, patch)  # refuses stale or foreign ones
            assert bundle.manifest["layout"]["surface"] == patch.surface.to_dict()
            assert len(bundle["taxel_xy"]) == len(patch.taxel_xy())


def test_forearm_bundle_loads_and_a_press_reconstructs(forearm_bundle):
    patch = load_layout(ICUB / "left_forearm_V2.yaml").patches[0]
    bundle = load_bundle(forearm_bundle, patch)
    assert bundle["taxel_xy"].shape == (240, 2)
    recon = Reconstructor.from_bundle(forearm_bundle)
    xy = patch.taxel_xy()
    for k in (33, 205):  # a taxel of board 13 and one of board 12
        res = recon.solve(_readings(patch, [(1.5, k)]))
        assert res.in_contact and len(res.contacts) == 1
        assert res.total_force == pytest.approx(1.5, rel=0.3)
        assert np.linalg.norm(np.asarray(res.cop) - xy[k]) < 1.5e-3


def test_forearm_tells_two_presses_apart(forearm_bundle):
    patch = load_layout(ICUB / "left_forearm_V2.yaml").patches[0]
    xy = patch.taxel_xy()
    recon = Reconstructor.from_bundle(forearm_bundle)
    # Two taxels of board 13, 20-30 mm apart: two spheres at 2 and 1.2 N.
    a = 40
    d = np.linalg.norm(xy - xy[a], axis=1)
    b = int(np.flatnonzero((d > 20e-3) & (d < 30e-3) & (np.arange(len(xy)) < 160))[0])
    res = recon.solve(_readings(patch, [(2.0, a), (1.2, b)], seed=1))
    found = sorted(res.contacts, key=lambda c: -c.force)
    assert len(found) == 2
    for c, (f, k) in zip(found, [(2.0, a), (1.2, b)], strict=True):
        assert np.linalg.norm(np.asarray(c.center) - xy[k]) < 2.5e-3
        assert c.force == pytest.approx(f, rel=0.4)


@pytest.mark.ros
@pytest.mark.slow
def test_bringup_simulates_an_imported_layout(ros_context, tmp_path):
    """simulator → CAN → driver → reconstruction in one process on the hand's palm layout."""
    from tactile_contact.ros.bringup import GraphConfig, running_graph
    from tactile_contact.ros.demo import Observed, match, observer_node

    layout = ICUB / "left_hand_V2_1.yaml"
    build_layout(layout, tmp_path, jobs=1)
    seen = Observed()
    config = GraphConfig(
        layout=str(layout),
        bundles_dir=str(tmp_path),
        channel=f"test_icub_{time.monotonic_ns()}",
        scenario="press",
        reconstruction={"queue_depth": 100},
        simulator={
            "period_ms": 50,
            "cycle_s": 3.0,
            "loop": False,
            "noise_cdc": 0.6,
            "rest_spread_cdc": 2.0,
            "start_delay_s": 1.0,
            "force_n": 2.0,
            "indenter_radius_m": 0.006,
        },
    )
    observer = observer_node(ros_context, "left_hand", seen)
    with running_graph(config, ros_context, extra_nodes=(observer,)) as executor:
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
    observer.destroy_node()
    assert seen.taxels and seen.contact
    report = match(seen, tolerance=0.025)
    loaded = report.force_true >= 1.0
    assert loaded.sum() >= 10, "the press must be seen"
    err = np.abs(report.force_est[loaded] / report.force_true[loaded] - 1.0)
    assert np.median(err) < 0.3
    cop = np.linalg.norm(report.cop_est[loaded] - report.cop_true[loaded], axis=1)
    assert np.median(cop) < 2e-3
