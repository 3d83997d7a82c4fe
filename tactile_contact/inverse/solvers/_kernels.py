"""The numerical kernels of the NNLS solver: two passive-set routes, pivoting and FISTA.

A route owns the matrices of one problem and offers, per frame, the unconstrained solution on
a passive set F and the gradient y = Hx − g, in its own variables (scaled for the diagonal
route). Kernels only raise numpy/scipy's own errors; NnlsSolver turns them into a status.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
import scipy.sparse.linalg
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf as potrf
from scipy.linalg.lapack import dpotrs as potrs

from tactile_contact.inverse.solvers.result import CONVERGED, MAX_ITER, NUMERICAL

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
# Rank-one updates of the K-space matrix accumulate rounding ~ eps·‖Ã‖²; rebuild it after this
# many updates, or when more columns change at once than a fresh product would cost.
REFRESH_UPDATES = 64
# Passive solves are refined while |y_F| > REFINE_TOL·max|g|, at most REFINE_STEPS times.
REFINE_TOL, REFINE_STEPS = 1e-11, 2
# Block pivoting settles in 1–10 steps on the kernels of this project; when it has not after
# this many (Murty's single pivots can take exponentially many), the active-set method takes over.
BPP_STEPS = 50
CROSSOVER_STEPS = 300
# A Schur-complement solve through H⁻¹ must meet |y_F| ≤ this·max|g| after refinement.
COMPLEMENT_TOL = 1e-9


class _Factor:
    """Cholesky factor of a symmetric positive definite H, by LAPACK directly (scipy's
    cho_factor wrapper checks cost more than a 72 × 72 factorisation); least squares when H is
    not numerically definite."""

    def __init__(self, h: Array) -> None:
        self._h = h
        c, info = potrf(h, lower=False, clean=False)
        self._c = c if info == 0 else None

    def solve(self, rhs: Array) -> Array:
        if self._c is not None:
            x, info = potrs(self._c, rhs, lower=False)
            if info == 0:
                return x
        return scipy.linalg.lstsq(self._h, rhs, check_finite=False)[0]


def _refine(x: Array, f: Mask, gradient, correct, scale: float) -> Array:
    """Iterative refinement of a passive solve: y_F = (Hx − g)_F must vanish; rounding in a
    badly scaled system (λ = 0, rank-deficient A) can leave it at 1e-3 relative, and one or
    two corrections with the same factor remove that. Returns y = Hx − g at the final x."""
    y = gradient(x)
    for _ in range(REFINE_STEPS):
        if not f.any() or np.abs(y[f]).max() <= REFINE_TOL * scale:
            break
        x[f] -= correct(y[f])
        y = gradient(x)
    return y


class DiagonalRoute:
    """H = AᵀA + diag(D): work with x̃ = √D·x, Ã = A/√D, so H̃ = ÃᵀÃ + I (K-space solves)."""

    def __init__(self, a: Array, dvec: Array) -> None:
        self._a = a
        self._dvec = dvec
        self._sqrt = np.sqrt(dvec)
        self.at = np.ascontiguousarray(a / self._sqrt)
        k, n = a.shape
        self._eye = np.eye(k)
        self._m = np.zeros((k, k))
        self._m_mask = np.zeros(n, dtype=bool)
        self._updates = 0
        self._full = self.at @ self.at.T  # Ã·Ãᵀ over all cells (K × K)
        # Incremental updates only while their rounding stays far below the identity term.
        self._incremental = float(np.sum(self.at**2)) * np.finfo(float).eps * REFRESH_UPDATES < 1e-8
        self._lipschitz: float | None = None
        self._d = np.zeros(k)
        self._scale = 0.0
        self._cached: tuple[Array, Array] | None = None  # (x̃, ỹ) of the last solve_on

    def start(self, d: Array) -> Array:
        """Prepare a frame; return g̃ = Ãᵀd."""
        self._d = d
        g = self.at.T @ d
        self._scale = float(np.abs(g).max())
        return g

    def _kspace_matrix(self, f: Mask) -> Array:
        """M = Ã_F·Ã_Fᵀ + I, from the cheapest of: rank-one updates of the previous M, the
        product over F, or the full product minus the one over the active set."""
        changed = f ^ self._m_mask
        count = int(changed.sum())
        nf = int(f.sum())
        direct = min(nf, f.size - nf) if self._incremental else nf
        if count and (count >= direct or self._updates >= REFRESH_UPDATES):
            if nf <= f.size - nf or not self._incremental:
                af = self.at[:, f]
                np.matmul(af, af.T, out=self._m)
            else:
                ag = self.at[:, ~f]
                np.matmul(ag, ag.T, out=self._m)
                np.subtract(self._full, self._m, out=self._m)
            self._updates = 0
        elif count:
            add, rem = self.at[:, changed & f], self.at[:, changed & self._m_mask]
            self._m += add @ add.T
            self._m -= rem @ rem.T
            self._updates += count
        self._m_mask[:] = f
        return self._m + self._eye

    def solve_on(self, f: Mask) -> Array:
        """x̃ minimising ‖Ãx̃ − d‖² + ‖x̃‖² with x̃ = 0 off F."""
        x = np.zeros(f.size)
        nf = int(f.sum())
        if nf == 0:
            self._cached = None
            return x
        if nf < self._m.shape[0]:
            af = self.at[:, f]
            h = af.T @ af
            h[np.diag_indices(nf)] += 1.0
            fac = _Factor(h)
            x[f] = fac.solve(af.T @ self._d)
            correct = fac.solve
        else:
            fac = _Factor(self._kspace_matrix(f))
            x[f] = (self.at.T @ fac.solve(self._d))[f]

            def correct(r: Array) -> Array:  # (I + Ã_FᵀÃ_F)⁻¹r by the push-through identity
                pad = np.zeros(f.size)
                pad[f] = r
                return r - (self.at.T @ fac.solve(self.at @ pad))[f]

        self._cached = (x, _refine(x, f, self._gradient, correct, self._scale))
        return x

    def _gradient(self, x: Array) -> Array:
        return self.at.T @ (self.at @ x - self._d) + x

    def gradient(self, x: Array) -> Array:
        """H̃x̃ − g̃ = Ãᵀ(Ãx̃ − d) + x̃."""
        if self._cached is not None and self._cached[0] is x:
            return self._cached[1]
        return self._gradient(x)

    @property
    def lipschitz(self) -> float:
        if self._lipschitz is None:
            at = self.at
            small = at @ at.T if at.shape[0] <= at.shape[1] else at.T @ at
            self._lipschitz = _largest_eigenvalue(small) + 1.0
        return self._lipschitz

    def prepare(self) -> None:
        """Compute the Lipschitz constant now (offline) rather than on first need."""
        _ = self.lipschitz

    def to_x(self, v: Array) -> Array:
        return v / self._sqrt

    def from_x(self, x: Array) -> Array:
        return x * self._sqrt

    def gram(self) -> Array:
        h = self._a.T @ self._a
        h[np.diag_indices_from(h)] += self._dvec
        return h


class GramRoute:
    """H = AᵀA + λ²LᵀL (+ ridge) precomputed (general L, or K ≥ N).

    A passive system H_FF·x_F = g_F is solved by Cholesky of H_FF (|F|³/3 flops) while F is
    the smaller set; once the active set G is smaller, through the inverse P = H⁻¹ (formed
    once, on first need): H_FF⁻¹ = P_FF − P_FG·P_GG⁻¹·P_GF (Schur complement), N² + |G|³
    flops. That result is checked against H_FF·x_F = g_F and redone by Cholesky if P has
    lost accuracy (H ill-conditioned), after which P is no longer used.
    """

    def __init__(self, a: Array, gram: Array) -> None:
        self._a = a
        self._h = gram
        self._g = np.zeros(gram.shape[0])
        self._lipschitz: float | None = None
        self._inverse: Array | None = None
        self._use_inverse = True
        self._cached: tuple[Array, Array] | None = None  # (x, Hx − g) of the last solve_on

    def start(self, d: Array) -> Array:
        self._g = self._a.T @ d
        return self._g

    def prepare(self) -> None:
        """Form H⁻¹ and the Lipschitz constant now (offline) rather than on first need."""
        if self._inverse is None and self._use_inverse:
            n = self._h.shape[0]
            try:
                factor = scipy.linalg.cho_factor(self._h, check_finite=False)
                self._inverse = scipy.linalg.cho_solve(factor, np.eye(n), check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                self._use_inverse = False  # not numerically definite: Cholesky of H_FF only
        _ = self.lipschitz

    def _complement(self, f: Mask) -> tuple[Array, Callable[[Array], Array]] | None:
        """x with x_F = H_FF⁻¹g_F through P = H⁻¹, and r_F ↦ H_FF⁻¹r_F for refinement."""
        if self._inverse is None:
            self.prepare()
            if self._inverse is None:
                return None
        p, act = self._inverse, ~f
        pg = p[:, act]
        fac = _Factor(pg[act]) if act.any() else None

        def apply(r_full: Array) -> Array:  # r_full zero off F
            u = p @ r_full
            if fac is not None:
                u -= pg @ fac.solve(u[act])
            return u

        def correct(r: Array) -> Array:
            pad = np.zeros(f.size)
            pad[f] = r
            return apply(pad)[f]

        x = apply(np.where(f, self._g, 0.0))
        x[act] = 0.0
        return x, correct

    def solve_on(self, f: Mask) -> Array:
        nf = int(f.sum())
        ng = f.size - nf
        scale = float(np.abs(self._g).max())
        self._cached = None
        # Forming P costs about N³ (Cholesky and N right-hand sides): worth it only for a
        # solver that keeps it (prepared, or warm across frames), not for a one-off solve.
        build = 0 if self._inverse is not None else f.size**3
        if self._use_inverse and nf > 0 and ng**3 / 3 + f.size**2 + build < nf**3 / 3:
            got = self._complement(f)
            if got is not None:
                x, correct = got
                y = _refine(x, f, self._gradient, correct, scale)
                if np.abs(y[f]).max() <= COMPLEMENT_TOL * max(scale, np.finfo(float).tiny):
                    self._cached = (x, y)
                    return x
                # P has lost accuracy (H ill-conditioned): Cholesky from now on.
                self._use_inverse = False
        x = np.zeros(f.size)
        if nf:
            fac = _Factor(self._h[np.ix_(f, f)])
            x[f] = fac.solve(self._g[f])
            self._cached = (x, _refine(x, f, self._gradient, fac.solve, scale))
        return x

    def _gradient(self, x: Array) -> Array:
        return self._h @ x - self._g

    def gradient(self, x: Array) -> Array:
        if self._cached is not None and self._cached[0] is x:
            return self._cached[1]
        return self._gradient(x)

    @property
    def lipschitz(self) -> float:
        if self._lipschitz is None:
            self._lipschitz = _largest_eigenvalue(self._h)
        return self._lipschitz

    def to_x(self, v: Array) -> Array:
        return v

    def from_x(self, x: Array) -> Array:
        return x

    def gram(self) -> Array:
        return self._h


def _largest_eigenvalue(h: Array) -> float:
    """λ_max of symmetric H, slightly over-estimated (a step 1/λ_max must not diverge)."""
    n = h.shape[0]
    if n <= 200:
        return float(scipy.linalg.eigvalsh(h, subset_by_index=[n - 1] * 2)[0])
    try:
        top = scipy.sparse.linalg.eigsh(h, k=1, which="LA", tol=1e-8, return_eigenvectors=False)
        return float(top[0]) * (1.0 + 1e-6)
    except scipy.sparse.linalg.ArpackError:
        return float(np.abs(h).sum(1).max())  # Gershgorin: a rigorous upper bound


Route = DiagonalRoute | GramRoute


def bpp(route: Route, d: Array, passive: Mask, tol: float, max_iter: int) -> tuple[Array, int, int]:
    """Block principal pivoting from the passive set ``passive``; returns (x, status, passive
    solves used). Should pivoting not settle within BPP_STEPS steps (degenerate problems: many
    values near zero, λ ≪ ‖A‖), a crossover: a few hundred FISTA steps from the best iterate
    give a near-correct passive set, pivoting restarts from it, and Lawson–Hanson's active-set
    method (which cannot cycle) finishes if it still has not settled."""
    g = route.start(d)
    scale_y = float(np.abs(g).max())
    n = g.size
    if scale_y == 0.0:
        return np.zeros(n), CONVERGED, 0
    x, done, used, best_x = _pivot(route, passive.copy(), tol, scale_y, min(max_iter, BPP_STEPS))
    if not done and used < max_iter:
        z, _, _ = _accelerated(route, g, np.maximum(best_x, 0.0), tol, CROSSOVER_STEPS)
        budget = min(max_iter - used, BPP_STEPS)
        x, done, more, best_x = _pivot(route, z > 0, tol, scale_y, budget)
        used += more
    if done:
        return route.to_x(x), CONVERGED, used
    if not np.all(np.isfinite(x)):
        return np.zeros(n), NUMERICAL, used
    x, status, more = _active_set(route, best_x, tol, scale_y, max_iter - used)
    return route.to_x(x), status, used + more


def _pivot(
    route: Route, f: Mask, tol: float, scale_y: float, steps: int
) -> tuple[Array, bool, int, Array]:
    """Kim & Park's block principal pivoting with Murty's backup rule; returns (x̃, converged,
    steps used, the iterate with the fewest infeasibilities)."""
    n = f.size
    backup, best, best_x = 3, n + 1, np.zeros(n)
    x = np.zeros(n)
    for it in range(1, steps + 1):
        x = route.solve_on(f)
        if not np.all(np.isfinite(x)):
            return x, False, it, best_x
        y = route.gradient(x)
        scale_x = max(float(np.abs(x).max()), np.finfo(float).tiny)
        infeasible = (f & (x < -tol * scale_x)) | (~f & (y < -tol * scale_y))
        count = int(infeasible.sum())
        if count == 0:
            x[~f] = 0.0
            return np.maximum(x, 0.0), True, it, x
        if count < best:
            best, backup, best_x = count, 3, x
            f ^= infeasible
        elif backup > 0:
            backup -= 1
            f ^= infeasible
        else:  # Murty's single-index rule: finite, but can take very many steps
            last = int(np.flatnonzero(infeasible)[-1])
            f[last] = not f[last]
    return x, False, steps, best_x


def _active_set(
    route: Route, x0: Array, tol: float, scale_y: float, max_iter: int
) -> tuple[Array, int, int]:
    """Lawson–Hanson's primal active-set method on the route's passive solves (after
    ``route.start``), from the feasible point max(x0, 0). x stays feasible and the objective
    decreases every step, so it cannot cycle; an index the multiplier test lets in but the
    solve throws straight out (rounding) is not tried again. Returns (x̃, status, solves)."""
    x = np.maximum(x0, 0.0)
    f = x > 0
    tabu = np.zeros(f.size, dtype=bool)
    entered, used = -1, 0
    while used < max_iter:
        s = route.solve_on(f)
        used += 1
        if not np.all(np.isfinite(s)):
            return np.zeros(f.size), NUMERICAL, used
        bad = f & ~(s > 0)
        if bad.any():  # step towards s until the first passive value reaches zero
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.nan_to_num(x[bad] / (x[bad] - s[bad]), nan=0.0, posinf=0.0)
            x = x + float(np.clip(ratio.min(), 0.0, 1.0)) * (s - x)
            f &= x > np.finfo(float).eps * max(float(np.abs(x).max()), np.finfo(float).tiny)
            x[~f] = 0.0
            if entered >= 0 and not f[entered]:
                tabu[entered] = True
            continue
        x = s
        y = route.gradient(x)
        free = ~f & ~tabu & (y < -tol * scale_y)
        if not free.any():
            return np.maximum(x, 0.0), CONVERGED, used
        entered = int(np.argmin(np.where(free, y, np.inf)))  # most negative multiplier
        f[entered] = True
    return np.maximum(x, 0.0), MAX_ITER, used


def fista(route: Route, d: Array, x0: Array, tol: float, max_iter: int) -> tuple[Array, int, int]:
    """Projected FISTA with gradient restart from ``x0`` (original variables); returns
    (x, status, iterations)."""
    g = route.start(d)
    if float(np.abs(g).max()) == 0.0:
        return np.zeros(g.size), CONVERGED, 0
    x, status, it = _accelerated(route, g, np.maximum(route.from_x(x0), 0.0), tol, max_iter)
    return route.to_x(x), status, it


def _accelerated(
    route: Route, g: Array, x: Array, tol: float, max_iter: int
) -> tuple[Array, int, int]:
    """FISTA in the route's variables from feasible ``x``; stops when the gradient mapping is
    below tol·max|g| (zero exactly at a KKT point)."""
    scale = float(np.abs(g).max())
    step = 1.0 / route.lipschitz
    z = x.copy()
    t = 1.0
    for it in range(1, max_iter + 1):
        x_new = np.maximum(z - step * route.gradient(z), 0.0)
        mapping = z - x_new
        if np.abs(mapping).max() <= tol * scale * step:
            return x_new, CONVERGED, it
        move = x_new - x
        if np.dot(mapping, move) > 0:  # momentum points uphill: restart
            t, z = 1.0, x_new
        else:
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            z = x_new + ((t - 1.0) / t_new) * move
            t = t_new
        x = x_new
    return x, MAX_ITER, max_iter
