"""One test suite for every solver variant, against scipy references and the KKT conditions.

References are independent of our code: scipy.optimize.nnls (Lawson–Hanson) and
scipy.optimize.lsq_linear (BVLS) on the stacked system [A; λL]·x ≈ [d; 0], numpy's pinv/SVD and
the normal equations for the linear operators, the Hessian AᵀA + λ²LᵀL formed here (not the
solver's) for the KKT checks, and build.laplacian (another engineer's) for the priors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.inverse.solvers import (
    CONVERGED,
    MAX_ITER,
    NnlsSolver,
    SvdInverse,
    grid_laplacian,
    nnls,
    support_weights,
)
from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.modules import ROBOSKIN12, place_channels

H, E, NU = 2e-3, 2.1e5, 0.5


# -- problems -------------------------------------------------------------------------------
def cell_grid(rows: int, cols: int, pitch: float) -> np.ndarray:
    ys, xs = (np.arange(rows) - (rows - 1) / 2) * pitch, (np.arange(cols) - (cols - 1) / 2) * pitch
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def love(points: np.ndarray, rows: int = 8, cols: int = 8, pitch: float = 2e-3) -> np.ndarray:
    """The real effective-compression matrix [m/Pa] of a grid of Love cells (ν = 0.5)."""
    return love_matrix(points, cell_grid(rows, cols, pitch), np.full(2, pitch / 2), H, E, NU)


def module_taxels() -> np.ndarray:
    return place_channels(ROBOSKIN12, (0.0, 0.0), 0.0)


def problem(name: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, x_true ≥ 0 sparse, d = A·x_true) for a named shape."""
    rng = np.random.default_rng(seed)
    if name.startswith("random"):
        k, n = {"random_tall": (60, 40), "random_square": (40, 40), "random_wide": (30, 80)}[name]
        a = rng.normal(size=(k, n))
        scale = 1.0
    else:
        pts = {
            "love_taxels": module_taxels(),  # K = 12 < N = 64: the real, under-determined case
            "love_square": cell_grid(8, 8, 2e-3),  # K = N, measured at the cell centres
            "love_fine": cell_grid(11, 11, 1.5e-3),  # K = 121 > N
        }[name]
        a = love(pts)
        scale = 3e4  # Pa
    n = a.shape[1]
    x_true = np.zeros(n)
    idx = rng.choice(n, max(2, n // 8), replace=False)
    x_true[idx] = rng.uniform(0.2, 1.0, idx.size) * scale
    return a, x_true, a @ x_true


PROBLEMS = [
    "random_tall",
    "random_square",
    "random_wide",
    "love_taxels",
    "love_square",
    "love_fine",
]


def regulariser(kind: str | None, n: int) -> np.ndarray | None:
    if kind == "diff":  # first differences, a smoothness prior with constants in its null space
        return np.diff(np.eye(n), axis=0)
    if kind == "weights":  # diagonal: stays on the measurement-space route
        return np.diag(np.linspace(0.5, 2.0, n))
    return None


@dataclass(frozen=True)
class Variant:
    method: str
    lam: float  # relative to ‖A‖₂
    reg: str | None
    warm: bool

    @property
    def id(self) -> str:
        return f"{self.method}-lam{self.lam}-{self.reg or 'I'}-{'warm' if self.warm else 'cold'}"

    def setup(self, a: np.ndarray) -> tuple[float, np.ndarray | None]:
        return self.lam * float(np.linalg.norm(a, 2)), regulariser(self.reg, a.shape[1])

    def solve(self, a: np.ndarray, d: np.ndarray, **kw: object):
        lam, ell = self.setup(a)
        s = NnlsSolver(a, tikhonov=lam, regulariser=ell, method=self.method, **kw)  # type: ignore[arg-type]
        if self.warm:  # a different previous frame, so the warm start is not the answer
            # Prepared as a real-time loop keeps it: the Gram route then solves through H⁻¹
            # (Schur complements); cold solvers factor H_FF instead. Both routes are tested.
            s.prepare()
            s.solve(np.roll(d, 3) * 0.7 + 0.1 * np.abs(d).max(), warm_start=False)
        return s, s.solve(d, warm_start=self.warm)


VARIANTS = [
    Variant(m, lam, reg, warm)
    for m in ("bpp", "fista")
    for lam, reg in ((0.0, None), (0.05, None), (0.05, "diff"), (0.05, "weights"))
    for warm in (False, True)
]
VARIANT_IDS = [v.id for v in VARIANTS]


def hessian(a: np.ndarray, lam: float, ell: np.ndarray | None) -> np.ndarray:
    n = a.shape[1]
    return a.T @ a + lam**2 * (np.eye(n) if ell is None else ell.T @ ell)


def objective(a: np.ndarray, d: np.ndarray, lam: float, ell: np.ndarray | None, x: np.ndarray):
    reg = x if ell is None else ell @ x
    return float(np.sum((a @ x - d) ** 2) + lam**2 * np.sum(reg**2))


def stacked(a: np.ndarray, d: np.ndarray, lam: float, ell: np.ndarray | None):
    n = a.shape[1]
    big = np.vstack([a, lam * (np.eye(n) if ell is None else ell)])
    return big, np.concatenate([d, np.zeros(big.shape[0] - a.shape[0])])


def scipy_nnls(a: np.ndarray, d: np.ndarray, lam: float, ell: np.ndarray | None) -> np.ndarray:
    big, rhs = stacked(a, d, lam, ell)
    return scipy.optimize.nnls(big, rhs, maxiter=100 * a.shape[1])[0]


# Tolerances, per method. Objective (relative): bpp solves the passive-set equations exactly up
# to rounding and a 1e-12 relative ridge; fista stops at a gradient mapping of 1e-7·max|Aᵀd|,
# which bounds the objective gap to about (1e-7)²·κ relative. Solution: the objective gap
# bounds ‖x − x*‖ only through the smallest curvature, so x is compared with a tolerance that
# scales with κ(H) and only where the minimiser is unique (κ(H) < 1e10).
TOL_OBJECTIVE = {"bpp": 1e-10, "fista": 1e-6}
TOL_X_PER_KAPPA = {"bpp": 1e-13, "fista": 1e-7}
# Floor for x: scipy's reference (Householder QR on the stacked system) rounds too, ~N·eps.
TOL_X_FLOOR = {"bpp": 1e-10, "fista": 1e-6}
TOL_KKT = {"bpp": 1e-8, "fista": 1e-5}


def gap_floor(method: str, d: np.ndarray) -> float:
    """Absolute objective slack relative to ‖d‖² (the objective at x = 0): exact fits of
    under-determined data have an objective at rounding level, where relative tests mean nothing."""
    return TOL_OBJECTIVE[method] * float(np.sum(d**2))


def assert_kkt(a, d, lam, ell, x, rtol):
    """x ≥ 0, y = Hx − Aᵀd ≥ 0 and x·y = 0 (relative to max|Aᵀd| and max|x|)."""
    g = a.T @ d
    y = hessian(a, lam, ell) @ x - g
    scale = max(np.abs(g).max(), 1e-300)
    assert np.all(x >= 0), "primal feasibility"
    assert y.min() >= -rtol * scale, f"dual feasibility: min y = {y.min():.3e}, scale {scale:.3e}"
    comp = np.abs(x * y).max() / (scale * max(np.abs(x).max(), 1e-300))
    assert comp <= rtol, f"complementarity {comp:.3e}"


# -- NNLS: every variant --------------------------------------------------------------------
@pytest.mark.parametrize("variant", VARIANTS, ids=VARIANT_IDS)
@pytest.mark.parametrize("name", PROBLEMS)
def test_nnls_matches_scipy_and_satisfies_kkt(variant: Variant, name: str) -> None:
    a, _, d0 = problem(name, seed=len(name))
    rng = np.random.default_rng(1)
    d = d0 + 0.02 * np.abs(d0).max() * rng.normal(size=d0.size)  # noisy: some bounds active
    lam, ell = variant.setup(a)
    solver, res = variant.solve(a, d)
    ref = scipy_nnls(a, d, lam, ell)
    f, f_ref = objective(a, d, lam, ell, res.x), objective(a, d, lam, ell, ref)
    if variant.method == "fista" and lam == 0 and a.shape[0] < a.shape[1]:
        # Singular H (only the 1e-12 ridge is curvature): projected gradient creeps, and may
        # stop at the iteration limit; it must still have reduced the objective to near optimal.
        assert res.status in (CONVERGED, MAX_ITER)
        assert f <= f_ref + 1e-6 * np.sum(d**2)
        return
    assert res.success and res.status == CONVERGED, res.message
    assert f <= f_ref * (1 + TOL_OBJECTIVE[variant.method]) + gap_floor(variant.method, d)
    kappa = np.linalg.cond(hessian(a, lam, ell))
    if kappa < 1e10:
        atol = max(TOL_X_PER_KAPPA[variant.method] * kappa, TOL_X_FLOOR[variant.method])
        atol *= np.abs(ref).max()
        np.testing.assert_allclose(res.x, ref, rtol=0, atol=atol)
    assert_kkt(a, d, lam, ell, res.x, TOL_KKT[variant.method])
    assert res.residual_norm == pytest.approx(np.linalg.norm(a @ res.x - d), rel=1e-12)
    np.testing.assert_array_equal(res.passive, res.x > 0)
    np.testing.assert_array_equal(solver.passive, res.x > 0)
    assert res.time_s >= 0 and res.iterations >= 1


@pytest.mark.parametrize("variant", [v for v in VARIANTS if v.lam > 0], ids=lambda v: v.id)
def test_nnls_matches_lsq_linear_on_a_love_problem(variant: Variant) -> None:
    a, _, d = problem("love_taxels", seed=4)
    lam, ell = variant.setup(a)
    big, rhs = stacked(a, d, lam, ell)
    ref = scipy.optimize.lsq_linear(big, rhs, bounds=(0, np.inf), method="bvls", tol=1e-14)
    _, res = variant.solve(a, d)
    f, f_ref = objective(a, d, lam, ell, res.x), objective(a, d, lam, ell, ref.x)
    assert f <= f_ref * (1 + TOL_OBJECTIVE[variant.method]) + gap_floor(variant.method, d)


@pytest.mark.parametrize("reg", [None, "diff", "weights"])
@pytest.mark.parametrize("name", ["love_taxels", "random_tall"])
def test_lawson_hanson_method_stacks_the_tikhonov_problem(reg: str | None, name: str) -> None:
    # The method hands scipy's Lawson–Hanson the stacked [A; λL]: checked against BVLS (another
    # algorithm) on the same objective and against the KKT conditions of the Hessian formed here.
    a, _, d0 = problem(name, seed=7)
    d = d0 + 0.02 * np.abs(d0).max() * np.random.default_rng(2).normal(size=d0.size)
    lam, ell = Variant("lawson_hanson", 0.05, reg, False).setup(a)
    res = NnlsSolver(a, tikhonov=lam, regulariser=ell, method="lawson_hanson").solve(d)
    big, rhs = stacked(a, d, lam, ell)
    ref = scipy.optimize.lsq_linear(big, rhs, bounds=(0, np.inf), method="bvls", tol=1e-14)
    f, f_ref = objective(a, d, lam, ell, res.x), objective(a, d, lam, ell, ref.x)
    assert res.success and f <= f_ref * (1 + 1e-10) + 1e-10 * float(np.sum(d**2))
    assert_kkt(a, d, lam, ell, res.x, 1e-8)
    np.testing.assert_allclose(
        NnlsSolver(a, tikhonov=lam, regulariser=ell, method="lawson_hanson").gram,
        hessian(a, lam, ell),
        rtol=1e-9,
        atol=1e-9 * np.abs(hessian(a, lam, ell)).max(),
    )


@pytest.mark.parametrize("method", ["bpp", "fista"])
@pytest.mark.parametrize("name", ["random_tall", "love_square", "love_fine"])
def test_recovers_a_known_sparse_answer(method: str, name: str) -> None:
    """Noise-free, λ = 0, K ≥ N: the unique minimiser is x_true itself."""
    a, x_true, d = problem(name, seed=7)
    res = nnls(a, d, method=method, tol=1e-9 if method == "fista" else None)
    tol = {"bpp": 1e-9, "fista": 1e-5}[method] * np.linalg.cond(a) ** 2
    np.testing.assert_allclose(res.x, x_true, rtol=0, atol=tol * x_true.max())


@pytest.mark.parametrize("method", ["bpp", "fista"])
def test_under_determined_noise_free_data_are_fitted(method: str) -> None:
    """K < N, λ = 0: many minimisers, all with zero residual."""
    a, _, d = problem("love_taxels", seed=8)
    res = nnls(a, d, method=method)
    assert res.residual_norm <= 1e-4 * np.linalg.norm(d)


# FISTA with λ = 0 on K < N has no curvature to converge with (see above): left out here.
WARM = [v for v in VARIANTS if v.warm and (v.method == "bpp" or v.lam > 0)]


@pytest.mark.parametrize("variant", WARM, ids=lambda v: v.id)
def test_warm_start_gives_the_cold_answer_on_a_moving_load(variant: Variant) -> None:
    taxels = np.vstack([module_taxels(), place_channels(ROBOSKIN12, (0.0, -6.35e-3), 180.0)])
    a = love(taxels, 10, 12)
    lam, ell = variant.setup(a)
    warm = NnlsSolver(a, tikhonov=lam, regulariser=ell, method=variant.method)
    rng = np.random.default_rng(5)
    for step in range(8):
        x_true = np.zeros(a.shape[1])
        x_true[30 + 7 * step : 33 + 7 * step] = 2e4
        d = a @ x_true + 1e-7 * rng.normal(size=a.shape[0])
        w = warm.solve(d, warm_start=True)
        c = NnlsSolver(a, tikhonov=lam, regulariser=ell, method=variant.method).solve(d, False)
        assert w.success and c.success
        f_w, f_c = objective(a, d, lam, ell, w.x), objective(a, d, lam, ell, c.x)
        assert f_w == pytest.approx(f_c, rel=10 * TOL_OBJECTIVE[variant.method])
        if variant.method == "bpp" and variant.lam > 0:
            np.testing.assert_allclose(w.x, c.x, rtol=0, atol=1e-8 * c.x.max())


def test_a_long_stream_keeps_the_k_space_matrix_accurate() -> None:
    """Hundreds of rank-one updates of the K × K matrix must not drift from a fresh solve."""
    a, _, _ = problem("love_taxels")
    lam = 0.02 * np.linalg.norm(a, 2)
    s = NnlsSolver(a, tikhonov=lam)
    rng = np.random.default_rng(9)
    for _ in range(300):
        x = np.maximum(rng.normal(size=a.shape[1]), 0) * 1e4
        d = a @ x + 1e-6 * rng.normal(size=a.shape[0])
        w = s.solve(d)
        c = NnlsSolver(a, tikhonov=lam).solve(d, warm_start=False)
        np.testing.assert_allclose(w.x, c.x, rtol=0, atol=1e-9 * max(c.x.max(), 1e-300))


@pytest.mark.parametrize("method", ["bpp", "fista"])
@pytest.mark.parametrize(
    "case", ["zero", "negative", "duplicated_columns", "one_row", "one_column", "zero_matrix"]
)
def test_degenerate_inputs(method: str, case: str) -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(size=(30, 20))
    d = a @ np.maximum(rng.normal(size=20), 0)
    if case == "zero":
        d = np.zeros(30)
    elif case == "negative":  # every column correlates negatively with d: x = 0
        a = np.abs(a)
        d = -a.sum(1)
    elif case == "duplicated_columns":  # rank-deficient A
        a[:, 10:] = a[:, :10]
    elif case == "one_row":
        a, d = a[:1], d[:1]
    elif case == "one_column":
        a = a[:, :1]
    else:
        a = np.zeros((30, 20))
    res = nnls(a, d, method=method)
    assert res.success, res.message
    assert np.isfinite(res.x).all() and np.all(res.x >= 0)
    if case in ("zero", "negative", "zero_matrix"):
        assert np.all(res.x == 0)
    ref = scipy_nnls(a, d, 0.0, None)
    f, f_ref = objective(a, d, 0, None, res.x), objective(a, d, 0, None, ref)
    assert f <= f_ref * (1 + 1e-6) + 1e-12 * np.sum(d**2)


@pytest.mark.parametrize("method", ["bpp", "fista"])
def test_iteration_limit_returns_a_status_not_an_exception(method: str) -> None:
    a, _, d = problem("love_taxels", seed=2)
    res = NnlsSolver(
        a, tikhonov=1e-3 * np.linalg.norm(a, 2), method=method, max_iter=1, fallback=False
    ).solve(d)
    assert not res.success and res.status == MAX_ITER and "iteration limit 1" in res.message
    assert np.isfinite(res.x).all() and np.all(res.x >= 0)


def test_bpp_falls_back_to_scipy_at_the_iteration_limit_when_asked() -> None:
    a, _, d = problem("love_taxels", seed=2)
    lam = 1e-3 * np.linalg.norm(a, 2)
    res = NnlsSolver(a, tikhonov=lam, max_iter=1, fallback=True).solve(d)
    assert res.success and "Lawson–Hanson" in res.message
    assert objective(a, d, lam, None, res.x) <= objective(
        a, d, lam, None, scipy_nnls(a, d, lam, None)
    ) * (1 + 1e-9)


@pytest.mark.parametrize("phase", ["crossover", "active_set"])
@pytest.mark.parametrize("reg", [None, "diff"])
def test_the_later_bpp_phases_solve_exactly(
    monkeypatch: pytest.MonkeyPatch, phase: str, reg: str | None
) -> None:
    """Pivoting cut to one step, so the crossover (FISTA, then pivoting again) or, with that cut
    too, Lawson–Hanson's active-set method must finish the job, to the same tolerance."""
    import tactile_contact.inverse.solvers._kernels as kernels

    monkeypatch.setattr(kernels, "BPP_STEPS", 1 if phase == "active_set" else 2)
    if phase == "active_set":
        monkeypatch.setattr(kernels, "CROSSOVER_STEPS", 1)
    for name in ("love_taxels", "random_wide", "random_tall"):
        a, _, d0 = problem(name, seed=21)
        d = d0 + 0.05 * np.abs(d0).max() * np.random.default_rng(2).normal(size=d0.size)
        lam, ell = 0.01 * np.linalg.norm(a, 2), regulariser(reg, a.shape[1])
        res = NnlsSolver(a, tikhonov=lam, regulariser=ell).solve(d)
        assert res.success, res.message
        f, f_ref = (
            objective(a, d, lam, ell, res.x),
            objective(a, d, lam, ell, scipy_nnls(a, d, lam, ell)),
        )
        assert f <= f_ref * (1 + 1e-10)
        assert_kkt(a, d, lam, ell, res.x, 1e-8)


def test_degenerate_wide_problems_converge() -> None:
    """Random wide problems with weak or no regularisation and repeated columns: block pivoting
    alone cycles on some of these (Murty's rule is slow); the crossover must settle them all."""
    rng = np.random.default_rng(17)
    for trial in range(24):
        k, n = int(rng.integers(20, 50)), int(rng.integers(60, 110))
        a = rng.normal(size=(k, n))
        if trial % 3 == 0:
            a = np.repeat(a[:, : n // 3], 3, axis=1)
        lam = (0.0, 1e-4, 1e-2)[trial % 3 - 1 if trial % 3 else 0] * np.linalg.norm(a, 2)
        ell = regulariser(("diff", None, "weights")[trial % 3], a.shape[1])
        s = NnlsSolver(a, tikhonov=lam, regulariser=ell)
        for _ in range(2):
            d = rng.normal(size=k)
            res = s.solve(d)
            assert res.success, f"trial {trial}: {res.message}"
            assert_kkt(a, d, lam, ell, res.x, 1e-6)


@pytest.mark.parametrize("method", ["bpp", "fista"])
@pytest.mark.parametrize("scale", [1e-150, 1e-30, 1e30, 1e150])
def test_unit_neutral_at_extreme_scales(method: str, scale: float) -> None:
    """(sA, d/s, sλ) has the minimiser x/s²: no NaN, no loss of accuracy from the scale alone
    (tolerance: the method's own, as at scale 1)."""
    a, _, d = problem("random_wide", seed=3)
    lam = 0.1 * np.linalg.norm(a, 2)
    y = nnls(a, d, tikhonov=lam, method=method).x
    res = nnls(a * scale, d / scale, tikhonov=lam * scale, method=method)
    assert res.success and np.isfinite(res.x).all() and np.isfinite(res.residual_norm)
    tol = {"bpp": 1e-12, "fista": 1e-9}[method]
    np.testing.assert_allclose(res.x * scale**2, y, rtol=0, atol=tol * y.max())


def test_reset_forgets_the_previous_frame() -> None:
    a, _, d = problem("love_taxels")
    s = NnlsSolver(a, tikhonov=0.05 * np.linalg.norm(a, 2))
    s.solve(d)
    assert s.passive.any()
    s.reset()
    assert not s.passive.any() and not s.solution.any()


def test_prepare_and_gram() -> None:
    a, _, d = problem("love_fine")
    lam = 0.05 * np.linalg.norm(a, 2)
    s = NnlsSolver(a, tikhonov=lam, regulariser=regulariser("diff", a.shape[1])).prepare()
    ref = hessian(a, lam, regulariser("diff", a.shape[1]))
    np.testing.assert_allclose(s.gram, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert s.solve(d).success


def test_arguments_are_validated_with_names() -> None:
    a = np.ones((3, 2))
    cases = [
        (lambda: nnls(a, np.ones(4)), r"d must have shape \(3,\)"),
        (lambda: nnls(a, np.array([1.0, np.nan, 0.0])), "d holds 1 NaN"),
        (lambda: nnls(a, np.array([1.0, np.inf, 0.0])), "d holds 1 NaN/inf"),
        (lambda: nnls(a, np.ones((3, 1))), "d must have shape"),
        (lambda: nnls(np.array([[np.inf, 0.0]]), np.ones(1)), "matrix holds"),
        (lambda: nnls(np.ones(3), np.ones(3)), "matrix must be a non-empty 2-D array"),
        (lambda: nnls(np.ones((0, 3)), np.ones(0)), "matrix must be a non-empty 2-D array"),
        (lambda: NnlsSolver(a, method="lbfgs"), "method must be one of"),
        (lambda: NnlsSolver(a, tikhonov=-1.0), "tikhonov must be finite and >= 0"),
        (lambda: NnlsSolver(a, tikhonov=np.nan), "tikhonov"),
        (lambda: NnlsSolver(a, regulariser=np.eye(3)), "regulariser must have 2 columns"),
        (lambda: NnlsSolver(a, regulariser=np.full((2, 2), np.nan)), "regulariser holds"),
        (lambda: NnlsSolver(a, tol=-1.0), "tol"),
        (lambda: NnlsSolver(a, max_iter=0), "max_iter must be a positive integer"),
        (lambda: SvdInverse(a, regulariser=np.zeros((2, 2))), "regulariser is zero"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()


@settings(max_examples=40)
@given(
    st.integers(1, 10),
    st.integers(1, 10),
    st.integers(0, 2**31),
    st.sampled_from(["bpp", "fista"]),
    st.sampled_from([0.0, 1e-3, 0.3]),
    st.sampled_from([None, "diff", "weights"]),
    st.booleans(),
)
def test_always_finite_non_negative_and_kkt(k, n, seed, method, lam, reg, warm) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(k, n)) * 10 ** rng.uniform(-6, 3)
    lam_abs = lam * np.linalg.norm(a, 2)
    ell = regulariser(reg, n) if n > 1 else None
    solver = NnlsSolver(a, tikhonov=lam_abs, regulariser=ell, method=method)
    for _ in range(2 if warm else 1):
        d = rng.normal(size=k) * 10 ** rng.uniform(-6, 3)
        res = solver.solve(d, warm_start=warm)
        assert np.isfinite(res.x).all() and np.all(res.x >= 0)
        well_posed = np.linalg.cond(hessian(a, lam_abs, ell)) < 1e6
        if method == "fista" and not well_posed:
            # A first-order method needs ~sqrt(cond) iterations per digit: with H singular or
            # cond ≥ 1e6 (λ = 1e-3‖A‖ on a differencing prior, k = 1) it may hit the limit.
            assert res.status in (CONVERGED, MAX_ITER)
            continue
        assert res.success, res.message
        if method == "bpp" or well_posed:
            assert_kkt(a, d, lam_abs, ell, res.x, 1e-6 if method == "bpp" else 1e-4)


# -- linear operators -----------------------------------------------------------------------
LINEAR = ["pinv", "tikhonov", "tsvd"]


@pytest.mark.parametrize("kind", LINEAR)
@pytest.mark.parametrize("name", PROBLEMS)
def test_linear_operators_match_numpy(kind: str, name: str) -> None:
    a, x_true, d = problem(name, seed=11)
    inv = SvdInverse(a)
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    if kind == "pinv":
        op, ref = inv.pinv_operator(1e-12), np.linalg.pinv(a, rcond=1e-12)
    elif kind == "tikhonov":
        lam = 0.05 * s[0]
        op, ref = (
            inv.tikhonov_operator(lam),
            np.linalg.solve(a.T @ a + lam**2 * np.eye(a.shape[1]), a.T),
        )
    else:
        k = min(a.shape) // 2
        op, ref = inv.tsvd_operator(k), (vt[:k].T / s[:k]) @ u[:, :k].T
    assert op.shape == (a.shape[1], a.shape[0]) and op.dtype == np.float64
    # Relative to the operator's size: the SVD (ours, numpy's) is backward stable, ~eps·κ.
    np.testing.assert_allclose(op, ref, rtol=0, atol=1e-9 * np.abs(ref).max())
    if kind == "pinv" and a.shape[0] >= a.shape[1]:  # known answer: full column rank, no noise
        np.testing.assert_allclose(
            op @ d, x_true, rtol=0, atol=1e-9 * x_true.max() * inv.condition_number
        )
    rel32 = (
        np.abs(op.astype(np.float32) @ d.astype(np.float32) - op @ d).max() / np.abs(op @ d).max()
    )
    assert rel32 < 1e-4  # float32 online product (about 1e-7 on well-conditioned operators)


@pytest.mark.parametrize("reg", ["diff", "dirichlet", "neumann"])
@pytest.mark.parametrize("name", ["love_taxels", "love_square", "random_wide"])
def test_generalised_tikhonov_matches_the_normal_equations(reg: str, name: str) -> None:
    a, _, _ = problem(name, seed=6)
    n = a.shape[1]
    ell = (
        regulariser("diff", n) if reg == "diff" or n != 64 else grid_laplacian((8, 8), boundary=reg)
    )
    lam = 0.05 * np.linalg.norm(a, 2)
    op = SvdInverse(a, regulariser=ell).tikhonov_operator(lam)
    hess = hessian(a, lam, ell)
    ref = np.linalg.solve(hess, a.T)
    # Both solve the same normal equations; the reference loses ~eps·κ(H).
    atol = 1e-13 * np.linalg.cond(hess) * np.abs(ref).max()
    np.testing.assert_allclose(op, ref, rtol=0, atol=max(atol, 1e-10 * np.abs(ref).max()))


def test_truncated_gsvd_at_full_rank_is_the_l_minimum_norm_fit() -> None:
    """Keeping every standard-form value: among the exact fits of K < N data, the smallest ‖Lx‖."""
    a, _, d = problem("love_taxels", seed=12)
    ell = grid_laplacian((8, 8))
    inv = SvdInverse(a, regulariser=ell)
    x = inv.tsvd_operator(inv.standard_form_singular_values.size) @ d
    np.testing.assert_allclose(a @ x, d, rtol=0, atol=1e-8 * np.abs(d).max())
    # Reference: min ‖Lx‖² s.t. Ax = d, by its KKT system.
    n, k = a.shape[1], a.shape[0]
    kkt = np.block([[ell.T @ ell, a.T], [a, np.zeros((k, k))]])
    ref = np.linalg.solve(kkt, np.concatenate([np.zeros(n), d]))[:n]
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-6 * np.abs(ref).max())


@pytest.mark.parametrize("reg", [None, "dirichlet"])
def test_closed_form_curve_matches_the_operators(reg: str | None) -> None:
    a, _, d0 = problem("love_taxels", seed=13)
    ell = None if reg is None else grid_laplacian((8, 8))
    d = d0 + 0.01 * np.abs(d0).max() * np.random.default_rng(0).normal(size=d0.size)
    inv = SvdInverse(a, regulariser=ell)
    lams = inv.default_lambdas(7)
    _, res, sol, dof = inv.tikhonov_curve(d, lams)
    for i, lam in enumerate(lams):
        op = inv.tikhonov_operator(lam)
        x = op @ d
        assert res[i] == pytest.approx(np.linalg.norm(a @ x - d), rel=1e-7)
        assert sol[i] == pytest.approx(np.linalg.norm(x if ell is None else ell @ x), rel=1e-7)
        assert dof[i] == pytest.approx(a.shape[0] - np.trace(a @ op), rel=1e-7, abs=1e-7)


def noisy_love(seed: int = 7) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    taxels = np.vstack([module_taxels(), place_channels(ROBOSKIN12, (0.0, -6.35e-3), 180.0)])
    a = love(taxels, 10, 12)
    x_true = np.zeros(a.shape[1])
    x_true[50:53] = 3e4
    x_true[62:65] = 3e4
    sigma = 0.02 * np.abs(a @ x_true).max()
    rng = np.random.default_rng(seed)
    return a, x_true, a @ x_true + sigma * rng.normal(size=a.shape[0]), sigma


@pytest.mark.parametrize("rule", ["gcv", "lcurve", "discrepancy"])
def test_parameter_rules(rule: str) -> None:
    a, x_true, d, sigma = noisy_love()
    inv = SvdInverse(a)
    lam = inv.choose_lambda(rule, d, noise=sigma)
    lams = inv.tikhonov_curve(d)[0]
    s = inv.singular_values
    assert lams[0] <= lam <= lams[-1]
    if rule == "gcv":  # brute force over the same grid, from the operators
        g = [
            np.sum((a @ inv.tikhonov_operator(v) @ d - d) ** 2)
            / (a.shape[0] - np.trace(a @ inv.tikhonov_operator(v))) ** 2
            for v in lams
        ]
        assert lam == lams[int(np.argmin(g))]
    if rule == "discrepancy":
        r = np.linalg.norm(a @ inv.tikhonov_operator(lam) @ d - d)
        assert r == pytest.approx(sigma * np.sqrt(a.shape[0]), rel=1e-5)
    err = np.linalg.norm(inv.tikhonov_operator(lam) @ d - x_true)
    err_tiny = np.linalg.norm(inv.tikhonov_operator(1e-6 * s[0]) @ d - x_true)
    assert err < err_tiny, "the chosen λ must beat almost no regularisation on noisy data"


@pytest.mark.parametrize("rule", ["gcv", "lcurve", "discrepancy"])
def test_rank_rules(rule: str) -> None:
    a, _, d, sigma = noisy_love()
    inv = SvdInverse(a)
    k = inv.choose_rank(rule, d, noise=sigma)
    assert 1 <= k <= a.shape[0]
    if rule == "discrepancy":
        res = [np.linalg.norm(a @ inv.tsvd_operator(j) @ d - d) for j in range(1, k + 1)]
        target = sigma * np.sqrt(a.shape[0])
        assert res[-1] <= target and (k == 1 or res[-2] > target)


def test_discrepancy_at_the_ends_of_the_range() -> None:
    a, _, d, _ = noisy_love()
    inv = SvdInverse(a)
    lams = inv.default_lambdas()
    assert inv.choose_lambda("discrepancy", d, noise=1e3) == lams[-1]  # everything fits
    assert inv.choose_lambda("discrepancy", d, noise=0.0) == lams[0]  # nothing fits exactly


def test_spectra_and_rank_deficiency() -> None:
    a, _, _ = problem("random_tall")
    a[:, 5] = a[:, 4]
    inv = SvdInverse(a)
    assert inv.condition_number == float("inf")
    s = np.linalg.svd(a, compute_uv=False)
    np.testing.assert_allclose(inv.singular_values, s, rtol=0, atol=1e-12 * s[0])
    np.testing.assert_allclose(inv.pinv_operator(), np.linalg.pinv(a, rcond=1e-10), atol=1e-10)


def test_linear_argument_validation() -> None:
    inv = SvdInverse(np.eye(3))
    d = np.ones(3)
    cases = [
        (lambda: inv.tsvd_operator(4), "rank must be an integer in 0..3"),
        (lambda: inv.tsvd_operator(1.5), "rank"),
        (lambda: inv.filter_factors("svd", 1), "method must be pinv, tsvd or tikhonov"),
        (lambda: inv.tikhonov_operator(-1.0), "lam must be finite and >= 0"),
        (lambda: inv.pinv_operator(np.nan), "rcond"),
        (lambda: inv.choose_lambda("discrepancy", d), "noise"),
        (lambda: inv.choose_lambda("aic", d), "rule must be one of"),
        (lambda: inv.choose_lambda("gcv", np.array([1.0, np.nan, 1.0])), "d holds 1 NaN"),
        (lambda: inv.choose_lambda("gcv", np.ones(4)), r"d must have shape \(3,\)"),
        (lambda: inv.choose_lambda("gcv", d, lambdas=[1.0, -1.0, 2.0]), "lambdas"),
        (lambda: inv.choose_rank("discrepancy", d), "noise"),
        (
            lambda: SvdInverse(np.ones((2, 2)), regulariser=np.ones((2, 3))),
            "regulariser must have 2 columns",
        ),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()


# -- priors ---------------------------------------------------------------------------------
def test_grid_laplacian_matches_the_build_laplacian_and_is_definite() -> None:
    from tactile_contact.model.grids import Grid
    from tactile_contact.offline.build import laplacian

    mask = np.ones((5, 6), dtype=bool)
    mask[0, :2] = mask[4, 5] = False
    neumann = grid_laplacian((5, 6), mask, boundary="neumann")
    grid = Grid(origin=(0.0, 0.0), cell_size=1e-3, shape=(5, 6), mask=mask)
    np.testing.assert_array_equal(neumann, laplacian(grid))


def test_grid_laplacian_properties() -> None:
    mask = np.ones((5, 6), dtype=bool)
    mask[2, 3] = False
    for boundary in ("neumann", "dirichlet"):
        lap = grid_laplacian((5, 6), mask, boundary=boundary)
        assert lap.shape == (29, 29)
        np.testing.assert_array_equal(lap, lap.T)
        eig = np.linalg.eigvalsh(lap)
        if boundary == "neumann":
            np.testing.assert_allclose(lap @ np.ones(29), 0.0)  # constants in the null space
            assert abs(eig[0]) < 1e-12 and eig[1] > 1e-3
        else:
            assert eig[0] > 1e-3  # nonsingular
            np.testing.assert_array_equal(np.diag(lap), 4.0)
    with pytest.raises(ValueError, match="boundary"):
        grid_laplacian((2, 2), boundary="periodic")
    with pytest.raises(ValueError, match="mask"):
        grid_laplacian((2, 2), np.ones((2, 3), dtype=bool))


def test_support_weights() -> None:
    centers = np.array([[0.0, 0.0], [3e-3, 4e-3]])
    w = support_weights(centers, np.zeros((1, 2)), radius=5e-3)
    np.testing.assert_allclose(np.diag(w), [1.0, 2.0])
    assert not np.any(w[~np.eye(2, dtype=bool)])
    with pytest.raises(ValueError, match="radius"):
        support_weights(centers, centers, radius=0.0)
