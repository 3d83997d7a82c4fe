"""Inverse solvers: regularised linear operators from one SVD, and warm-started NNLS.

- :class:`SvdInverse`: pseudo-inverse, truncated SVD and Tikhonov operators (filter factors of
  one offline SVD; generalised Tikhonov with a regulariser L), λ by GCV, L-curve or the
  discrepancy principle.
- :class:`NnlsSolver` / :func:`nnls`: min ‖Ax − d‖² + λ²‖Lx‖², x ≥ 0, by block principal
  pivoting or FISTA, warm-started from the previous frame.

Every solve returns a :class:`SolveResult` (status, message, iterations, residual) instead of
raising on numerical trouble; invalid arguments raise ValueError naming the argument.
"""

from tactile_contact.solvers.linear import SvdInverse
from tactile_contact.solvers.nnls import METHODS, NnlsSolver, nnls
from tactile_contact.solvers.result import SolveResult

__all__ = ["METHODS", "NnlsSolver", "SolveResult", "SvdInverse", "nnls"]
