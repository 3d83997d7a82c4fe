"""Linear inverse operators from one offline SVD: pseudo-inverse, truncated SVD, Tikhonov.

For A = U·diag(s)·Vᵀ (K × N, thin SVD in float64) every regularised inverse is
A⁺_f = V·diag(f/s)·Uᵀ with filter factors f: pinv f = [s > rcond·s₁], TSVD f = [i < k],
Tikhonov f = s²/(s² + λ²) (the minimiser of ‖Ax − d‖² + λ²‖x‖²). With a regulariser L
(e.g. a discrete Laplacian for smoothness) Tikhonov minimises ‖Ax − d‖² + λ²‖Lx‖² and the
operator is (AᵀA + λ²LᵀL)⁻¹Aᵀ, formed directly (offline, N ≤ a few thousand).

λ is in the units of the singular values (those of A). Three documented rules pick it from a
representative data vector d: generalised cross-validation (GCV), the corner of the L-curve
(maximum curvature of (log‖r‖, log‖x‖)), and the discrepancy principle ‖A·x_λ − d‖ = τ·σ·√K
for a measurement noise σ. Operators come back dense (N × K, float64); cast them to float32 for
the online product (DESIGN.md §2: 1e-7..1e-6 relative, 2–3× faster).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from tactile_contact.solvers._checks import as_matrix, as_regulariser, as_vector, non_negative

Array = NDArray[np.float64]


class SvdInverse:
    """One SVD of ``matrix`` (K × N), then any regularised inverse operator from it.

    Args:
        matrix: forward operator A (measurements × unknowns).
        regulariser: optional L (p × N) for generalised Tikhonov; None means L = I.
    """

    def __init__(self, matrix: ArrayLike, regulariser: ArrayLike | None = None) -> None:
        self.matrix = as_matrix(matrix)
        self.regulariser = as_regulariser(regulariser, self.matrix.shape[1])
        u, s, vt = scipy.linalg.svd(self.matrix, full_matrices=False, lapack_driver="gesdd")
        self._u, self._s, self._vt = u, s, vt

    @property
    def singular_values(self) -> Array:
        """Singular values of A, descending (units of A)."""
        return self._s.copy()

    @property
    def condition_number(self) -> float:
        """s_max / s_min (inf when A is rank deficient)."""
        smin = self._s[-1]
        return float(self._s[0] / smin) if smin > 0 else float("inf")

    # -- filter factors ------------------------------------------------------------------
    def filter_factors(self, method: str, param: float) -> Array:
        """Filter factors f_i for ``method`` ∈ {pinv (rcond), tsvd (rank k), tikhonov (λ)}."""
        s = self._s
        if method == "pinv":
            rcond = non_negative(param, "rcond")
            return (s > rcond * s[0]).astype(np.float64)
        if method == "tsvd":
            k = int(param)
            if not 0 <= k <= s.size:
                raise ValueError(f"rank must be in 0..{s.size}, got {param!r}")
            return (np.arange(s.size) < k).astype(np.float64)
        if method == "tikhonov":
            lam = non_negative(param, "lam")
            return s**2 / (s**2 + lam**2) if lam > 0 else (s > 0).astype(np.float64)
        raise ValueError(f"method must be pinv, tsvd or tikhonov, got {method!r}")

    def _from_filter(self, f: Array) -> Array:
        s = self._s
        scale = np.divide(f, s, out=np.zeros_like(s), where=(f > 0) & (s > 0))
        return (self._vt.T * scale) @ self._u.T

    # -- operators -----------------------------------------------------------------------
    def pinv_operator(self, rcond: float = 1e-10) -> Array:
        """(N, K) Moore–Penrose pseudo-inverse, singular values below rcond·s₁ dropped."""
        return self._from_filter(self.filter_factors("pinv", rcond))

    def tsvd_operator(self, k: int) -> Array:
        """(N, K) truncated-SVD inverse keeping the k largest singular values."""
        return self._from_filter(self.filter_factors("tsvd", k))

    def tikhonov_operator(self, lam: float) -> Array:
        """(N, K) Tikhonov inverse for ‖Ax − d‖² + λ²‖Lx‖² (L = I without a regulariser)."""
        lam = non_negative(lam, "lam")
        if self.regulariser is None or lam == 0:
            return self._from_filter(self.filter_factors("tikhonov", lam))
        a, ell = self.matrix, self.regulariser
        gram = a.T @ a + lam**2 * (ell.T @ ell)
        # L's null space (constants for a Laplacian) meets A's near-null space at ν = 0.5; a
        # ridge at rounding level keeps the Cholesky factorisation defined without biasing.
        gram[np.diag_indices_from(gram)] += 1e-13 * np.trace(gram) / gram.shape[0]
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(gram), a.T)

    # -- parameter choice ----------------------------------------------------------------
    def default_lambdas(self, count: int = 60) -> Array:
        """Log-spaced λ from 1e-6·s₁ to s₁."""
        return np.geomspace(1e-6 * self._s[0], self._s[0], count)

    def _curve(self, d: Array, lambdas: Sequence[float]) -> tuple[Array, Array, Array]:
        """Residual norm, solution norm and trace(I − A·A⁺_λ) for each λ."""
        res, sol, dof = [], [], []
        for lam in lambdas:
            op = self.tikhonov_operator(lam)
            x = op @ d
            r = self.matrix @ x - d
            influence = self.matrix @ op
            res.append(np.linalg.norm(r))
            reg = x if self.regulariser is None else self.regulariser @ x
            sol.append(np.linalg.norm(reg))
            dof.append(self.matrix.shape[0] - np.trace(influence))
        return np.asarray(res), np.asarray(sol), np.asarray(dof)

    def choose_lambda(
        self,
        rule: str,
        d: ArrayLike,
        noise: float | None = None,
        lambdas: Sequence[float] | None = None,
        tau: float = 1.0,
    ) -> float:
        """λ by ``rule`` ∈ {gcv, lcurve, discrepancy} for a representative data vector ``d``.

        ``noise`` (σ, units of d) is required by the discrepancy principle; it returns the
        largest λ whose residual stays within τ·σ·√K (the smallest λ when none does).
        """
        dv = as_vector(d, self.matrix.shape[0])
        lams = np.asarray(self.default_lambdas() if lambdas is None else lambdas, dtype=float)
        if lams.ndim != 1 or lams.size < 3 or np.any(lams <= 0):
            raise ValueError("lambdas must be at least 3 positive values")
        res, sol, dof = self._curve(dv, lams)
        if rule == "gcv":
            g = res**2 / np.maximum(dof, 1e-300) ** 2
            return float(lams[int(np.argmin(g))])
        if rule == "discrepancy":
            if noise is None:
                raise ValueError("the discrepancy principle needs the noise level")
            target = tau * non_negative(noise, "noise") * np.sqrt(dv.size)
            ok = np.nonzero(res <= target)[0]
            return float(lams[ok.max()] if ok.size else lams[0])
        if rule == "lcurve":
            x, y = np.log(np.maximum(res, 1e-300)), np.log(np.maximum(sol, 1e-300))
            t = np.log(lams)
            dx, dy = np.gradient(x, t), np.gradient(y, t)
            ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
            kappa = (dx * ddy - dy * ddx) / np.maximum((dx**2 + dy**2) ** 1.5, 1e-300)
            inner = slice(2, -2)
            return float(lams[inner][int(np.argmax(kappa[inner]))])
        raise ValueError(f"rule must be gcv, lcurve or discrepancy, got {rule!r}")
