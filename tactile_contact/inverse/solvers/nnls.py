"""Non-negative least squares with optional Tikhonov term, warm-started frame to frame.

Solves  min ‖A·x − d‖² + λ²‖L·x‖²  subject to x ≥ 0  (L = I when no regulariser is given),
the quadratic program  min ½xᵀHx − gᵀx, x ≥ 0  with H = AᵀA + λ²LᵀL and g = Aᵀd. Its KKT
conditions are x ≥ 0, y = Hx − g ≥ 0, xᵢyᵢ = 0. A ridge of 1e-12·trace(H)/N is added to H so
that every passive-set system is nonsingular (needed for block pivoting to terminate when A has
fewer rows than columns and λ = 0); it moves the minimiser by O(1e-12·κ²) relative.

Two routes, chosen once from L and the shape of A:

- **diagonal L and K < N** (L None, or a square diagonal matrix such as per-cell weights):
  with D = λ²·diag(L)² + ridge, the substitution x = D^(−½)·x̃ turns the problem into
  min ‖Ã·x̃ − d‖² + ‖x̃‖², Ã = A·D^(−½), and a passive set F larger than K is solved in
  measurement space, x̃_F = Ã_Fᵀ·(Ã_F·Ã_Fᵀ + I)⁻¹·d (push-through identity): a K × K system
  (K = 72) instead of |F| × |F|, its matrix updated by rank-one terms as F changes. No N × N
  matrix is formed.
- **otherwise** (a Laplacian L, or K ≥ N): the Gram matrix H is formed offline; passive
  systems H_FF·x_F = g_F are solved by Cholesky while F is small, and through H⁻¹ (formed on
  first need) and the Schur complement of the small active set once F is large.

Two methods:

- ``bpp``: block principal pivoting (Júdice & Pires 1994; Kim & Park 2011). Each step solves
  the unconstrained problem on F and exchanges every KKT-infeasible index at once; after three
  exchanges that do not reduce the number of infeasibilities it exchanges one index only (the
  largest, Murty's rule). Warm start: the previous frame's F. On the kernels of this project it
  settles in 1–10 steps. On degenerate problems (many values near zero, λ ≪ ‖A‖₂) Murty's
  steps can be very many, so after 50 steps a crossover takes over: 300 FISTA steps give a
  near-correct F, pivoting restarts from it, and Lawson–Hanson's primal active-set method
  (monotone, cannot cycle) finishes if needed. Every passive solve is refined until
  |y_F| ≤ 1e-11·max|g| (rounding in badly scaled systems).
- ``fista``: accelerated projected gradient with gradient-based adaptive restart
  (O'Donoghue & Candès 2015), step 1/Lipschitz; stops when the gradient mapping is below
  tol·max|g|. Warm start: the previous frame's solution. Needs curvature: with λ = 0 and
  K < N it creeps and may stop at the iteration limit.

- ``lawson_hanson``: scipy.optimize.nnls on the stacked system [A; λL]·x ≈ [d; 0], cold
  every time (no warm start). For small one-off problems (tens of columns) it is several times
  faster than building and pivoting either route above in Python.

scipy.optimize.nnls (Lawson–Hanson) has no warm start; it is the reference in the tests and,
with ``fallback=True``, a last resort when the iteration limit is reached. A solve never raises
on numerical trouble: it returns ``success=False`` with a finite, non-negative x (argument
errors still raise ValueError).
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from tactile_contact.inverse.solvers._checks import (
    as_matrix,
    as_regulariser,
    as_vector,
    non_negative,
)
from tactile_contact.inverse.solvers._kernels import DiagonalRoute, GramRoute, bpp, fista
from tactile_contact.inverse.solvers.result import CONVERGED, MAX_ITER, NUMERICAL, SolveResult

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
METHODS = ("bpp", "fista", "lawson_hanson")
RIDGE = 1e-12
MESSAGES = {
    CONVERGED: "converged",
    MAX_ITER: "iteration limit reached",
    NUMERICAL: "numerical failure (unusable passive-set system or non-finite iterate)",
}


def _diagonal_of(reg: Array | None, n: int) -> Array | None:
    """diag(L) when L is None (ones) or a square diagonal matrix, else None."""
    if reg is None:
        return np.ones(n)
    if reg.shape == (n, n) and not np.any(reg[~np.eye(n, dtype=bool)]):
        return np.diag(reg).copy()
    return None


class NnlsSolver:
    """Warm-startable NNLS(+Tikhonov) for one fixed matrix.

    Args:
        matrix: A (K × N), e.g. [m/Pa] from cell pressures to taxel compressions.
        tikhonov: λ ≥ 0, in the units of A's singular values (the bundles use 0.1·‖A‖₂).
        regulariser: optional L (p × N); None means the identity. A square diagonal L (per-cell
            weights, e.g. a compact-support prior) keeps the fast measurement-space route.
        method: "bpp" (block principal pivoting), "fista", or "lawson_hanson" (scipy's, cold;
            for small problems solved once).
        tol: relative KKT tolerance (bpp: sign tests, default 1e-9; fista: gradient mapping,
            default 1e-7), relative to max|x| and max|Aᵀd|.
        max_iter: limit on passive-set solves for bpp (all phases; default 5·N + 100) or on
            gradient steps for fista (default 20 000). It bounds the worst-case time.
        fallback: bpp only; at the iteration limit re-solve with scipy's Lawson–Hanson (exact,
            ~50 ms at N ≈ 600, unbounded in a real-time sense) instead of returning
            success=False. Off by default.
    """

    def __init__(
        self,
        matrix: ArrayLike,
        tikhonov: float = 0.0,
        regulariser: ArrayLike | None = None,
        method: str = "bpp",
        tol: float | None = None,
        max_iter: int | None = None,
        fallback: bool = False,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.matrix = as_matrix(matrix)
        n = self.matrix.shape[1]
        self.tikhonov = non_negative(tikhonov, "tikhonov")
        self.regulariser = as_regulariser(regulariser, n)
        self.method = method
        default_tol = 1e-9 if method == "bpp" else 1e-7
        self.tol = non_negative(default_tol if tol is None else tol, "tol")
        limit = (5 * n + 100 if method == "bpp" else 20000) if max_iter is None else max_iter
        if int(limit) != limit or limit < 1:
            raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
        self.max_iter = int(limit)
        self.fallback = bool(fallback)
        lam2 = self.tikhonov**2
        reg_trace = (
            0.0
            if lam2 == 0
            else lam2 * float(n if self.regulariser is None else np.sum(self.regulariser**2))
        )
        trace = float(np.sum(self.matrix**2)) + reg_trace
        self.ridge = RIDGE * max(trace / n, np.finfo(float).tiny)
        diag = _diagonal_of(self.regulariser, n)
        self._route: DiagonalRoute | GramRoute | None
        if method == "lawson_hanson":
            self._route = None  # scipy works on the stacked system itself
        elif diag is not None and self.matrix.shape[0] < n:
            self._route = DiagonalRoute(self.matrix, lam2 * diag**2 + self.ridge)
        else:
            gram = self.matrix.T @ self.matrix
            if diag is not None:
                gram[np.diag_indices(n)] += lam2 * diag**2
            elif lam2 > 0:
                gram += lam2 * (self.regulariser.T @ self.regulariser)  # type: ignore[union-attr]
            gram[np.diag_indices(n)] += self.ridge
            self._route = GramRoute(self.matrix, gram)
        self._passive: Mask = np.zeros(n, dtype=bool)
        self._x: Array = np.zeros(n)

    @property
    def gram(self) -> Array:
        """H = AᵀA + λ²LᵀL + ridge·I (N × N), formed on first use for the diagonal route."""
        if self._route is None:
            n = self.matrix.shape[1]
            ell = np.eye(n) if self.regulariser is None else self.regulariser
            gram = self.matrix.T @ self.matrix + self.tikhonov**2 * (ell.T @ ell)
            gram[np.diag_indices(n)] += self.ridge
            return gram
        return self._route.gram()

    @property
    def passive(self) -> Mask:
        """The passive set (x > 0) of the last solve, the next warm start of bpp."""
        return self._passive.copy()

    @property
    def solution(self) -> Array:
        """The last solution, the next warm start of fista."""
        return self._x.copy()

    def prepare(self) -> NnlsSolver:
        """Do now, offline, the work a first solve would otherwise do (H⁻¹ for the Gram route,
        the step size of fista); returns self. Call it at load time in a real-time loop."""
        if self._route is not None:
            with np.errstate(all="ignore"):
                self._route.prepare()
        return self

    def reset(self) -> None:
        """Forget the previous frame (next solve starts cold)."""
        self._passive[:] = False
        self._x[:] = 0.0

    def solve(self, d: ArrayLike, warm_start: bool = True) -> SolveResult:
        """Solve for data ``d`` (K,) [units of A·x]; start from the previous frame's passive set
        (bpp) or solution (fista) when ``warm_start``. The result is remembered either way."""
        dv = as_vector(d, self.matrix.shape[0])
        t0 = time.perf_counter()
        n = self.matrix.shape[1]
        status, it, note = CONVERGED, 0, ""
        try:
            with np.errstate(all="ignore"):
                if not dv.any():
                    x = np.zeros(n)
                elif self.method == "lawson_hanson":
                    x, status = self._lawson_hanson(dv)
                elif self.method == "bpp":
                    start = self._passive if warm_start else np.zeros(n, dtype=bool)
                    x, status, it = bpp(self._route, dv, start, self.tol, self.max_iter)
                else:
                    start_x = self._x if warm_start else np.zeros(n)
                    x, status, it = fista(self._route, dv, start_x, self.tol, self.max_iter)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            x, status = np.zeros(n), NUMERICAL
        if status != CONVERGED and self.method == "bpp" and self.fallback:
            x, status, note = *self._lawson_hanson(dv), " (Lawson–Hanson fallback)"
        if not np.all(np.isfinite(x)):
            x, status = np.zeros(n), NUMERICAL
        x = np.maximum(x, 0.0)
        passive = x > 0
        self._passive, self._x = passive, x.copy()
        message = MESSAGES[status] + note
        if status == MAX_ITER:
            message = f"iteration limit {self.max_iter} reached{note}"
        return SolveResult(
            x=x,
            success=status == CONVERGED,
            status=status,
            message=message,
            iterations=it,
            residual_norm=float(np.linalg.norm(self.matrix @ x - dv)),
            passive=passive.copy(),
            time_s=time.perf_counter() - t0,
        )

    def _lawson_hanson(self, d: Array) -> tuple[Array, int]:
        """scipy's active-set NNLS on [A; λL]·x ≈ [d; 0]: same objective, no warm start."""
        a, n = self.matrix, self.matrix.shape[1]
        if self.tikhonov > 0:
            ell = np.eye(n) if self.regulariser is None else self.regulariser
            a = np.vstack([a, self.tikhonov * ell])
            d = np.concatenate([d, np.zeros(a.shape[0] - d.size)])
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                x, _ = scipy.optimize.nnls(a, d, maxiter=50 * n)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            return np.zeros(n), NUMERICAL
        return x, CONVERGED if np.all(np.isfinite(x)) else NUMERICAL


def nnls(
    matrix: ArrayLike,
    d: ArrayLike,
    tikhonov: float = 0.0,
    regulariser: ArrayLike | None = None,
    method: str = "bpp",
    tol: float | None = None,
    max_iter: int | None = None,
) -> SolveResult:
    """One cold NNLS(+Tikhonov) solve of min ‖Ax − d‖² + λ²‖Lx‖², x ≥ 0; see NnlsSolver."""
    return NnlsSolver(matrix, tikhonov, regulariser, method, tol, max_iter).solve(d, False)
