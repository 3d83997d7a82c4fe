"""The paper's protocol and the patch it runs on.

Indenters: sphere 12 mm (HertzSphere 6 mm), sphere 6 mm (3 mm), cylinder 12 mm (FlatPunch
6 mm), cylinder 3 mm (1.5 mm); forces 0.2, 0.5, 1, 1.8, 2.5, 3 N; places over taxel 3, between
taxels 7 and 11, at the centroid of 3, 7, 11 of modules 4 and 2 of the default patch
(config/hexagon_patch.yaml). Variants of the patch are the default YAML with a few keys changed.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from benchkit import LAYOUT
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import PatchLayout, load_layout, parse_layout
from tactile_contact.model.sensor import (
    compression_to_delta_c,
    delta_c_to_compression,
    value_count_farad,
)
from tactile_contact.offline.build import build_layout

INDENTERS = {
    "sphere 12 mm": HertzSphere(6e-3),
    "sphere 6 mm": HertzSphere(3e-3),
    "cylinder 12 mm": FlatPunch(6e-3),
    "cylinder 3 mm": FlatPunch(1.5e-3),
}
#: Forces [N], and the quick protocol's.
FORCES = (0.2, 0.5, 1.0, 1.8, 2.5, 3.0)
QUICK_FORCES = (0.2, 0.5, 1.0, 3.0)
#: The kinds of place, in the order :func:`positions` gives them per module.
PLACES = ("over a taxel", "between two", "between three")


def positions(
    xy: NDArray, modules: tuple[int, ...] = (4, 2), ids: NDArray | None = None
) -> list[tuple[str, NDArray]]:
    """(kind, centre [m]) of the protocol's places: over taxel 3, between taxels 7 and 11, at
    the centroid of 3, 7, 11 of each module (the k-th module of the bundle order). Without
    ``ids`` every module has 12 taxels (the default patch's roboskin12); with the bundle's
    taxel ids (board << 8 | triangle << 4 | channel) any module type whose channels 3, 7, 11
    are taxels (an imported iCub patch's icub_v2_10pad: 10 taxels a module)."""
    out = []
    if ids is None:
        per_module = [(xy[12 * k + 3], xy[12 * k + 7], xy[12 * k + 11]) for k in modules]
    else:
        ids = np.asarray(ids)
        order = list(dict.fromkeys((ids >> 4).tolist()))  # modules in bundle order
        per_module = [
            tuple(xy[int(np.flatnonzero(ids == (order[k] << 4 | c))[0])] for c in (3, 7, 11))
            for k in modules
        ]
    for t3, t7, t11 in per_module:
        out += [
            (PLACES[0], t3),
            (PLACES[1], (t7 + t11) / 2),
            (PLACES[2], (t3 + t7 + t11) / 3),
        ]
    return out


class Patch:
    """A patch under test (the first of a layout file): taxel centres (bundle order), the
    elastic layer and the sensor model's constants, 1 count of ΔC [F]."""

    def __init__(self, path: Path = LAYOUT) -> None:
        patch = load_layout(path).patches[0]
        self.name = patch.name
        self.xy = patch.taxel_xy()
        self.ids = patch.taxel_ids()
        e, s = patch.elastomer, patch.sensor
        self.thickness, self.young, self.poisson = e.thickness, e.young, e.poisson
        self.epsilon_r, self.area = s.epsilon_r, s.area
        self.lsb = float(value_count_farad(s.farad_per_count, s.shift))

    def to_delta_c(self, d: NDArray) -> NDArray[np.float64]:
        """ΔC [F] of compressions ``d`` [m] (the sensor model)."""
        return compression_to_delta_c(d, self.thickness, self.epsilon_r, self.area)

    def to_deflection(self, dc: NDArray) -> NDArray[np.float64]:
        """Compressions [m] of ΔC ``dc`` [F] (the sensor model's inverse)."""
        return delta_c_to_compression(dc, self.thickness, self.epsilon_r, self.area)


def default_reconstructor(folder: Path, layout: Path = LAYOUT) -> Reconstructor:
    """Build the layout's bundle under ``folder`` (one process) and load it as a node does."""
    build_layout(layout, folder, jobs=1)
    return Reconstructor.from_bundle(folder / load_layout(layout).patches[0].name)


#: The default patch document (config/hexagon_patch.yaml), as loaded from YAML.
BASE_DOC: dict[str, Any] = yaml.safe_load(LAYOUT.read_text())


def variant_doc(sections: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The default layout document with the given ``{section: {key: value}}`` overrides."""
    doc = copy.deepcopy(BASE_DOC)
    for sec, kv in sections.items():
        doc["patches"][0].setdefault(sec, {}).update(kv)
    return doc


def variant(sections: dict[str, dict[str, Any]]) -> PatchLayout:
    """The default patch with the given ``{section: {key: value}}`` overrides."""
    return parse_layout(variant_doc(sections)).patches[0]
