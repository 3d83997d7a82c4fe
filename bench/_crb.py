"""Truth presses with their Jacobians, and the Cramér–Rao bound (helper of the issue-16 benches).

:class:`Truth` reproduces :class:`tactile_contact.model.forward.ForwardModel` exactly (the same fine
cells, centred on the contact, of edge min(fine_cell, a/8); the same 8 × 24-point electrode
quadrature; the Love kernel) but keeps the kernel from the fine cells to the taxels: every
force of a press that shares the cell size (a flat punch at any force, a sphere at the forces
whose contact radius is ≥ 8 fine cells) reuses it, and the Jacobian of the readings in
(x, y, force, indenter size) costs only cell pressures on the same cells (central differences
at fixed discretisation). The first press of each truth is checked against
``ForwardModel.compression``.

The bound: with readings y = g(θ) + noise, independent Gaussian noise σ_k per taxel, the
Fisher information is Jᵀ·diag(σ⁻²)·J and any unbiased estimator of F has std ≥ √(I⁻¹)_FF.
Four unknowns: the centre (x, y), the force and the indenter's size (sphere radius R or punch
radius a); the family (sphere or punch) is taken as known, so a fit that must also tell the
shape can do worse. For an efficient estimator with Gaussian errors the median |error| is
0.674 × the bound. Quantised readings are treated as Gaussian with the rounding's variance
(1/12 count²) added: an approximation (the rounding of a reading that moves less than a count
is not random).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.grids import disc_quadrature
from tactile_contact.model.indenters import Indenter

#: Parameters of the Jacobian's columns, in order.
PARAMS = ("x", "y", "force", "size")
#: Central-difference steps: centre [m], force and size (relative).
STEP_XY = 1.0e-5
STEP_REL = 1.0e-3
#: Points per kernel chunk (bounds the memory of the quadrature points × cells block).
CHUNK = 1_500_000


@dataclass(frozen=True)
class Press:
    """One press: indenter, force [N], centre (x, y) [m]."""

    indenter: Indenter
    force: float
    center: tuple[float, float]


class Truth:
    """A taxel response (point value or electrode mean) over an elastic layer; see module doc.

    Args:
        xy: (K, 2) taxel centres [m], bundle order.
        thickness, young, poisson: layer h [m], E [Pa], ν.
        taxel_radius: footprint the taxel averages the compression over [m] (0: point value).
        fine_cell: edge of the fine pressure cells [m] (as ForwardModel).
    """

    def __init__(
        self,
        xy: NDArray[np.float64],
        thickness: float,
        young: float,
        poisson: float,
        taxel_radius: float,
        fine_cell: float = 2.5e-4,
    ) -> None:
        self.xy = np.asarray(xy, dtype=np.float64)
        self.thickness, self.young, self.poisson = float(thickness), float(young), float(poisson)
        self.taxel_radius, self.fine_cell = float(taxel_radius), float(fine_cell)
        q, self._w = disc_quadrature(self.taxel_radius, n_r=8, n_theta=24)
        self._q = len(self._w)
        self._pts = (self.xy[:, None, :] + q[None, :, :]).reshape(-1, 2)
        self._checked = False

    def model(self) -> ForwardModel:
        """The ForwardModel this truth reproduces."""
        return ForwardModel(
            self.xy,
            self.thickness,
            self.young,
            self.poisson,
            fine_cell=self.fine_cell,
            taxel_radius=self.taxel_radius,
        )

    def cell(self, indenter: Indenter, force: float) -> float:
        """ForwardModel's fine cell edge [m] for this contact."""
        a = indenter.contact_radius(force, self.young, self.poisson)
        return min(self.fine_cell, a / 8.0)

    @staticmethod
    def _cells(reach: float, cell: float, center: NDArray) -> NDArray[np.float64]:
        """ForwardModel._cells' lattice (cells centred at ±(k + ½)·cell about the centre) over a
        disc of radius ``reach``: for reach ≥ a it holds every cell ForwardModel uses."""
        n = 2 * math.ceil(reach / cell)
        c1 = (np.arange(n) - n / 2 + 0.5) * cell
        xx, yy = np.meshgrid(c1, c1)
        dx = np.maximum(np.abs(xx) - cell / 2, 0)
        dy = np.maximum(np.abs(yy) - cell / 2, 0)
        keep = dx**2 + dy**2 < reach * reach
        return np.stack((xx[keep], yy[keep]), axis=-1) + center

    def _kernel(self, cells: NDArray, cell: float) -> NDArray[np.float64]:
        """(K, M) compression at the taxels [m] per unit pressure [Pa] on each fine cell."""
        k, q, m = len(self.xy), self._q, len(cells)
        out = np.empty((k, m))
        rows = max(1, CHUNK // max(m * q, 1))  # taxels per chunk
        hs = np.full(2, cell / 2)
        for s in range(0, k, rows):
            e = min(k, s + rows)
            g = love_matrix(
                self._pts[s * q : e * q], cells, hs, self.thickness, self.young, self.poisson
            )
            out[s:e] = self._w @ g.reshape(e - s, q, m)
        return out

    def presses(
        self, indenter: Indenter, forces: list[float], center: NDArray, jacobian: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Readings (len(forces), K) [m] of ``indenter`` at ``center`` [m] pressed with each
        force, and their Jacobians (len(forces), K, 4) in (x [m], y [m], force [N], size [m])
        (None without ``jacobian``)."""
        c = np.asarray(center, dtype=np.float64)
        make = type(indenter)
        size = float(indenter.radius)
        e, nu = self.young, self.poisson
        out = np.empty((len(forces), len(self.xy)))
        jac = np.empty((len(forces), len(self.xy), 4)) if jacobian else None
        groups: dict[float, list[int]] = {}
        for i, f in enumerate(forces):
            groups.setdefault(self.cell(indenter, f), []).append(i)
        for cell, idx in groups.items():
            a_max = max(indenter.contact_radius(forces[i], e, nu) for i in idx)
            # Room for the perturbed contacts (larger force or size, shifted centre).
            reach = a_max * (1.0 + 4.0 * STEP_REL) + 2.0 * STEP_XY + 2.0 * cell
            cells = self._cells(reach, cell, c)
            kern = self._kernel(cells, cell)
            hs = np.full(2, cell / 2)

            def reading(x, y, f, s, kern=kern, cells=cells, hs=hs):
                p = make(s).pressure_on_cells(cells, hs, f, (x, y), e, nu)
                return kern @ p

            for i in idx:
                f = float(forces[i])
                v0 = np.array([c[0], c[1], f, size])
                out[i] = reading(*v0)
                if jac is None:
                    continue
                steps = (STEP_XY, STEP_XY, STEP_REL * f, STEP_REL * size)
                for j, h in enumerate(steps):
                    dv = np.zeros(4)
                    dv[j] = h
                    jac[i, :, j] = (reading(*(v0 + dv)) - reading(*(v0 - dv))) / (2 * h)
        if not self._checked:
            ref = self.model().compression(indenter, float(forces[0]), c)
            err = np.abs(out[0] - ref).max() / max(np.abs(ref).max(), 1e-30)
            if err > 1e-9:
                raise RuntimeError(f"Truth differs from ForwardModel by {err:.2e} (relative)")
            self._checked = True
        return out, jac


def fisher_bound(jac: NDArray, sigma: NDArray) -> NDArray[np.float64]:
    """(4, 4) inverse Fisher information (the Cramér–Rao covariance) of (x, y, F, size) for
    Jacobian ``jac`` (K, 4) and per-taxel noise ``sigma`` (K,) in the reading's units.
    Parameters are rescaled before inverting (they span 1e-6 m to newtons)."""
    s = np.maximum(np.abs(jac).max(axis=0), 1e-300)
    a = (jac / s) / np.asarray(sigma, dtype=np.float64)[:, None]
    fisher = a.T @ a
    try:
        cov = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return np.full((4, 4), np.inf)
    return cov / np.outer(s, s)


def crb(jac: NDArray, sigma: NDArray, force: float) -> tuple[float, float]:
    """(σ_F / F [%], RMS centre error [m]) bounds of one press (see :func:`fisher_bound`)."""
    cov = fisher_bound(jac, sigma)
    sf = math.sqrt(max(cov[2, 2], 0.0)) / force * 100.0
    sc = math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0))
    return sf, sc
