"""Fine forward simulation: DESIGN.md's measured facts, linearity, convergence, an independent
point-force check, and the exact-capacitance taxel model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_contact.model.elastic import boussinesq_effective
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import load_layout
from tactile_contact.model.sensor import delta_c_to_compression

ROOT = Path(__file__).resolve().parents[1]
XY = load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0].taxel_xy()
MOD = XY[48:60]  # the module at the patch origin
E, NU, H = 2.1e5, 0.5, 2e-3


@pytest.fixture(scope="module")
def model() -> ForwardModel:
    return ForwardModel(XY, H, E, NU)


def test_design_facts_negative_readings_between_taxels(model):
    # DESIGN.md §2: 3 mm punch, 1 N, midway between three taxels → about −28 µm at each, no
    # positive reading anywhere; 12 mm sphere, 1 N, between two → about +2 µm at the two and
    # −16 µm at the next.
    c3 = (MOD[3] + MOD[7] + MOD[11]) / 3
    d = model.compression(FlatPunch(1.5e-3), 1.0, c3)
    np.testing.assert_allclose(d[[48 + 3, 48 + 7, 48 + 11]], -28e-6, atol=2e-6)
    assert d.max() < 0
    c2 = (MOD[7] + MOD[11]) / 2
    d = model.compression(HertzSphere(6e-3), 1.0, c2)
    order = np.argsort(np.hypot(*(XY - c2).T))
    np.testing.assert_allclose(d[order[:2]], 2.5e-6, atol=1.5e-6)
    assert d[order[2]] == pytest.approx(-16e-6, abs=1.5e-6)


def test_linear_in_force_for_a_punch(model):
    a = model.compression(FlatPunch(3e-3), 0.5, MOD[3])
    b = model.compression(FlatPunch(3e-3), 2.0, MOD[3])
    np.testing.assert_allclose(b, 4 * a, rtol=1e-10, atol=1e-15)


def test_fields_pressure_integrates_to_force(model):
    f = model.fields(HertzSphere(3e-3), 1.5, MOD[0])
    area = 4 * f.half_sizes[:, 0] * f.half_sizes[:, 1]
    assert (f.pressure * area).sum() == pytest.approx(1.5, rel=1e-9)
    assert f.contact_area == pytest.approx(np.pi * f.contact_radius**2)
    assert f.centers.shape[0] > 300  # "much finer than the reconstruction grid"


def test_far_taxels_match_point_forces():
    # Independent check: beyond a few h, a cell acts as a point force p·A (Boussinesq-Cerruti).
    fm = ForwardModel(XY, H, E, NU, fine_cell=2.5e-4)
    f = fm.fields(HertzSphere(6e-3), 2.0, MOD[3])
    r = np.hypot(*(XY - MOD[3]).T)
    far = r > 8e-3
    force = f.pressure * 4 * f.half_sizes[:, 0] * f.half_sizes[:, 1]
    dx = XY[far, None, 0] - f.centers[None, :, 0]
    dy = XY[far, None, 1] - f.centers[None, :, 1]
    ref = boussinesq_effective(dx, dy, H, E, NU) @ force
    np.testing.assert_allclose(f.compression[far], ref, rtol=0.02, atol=2e-8)


def test_converged_in_the_fine_cell():
    a = ForwardModel(XY[40:60], H, E, NU, fine_cell=2e-4).compression(FlatPunch(1.5e-3), 1, MOD[3])
    b = ForwardModel(XY[40:60], H, E, NU, fine_cell=1e-4).compression(FlatPunch(1.5e-3), 1, MOD[3])
    np.testing.assert_allclose(a, b, rtol=0.01, atol=0.2e-6)


def test_delta_c_is_the_exact_plate_capacitance():
    fm = ForwardModel(XY, H, E, NU, taxel_radius=2e-3)
    ind, c = HertzSphere(6e-3), MOD[3]
    mean = fm.compression(ind, 1.0, c)
    dc = fm.delta_c(ind, 1.0, c, 4.37)
    back = delta_c_to_compression(dc, H, 4.37, np.pi * 4e-6)
    # ΔC integrates 1/(h − δ): the plate formula applied to it returns at least the mean δ
    # (Jensen), and equals it where δ is small.
    small = np.abs(mean) < 2e-6
    np.testing.assert_allclose(back[small], mean[small], atol=1e-9)
    assert np.all(back >= mean - 1e-12)
    assert back.max() == pytest.approx(mean.max(), rel=0.1)


def test_validation():
    with pytest.raises(ValueError, match="points_xy"):
        ForwardModel(np.zeros((3,)), H, E, NU)
    with pytest.raises(ValueError, match="poisson"):
        ForwardModel(XY, H, E, 0.7)
    with pytest.raises(ValueError, match="taxel_radius > 0"):
        ForwardModel(XY, H, E, NU).delta_c(FlatPunch(1e-3), 1.0, (0, 0), 4.37)
    zero = ForwardModel(XY, H, E, NU).compression(FlatPunch(1e-3), 0.0, (0, 0))
    assert np.all(zero == 0)
