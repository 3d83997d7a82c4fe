"""Boussinesq–Cerruti point kernels: elasticity equations, Johnson's surface formulas,
high-precision references for the effective (u(0) − u(h)) forms, Muscari self term."""

from __future__ import annotations

import itertools
from decimal import Decimal, getcontext

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import integrate

from tactile_contact.model.elastic import (
    boussinesq_block,
    boussinesq_block_effective,
    boussinesq_effective,
    boussinesq_uz,
    min_magnitude,
    muscari_psi,
    muscari_self,
    shear_self,
)

E, H = 2.1e5, 2e-3


def test_uz_closed_form_via_shear_modulus():
    # Johnson (3.19): u_z = F/(4πG)·[2(1−ν)/ρ + z²/ρ³], G = E/(2(1+ν)).
    nu, x, y, z = 0.3, 1e-3, -2e-3, 0.5e-3
    g = E / (2 * (1 + nu))
    rho = np.sqrt(x * x + y * y + z * z)
    ref = (2 * (1 - nu) / rho + z * z / rho**3) / (4 * np.pi * g)
    assert boussinesq_uz(x, y, z, E, nu) == pytest.approx(ref, rel=1e-14, abs=0)
    assert boussinesq_block(x, y, z, E, nu)[2, 2] == pytest.approx(ref, rel=1e-14, abs=0)


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
def test_block_on_the_surface_matches_johnson(nu):
    # Johnson (3.20) and (3.86) at z = 0, r = |(x, y)|.
    x, y = 1.5e-3, -0.7e-3
    r = np.hypot(x, y)
    g = E / (2 * (1 + nu))
    blk = boussinesq_block(x, y, 0.0, E, nu)
    assert blk[2, 2] == pytest.approx((1 - nu) / (2 * np.pi * g * r), rel=1e-14, abs=0)
    ref_rz = -(1 - 2 * nu) / (4 * np.pi * g * r)  # u_r under a normal force (inwards)
    assert blk[0, 2] == pytest.approx(ref_rz * x / r, rel=1e-14, abs=1e-30)
    assert blk[1, 2] == pytest.approx(ref_rz * y / r, rel=1e-14, abs=1e-30)
    assert blk[0, 0] == pytest.approx(
        ((1 - nu) + nu * x * x / r**2) / (2 * np.pi * g * r), rel=1e-14, abs=0
    )
    assert blk[0, 1] == pytest.approx(nu * x * y / r**2 / (2 * np.pi * g * r), rel=1e-14, abs=0)
    assert blk[2, 0] == pytest.approx(
        (1 - 2 * nu) * x / (4 * np.pi * g * r * r), rel=1e-14, abs=1e-30
    )


def test_block_reciprocity_on_the_surface():
    # Betti: G_ij(p ← q) = G_ji(q ← p) for two surface points.
    x, y = 1.2e-3, 0.4e-3
    fwd = boussinesq_block(x, y, 0.0, E, 0.3)
    back = boussinesq_block(-x, -y, 0.0, E, 0.3)
    np.testing.assert_allclose(fwd, back.T, rtol=1e-14, atol=0)


@pytest.mark.parametrize("nu", [0.5, 0.3])
def test_block_satisfies_navier(nu):
    # Displacements from any force satisfy (1−2ν)∇²u + ∇(∇·u) = 0 inside the body (checked by
    # central differences, relative to the size of the individual terms).
    p = np.array([0.8e-3, -0.5e-3, 0.6e-3])
    step = 2e-6  # truncation ~(step/|p|)² ≈ 4e-6, round-off ~1e-16·u/step² ≪ that

    def u(q):
        return boussinesq_block(q[0], q[1], q[2], E, nu)

    lap = np.zeros((3, 3))
    grad_div = np.zeros((3, 3))
    for i in range(3):
        ei = np.eye(3)[i] * step
        lap += (u(p + ei) - 2 * u(p) + u(p - ei)) / step**2
    for i, k in itertools.product(range(3), range(3)):
        ei, ek = np.eye(3)[i] * step, np.eye(3)[k] * step
        d2 = (u(p + ei + ek) - u(p + ei - ek) - u(p - ei + ek) + u(p - ei - ek)) / (4 * step**2)
        grad_div[i] += d2[k]
    residual = (1 - 2 * nu) * lap + grad_div
    assert np.max(np.abs(residual)) < 2e-5 * np.max(np.abs(lap))


getcontext().prec = 60


def _dec_eff_zz(r: float, h: float, nu: float) -> float:
    """u_z(0) − u_z(h) per unit force from the plain formula in 60-digit decimals."""
    r_, h_, nu_, e_ = Decimal(r), Decimal(h), Decimal(nu), Decimal(E)
    rho = (r_ * r_ + h_ * h_).sqrt()
    c = (1 + nu_) / (2 * Decimal(np.pi) * e_)
    u0 = c * 2 * (1 - nu_) / r_
    uh = c * (2 * (1 - nu_) / rho + h_ * h_ / rho**3)
    return float(u0 - uh)


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
def test_effective_zz_against_high_precision(nu):
    for r in (1e-12, 1e-6, 1e-3, 1.5717e-3, 5e-3, 0.1, 10.0, 1e3):
        ref = _dec_eff_zz(r, H, nu)
        assert boussinesq_effective(r, 0.0, H, E, nu) == pytest.approx(ref, rel=1e-13, abs=0)


