"""Stage 4 of a frame, when no round contact explains the readings: the grid solution.

q = C⁺_λ·δ with the bundle's precomputed regularised inverse (the "free" solution); where it
goes negative beyond noise, two passes of non-negative Tikhonov least squares (near the taxels
reading a contact or the whole grid, then near the first pass's strong cells:
docs/reconstruction.md); then round contacts fitted around it replace it when they explain the
readings about as well. The paper's methods (``tikhonov``, ``tsvd``, ``pinv``) and
``refine: none`` use the free solution alone. Prepared solvers are cached per set of valid
taxels. No ROS import.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.contacts import (
    CONTACT_SEED_LEVEL,
    ContactFitter,
    on_skin,
    skin_hull,
)
from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.round_contact import RoundFit, RoundTables
from tactile_contact.model.grids import distance_to_points

#: Operators and solvers kept, one per set of valid taxels (and pass): the full set and a few
#: sets with taxels out. Each prepared NNLS solver holds N × N float64 (2.6 MB at N = 568).
SOLVER_CACHE_SIZE = 8

#: The first NNLS pass keeps the cells within this distance [m] of the taxels reading a
#: contact (above CONTACT_SEED_LEVEL thresholds), when they are at most FIRST_PASS_MAX_CELLS;
#: else it solves the whole grid. Chosen on the bench's fallback frames: forces as the
#: whole-grid pass gave them, 1.7-1.9 instead of 2.3-2.9 ms per frame.
FIRST_PASS_REACH = 6.0e-3
FIRST_PASS_MAX_CELLS = 150
#: The second pass (near the first pass's strong cells) runs only on this many cells at most.
SECOND_PASS_MAX_CELLS = 150
#: Round contacts fitted around the grid solution are kept only if their residual is at most
#: this factor times the grid solution's plus the noise.
FIT_RESIDUAL_FACTOR = 1.5


@dataclass(frozen=True)
class GridSolution:
    """The stage's result.

    Attributes:
        q: (N,) pressure [Pa] per traction cell (the grid solution, even when ``fits``
            replace it in the summary).
        path: ``free``, ``nnls`` or the paper's method name.
        success, iterations: of the constrained solver (True, 0 for products).
        fits: round contacts fitted around q that explain the readings about as well, or
            None.
    """

    q: NDArray[np.float64]
    path: str
    success: bool
    iterations: int
    fits: list[RoundFit] | None


def regularised_inverse(
    matrix: NDArray, method: str, lam: float, reg: NDArray | None, rcond: float, rank: int
) -> NDArray[np.float64]:
    """(N, K) free inverse: ``pinv`` (rcond), ``tsvd`` (rank) or Tikhonov (λ, regulariser L),
    all from one SVD (:class:`tactile_contact.inverse.solvers.SvdInverse`)."""
    from tactile_contact.inverse.solvers import SvdInverse

    inv = SvdInverse(matrix, regulariser=reg)
    if method == "pinv":
        return np.asarray(inv.pinv_operator(rcond), dtype=np.float64)
    if method == "tsvd":
        return np.asarray(inv.tsvd_operator(rank), dtype=np.float64)
    return np.asarray(inv.tikhonov_operator(lam), dtype=np.float64)


def nnls_solver(matrix: NDArray, tikhonov: float, regulariser: NDArray | None, method: str) -> Any:
    """A warm-startable solver of min ‖Ax − d‖² + λ²‖Lx‖², x ≥ 0 (NnlsSolver)."""
    from tactile_contact.inverse.solvers import NnlsSolver

    return NnlsSolver(matrix, tikhonov=tikhonov, regulariser=regulariser, method=method)


class GridFallback:
    """The grid path of one patch (see module docstring).

    Args:
        forward: (K, N) matrix C [m/Pa] from traction cells to taxel compressions.
        inverse: (N, K) the bundle's free inverse (used as float32).
        regulariser: (M, N) Tikhonov operator L, or None (identity).
        taxel_xy: (K, 2) taxel centres [m].
        centres: (N, 2) traction cell centres [m].
        params: the bundle's parameters (method, noise, tikhonov, tsvd_rank, rcond,
            nnls_method, seed_fraction, support_radius, contact_threshold).
        tables: radial responses for the round contacts fitted around the solution, or None.
    """

    def __init__(
        self,
        forward: NDArray[np.float64],
        inverse: NDArray,
        regulariser: NDArray | None,
        taxel_xy: NDArray[np.float64],
        centres: NDArray[np.float64],
        params: Mapping[str, Any],
        tables: RoundTables | None,
    ) -> None:
        self.forward = forward
        self.inverse = np.asarray(inverse, dtype=np.float32)
        self._regulariser = regulariser
        self._taxel_xy = taxel_xy
        self._centres = centres
        self._params = params
        self.method = str(params["method"])
        self.noise = float(params["noise"])
        self.contact_threshold = float(params["contact_threshold"])
        self.tables = tables
        self._skin = skin_hull(taxel_xy)
        # Per-cell noise of the free solution, for the "violates non-negativity" test.
        self._cell_noise = self.noise * np.linalg.norm(self.inverse.astype(np.float64), axis=1)
        # Per set of valid taxels (a taxel drops out, comes back): bounded, so a flickering
        # taxel cannot grow it without end (each prepared NNLS solver holds an N × N matrix).
        self.solvers: OrderedDict[bytes, Any] = OrderedDict()
        self._seen: OrderedDict[bytes, int] = OrderedDict()

    def solve(
        self, frame: Frame, count_sigma: float, fit_sigma: float, max_contacts: int
    ) -> GridSolution:
        """The grid solution of ``frame``, then round contacts fitted around it
        (``count_sigma``, ``fit_sigma`` [m] and ``max_contacts`` as in
        :class:`tactile_contact.inverse.contacts.ContactFitter`)."""
        delta, ok = frame.delta, frame.ok
        success, iterations, path = True, 0, self.method
        if ok.all():
            q = (self.inverse @ delta.astype(np.float32)).astype(np.float64)
        else:
            q = self._masked_free(ok) @ delta[ok]
        if self.method == "nnls_tikhonov":
            path = "free"
            # A net pull is no contact a skin can feel: it too needs the constrained solve.
            if q.sum() <= 0 or np.any(q < -3.0 * self._cell_noise):
                path = "nnls"
                q, success, iterations = self._constrained(delta, ok)
        fits = None
        if self.tables is not None:
            estimate = frame.estimate and frame.frames == 1
            fits = self._round_fit(q, delta, ok, count_sigma, fit_sigma, max_contacts, estimate)
        return GridSolution(q, path, success, iterations, fits)

    def _round_fit(
        self,
        q: NDArray,
        delta: NDArray,
        ok: NDArray,
        count_sigma: float,
        fit_sigma: float,
        max_contacts: int,
        estimate: bool = False,
    ) -> list[RoundFit] | None:
        """Round contacts started at q's centre of pressure, or None when they explain the
        data clearly worse than q; ``estimate``: no noise level was passed with the frame,
        the contacts' evidence is weighed in the noise the far taxels read."""
        assert self.tables is not None
        xy, d = self._taxel_xy[ok], delta[ok]
        pos = q > 0
        cop = (q[pos] @ self._centres[pos]) / q[pos].sum() if pos.any() else None
        fitter = ContactFitter(
            self.tables,
            count_sigma,
            self.contact_threshold,
            sigma=fit_sigma if fit_sigma > 0 else None,
            max_contacts=max_contacts,
            estimate_noise=estimate,
        )
        found = fitter.fit(xy, d, cop)
        if found is None:
            return None
        fits, residual = found
        if not all(on_skin(self._skin, f.center) for f in fits):
            # (as the search's fits: a contact centred off the skin explains the edge taxels
            # with a force no taxel reads — 32.6 N 2.4 mm beyond the edge for a 5.1 N field,
            # in 7 of 400 noise draws of one press at the hexagon's edge)
            return None
        r_grid = float(np.linalg.norm(self.forward[ok] @ q - d))
        if residual > FIT_RESIDUAL_FACTOR * r_grid + self.noise * math.sqrt(ok.sum()):
            return None
        return fits

    # --- the constrained solve --------------------------------------------------------------

    def _constrained(self, delta: NDArray, ok: NDArray) -> tuple[NDArray, bool, int]:
        # First pass on the cells near the taxels that read a contact, when they are few (one
        # or two presses): a small cold problem for scipy (~0.3 ms) instead of pivoting over the
        # whole grid (~1.1 ms); the pressure it leaves out lies under taxels reading nothing.
        xy, d = self._taxel_xy[ok], delta[ok]
        lit = d > CONTACT_SEED_LEVEL * self.contact_threshold
        near = None
        if lit.any():
            near = distance_to_points(self._centres, xy[lit]) <= FIRST_PASS_REACH
        if near is not None and 0 < near.sum() <= FIRST_PASS_MAX_CELLS:
            q1 = np.zeros(len(self._centres))
            q1[near], s1, it1 = self._nnls(near, ok, delta, warm=False, method="lawson_hanson")
        else:
            q1, s1, it1 = self._nnls(None, ok, delta, warm=True)
        peak = q1.max(initial=0.0)
        if peak <= 0:
            return q1, s1, it1
        p = self._params
        seeds = self._centres[q1 >= float(p["seed_fraction"]) * peak]
        cols = distance_to_points(self._centres, seeds) <= float(p["support_radius"])
        if cols.sum() > SECOND_PASS_MAX_CELLS:
            # Seeds all over the grid (a faint frame: pressure spread thin): the support is no
            # smaller than the first pass's, and scipy on 500 columns takes 40-50 ms.
            return q1, s1, it1
        # The support is a few tens of cells, solved once: scipy's Lawson–Hanson on the
        # stacked system beats building a pivoting route in Python (~50 vs ~350 µs).
        q2, s2, it2 = self._nnls(cols, ok, delta, warm=False, method="lawson_hanson")
        q = np.zeros_like(q1)
        q[cols] = q2
        return q, s1 and s2, it1 + it2

    def _nnls(
        self, cols: NDArray | None, ok: NDArray, delta: NDArray, warm: bool, method: str = ""
    ) -> tuple[NDArray[np.float64], bool, int]:
        key = np.packbits(ok).tobytes() + (b"" if cols is None else np.packbits(cols).tobytes())
        solver = self._cached(key) if warm else None
        if solver is None:
            a = self.forward[ok] if cols is None else self.forward[np.ix_(ok, cols)]
            reg = self._regulariser
            if reg is not None and cols is not None:
                reg = reg[:, cols]
            solver = nnls_solver(
                a,
                float(self._params["tikhonov"]),
                reg,
                method or str(self._params["nnls_method"]),
            )
            if warm and (ok.all() or self._recurring(key)):
                # Kept across frames: the one-off work (H⁻¹ on the Gram route) pays off.
                self._cache(key, solver.prepare())
        res = solver.solve(delta[ok], warm_start=warm)
        return np.asarray(res.x, dtype=np.float64), bool(res.success), int(res.iterations)

    def _masked_free(self, ok: NDArray) -> NDArray[np.float64]:
        """Free inverse for a subset of taxels (cached per subset; rows of C dropped)."""
        key = b"free" + np.packbits(ok).tobytes()
        inverse = self._cached(key)
        if inverse is None:
            p = self._params
            a = self.forward[ok]
            rank = min(int(p["tsvd_rank"] or min(a.shape)), *a.shape)
            inverse = self._cache(
                key,
                regularised_inverse(
                    a,
                    self.method,
                    float(p["tikhonov"]),
                    self._regulariser,
                    float(p["rcond"]),
                    rank,
                ),
            )
        return inverse

    # --- caches -------------------------------------------------------------------------------

    def _cached(self, key: bytes) -> Any:
        """The cached operator or solver under ``key`` (None if absent), now most recent."""
        if key not in self.solvers:
            return None
        self.solvers.move_to_end(key)
        return self.solvers[key]

    def _cache(self, key: bytes, value: Any) -> Any:
        self.solvers[key] = value
        while len(self.solvers) > SOLVER_CACHE_SIZE:
            self.solvers.popitem(last=False)
        return value

    def _recurring(self, key: bytes) -> bool:
        """True from the second frame with this set of valid taxels on (counted for the last
        SOLVER_CACHE_SIZE sets): a set met once, a taxel flickering out for one frame, is not
        worth a prepared solver's N³ set-up."""
        n = self._seen.pop(key, 0) + 1
        self._seen[key] = n
        while len(self._seen) > 4 * SOLVER_CACHE_SIZE:
            self._seen.popitem(last=False)
        return n >= 2
