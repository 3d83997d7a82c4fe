"""Reference contact pressures: integrate to the force, match closed forms and quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import dblquad, quad

from tactile_contact.model.grids import Grid
from tactile_contact.model.indenters import FlatPunch, HertzSphere, effective_modulus

E, NU = 2.1e5, 0.5


def cells(cell, extent, offset=(0.0, 0.0)):
    g = Grid.covering([[-extent, -extent], [extent, extent]], cell, 0.0)
    return g.centers() + offset, g.half_sizes()


def test_hertz_contact_radius_and_peak():
    s = HertzSphere(6e-3)
    a = s.contact_radius(1.0, E, NU)
    assert a == pytest.approx((3 * 1.0 * 6e-3 / (4 * E / 0.75)) ** (1 / 3))
    assert s.pressure_at_radius(0.0, 1.0, E, NU) == pytest.approx(3 / (2 * math.pi * a * a))
    # p(r) integrates to F (radial quadrature)
    f = quad(lambda r: 2 * math.pi * r * s.pressure_at_radius(r, 1.0, E, NU), 0, a)[0]
    assert f == pytest.approx(1.0, rel=1e-8)
    # Johnson: centre deflection π p0 a / (2 E*) = a² / R
    assert s.surface_deflection(0.0, 1.0, E, NU) == pytest.approx(a * a / 6e-3, rel=1e-12)


def test_punch_profile_integrates_to_force():
    p = FlatPunch(1.5e-3)
    # substitute r = a sin t to remove the edge singularity
    f = quad(
        lambda t: (
            2
            * math.pi
            * 1.5e-3
            * math.sin(t)
            * 1.5e-3
            * math.cos(t)
            * p.pressure_at_radius(1.5e-3 * math.sin(t), 2.0, E, NU)
        ),
        0,
        math.pi / 2 - 1e-12,
    )[0]
    assert f == pytest.approx(2.0, rel=1e-6)
    assert p.pressure_at_radius(2e-3, 2.0, E, NU) == 0.0


@settings(max_examples=15)
@given(
    st.sampled_from(["hertz", "punch"]),
    st.floats(0.05, 5.0),
    st.floats(1e-4, 1e-3),
    st.floats(-1e-3, 1e-3),
    st.floats(-1e-3, 1e-3),
)
def test_cell_pressures_sum_to_force(kind, force, cell, ox, oy):
    ind = HertzSphere(4e-3) if kind == "hertz" else FlatPunch(2e-3)
    c, hs = cells(cell, 5e-3)
    p = ind.pressure_on_cells(c, hs, force, (ox, oy), E, NU)
    assert np.all(p >= 0)
    assert p.sum() * 4 * hs[0, 0] * hs[0, 1] == pytest.approx(force, rel=1e-10)


@pytest.mark.parametrize("ind", [HertzSphere(6e-3), FlatPunch(1.5e-3)], ids=["hertz", "punch"])
def test_cell_averages_match_quadrature(ind):
    a = ind.contact_radius(1.0, E, NU)
    h = 2e-4
    for cx, cy in [(0.0, 0.0), (0.3 * a, -0.2 * a), (0.0, 0.7 * a)]:  # cells inside the contact
        ref = dblquad(
            lambda y, x: ind.pressure_at_radius(math.hypot(x, y), 1.0, E, NU),
            cx - h,
            cx + h,
            cy - h,
            cy + h,
            epsabs=0,
            epsrel=1e-10,
        )[0] / (4 * h * h)
        got = ind.pressure_on_cells([[cx, cy]], [h, h], 1.0, (0, 0), E, NU)[0]
        assert got == pytest.approx(ref, rel=1e-6)


def test_punch_edge_cell_force_matches_ring_formula():
    # Force inside radius ρ: F (1 − √(1 − ρ²/a²)). Cells fully inside a 0.9a disc and those
    # reaching beyond a must bracket that value; fine cells make the bracket tight.
    a, force = 1.5e-3, 1.0
    c, hs = cells(2.5e-5, a * 1.05)
    p = FlatPunch(a).pressure_on_cells(c, hs, force, (0, 0), E, NU) * (4 * hs[:, 0] * hs[:, 1])
    r = np.hypot(*c.T)
    ring = force * (1 - math.sqrt(1 - 0.9**2))
    inner, outer = p[r + 1.8e-5 < 0.9 * a].sum(), p[r - 1.8e-5 < 0.9 * a].sum()
    assert inner <= ring <= outer and outer - inner < 0.06


def test_zero_force_and_validation():
    c, hs = cells(1e-3, 3e-3)
    assert np.all(HertzSphere(3e-3).pressure_on_cells(c, hs, 0.0, (0, 0), E, NU) == 0)
    with pytest.raises(ValueError, match="force must be finite and >= 0"):
        FlatPunch(1e-3).pressure_on_cells(c, hs, -1.0, (0, 0), E, NU)
    with pytest.raises(ValueError, match="center_xy"):
        FlatPunch(1e-3).pressure_on_cells(c, hs, 1.0, (0, 0, 0), E, NU)
    with pytest.raises(ValueError, match="radius"):
        HertzSphere(-1.0)
    with pytest.raises(ValueError, match="poisson"):
        effective_modulus(E, 0.6)
