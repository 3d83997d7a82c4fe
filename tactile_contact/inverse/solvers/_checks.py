"""Argument validation shared by the solvers (names and shapes in every message)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def as_matrix(matrix: ArrayLike, name: str = "matrix") -> NDArray[np.float64]:
    """A finite 2-D float64 array with at least one row and column."""
    a = np.asarray(matrix, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 1:
        raise ValueError(f"{name} must be a non-empty 2-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds {int(np.count_nonzero(~np.isfinite(a)))} NaN/inf")
    return a


def as_vector(d: ArrayLike, length: int, name: str = "d") -> NDArray[np.float64]:
    """A finite 1-D float64 array of ``length`` entries."""
    v = np.asarray(d, dtype=np.float64)
    if v.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} holds {int(np.count_nonzero(~np.isfinite(v)))} NaN/inf")
    return v


def as_regulariser(reg: ArrayLike | None, n: int) -> NDArray[np.float64] | None:
    """None, or a finite (p, n) matrix."""
    if reg is None:
        return None
    r = as_matrix(reg, "regulariser")
    if r.shape[1] != n:
        raise ValueError(f"regulariser must have {n} columns (one per unknown), got {r.shape}")
    return r


def non_negative(value: float, name: str) -> float:
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return float(value)
