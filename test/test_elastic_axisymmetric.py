"""Round loads on the Love layer without cells (tactile_contact.model.elastic.axisymmetric),
against independent references: the half-space closed forms (Johnson, Contact Mechanics,
§3.8 flat punch and §3.9 Hertz pressure), the cell model converging to it, the point kernel far
away, and properties (finite, linear, continuous across the edge)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.model.elastic.axisymmetric import round_response, round_responses
from tactile_contact.model.elastic.boussinesq import boussinesq_effective
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere

E, NU, H = 2.1e5, 0.5, 2.0e-3


def half_space(profile: str, a: float, r: np.ndarray, nu: float) -> np.ndarray:
    """Surface displacement of a half-space under a unit-force round load [m/N]."""
    rr = np.maximum(r, 1e-300)
    out = np.minimum(a / rr, 1.0)
    c = (1.0 - nu * nu) / E
    if profile == "punch":
        return np.where(r <= a, c / (2.0 * a), c / (math.pi * a) * np.arcsin(out))
    p0 = 3.0 / (2.0 * math.pi * a * a)
    inside = c * math.pi * p0 / (4.0 * a) * (2.0 * a * a - r * r)
    outside = (
        c
        * p0
        / (2.0 * a)
        * ((2 * a * a - r * r) * np.arcsin(out) + r * a * np.sqrt(np.maximum(1 - out**2, 0)))
    )
    return np.where(r <= a, inside, outside)


@pytest.mark.parametrize("profile", ["punch", "hertz"])
@pytest.mark.parametrize("a", [0.4e-3, 6.0e-3])
@pytest.mark.parametrize("nu", [0.3, 0.5])
def test_thick_layer_is_the_half_space(profile: str, a: float, nu: float) -> None:
    # u_z(h) vanishes as h grows: the layer's compression tends to the half-space's surface
    # displacement, in closed form, across the edge (r = a) where the punch's pressure is singular.
    r = a * np.array([0.0, 0.3, 0.9, 0.999, 1.0, 1.001, 1.1, 2.0, 10.0])
    got = round_response(profile, a, r, 1.0e6, E, nu)
    np.testing.assert_allclose(got, half_space(profile, a, r, nu), rtol=1e-6)


@pytest.mark.parametrize(
    ("indenter", "profile", "cells"),
    [(FlatPunch(6e-3), "punch", (1e-4, 5e-5, 2.5e-5)), (HertzSphere(3e-3), "hertz", (1e-4, 5e-5))],
)
def test_cells_converge_to_it(indenter, profile: str, cells: tuple[float, ...]) -> None:
    # The cell model (exact cell-averaged pressure, Love's rectangles) approaches the continuum
    # as its cells shrink, first order at the punch's edge.
    a = indenter.contact_radius(1.5, E, NU)
    r = np.array([0.0, 1.0, 0.9 * a, 0.99 * a, 1.01 * a, 1.1 * a, 2 * a]) * 1.0
    r[1] = 0.5 * a
    exact = 1.5 * round_response(profile, a, r, H, E, NU)
    errors = []
    for cell in cells:
        pts = np.column_stack((r, np.zeros_like(r)))
        got = ForwardModel(pts, H, E, NU, fine_cell=cell).compression(indenter, 1.5, (0, 0))
        errors.append(np.max(np.abs(got - exact)) / exact.max())
    assert all(b < 0.7 * e for e, b in itertools.pairwise(errors)), errors
    assert errors[-1] < (0.02 if profile == "punch" else 1e-3), errors


def test_far_away_is_the_point_kernel() -> None:
    # Away from the load it acts as one point force; what is left falls off as a² (the load's
    # second moment over the kernel's curvature, on the scale of the layer).
    r = np.array([8e-3, 12e-3, 20e-3])
    point = boussinesq_effective(r, 0 * r, H, E, NU)
    for profile in ("punch", "hertz"):
        e1, e2 = (
            np.max(np.abs(round_response(profile, a, r, H, E, NU) / point - 1))
            for a in (0.4e-3, 0.2e-3)
        )
        assert 3.0 < e1 / e2 < 5.0 and e2 < 2e-3, (e1, e2)


def test_many_profiles_agree_with_one_at_a_time() -> None:
    r = np.linspace(0, 20e-3, 41)
    profiles = [("punch", 1e-3), ("hertz", 2.5e-3), ("punch", 6e-3)]
    many = round_responses(profiles, r, H, E, NU)
    for row, (name, a) in zip(many, profiles, strict=True):
        np.testing.assert_allclose(row, round_response(name, a, r, H, E, NU), rtol=1e-7)


@settings(max_examples=40, deadline=None)
@given(
    a=st.floats(0.3e-3, 10e-3),
    h=st.floats(0.5e-3, 5e-3),
    nu=st.floats(0.0, 0.5),
    profile=st.sampled_from(["punch", "hertz"]),
)
def test_finite_and_continuous_across_the_edge(a: float, h: float, nu: float, profile: str) -> None:
    r = a * np.array([0.0, 0.5, 1 - 1e-10, 1.0, 1 + 1e-10, 3.0])  # √ε across the edge
    u = round_response(profile, a, r, h, E, nu)
    assert np.all(np.isfinite(u))
    assert u[0] > 0
    np.testing.assert_allclose(u[2:5], u[3], rtol=1e-3)


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match="profile"):
        round_response("cone", 1e-3, [0.0], H, E, NU)
    with pytest.raises(ValueError, match="distances"):
        round_response("punch", 1e-3, [np.nan], H, E, NU)
    with pytest.raises(ValueError, match="radius"):
        round_response("punch", 0.0, [0.0], H, E, NU)
