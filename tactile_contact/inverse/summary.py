"""Contact summary of a pressure field: total force, centre of pressure, contact area, peak.

Definitions (pressure p [Pa] on cells of area A [m²], centres x_i [m]):

- total force F = Σ p_i·A (net normal force [N]; negative cells, possible with unconstrained
  solvers, count with their sign);
- centre of pressure = Σ p_i·x_i / Σ p_i over the cells with p_i > 0 (patch frame [m]); with no
  positive pressure it is undefined and reported as (0, 0) together with ``in_contact=False``;
- peak pressure = max p_i [Pa] (0 when no cell is positive);
- contact area = A × number of cells *in contact*. A cell is in contact when
  p_i > max(rel_threshold·peak, min_pressure): by default 10 % of the peak (the Hertz
  profile is above 10 % of its peak over 99.5 % of its true radius) and 100 Pa (a 2 mm cell at
  100 Pa carries 0.4 mN, below anything 8-bit taxels resolve). Both are arguments, not hidden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: Default relative threshold (fraction of the peak pressure) for "in contact".
REL_THRESHOLD = 0.1
#: Default absolute threshold [Pa] for "in contact".
MIN_PRESSURE = 100.0


@dataclass(frozen=True)
class ContactSummary:
    """Summary of one pressure field (SI units)."""

    total_force: float  # N
    cop: tuple[float, float]  # m
    contact_area: float  # m²
    peak_pressure: float  # Pa
    in_contact: bool


@dataclass(frozen=True)
class Contact:
    """One contact of a frame (SI units, patch frame).

    Attributes:
        force: normal force [N].
        center: centre (x, y) [m].
        radius: radius of the contact disc [m].
        profile: ``"punch"`` or ``"hertz"`` for a round contact fitted to the readings
            (:mod:`tactile_contact.inverse.round_contact`), ``"field"`` for a traction field's
            summary
            (its force and centre of pressure, the radius of a disc of its contact area).
    """

    force: float
    center: tuple[float, float]
    radius: float
    profile: str

    @classmethod
    def of_field(cls, summary: ContactSummary) -> Contact:
        """The field summarised by ``summary`` as one contact."""
        return cls(
            summary.total_force,
            summary.cop,
            math.sqrt(summary.contact_area / math.pi),
            "field",
        )


def summarize(
    pressure: ArrayLike,
    centers: ArrayLike,
    cell_area: float,
    rel_threshold: float = REL_THRESHOLD,
    min_pressure: float = MIN_PRESSURE,
) -> ContactSummary:
    """Summarise ``pressure`` (N,) [Pa] on cells with ``centers`` (N, 2) [m] of ``cell_area`` [m²].

    NaN/inf pressures raise ValueError (a solver failure must be handled by the caller).
    """
    p = np.asarray(pressure, dtype=np.float64).ravel()
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if c.shape[0] != p.shape[0]:
        raise ValueError(f"pressure has {p.shape[0]} cells but centers has {c.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise ValueError("pressure contains NaN or inf")
    if not (math.isfinite(cell_area) and cell_area > 0):
        raise ValueError(f"cell_area must be finite and > 0 m², got {cell_area!r}")
    if not (0 <= rel_threshold < 1):
        raise ValueError(f"rel_threshold must be in [0, 1), got {rel_threshold!r}")
    if not (math.isfinite(min_pressure) and min_pressure >= 0):
        raise ValueError(f"min_pressure must be finite and >= 0 Pa, got {min_pressure!r}")
    force = float(p.sum() * cell_area)
    pos = np.clip(p, 0.0, None)
    if len(p) == 0 or not np.any(pos > 0):
        return ContactSummary(force, (0.0, 0.0), 0.0, 0.0, False)
    peak = float(pos.max())
    cop = (pos @ c) / pos.sum()
    on = p > max(rel_threshold * peak, min_pressure)
    return ContactSummary(
        force, (float(cop[0]), float(cop[1])), float(on.sum() * cell_area), peak, bool(on.any())
    )
