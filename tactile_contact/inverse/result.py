"""Stage 5 of a frame: the result: summary (force, CoP, area, peak), traction and deflection.

From round contacts, the summary is their own (force, centre, disc), and the traction grid is
their rendering on the cells; from a grid solution, the summary is the field's
(:func:`tactile_contact.inverse.summary.summarize`). Grids are made only when asked for. No
ROS import.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.round_contact import FAMILIES, RoundFit, RoundTables
from tactile_contact.inverse.summary import Contact, ContactSummary, summarize
from tactile_contact.model.grids import Grid

#: Sub-samples per cell edge when round contacts are rendered on the traction grid.
RENDER_SUB = 4


@dataclass(frozen=True)
class ContactResult:
    """Result of one frame (SI units).

    Attributes:
        traction: (rows, cols) pressure [Pa] on the traction grid (0 off the skin), or None
            when not requested.
        deflection: (rows, cols) effective deflection u_z(0) − u_z(h) [m] on the deflection
            grid, or None when not requested.
        total_force: net normal force [N].
        cop: centre of pressure (x, y) [m], patch frame; (0, 0) without contact.
        contact_area: area of the cells in contact [m²] (see
            :mod:`tactile_contact.inverse.summary`).
        peak_pressure: largest cell pressure [Pa].
        in_contact: a taxel read above the contact threshold and the solve found pressure.
        solver: which path ran: ``none`` (no contact), ``round``, ``free``, ``nnls``,
            ``pinv``, ``tikhonov`` or ``tsvd``.
        success: the solver converged (False results still hold its last iterate).
        iterations: solver iterations (0 for products).
        residual_norm: ‖C·q − δ‖ [m] over the valid taxels.
        solve_time: wall time of the solve [s].
        taxels_active: valid taxels with |δ| above the contact threshold.
        refined: round contacts replaced the grid solution.
        contacts: the contacts the summary adds up
            (:class:`tactile_contact.inverse.summary.Contact`): one per fitted round contact,
            else the field as one contact; empty without contact.
        taxels_used: valid taxels the solve used (those excluded: ``valid`` False, NaN, out
            of range).
        frames: frames of a held scene this result fuses (1: this frame alone; a
            reconstructor made with ``fuse=True``, :mod:`tactile_contact.inverse.temporal`).
    """

    traction: NDArray[np.float64] | None
    deflection: NDArray[np.float64] | None
    total_force: float
    cop: tuple[float, float]
    contact_area: float
    peak_pressure: float
    in_contact: bool
    solver: str
    success: bool
    iterations: int
    residual_norm: float
    solve_time: float
    taxels_active: int
    refined: bool = False
    contacts: tuple[Contact, ...] = ()
    taxels_used: int = 0
    frames: int = 1


class Request(NamedTuple):
    """What the caller of one frame asked for, and the frame's counts.

    Attributes:
        want_traction, want_deflection: make that grid.
        active: valid taxels above the contact threshold.
        used: taxels used.
        t0: :func:`time.perf_counter` when the solve began [s].
    """

    want_traction: bool
    want_deflection: bool
    active: int
    used: int
    t0: float


class ResultMaker:
    """Makes one patch's :class:`ContactResult` (see module docstring).

    Args:
        traction_grid, deflection_grid: the bundle's grids.
        forward: (K, N) matrix C [m/Pa] (the grid solution's residual).
        deflection_operator: (cells, N) traction → deflection grid [m/Pa] (memory-mapped,
            used on demand: grid solutions only).
        tables: the taxels' radial responses (round contacts' residuals), or None.
        point_tables: true (point) radial responses, for round contacts' deflection grids,
            or None.
        taxel_xy: (K, 2) taxel centres [m].
        params: the bundle's parameters (rel_threshold, min_pressure).
    """

    def __init__(
        self,
        traction_grid: Grid,
        deflection_grid: Grid,
        forward: NDArray[np.float64],
        deflection_operator: Any,
        tables: RoundTables | None,
        point_tables: RoundTables | None,
        taxel_xy: NDArray[np.float64],
        params: Mapping[str, Any],
    ) -> None:
        self.traction_grid = traction_grid
        self.deflection_grid = deflection_grid
        self._forward = forward
        self._deflection_op = deflection_operator
        self._tables = tables
        self._point = point_tables
        self._taxel_xy = taxel_xy
        self._centers = traction_grid.centers()
        self._dg_centers = deflection_grid.centers()
        self._rel_threshold = float(params["rel_threshold"])
        self._min_pressure = float(params["min_pressure"])

    def zero(self, request: Request) -> ContactResult:
        """No contact: zero grids (when asked for), no solve."""
        tg, dg = self.traction_grid, self.deflection_grid
        return ContactResult(
            np.zeros(tg.shape) if request.want_traction else None,
            np.zeros(dg.shape) if request.want_deflection else None,
            0.0,
            (0.0, 0.0),
            0.0,
            0.0,
            False,
            "none",
            True,
            0,
            0.0,
            0.0,
            request.active,
            taxels_used=request.used,
        )

    def residual_of(self, fits: list[RoundFit], frame: Frame) -> float:
        """‖prediction of ``fits`` − readings‖ [m] over the taxels used."""
        assert self._tables is not None
        ok = frame.ok
        pred = sum(self._tables.predict(f, self._taxel_xy[ok]) for f in fits)
        return float(np.linalg.norm(pred - frame.delta[ok]))

    def of_contacts(
        self,
        fits: list[RoundFit],
        residual: float,
        path: str,
        success: bool,
        iterations: int,
        request: Request,
    ) -> ContactResult:
        """The result of round contacts ``fits``: their own force, centre and disc, not their
        2 mm-cell rendering (which loses the part of a contact beyond the skin mask and blurs
        a small disc); of the rendering only the peak, and whether any cell clears
        min_pressure (as summarize would find it: a cell above the threshold exists iff the
        peak is), or, when no cell took them, their own mean pressure."""
        q = self.render(fits)
        contacts = tuple(Contact(f.force, f.center, f.radius, FAMILIES[f.family]) for f in fits)
        force = sum(c.force for c in contacts)
        cop = sum(c.force * np.asarray(c.center) for c in contacts) / force
        peak = max(float(q.max(initial=0.0)), 0.0)
        if not peak > self._min_pressure:
            # No cell took the contacts: they press where the grid has no cells (the middle of
            # the hexagon, 6.8 mm from every taxel, beyond the mask). Their own mean pressure
            # says whether they press: a 1 N sphere there was fitted to 4 % and reported as
            # no contact.
            peak = max(peak, max(c.force / (math.pi * c.radius**2) for c in contacts))
        summary = ContactSummary(
            force,
            (float(cop[0]), float(cop[1])),
            sum(math.pi * c.radius**2 for c in contacts),
            peak,
            peak > self._min_pressure,
        )
        deflection = None
        if request.want_deflection:
            if self._point is not None:
                deflection = self.deflection_grid.to_image(self._deflection_of(fits))
            else:
                deflection = self._field_deflection(q)
        return self._make(
            q, summary, contacts, deflection, path, success, iterations, residual, True, request
        )

    def of_field(
        self, q: NDArray, frame: Frame, path: str, success: bool, iterations: int, request: Request
    ) -> ContactResult:
        """The result of a grid solution q [Pa] per cell: the field's summary."""
        residual = float(np.linalg.norm((self._forward @ q - frame.delta)[frame.ok]))
        s = summarize(
            q,
            self._centers,
            self.traction_grid.cell_area,
            self._rel_threshold,
            self._min_pressure,
        )
        contacts = (Contact.of_field(s),) if s.in_contact else ()
        deflection = self._field_deflection(q) if request.want_deflection else None
        return self._make(
            q, s, contacts, deflection, path, success, iterations, residual, False, request
        )

    def render(self, fits: list[RoundFit]) -> NDArray[np.float64]:
        """Pressure [Pa] of the round contacts ``fits`` on the traction grid: the mean over
        RENDER_SUB² points per cell, scaled so that each contact's cells carry its force (the
        flat punch's integrable edge singularity makes point means uneven, not wrong in sum;
        a part beyond the skin mask lands on the cells at its edge)."""
        from tactile_contact.inverse._round_kernels import render

        out = np.zeros(len(self._centers))
        cell = self.traction_grid.cell_size
        for f in fits:
            punch = FAMILIES[f.family] == "punch"
            render(self._centers, cell, RENDER_SUB, *f.center, f.radius, f.force, punch, out)
        return out

    def _deflection_of(self, fits: list[RoundFit]) -> NDArray[np.float64]:
        """(cells,) effective deflection [m] of the round contacts on the deflection grid's
        cells, from the point-response tables (true deflection: no taxel gain)."""
        assert self._point is not None
        out = np.zeros(len(self._dg_centers))
        for fit in fits:
            out += self._point.predict(fit, self._dg_centers)
        return out

    def _field_deflection(self, q: NDArray) -> NDArray[np.float64]:
        """Deflection image [m] of the pressure field q [Pa] (float32 product)."""
        op = np.asarray(self._deflection_op, np.float32)
        return self.deflection_grid.to_image(op @ q.astype(np.float32)).astype(np.float64)

    def _make(
        self,
        q: NDArray,
        s: ContactSummary,
        contacts: tuple[Contact, ...],
        deflection: NDArray | None,
        path: str,
        success: bool,
        iterations: int,
        residual: float,
        refined: bool,
        request: Request,
    ) -> ContactResult:
        return ContactResult(
            self.traction_grid.to_image(q) if request.want_traction else None,
            deflection,
            s.total_force,
            s.cop,
            s.contact_area,
            s.peak_pressure,
            s.in_contact,
            path,
            success,
            iterations,
            residual,
            time.perf_counter() - request.t0,
            request.active,
            refined,
            contacts,
            taxels_used=request.used,
        )
