"""The numerical kernels of the NNLS solver: two passive-set routes, pivoting and FISTA.

A route owns the matrices of one problem and offers, per frame, the unconstrained solution on
a passive set F and the gradient y = Hx − g, in its own variables (scaled for the diagonal
route). Kernels only raise numpy/scipy's own errors; NnlsSolver turns them into a status.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse.linalg
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf as potrf
from scipy.linalg.lapack import dpotrs as potrs

from tactile_contact.solvers.result import CONVERGED, MAX_ITER, NUMERICAL

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
# Rank-one updates of the K-space matrix accumulate rounding ~ eps·‖Ã‖²; rebuild it after this
# many updates, or when more columns change at once than a fresh product would cost.
REFRESH_UPDATES = 64


def _cholesky_solve(h: Array, rhs: Array) -> Array:
    """Solve H·x = rhs for symmetric positive definite H; LAPACK directly, as
    scipy's cho_factor wrapper checks cost more than a 72 × 72 factorisation."""
    c, info = potrf(h, lower=False, clean=False)
    if info == 0:
        x, info = potrs(c, rhs, lower=False)
        if info == 0:
            return x
    # Not numerically positive definite: the minimum-norm solution of the same equations.
    return scipy.linalg.lstsq(h, rhs, check_finite=False)[0]


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

    def start(self, d: Array) -> Array:
        """Prepare a frame; return g̃ = Ãᵀd."""
        self._d = d
        return self.at.T @ d

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
            return x
        if nf < self._m.shape[0]:
            af = self.at[:, f]
            h = af.T @ af
            h[np.diag_indices(nf)] += 1.0
            x[f] = _cholesky_solve(h, af.T @ self._d)
            return x
        z = _cholesky_solve(self._kspace_matrix(f), self._d)
        full = self.at.T @ z
        x[f] = full[f]
        return x

    def gradient(self, x: Array) -> Array:
        """H̃x̃ − g̃ = Ãᵀ(Ãx̃ − d) + x̃."""
        return self.at.T @ (self.at @ x - self._d) + x

    @property
    def lipschitz(self) -> float:
        if self._lipschitz is None:
            small = (
                self.at @ self.at.T if self.at.shape[0] <= self.at.shape[1] else self.at.T @ self.at
            )
            top = scipy.linalg.eigvalsh(small, subset_by_index=[small.shape[0] - 1] * 2)[0]
            self._lipschitz = float(top) + 1.0
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

    def _complement(self, f: Mask, tol: float) -> Array | None:
        if self._inverse is None:
            self.prepare()
            if self._inverse is None:
                return None
        p, g, act = self._inverse, self._g, ~f
        u = p @ np.where(f, g, 0.0)
        if act.any():
            pg = p[:, act]
            u -= pg @ _cholesky_solve(pg[act], u[act])
        u[act] = 0.0
        y = self._h @ u - g
        if np.abs(y[f]).max() > tol * max(float(np.abs(g).max()), np.finfo(float).tiny):
            self._use_inverse = False
            return None
        self._cached = (u, y)
        return u

    def solve_on(self, f: Mask) -> Array:
        nf = int(f.sum())
        ng = f.size - nf
        if self._use_inverse and nf > 0 and ng**3 / 3 + f.size**2 < nf**3 / 3:
            x = self._complement(f, 1e-8)
            if x is not None:
                return x
        x = np.zeros(f.size)
        if nf:
            x[f] = _cholesky_solve(self._h[np.ix_(f, f)], self._g[f])
        return x

    def gradient(self, x: Array) -> Array:
        if self._cached is not None and self._cached[0] is x:
            return self._cached[1]
        return self._h @ x - self._g

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
    """Block principal pivoting from the passive set ``passive``; returns (x, status, steps)."""
    g = route.start(d)
    scale_y = float(np.abs(g).max())
    n = g.size
    if scale_y == 0.0:
        return np.zeros(n), CONVERGED, 0
    f = passive.copy()
    backup, best = 3, n + 1
    x = np.zeros(n)
    for it in range(1, max_iter + 1):
        x = route.solve_on(f)
        if not np.all(np.isfinite(x)):
            return np.zeros(n), NUMERICAL, it
        y = route.gradient(x)
        scale_x = max(float(np.abs(x).max()), np.finfo(float).tiny)
        infeasible = (f & (x < -tol * scale_x)) | (~f & (y < -tol * scale_y))
        count = int(infeasible.sum())
        if count == 0:
            x[~f] = 0.0
            return route.to_x(np.maximum(x, 0.0)), CONVERGED, it
        if count < best:
            best, backup = count, 3
            f ^= infeasible
        elif backup > 0:
            backup -= 1
            f ^= infeasible
        else:  # Murty's single-index rule: finite termination
            last = int(np.flatnonzero(infeasible)[-1])
            f[last] = not f[last]
    return route.to_x(np.maximum(x, 0.0)), MAX_ITER, max_iter


def fista(route: Route, d: Array, x0: Array, tol: float, max_iter: int) -> tuple[Array, int, int]:
    """Projected FISTA with gradient restart from ``x0``; returns (x, status, iterations)."""
    g = route.start(d)
    scale = float(np.abs(g).max())
    if scale == 0.0:
        return np.zeros(g.size), CONVERGED, 0
    step = 1.0 / route.lipschitz
    x = np.maximum(route.from_x(x0), 0.0)
    z = x.copy()
    t = 1.0
    for it in range(1, max_iter + 1):
        x_new = np.maximum(z - step * route.gradient(z), 0.0)
        mapping = z - x_new  # gradient mapping × step: zero exactly at a KKT point
        if np.abs(mapping).max() <= tol * scale * step:
            return route.to_x(x_new), CONVERGED, it
        move = x_new - x
        if np.dot(mapping, move) > 0:  # momentum points uphill: restart
            t, z = 1.0, x_new
        else:
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            z = x_new + ((t - 1.0) / t_new) * move
            t = t_new
        x = x_new
    return route.to_x(x), MAX_ITER, max_iter
