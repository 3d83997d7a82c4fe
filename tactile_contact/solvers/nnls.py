"""Non-negative least squares with optional Tikhonov term, warm-started frame to frame.

Solves  min ‖A·x − d‖² + λ²‖L·x‖²  subject to x ≥ 0  (L = I when no regulariser is given)
through the equivalent quadratic program  min ½xᵀHx − gᵀx, x ≥ 0, with the Gram matrix
H = AᵀA + λ²LᵀL precomputed offline and g = Aᵀd per frame. Its KKT conditions are
x ≥ 0, y = Hx − g ≥ 0, xᵢyᵢ = 0.

Two methods:

- ``bpp``: block principal pivoting (Júdice & Pires 1994; Kim & Park 2011). Each iteration
  solves the unconstrained problem on the passive set F and exchanges every KKT-infeasible
  index at once; after three exchanges that do not reduce the number of infeasibilities it
  falls back to exchanging one index (Murty's rule), which guarantees termination. Warm start:
  the previous frame's passive set, usually one or two iterations for a moving contact.
- ``fista``: accelerated projected gradient with gradient-based adaptive restart
  (O'Donoghue & Candès 2015), step 1/‖H‖₂. Warm start: the previous frame's solution.

scipy.optimize.nnls (Lawson–Hanson) has no warm start; it is the reference in the tests.
When pivoting does not settle (rounding on a nearly singular Gram matrix, λ = 0 with fewer
measurements than unknowns), the solve falls back to scipy's Lawson–Hanson on the stacked
system. A solve never raises on numerical trouble: it returns ``success=False`` with the last
iterate (argument errors still raise ValueError).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from tactile_contact.solvers._checks import as_matrix, as_regulariser, as_vector, non_negative
from tactile_contact.solvers.result import CONVERGED, MAX_ITER, NUMERICAL, SolveResult

Array = NDArray[np.float64]
METHODS = ("bpp", "fista")


class NnlsSolver:
    """Warm-startable NNLS(+Tikhonov) for one fixed matrix.

    Args:
        matrix: A (K × N), e.g. [m/Pa] from cell pressures to taxel compressions.
        tikhonov: λ ≥ 0 (units of A's singular values).
        regulariser: optional L (p × N); None means the identity.
        method: "bpp" or "fista".
        tol: relative KKT tolerance (bpp: sign tests; fista: projected-gradient norm).
        max_iter: iteration limit (default 5·N for bpp, 20 000 for fista).
    """

    def __init__(
        self,
        matrix: ArrayLike,
        tikhonov: float = 0.0,
        regulariser: ArrayLike | None = None,
        method: str = "bpp",
        tol: float | None = None,
        max_iter: int | None = None,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.matrix = as_matrix(matrix)
        n = self.matrix.shape[1]
        lam = non_negative(tikhonov, "tikhonov")
        reg = as_regulariser(regulariser, n)
        gram = self.matrix.T @ self.matrix
        if lam > 0:
            gram += lam**2 * (np.eye(n) if reg is None else reg.T @ reg)
        # A ridge at rounding level makes H positive definite when A has fewer rows than
        # columns and λ = 0: block pivoting needs nonsingular passive-set systems to terminate
        # (it may cycle on a singular H), and the minimiser moves by O(1e-10) relative only.
        ridge = 1e-10 * max(np.trace(gram) / n, np.finfo(float).tiny)
        gram[np.diag_indices_from(gram)] += ridge
        self.gram = gram
        # With L = I, H = AᵀA + μI and a passive set larger than the K measurements is solved
        # in K-space: (A_FᵀA_F + μI)⁻¹A_Fᵀd = A_Fᵀ(A_F A_Fᵀ + μI)⁻¹d (push-through identity),
        # a K × K system instead of |F| × |F|; broad Tikhonov solutions keep most cells passive.
        self._mu = lam**2 + ridge if reg is None else None
        self.tikhonov = lam
        self._reg = reg
        self.method = method
        self.tol = float(tol if tol is not None else (1e-9 if method == "bpp" else 1e-7))
        self.max_iter = int(
            max_iter if max_iter is not None else (5 * n + 10 if method == "bpp" else 20000)
        )
        if method == "fista":
            self._lipschitz = float(scipy.linalg.eigvalsh(gram, subset_by_index=[n - 1, n - 1])[0])
        self._passive: NDArray[np.bool_] = np.zeros(n, dtype=bool)
        self._x: Array = np.zeros(n)

    def reset(self) -> None:
        """Forget the previous frame (next solve starts cold)."""
        self._passive[:] = False
        self._x[:] = 0.0

    def _lawson_hanson(self, d: Array) -> tuple[Array, int]:
        """Fallback when pivoting does not settle (rounding on a nearly singular H): scipy's
        active-set NNLS on the stacked system [A; λL]·x ≈ [d; 0], same objective, no warm start."""
        a = self.matrix
        if self.tikhonov > 0:
            ell = np.eye(a.shape[1]) if self._reg is None else self._reg
            a = np.vstack([a, self.tikhonov * ell])
            d = np.concatenate([d, np.zeros(a.shape[0] - d.size)])
        try:
            x, _ = scipy.optimize.nnls(a, d, maxiter=50 * a.shape[1])
        except RuntimeError:
            return np.zeros(a.shape[1]), MAX_ITER
        return x, CONVERGED

    def _passive_solver(self, d: Array, g: Array) -> Callable[[NDArray[np.bool_]], Array | None]:
        a, k, mu = self.matrix, self.matrix.shape[0], self._mu

        def solve_on(f: NDArray[np.bool_]) -> Array | None:
            if mu is None or int(f.sum()) <= k:
                return _solve_passive(self.gram, g, f)
            af = a[:, f]
            m = af @ af.T
            m[np.diag_indices_from(m)] += mu
            x = np.zeros_like(g)
            try:
                x[f] = af.T @ scipy.linalg.cho_solve(scipy.linalg.cho_factor(m), d)
            except (np.linalg.LinAlgError, ValueError):
                return None
            return x

        return solve_on

    def _gradient(self, d: Array, g: Array) -> Callable[[Array], Array]:
        a, mu = self.matrix, self._mu
        if mu is None or a.shape[0] >= a.shape[1]:
            return lambda x: self.gram @ x - g
        return lambda x: a.T @ (a @ x - d) + mu * x

    def solve(self, d: ArrayLike, warm_start: bool = True) -> SolveResult:
        """Solve for data ``d`` (K,), starting from the previous frame when ``warm_start``."""
        dv = as_vector(d, self.matrix.shape[0])
        t0 = time.perf_counter()
        g = self.matrix.T @ dv
        if self.method == "bpp":
            start = self._passive if warm_start else np.zeros_like(self._passive)
            x, status, it = _bpp(
                self._passive_solver(dv, g), self._gradient(dv, g), start, self.tol, self.max_iter
            )
            if status != CONVERGED:
                x, status = self._lawson_hanson(dv)
        else:
            start_x = self._x if warm_start else np.zeros_like(self._x)
            x, status, it = _fista(self.gram, g, start_x, self._lipschitz, self.tol, self.max_iter)
        if not np.all(np.isfinite(x)):
            x, status = np.zeros_like(x), NUMERICAL
        passive = x > 0
        self._passive, self._x = passive.copy(), x.copy()
        messages = {
            CONVERGED: "converged",
            MAX_ITER: f"iteration limit {self.max_iter} reached",
            NUMERICAL: "numerical failure (singular passive-set system or non-finite iterate)",
        }
        return SolveResult(
            x=x,
            success=status == CONVERGED,
            status=status,
            message=messages[status],
            iterations=it,
            residual_norm=float(np.linalg.norm(self.matrix @ x - dv)),
            passive=passive,
            time_s=time.perf_counter() - t0,
        )


def nnls(
    matrix: ArrayLike,
    d: ArrayLike,
    tikhonov: float = 0.0,
    regulariser: ArrayLike | None = None,
    method: str = "bpp",
    tol: float | None = None,
    max_iter: int | None = None,
) -> SolveResult:
    """One cold NNLS(+Tikhonov) solve; see :class:`NnlsSolver`."""
    return NnlsSolver(matrix, tikhonov, regulariser, method, tol, max_iter).solve(d, False)


def _solve_passive(h: Array, g: Array, f: NDArray[np.bool_]) -> Array | None:
    """x on the passive set F from H_FF x_F = g_F; None when the system is unusable."""
    x = np.zeros_like(g)
    if not f.any():
        return x
    hff, gf = h[np.ix_(f, f)], g[f]
    try:
        x[f] = scipy.linalg.cho_solve(scipy.linalg.cho_factor(hff, check_finite=False), gf)
    except (np.linalg.LinAlgError, ValueError):
        # Singular H_FF (no Tikhonov, more passive cells than measurements): minimum-norm
        # solution of the same normal equations.
        try:
            x[f] = scipy.linalg.lstsq(hff, gf, check_finite=False)[0]
        except (np.linalg.LinAlgError, ValueError):
            return None
    return x


def _bpp(
    solve_on: Callable[[NDArray[np.bool_]], Array | None],
    gradient: Callable[[Array], Array],
    passive: NDArray[np.bool_],
    tol: float,
    max_iter: int,
) -> tuple[Array, int, int]:
    """Block principal pivoting: ``solve_on(F)`` solves H_FF x_F = g_F, ``gradient(x)`` = Hx − g."""
    n = passive.size
    f = passive.copy()
    y = gradient(np.zeros(n))
    scale_y = max(float(np.abs(y).max()), np.finfo(float).tiny)
    backup, best = 3, n + 1
    x = np.zeros(n)
    for it in range(1, max_iter + 1):
        new = solve_on(f)
        if new is None:
            return x, NUMERICAL, it
        x = new
        y = gradient(x)
        scale_x = max(float(np.abs(x).max()), np.finfo(float).tiny)
        bad_f = f & (x < -tol * scale_x)
        bad_g = ~f & (y < -tol * scale_y)
        infeasible = bad_f | bad_g
        count = int(infeasible.sum())
        if count == 0:
            x[~f] = 0.0
            return np.maximum(x, 0.0), CONVERGED, it
        if count < best:
            best, backup = count, 3
            f ^= infeasible
        elif backup > 0:
            backup -= 1
            f ^= infeasible
        else:
            last = int(np.nonzero(infeasible)[0][-1])
            f[last] = not f[last]
    return np.maximum(x, 0.0), MAX_ITER, max_iter


def _fista(
    h: Array, g: Array, x0: Array, lipschitz: float, tol: float, max_iter: int
) -> tuple[Array, int, int]:
    if lipschitz <= 0:
        return np.zeros_like(g), CONVERGED, 0
    x = np.maximum(x0, 0.0)
    z = x.copy()
    t = 1.0
    scale = max(float(np.abs(g).max()), np.finfo(float).tiny)
    for it in range(1, max_iter + 1):
        grad = h @ z - g
        x_new = np.maximum(z - grad / lipschitz, 0.0)
        step = x_new - x
        if np.dot(z - x_new, step) > 0:  # momentum points uphill: restart
            t, z = 1.0, x_new
        else:
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            z = x_new + ((t - 1.0) / t_new) * step
            t = t_new
        x = x_new
        pg = h @ x - g
        pg = np.where(x > 0, pg, np.minimum(pg, 0.0))
        if np.abs(pg).max() <= tol * scale:
            return x, CONVERGED, it
    return x, MAX_ITER, max_iter
