"""Linear inverse operators from one offline SVD: pseudo-inverse, truncated SVD, Tikhonov.

For A = U·diag(s)·Vᵀ (K × N, thin SVD in float64) every regularised inverse is
A⁺_f = V·diag(f/s)·Uᵀ with filter factors f: pinv f = [s > rcond·s₁], TSVD f = [i < k],
Tikhonov f = s²/(s² + λ²) (the minimiser of ‖Ax − d‖² + λ²‖x‖²).

With a regulariser L (p × N, e.g. a discrete Laplacian for smoothness) Tikhonov minimises
‖Ax − d‖² + λ²‖Lx‖². The problem is brought to standard form once, offline (Eldén 1982;
Hansen, *Rank-Deficient and Discrete Ill-Posed Problems*, §2.3): with W a basis of L's null
space, T = (AW)⁺ and the A-weighted inverse L_A⁺ = (I − W·T·A)·L⁺, the standard-form matrix
Ā = A·L_A⁺ is decomposed instead of A, and x = L_A⁺·x̄ + W·T·d. The same filter factors then
apply to Ā's singular values (TSVD becomes truncated GSVD), and ‖Lx‖ = ‖x̄‖. Null-space
components of L are fitted to the data without regularisation: with L a Neumann Laplacian
(constants in its null space) and ν = 0.5 (A almost blind to a uniform load) that fit is
noise-dominated, so prefer a Dirichlet Laplacian
(:func:`tactile_contact.inverse.solvers.grid_laplacian`).
The pseudo-inverse always inverts A itself (the paper's operator).

λ is in the units of the standard-form singular values (those of A when L = I). Three rules,
all evaluated in closed form from the SVD (no operator formed per trial λ), pick it from a
representative data vector d (:meth:`SvdInverse.choose_lambda`, :meth:`SvdInverse.choose_rank`):
generalised cross-validation (GCV), the L-curve corner (maximum curvature of
(log‖Ax − d‖, log‖Lx‖)) and the discrepancy principle ‖Ax − d‖ = τ·σ·√K for a measurement noise
σ. Operators come back dense (N × K, float64); cast them to float32 for the online product
(DESIGN.md §2: 1e-7..1e-6 relative, 2–3× faster).
"""

from __future__ import annotations

from collections.abc import Sequence

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

Array = NDArray[np.float64]
RULES = ("gcv", "lcurve", "discrepancy")
# Relative level below which a singular value counts as zero (rank decisions, null spaces).
RANK_RTOL = 1e-12


def _svd(a: Array) -> tuple[Array, Array, Array]:
    try:
        return scipy.linalg.svd(a, full_matrices=False, lapack_driver="gesdd")
    except np.linalg.LinAlgError:  # gesdd rarely fails to converge; gesvd is slower, sturdier
        return scipy.linalg.svd(a, full_matrices=False, lapack_driver="gesvd")


