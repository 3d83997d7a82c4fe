"""Regular-grid fast path: distinct kernel values, FFT products against the dense matrix."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.model.elastic import (
    RegularGridOperator,
    boussinesq_matrix,
    love_matrix,
    regular_grid_operator,
)

E, H = 2.1e5, 2e-3


def grid(nx, ny, px, py):
    gx, gy = np.meshgrid(np.arange(nx) * px, np.arange(ny) * py, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


@pytest.mark.parametrize("nu", [0.5, 0.3])
def test_love_operator_equals_dense_assembly(nu):
    nx, ny, px, py = 11, 8, 1e-3, 0.7e-3
    op = regular_grid_operator(nx, ny, px, py, H, E, nu)
    assert isinstance(op, RegularGridOperator)
    assert op.kernel.shape == (nx, ny) and op.shape == (88, 88)
    centers = grid(nx, ny, px, py)
    dense = love_matrix(centers, centers, [px / 2, py / 2], H, E, nu)
    np.testing.assert_allclose(op.dense(), dense, rtol=1e-10, atol=1e-12 * np.abs(dense).max())


@pytest.mark.parametrize("psi", ["exact", 0.25])
def test_boussinesq_operator_equals_dense_assembly(psi):
    nx, ny, p = 6, 9, 1.2e-3
    op = regular_grid_operator(nx, ny, p, p, H, E, 0.5, model="boussinesq", psi=psi)
    centers = grid(nx, ny, p, p)
    dense = boussinesq_matrix(centers, centers, p * p, H, E, 0.5, psi)
    np.testing.assert_allclose(op.dense(), dense, rtol=1e-12, atol=0)


@settings(max_examples=30)
@given(
    nx=st.integers(1, 12),
    ny=st.integers(1, 12),
    px=st.floats(1e-4, 5e-3),
    py=st.floats(1e-4, 5e-3),
    model=st.sampled_from(["love", "boussinesq"]),
    m=st.integers(1, 3),
    seed=st.integers(0, 2**31),
)
def test_fft_products_match_dense(nx, ny, px, py, model, m, seed):
    op = regular_grid_operator(nx, ny, px, py, H, E, 0.5, model=model)
    dense = op.dense()
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(nx * ny, m))
    ref = dense @ q
    tol = 1e-12 * np.abs(dense).max() * np.abs(q).sum(axis=0)  # 1e-12 of the largest term
    assert np.all(np.abs(op.matvec(q) - ref) <= tol)
    assert np.all(np.abs(op.rmatvec(q) - dense.T @ q) <= tol)
    assert np.all(np.abs(op.matvec(q[:, 0]) - ref[:, 0]) <= tol[0])
    np.testing.assert_array_equal(dense, dense.T)


def test_fft_relative_accuracy_on_a_smooth_load():
    op = regular_grid_operator(40, 30, 1e-3, 1e-3, H, E, 0.5)
    gx, gy = np.meshgrid(np.arange(40), np.arange(30), indexing="ij")
    q = 1e4 * np.exp(-((gx - 20) ** 2 + (gy - 14) ** 2) / 30.0).ravel()
    ref = op.dense() @ q
    got = op.matvec(q)
    assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_linear_operator_solves_like_dense():
    op = regular_grid_operator(10, 10, 1e-3, 1e-3, H, E, 0.5)
    d = np.linspace(-1e-6, 2e-6, 100)
    sol, info = spla.gmres(op.as_linear_operator(), d, rtol=1e-12, atol=0, restart=100)
    assert info == 0
    np.testing.assert_allclose(sol, np.linalg.solve(op.dense(), d), rtol=1e-8, atol=1e-3)


def test_validation():
    with pytest.raises(ValueError, match="nx"):
        regular_grid_operator(0, 3, 1e-3, 1e-3, H, E, 0.5)
    with pytest.raises(ValueError, match="ny"):
        regular_grid_operator(3, 2.5, 1e-3, 1e-3, H, E, 0.5)
    with pytest.raises(ValueError, match="pitch_y"):
        regular_grid_operator(3, 3, 1e-3, -1e-3, H, E, 0.5)
    with pytest.raises(ValueError, match="model"):
        regular_grid_operator(3, 3, 1e-3, 1e-3, H, E, 0.5, model="hertz")
    op = regular_grid_operator(3, 3, 1e-3, 1e-3, H, E, 0.5)
    with pytest.raises(ValueError, match="q must have shape"):
        op.matvec(np.ones(8))
    with pytest.raises(ValueError, match="q must have shape"):
        op.rmatvec(np.float64(1.0))
    with pytest.raises(ValueError, match="finite"):
        op.matvec(np.full(9, np.nan))