@pytest.mark.parametrize("nu", [0.5, 0.3])
def test_effective_block_equals_difference_of_blocks(nu):
    # Near the load the plain difference loses < 2 digits; far away the stable form must
    # agree with 60-digit arithmetic (zz) and keep its relative accuracy.
    for x, y in ((1e-3, 0.5e-3), (-3e-3, 2e-3), (0.2e-3, -4e-3)):
        direct = boussinesq_block(x, y, 0.0, E, nu) - boussinesq_block(x, y, H, E, nu)
        np.testing.assert_allclose(
            boussinesq_block_effective(x, y, H, E, nu),
            direct,
            rtol=1e-12,
            atol=1e-14 * np.abs(direct).max(),
        )


def test_effective_sign_change_at_079h():
    # ν = 0.5: 1/(rρ(r+ρ)) = 1/ρ³ ⇔ t²(1+t²) = 1 with t = r/h, t² = (√5 − 1)/2.
    t = np.sqrt((np.sqrt(5) - 1) / 2)
    assert t == pytest.approx(0.786, abs=1e-3)
    assert boussinesq_effective(0.99 * t * H, 0, H, E, 0.5) > 0
    assert boussinesq_effective(1.01 * t * H, 0, H, E, 0.5) < 0


def test_singular_point_raises():
    with pytest.raises(ValueError, match="singular"):
        boussinesq_uz(0.0, 0.0, 0.0, E, 0.5)
    with pytest.raises(ValueError, match="singular"):
        boussinesq_effective([1e-3, 0.0], 0.0, H, E, 0.5)
    with pytest.raises(ValueError, match="singular"):
        boussinesq_block(0.0, 0.0, 0.0, E, 0.3)
    assert np.isfinite(boussinesq_uz(0.0, 0.0, 1e-3, E, 0.5))  # below the load is fine


def test_muscari_self_term():
    area = 1e-6
    z0 = np.sqrt(3 * area / (2 * np.pi))
    x = H / z0
    ref = 9 / (2 * np.pi * E) * (0.2431 * x - 0.1814) / x / z0
    assert muscari_self(area, H, E) == pytest.approx(ref, rel=1e-15, abs=0)
    assert muscari_self(area, H, E, psi=0.25) == pytest.approx(
        9 / (2 * np.pi * E) * 0.25 / z0, rel=1e-15, abs=0
    )
    assert muscari_psi(2.0) == pytest.approx((0.2431 * 2 - 0.1814) / 2, rel=1e-15, abs=0)
    with pytest.raises(ValueError, match="psi"):
        muscari_self(area, H, E, psi="approx")
    with pytest.raises(ValueError, match="area"):
        muscari_self(-1.0, H, E)


def test_min_magnitude_rule():
    exact = np.array([np.inf, 3.0, -1.0, 5.0])
    approx = np.array([2.0, 2.0, 2.0, -4.0])
    np.testing.assert_array_equal(min_magnitude(exact, approx), [2.0, 2.0, -1.0, -4.0])


@pytest.mark.parametrize("nu", [0.5, 0.3])
def test_shear_self_matches_quadrature(nu):
    # Centre of a square of side 2c under unit total shear force: ∫∫ [G_xx(0) − G_xx(h)]/A.
    area = 1.2e-6
    c = np.sqrt(area) / 2
    k = (1 + nu) / (2 * np.pi * E)

    def gxx(x, y, z):
        rho = np.sqrt(x * x + y * y + z * z)
        return k * (
            1 / rho
            + x * x / rho**3
            + (1 - 2 * nu) * (1 / (rho + z) - x * x / (rho * (rho + z) ** 2))
        )

    total = 0.0
    for z, sign in ((0.0, 1.0), (H, -1.0)):
        val, _ = integrate.dblquad(
            lambda y, x, z=z: gxx(x, y, z), 0, c, 0, c, epsabs=0, epsrel=1e-12
        )
        total += sign * 4 * val
    assert shear_self(area, H, E, nu) == pytest.approx(total / area, rel=1e-10, abs=0)


def test_material_validation():
    for bad in (0.5000001, -1.0, np.nan):
        with pytest.raises(ValueError, match="poisson"):
            boussinesq_uz(1e-3, 0, 0, E, bad)
    with pytest.raises(ValueError, match="young"):
        boussinesq_uz(1e-3, 0, 0, 0.0, 0.3)
    with pytest.raises(ValueError, match="thickness"):
        boussinesq_effective(1e-3, 0, -H, E, 0.3)
    with pytest.raises(TypeError, match="numeric"):
        boussinesq_uz("a", 0, 0, E, 0.3)


coord = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([1e-12, -1e-12, 1e3]))


@given(x=coord, y=coord, h=st.floats(1e-6, 1.0), nu=st.one_of(st.floats(-0.99, 0.5), st.just(0.5)))
def test_effective_kernels_finite_away_from_the_load(x, y, h, nu):
    # Finite values or, within 1e-100 m of the load (where 1/r³ overflows), a ValueError.
    try:
        values = [
            boussinesq_effective(x, y, h, E, nu),
            boussinesq_block_effective(x, y, h, E, nu),
            boussinesq_block(x, y, h, E, nu),
        ]
    except ValueError as exc:
        assert "singular" in str(exc)
        assert np.hypot(x, y) < 1e-100
        return
    assert all(np.all(np.isfinite(v)) for v in values)