class SvdInverse:
    """One SVD of ``matrix`` (K × N), then any regularised inverse operator from it.

    Args:
        matrix: forward operator A (measurements × unknowns), e.g. [m/Pa].
        regulariser: optional L (p × N) for generalised Tikhonov / truncated GSVD; None means
            L = I. Cost offline: one SVD of L (O(N³); about 1 s at N = 2000).
    """

    def __init__(self, matrix: ArrayLike, regulariser: ArrayLike | None = None) -> None:
        self.matrix = as_matrix(matrix)
        self.regulariser = as_regulariser(regulariser, self.matrix.shape[1])
        a = self.matrix
        self._u, self._s, self._vt = _svd(a)
        if self.regulariser is None:
            # Standard form is A itself: basis (N × r) maps filtered coefficients to x.
            self._ub, self._sb, self._basis = self._u, self._s, self._vt.T
            self._x0: Array | None = None  # (N, K) null-space part W·T, absent for L = I
            self._aw_rank = 0
            return
        ell = self.regulariser
        ul, sl, vlt = scipy.linalg.svd(ell, full_matrices=True)
        rank_l = int(np.count_nonzero(sl > RANK_RTOL * max(sl[0], 0.0) * max(ell.shape)))
        if rank_l == 0:
            raise ValueError("regulariser is zero; pass None for the identity")
        lpinv = (vlt[:rank_l].T / sl[:rank_l]) @ ul[:, :rank_l].T  # L⁺ (N × p)
        w = vlt[rank_l:].T  # null space of L (N × q)
        if w.shape[1]:
            aw = a @ w
            t = np.linalg.pinv(aw, rcond=RANK_RTOL)  # (AW)⁺ (q × K)
            self._aw_rank = int(np.linalg.matrix_rank(aw, tol=RANK_RTOL * max(self._s[0], 0.0)))
            l_a = lpinv - w @ (t @ (a @ lpinv))  # L_A⁺ = (I − W T A) L⁺
            self._x0 = w @ t
        else:
            l_a, self._x0, self._aw_rank = lpinv, None, 0
        ub, sb, vbt = _svd(a @ l_a)
        self._ub, self._sb, self._basis = ub, sb, l_a @ vbt.T

    # -- spectra -------------------------------------------------------------------------
    @property
    def singular_values(self) -> Array:
        """Singular values of A, descending (units of A)."""
        return self._s.copy()

    @property
    def standard_form_singular_values(self) -> Array:
        """Singular values of the standard-form matrix Ā (= those of A when L = I); the
        Tikhonov λ and the TSVD rank refer to these."""
        return self._sb.copy()

    @property
    def condition_number(self) -> float:
        """s_max / s_min of A (inf when A is rank deficient)."""
        smin = self._s[-1]
        return float(self._s[0] / smin) if smin > RANK_RTOL * self._s[0] else float("inf")

    # -- filter factors ------------------------------------------------------------------
    def filter_factors(self, method: str, param: float) -> Array:
        """Filter factors f_i for ``method`` ∈ {pinv (rcond), tsvd (rank k), tikhonov (λ)}.

        pinv filters A's singular values; tsvd and tikhonov filter the standard-form ones.
        """
        if method == "pinv":
            rcond = non_negative(param, "rcond")
            s = self._s
            return (s > max(rcond, RANK_RTOL) * s[0]).astype(np.float64)
        s = self._sb
        if method == "tsvd":
            k = int(param)
            if k != param or not 0 <= k <= s.size:
                raise ValueError(f"rank must be an integer in 0..{s.size}, got {param!r}")
            return ((np.arange(s.size) < k) & (s > RANK_RTOL * s[0])).astype(np.float64)
        if method == "tikhonov":
            lam = non_negative(param, "lam")
            if lam == 0:
                return (s > RANK_RTOL * s[0]).astype(np.float64)
            return s**2 / (s**2 + lam**2)
        raise ValueError(f"method must be pinv, tsvd or tikhonov, got {method!r}")

    def _standard(self, f: Array) -> Array:
        s = self._sb
        scale = np.divide(f, s, out=np.zeros_like(s), where=(f > 0) & (s > 0))
        op = (self._basis * scale) @ self._ub.T
        return op if self._x0 is None else op + self._x0

    # -- operators -----------------------------------------------------------------------
    def pinv_operator(self, rcond: float = 1e-10) -> Array:
        """(N, K) Moore–Penrose pseudo-inverse of A, singular values ≤ rcond·s₁ dropped."""
        f = self.filter_factors("pinv", rcond)
        scale = np.divide(f, self._s, out=np.zeros_like(f), where=f > 0)
        return (self._vt.T * scale) @ self._u.T

    def tsvd_operator(self, k: int) -> Array:
        """(N, K) truncated (G)SVD inverse keeping the k largest standard-form singular values."""
        return self._standard(self.filter_factors("tsvd", k))

    def tikhonov_operator(self, lam: float) -> Array:
        """(N, K) Tikhonov inverse for ‖Ax − d‖² + λ²‖Lx‖² (L = I without a regulariser)."""
        return self._standard(self.filter_factors("tikhonov", lam))

    # -- parameter choice ----------------------------------------------------------------
    def default_lambdas(self, count: int = 200) -> Array:
        """Log-spaced λ from 1e-6·s̄₁ to s̄₁ (s̄: standard-form singular values)."""
        return np.geomspace(1e-6 * self._sb[0], self._sb[0], count)

    def _coefficients(self, d: ArrayLike) -> tuple[Array, float]:
        """β = Ūᵀd̄ and ‖d̄ − Ūβ‖² (the part of d no filter can fit), d̄ = d − A·W·T·d."""
        dv = as_vector(d, self.matrix.shape[0])
        dbar = dv if self._x0 is None else dv - self.matrix @ (self._x0 @ dv)
        beta = self._ub.T @ dbar
        return beta, float(np.sum((dbar - self._ub @ beta) ** 2))

    def _norms(self, beta: Array, r0: float, f: Array) -> tuple[float, float, float]:
        """‖Ax − d‖, ‖Lx‖ (‖x‖ for L = I) and K − trace(A·A⁺_f) for filter factors f."""
        s = self._sb
        res = float(np.sqrt(np.sum(((1 - f) * beta) ** 2) + r0))
        coef = np.divide(f * beta, s, out=np.zeros_like(s), where=s > 0)
        dof = self.matrix.shape[0] - float(f.sum()) - self._aw_rank
        return res, float(np.linalg.norm(coef)), dof

    def tikhonov_curve(
        self, d: ArrayLike, lambdas: Sequence[float] | None = None
    ) -> tuple[Array, Array, Array, Array]:
        """(λ, ‖Ax_λ − d‖, ‖Lx_λ‖, K − trace(influence)) per λ, in closed form from the SVD.

        The (log residual, log seminorm) pair is the L-curve; plot it to see the corner.
        """
        lams = np.asarray(self.default_lambdas() if lambdas is None else lambdas, dtype=float)
        if lams.ndim != 1 or lams.size < 3 or not np.all(np.isfinite(lams) & (lams > 0)):
            raise ValueError(f"lambdas must be at least 3 positive finite values, got {lams!r}")
        beta, r0 = self._coefficients(d)
        rows = [self._norms(beta, r0, self.filter_factors("tikhonov", lam)) for lam in lams]
        res, sol, dof = (np.asarray(c) for c in zip(*rows, strict=True))
        return lams, res, sol, dof

    def choose_lambda(
        self,
        rule: str,
        d: ArrayLike,
        noise: float | None = None,
        lambdas: Sequence[float] | None = None,
        tau: float = 1.0,
    ) -> float:
        """Tikhonov λ by ``rule`` for a representative data vector ``d`` (units of d).

        - ``gcv``: minimiser of ‖Ax_λ − d‖² / (K − trace(A·A⁺_λ))² over ``lambdas``.
        - ``lcurve``: maximum curvature of (log‖Ax_λ − d‖, log‖Lx_λ‖) over ``lambdas``.
        - ``discrepancy``: the λ with ‖Ax_λ − d‖ = τ·σ·√K, σ = ``noise`` (required, units
          of d); the smallest λ of the range when even it misfits, the largest when all fit.

        ``lambdas`` defaults to :meth:`default_lambdas` (200 values over six decades).
        """
        if rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
        if rule == "discrepancy" and noise is None:
            raise ValueError("the discrepancy principle needs the noise level (noise=σ)")
        lams, res, sol, dof = self.tikhonov_curve(d, lambdas)
        if rule == "gcv":
            g = res**2 / np.maximum(dof, 1e-12) ** 2
            return float(lams[int(np.argmin(g))])
        if rule == "lcurve":
            return float(lams[_corner(np.log(lams), res, sol)])
        target = _target(tau, noise, self.matrix.shape[0])
        if res[0] >= target:
            return float(lams[0])
        if res[-1] <= target:
            return float(lams[-1])
        beta, r0 = self._coefficients(d)

        def misfit(log_lam: float) -> float:
            f = self.filter_factors("tikhonov", float(np.exp(log_lam)))
            return self._norms(beta, r0, f)[0] - target

        hi = int(np.argmax(res > target))  # residual grows with λ: bracket the crossing
        root = scipy.optimize.brentq(misfit, np.log(lams[hi - 1]), np.log(lams[hi]), xtol=1e-6)
        return float(np.exp(root))

    def choose_rank(
        self, rule: str, d: ArrayLike, noise: float | None = None, tau: float = 1.0
    ) -> int:
        """TSVD rank k ≥ 1 by ``rule`` (same rules as :meth:`choose_lambda`).

        ``discrepancy`` returns the smallest k with ‖Ax_k − d‖ ≤ τ·σ·√K (the full rank when none
        does); ``lcurve`` the point of the discrete L-curve furthest from the chord joining its
        ends (in log–log coordinates).
        """
        if rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
        if rule == "discrepancy" and noise is None:
            raise ValueError("the discrepancy principle needs the noise level (noise=σ)")
        beta, r0 = self._coefficients(d)
        rmax = int(np.count_nonzero(self._sb > RANK_RTOL * self._sb[0]))
        ks = np.arange(1, max(rmax, 1) + 1)
        rows = [self._norms(beta, r0, self.filter_factors("tsvd", k)) for k in ks]
        res, sol, dof = (np.asarray(c) for c in zip(*rows, strict=True))
        if rule == "gcv":
            return int(ks[int(np.argmin(res**2 / np.maximum(dof, 1e-12) ** 2))])
        if rule == "discrepancy":
            target = _target(tau, noise, self.matrix.shape[0])
            ok = np.nonzero(res <= target)[0]
            return int(ks[ok[0]] if ok.size else ks[-1])
        if ks.size < 3:
            return int(ks[-1])
        x, y = np.log(np.maximum(res, 1e-300)), np.log(np.maximum(sol, 1e-300))
        chord = np.array([x[-1] - x[0], y[-1] - y[0]])
        dist = np.abs(chord[0] * (y - y[0]) - chord[1] * (x - x[0]))
        return int(ks[int(np.argmax(dist))])


def _target(tau: float, noise: float | None, k: int) -> float:
    """τ·σ·√K, the residual norm the discrepancy principle aims at (units of d)."""
    return non_negative(tau, "tau") * non_negative(float(noise or 0.0), "noise") * float(np.sqrt(k))


def _corner(t: Array, res: Array, sol: Array) -> int:
    """Index of maximum curvature of (log res, log sol) parametrised by t = log λ."""
    x, y = np.log(np.maximum(res, 1e-300)), np.log(np.maximum(sol, 1e-300))
    dx, dy = np.gradient(x, t), np.gradient(y, t)
    ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
    # With λ increasing the curve runs down the steep branch and turns left onto the flat one:
    # a counter-clockwise turn, so the corner is the largest positive signed curvature.
    kappa = (dx * ddy - dy * ddx) / np.maximum((dx**2 + dy**2) ** 1.5, 1e-300)
    inner = slice(2, -2)
    return int(np.argmax(kappa[inner])) + 2
