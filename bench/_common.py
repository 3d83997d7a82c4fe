"""Helpers shared by bench/tradeoff.py and bench/stability.py (not a library module).

Everything here reuses the package: layouts are the default YAML with a few keys changed,
bundles come from :func:`tactile_contact.offline.build.build_patch`, reconstructions from
:class:`tactile_contact.inverse.reconstruction.Reconstructor`. SI units throughout (m, Pa, N, F).
"""

from __future__ import annotations

import copy
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the package without installing it

from tactile_contact.inverse.reconstruction import Reconstructor  # noqa: E402
from tactile_contact.model.layout import PatchLayout, parse_layout  # noqa: E402
from tactile_contact.offline.bundle import save_bundle  # noqa: E402

#: The default patch document (config/hexagon_patch.yaml), as loaded from YAML.
BASE_DOC: dict[str, Any] = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())


def variant(sections: dict[str, dict[str, Any]]) -> PatchLayout:
    """The default patch with the given ``{section: {key: value}}`` overrides."""
    doc = copy.deepcopy(BASE_DOC)
    for sec, kv in sections.items():
        doc["patches"][0].setdefault(sec, {}).update(kv)
    return parse_layout(doc).patches[0]


def timed_build(build: Any, *args: Any) -> tuple[Any, float, float]:
    """(result, wall time [s], peak traced memory [MB]) of ``build(*args)``.

    Timed once untraced (tracemalloc slows allocation-heavy code), then run again under
    tracemalloc for the peak of Python and NumPy allocations."""
    t0 = time.perf_counter()
    out = build(*args)
    seconds = time.perf_counter() - t0
    tracemalloc.start()
    try:
        build(*args)
        peak = tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
    return out, seconds, peak


def load(folder: Path, manifest: dict[str, Any], arrays: dict[str, NDArray]) -> Reconstructor:
    """Save a bundle under ``folder`` and load it the way a node does (memory-mapped)."""
    return Reconstructor.from_bundle(save_bundle(folder, manifest, arrays))


def interpolation_matrix(taxel_xy: NDArray, points: NDArray) -> NDArray[np.float64]:
    """(M, K) linear map from K taxel readings to M points: piecewise-linear on the Delaunay
    triangulation of the taxels inside their convex hull, the nearest taxel outside it.

    This is the paper's "interpolated measurement grid": readings are interpolated onto a
    regular grid before the inverse."""
    k = len(taxel_xy)
    lin = LinearNDInterpolator(taxel_xy, np.eye(k), fill_value=np.nan)(points)
    inside = np.isfinite(lin).all(axis=1)
    nearest = cKDTree(taxel_xy).query(points[~inside])[1]
    p = np.where(inside[:, None], np.nan_to_num(lin), 0.0)
    p[np.flatnonzero(~inside), nearest] = 1.0
    return p


def square_grid(n: int, pitch: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centres (n², 2) [m] of an n × n grid of ``pitch`` [m] cells and the cell half sizes."""
    c = (np.arange(n) - (n - 1) / 2) * pitch
    xx, yy = np.meshgrid(c, c)
    return np.column_stack([xx.ravel(), yy.ravel()]), np.full(2, pitch / 2)


def kappa_estimate(h: float, d: float, length: float) -> float:
    """DESIGN.md §2: κ ≈ max(0.94·h/d, 0.19·L/h) of a square problem (pitch d, side L)."""
    return max(0.94 * h / d, 0.19 * length / h)
