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

# fmt: on

MODULE_TYPES: dict[str, ModuleType] = {m.name: m for m in (ROBOSKIN12, ICUB_V2_10PAD)}


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
