"""One test suite for every solver variant, against scipy references and the KKT conditions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given
from hypothesis import strategies as st

from tactile_contact.solvers import NnlsSolver, SvdInverse, nnls

NNLS_VARIANTS = [("bpp", 0.0), ("bpp", 0.3), ("fista", 0.0), ("fista", 0.3)]
# Reason for each tolerance: BPP solves the passive-set normal equations exactly (rounding of a
# Cholesky solve plus a 1e-10 relative ridge); FISTA stops at a projected-gradient tolerance
# of 1e-7·‖g‖, which bounds the objective, not x, on ill-conditioned problems.
TOL_X = {"bpp": 1e-7, "fista": 1e-4}


def love_like(k: int, n: int, seed: int = 0) -> np.ndarray:
    """A kernel matrix with the effective layer's sign change (negative beyond ~0.8 h)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, 0.03, (k, 2))
    src = rng.uniform(0, 0.03, (n, 2))
    h = 0.002
    r = np.linalg.norm(pts[:, None] - src[None], axis=2) + 3e-4
    rho = np.hypot(r, h)
    return (1.5 / (2 * np.pi * 2.1e5)) * (1.0 / r - 1.0 / rho - h**2 / (2 * rho**3)) * 4e-6


def problem(k: int, n: int, seed: int, noise: float = 0.0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(k, n))
    x_true = np.maximum(rng.normal(size=n), 0) * (rng.random(n) < 0.3)
    return a, x_true, a @ x_true + noise * rng.normal(size=k)


def stacked_reference(a: np.ndarray, d: np.ndarray, lam: float) -> np.ndarray:
    """scipy's Lawson–Hanson NNLS on [A; λI] x ≈ [d; 0] (same objective as ours)."""
    n = a.shape[1]
    big = np.vstack([a, lam * np.eye(n)])
    rhs = np.concatenate([d, np.zeros(n)])
    return scipy.optimize.nnls(big, rhs, maxiter=50 * n)[0]


def objective(a: np.ndarray, d: np.ndarray, lam: float, x: np.ndarray) -> float:
    return float(np.sum((a @ x - d) ** 2) + lam**2 * np.sum(x**2))


def assert_kkt(solver: NnlsSolver, d: np.ndarray, x: np.ndarray, rtol: float) -> None:
    g = solver.matrix.T @ d
    y = solver.gram @ x - g
    scale = np.abs(g).max()
    assert np.all(x >= 0)
    assert np.all(y >= -rtol * scale), "dual feasibility"
    assert np.all(np.abs(x * y) <= rtol * scale * max(np.abs(x).max(), 1e-300)), "complementarity"


@pytest.mark.parametrize(("method", "lam"), NNLS_VARIANTS)
@pytest.mark.parametrize(("k", "n"), [(60, 40), (40, 40), (72, 150)])
def test_nnls_matches_scipy(method: str, lam: float, k: int, n: int) -> None:
    a, _, d = problem(k, n, seed=k + n, noise=0.05)
    res = nnls(a, d, tikhonov=lam, method=method)
    ref = stacked_reference(a, d, lam)
    assert res.success, res.message
    # Under-determined plain NNLS has many minimisers: compare objectives there.
    f_res, f_ref = objective(a, d, lam, res.x), objective(a, d, lam, ref)
    assert f_res <= f_ref * (1 + TOL_X[method]) + TOL_X[method] * np.sum(d**2)
    if k >= n or lam > 0:
        np.testing.assert_allclose(res.x, ref, atol=TOL_X[method] * np.abs(ref).max())
    assert_kkt(NnlsSolver(a, lam, method=method), d, res.x, 1e-6 if method == "bpp" else 1e-3)
    assert res.residual_norm == pytest.approx(np.linalg.norm(a @ res.x - d))


@pytest.mark.parametrize("method", ["bpp", "fista"])
def test_recovers_a_sparse_non_negative_answer(method: str) -> None:
    a, x_true, d = problem(80, 50, seed=3)
    res = nnls(a, d, method=method)
    np.testing.assert_allclose(res.x, x_true, atol=TOL_X[method] * x_true.max())


def test_agrees_with_lsq_linear_on_a_love_like_problem() -> None:
    a = love_like(72, 300)
    rng = np.random.default_rng(1)
    x_true = np.zeros(300)
    x_true[rng.choice(300, 10, replace=False)] = rng.uniform(1e3, 5e4, 10)
    d = a @ x_true + 2e-7 * rng.normal(size=72)
    lam = 1e-3 * np.linalg.norm(a, 2)
    res = nnls(a, d, tikhonov=lam)
    big = np.vstack([a, lam * np.eye(300)])
    ref = scipy.optimize.lsq_linear(
        big, np.concatenate([d, np.zeros(300)]), bounds=(0, np.inf), tol=1e-14, max_iter=10000
    )
    assert objective(a, d, lam, res.x) <= objective(a, d, lam, ref.x) * (1 + 1e-9)


@pytest.mark.parametrize("method", ["bpp", "fista"])
def test_warm_start_gives_the_cold_answer_on_a_moving_load(method: str) -> None:
    a = love_like(72, 200, seed=2)
    lam = 1e-2 * np.linalg.norm(a, 2)
    warm = NnlsSolver(a, tikhonov=lam, method=method)
    for step in range(6):
        x_true = np.zeros(200)
        x_true[20 + 10 * step : 24 + 10 * step] = 2e4
        d = a @ x_true
        w = warm.solve(d, warm_start=True)
        c = NnlsSolver(a, tikhonov=lam, method=method).solve(d, warm_start=False)
        assert w.success and c.success
        f_w, f_c = objective(a, d, lam, w.x), objective(a, d, lam, c.x)
        assert f_w == pytest.approx(f_c, rel=TOL_X[method], abs=TOL_X[method] * np.sum(d**2))
        if method == "bpp":
            np.testing.assert_allclose(w.x, c.x, atol=1e-8 * max(c.x.max(), 1.0))


