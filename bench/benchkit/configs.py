"""Library configurations under test, each as one online path ΔC [F] → ContactResult.

A :class:`Config` is the default patch (config/hexagon_patch.yaml) with layout overrides, plus
what the library has no option for: the paper's interpolated measurement grid (``mode``
``grid``), the free operator in float64 (``dtype``), one NNLS(+Tikhonov) over the whole grid
instead of the library's two-pass solve (``passes`` 1). Bundles come from
:func:`tactile_contact.offline.build.build_patch` and are loaded the way a node loads them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree

from benchkit.protocol import variant
from benchkit.timing import timed_build
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.result import ContactResult
from tactile_contact.inverse.solvers import NnlsSolver
from tactile_contact.inverse.summary import summarize
from tactile_contact.model.layout import PatchLayout
from tactile_contact.model.sensor import compression_to_delta_c
from tactile_contact.offline.build import build_patch, forward_matrix, free_inverse, grids_for
from tactile_contact.offline.bundle import save_bundle


@dataclass(frozen=True)
class Config:
    """One configuration.

    ``sections`` overrides the default layout; ``mode`` is ``taxels`` (solve at the taxels,
    the default) or ``grid`` (the paper's: readings interpolated onto the traction grid's cell
    centres, then the square problem); ``dtype`` is the free product's precision; ``passes`` 1
    runs one NNLS(+Tikhonov) over the whole grid through :class:`NnlsSolver` instead of the
    library's two-pass solve."""

    key: str
    name: str
    factor: str
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)
    mode: str = "taxels"
    dtype: str = "float32"
    passes: int = 2


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


def _build(patch: PatchLayout, cfg: Config) -> tuple[dict, dict, dict]:
    """Bundle contents of a configuration plus bench-side extras (float64 inverse, P)."""
    manifest, arrays = build_patch(patch)
    extra: dict[str, Any] = {}
    reg = arrays.get("regulariser")
    if cfg.mode == "grid":
        tg, _ = grids_for(patch)
        centres = tg.centers()
        c = forward_matrix(patch, centres, tg)  # point values at the virtual grid nodes
        inverse, lam = free_inverse(patch, c, reg)
        extra["interp"] = interpolation_matrix(patch.taxel_xy(), centres)
        arrays.update(
            forward=c,
            inverse=inverse.astype(np.float32),
            taxel_xy=centres,
            taxel_ids=np.arange(len(centres)),
        )
        manifest["params"]["tikhonov"] = lam
    else:
        inverse, _ = free_inverse(patch, arrays["forward"], reg)
    if cfg.dtype == "float64":
        extra["inverse64"] = inverse
    if cfg.passes == 1:
        p = manifest["params"]
        extra["nnls"] = NnlsSolver(
            arrays["forward"], p["tikhonov"], reg, p["nnls_method"]
        ).prepare()
    return manifest, arrays, extra


class Pipeline:
    """A configuration's online path: ΔC [F] (K,) → ContactResult, through Reconstructor;
    ``build_s`` and ``build_mb``: its offline build's wall time [s] and peak memory [MB]
    (``measure`` False: built once, not measured, both NaN)."""

    def __init__(self, cfg: Config, folder: Path, measure: bool = True) -> None:
        self.cfg = cfg
        if measure:
            (manifest, arrays, extra), self.build_s, self.build_mb = timed_build(
                _build, variant(cfg.sections), cfg
            )
        else:
            manifest, arrays, extra = _build(variant(cfg.sections), cfg)
            self.build_s = self.build_mb = float("nan")
        self.recon: Reconstructor = Reconstructor.from_bundle(save_bundle(folder, manifest, arrays))
        if "inverse64" in extra:
            # Reconstructor has no precision option (it always casts C⁺ to float32); the bench
            # swaps in the float64 operator, which its product then uses as is.
            grid = self.recon.grid  # the grid-fallback stage holds the free operator
            assert grid.inverse.shape == extra["inverse64"].shape
            grid.inverse = np.ascontiguousarray(extra["inverse64"])
        self.interp = extra.get("interp")
        self.nnls: NnlsSolver | None = extra.get("nnls")
        r = self.recon
        self._defl = np.asarray(r.bundle["deflection_operator"], np.float32)
        self._centres, self._area = r.traction_grid.centers(), r.traction_grid.cell_area

    def frame(self, dc: NDArray) -> ContactResult:
        r = self.recon
        if self.interp is not None:
            return r.solve_deflection(self.interp @ r.compression(dc))
        if self.nnls is None:
            return r.solve(dc)
        return self._one_pass(dc)

    def _one_pass(self, dc: NDArray) -> ContactResult:
        """One NNLS over every cell, with the Reconstructor's contact test, summary and
        deflection product: the ablation of the library's second (support) pass."""
        r = self.recon
        delta = r.compression(dc)
        active = int(np.count_nonzero(np.abs(delta) > r.contact_threshold))
        if active == 0:
            return r.solve(dc)  # the library's zero result
        sol = self.nnls.solve(delta)  # type: ignore[union-attr]
        q = sol.x
        p = r.params
        s = summarize(q, self._centres, self._area, p["rel_threshold"], p["min_pressure"])
        d = r.deflection_grid.to_image(self._defl @ q.astype(np.float32)).astype(np.float64)
        return ContactResult(
            r.traction_grid.to_image(q),
            d,
            s.total_force,
            s.cop,
            s.contact_area,
            s.peak_pressure,
            s.in_contact,
            "nnls",
            sol.success,
            sol.iterations,
            sol.residual_norm,
            sol.time_s,
            active,
        )

    def deflection(self, delta: NDArray) -> ContactResult:
        """Reconstruct from compressions δ [m] (the one-pass path takes ΔC: the sensor model is
        inverted exactly, compression being monotonic)."""
        r = self.recon
        if self.nnls is None:
            return r.solve_deflection(delta)
        p = r.params
        return self.frame(compression_to_delta_c(delta, p["thickness"], p["epsilon_r"], p["area"]))


_LINEAR = {"refine": "none"}
#: The solvers the stability benches set side by side: the linear operators alone (the default
#: would add the round fit to them), one-pass NNLS, the default, and float64 products.
SOLVERS = {
    "pinv": Config("pinv", "pinv", "solver", {"solver": {"method": "pinv", **_LINEAR}}),
    "tikhonov": Config(
        "tikhonov", "Tikhonov", "solver", {"solver": {"method": "tikhonov", **_LINEAR}}
    ),
    "nnls (1 pass)": Config("nnls", "NNLS", "solver", {"solver": {"tikhonov": 0.0}}, passes=1),
    "nnls+tikhonov (1 pass)": Config("nnls+tikh", "NNLS+Tikhonov", "solver", passes=1),
    "default (2-pass)": Config("default", "default", "default"),
    "default, float64": Config("f64", "default f64", "dtype", dtype="float64"),
    "pinv, float64": Config(
        "pinv f64",
        "pinv f64",
        "dtype",
        {"solver": {"method": "pinv", **_LINEAR}},
        dtype="float64",
    ),
}


def pipelines(names: list[str], folder: Path) -> dict[str, Pipeline]:
    """The named SOLVERS' pipelines, their bundles under ``folder`` (builds not measured)."""
    return {k: Pipeline(SOLVERS[k], folder / k.replace(" ", "_"), measure=False) for k in names}
