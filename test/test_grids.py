"""Grids: geometry convention, masks, resampling, disc quadrature."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.model.grids import (
    Grid,
    disc_quadrature,
    distance_to_hull,
    distance_to_points,
    resample,
    skin_grid,
)


def test_covering_grid_convention():
    pts = np.array([[0.0, 0.0], [0.010, 0.004]])
    g = Grid.covering(pts, 0.002, 0.001)
    assert g.shape == (3, 6)  # rows along y: 6 mm / 2 mm; cols along x: 12 mm / 2 mm
    c = g.all_centers()
    assert c[0, 0] == pytest.approx([g.origin[0] + 0.001, g.origin[1] + 0.001])
    assert c[0, 1, 0] > c[0, 0, 0] and c[1, 0, 1] > c[0, 0, 1]  # j → +x, i → +y
    assert np.allclose(c.reshape(-1, 2).mean(0), [0.005, 0.002])  # centred on the box
    assert g.cell == (0.002, 0.002) and g.cell_area == pytest.approx(4e-6)
    lo = np.array(g.origin)
    hi = lo + np.array(g.shape[::-1]) * 0.002
    assert np.all(pts.min(0) - 0.001 >= lo - 1e-12) and np.all(pts.max(0) + 0.001 <= hi + 1e-12)


def test_image_vector_round_trip_and_mask():
    g = Grid.covering([[0, 0], [0.01, 0.01]], 0.002, 0.0)
    mask = np.zeros(g.shape, bool)
    mask[1:3, 2:4] = True
    g = g.with_mask(mask)
    v = np.arange(4.0)
    img = g.to_image(v)
    assert img[~mask].sum() == 0 and np.array_equal(g.to_vector(img), v)
    assert g.centers().shape == (4, 2) and g.half_sizes().shape == (4, 2)
    with pytest.raises(ValueError, match=r"shape \(4,\)"):
        g.to_image(np.zeros(5))


def test_taxel_mask_keeps_cells_near_taxels():
    xy = np.array([[0.0, 0.0], [0.02, 0.0]])
    g = skin_grid(xy, 0.001, 0.004, "taxels", 0.003)
    d = distance_to_points(g.all_centers().reshape(-1, 2), xy).reshape(g.shape)
    assert np.array_equal(g.mask, d <= 0.003)
    assert not g.mask[g.shape[0] // 2, g.shape[1] // 2]  # midway between the two taxels


def test_distance_to_hull():
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    q = np.array([[0.2, 0.2], [2.0, 0.0], [-1.0, -1.0], [1.0, 1.0]])
    np.testing.assert_allclose(distance_to_hull(q, tri), [0, 1, np.sqrt(2), np.sqrt(0.5)])


def test_resample_linear_field_exact():
    src = Grid.covering([[0, 0], [0.02, 0.01]], 0.002, 0.0)
    f = 3.0 * src.all_centers()[..., 0] - 2.0 * src.all_centers()[..., 1] + 0.5
    dst = Grid(
        (src.origin[0] + 0.002, src.origin[1] + 0.002), 0.0007, (8, 20), np.ones((8, 20), bool)
    )
    out = resample(f, src, dst)
    c = dst.all_centers()
    np.testing.assert_allclose(out, 3.0 * c[..., 0] - 2.0 * c[..., 1] + 0.5, atol=1e-12)
    far = Grid((1.0, 1.0), 0.001, (2, 2), np.ones((2, 2), bool))
    assert np.all(resample(f, src, far, fill=-1.0) == -1.0)


def test_resample_coarse_to_fine_to_coarse_preserves_smooth_field():
    src = Grid.covering([[0, 0], [0.03, 0.03]], 0.001, 0.0)
    x, y = src.all_centers()[..., 0], src.all_centers()[..., 1]
    f = np.exp(-((x - 0.015) ** 2 + (y - 0.015) ** 2) / 0.008**2)
    coarse = Grid.covering([[0, 0], [0.03, 0.03]], 0.003, 0.0)
    back = resample(resample(f, src, coarse), coarse, src)
    inner = (np.abs(x - 0.015) < 0.012) & (np.abs(y - 0.015) < 0.012)
    assert np.max(np.abs(back - f)[inner]) < 0.1


@settings(max_examples=20)
@given(st.floats(0.0, 5e-3), st.integers(1, 5), st.integers(4, 12))
def test_disc_quadrature_integrates_r_squared(radius, n_r, n_t):
    pts, w = disc_quadrature(radius, n_r, n_t)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(np.hypot(*pts.T) <= radius + 1e-15)
    # mean of r² over a disc is R²/2 (degree 1 in r², exact for any n_r ≥ 1)
    assert (w @ (pts**2).sum(1)) == pytest.approx(radius**2 / 2, abs=1e-18)
    assert np.allclose(w @ pts, 0.0, atol=1e-15)


def test_invalid_arguments():
    with pytest.raises(ValueError, match="cell must be finite"):
        Grid.covering([[0, 0]], 0.0, 0.0)
    with pytest.raises(ValueError, match=r"points must be a finite non-empty \(K, 2\)"):
        Grid.covering(np.zeros((0, 2)), 0.001, 0.0)
    with pytest.raises(ValueError, match="unknown mask"):
        skin_grid([[0, 0]], 0.001, 0.0, "round")


@given(
    st.lists(st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1)), min_size=1, max_size=30),
    st.lists(st.tuples(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2)), min_size=1, max_size=50),
)
def test_distance_to_points_is_the_nearest_of_all_pairs(points, query):
    """The k-d tree's distances against every pair's (the reference it replaced)."""
    p, q = np.array(points), np.array(query)
    brute = np.sqrt(((q[:, None, :] - p[None, :, :]) ** 2).sum(-1).min(axis=1))
    np.testing.assert_allclose(distance_to_points(q, p), brute, rtol=1e-12, atol=1e-15)
