"""Patch layouts as data: the frozen records a layout file becomes (modules, elastomer,
sensor, grids, elastic model, solver options, surface) and their derived quantities (taxel
places and ids, the hashes a bundle is checked against).

All lengths are metres, moduli pascals, capacitances farads. Reading and validating the YAML
is :mod:`tactile_contact.model.layout`, which re-exports everything here.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.modules import MODULE_TYPES, ModuleType, place_channels, taxel_id
from tactile_contact.model.surface import Surface

SCHEMA_VERSION = 1
MODELS = ("love", "boussinesq")
MASKS = ("taxels", "modules", "none")
SOLVER_METHODS = ("nnls_tikhonov", "tikhonov", "tsvd", "pinv")
REGULARISERS = ("identity", "laplacian")
#: Rules that pick the Tikhonov λ or the TSVD rank at build time
#: (tactile_contact.offline.build.regularisation).
PARAMETER_RULES = ("gcv", "lcurve", "discrepancy")
#: Two taxels closer than this [m] are treated as the same place (a layout mistake), whatever
#: their electrodes; taxels whose electrode discs overlap are refused too.
MIN_TAXEL_SEPARATION = 1.0e-3


class LayoutError(ValueError):
    """A layout file is unreadable or invalid; the message names file, key path and problem."""


@dataclass(frozen=True)
class ModuleSpec:
    """One skin module placed in the patch frame.

    Attributes:
        type: module type name (see :data:`tactile_contact.model.modules.MODULE_TYPES`).
        board: CAN board address 0..15.
        triangle: triangle address 0..15 on that board.
        position: (x, y) of the module origin in the patch frame [m].
        rotation_deg: counter-clockwise rotation of the module frame [deg].
        mirrored: module frame mirrored about its y axis before rotating.
        disabled_channels: channels excluded from reconstruction (broken or covered taxels).
    """

    type: str
    board: int
    triangle: int
    position: tuple[float, float]
    rotation_deg: float = 0.0
    mirrored: bool = False
    disabled_channels: tuple[int, ...] = ()

    @property
    def module_type(self) -> ModuleType:
        return MODULE_TYPES[self.type]


@dataclass(frozen=True)
class Elastomer:
    """The soft layer: thickness h [m], Young's modulus E [Pa], Poisson's ratio ν [-]."""

    thickness: float = 2.0e-3
    young: float = 2.1e5
    poisson: float = 0.5


@dataclass(frozen=True)
class SensorSpec:
    """Capacitive taxel calibration.

    Attributes:
        epsilon_r: relative permittivity of the dielectric [-].
        taxel_radius: radius of a taxel's electrode [m]; its area is π r².
        farad_per_count: capacitance of one CDC count [F].
        no_load: 8-bit reading with no load [counts].
        shift: right shift applied by the firmware to the CDC value [bits].
        cdc_offset: the CDC offset the boards are configured with (SET_TRIANG_CFG) [CDC
            counts], when the layout says (an imported robot skin spec); None: the driver's.
    """

    epsilon_r: float = 4.37
    taxel_radius: float = 2.0e-3
    farad_per_count: float = 0.32e-15
    no_load: int = 240
    shift: int = 2
    cdc_offset: int | None = None

    @property
    def area(self) -> float:
        """Electrode area [m²]."""
        return math.pi * self.taxel_radius**2


@dataclass(frozen=True)
class GridSpec:
    """Reconstruction grids.

    Attributes:
        traction_cell: edge of the square pressure cells [m].
        deflection_cell: edge of the square cells of the output deflection grid [m].
        margin: extent of the grids beyond the outermost taxel centres [m].
        mask: which cells are skin: ``taxels`` (within ``mask_distance`` of a valid taxel),
            ``modules`` (within ``mask_distance`` of a module's channel hull) or ``none``.
        mask_distance: distance used by the mask [m].
    """

    traction_cell: float = 2.0e-3
    deflection_cell: float = 1.0e-3
    margin: float = 3.0e-3
    mask: str = "taxels"
    mask_distance: float = 3.5e-3


@dataclass(frozen=True)
class ModelSpec:
    """Elastic model: ``love`` (uniform pressure cells) or ``boussinesq`` (point forces with the
    Muscari self term, ``psi`` = ``exact`` for Ψ(x) = (0.2431x − 0.1814)/x or a constant such as
    0.25). ``taxel_average``: a taxel measures the mean deflection over its electrode disc
    (True, default) rather than the value at its centre.

    The taxel's effective response, as ``tactile-contact-calibrate`` fits it to presses of
    known force and position (defaults: the nominal sensor):
    ``footprint_radius``: radius [m] of the disc a taxel averages the deflection over (None:
    the electrode's, ``sensor.taxel_radius``; 0: the value at its centre); ``gain``: reading
    per true compression [-]; ``layer_scale``: elastic layer thickness over the nominal
    ``elastomer.thickness`` [-]."""

    kind: str = "love"
    psi: str | float = "exact"
    taxel_average: bool = True
    footprint_radius: float | None = None
    gain: float = 1.0
    layer_scale: float = 1.0


@dataclass(frozen=True)
class SolverSpec:
    """Online solver options (docs/reconstruction.md explains the choices and defaults).

    Attributes:
        method: ``nnls_tikhonov`` (default), ``tikhonov``, ``tsvd`` or ``pinv`` (the paper's).
        regulariser: ``identity`` or ``laplacian`` (smoothness) for the Tikhonov term.
        tikhonov: λ relative to the largest singular value of C [-], or a rule that picks it
            at build time (``gcv``, ``lcurve``, ``discrepancy``; PARAMETER_RULES).
        rcond: relative singular-value cut-off of ``pinv`` [-].
        tsvd_rank: singular values kept by ``tsvd``, or a rule (default ``discrepancy``).
        noise: taxel compression noise [m], for the free solution's non-negativity test.
        contact_threshold: compression [m] above which a taxel counts as active (reported as
            ``taxels_active``; a seed of a separate contact above 2.5×). With ``refine: round``
            contact is detected against the noise (tactile_contact.inverse.detection); for the
            grid-only
            methods a frame is in contact when a valid taxel's |δ| exceeds it. The default,
            1.1e-5 m (≈ 1.05 count), ignores the ±1-count readings of an idle skin.
        nnls_method: ``bpp`` (block principal pivoting) or ``fista``.
        support_radius: the second NNLS pass keeps cells within this distance of the first
            pass's strong cells [m].
        seed_fraction: first-pass cells at or above this fraction of its peak seed the support.
        area_rel_threshold: a cell is in contact above this fraction of the peak pressure [-].
        area_min_pressure: ... and above this pressure [Pa].
        refine: ``round`` (default): on every contact frame, fit round contacts straight to
            the readings through radial responses tabulated offline on a 0.1 mm grid
            (tactile_contact.inverse.round_contact): least squares, or the posterior mean for
            quantised readings; the grid solution only when they do not explain the readings;
            ``none``: the grid solution always (far worse force).
        max_contacts: ``refine: round`` fits up to this many separate round contacts (one per
            taxel that reads most within 8 mm), kept over the single contact only when they
            explain the readings better than extra parameters fitted to noise would; 1 fits
            one contact always.
    """

    method: str = "nnls_tikhonov"
    regulariser: str = "identity"
    tikhonov: float | str = 0.1
    rcond: float = 1.0e-3
    tsvd_rank: int | str | None = "discrepancy"
    noise: float = 6.0e-6
    contact_threshold: float = 1.1e-5
    nnls_method: str = "bpp"
    support_radius: float = 4.0e-3
    seed_fraction: float = 0.3
    area_rel_threshold: float = 0.1
    area_min_pressure: float = 100.0
    refine: str = "round"
    max_contacts: int = 3


@dataclass(frozen=True)
class PatchLayout:
    """One patch: modules plus the physical and numerical parameters of its reconstruction;
    ``surface``: where the flat patch lies on the robot (None: nowhere known; see
    :mod:`tactile_contact.model.surface`); ``bus``: the CAN bus its modules are on ("": the
    only one), served by one ``skin_driver`` per bus."""

    name: str
    frame_id: str
    modules: tuple[ModuleSpec, ...]
    elastomer: Elastomer = field(default_factory=Elastomer)
    sensor: SensorSpec = field(default_factory=SensorSpec)
    grid: GridSpec = field(default_factory=GridSpec)
    model: ModelSpec = field(default_factory=ModelSpec)
    solver: SolverSpec = field(default_factory=SolverSpec)
    surface: Surface | None = None
    bus: str = ""

    def _channels(self, valid_only: bool) -> list[tuple[ModuleSpec, int, NDArray[np.float64]]]:
        out = []
        for m in self.modules:
            xy = place_channels(m.module_type, m.position, m.rotation_deg, m.mirrored)
            for ch in range(len(xy)):
                ok = m.module_type.taxel[ch] and ch not in m.disabled_channels
                if ok or not valid_only:
                    out.append((m, ch, xy[ch]))
        return out

    def taxel_xy(self) -> NDArray[np.float64]:
        """(K, 2) centres [m] of the valid taxels in the patch frame, in bundle order (modules in
        file order, channels ascending; thermal pads and disabled channels left out)."""
        ch = self._channels(valid_only=True)
        return np.array([c[2] for c in ch], dtype=np.float64).reshape(-1, 2)

    def taxel_ids(self) -> NDArray[np.int64]:
        """(K,) bus-unique ids (:func:`tactile_contact.model.modules.taxel_id`) of the valid
        taxels."""
        ch = self._channels(valid_only=True)
        return np.array([taxel_id(m.board, m.triangle, c) for m, c, _ in ch], dtype=np.int64)

    def channel_xy(self) -> NDArray[np.float64]:
        """(12·M, 2) centres [m] of every channel of every module, valid or not."""
        return np.array([c[2] for c in self._channels(valid_only=False)]).reshape(-1, 2)

    def valid_mask(self) -> NDArray[np.bool_]:
        """(12·M,) True for channels that are valid taxels (same order as :meth:`channel_xy`)."""
        return np.array(
            [
                m.module_type.taxel[c] and c not in m.disabled_channels
                for m, c, _ in self._channels(False)
            ],
            dtype=bool,
        )

    def module_outlines(self) -> list[NDArray[np.float64]]:
        """Per module, the (12, 2) channel centres [m] (pads included) in the patch frame."""
        return [
            place_channels(m.module_type, m.position, m.rotation_deg, m.mirrored)
            for m in self.modules
        ]

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (lists, floats) used for hashing and in bundle manifests."""
        d = asdict(self)
        d["modules"] = [
            dict(m, position=list(m["position"]), disabled_channels=list(m["disabled_channels"]))
            for m in d["modules"]
        ]
        # Keys added after version 1 appear only when set, so that the hashes of bundles
        # built before them stay valid.
        if d["sensor"]["cdc_offset"] is None:
            del d["sensor"]["cdc_offset"]
        if self.surface is None:
            del d["surface"]
        else:
            d["surface"] = self.surface.to_dict()
        if not self.bus:
            del d["bus"]
        return d

    @property
    def footprint(self) -> float:
        """Radius [m] of the disc each taxel averages the deflection over (0: a point)."""
        if self.model.footprint_radius is not None:
            return self.model.footprint_radius
        return self.sensor.taxel_radius if self.model.taxel_average else 0.0

    @property
    def layer_thickness(self) -> float:
        """Thickness [m] of the elastic layer in the model (nominal × ``layer_scale``)."""
        return self.elastomer.thickness * self.model.layer_scale

    def layout_hash(self) -> str:
        """sha256 of the geometry (modules) — a bundle of another layout is *foreign*."""
        geo = {"name": self.name, "modules": self.to_dict()["modules"]}
        return _sha(geo)

    def parameter_hash(self) -> str:
        """sha256 of everything that changes the matrices (all but name/frame) — *stale* check."""
        d = self.to_dict()
        d.pop("frame_id")
        d.pop("bus", None)  # wiring, like the frame: moving a patch to another bus needs no rebuild
        return _sha(d)


@dataclass(frozen=True)
class Layout:
    """A layout file: one or more patches with unique names."""

    patches: tuple[PatchLayout, ...]
    source: str = "<memory>"

    def buses(self) -> tuple[str, ...]:
        """The CAN buses of the patches, in file order ("" is the single unnamed bus)."""
        return tuple(dict.fromkeys(p.bus for p in self.patches))

    def patch(self, name: str) -> PatchLayout:
        for p in self.patches:
            if p.name == name:
                return p
        raise KeyError(
            f"{self.source}: no patch named {name!r} (have: {[p.name for p in self.patches]})"
        )


def _sha(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()
