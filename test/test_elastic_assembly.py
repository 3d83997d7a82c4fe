"""Influence matrices between arbitrary point sets: agreement with the elementwise kernels,
ContactMechanics' surface deflections, symmetry, the paper's self-term rule, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.model.elastic import (
    boussinesq_block_effective,
    boussinesq_block_matrix,
    boussinesq_effective,
    boussinesq_matrix,
    love_depth_matrix,
    love_effective,
    love_matrix,
    love_uz,
    muscari_self,
    shear_self,
)

E, H = 2.1e5, 2e-3


def grid(nx, ny, px, py, x0=0.0, y0=0.0):
    """Cell centres in the flattening order of the package (index = i·ny + j)."""
    gx, gy = np.meshgrid(x0 + np.arange(nx) * px, y0 + np.arange(ny) * py, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def _elementwise(points, centers, half, nu, component="z", h=H):
    dx = points[:, 0:1] - centers[None, :, 0]
    dy = points[:, 1:2] - centers[None, :, 1]
    return love_effective(dx, dy, half[..., 0], half[..., 1], h, E, nu, component)


@pytest.mark.parametrize("nu", [0.5, 0.3, 0.0])
def test_love_matrix_matches_elementwise_kernel(nu):
    rng = np.random.default_rng(1)
    centers = grid(9, 7, 1e-3, 0.8e-3)
    half = np.array([0.5e-3, 0.4e-3])
    # random points plus points exactly on cell centres, edges and corners (edge corrections)
    points = np.concatenate(
        [
            rng.uniform(-0.01, 0.02, (40, 2)),
            centers[::5],
            centers[::7] + half * [1, 0],
            centers[::6] + half,
            centers[::4] - half * [0, 1],
            [[0.3, -0.2], [5.0, 1.0]],  # far: quadrature branch
        ]
    )
    got = love_matrix(points, centers, half, H, E, nu)
    ref = _elementwise(points, centers, half, nu)
    scale = np.abs(ref).max(axis=1, keepdims=True)
    # both sides carry ~1e-11 (rounding of corner offsets, amplified by the corner sum)
    assert np.all(np.abs(got - ref) <= 1e-10 * np.abs(ref) + 1e-13 * scale)


def test_love_matrix_cells_of_different_sizes_and_chunks():
    rng = np.random.default_rng(2)
    centers = rng.uniform(0, 0.02, (30, 2))
    half = rng.uniform(0.2e-3, 2e-3, (30, 2))
    points = np.concatenate([rng.uniform(0, 0.02, (25, 2)), centers[:5]])
    ref = _elementwise(points, centers, half, 0.45)
    for chunk in (7, 10_000):
        got = love_matrix(points, centers, half, H, E, 0.45, chunk_elements=chunk)
        np.testing.assert_allclose(got, ref, rtol=1e-11, atol=1e-13 * np.abs(ref).max())


@pytest.mark.parametrize("component", ["x", "y"])
def test_love_matrix_lateral_components(component):
    centers = grid(4, 3, 1e-3, 1e-3)
    points = centers + np.array([0.2e-3, -0.3e-3])
    half = np.full((12, 2), 0.5e-3)
    got = love_matrix(points, centers, half, H, E, 0.3, component=component)
    np.testing.assert_array_equal(got, _elementwise(points, centers, half, 0.3, component))


def test_love_depth_matrix():
    centers = grid(3, 3, 1e-3, 1e-3)
    points = centers[:4] + 0.1e-3
    got = love_depth_matrix(points, centers, [0.5e-3, 0.5e-3], 1e-3, E, 0.5)
    dx = points[:, 0:1] - centers[None, :, 0]
    dy = points[:, 1:2] - centers[None, :, 1]
    np.testing.assert_array_equal(got, love_uz(dx, dy, 1e-3, 0.5e-3, 0.5e-3, E, 0.5))


@pytest.mark.parametrize("nu", [0.5, 0.3])
def test_surface_deflection_matches_contactmechanics(nu):
    # ContactMechanics' FreeFFTElasticHalfSpace integrates the same Love surface kernel in its
    # own (log-form) code: displacement = −(Love u_z at z = 0)·force/pixel area, with E' =
    # E/(1−ν²) as its modulus and the opposite sign convention.
    from ContactMechanics import FreeFFTElasticHalfSpace

    nx, ny, px, py = 12, 9, 0.7e-3, 0.5e-3
    rng = np.random.default_rng(3)
    pressure = rng.uniform(0, 2e4, (nx, ny))
    cm = FreeFFTElasticHalfSpace((nx, ny), E / (1 - nu**2), (nx * px, ny * py))
    ref = -cm.evaluate_disp(pressure * px * py)
    centers = grid(nx, ny, px, py)
    got = love_depth_matrix(centers, centers, [px / 2, py / 2], 0.0, E, nu) @ pressure.ravel()
    np.testing.assert_allclose(got, ref.ravel(), rtol=1e-10, atol=0)


@settings(max_examples=25)
@given(
    nx=st.integers(1, 6),
    ny=st.integers(1, 6),
    px=st.floats(1e-4, 5e-3),
    py=st.floats(1e-4, 5e-3),
    h=st.floats(1e-4, 1e-2),
    nu=st.one_of(st.floats(0.0, 0.5), st.just(0.5)),
)
def test_square_love_matrix_of_identical_cells_is_symmetric(nx, ny, px, py, h, nu):
    centers = grid(nx, ny, px, py, x0=0.013, y0=-0.004)
    m = love_matrix(centers, centers, [px / 2, py / 2], h, E, nu)
    assert np.all(np.isfinite(m))
    np.testing.assert_allclose(m, m.T, rtol=1e-10, atol=1e-12 * np.abs(m).max())


coords = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([0.0, 1e-12, -1e-12, 1e3]))


@settings(max_examples=40)
@given(
    pts=st.lists(st.tuples(coords, coords), min_size=1, max_size=4),
    size=st.one_of(st.floats(1e-6, 1.0), st.just(1e-12)),
    h=st.floats(1e-6, 1.0),
    nu=st.one_of(st.floats(-0.99, 0.5), st.just(0.5)),
)
def test_matrices_finite_for_any_points(pts, size, h, nu):
    points = np.array(pts, dtype=float)
    # sources at the points themselves (coincident), on their cell edges and corners
    centers = np.concatenate([points, points + np.array([size, 0.0]), points + size])
    assert np.all(np.isfinite(love_matrix(points, centers, [size, size], h, E, nu)))
    b = boussinesq_matrix(points, centers, 4 * size * size, h, E, nu)
    assert np.all(np.isfinite(b))
    assert np.all(np.isfinite(boussinesq_block_matrix(points, centers, 4 * size * size, h, E, nu)))


@pytest.mark.parametrize("psi", ["exact", 0.25])
def test_boussinesq_matrix_applies_the_papers_rule(psi):
    sources = grid(5, 4, 1e-3, 1e-3)
    points = np.concatenate([sources, sources[:3] + np.array([0.2e-3, 0.0]), [[0.03, 0.01]]])
    area = 1e-6
    m = boussinesq_matrix(points, sources, area, H, E, 0.5, psi)
    self_term = muscari_self(area, H, E, psi)
    r = np.hypot(*(points[:, None, :] - sources[None, :, :]).transpose(2, 0, 1))
    with np.errstate(divide="ignore"):
        exact = np.where(
            r > 0, boussinesq_effective(np.where(r > 0, r, 1.0), 0.0, H, E, 0.5), np.inf
        )
    expected = np.where(np.abs(exact) <= np.abs(self_term), exact, self_term)
    np.testing.assert_allclose(m, expected, rtol=1e-14, atol=0)
    assert np.all(np.diag(m[:20]) == self_term)  # coincident points take the self term
    assert np.any(m < 0)  # beyond ≈ 0.79 h the coefficients are negative, as they must be


def test_boussinesq_block_matrix_layout_and_self_terms():
    sources = grid(3, 2, 1.5e-3, 1.5e-3)
    points = np.concatenate([sources, [[4e-3, 5e-3]]])
    area = 2e-6
    blk = boussinesq_block_matrix(points, sources, area, H, E, 0.3)
    assert blk.shape == (3 * 7, 3 * 6)
    np.testing.assert_array_equal(
        blk[2::3, 2::3], boussinesq_matrix(points, sources, area, H, E, 0.3)
    )
    # an off-diagonal pair: the 3×3 block equals the effective Boussinesq–Cerruti block
    d = points[6] - sources[1]
    np.testing.assert_allclose(
        blk[18:21, 3:6], boussinesq_block_effective(d[0], d[1], H, E, 0.3), rtol=1e-14
    )
    # coincident pairs: no odd coupling, shear self term on xx and yy
    s = shear_self(area, H, E, 0.3)
    for k in range(6):
        b = blk[3 * k : 3 * k + 3, 3 * k : 3 * k + 3]
        assert b[0, 0] == b[1, 1] == s
        assert b[0, 1] == b[0, 2] == b[1, 2] == b[2, 0] == 0.0


def test_empty_point_sets():
    none, one = np.zeros((0, 2)), np.zeros((1, 2))
    assert love_matrix(none, one, [1e-3, 1e-3], H, E, 0.5).shape == (0, 1)
    assert love_matrix(one, none, [1e-3, 1e-3], H, E, 0.5).shape == (1, 0)
    assert boussinesq_matrix(none, one, 1e-6, H, E).shape == (0, 1)
    assert boussinesq_matrix(one, none, 1e-6, H, E).shape == (1, 0)
    assert boussinesq_block_matrix(one, none, 1e-6, H, E).shape == (3, 0)


def test_validation_messages():
    pts = np.zeros((2, 2))
    with pytest.raises(ValueError, match=r"points must have shape \(n, 2\)"):
        love_matrix(np.zeros((2, 3)), pts, [1e-3, 1e-3], H, E, 0.5)
    with pytest.raises(ValueError, match="half_sizes"):
        love_matrix(pts, pts, [1e-3, 1e-3, 1e-3], H, E, 0.5)
    with pytest.raises(ValueError, match="half_sizes"):
        love_matrix(pts, pts, [0.0, 1e-3], H, E, 0.5)
    with pytest.raises(ValueError, match="finite"):
        boussinesq_matrix([[np.inf, 0.0]], pts, 1e-6, H, E)
    with pytest.raises(ValueError, match="areas"):
        boussinesq_matrix(pts, pts, [1e-6, 1e-6, 1e-6], H, E)
    with pytest.raises(ValueError, match="thickness"):
        boussinesq_matrix(pts, pts, 1e-6, 0.0, E)
    with pytest.raises(ValueError, match="psi"):
        boussinesq_matrix(pts, pts, 1e-6, H, E, psi="fitted")
    with pytest.raises(ValueError, match="component"):
        love_matrix(pts, pts, [1e-3, 1e-3], H, E, 0.5, component="q")
