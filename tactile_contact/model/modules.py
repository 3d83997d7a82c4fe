"""Skin module types: taxel geometry in each module's own frame.

Channel centres come from the public iCub / ROBOSKIN host code (DESIGN.md §6). Coordinates are
stored in millimetres as published and exposed in metres. Channel order is the order in which
the module sends them on the CAN bus (frame A: channels 0-6, frame B: channels 7-11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

CHANNELS_PER_MODULE = 12


@dataclass(frozen=True)
class ModuleType:
    """Geometry of one kind of skin module.

    Attributes:
        name: type name used in layout YAML files.
        channel_xy_mm: (12, 2) channel centres [mm] in the module frame, in CAN channel order.
        taxel: (12,) True where the channel is a pressure taxel (False for thermal pads).
        pitch_mm: nominal distance between neighbouring taxels [mm].
    """

    name: str
    channel_xy_mm: tuple[tuple[float, float], ...]
    taxel: tuple[bool, ...]
    pitch_mm: float

    @property
    def channel_xy(self) -> NDArray[np.float64]:
        """(12, 2) channel centres [m] in the module frame."""
        return np.asarray(self.channel_xy_mm, dtype=np.float64) * 1e-3

    @property
    def taxel_mask(self) -> NDArray[np.bool_]:
        """(12,) True for channels that measure pressure."""
        return np.asarray(self.taxel, dtype=bool)


# fmt: off
ROBOSKIN12 = ModuleType(
    name="roboskin12",
    channel_xy_mm=(
        (7.5, -1.155), (10.25, -5.918), (4.75, -5.918), (0.0, -3.175),
        (-4.75, -5.918), (-10.25, -5.918), (-7.5, -1.155), (-2.75, 1.588),
        (-2.75, 7.073), (0.0, 11.836), (2.75, 7.073), (2.75, 1.588),
    ),
    taxel=(True,) * 12,
    pitch_mm=5.5,
)

ICUB_V2_10PAD = ModuleType(
    name="icub_v2_10pad",
    channel_xy_mm=(
        (6.533, 0.0), (9.8, -5.66), (3.267, -5.66), (0.0, 0.0),
        (-3.267, -5.66), (-9.8, -5.66), (-6.51, -3.75), (-6.533, 0.0),
        (-3.267, 5.66), (0.0, 11.317), (0.0, 7.532), (3.267, 5.66),
    ),
    taxel=(True,) * 6 + (False,) + (True,) * 3 + (False,) + (True,),
    pitch_mm=6.533,
)

# The iCub V2 palm (skinGui types palmL / palmR): 48 channels on one CAN board, sent as its
# triangles 8..11 (12 channels each), so it is four module types placed at one pose. Channel
# centres from icub-main src/tools/iCubSkinGui/plugin/include/PalmLeft.h / PalmRight.h at
# 1 mm per unit (their drawing scales by 1.2 more; the l_hand/r_hand positions files match
# these at 1.0009 mm per unit, 0.1 mm rms, except palm channel 25, 2.8 mm off). Thermal pads:
# palm channels 11, 23, 35, 43. Seen from outside the hand: the left palm as drawn, the right
# palm mirror-imaged (x → −x; the GUI draws both alike). Origin: the drawing's origin, at the
# palm's edge next to channel 29.
_PALM_LEFT = (
    ((32, -3.5), (32, 1), (27, -3.5), (27, 1), (37, 1), (42, 0),
     (27, 6), (32, 6), (37, 6), (42, 5.5), (47, 4.5), (51.7, 4)),
    ((47.5, -18), (38, -14), (32, -9), (27, -9), (37, -9), (37.5, -4.5),
     (43, -16), (42, -10.5), (42, -5.5), (46.5, -8), (47, -13), (43.5, -20)),
    ((21.5, -4), (14.5, -3.5), (11.5, 1), (6.5, 1), (6.5, 6), (1.5, 6.5),
     (11.5, 6), (16.5, 6), (16.5, 1), (21.5, 6), (21.5, 1), (9.5, -2)),
    ((38, -19.5), (43, -26), (38, -24.5), (40, -29.5), (33, -24.5), (35, -29),
     (33, -19.5), (37, -32.5), (28, -24.5), (28, -19.5), (28, -14.5), (33, -14.5)),
)
_PALM_RIGHT = (
    ((-47, 4.5), (-42, 5.5), (-37, 6), (-32, 6), (-37, 1), (-42, 0),
     (-27, 6), (-27, 1), (-32, 1), (-27, -3.5), (-32, -3.5), (-51.7, 4)),
    ((-47.5, -18), (-47, -13), (-46.5, -8), (-42, -5.5), (-37.5, -4.5), (-37, -9),
     (-43, -16), (-42, -10.5), (-27, -9), (-32, -9), (-38, -14), (-43.5, -20)),
    ((-16.5, 6), (-11.5, 6), (-6.5, 6), (-1.5, 6.5), (-11.5, 1), (-6.5, 1),
     (-14.5, -3.5), (-21.5, 6), (-16.5, 1), (-21.5, 1), (-21.5, -4), (-9.5, -2)),
    ((-28, -19.5), (-28, -24.5), (-33, -24.5), (-35, -29), (-40, -29.5), (-38, -24.5),
     (-33, -19.5), (-37, -32.5), (-43, -26), (-38, -19.5), (-33, -14.5), (-28, -14.5)),
)
_PALM_PADS = (11, 11, 11, 7)  # per part: the channel that is a thermal pad
# fmt: on

PALM_TYPES = tuple(
    ModuleType(
        name=f"icub_palm_{side}_{k}",
        channel_xy_mm=tuple((float(x), float(y)) for x, y in xy),
        taxel=tuple(ch != _PALM_PADS[k] for ch in range(CHANNELS_PER_MODULE)),
        pitch_mm=5.0,
    )
    for side, parts in (("left", _PALM_LEFT), ("right", _PALM_RIGHT))
    for k, xy in enumerate(parts)
)

MODULE_TYPES: dict[str, ModuleType] = {m.name: m for m in (ROBOSKIN12, ICUB_V2_10PAD, *PALM_TYPES)}


def module_type(name: str) -> ModuleType:
    """Return the module type called ``name``; KeyError lists the known names."""
    try:
        return MODULE_TYPES[name]
    except KeyError:
        known = ", ".join(sorted(MODULE_TYPES))
        raise KeyError(f"unknown module type {name!r} (known: {known})") from None


def place_channels(
    mtype: ModuleType,
    position_m: tuple[float, float],
    rotation_deg: float,
    mirrored: bool = False,
) -> NDArray[np.float64]:
    """Channel centres [m] of one module placed in the patch frame.

    The module frame is first mirrored about its y axis (x → −x) if ``mirrored``, then rotated
    counter-clockwise by ``rotation_deg`` and translated to ``position_m``.
    """
    xy = mtype.channel_xy.copy()
    if mirrored:
        xy[:, 0] = -xy[:, 0]
    t = np.deg2rad(rotation_deg)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return xy @ rot.T + np.asarray(position_m, dtype=np.float64)


def taxel_id(board: int, triangle: int, channel: int) -> int:
    """Bus-unique integer id of one channel: ``board << 8 | triangle << 4 | channel``.

    Board 0..15, triangle 0..15, channel 0..11 (DESIGN.md §6 addressing). Messages carry this id
    so that a consumer can map readings to bundle taxels without knowing the module order.
    """
    if not (0 <= board <= 15 and 0 <= triangle <= 15 and 0 <= channel < CHANNELS_PER_MODULE):
        raise ValueError(
            f"taxel address out of range: board {board} (0..15), triangle {triangle} (0..15), "
            f"channel {channel} (0..{CHANNELS_PER_MODULE - 1})"
        )
    return (board << 8) | (triangle << 4) | channel


def split_taxel_id(tid: int) -> tuple[int, int, int]:
    """Inverse of :func:`taxel_id`: (board, triangle, channel)."""
    return (tid >> 8) & 0xF, (tid >> 4) & 0xF, tid & 0xF
