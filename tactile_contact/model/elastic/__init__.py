"""Elastic half-space influence coefficients (Boussinesq–Cerruti, Love) and their assembly.

Units are SI: positions [m], pressures [Pa], forces [N], displacements [m]; coefficients are
[m/Pa] for pressure cells (Love) and [m/N] for point forces (Boussinesq–Cerruti). Depth z ≥ 0
points into the skin; compressive load and displacement into the skin are positive. The
"effective" displacement is u(0) − u(h), what a taxel over a layer of thickness h measures.
See docs/elastic.md for the formulas and their validation.
"""

from __future__ import annotations

from tactile_contact.model.elastic.assembly import (
    boussinesq_block_matrix,
    boussinesq_matrix,
    love_depth_matrix,
    love_matrix,
    shear_self,
)
from tactile_contact.model.elastic.boussinesq import (
    boussinesq_block,
    boussinesq_block_effective,
    boussinesq_effective,
    boussinesq_uz,
    min_magnitude,
    muscari_psi,
    muscari_self,
)
from tactile_contact.model.elastic.love import (
    love_effective,
    love_ux,
    love_uy,
    love_uz,
    love_uz_effective,
)
from tactile_contact.model.elastic.toeplitz import RegularGridOperator, regular_grid_operator

__all__ = [
    "RegularGridOperator",
    "boussinesq_block",
    "boussinesq_block_effective",
    "boussinesq_block_matrix",
    "boussinesq_effective",
    "boussinesq_matrix",
    "boussinesq_uz",
    "love_depth_matrix",
    "love_effective",
    "love_matrix",
    "love_ux",
    "love_uy",
    "love_uz",
    "love_uz_effective",
    "min_magnitude",
    "muscari_psi",
    "muscari_self",
    "regular_grid_operator",
    "shear_self",
]
