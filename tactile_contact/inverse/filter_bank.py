"""The matched-filter bank of a patch: what the detection stage compares each frame with.

Round contacts of a few sizes (:data:`DETECTION_PROFILES`) on a lattice of
:data:`DETECTION_PITCH` over the skin, each one filter of
:class:`tactile_contact.inverse.detection.ContactDetector`; the refined test counts every
tabulated profile on a finer lattice (:data:`REFINE_PITCH`), which a fitted contact stands
for. No ROS import.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.detection import ContactDetector
from tactile_contact.inverse.round_contact import RoundTables
from tactile_contact.model.grids import distance_to_points

#: Lattice pitch [m] of the detector's bank, and how far beyond a taxel it reaches [m].
DETECTION_PITCH = 2.0e-3
DETECTION_REACH = 4.0e-3
REFINE_PITCH = 0.25e-3
#: Bank profiles (family index into round_contact.FAMILIES, contact radius [m]): small to
#: broad punches and spheres. Without the 6.5 mm punch a 12 mm flat punch read by point-like
#: taxels explained only 35 % of its frame's energy and light presses of it went unseen.
DETECTION_PROFILES = ((0, 1.0e-3), (1, 2.5e-3), (0, 4.0e-3), (1, 5.0e-3), (0, 6.5e-3))


def patch_detector(
    tables: RoundTables, taxel_xy: NDArray, margin: float, noise: NDArray
) -> ContactDetector:
    """The detector of a patch with taxels at ``taxel_xy`` (K, 2) [m]: the bank's lattice
    spans the taxels' bounding box grown by ``margin`` [m] (the traction cell), kept within
    DETECTION_REACH of a taxel; ``noise`` (K,) [m] each taxel's compression noise."""
    lo = taxel_xy.min(axis=0) - margin
    hi = taxel_xy.max(axis=0) + margin
    axes = [np.arange(lo[i], hi[i] + 1e-12, DETECTION_PITCH) for i in (0, 1)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    grid = grid[distance_to_points(grid, taxel_xy) <= DETECTION_REACH]
    dist = np.hypot(
        grid[:, None, 0] - taxel_xy[None, :, 0],
        grid[:, None, 1] - taxel_xy[None, :, 1],
    )
    rows, centres = [], []
    for fam, radius in DETECTION_PROFILES:
        rows.append(tables.response(fam, math.log(radius), dist))
        centres.append(grid)
    # The refined test's count: every tabulated profile (both families, every radius) on a
    # REFINE_PITCH lattice, which a fitted contact stands for (the responses of 2 mm
    # electrodes change little over a quarter of a millimetre).
    per_centre = round(DETECTION_PITCH / REFINE_PITCH) ** 2
    refined = len(grid) * per_centre * tables.table.shape[0] * len(tables.radii)
    return ContactDetector(
        np.concatenate(rows),
        np.concatenate(centres),
        noise,
        refined_filters=refined,
    )
