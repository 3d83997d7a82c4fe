"""Inverse solvers: regularised linear operators from one SVD, and warm-started NNLS.

- :class:`SvdInverse`: pseudo-inverse, truncated (G)SVD and Tikhonov operators (filter factors
  of one offline SVD; a regulariser L by standard-form transformation), λ or rank by GCV,
  L-curve or the discrepancy principle.
- :class:`NnlsSolver` / :func:`nnls`: min ‖Ax − d‖² + λ²‖Lx‖², x ≥ 0, by block principal
  pivoting or FISTA, warm-started from the previous frame.
- :func:`grid_laplacian`, :func:`support_weights`: smoothness and compact-support priors L.

Every NNLS solve returns a :class:`SolveResult` (status, message, iterations, residual) instead
of raising on numerical trouble; invalid arguments raise ValueError naming the argument.
See docs/solvers.md.
"""

from tactile_contact.inverse.solvers.linear import RULES, SvdInverse
from tactile_contact.inverse.solvers.nnls import METHODS, NnlsSolver, nnls
from tactile_contact.inverse.solvers.priors import grid_laplacian, support_weights
from tactile_contact.inverse.solvers.result import CONVERGED, MAX_ITER, NUMERICAL, SolveResult

__all__ = [
    "CONVERGED",
    "MAX_ITER",
    "METHODS",
    "NUMERICAL",
    "RULES",
    "NnlsSolver",
    "SolveResult",
    "SvdInverse",
    "grid_laplacian",
    "nnls",
    "support_weights",
]
