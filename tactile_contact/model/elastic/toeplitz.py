"""Regular-grid fast path: Toeplitz-block-Toeplitz influence operators and FFT products.

On an nx × ny grid of identical cells whose centres are also the measurement points, the
coefficient between cells (i1, j1) and (i2, j2) depends only on (|i1 − i2|, |j1 − j2|) (both
kernels are even in x and y), so the nx·ny distinct values in `kernel` define the whole
(nx·ny)² matrix. Products cost O(n log n) through a zero-padded 2-D FFT (circulant embedding),
and the dense matrix is never formed unless `.dense()` is called.

Vectors are flattened in C order of an (nx, ny) array: index = i·ny + j, cell centre
(i·pitch_x, j·pitch_y) relative to the first cell — the order of
``np.stack(np.meshgrid(x, y, indexing="ij"), -1).reshape(-1, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft as sfft
from numpy.typing import ArrayLike
from scipy.sparse.linalg import LinearOperator

from tactile_contact.model.elastic.boussinesq import (
    Array,
    _effective_zz,
    finite_array,
    material,
    min_magnitude,
    muscari_self,
    positive_array,
)
from tactile_contact.model.elastic.love import love_effective


@dataclass(frozen=True)
class RegularGridOperator:
    """Square influence operator of a regular grid (displacement per unit pressure or force).

    Attributes:
        kernel: (nx, ny) distinct coefficients; kernel[i, j] couples cells i and j steps apart
            along x and y. [m/Pa] for model "love", [m/N] for model "boussinesq".
        model: "love" or "boussinesq".
    """

    kernel: Array
    model: str
    _spectrum: Array = field(repr=False, compare=False)
    _shape: tuple[int, int] = field(repr=False, compare=False)

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(nx, ny) cells."""
        return self.kernel.shape  # type: ignore[return-value]

    @property
    def shape(self) -> tuple[int, int]:
        """(n, n) with n = nx·ny, the shape of the matrix this operator stands for."""
        n = self.kernel.size
        return (n, n)

    def _apply(self, q: ArrayLike, spectrum: Array) -> Array:
        nx, ny = self.kernel.shape
        n = nx * ny
        v = finite_array("q", q)
        if v.ndim not in (1, 2) or v.shape[0] != n:
            raise ValueError(f"q must have shape ({n},) or ({n}, m), got {v.shape}")
        batch = v.reshape(nx, ny, -1)
        f = sfft.rfft2(batch, s=self._shape, axes=(0, 1), workers=-1)
        f *= spectrum[..., None]
        out = sfft.irfft2(f, s=self._shape, axes=(0, 1), workers=-1)[:nx, :ny]
        return out.reshape(v.shape)

    def matvec(self, q: ArrayLike) -> Array:
        """C·q for q of shape (n,) or (n, m) (pressures [Pa] or forces [N]) → displacements [m]."""
        return self._apply(q, self._spectrum)

    def rmatvec(self, d: ArrayLike) -> Array:
        """Cᵀ·d for d of shape (n,) or (n, m); equals matvec since C is symmetric here."""
        return self._apply(d, np.conj(self._spectrum))

    def dense(self) -> Array:
        """The (n, n) float64 matrix (n = nx·ny); O(n²) memory."""
        nx, ny = self.kernel.shape
        i, j = np.divmod(np.arange(nx * ny), ny)
        return self.kernel[np.abs(i[:, None] - i[None, :]), np.abs(j[:, None] - j[None, :])]

    def as_linear_operator(self) -> LinearOperator:
        """A scipy LinearOperator (for iterative solvers such as scipy.sparse.linalg.cg)."""
        return LinearOperator(self.shape, matvec=self.matvec, rmatvec=self.rmatvec, dtype=float)


def _fft_size(n: int) -> int:
    return sfft.next_fast_len(2 * n - 1, real=True)


def grid_kernel(
    nx: int,
    ny: int,
    pitch_x: float,
    pitch_y: float,
    thickness: float,
    young: float,
    poisson: float,
    model: str = "love",
    psi: str | float = "exact",
) -> Array:
    """(nx, ny) distinct coefficients of a regular grid's influence operator: [i, j] couples
    two cells i and j steps apart along x and y ([m/Pa] for "love", [m/N] for "boussinesq";
    :func:`regular_grid_operator`'s ``kernel``, whose arguments these are). Alone for a
    convolution that needs only some offsets (round_contact.radial_responses)."""
    for name, value in (("nx", nx), ("ny", ny)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    px, py = float(positive_array("pitch_x", pitch_x)), float(positive_array("pitch_y", pitch_y))
    h = float(positive_array("thickness", thickness))
    e, nu = material(young, poisson)
    dx = np.arange(nx)[:, None] * px
    dy = np.arange(ny)[None, :] * py
    if model == "love":
        return love_effective(dx, dy, 0.5 * px, 0.5 * py, h, e, nu)
    if model == "boussinesq":
        self_term = muscari_self(px * py, h, e, psi)
        return min_magnitude(_effective_zz(np.hypot(dx, dy), h, e, nu), self_term)
    raise ValueError(f"model must be 'love' or 'boussinesq', got {model!r}")


def regular_grid_operator(
    nx: int,
    ny: int,
    pitch_x: float,
    pitch_y: float,
    thickness: float,
    young: float,
    poisson: float,
    model: str = "love",
    psi: str | float = "exact",
) -> RegularGridOperator:
    """Fast operator for an nx × ny grid of pitch_x × pitch_y [m] cells, measured at the centres.

    model "love": cells of half-size (pitch/2) under uniform pressure, coefficients [m/Pa] equal
    to :func:`love_matrix`; "boussinesq": point forces at the centres, [m/N], equal to
    :func:`boussinesq_matrix` with area pitch_x·pitch_y and the given psi.
    thickness h [m], young E [Pa], poisson ν ∈ (−1, 0.5].
    """
    kernel = grid_kernel(nx, ny, pitch_x, pitch_y, thickness, young, poisson, model, psi)
    shape = (_fft_size(nx), _fft_size(ny))
    # Circulant embedding of the even kernel: c[i] = K[|i|] for i = −(n−1)..n−1, zero elsewhere.
    c = np.zeros(shape)
    c[:nx, :ny] = kernel
    c[shape[0] - nx + 1 :, :ny] = kernel[:0:-1, :]
    c[:, shape[1] - ny + 1 :] = c[:, ny - 1 : 0 : -1]
    spectrum = sfft.rfft2(c, workers=-1)
    return RegularGridOperator(np.ascontiguousarray(kernel), model, spectrum, shape)
