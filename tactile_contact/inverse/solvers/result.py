"""The result object every solver returns (scipy.optimize style: status, not exceptions)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SolveResult:
    """Outcome of one solve.

    Attributes:
        x: (N,) solution (pressures [Pa] when the matrix maps pressures to deflections).
        success: the solver met its optimality test; False still carries the last iterate.
        status: 0 converged, 1 iteration limit reached, 2 numerical failure.
        message: one line saying which.
        iterations: outer iterations (block exchanges for BPP, gradient steps for FISTA).
        residual_norm: ‖A·x − d‖ in the units of d.
        passive: (N,) bool, the cells left free (x > 0) at the end, or None.
        time_s: wall time of the solve [s].
    """

    x: NDArray[np.float64]
    success: bool
    status: int
    message: str
    iterations: int
    residual_norm: float
    passive: NDArray[np.bool_] | None
    time_s: float


CONVERGED, MAX_ITER, NUMERICAL = 0, 1, 2