@pytest.mark.parametrize("method", ["bpp", "fista"])
@pytest.mark.parametrize("case", ["zero", "negative", "rank_deficient"])
def test_degenerate_inputs(method: str, case: str) -> None:
    a, _, d = problem(30, 20, seed=5)
    if case == "zero":
        d = np.zeros(30)
    elif case == "negative":
        d = -np.abs(a).sum(1)
        a = np.abs(a)
    else:
        a[:, 10:] = a[:, :10]  # duplicated columns
    res = nnls(a, d, method=method)
    assert np.isfinite(res.x).all() and np.all(res.x >= 0)
    if case in ("zero", "negative"):
        assert np.all(res.x == 0)
    ref = stacked_reference(a, d, 0.0)
    assert objective(a, d, 0, res.x) <= objective(a, d, 0, ref) * (1 + 1e-6) + 1e-12


def test_arguments_are_validated_with_names() -> None:
    a = np.ones((3, 2))
    with pytest.raises(ValueError, match="d must have shape"):
        nnls(a, np.ones(4))
    with pytest.raises(ValueError, match="d holds 1 NaN"):
        nnls(a, np.array([1.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="matrix holds"):
        nnls(np.array([[np.inf, 0.0]]), np.ones(1))
    with pytest.raises(ValueError, match="method"):
        NnlsSolver(a, method="lbfgs")
    with pytest.raises(ValueError, match="tikhonov"):
        NnlsSolver(a, tikhonov=-1.0)
    with pytest.raises(ValueError, match="regulariser must have 2 columns"):
        NnlsSolver(a, regulariser=np.eye(3))


@given(
    st.integers(2, 12),
    st.integers(2, 12),
    st.integers(0, 10_000),
    st.sampled_from(["bpp", "fista"]),
    st.floats(0, 1),
)
def test_always_finite_and_kkt(k: int, n: int, seed: int, method: str, lam: float) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(k, n)) * 10 ** rng.uniform(-6, 3)
    d = rng.normal(size=k) * 10 ** rng.uniform(-6, 3)
    solver = NnlsSolver(a, tikhonov=lam * np.abs(a).max(), method=method)
    res = solver.solve(d)
    assert np.isfinite(res.x).all() and np.all(res.x >= 0)
    if res.success and method == "bpp":
        assert_kkt(solver, d, res.x, 1e-6)


# -- linear operators -----------------------------------------------------------------------
def test_pinv_tsvd_tikhonov_match_numpy() -> None:
    a = love_like(40, 60, seed=4)
    inv = SvdInverse(a)
    np.testing.assert_allclose(
        inv.pinv_operator(1e-12),
        np.linalg.pinv(a, rcond=1e-12),
        rtol=1e-8,
        atol=1e-6 * np.abs(np.linalg.pinv(a)).max(),
    )
    lam = 0.05 * np.linalg.norm(a, 2)
    ref = np.linalg.solve(a.T @ a + lam**2 * np.eye(60), a.T)
    np.testing.assert_allclose(
        inv.tikhonov_operator(lam), ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max()
    )
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    np.testing.assert_allclose(
        inv.tsvd_operator(5), (vt[:5].T / s[:5]) @ u[:, :5].T, atol=1e-9 * (1 / s[4])
    )
    assert inv.condition_number == pytest.approx(s[0] / s[-1])


def test_generalised_tikhonov_matches_the_normal_equations() -> None:
    a = love_like(30, 25, seed=6)
    ell = np.diff(np.eye(25), axis=0)  # first differences: a smoothness prior
    lam = 0.1 * np.linalg.norm(a, 2)
    op = SvdInverse(a, regulariser=ell).tikhonov_operator(lam)
    ref = np.linalg.solve(a.T @ a + lam**2 * ell.T @ ell, a.T)
    np.testing.assert_allclose(op, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("rule", ["gcv", "lcurve", "discrepancy"])
def test_parameter_rules_pick_a_sensible_lambda(rule: str) -> None:
    a = love_like(72, 100, seed=7)
    rng = np.random.default_rng(7)
    x_true = np.zeros(100)
    x_true[40:45] = 3e4
    sigma = 0.02 * np.abs(a @ x_true).max()
    d = a @ x_true + sigma * rng.normal(size=72)
    inv = SvdInverse(a)
    lam = inv.choose_lambda(rule, d, noise=sigma)
    s = inv.singular_values
    assert s[-1] * 1e-3 < lam < s[0]
    err = np.linalg.norm(inv.tikhonov_operator(lam) @ d - x_true)
    err_tiny = np.linalg.norm(inv.tikhonov_operator(1e-6 * s[0]) @ d - x_true)
    assert err < err_tiny, "the chosen λ must beat almost no regularisation on noisy data"


def test_filter_factor_validation() -> None:
    inv = SvdInverse(np.eye(3))
    with pytest.raises(ValueError, match="rank"):
        inv.tsvd_operator(4)
    with pytest.raises(ValueError, match="method"):
        inv.filter_factors("svd", 1)
    with pytest.raises(ValueError, match="noise"):
        inv.choose_lambda("discrepancy", np.ones(3))
