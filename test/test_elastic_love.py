"""Love cell kernels against scipy quadrature of the point-force kernel, Johnson and Hertz."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from tactile_contact.model.elastic import (
    boussinesq_effective,
    boussinesq_uz,
    love_effective,
    love_ux,
    love_uy,
    love_uz,
    love_uz_effective,
    muscari_self,
)

# dblquad is asked for 1e-13 and sometimes reports round-off at that level; agreement is
# asserted at 1e-10, so the warning carries no information here.
pytestmark = pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")

E = 2.1e5
A, B = 1.0e-3, 0.6e-3
H = 2.0e-3


def _kz(nu, z):
    c = (1 + nu) / (2 * np.pi * E)

    def f(dx, dy):
        rho = np.sqrt(dx * dx + dy * dy + z * z)
        return c * (2 * (1 - nu) / rho + z * z / rho**3)

    return f


def _kx(nu, z):
    c = (1 + nu) / (2 * np.pi * E)

    def f(dx, dy):
        rho = np.sqrt(dx * dx + dy * dy + z * z)
        return c * dx * (z / rho**3 - (1 - 2 * nu) / (rho * (rho + z)))

    return f


def _keff(nu, h):
    # Independent of the library: the plain difference u(0) − u(h) of the point kernel, used
    # only within a few h of the load where the subtraction costs < 3 digits.
    fz0, fzh = _kz(nu, 0.0), _kz(nu, h)
    return lambda dx, dy: fz0(dx, dy) - fzh(dx, dy)


def quad_cell(kernel, x, y, a=A, b=B):
    """∫∫ kernel(x − ξ, y − η) over the cell, split at (x, y) so singularities sit at corners."""
    xs = sorted({-a, a, *([x] if -a < x < a else [])})
    ys = sorted({-b, b, *([y] if -b < y < b else [])})
    total = 0.0
    for x0, x1 in itertools.pairwise(xs):
        for y0, y1 in itertools.pairwise(ys):
            val, _ = integrate.dblquad(
                lambda eta, xi: kernel(x - xi, y - eta), x0, x1, y0, y1, epsabs=0, epsrel=1e-13
            )
            total += val
    return total


# Offsets (x, y) [m] inside, on edges, at corners, near and far from the 2 mm × 1.2 mm cell.
OFFSETS = [
    (0.0, 0.0),
    (0.3e-3, -0.1e-3),
    (A, 0.0),
    (A, B),
    (-A, 0.2e-3),
    (0.1e-3, -B),
    (1.7e-3, 0.9e-3),
    (4e-3, -2.5e-3),
    (0.02, 0.011),
    (0.04, -0.01),
    (0.3, 0.2),
]
DEPTHS = [0.0, 1e-5, 0.4e-3, 2e-3, 1e-2]


@pytest.mark.parametrize("nu", [0.5, 0.3])
@pytest.mark.parametrize("z", DEPTHS)
def test_love_uz_matches_quadrature(nu, z):
    for x, y in OFFSETS:
        ref = quad_cell(_kz(nu, z), x, y)
        got = love_uz(x, y, z, A, B, E, nu)
        assert got == pytest.approx(ref, rel=1e-10, abs=0), (x, y, z)


@pytest.mark.parametrize("nu", [0.5, 0.25])
@pytest.mark.parametrize("z", [0.0, 0.4e-3, 3e-3])
def test_love_ux_uy_match_quadrature(nu, z):
    kx = _kx(nu, z)

    def ky(dx, dy):
        return kx(dy, dx)

    for x, y in OFFSETS[1:]:
        scale = abs(quad_cell(_kz(nu, z), x, y))  # u_x vanishes on axes: compare to |u_z|
        ref_x = quad_cell(kx, x, y)
        ref_y = quad_cell(ky, x, y)
        assert love_ux(x, y, z, A, B, E, nu) == pytest.approx(ref_x, rel=1e-10, abs=1e-12 * scale)
        assert love_uy(x, y, z, A, B, E, nu) == pytest.approx(ref_y, rel=1e-10, abs=1e-12 * scale)


def test_love_ux_points_towards_the_load():
    # ν < 0.5: surface material moves towards the loaded cell (Johnson §3.4).
    assert love_ux(3e-3, 0.0, 0.0, A, B, E, 0.3) < 0 < love_ux(-3e-3, 0.0, 0.0, A, B, E, 0.3)
    assert love_uy(0.0, 3e-3, 0.0, A, B, E, 0.3) < 0


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
def test_love_effective_matches_quadrature_near(nu):
    for x, y in OFFSETS[:8]:
        ref = quad_cell(_keff(nu, H), x, y)
        scale = quad_cell(_kz(nu, 0.0), x, y)
        got = love_effective(x, y, A, B, H, E, nu)
        assert got == pytest.approx(ref, rel=1e-10, abs=1e-12 * scale), (x, y)


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
@pytest.mark.parametrize("h", [H, 0.05e-3])
@pytest.mark.parametrize("ratio", [3.0, 20.0, 90.0, 180.0, 250.0, 1e3, 1e5])
@pytest.mark.parametrize("angle", [0.0, 0.5, np.pi / 2])
def test_love_effective_far_field_relative_accuracy(nu, h, ratio, angle):
    # Far away the effective kernel is ~1e-6 of u(0) (less for small ν, where its 1/r³ parts
    # cancel); the reference integrates the point kernel, rewritten by hand without that
    # cancellation, by dblquad: [h²(2ρ+r)/(ρ²(r+ρ)) − 2ν]·h²/(rρ(r+ρ)).
    x, y = ratio * A * np.cos(angle), ratio * A * np.sin(angle)
    c = (1 + nu) / (2 * np.pi * E)

    def keff(dx, dy):
        r = np.hypot(dx, dy)
        rho = np.sqrt(r * r + h * h)
        base = h * h / (r * rho * (r + rho))
        return c * base * (h * h * (2 * rho + r) / (rho * rho * (r + rho)) - 2 * nu)

    ref = quad_cell(keff, x, y)
    assert love_effective(x, y, A, B, h, E, nu) == pytest.approx(ref, rel=1e-10, abs=0)


@pytest.mark.parametrize("nu", [0.5, 0.15])
@pytest.mark.parametrize("ratio", [4.0, 60.0, 80.0, 150.0])
@pytest.mark.parametrize("angle", [0.3, 1.2, 4.55])
def test_love_effective_elongated_cell(nu, ratio, angle):
    # A 7.8 mm × 0.06 mm strip: its corner sum cancels like r²/(ab), not r²/max(a, b)² (a
    # quadrature switch based on max(a, b) alone erred by up to 5e-10 on these cases).
    a, b, h = 3.9e-3, 0.03e-3, 4.8e-3
    x, y = ratio * a * np.cos(angle), ratio * a * np.sin(angle)
    c = (1 + nu) / (2 * np.pi * E)

    def keff(dx, dy):
        r = np.hypot(dx, dy)
        rho = np.sqrt(r * r + h * h)
        base = h * h / (r * rho * (r + rho))
        return c * base * (h * h * (2 * rho + r) / (rho * rho * (r + rho)) - 2 * nu)

    ref = quad_cell(keff, x, y, a, b)
    assert love_effective(x, y, a, b, h, E, nu) == pytest.approx(ref, rel=1e-10, abs=0)


@pytest.mark.parametrize("ratio", [25.0, 100.0, 1e3, 1e5])
def test_love_uz_and_ux_far_field(ratio):
    x, y = 0.8 * ratio * A, -0.6 * ratio * A
    for z in (0.0, 2e-3):
        assert love_uz(x, y, z, A, B, E, 0.3) == pytest.approx(
            quad_cell(_kz(0.3, z), x, y), rel=1e-10, abs=0
        )
        assert love_ux(x, y, z, A, B, E, 0.3) == pytest.approx(
            quad_cell(_kx(0.3, z), x, y), rel=1e-10, abs=0
        )


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
def test_johnson_square_centre(nu):
    a = 0.7e-3
    ref = (1 - nu**2) / (np.pi * E) * 8 * a * np.log(1 + np.sqrt(2))
    assert love_uz(0.0, 0.0, 0.0, a, a, E, nu) == pytest.approx(ref, rel=1e-14, abs=0)


def test_paper_example_centre_deflection():
    # DESIGN.md §2: p = 1e5 Pa on a 1 × 0.4 mm cell, h = 2 mm: below 2e-4 m, B-C shallower.
    p, a, b = 1e5, 0.5e-3, 0.2e-3
    love = p * love_uz_effective(0.0, 0.0, a, b, H, E, 0.5)
    assert 0 < love < 2e-4
    area = 4 * a * b
    for psi in ("exact", 0.25):
        bc = p * area * muscari_self(area, H, E, psi)  # the same load as one point force
        assert 0 < bc < love


def test_effective_changes_sign_like_the_point_kernel():
    # Beyond ≈ 0.79 h the layer bulges: negative coefficients are physics, not error.
    small = 0.05e-3
    assert love_effective(0.5 * H, 0.0, small, small, H, E, 0.5) > 0
    assert love_effective(0.9 * H, 0.0, small, small, H, E, 0.5) < 0


def test_effective_consistent_with_two_depths():
    for x, y in OFFSETS[:9]:
        top, bottom = love_uz(x, y, 0.0, A, B, E, 0.4), love_uz(x, y, H, A, B, E, 0.4)
        # Far out the two depths cancel to 3 digits: the reference's own error scales with
        # the terms, not with their difference.
        tol = 1e-11 * max(abs(top), abs(bottom))
        assert love_effective(x, y, A, B, H, E, 0.4) == pytest.approx(top - bottom, abs=tol)


def test_hertz_pressure_reproduces_hertz_deflection():
    # p = p0·√(1 − r²/c²) sampled at cell centres of a fine grid (piecewise constant). The
    # sampling error is O(pitch^1.5) at the contact edge, where √ is not smooth; with 81 cells
    # across the contact it is below 2e-3 of the centre deflection, and it halves on refining.
    c, p0, nu = 1e-3, 2e4, 0.5
    e_star = E / (1 - nu**2)
    errs = []
    for n in (41, 81):
        pitch = 2 * c / n
        g = (np.arange(n) - (n - 1) / 2) * pitch
        gx, gy = np.meshgrid(g, g, indexing="ij")
        p = p0 * np.sqrt(np.clip(1 - (gx**2 + gy**2) / c**2, 0, None))
        pts = np.array([[0, 0], [0.3e-3, 0.1e-3], [0.6e-3, -0.2e-3], [0, 0.85e-3]])
        u = np.array(
            [np.sum(p * love_uz(x - gx, y - gy, 0.0, pitch / 2, pitch / 2, E, nu)) for x, y in pts]
        )
        r2 = np.sum(pts**2, axis=1)
        ref = np.pi * p0 * (2 * c**2 - r2) / (4 * c * e_star)
        errs.append(np.max(np.abs(u - ref)) / ref[0])
    assert errs[1] < 2e-3
    assert errs[1] < 0.6 * errs[0]


@settings(max_examples=60)
@given(
    angle=st.floats(0, 2 * np.pi),
    log_ratio=st.floats(1.5, 4.0),
    nu=st.one_of(st.floats(0.2, 0.5), st.just(0.5)),
)
def test_far_field_decays_like_a_point_force(angle, log_ratio, nu):
    # A cell far away acts like its total force at the centre; the first correction is the
    # cell's second moment, relative size ~(s/d)² (times |f''|d²/|f| ≲ 20 for these kernels).
    d = 10**log_ratio * A
    x, y = d * np.cos(angle), d * np.sin(angle)
    area = 4 * A * B
    assert love_uz(x, y, 0.0, A, B, E, nu) == pytest.approx(
        boussinesq_uz(x, y, 0.0, E, nu) * area, rel=3 * (A / d) ** 2, abs=0
    )
    assert love_effective(x, y, A, B, H, E, nu) == pytest.approx(
        boussinesq_effective(x, y, H, E, nu) * area, rel=20 * (A / d) ** 2, abs=0
    )


def test_validation():
    with pytest.raises(ValueError, match="poisson"):
        love_uz(0, 0, 0, A, B, E, 0.51)
    with pytest.raises(ValueError, match="young"):
        love_uz(0, 0, 0, A, B, -1.0, 0.5)
    with pytest.raises(ValueError, match="depth"):
        love_uz(0, 0, -1e-3, A, B, E, 0.5)
    with pytest.raises(ValueError, match="half-size"):
        love_uz(0, 0, 0, 0.0, B, E, 0.5)
    with pytest.raises(ValueError, match="finite"):
        love_uz(np.nan, 0, 0, A, B, E, 0.5)
    with pytest.raises(ValueError, match="thickness"):
        love_effective(0, 0, A, B, 0.0, E, 0.5)
    with pytest.raises(ValueError, match="component"):
        love_effective(0, 0, A, B, H, E, 0.5, "w")


coord = st.one_of(
    st.floats(-1e3, 1e3),
    st.sampled_from([0.0, 1e-12, -1e-12, 1e3, -1e3]),
)
size = st.one_of(st.floats(1e-6, 1.0), st.sampled_from([1e-12, 1e-3]))
nus = st.one_of(st.floats(-0.99, 0.5), st.just(0.5))


@settings(max_examples=150)
@given(x=coord, y=coord, z=st.one_of(st.just(0.0), st.floats(0, 1e3)), a=size, b=size, nu=nus)
def test_finite_everywhere(x, y, z, a, b, nu):
    for fn in (love_uz, love_ux, love_uy):
        assert np.isfinite(fn(x, y, z, a, b, E, nu))
    # points on edges and corners of the same cell
    for px, py in ((a, y), (x, b), (a, b), (-a, -b), (0.0, 0.0)):
        assert np.isfinite(love_uz(px, py, z, a, b, E, nu))
        assert np.isfinite(love_effective(px, py, a, b, max(z, 1e-6), E, nu))
    assert np.isfinite(love_effective(x, y, a, b, max(z, 1e-9), E, nu))


@settings(max_examples=60)
@given(
    x=st.floats(-0.05, 0.05),
    y=st.floats(-0.05, 0.05),
    a=st.floats(1e-4, 5e-3),
    b=st.floats(1e-4, 5e-3),
    nu=nus,
)
def test_superposition_four_subcells(x, y, a, b, nu):
    whole = love_uz(x, y, 0.0, a, b, E, nu)
    parts = sum(
        love_uz(x - sx * a / 2, y - sy * b / 2, 0.0, a / 2, b / 2, E, nu)
        for sx in (-1, 1)
        for sy in (-1, 1)
    )
    assert parts == pytest.approx(whole, rel=1e-10, abs=0)
    whole_eff = love_effective(x, y, a, b, H, E, nu)
    parts_eff = sum(
        love_effective(x - sx * a / 2, y - sy * b / 2, a / 2, b / 2, H, E, nu)
        for sx in (-1, 1)
        for sy in (-1, 1)
    )
    # the effective kernel crosses zero: compare against the size of u(0)
    assert parts_eff == pytest.approx(whole_eff, rel=1e-10, abs=1e-11 * whole)


@settings(max_examples=60)
@given(x=st.floats(-0.02, 0.02), y=st.floats(-0.02, 0.02), nu=nus)
def test_symmetry_in_both_axes(x, y, nu):
    v = love_effective(x, y, A, B, H, E, nu)
    for sx, sy in ((-1, 1), (1, -1), (-1, -1)):
        assert love_effective(sx * x, sy * y, A, B, H, E, nu) == pytest.approx(v, rel=1e-12, abs=0)
    assert love_ux(-x, y, 0.0, A, B, E, nu) == pytest.approx(
        -love_ux(x, y, 0.0, A, B, E, nu), rel=1e-12, abs=1e-30
    )
